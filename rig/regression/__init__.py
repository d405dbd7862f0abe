"""Catching regressions inside the limits: the baselines of the CI suites (``baseline``:
every criterion's accepted value and its band over the plant's noise seeds), two sets of
results side by side (``compare``), the statistics both use (``stats``), and mutation
testing of the firmware (``mutation``: does the gate catch realistic bugs?).
"""
