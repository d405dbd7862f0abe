"""Validating decoder for frames on the rig's bus.

Every frame is checked against the DBC files before anything uses it. A frame with an ID
no DBC defines, a length that does not match its message, or a signal outside its DBC range
is rejected: counted by reason and logged (once per reason and ID, then every 1000th), never
raised and never used.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import can
from cantools.database.can import Message

from rig import protocols

log = logging.getLogger("rig.bus.frames")

REASONS = ("unknown_id", "bad_length", "out_of_range", "malformed", "wrong_frame_type")


@dataclass(frozen=True)
class Decoded:
    name: str
    signals: dict[str, Any]
    timestamp: float


@dataclass
class FrameDecoder:
    databases: Iterable[str] = protocols.DATABASES
    rejected: Counter[str] = field(default_factory=Counter)
    _by_id: dict[int, Message] = field(default_factory=dict, init=False)
    _by_name: dict[str, Message] = field(default_factory=dict, init=False)
    _logged: Counter[tuple[str, int]] = field(default_factory=Counter, init=False)

    def __post_init__(self) -> None:
        for name in self.databases:
            for msg in protocols.database(name).messages:
                if msg.frame_id in self._by_id:
                    raise ValueError(f"frame id 0x{msg.frame_id:X} defined twice ({msg.name})")
                self._by_id[msg.frame_id] = msg
                self._by_name[msg.name] = msg

    def message(self, name: str) -> Message:
        return self._by_name[name]

    def decode(self, frame: can.Message) -> Decoded | None:
        """The decoded frame, or None (counted and logged) when it is not acceptable."""
        msg = self._by_id.get(frame.arbitration_id)
        if msg is None or frame.is_extended_id:
            return self._reject("unknown_id", frame, "no message with this id in the DBC files")
        if bool(msg.is_fd) != bool(frame.is_fd):
            return self._reject("wrong_frame_type", frame,
                                f"{msg.name} is a {'CAN FD' if msg.is_fd else 'classic'} frame")
        if len(frame.data) != msg.length:
            return self._reject("bad_length", frame,
                                f"{msg.name} has {msg.length} bytes, got {len(frame.data)}")
        try:
            values = msg.decode(bytes(frame.data), decode_choices=False, scaling=True)
        except Exception as exc:  # cantools raises several types for undecodable payloads
            return self._reject("malformed", frame, f"{msg.name}: {exc}")
        assert isinstance(values, dict)
        for sig in msg.signals:
            v = values[sig.name]
            lo, hi = sig.minimum, sig.maximum
            if (lo is not None and v < lo) or (hi is not None and v > hi):
                return self._reject("out_of_range", frame,
                                    f"{msg.name}.{sig.name} = {v} outside [{lo}, {hi}]")
        return Decoded(msg.name, dict(values), frame.timestamp)

    def encode(self, name: str, values: dict[str, Any]) -> can.Message:
        """A frame for a message, range-checked by cantools (strict)."""
        msg = self.message(name)
        data = msg.encode(values, scaling=True, strict=True)
        return can.Message(arbitration_id=msg.frame_id, data=data, is_fd=bool(msg.is_fd),
                           is_extended_id=False)

    def _reject(self, reason: str, frame: can.Message, detail: str) -> None:
        self.rejected[reason] += 1
        key = (reason, frame.arbitration_id)
        self._logged[key] += 1
        if self._logged[key] == 1 or self._logged[key] % 1000 == 0:
            log.warning("rejected frame 0x%X (%s, %d so far): %s", frame.arbitration_id,
                        reason, self.rejected[reason], detail)
        return None
