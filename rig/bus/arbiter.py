"""A bit clock for a fallback-bus channel (``rig bus arbiter``, ``rig up --bitrate``): the
channel's classic CAN frames take the wire one at a time, each for its bit time, the lowest
identifier first, as on the lab's classic-CAN bus.

The fallback bus delivers a frame as soon as it is sent, whatever the load. With the arbiter
bound in the channel folder (protocols/unixcan.toml [socket] arbiter) every node, C or
Python, sends its classic frames to it alone (``rig.bus.unixcan``, ``hilbus/src/unixcan.c``)
and its CAN FD frames (the virtual wires, the bench's frames: not on the lab's bus) to the
other nodes as before. The arbiter queues what it is given; whenever the emulated bus falls
free it takes the frame that wins arbitration among those queued (the lower identifier; a
base frame before an extended one of the same base; a data frame before a remote one), holds
the bus for the frame's bits (``rig.bus.bittime``, stuffing counted exactly) and then delivers
it to every node but its sender. The emulated bus runs on its own time line: a frame queued
while the bus was busy starts when the previous one ended, however late the process woke up,
so deliveries may come late by the machine's scheduling but the bus's timing does not drift.

Like a CAN controller's transmit mailbox, a node holds one frame per identifier: a newer frame
of an identifier it still has queued is refused and counted (``overruns``, by sender and
identifier): on an overloaded bus the lowest priorities starve and lose frames, the highest
still go through. Only for a free-running bench: in lockstep a classic frame would arrive
after the CAN FD grant it was sent before.
"""

from __future__ import annotations

import collections
import heapq
import os
import select
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from rig.bus import bittime, unixcan
from rig.bus.unixcan_wire import WIRE

POLL_S = 0.1  # idle: how often the stop flag is looked at


class ArbiterError(RuntimeError):
    """The channel has a bit clock already, or its folder cannot be used."""


def arbitration_key(id_word: int) -> tuple[int, int, int, int]:
    """What decides arbitration, smaller first: the base identifier, then a base frame before
    an extended one, the extension, a data frame before a remote one."""
    remote = int(bool(id_word & WIRE.rtr_flag))
    if id_word & WIRE.eff_flag:
        ident = id_word & WIRE.eff_mask
        return ident >> 18, 1, ident & 0x3FFFF, remote
    return id_word & WIRE.sff_mask, 0, 0, remote


def datagram_bits(datagram: bytes) -> int:
    """The wire length of a classic frame's datagram."""
    id_word = int.from_bytes(datagram[0:4], "little")
    length = datagram[WIRE.len_offset]
    data = datagram[WIRE.data_offset:WIRE.data_offset + length]
    remote = bool(id_word & WIRE.rtr_flag)
    extended = bool(id_word & WIRE.eff_flag)
    ident = id_word & (WIRE.eff_mask if extended else WIRE.sff_mask)
    return bittime.frame_bits(ident, b"" if remote else data, extended=extended, remote=remote)


@dataclass
class ArbiterStats:
    frames: int = 0  # delivered
    started: int = 0  # taken onto the wire
    busy_s: float = 0.0  # emulated time the bus was busy
    max_wait_s: float = 0.0  # the longest a frame was queued before it took the bus
    max_queue: int = 0
    overruns: collections.Counter[str] = field(default_factory=collections.Counter)
    listener_drops: collections.Counter[str] = field(default_factory=collections.Counter)
    malformed: int = 0

    def line(self, elapsed_s: float) -> str:
        load = 100.0 * self.busy_s / elapsed_s if elapsed_s > 0 else 0.0
        over = sum(self.overruns.values())
        text = (f"{self.frames} classic frames, bus busy {load:.1f} %, longest wait "
                f"{self.max_wait_s * 1e6:.0f} µs, queue at most {self.max_queue}, "
                f"overruns {over}")
        if over:
            text += " (" + ", ".join(f"{k} {n}" for k, n in self.overruns.most_common(4)) + ")"
        drops = sum(self.listener_drops.values())
        if drops:
            text += f", dropped for slow listeners {drops}"
        return text


@dataclass(order=True)
class _Queued:
    key: tuple[int, int, int, int]
    seq: int
    id_word: int = field(compare=False)
    datagram: bytes = field(compare=False)
    sender: str = field(compare=False)
    queued_at: float = field(compare=False)


