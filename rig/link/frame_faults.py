"""The rig's own frames under fault injection: a scenario's frame faults on the drive-protocol
frames the rig sends (DRIVE_CMD, DRIVE_LIMITS) and the loss of the command heartbeat.

The rig sends its frames at grant starts (lockstep, also in process) or on the wall clock
(real time), and names the period before it sends (``at``). A frame inside a fault's window
is dropped (``frame_loss``; ``heartbeat_loss`` drops every DRIVE_CMD), XORed
(``frame_corrupt``: the raw bits of one signal, placed by the DBC), or held back and sent at
the first send at or after its due period (``frame_delay``; in lockstep the plan makes every
due period a grant start, so it reaches the firmware before exactly that period). The bus and
the in-process bench get their frames from the same sender, so they see the same frames.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from rig.scenario import faults


@dataclass(frozen=True)
class Window:
    """A fault on one of the rig's messages over periods [start, end)."""

    message: str
    kind: str  # frame_loss | frame_delay | frame_corrupt
    start: int
    end: int
    delay: int = 0
    byte: int = 0
    mask: int = 0

    def covers(self, period: int) -> bool:
        return self.start <= period < self.end


def windows(events: Iterable[faults.Fault], n: int) -> list[Window]:
    """The rig-side faults of a scenario of n periods."""
    out: list[Window] = []
    for f in events:
        if f.on_plant:
            continue
        start, end = f.periods(n)
        if f.kind == faults.HEARTBEAT_LOSS:
            out.append(Window("DRIVE_CMD", "frame_loss", start, end))
        elif f.kind == "frame_corrupt":
            c = faults.corruption(f.message, f.signal, f.xor)
            out.append(Window(f.message, f.kind, start, end, byte=c.byte, mask=c.mask))
        else:
            out.append(Window(f.message, f.kind, start, end, delay=f.delay))
    return out


def due_periods(ws: Sequence[Window], send_points: Iterable[int], n: int) -> set[int]:
    """The periods frames sent at ``send_points`` fall due at (inside the run)."""
    due: set[int] = set()
    for p in send_points:
        for w in ws:
            if w.kind == "frame_delay" and w.covers(p) and p + w.delay < n:
                due.add(p + w.delay)
    return due


def xor_word(data: bytes, byte: int, mask: int) -> bytes:
    """``data`` with the 32-bit little-endian word at ``byte`` XORed with ``mask`` (bytes
    beyond the frame are not there to flip)."""
    out = bytearray(data)
    for k in range(4):
        if byte + k < len(out):
            out[byte + k] ^= (mask >> (8 * k)) & 0xFF
    return bytes(out)


@dataclass
class FrameFaults:
    """What happens to the rig's frames: ``at(period)``, then ``due()`` (held frames now due,
    oldest first) and ``filter(message, data)`` for each fresh frame."""

    windows: list[Window] = field(default_factory=list)
    period: int = 0
    # (due period, order, message, data, corrupted)
    held: list[tuple[int, int, str, bytes, bool]] = field(default_factory=list)
    dropped: int = 0
    delayed: int = 0
    corrupted: int = 0
    _serial: int = 0

    def at(self, period: int) -> None:
        self.period = period

    def due(self) -> list[tuple[str, bytes, bool]]:
        """(message, data, corrupted) of the held frames due now, oldest first."""
        ready = sorted(h for h in self.held if h[0] <= self.period)
        self.held = [h for h in self.held if h[0] > self.period]
        return [(name, data, corrupted) for _, _, name, data, corrupted in ready]

    def filter(self, message: str, data: bytes) -> bytes | None:
        """The frame to send now, or None (dropped, or held back)."""
        delay = 0
        corrupted = False
        for w in self.windows:
            if w.message != message or not w.covers(self.period):
                continue
            if w.kind == "frame_loss":
                self.dropped += 1
                return None
            if w.kind == "frame_corrupt":
                data = xor_word(data, w.byte, w.mask)
                self.corrupted += 1
                corrupted = True
            else:
                delay = w.delay
        if delay:
            self._serial += 1
            self.held.append((self.period + delay, self._serial, message, data, corrupted))
            self.delayed += 1
            return None
        return data

    def counters(self) -> dict[str, float]:
        return {"rig.faults.frames_dropped": float(self.dropped),
                "rig.faults.frames_delayed": float(self.delayed),
                "rig.faults.frames_corrupted": float(self.corrupted)}
