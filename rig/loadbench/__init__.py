"""The load bench: the load machine and torque sensor behind a Modbus register map
(protocols/modbus_load_bench.json): the rig's client of any load bench, real or virtual
(``client``), and the virtual one, a Modbus server in front of plant_rt's load machine
(``server``, ``rig loadbench serve``).
"""
