"""Commissioning scripts: the same steps on the virtual bench (tests, CI) and on the real
bench (DSP on CAN and a serial console, load machine and torque sensor over Modbus).

``rig commission <step>|all --bench FILE`` (rig.commands.commission) runs
``commission.commission``; a bench description (rig.bench.description) says where everything is
and whether bench time passes by lockstep grants or on the wall clock (``clock``).
"""
