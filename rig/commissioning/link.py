"""The commissioning scripts' node on the CAN bus: validated frames in and out, a recording.

Only the frames the scripts use are received (ID filters, so the 10 kHz virtual I/O traffic of
a virtual bench costs nothing here); each is validated by ``rig.frames`` (unknown IDs, bad
lengths, out-of-range signals are counted rejections). Frames are handled only while the
scripts pump the link (``pump``, ``wait_for``, or a bench clock advancing), in order.
Everything sent and received goes into a candump-format log (``bus.log``): the run's
recording, readable with python-can and cantools on both the virtual and the real bench.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import can

from rig import bus as rigbus
from rig import protocols
from rig.frames import FrameDecoder

LISTEN = (
    ("drive", "DRIVE_STATUS"), ("drive", "HEARTBEAT"), ("drive", "PARAM_RESP"),
    ("drive", "TLM_POS"), ("drive", "TLM_CUR"), ("drive", "TLM_REF"), ("drive", "TLM_PARAM"),
    ("drive", "TLM_VOLT"), ("bench", "BENCH_TRUTH"), ("bench", "BENCH_PROGRESS"),
    ("bench", "BENCH_COUNTERS"),
)
# high-rate frames: decoded only while a handler (a telemetry window) wants them
LAZY = frozenset({"TLM_POS", "TLM_CUR", "TLM_REF", "TLM_PARAM", "TLM_VOLT", "BENCH_TRUTH"})
Signals = Mapping[str, Any]
Handler = Callable[[Signals], None]


class LinkError(RuntimeError):
    """The bus cannot be opened or used."""


class CanLink:
    """Send by message name, receive decoded signals, wait for a condition."""

    def __init__(self, transport: str | None, channel: str | None, *,
                 record: Path | None = None) -> None:
        self.transport, self.channel = rigbus.select_transport(transport, channel)
        filters = [{"can_id": int(protocols.database(db).get_message_by_name(n).frame_id),
                    "can_mask": 0x7FF} for db, n in LISTEN]
        try:
            self.bus = rigbus.open_bus(self.transport, self.channel, can_filters=filters)
        except (can.CanError, OSError, ValueError) as exc:
            raise LinkError(f"cannot open the {self.transport} bus {self.channel!r}: "
                            f"{exc}") from exc
        self.decoder = FrameDecoder()
        self._names = {int(protocols.database(db).get_message_by_name(n).frame_id): n
                       for db, n in LISTEN}
        self.latest: dict[str, Signals] = {}
        self.latest_wall: dict[str, float] = {}
        self._handlers: dict[str, list[Handler]] = {}
        self.recording = record
        self._log: Any = can.Logger(str(record)) if record is not None else None
        self.rx = 0
        self.tx = 0
        self.lazy = 0

    @property
    def where(self) -> str:
        return f"{self.transport} {self.channel}"

    # -- sending -----------------------------------------------------------------------
    def send(self, name: str, values: Mapping[str, Any]) -> None:
        msg = self.decoder.encode(name, dict(values))
        msg.timestamp = time.time()
        try:
            self.bus.send(msg)
        except (can.CanError, OSError) as exc:
            raise LinkError(f"{self.where}: cannot send {name}: {exc}") from exc
        self.tx += 1
        if self._log is not None:
            self._log(msg)

    # -- receiving ---------------------------------------------------------------------
    def on(self, name: str, handler: Handler) -> Callable[[], None]:
        """Calls handler(signals) for every valid frame of that name; returns the remover."""
        self._handlers.setdefault(name, []).append(handler)

        def remove() -> None:
            with contextlib.suppress(ValueError):
                self._handlers[name].remove(handler)

        return remove

    @contextlib.contextmanager
    def subscribed(self, name: str, handler: Handler) -> Iterator[None]:
        remove = self.on(name, handler)
        try:
            yield
        finally:
            remove()

    def _handle(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            return
        self.rx += 1
        if self._log is not None:
            self._log(msg)
        name = self._names.get(msg.arbitration_id)
        if name in LAZY and not self._handlers.get(name):
            self.lazy += 1  # nobody listens: validated and decoded only when asked for
            return
        d = self.decoder.decode(msg)
        if d is None:
            return
        self.latest[d.name] = d.signals
        self.latest_wall[d.name] = time.monotonic()
        for h in list(self._handlers.get(d.name, ())):
            h(d.signals)

    def pump(self, timeout_s: float = 0.0) -> int:
        """Handles every frame already received, waiting up to timeout_s for the first one."""
        n = 0
        try:
            msg = self.bus.recv(timeout=max(timeout_s, 0.0))
            while msg is not None:
                self._handle(msg)
                n += 1
                msg = self.bus.recv(timeout=0.0)
        except (can.CanError, OSError) as exc:
            raise LinkError(f"{self.where}: receive failed: {exc}") from exc
        return n

    def wait_for(self, name: str, predicate: Callable[[Signals], bool], timeout_s: float,
                 what: str) -> Signals:
        """The first frame of that name arriving from now on for which predicate holds."""
        found: list[Signals] = []

        def catch(v: Signals) -> None:
            if not found and predicate(v):
                found.append(v)

        deadline = time.monotonic() + timeout_s
        with self.subscribed(name, catch):
            while not found:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"{self.where}: no {what} within {timeout_s:g} s")
                self.pump(min(left, 0.05))
        return found[0]

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.bus.shutdown()
        if self._log is not None:
            with contextlib.suppress(Exception):
                self._log.stop()
            self._log = None
