"""The rig's node on the bench's CAN bus: validated frames in, DBC-encoded frames out.

In: only the messages of ``LISTEN`` pass the ID filters (the 10 kHz virtual I/O of a virtual
bench costs nothing here); each is validated by ``rig.bus.frames`` (unknown IDs, bad lengths,
out-of-range signals are counted rejections, never raised). The high-rate messages
(``LAZY``) are decoded only while a handler wants them or when somebody asks for the last
one. Frames are handled only while the owner pumps the link (``pump``, ``wait_for``, a clock
advancing), in order.

Out: frames are encoded by message name from the DBC (strict ranges). The drive-protocol
frames of the rig pass the scenario's frame faults on the way (``rig.link.frame_faults``). The
frames sent since the last ``at(period)`` are kept, so a lost lockstep grant goes out again
byte for byte (``resend``).

With ``record``, everything sent and received also goes into a log file (python-can's
``Logger``: candump format for ``.log``), readable with python-can and cantools. With
``trace``, the same frames go into a trace file (``rig.trace``, the format of the programs'
traces: ``rig.data.trace``), except the messages the programs trace themselves; ``note`` puts a
frame there that is not sent (the in-process bench's grants, a call there, are the
BENCH_STEP frames they are on the bus), so ``rig export`` has every frame of a run.

Foreign traffic: the link also receives the messages only the rig sends (their DBC
transmitter is RIG: BENCH_STEP, LOAD_CMD, FAULT_CMD, DRIVE_CMD, DRIVE_LIMITS, PARAM_REQ): one
arriving comes from a node outside the run; it is counted in ``foreign`` and reported to
``on_foreign`` (a run stops on it, ``rig.run.on_bus``). Frames are counted by identifier both
ways by their whole identity (``tx_ids``, ``rx_ids``: ``rig.bus.identity``, so an extended or
a remote frame is never taken for a message of the DBC) for the run's check of what every
node received against what the run's nodes sent (``rig.run.traffic``).
"""

from __future__ import annotations

import collections
import contextlib
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, Protocol

import can
from cantools.database.can import Message

from rig import bus as rigbus
from rig import protocols
from rig.bench import sil
from rig.bus import identity
from rig.bus.frames import FrameDecoder
from rig.data.trace import TraceWriter
from rig.link.frame_faults import FrameFaults
from rig.scenario import faults

LISTEN = (
    ("drive", "DRIVE_STATUS"), ("drive", "HEARTBEAT"), ("drive", "PARAM_RESP"),
    ("drive", "TLM_POS"), ("drive", "TLM_CUR"), ("drive", "TLM_REF"), ("drive", "TLM_PARAM"),
    ("drive", "TLM_VOLT"), ("bench", "BENCH_TRUTH"), ("bench", "BENCH_PROGRESS"),
    ("bench", "BENCH_COUNTERS"), ("bench", "BENCH_REJECTS"),
)
# the frames at the speed-loop rate and the plant's truth: decoded only on demand
LAZY = frozenset({"TLM_POS", "TLM_CUR", "TLM_REF", "TLM_PARAM", "TLM_VOLT", "BENCH_TRUTH"})
FOREIGN_LISTEN_S = 0.25  # how long the rig listens for other traffic before a run starts
RUN_NODES = 3  # the rig, plant_rt and fw_host: the other nodes a unixcan node must reach
# traced by plant_rt and fw_host themselves (plant.trace, fw.trace): not again in rig.trace
PROGRAM_TRACED = frozenset({"BENCH_TRUTH", "BENCH_TRUTH_MAG", "FW_TRACE"})
Signals = Mapping[str, Any]
Handler = Callable[[Signals], None]


class LinkError(RuntimeError):
    """The bus cannot be opened or used."""


class ForeignNodes(RuntimeError):
    """Somebody else sends on the channel (another run, another node), or more nodes listen
    there than a unixcan node reaches."""


class ForeignTraffic(ForeignNodes):
    """Frames arrived from a node outside the run."""


