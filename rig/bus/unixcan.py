"""python-can interface for the userspace fallback bus ``unixcan`` (docs/interfaces.md).

The same ``struct canfd_frame`` as SocketCAN, carried over Unix datagram sockets: every node
of a channel binds ``$UNIXCAN_DIR/<channel>/<pid>-<serial>.sock`` and sends each frame to all
other sockets of the channel. Registered as the python-can interface ``unixcan``, so
``can.Bus(interface="unixcan", channel="vcan0")``, ``can.Logger`` and ``cantools monitor``
work on it.

The kernel queues only a few datagrams per receiving socket (``net.unix.max_dgram_qlen``), so
a reader thread drains the socket into a bounded buffer at once. A node opened with
``lossless=True`` (the nodes of a lockstep run; the rig's own ``--can-log`` listener) loses no
frame: its name says so (protocols/unixcan.toml [socket] lossless_mark), every sender waits
for it while its queue is full (``stats["tx_stalls"]``, a bounded stall that ends in a
``CanOperationError`` naming it), and its reader waits for room in its buffer rather than
drop. Any other node is a listener: a frame that finds its buffer full is counted in
``stats["rx_overflows"]``, and a frame a sender could not deliver to it is counted by that
sender as a transmit drop, per listener (``listener_drops``, by socket name). Nothing is lost
silently: ``shutdown`` logs a warning (logger ``can.unixcan``, on stderr by default, also
under ``can.player`` and ``can.logger``) with the drops and overflows of the node's life.

``rx_ids`` counts every frame that reached the node by its whole identity (the id word with
its flags, and ``FD_KEY`` for a CAN FD frame: ``rig.bus.identity``), the filtered ones too
(the rig compares what nodes received with what the run's nodes sent: ``rig.run.traffic``).
"""

from __future__ import annotations

import collections
import errno
import grp
import itertools
import logging
import os
import select
import socket
import stat
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
from can.bus import CanProtocol
from can.typechecking import AutoDetectedConfig, CanFilters

from rig.bus.unixcan_wire import FD_KEY, WIRE

# The wire (datagram layout, flag bits, FD lengths, channel names, folder and socket naming
# and modes, the timing nodes promise each other) is protocols/unixcan.toml: WIRE.
_FRAME = WIRE.frame_struct()
_ID = struct.Struct("<I")  # the id word alone: the filter looks at nothing else
# This node's own: folder timestamps are coarse, so while the folder changed less than this
# long ago it is re-read on every send (a node that joined within the timestamp tick of the
# last read is not missed); otherwise its timestamp is looked at on every send.
_RECENT_CHANGE_S = 0.1
_serial = itertools.count()
log = logging.getLogger("can.unixcan")


class UnixCanDirError(OSError):
    """The bus folder breaks the directory rule (not ours, a symlink, writable by others)."""


def base_dir() -> Path:
    """Folder holding one sub-folder per channel: ``$UNIXCAN_DIR``, else
    ``$XDG_RUNTIME_DIR/unixcan`` (an absolute, existing XDG_RUNTIME_DIR), else
    ``/tmp/unixcan-<uid>`` (protocols/unixcan.toml [directory])."""
    explicit = os.environ.get(WIRE.base_env)
    if explicit:
        path = explicit
    else:
        xdg = os.environ.get(WIRE.runtime_env, "")
        if xdg.startswith("/") and os.path.isdir(xdg):
            path = os.path.join(xdg, WIRE.runtime_subdir)
        else:
            path = WIRE.fallback_base_path()
    return Path(path.rstrip("/") or "/")


def channel_name_ok(channel: str) -> bool:
    """A plain name (protocols/unixcan.toml [channel]): no path, no "..", no option."""
    return WIRE.channel_name_ok(channel)


def bus_group() -> int | None:
    """The group of ``UNIXCAN_GROUP`` (a name or a number), or None."""
    name = os.environ.get(WIRE.group_env)
    if not name:
        return None
    try:
        return grp.getgrnam(name).gr_gid
    except KeyError:
        if name.isdigit():
            return int(name)
        raise UnixCanDirError(f"unixcan: {WIRE.group_env}={name}: no such group") from None


