"""Mutation testing of the firmware (``rig mutate``): a catalogue of realistic bugs
(``catalogue``), a copy of the tree each one is built in (``worktree``), and the runs that
decide whether the gate kills it (``campaign``)."""