def rig_messages() -> dict[int, str]:
    """The messages only the rig sends (their DBC transmitter is RIG), by frame id."""
    return {int(m.frame_id): m.name
            for db in ("drive", "vio", "bench") for m in protocols.database(db).messages
            if "RIG" in (m.senders or [])}


def rig_message_keys() -> dict[int, str]:
    """The same by their whole identity (``rig.bus.identity``)."""
    names = set(rig_messages().values())
    return {k: n for k, n in identity.dbc_keys().items() if n in names}


class FrameSink(Protocol):
    """Where frames go: a python-can bus, or the in-process bench's port (``rig.bench.sil``)."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None: ...

    def recv(self, timeout: float | None = None) -> can.Message | None: ...

    def shutdown(self) -> None: ...


class BusLink:
    """Send by message name, receive decoded signals, wait for a condition."""

    def __init__(self, bus: FrameSink, *, transport: str = "", channel: str = "",
                 record: Path | None = None,
                 frame_faults: FrameFaults | None = None,
                 trace: Path | None = None) -> None:
        self.bus = bus
        self.transport, self.channel = transport, channel
        self.decoder = FrameDecoder()
        self.faults = frame_faults if frame_faults is not None else FrameFaults()
        by_name = {n: k for k, n in identity.dbc_keys().items()}
        self._names = {by_name[n]: n for _, n in LISTEN}
        self._rig_only = rig_message_keys()
        # frames by their whole identity (rig.bus.identity)
        self.tx_ids: collections.Counter[int] = collections.Counter()
        self.rx_ids: collections.Counter[int] = collections.Counter()
        self.foreign: list[str] = []  # what arrived that only the rig sends
        self.on_foreign: Callable[[str], None] | None = None
        self.listeners_at_start: int | None = None  # other nodes on a unixcan channel
        self.others_at_start: dict[str, str] = {}  # their socket names, in words
        self.latest: dict[str, Signals] = {}
        self.latest_wall: dict[str, float] = {}
        self._undecoded: dict[str, can.Message] = {}
        self._handlers: dict[str, list[Handler]] = {}
        # the frames sent since the last at() (none kept before the first), and whether a
        # fault corrupted each
        self.batch: list[tuple[can.Message, bool]] | None = None
        self.recording = record
        self._log: Any = can.Logger(str(record)) if record is not None else None
        self._trace: TraceWriter | None = TraceWriter(trace) if trace is not None else None
        self._untraced = {int(self.decoder.message(n).frame_id) for n in PROGRAM_TRACED}
        self.rx = 0
        self.tx = 0
        self.lazy = 0

    @classmethod
    def open(cls, transport: str | None, channel: str | None, *, record: Path | None = None,
             frame_faults: FrameFaults | None = None,
             trace: Path | None = None, lossless: bool = False) -> BusLink:
        """A link on a bus channel (``rig.bus.select_transport`` resolves ``auto``);
        ``lossless`` in lockstep: on unixcan the rig's node loses no frame (its senders wait
        for it, as it waits for the programs)."""
        transport, channel = rigbus.select_transport(transport, channel)
        try:
            bus = rigbus.open_bus(transport, channel, can_filters=listen_filters(),
                                  lossless=lossless)
        except (can.CanError, OSError, ValueError) as exc:
            raise LinkError(f"cannot open {transport} bus {channel!r}: {exc}") from exc
        return cls(bus, transport=transport, channel=channel, record=record,
                   frame_faults=frame_faults, trace=trace)

    @property
    def where(self) -> str:
        return f"{self.transport} {self.channel}"

    # -- sending -----------------------------------------------------------------------
    def send(self, name: str, values: Mapping[str, Any]) -> None:
        m = self.decoder.message(name)
        data = bytes(m.encode(dict(values), scaling=True, strict=True))
        if name not in faults.RIG_MESSAGES:
            self._send_frame(m, data)
            return
        sent = self.faults.filter(name, data)
        if sent is not None:  # else dropped or held back by a fault (rig.link.frame_faults)
            self._send_frame(m, sent, faulted=sent != data)

    def _send_frame(self, m: Message, data: bytes, faulted: bool = False) -> None:
        msg = can.Message(arbitration_id=m.frame_id, is_extended_id=m.is_extended_frame,
                          data=data, is_fd=bool(m.is_fd), bitrate_switch=False)
        self._put(msg, faulted)
        if self.batch is not None:
            self.batch.append((msg, faulted))

    def _put(self, msg: can.Message, faulted: bool) -> None:
        msg.timestamp = time.time()
        try:
            if faulted and isinstance(self.bus, sil.BenchPort):
                self.bus.send_faulted(msg)
            else:
                self.bus.send(msg)
        except (can.CanError, OSError) as exc:
            name = identity.describe(identity.of_message(msg))
            raise LinkError(f"{self.where}: cannot send {name}: {exc}") from exc
        self.tx += 1
        self.tx_ids[identity.of_message(msg)] += 1
        if self._log is not None:
            self._log(msg)
        self._traced(msg)

    def _traced(self, msg: can.Message) -> None:
        if self._trace is not None and msg.arbitration_id not in self._untraced:
            self._trace.write(msg.arbitration_id, bytes(msg.data), fd=bool(msg.is_fd))

    def note(self, name: str, values: Mapping[str, Any]) -> None:
        """A frame into the trace only, not sent (a grant in process: BENCH_STEP)."""
        if self._trace is not None:
            m = self.decoder.message(name)
            self._trace.write(int(m.frame_id),
                              bytes(m.encode(dict(values), scaling=True, strict=True)),
                              fd=bool(m.is_fd))

    def at(self, period: int) -> None:
        """The sends that follow are before ``period``: frames a fault held back until then
        go first."""
        self.batch = []
        self.faults.at(period)
        for name, data, corrupted in self.faults.due():
            self._send_frame(self.decoder.message(name), data, faulted=corrupted)

    def resend(self) -> None:
        """The frames sent since the last ``at()`` again, byte for byte (a lost grant)."""
        for msg, faulted in list(self.batch or ()):
            self._put(msg, faulted)

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

    def last(self, name: str) -> Signals | None:
        """The last valid frame of a message (a lazy one decoded now)."""
        raw = self._undecoded.pop(name, None)
        if raw is not None:
            self._decode(raw)
        return self.latest.get(name)

    def handle(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            return
        self.rx += 1
        k = identity.of_message(msg)
        self.rx_ids[k] += 1
        if self._log is not None:
            self._log(msg)
        self._traced(msg)
        own = self._rig_only.get(k)
        if own is not None:
            self.note_foreign(f"a {own} frame (id 0x{msg.arbitration_id:03X}), which only the "
                              "rig sends, from a node outside the run")
            return
        name = self._names.get(k)
        if name is None:
            return  # not a message the rig listens to (the filters let it through), or a
            # frame with its identifier but another identity (extended, remote, format)
        if name in LAZY and not self._handlers.get(name):
            self._undecoded[name] = msg  # validated and decoded only when asked for
            self.lazy += 1
            return
        self._decode(msg)

    def _decode(self, msg: can.Message) -> None:
        d = self.decoder.decode(msg)
        if d is None:
            return
        self._undecoded.pop(d.name, None)
        self.latest[d.name] = d.signals
        self.latest_wall[d.name] = time.monotonic()
        for h in list(self._handlers.get(d.name, ())):
            h(d.signals)

    def pump(self, timeout_s: float = 0.0, until: Callable[[], bool] | None = None) -> int:
        """Handles the frames already received, waiting up to timeout_s for the first one;
        stops early once ``until()`` holds (what follows stays queued)."""
        n = 0
        try:
            msg = self.bus.recv(timeout=max(timeout_s, 0.0))
            while msg is not None:
                self.handle(msg)
                n += 1
                if until is not None and until():
                    break
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

    def note_foreign(self, what: str) -> None:
        """A frame no node of the run sent: counted, and reported to ``on_foreign``."""
        self.foreign.append(what)
        if self.on_foreign is not None:
            self.on_foreign(what)

    def check_channel(self) -> None:
        """Before a run: nobody may send on the channel (a second run there paces or answers
        ours: a 180° error, 300 000 periods of capture loss), so no frame may arrive within
        FOREIGN_LISTEN_S (ForeignNodes, the frames named). Nodes that only listen (a
        candump-like ``can.logger``, ``cantools monitor``) are welcome: unixcan counts them
        (``listeners_at_start``), unless there are more than a unixcan node reaches
        (HILBUS_MAX_PEERS, hilbus.h: the run's own nodes must reach each other)."""
        transport, channel = self.transport, self.channel
        if transport == "unixcan":
            from rig.bus import unixcan

            max_peers = rigbus.unixcan_max_peers(channel)  # (before counting: its node leaves)
            own = {str(getattr(self.bus, "socket_path", ""))}
            others = unixcan.live_nodes(channel, own)
            if len(others) > max_peers - (RUN_NODES - 1):
                pids = sorted({Path(p).name.split("-", 1)[0] for p in others})
                raise ForeignNodes(
                    f"unixcan channel {channel!r} holds {len(others)} other node(s) in "
                    f"{unixcan.base_dir() / channel} (pids {', '.join(pids[:8])}"
                    f"{', ...' if len(pids) > 8 else ''}): with the run's own, more than a "
                    f"unixcan node reaches (HILBUS_MAX_PEERS = {max_peers}, hilbus.h); "
                    "use --channel NAME")
            self.listeners_at_start = len(others)
            self.others_at_start = {Path(p).name: unixcan.node_label(p) for p in others}
        seen: collections.Counter[int] = collections.Counter()
        before = collections.Counter(getattr(self.bus, "rx_ids", {}))
        # SocketCAN filters in the kernel: for the check the link takes every frame (a node
        # sending only ids the rig does not listen to would pass unseen otherwise)
        widen = transport != "unixcan"
        if widen:
            self.bus.set_filters(None)  # type: ignore[attr-defined]
        try:
            deadline = time.monotonic() + FOREIGN_LISTEN_S
            while (left := deadline - time.monotonic()) > 0:
                msg = self.bus.recv(timeout=left)
                if msg is not None and not msg.is_error_frame:
                    seen[identity.of_message(msg)] += 1
        finally:
            if widen:
                self.bus.set_filters(listen_filters())  # type: ignore[attr-defined]
        # unixcan counts what its filters let through too (a node sending only the 10 kHz
        # virtual I/O would pass unseen otherwise), by the same identity
        seen |= collections.Counter(getattr(self.bus, "rx_ids", {})) - before
        if seen:
            raise ForeignTraffic(
                f"{transport} channel {channel!r} is in use: {describe_ids(seen)} arrived "
                f"within {FOREIGN_LISTEN_S:g} s before the run started, from a node that "
                "sends there (another run?); nodes that only listen are welcome. Use "
                "--channel NAME")

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.bus.shutdown()
        if self._log is not None:
            with contextlib.suppress(Exception):
                self._log.stop()
            self._log = None
        if self._trace is not None:
            with contextlib.suppress(OSError):
                self._trace.close()
            self._trace = None


def listen_filters() -> list[dict[str, int]]:
    """The ID filters of the messages the rig listens to, and of those only it sends (one
    arriving is foreign traffic)."""
    ids = {int(FrameDecoder().message(n).frame_id) for _, n in LISTEN} | set(rig_messages())
    return [{"can_id": i, "can_mask": 0x7FF} for i in sorted(ids)]


def describe_ids(counts: Mapping[int, int], limit: int = 6) -> str:
    """``3 VIO_ADC_0 (0x011), 2 of extended frame 0x00000011`` for frame counts by their whole
    identity (``rig.bus.identity``)."""
    parts = []
    for k, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))[:limit]:
        known = identity.name(k)
        parts.append(f"{n} {identity.describe(k)}" if known else
                     f"{n} of {identity.describe(k)}")
    more = len(counts) - limit
    return ", ".join(parts) + (f" and frames of {more} more kind(s)" if more > 0 else "")
