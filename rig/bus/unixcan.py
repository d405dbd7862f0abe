"""python-can interface for the userspace fallback bus ``unixcan`` (docs/interfaces.md).

The same ``struct canfd_frame`` as SocketCAN, carried over Unix datagram sockets: every node
of a channel binds ``$UNIXCAN_DIR/<channel>/<pid>-<serial>.sock`` and sends each frame to all
other sockets of the channel. Registered as the python-can interface ``unixcan``, so
``can.Bus(interface="unixcan", channel="vcan0")``, ``can.Logger`` and ``cantools monitor``
work on it.

The kernel queues only a few datagrams per receiving socket (``net.unix.max_dgram_qlen``), so
a reader thread drains the socket into a bounded buffer at once; a frame that finds the
buffer full is counted in ``stats["rx_overflows"]``, and a frame a peer could not deliver to
us is counted by that peer as a transmit drop. Nothing is lost silently: ``shutdown`` logs a
warning (logger ``can.unixcan``, on stderr by default, also under ``can.player`` and
``can.logger``) with the drops and overflows of the node's life.

``rx_ids`` counts every frame that reached the node by identifier, the filtered ones too (the
rig compares what nodes received with what the run's nodes sent: ``rig.run.traffic``).
"""

from __future__ import annotations

import collections
import errno
import grp
import itertools
import logging
import os
import re
import select
import socket
import stat
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
from can.bus import CanProtocol
from can.typechecking import AutoDetectedConfig, CanFilters

CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
CANFD_BRS = 0x01
CANFD_ESI = 0x02
CANFD_FDF = 0x04
CAN_MTU = 16
CANFD_MTU = 72
_FRAME = struct.Struct("<IBBBB64s")
_ID = struct.Struct("<I")
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
_RESCAN_INTERVAL_S = 1.0
_RECENT_CHANGE_S = 0.1
# A receiving socket queues only net.unix.max_dgram_qlen datagrams (often 10). A sender that
# finds a peer full waits this long for it to drain before counting a drop; a peer still
# full after that is marked congested and costs no more waiting until it accepts a frame.
_FULL_PEER_GRACE_S = 0.002
_serial = itertools.count()
log = logging.getLogger("can.unixcan")


_CHANNEL_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,62}")


class UnixCanDirError(OSError):
    """The bus folder breaks the directory rule (not ours, a symlink, writable by others)."""


def base_dir() -> Path:
    """Folder holding one sub-folder per channel: ``$UNIXCAN_DIR``, else
    ``$XDG_RUNTIME_DIR/unixcan`` (an absolute, existing XDG_RUNTIME_DIR), else
    ``/tmp/unixcan-<uid>`` (the same rule as hilbus/src/unixcan.c)."""
    explicit = os.environ.get("UNIXCAN_DIR")
    if explicit:
        path = explicit
    else:
        xdg = os.environ.get("XDG_RUNTIME_DIR", "")
        if xdg.startswith("/") and os.path.isdir(xdg):
            path = os.path.join(xdg, "unixcan")
        else:
            path = f"/tmp/unixcan-{os.geteuid()}"
    return Path(path.rstrip("/") or "/")


def channel_name_ok(channel: str) -> bool:
    """A plain name: 1..63 of ``[A-Za-z0-9_.-]``, not starting with '.' or '-'."""
    return _CHANNEL_RE.fullmatch(channel) is not None


def bus_group() -> int | None:
    """The group of ``UNIXCAN_GROUP`` (a name or a number), or None."""
    name = os.environ.get("UNIXCAN_GROUP")
    if not name:
        return None
    try:
        return grp.getgrnam(name).gr_gid
    except KeyError:
        if name.isdigit():
            return int(name)
        raise UnixCanDirError(f"unixcan: UNIXCAN_GROUP={name}: no such group") from None


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
    """One existing folder above the base (the rule in hilbus/src/unixcan.c): a directory of
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
    folder's mode is set to 0700 (0770)."""
    if not channel_name_ok(channel):
        raise UnixCanDirError(
            f"invalid channel name {channel!r}: a plain name of 1 to 63 letters, digits, '_', "
            "'-' or '.', not starting with '.' or '-'")
    group = bus_group()
    mode = 0o770 if group is not None else 0o700
    base = base_dir()
    missing = False  # a folder above is missing: what is below it is made here, 0700
    for parent in reversed(base.parents):
        if parent == parent.parent:
            continue  # the root, or the start of a relative path
        if not missing:
            missing = not _trusted_parent(parent, group)
        if missing:
            try:
                parent.mkdir(mode=0o700)
            except FileExistsError:
                pass
            except OSError as exc:
                raise UnixCanDirError(f"unixcan: cannot create {parent}: {exc.strerror}") from exc
    _own_directory(base, mode, group, tighten=False)
    folder = base / channel
    _own_directory(folder, mode, group, tighten=True)
    return folder


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
    for length in _FD_LENGTHS:
        if n <= length:
            return length
    raise ValueError(f"CAN FD payload of {n} bytes exceeds 64")