def _own_directory(path: Path, mode: int, group: int | None, tighten: bool) -> None:
    try:
        path.mkdir(mode=mode)
        if group is not None:
            os.chown(path, -1, group)
        os.chmod(path, mode)  # mkdir applies the umask
    except FileExistsError:
        pass
    except OSError as exc:
        raise UnixCanDirError(f"unixcan: cannot create {path}: {exc.strerror}") from exc
    st = os.lstat(path)
    if stat.S_ISLNK(st.st_mode):
        raise UnixCanDirError(f"unixcan: {path} is a symbolic link; refused (the bus folder "
                              "must be a real directory)")
    if not stat.S_ISDIR(st.st_mode):
        raise UnixCanDirError(f"unixcan: {path} is not a directory")
    if st.st_uid != os.geteuid():
        raise UnixCanDirError(
            f"unixcan: {path} belongs to uid {st.st_uid}, not to this user (uid "
            f"{os.geteuid()}); refused (set UNIXCAN_DIR to a folder of your own)")
    foreign_write = stat.S_IWOTH if group is not None and st.st_gid == group else (
        stat.S_IWGRP | stat.S_IWOTH)
    if tighten:
        if stat.S_IMODE(st.st_mode) != mode:
            os.chmod(path, mode)
        if group is not None and st.st_gid != group:
            os.chown(path, -1, group)
    elif st.st_mode & foreign_write:
        raise UnixCanDirError(
            f"unixcan: {path} is writable by other users (mode {stat.S_IMODE(st.st_mode):03o}); "
            "refused (chmod go-w it, or set UNIXCAN_DIR to a folder of your own)")


def _trusted_parent(path: Path, group: int | None) -> bool:
    """One existing folder above the base (the rule of docs/interfaces.md): a directory of
    root or of this user that nobody else can write (a sticky one such as /tmp excepted, the
    bus's group with UNIXCAN_GROUP); a symbolic link among them must be root's or this
    user's. True when it exists and is trusted, False when it does not exist; refused with
    UnixCanDirError."""
    me = os.geteuid()
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    except OSError as exc:
        raise UnixCanDirError(f"unixcan: {path}: {exc.strerror}") from exc
    if stat.S_ISLNK(st.st_mode):
        if st.st_uid not in (0, me):
            raise UnixCanDirError(
                f"unixcan: {path} (above the bus folder) is a symbolic link of uid {st.st_uid}, "
                "neither root nor this user; refused (set UNIXCAN_DIR to a folder of your own)")
        try:
            st = os.stat(path)
        except FileNotFoundError:
            return False  # a dangling link: making the folder fails and says so
        except OSError as exc:
            raise UnixCanDirError(f"unixcan: {path}: {exc.strerror}") from exc
    if not stat.S_ISDIR(st.st_mode):
        raise UnixCanDirError(f"unixcan: {path} (above the bus folder) is not a directory")
    if st.st_uid not in (0, me):
        raise UnixCanDirError(
            f"unixcan: {path} (above the bus folder) belongs to uid {st.st_uid}, neither root "
            "nor this user; refused (set UNIXCAN_DIR to a folder of your own)")
    group_ok = group is not None and st.st_gid == group
    if not st.st_mode & stat.S_ISVTX and (
            st.st_mode & stat.S_IWOTH or (st.st_mode & stat.S_IWGRP and not group_ok)):
        raise UnixCanDirError(
            f"unixcan: {path} (above the bus folder) is writable by other users (mode "
            f"{stat.S_IMODE(st.st_mode):03o}); refused (set UNIXCAN_DIR to a folder of your own)")
    return True