class Arbiter:
    """The bit clock of one channel: ``run(stop)`` until ``stop`` is set; ``close()``."""

    def __init__(self, channel: str, bitrate: int) -> None:
        if bitrate <= 0:
            raise ArbiterError(f"bit rate {bitrate}: a positive number of bits per second")
        self.channel, self.bitrate = channel, bitrate
        try:
            self._group = unixcan.bus_group()
            self._dir = unixcan.channel_dir(channel)
        except OSError as exc:
            raise ArbiterError(str(exc)) from exc
        self.path = self._dir / WIRE.arbiter_socket
        if self.path.exists() or self.path.is_symlink():
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as probe:
                try:
                    probe.connect(str(self.path))
                except OSError:
                    self.path.unlink(missing_ok=True)  # a dead one's socket
                else:
                    raise ArbiterError(f"unixcan channel {channel} has a bit clock already "
                                       f"({self.path})")
        self._sock = unixcan.bind_node_socket(self.path, self._group)
        self.stats = ArbiterStats()
        self._queue: list[_Queued] = []
        self._pending: set[tuple[str, int]] = set()  # (sender, id word) queued: its mailbox
        self._seq = 0
        self._peers: list[str] = []
        self._last_scan = 0.0
        self._dir_mtime = 0.0
        self.t0 = time.monotonic()

    def _scan(self) -> None:
        view = unixcan.scan_folder(self._dir, WIRE.arbiter_socket, self._group)
        self._last_scan, self._dir_mtime, self._peers = view.scanned, view.mtime, view.peers

    def _take(self, now: float) -> None:
        """Every datagram waiting, into the queue (a node's second frame of an identifier
        it has queued is an overrun)."""
        while True:
            try:
                datagram, sender = self._sock.recvfrom(WIRE.fd_size)
            except (BlockingIOError, InterruptedError):
                return
            if len(datagram) != WIRE.classic_size or datagram[WIRE.len_offset] > 8:
                self.stats.malformed += 1  # a CAN FD frame is not the bit clock's
                continue
            id_word = int.from_bytes(datagram[0:4], "little")
            # a bound node's socket path (every node sends to the clock from its own)
            sender = os.fsdecode(sender) if sender else ""
            if (sender, id_word) in self._pending:
                self.stats.overruns[f"{os.path.basename(sender)}:0x{id_word:X}"] += 1
                continue
            self._pending.add((sender, id_word))
            self._seq += 1
            heapq.heappush(self._queue, _Queued(arbitration_key(id_word), self._seq, id_word,
                                                datagram, sender, now))
            self.stats.max_queue = max(self.stats.max_queue, len(self._queue))

    def _deliver(self, item: _Queued) -> None:
        if unixcan.folder_stale(self._dir, self._last_scan, self._dir_mtime):
            self._scan()  # the nodes as a sender sees them
        for peer in self._peers:
            if peer == item.sender:
                continue
            try:
                self._sock.sendto(item.datagram, peer)
            except BlockingIOError:
                # as every sender: a lossless node is waited for, a listener for the grace
                lossless = WIRE.is_lossless(os.path.basename(peer))
                if not self._wait_for(item.datagram, peer, WIRE.lossless_stall_s if lossless
                                      else WIRE.full_peer_grace_s):
                    self.stats.listener_drops[os.path.basename(peer)] += 1
            except (ConnectionRefusedError, FileNotFoundError):
                self._scan()  # gone
            except OSError:
                self.stats.listener_drops[os.path.basename(peer)] += 1
        self.stats.frames += 1

    def _wait_for(self, datagram: bytes, peer: str, patience_s: float) -> bool:
        """A node's queue is full: try again for ``patience_s``; whether it took the frame."""
        give_up = time.monotonic() + patience_s
        while time.monotonic() < give_up:
            time.sleep(0)
            try:
                self._sock.sendto(datagram, peer)
                return True
            except BlockingIOError:
                continue
            except OSError:
                return False
        return False

    def run(self, stop: threading.Event) -> None:
        """The bus until ``stop``: the frame on the wire ends at ``ends``; then the next."""
        self._scan()
        on_wire: _Queued | None = None
        ends = 0.0
        while not stop.is_set():
            now = time.monotonic()
            timeout = POLL_S if on_wire is None else max(0.0, ends - now)
            if timeout > 0.0:
                select.select([self._sock], [], [], timeout)
            now = time.monotonic()
            self._take(now)
            if on_wire is not None and now >= ends:
                self._deliver(on_wire)
                self._pending.discard((on_wire.sender, on_wire.id_word))
                on_wire = None
            if on_wire is None and self._queue:
                on_wire = heapq.heappop(self._queue)
                self.stats.started += 1
                # back to back on the emulated time line: a frame queued while the bus was
                # busy starts when the last one ended, not when this process woke up
                start = max(on_wire.queued_at, ends)
                self.stats.max_wait_s = max(self.stats.max_wait_s, start - on_wire.queued_at)
                bits = datagram_bits(on_wire.datagram)
                ends = start + bits / self.bitrate
                self.stats.busy_s += bits / self.bitrate

    def close(self) -> None:
        self._sock.close()
        self.path.unlink(missing_ok=True)

    def __enter__(self) -> Arbiter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def socket_path(channel: str) -> Path:
    """Where a channel's bit clock binds."""
    return unixcan.channel_dir(channel) / WIRE.arbiter_socket
