"""Sensorless IPMSM hardware-in-the-loop rig: orchestrator, bus tools and commissioning."""

from rig import _defer_mf4

__version__ = "0.1.0"

_defer_mf4.install()  # python-can's MF4 support loads asammdf on first use, not at import