def channel_dir(channel: str) -> Path:
    """The channel's folder, created and checked by the directory rule (docs/interfaces.md):
    the folders above the base that exist must be trusted (``_trusted_parent``); missing
    folders are made 0700 (0770 of ``UNIXCAN_GROUP``); the base and the channel
    folder must be real directories of this user that nobody else can write; the channel
    folder's mode is set to 0700 (0770): the modes of protocols/unixcan.toml."""
    if not channel_name_ok(channel):
        raise UnixCanDirError(f"invalid channel name {channel!r}: {WIRE.channel_rule()}")
    group = bus_group()
    mode = WIRE.group_folder_mode if group is not None else WIRE.folder_mode
    base = base_dir()
    missing = False  # a folder above is missing: what is below it is made here, 0700
    for parent in reversed(base.parents):
        if parent == parent.parent:
            continue  # the root, or the start of a relative path
        if not missing:
            missing = not _trusted_parent(parent, group)
        if missing:
            try:
                parent.mkdir(mode=WIRE.folder_mode)
            except FileExistsError:
                pass
            except OSError as exc:
                raise UnixCanDirError(f"unixcan: cannot create {parent}: {exc.strerror}") from exc
    _own_directory(base, mode, group, tighten=False)
    folder = base / channel
    _own_directory(folder, mode, group, tighten=True)
    return folder


def bind_node_socket(path: Path, group: int | None) -> socket.socket:
    """A node's datagram socket bound at ``path`` (which must not exist), non-blocking, with
    the wire's mode and group."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    for opt in (socket.SO_SNDBUF, socket.SO_RCVBUF):
        sock.setsockopt(socket.SOL_SOCKET, opt, 4 << 20)
    sock.bind(str(path))
    # The folder is closed already; the socket's own mode says the same to whoever looks.
    os.chmod(path, WIRE.group_socket_mode if group is not None else WIRE.socket_mode)
    if group is not None:
        os.chown(path, -1, group)
    sock.setblocking(False)
    return sock


@dataclass(frozen=True)
class FolderView:
    scanned: float  # when (time.time)
    mtime: float  # the folder's timestamp then (0: unreadable)
    peers: list[str]  # every node's socket but one's own
    foreign: int  # entries that are not the user's (or the group's) sockets


def scan_folder(folder: Path, own: str, group: int | None) -> FolderView:
    """The channel's sockets as a node sees them: every ``*<suffix>`` of the user (or the
    bus's group) but its own."""
    scanned = time.time()
    try:
        mtime = folder.stat().st_mtime
        names = os.listdir(folder)
    except OSError:
        return FolderView(scanned, 0.0, [], 0)
    peers, foreign = [], 0
    for n in names:
        if not n.endswith(WIRE.socket_suffix) or n == own:
            continue
        path = str(folder / n)
        if peer_socket_ok(path, group):
            peers.append(path)
        else:
            foreign += 1
    return FolderView(scanned, mtime, peers, foreign)


def folder_stale(folder: Path, last_scan: float, folder_mtime: float) -> bool:
    """Whether a node's list of the channel's sockets, read at ``last_scan`` (``time.time``)
    when the folder's timestamp was ``folder_mtime``, must be read again: the timestamp moved,
    or the rescan interval passed, or the last change is recent (timestamps are coarse: a node
    that joined within the tick of the last read would be missed)."""
    now = time.time()
    if now - last_scan > WIRE.rescan_interval_s or now - folder_mtime < _RECENT_CHANGE_S:
        return True
    try:
        return folder.stat().st_mtime != folder_mtime
    except OSError:
        return False


def peer_socket_ok(path: str, group: int | None) -> bool:
    """A folder entry that may be a peer: a socket of this user (or of the bus's group)."""
    try:
        st = os.lstat(path)
    except OSError:
        return False
    if not stat.S_ISSOCK(st.st_mode):
        return False
    return st.st_uid == os.geteuid() or (group is not None and st.st_gid == group)


def fd_length(n: int) -> int:
    """The smallest valid CAN FD payload length that holds n bytes."""
    for length in WIRE.fd_lengths:
        if n <= length:
            return length
    raise ValueError(f"CAN FD payload of {n} bytes exceeds {WIRE.fd_max_len}")


