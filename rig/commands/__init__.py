"""Sub-commands of the ``rig`` command line."""
