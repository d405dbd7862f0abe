"""The rig's one link to a bench, for scenario runs (``rig.run``) and commissioning
(``rig.commissioning``) alike:

- ``bus``: the rig's node on the CAN bus (validated frames in, DBC-encoded frames out, the
  scenario's faults on the rig's own frames, a recording);
- ``clock``: how bench time passes (lockstep grants on the bus or in process, or the wall
  clock), with the cyclic and idle hooks the owners hang their work on;
- ``drive_master``: the rig as the drive's CAN master (DRIVE_CMD, DRIVE_LIMITS);
- ``bench_commands``: the rig's commands to the emulated bench (LOAD_CMD, FAULT_CMD);
- ``frame_faults``: a scenario's faults on the frames the rig sends.
"""
