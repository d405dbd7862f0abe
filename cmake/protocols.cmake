# Generates C pack/unpack code for every DBC file under protocols/ with
# `cantools generate_c_source`, and wraps it in the static library `hil_protocols`.
# --use-round: the generated `<msg>_<signal>_encode()` rounds to the nearest raw value, as
# cantools' Python encoder does (without it C truncates toward zero: 3.57 A at 1 mA/LSB
# would be raw 3569 in C and 3570 in Python; tests/c/hilbus checks C and Python agree).
set(HIL_GEN_DIR ${CMAKE_BINARY_DIR}/generated)
file(MAKE_DIRECTORY ${HIL_GEN_DIR})
set(HIL_PROTOCOL_SOURCES "")
foreach(dbc drive vio bench)
  set(src ${CMAKE_SOURCE_DIR}/protocols/${dbc}.dbc)
  add_custom_command(
    OUTPUT ${HIL_GEN_DIR}/hil_${dbc}.c ${HIL_GEN_DIR}/hil_${dbc}.h
    COMMAND ${Python3_EXECUTABLE} -m cantools generate_c_source --use-round
            --database-name hil_${dbc} --output-directory ${HIL_GEN_DIR} ${src}
    DEPENDS ${src} ${CMAKE_CURRENT_LIST_FILE}
    COMMENT "cantools: C pack/unpack from protocols/${dbc}.dbc"
    VERBATIM)
  list(APPEND HIL_PROTOCOL_SOURCES ${HIL_GEN_DIR}/hil_${dbc}.c)
endforeach()
# The wire facts the DBC files hold beyond pack/unpack (time base, value-table names) for the
# programs on the bus, generated at configure time like the parameter table: an edit of a DBC
# or of the script re-runs configure. The control core's share is fw_wire_gen.h
# (firmware_c2000/CMakeLists.txt), FW_TRACE's packer fw_trace_gen.c (hal_host).
set(HIL_WIRE_GEN ${CMAKE_SOURCE_DIR}/firmware_c2000/tools/gen_wire.py)
set(HIL_WIRE_DEPENDS ${HIL_WIRE_GEN} ${CMAKE_SOURCE_DIR}/firmware_c2000/tools/c_codegen.py
    ${CMAKE_SOURCE_DIR}/protocols/drive.dbc ${CMAKE_SOURCE_DIR}/protocols/vio.dbc
    ${CMAKE_SOURCE_DIR}/protocols/bench.dbc)
# hil_arrays.h: the signals spelled <name>_<k> (VIO_ADC_x.ia_k, VIO_PWM.soc_k) read and written
# by index, so neither side unrolls them by hand.
foreach(mode host arrays)
  execute_process(
    COMMAND ${Python3_EXECUTABLE} ${HIL_WIRE_GEN} ${mode} ${HIL_GEN_DIR}
            ${CMAKE_SOURCE_DIR}/protocols
    RESULT_VARIABLE HIL_WIRE_RESULT
    ERROR_VARIABLE HIL_WIRE_ERROR)
  if(NOT HIL_WIRE_RESULT EQUAL 0)
    message(FATAL_ERROR "gen_wire.py ${mode} failed: ${HIL_WIRE_ERROR}")
  endif()
endforeach()
set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${HIL_WIRE_DEPENDS})
list(APPEND HIL_PROTOCOL_SOURCES ${HIL_GEN_DIR}/hil_wire.c ${HIL_GEN_DIR}/hil_arrays.c)

add_library(hil_protocols STATIC ${HIL_PROTOCOL_SOURCES})
target_include_directories(hil_protocols PUBLIC ${HIL_GEN_DIR})
if(HIL_LIBM)
  target_link_libraries(hil_protocols PUBLIC ${HIL_LIBM}) # round() of the encoders
endif()

# hil_unixcan.h: the wire of the unixcan fallback bus (datagram layout, flag bits, FD lengths,
# channel-name rule, folder and socket naming, the timing nodes promise each other) for hilbus,
# from protocols/unixcan.toml, at configure time like the above; rig/bus/unixcan_wire.py reads
# the same file.
set(HIL_UNIXCAN_GEN ${CMAKE_SOURCE_DIR}/firmware_c2000/tools/gen_unixcan.py)
execute_process(
  COMMAND ${Python3_EXECUTABLE} ${HIL_UNIXCAN_GEN} ${CMAKE_SOURCE_DIR}/protocols/unixcan.toml
          ${HIL_GEN_DIR}
  RESULT_VARIABLE HIL_UNIXCAN_RESULT
  ERROR_VARIABLE HIL_UNIXCAN_ERROR)
if(NOT HIL_UNIXCAN_RESULT EQUAL 0)
  message(FATAL_ERROR "gen_unixcan.py failed: ${HIL_UNIXCAN_ERROR}")
endif()
set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${HIL_UNIXCAN_GEN}
             ${CMAKE_SOURCE_DIR}/firmware_c2000/tools/c_codegen.py
             ${CMAKE_SOURCE_DIR}/protocols/unixcan.toml)
