"""The scenario run's commands to the emulated bench: the load machine (LOAD_CMD) and the
fault injection (FAULT_CMD), each with its sequence counter. (The drive's own frames are
``rig.link.drive_master``'s; the lockstep grants the clock's.)"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from rig import protocols
from rig.link.bus import BusLink

LOAD_MODES = protocols.choices("bench", "LOAD_CMD", "mode")


@dataclass(frozen=True)
class LoadSetting:
    """What the load machine does (mode by its DBC name, lower case)."""

    mode: str = "torque"
    torque: float = 0.0
    speed: float = 0.0
    k_speed: float = 0.0


class BenchCommands:
    def __init__(self, link: BusLink) -> None:
        self.link = link
        self.load_seq = 0
        self.fault_seq = 0

    def load(self, s: LoadSetting) -> None:
        self.load_seq = (self.load_seq + 1) % 256
        self.link.send("LOAD_CMD", {"mode": LOAD_MODES[s.mode], "seq": self.load_seq,
                                    "torque": s.torque, "speed": s.speed,
                                    "k_speed": s.k_speed})

    def fault(self, values: Mapping[str, float | int]) -> None:
        self.fault_seq = (self.fault_seq + 1) % 256
        self.link.send("FAULT_CMD", {**values, "seq": self.fault_seq})
