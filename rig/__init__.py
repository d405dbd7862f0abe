"""Sensorless IPMSM hardware-in-the-loop rig: orchestrator, bus tools and commissioning."""

__version__ = "0.1.0"
