"""The control core on a Cortex-M4F under emulation, against the host build.

``firmware_c2000/target_m4`` builds the core for the Cortex-M4F (``fw_core_m4.elf``); the
in-process bench journals every call into the host's core (``bench/src/core_journal.c``).
Here: ``elf`` reads the image, ``emulator`` runs it (unicorn, instructions counted per basic
block), ``journal`` reads a journal, ``replay`` feeds it to the image and compares every
period's outputs with the host's, ``record`` journals a scenario run, ``budget`` turns the
replay's instruction counts into the per-path figures of ``rig bench isr --target``.
"""
