"""The rig's one link to a bench, for scenario runs (``rig.runner``) and commissioning
(``rig.commissioning``) alike:

- ``bus``: the rig's node on the CAN bus (validated frames in, DBC-encoded frames out, the
  scenario's faults on the rig's own frames, a recording);
- ``clock``: how bench time passes (lockstep grants on the bus or in process, or the wall
  clock), with the cyclic and idle hooks the owners hang their work on;
- ``drive``: the rig as the drive's CAN master (DRIVE_CMD, DRIVE_LIMITS);
- ``bench``: the virtual bench's programs (plant_rt, fw_host, the Modbus load bench) as
  child processes, from a bench description or a scenario.
"""
