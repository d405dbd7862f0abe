"""What a run measured, as data: the programs' binary traces (``trace``), the lossless capture
merged from them by PWM period (``capture``), the metrics the criteria read off it
(``metrics``), and the same data as files other tools open (``export``: ASAM MDF4, CAN logs).
"""