def pack_frame(msg: can.Message) -> bytes:
    """The datagram for a message: 16 bytes (classic) or 72 bytes (CAN FD)."""
    can_id = msg.arbitration_id & CAN_EFF_MASK
    if msg.is_extended_id:
        can_id |= CAN_EFF_FLAG
    if msg.is_remote_frame:
        can_id |= CAN_RTR_FLAG
    if msg.is_error_frame:
        can_id |= CAN_ERR_FLAG
    data = bytes(msg.data)
    if msg.is_fd:
        length = fd_length(len(data))
        flags = CANFD_FDF | (CANFD_BRS if msg.bitrate_switch else 0) | (
            CANFD_ESI if msg.error_state_indicator else 0
        )
        return _FRAME.pack(can_id, length, flags, 0, 0, data.ljust(64, b"\0"))
    if len(data) > 8:
        raise ValueError(f"classic CAN frame with {len(data)} data bytes; set is_fd=True")
    length = msg.dlc if msg.is_remote_frame else len(data)
    return _FRAME.pack(can_id, length, 0, 0, 0, data.ljust(64, b"\0"))[:CAN_MTU]


def unpack_frame(datagram: bytes, timestamp: float, channel: str) -> can.Message | None:
    """The message in a datagram, or None for a datagram that is not a frame: a size other
    than 16 or 72 bytes, or a length no controller sends (> 8 classic, not an FD length)."""
    if len(datagram) == CANFD_MTU:
        is_fd = True
    elif len(datagram) == CAN_MTU:
        is_fd = False
        datagram = datagram.ljust(CANFD_MTU, b"\0")
    else:
        return None
    can_id, length, flags, _, _, data = _FRAME.unpack(datagram)
    if length > (64 if is_fd else 8) or (is_fd and length not in _FD_LENGTHS):
        return None
    is_remote = bool(can_id & CAN_RTR_FLAG)
    return can.Message(
        timestamp=timestamp,
        arbitration_id=can_id & CAN_EFF_MASK,
        is_extended_id=bool(can_id & CAN_EFF_FLAG),
        is_remote_frame=is_remote,
        is_error_frame=bool(can_id & CAN_ERR_FLAG),
        is_fd=is_fd,
        bitrate_switch=bool(flags & CANFD_BRS),
        error_state_indicator=bool(flags & CANFD_ESI),
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
        if not n.endswith(".sock") or path in exclude:
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


class UnixCanBus(can.BusABC):
    """A node on a unixcan channel (the userspace stand-in for a SocketCAN interface)."""

    def __init__(
        self,
        channel: str = "vcan0",
        can_filters: CanFilters | None = None,
        fd: bool = True,
        receive_buffer: int = 1_000_000,
        **kwargs: Any,
    ) -> None:
        self.channel = str(channel)
        self.channel_info = f"unixcan channel {self.channel}"
        try:
            self._group = bus_group()
            self._dir = channel_dir(self.channel)
        except OSError as exc:
            raise can.CanInitializationError(str(exc)) from exc
        self._path = self._dir / f"{os.getpid()}-py{next(_serial)}.sock"
        if len(os.fsencode(self._path)) >= 108:
            raise can.CanInitializationError(f"unixcan: socket path {self._path} is too long")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        for opt in (socket.SO_SNDBUF, socket.SO_RCVBUF):
            self._sock.setsockopt(socket.SOL_SOCKET, opt, 4 << 20)
        self._path.unlink(missing_ok=True)
        self._sock.bind(str(self._path))
        # The folder is 0700 already; the socket's own mode says the same to whoever looks.
        os.chmod(self._path, 0o660 if self._group is not None else 0o600)
        if self._group is not None:
            os.chown(self._path, -1, self._group)
        self._sock.setblocking(False)
        self._peers: list[str] = []
        self._congested: set[str] = set()
        self._dir_mtime = 0.0
        self._last_scan = 0.0
        self._lock = threading.Lock()
        self.stats = {"tx_frames": 0, "tx_drops": 0, "tx_errors": 0, "rx_frames": 0,
                      "rx_overflows": 0, "rx_filtered": 0, "peers_removed": 0,
                      "rx_malformed": 0, "foreign_entries": 0}
        self.rx_ids: collections.Counter[int] = collections.Counter()  # by raw can_id
        self._accept: Callable[[int], bool] | None = None
        self._rx: collections.deque[can.Message] = collections.deque()
        self._rx_limit = receive_buffer
        self._rx_ready = threading.Condition()
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
        self._last_scan = time.time()
        try:
            self._dir_mtime = self._dir.stat().st_mtime
            names = os.listdir(self._dir)
        except OSError:
            self._peers = []
            return
        own = self._path.name
        peers = []
        for n in names:
            if not n.endswith(".sock") or n == own:
                continue
            path = str(self._dir / n)
            if peer_socket_ok(path, self._group):
                peers.append(path)
            else:
                self.stats["foreign_entries"] += 1
        self._peers = peers
        self._congested.intersection_update(self._peers)

    def _refresh_peers(self) -> None:
        now = time.time()
        # Directory timestamps are coarse: keep re-reading while a change is recent.
        if now - self._last_scan > _RESCAN_INTERVAL_S or now - self._dir_mtime < _RECENT_CHANGE_S:
            self._scan_peers()
            return
        try:
            if self._dir.stat().st_mtime != self._dir_mtime:
                self._scan_peers()
        except OSError:
            pass

    # -- sending ----------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_fd and self._can_protocol is CanProtocol.CAN_20:
            raise can.CanOperationError("this unixcan bus was opened with fd=False")
        try:
            datagram = pack_frame(msg)
        except ValueError as exc:
            raise can.CanOperationError(str(exc)) from exc
        with self._lock:
            self._refresh_peers()
            for peer in list(self._peers):
                try:
                    self._send_to(datagram, peer)
                    self._congested.discard(peer)
                except BlockingIOError:
                    self.stats["tx_drops"] += 1
                    self._congested.add(peer)
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

    def _send_to(self, datagram: bytes, peer: str) -> None:
        try:
            self._sock.sendto(datagram, peer)
            return
        except BlockingIOError:
            if peer in self._congested:
                raise
        give_up = time.monotonic() + _FULL_PEER_GRACE_S
        while True:
            time.sleep(0)  # lets this process's own reader thread drain, if it is the peer
            try:
                self._sock.sendto(datagram, peer)
                return
            except BlockingIOError:
                if time.monotonic() >= give_up:
                    raise

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
                try:
                    # one byte more than a frame: a longer datagram shows as malformed
                    datagram = self._sock.recv(CANFD_MTU + 1)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    return
                if len(datagram) not in (CAN_MTU, CANFD_MTU):
                    self.stats["rx_malformed"] += 1  # no struct can_frame / canfd_frame
                    continue
                # Filter on the raw id before building a Message: a node that listens to a
                # few IDs must not pay for every frame of the bus (it has to keep up with
                # the 10 kHz virtual I/O traffic it ignores).
                (raw_id,) = _ID.unpack_from(datagram)
                self.rx_ids[raw_id] += 1
                if accept is not None:
                    if not accept(raw_id):
                        self.stats["rx_filtered"] += 1
                        continue
                msg = unpack_frame(datagram, time.time(), self.channel)
                if msg is None:
                    self.stats["rx_malformed"] += 1
                else:
                    batch.append(msg)
            if batch:
                with self._rx_ready:
                    room = self._rx_limit - len(self._rx)
                    if len(batch) > room:
                        self.stats["rx_overflows"] += len(batch) - max(room, 0)
                        batch = batch[: max(room, 0)]
                    self._rx.extend(batch)
                    self._rx_ready.notify_all()

    def _apply_filters(self, filters: CanFilters | None) -> None:
        """Filters run in the reader thread on the raw id (SocketCAN semantics)."""
        if not filters:
            self._accept = None
            return
        rules = []
        for f in filters:
            mask = int(f["can_mask"])
            can_id = int(f["can_id"])
            ext = f.get("extended")
            rules.append((can_id & mask, mask, ext))

        def accept(raw_id: int) -> bool:
            ident = raw_id & CAN_EFF_MASK
            is_ext = bool(raw_id & CAN_EFF_FLAG)
            return any((ident & mask) == want and (ext is None or ext == is_ext)
                       for want, mask, ext in rules)

        self._accept = accept

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        with self._rx_ready:
            if not self._rx:
                self._rx_ready.wait_for(lambda: bool(self._rx) or self._closing, timeout)
            if not self._rx:
                return None, self._accept is not None
            self.stats["rx_frames"] += 1
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
        os.close(self._wake_r)
        os.close(self._wake_w)
        self._path.unlink(missing_ok=True)
        st = self.stats
        if st["tx_drops"] or st["rx_overflows"]:
            # a replay (can.player) or a log (can.logger) must not lose frames without a word
            log.warning("unixcan channel %s: %d deliveries of the %d frames sent were "
                        "dropped (a receiver's queue stayed full for %g ms), %d received "
                        "frames overflowed this node's buffer", self.channel, st["tx_drops"],
                        st["tx_frames"], _FULL_PEER_GRACE_S * 1e3, st["rx_overflows"])
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
