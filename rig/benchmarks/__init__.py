"""Benchmarks (``rig bench``): each measures one cost and prints one JSON object: the bus
round trip (``bus``), the firmware ISR on the host and on the emulated Cortex-M4F (``isr``,
``isr_m4``), the plant's period (``plant``), the closed loop in process against the bus
(``sil``), a scenario's start (``startup``), the regression gate (``gate``).
"""
