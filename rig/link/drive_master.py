"""The rig as the drive's CAN master: the drive command (DRIVE_CMD, with its alive counter)
and the limits (DRIVE_LIMITS), and what the drive says of its state (DRIVE_STATUS).

Modes go on the wire as the DBC's value tables name them (``protocols.choices``); the
references as the DBC scales them (cantools rounds to the signal's step, ``quantize`` says
what a value becomes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rig import protocols
from rig.link.bus import BusLink

CTRL_MODES = protocols.choices("drive", "DRIVE_CMD", "ctrl_mode")
FW_MODES = protocols.choices("drive", "DRIVE_CMD", "fw_mode")
STATES = protocols.names("drive", "DRIVE_STATUS", "state")


@dataclass(frozen=True)
class DriveCommand:
    enable: int = 0
    ctrl_mode: str = "speed"
    fw_mode: str = "conventional"
    speed_ref: float = 0.0
    iq_ref: float = 0.0
    fault_reset: int = 0


@dataclass(frozen=True)
class DriveLimits:
    i_max: float = 3.0
    speed_max: float = 3300.0
    accel: float = 0.0


def quantize(signal: str, value: float) -> float:
    """What a DRIVE_CMD reference becomes on the wire."""
    return protocols.quantize("drive", "DRIVE_CMD", signal, value)


def accel_max() -> float:
    """The largest acceleration DRIVE_LIMITS can carry (a speed 'step'; the DBC maximum)."""
    sig = protocols.database("drive").get_message_by_name("DRIVE_LIMITS").get_signal_by_name(
        "accel_max")
    return float(sig.maximum)


def accel_on_wire(accel: float) -> float:
    """What DRIVE_LIMITS carries for an acceleration limit."""
    return protocols.quantize("drive", "DRIVE_LIMITS", "accel_max", accel)


class DriveMaster:
    """Sends the drive command (``cmd``) and the limits; reads the drive's status."""

    def __init__(self, link: BusLink, cmd: DriveCommand | None = None) -> None:
        self.link = link
        self.cmd = cmd if cmd is not None else DriveCommand()
        self.alive = 0
        self.sent = 0

    def send_command(self) -> None:
        self.alive = (self.alive + 1) % 256
        c = self.cmd
        self.link.send("DRIVE_CMD", {
            "enable": c.enable, "fault_reset": c.fault_reset,
            "ctrl_mode": CTRL_MODES[c.ctrl_mode], "fw_mode": FW_MODES[c.fw_mode],
            "alive": self.alive, "speed_ref": c.speed_ref, "iq_ref": c.iq_ref})
        self.sent += 1

    def send_limits(self, limits: DriveLimits) -> None:
        self.link.send("DRIVE_LIMITS", {"i_max": limits.i_max, "speed_max": limits.speed_max,
                                        "accel_max": limits.accel})

    @property
    def status(self) -> dict[str, Any]:
        """The last DRIVE_STATUS ({} before the first)."""
        return dict(self.link.latest.get("DRIVE_STATUS", {}))

    @property
    def state(self) -> str:
        """The drive's state as the DBC names it (INIT, IDLE, ...; UNKNOWN before the first
        DRIVE_STATUS)."""
        st = self.status
        return STATES.get(int(st["state"]), "?") if st else "UNKNOWN"
