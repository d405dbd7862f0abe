"""The test bench the drive runs on: a machine, an inverter, sensors and a load machine,
emulated or in the lab.

- ``description``: a bench description file (``rig/benches/*.toml``): where the drive, its
  console and the load bench are, and how bench time passes;
- ``profiles``, ``plant_schema``: the plant's fidelity profiles and their schema, asked of
  the plant itself;
- ``configuration``: what an emulated bench is set to (the plant's profile and settings,
  the firmware's parameters over the hardware the profile fixes), built in one place;
- ``virtual``: plant_rt, fw_host and the Modbus load bench as child processes on a bus;
- ``sil``: the same plant and control core in one process (``--bus inproc``).

A word of the rig's: a *bench* is this, everywhere (``protocols/bench.dbc`` holds its
frames). Measurements of speed and cost are *benchmarks* (``rig.benchmarks``; the command
``rig bench`` keeps its short name).
"""