def pack_frame(msg: can.Message) -> bytes:
    """The datagram for a message: 16 bytes (classic) or 72 bytes (CAN FD)."""
    can_id = msg.arbitration_id & WIRE.eff_mask
    if msg.is_extended_id:
        can_id |= WIRE.eff_flag
    if msg.is_remote_frame:
        can_id |= WIRE.rtr_flag
    if msg.is_error_frame:
        can_id |= WIRE.err_flag
    data = bytes(msg.data)
    if msg.is_fd:
        length = fd_length(len(data))
        flags = WIRE.fdf | (WIRE.brs if msg.bitrate_switch else 0) | (
            WIRE.esi if msg.error_state_indicator else 0
        )
        return _FRAME.pack(can_id, length, flags, 0, 0, data.ljust(WIRE.fd_max_len, b"\0"))
    if len(data) > WIRE.classic_max_len:
        raise ValueError(f"classic CAN frame with {len(data)} data bytes; set is_fd=True")
    length = msg.dlc if msg.is_remote_frame else len(data)
    datagram = _FRAME.pack(can_id, length, 0, 0, 0, data.ljust(WIRE.fd_max_len, b"\0"))
    return datagram[:WIRE.classic_size]


def unpack_frame(datagram: bytes, timestamp: float, channel: str) -> can.Message | None:
    """The message in a datagram, or None for a datagram that is not a frame: a size other
    than 16 or 72 bytes, or a length no controller sends (> 8 classic, not an FD length)."""
    if len(datagram) == WIRE.fd_size:
        is_fd = True
    elif len(datagram) == WIRE.classic_size:
        is_fd = False
        datagram = datagram.ljust(WIRE.fd_size, b"\0")
    else:
        return None
    can_id, length, flags, _, _, data = _FRAME.unpack(datagram)
    if length > (WIRE.fd_max_len if is_fd else WIRE.classic_max_len) or (
            is_fd and length not in WIRE.fd_lengths):
        return None
    is_remote = bool(can_id & WIRE.rtr_flag)
    return can.Message(
        timestamp=timestamp,
        arbitration_id=can_id & WIRE.eff_mask,
        is_extended_id=bool(can_id & WIRE.eff_flag),
        is_remote_frame=is_remote,
        is_error_frame=bool(can_id & WIRE.err_flag),
        is_fd=is_fd,
        bitrate_switch=bool(flags & WIRE.brs),
        error_state_indicator=bool(flags & WIRE.esi),
        dlc=length,
        data=b"" if is_remote else data[:length],
        channel=channel,
        is_rx=True,
    )


def live_nodes(channel: str, exclude: set[str] | frozenset[str] = frozenset()) -> list[str]:
    """Socket paths of the nodes on a channel that are alive (a socket a connection reaches;
    a dead node's file refuses it), besides ``exclude``."""
    folder = base_dir() / channel
    try:
        names = sorted(os.listdir(folder))
    except OSError:
        return []
    alive = []
    for n in names:
        path = str(folder / n)
        if not n.endswith(WIRE.socket_suffix) or path in exclude:
            continue
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            probe.connect(path)
            alive.append(path)
        except OSError:
            pass
        finally:
            probe.close()
    return alive


def node_pid(socket_name: str) -> int | None:
    """The pid a node's socket name starts with (protocols/unixcan.toml [socket])."""
    head = os.path.basename(socket_name).split("-", 1)[0]
    return int(head) if head.isdigit() else None


def node_label(socket_name: str) -> str:
    """A node in words: its pid and the command line of that process (``pid 4242: python3 -m
    can.logger -i unixcan -c vcan0 --fd``), or what is known of it."""
    pid = node_pid(socket_name)
    if pid is None:
        return f"socket {os.path.basename(socket_name)}"
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            words = [w.decode(errors="replace") for w in fh.read().split(b"\0") if w]
    except OSError:
        return f"pid {pid} (gone)"
    words[:1] = [os.path.basename(words[0])] if words else []
    text = " ".join(words)
    return f"pid {pid}: {text[:157] + '...' if len(text) > 160 else text}"


