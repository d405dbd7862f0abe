"""The drive under test as the rig knows it: its parameters (``params``: the table of
protocols/parameters.csv and access over CAN), its SCI console (``console``), and what
commissioning left on it on each profile's virtual bench (``commissioned``). The rig's
commands to it on the bus are ``rig.link.drive_master``'s.
"""