class UnixCanBus(can.BusABC):
    """A node on a unixcan channel (the userspace stand-in for a SocketCAN interface)."""

    def __init__(
        self,
        channel: str = "vcan0",
        can_filters: CanFilters | None = None,
        fd: bool = True,
        receive_buffer: int = 1_000_000,
        lossless: bool = False,
        **kwargs: Any,
    ) -> None:
        self.channel = str(channel)
        self.lossless = bool(lossless)
        self.channel_info = f"unixcan channel {self.channel}"
        try:
            self._group = bus_group()
            self._dir = channel_dir(self.channel)
        except OSError as exc:
            raise can.CanInitializationError(str(exc)) from exc
        mark = WIRE.lossless_mark if self.lossless else ""
        name = f"{os.getpid()}-{WIRE.python_tag}{next(_serial)}{mark}{WIRE.socket_suffix}"
        self._path = self._dir / name
        if len(os.fsencode(self._path)) >= 108:
            raise can.CanInitializationError(f"unixcan: socket path {self._path} is too long")
        self._path.unlink(missing_ok=True)
        self._sock = bind_node_socket(self._path, self._group)
        self._peers: list[str] = []
        self._congested: set[str] = set()
        self._connected: dict[str, socket.socket] = {}  # lossless peers waited for
        self._dir_mtime = 0.0
        self._last_scan = 0.0
        self._lock = threading.Lock()
        self.stats = {"tx_frames": 0, "tx_drops": 0, "tx_errors": 0, "rx_frames": 0,
                      "rx_overflows": 0, "rx_filtered": 0, "peers_removed": 0,
                      "rx_malformed": 0, "foreign_entries": 0, "tx_stalls": 0,
                      "tx_stall_failures": 0}
        # the waits for lossless peers: in all, the longest (ms)
        self.stall_ms: dict[str, float] = {"tx_stall_ms_total": 0.0, "tx_stall_ms_max": 0.0}
        # frames dropped for each listener, by its socket's name
        self.listener_drops: collections.Counter[str] = collections.Counter()
        # by the id word (flags included) | FD_KEY for a CAN FD frame (rig.bus.identity)
        self.rx_ids: collections.Counter[int] = collections.Counter()
        self._accept: Callable[[int], bool] | None = None
        self._rx: collections.deque[can.Message] = collections.deque()
        self._rx_limit = receive_buffer
        self._rx_ready = threading.Condition()
        self._reader_waits = False  # lossless: the reader waits for room in _rx
        self._closing = False
        self._wake_r, self._wake_w = os.pipe()
        self._scan_peers()
        self._reader = threading.Thread(target=self._read_loop, name=f"unixcan-{channel}",
                                        daemon=True)
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self._reader.start()  # after the filters are in place

    # -- membership -------------------------------------------------------------------
    def _scan_peers(self) -> None:
        view = scan_folder(self._dir, self._path.name, self._group)
        self._last_scan, self._dir_mtime, peers = view.scanned, view.mtime, view.peers
        self.stats["foreign_entries"] += view.foreign
        self._peers = peers
        self._congested.intersection_update(self._peers)
        for gone in set(self._connected) - set(peers):
            self._connected.pop(gone).close()

    def _refresh_peers(self) -> None:
        if folder_stale(self._dir, self._last_scan, self._dir_mtime):
            self._scan_peers()

    # -- sending ----------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_fd and self._can_protocol is CanProtocol.CAN_20:
            raise can.CanOperationError("this unixcan bus was opened with fd=False")
        try:
            datagram = pack_frame(msg)
        except ValueError as exc:
            raise can.CanOperationError(str(exc)) from exc
        failed: list[str] = []
        with self._lock:
            self._refresh_peers()
            for peer in self._targets(msg.is_fd):
                try:
                    self._send_to(datagram, peer)
                    self._congested.discard(peer)
                except BlockingIOError:
                    self.stats["tx_drops"] += 1
                    self.listener_drops[os.path.basename(peer)] += 1
                    self._congested.add(peer)
                except TimeoutError:
                    self.stats["tx_stall_failures"] += 1
                    failed.append(peer)
                except (ConnectionRefusedError, FileNotFoundError):
                    # Nobody reads that socket any more: its node died without cleaning up.
                    self._peers.remove(peer)
                    self.stats["peers_removed"] += 1
                    try:
                        os.unlink(peer)
                    except OSError:
                        pass
                except OSError as exc:
                    self.stats["tx_errors"] += 1
                    if exc.errno not in (errno.ENOBUFS,):
                        raise can.CanOperationError(f"unixcan send to {peer}: {exc}") from exc
            self.stats["tx_frames"] += 1
        if failed:
            name = os.path.basename(failed[0])
            raise can.CanOperationError(
                f"unixcan channel {self.channel}: node {name} (pid {name.split('-', 1)[0]}), "
                f"which loses no frame, took none for {WIRE.lossless_stall_s * 1e3:.0f} ms "
                f"(its queue stayed full): frame 0x{msg.arbitration_id:X} not delivered to it")

    def _targets(self, fd: bool) -> list[str]:
        """Every peer; with a bit clock on the channel (``rig.bus.arbiter``), a classic frame
        goes to it alone and a CAN FD frame to every peer but it."""
        arbiter = [p for p in self._peers if os.path.basename(p) == WIRE.arbiter_socket]
        if not arbiter:
            return list(self._peers)
        return [p for p in self._peers if p not in arbiter] if fd else arbiter

    def _send_to(self, datagram: bytes, peer: str) -> None:
        try:
            self._sock.sendto(datagram, peer)
            return
        except BlockingIOError:
            if WIRE.is_lossless(os.path.basename(peer)):
                self._wait_for_lossless(datagram, peer)
                return
            if peer in self._congested:
                raise
        give_up = time.monotonic() + WIRE.full_peer_grace_s
        while True:
            time.sleep(0)  # lets this process's own reader thread drain, if it is the peer
            try:
                self._sock.sendto(datagram, peer)
                return
            except BlockingIOError:
                if time.monotonic() >= give_up:
                    raise

    def _wait_for_lossless(self, datagram: bytes, peer: str) -> None:
        """A frame to a lossless peer whose queue is full: wait until it takes it (this
        node's reader thread goes on taking its own frames meanwhile), at most
        ``lossless_stall_s`` (then TimeoutError). Sent from this node's own socket, as every
        frame: the bit clock (``rig.bus.arbiter``) goes by the sender's name."""
        start = time.monotonic()
        give_up = start + WIRE.lossless_stall_s
        self.stats["tx_stalls"] += 1
        try:
            conn = self._connected.get(peer)
            if conn is None:  # connected to it, poll() says when its queue has room
                conn = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
                conn.setblocking(False)
                conn.connect(peer)
                self._connected[peer] = conn
            poller = select.poll()
            poller.register(conn, select.POLLOUT)
            while True:
                try:
                    self._sock.sendto(datagram, peer)
                    return
                except BlockingIOError:
                    pass
                left = give_up - time.monotonic()
                if left <= 0:
                    raise TimeoutError(peer)
                poller.poll(min(left, 0.1) * 1e3)
        finally:
            waited = (time.monotonic() - start) * 1e3
            self.stall_ms["tx_stall_ms_total"] += waited
            self.stall_ms["tx_stall_ms_max"] = max(self.stall_ms["tx_stall_ms_max"], waited)

    # -- receiving --------------------------------------------------------------------
    def _read_loop(self) -> None:
        poller = select.poll()
        poller.register(self._sock, select.POLLIN)
        poller.register(self._wake_r, select.POLLIN)
        while not self._closing:
            try:
                events = poller.poll(500)
            except InterruptedError:
                continue
            if not events:
                continue
            batch: list[can.Message] = []
            accept = self._accept
            while True:
                if self.lossless and len(self._rx) + len(batch) >= self._rx_limit:
                    break  # no room: what waits stays on the socket (its senders wait)
                try:
                    # one byte more than a frame: a longer datagram shows as malformed
                    datagram = self._sock.recv(WIRE.fd_size + 1)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    return
                if len(datagram) not in (WIRE.classic_size, WIRE.fd_size):
                    self.stats["rx_malformed"] += 1  # no struct can_frame / canfd_frame
                    continue
                # Filter on the raw id before building a Message: a node that listens to a
                # few IDs must not pay for every frame of the bus (it has to keep up with
                # the 10 kHz virtual I/O traffic it ignores).
                (raw_id,) = _ID.unpack_from(datagram)
                self.rx_ids[raw_id | (FD_KEY if len(datagram) == WIRE.fd_size else 0)] += 1
                if accept is not None:
                    if not accept(raw_id):
                        self.stats["rx_filtered"] += 1
                        continue
                msg = unpack_frame(datagram, time.time(), self.channel)
                if msg is None:
                    self.stats["rx_malformed"] += 1
                else:
                    batch.append(msg)
            with self._rx_ready:
                room = self._rx_limit - len(self._rx)
                if len(batch) > room:
                    self.stats["rx_overflows"] += len(batch) - max(room, 0)
                    batch = batch[: max(room, 0)]
                self._rx.extend(batch)
                if batch:
                    self._rx_ready.notify_all()
                while self.lossless and len(self._rx) >= self._rx_limit and not self._closing:
                    self._reader_waits = True  # until the owner takes frames
                    self._rx_ready.wait(0.1)
                self._reader_waits = False

    def _apply_filters(self, filters: CanFilters | None) -> None:
        """Filters run in the reader thread on the raw id (SocketCAN semantics)."""
        if not filters:
            self._accept = None
            return
        # the rules grouped by (mask, extended): one set lookup per group and frame (a node
        # listening to a few ids must keep up with the 10 kHz traffic it ignores)
        groups: dict[tuple[int, bool | None], set[int]] = {}
        for f in filters:
            mask = int(f["can_mask"])
            ext = f.get("extended")
            groups.setdefault((mask, None if ext is None else bool(ext)), set()).add(
                int(f["can_id"]) & mask)
        rules = [(mask, ext, frozenset(wants)) for (mask, ext), wants in groups.items()]
        eff_mask, eff_flag = WIRE.eff_mask, WIRE.eff_flag

        def accept(raw_id: int) -> bool:
            ident = raw_id & eff_mask
            is_ext = bool(raw_id & eff_flag)
            for mask, ext, wants in rules:
                if (ident & mask) in wants and (ext is None or ext == is_ext):
                    return True
            return False

        self._accept = accept

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        with self._rx_ready:
            if not self._rx:
                self._rx_ready.wait_for(lambda: bool(self._rx) or self._closing, timeout)
            if not self._rx:
                return None, self._accept is not None
            self.stats["rx_frames"] += 1
            if self._reader_waits:
                self._rx_ready.notify_all()
            return self._rx.popleft(), self._accept is not None

    @property
    def socket_path(self) -> str:
        """This node's socket in the channel folder."""
        return str(self._path)

    def fileno(self) -> int:
        # The socket itself is drained by the reader thread; there is no pollable handle
        # whose readability means "recv() will not block".
        raise NotImplementedError("unixcan buses are not pollable; use recv(timeout)")

    def shutdown(self) -> None:
        if self._closing:
            return
        self._closing = True
        os.write(self._wake_w, b"x")
        self._reader.join(timeout=2.0)
        with self._rx_ready:
            self._rx_ready.notify_all()
        self._sock.close()
        for conn in self._connected.values():
            conn.close()
        os.close(self._wake_r)
        os.close(self._wake_w)
        self._path.unlink(missing_ok=True)
        st = self.stats
        if st["tx_drops"] or st["rx_overflows"]:
            # a replay (can.player) or a log (can.logger) must not lose frames without a word
            who = ", ".join(f"{n} for {name}" for name, n in self.listener_drops.most_common(4))
            log.warning("unixcan channel %s: %d deliveries of the %d frames sent were "
                        "dropped (a listener's queue stayed full for %g ms: %s), %d received "
                        "frames overflowed this node's buffer", self.channel, st["tx_drops"],
                        st["tx_frames"], WIRE.full_peer_grace_s * 1e3, who or "none",
                        st["rx_overflows"])
        super().shutdown()

    @staticmethod
    def _detect_available_configs() -> list[AutoDetectedConfig]:
        base = base_dir()
        if base.is_symlink() or not base.is_dir():
            return []
        return [
            {"interface": "unixcan", "channel": d.name}
            for d in sorted(base.iterdir())
            if d.is_dir() and not d.is_symlink() and channel_name_ok(d.name)
        ]
