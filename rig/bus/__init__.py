"""The rig's CAN bus: SocketCAN where the kernel has it, the unixcan fallback elsewhere.

Selection order: an explicit argument, then ``HIL_BUS`` / ``HIL_CHANNEL``, then ``auto``:
SocketCAN when the kernel supports CAN and the interface exists (or, as root, can be
created), else unixcan.

Apart by default: what starts its own nodes (a run, a suite, a commissioning session on the
virtual bench, a benchmark) and names no channel gets a channel of its own on unixcan
(``own_channel``: ``run-<pid>``, ``commission-<pid>``, ...), so two of them on one machine
never meet. A command that talks to nodes already there (``rig param``, ``rig bus``, ``rig
loadbench serve``, plant_rt and fw_host started by hand) keeps ``vcan0``: that is where the
user's own bench is. SocketCAN interfaces are the kernel's (vcan0, can0): a run there holds
the interface (``claim_channel``), and a second run on it is refused at once, as a node that
sends there is (``rig.link.bus``).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import socket
import struct
import subprocess
from pathlib import Path
from typing import Any

import can

TRANSPORTS = ("auto", "socketcan", "unixcan")
DEFAULT_CHANNEL = "vcan0"


def kernel_has_can() -> bool:
    """True when this kernel can open a raw CAN socket (CONFIG_CAN and can-raw)."""
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError:
        return False
    s.close()
    return True


def interface_exists(channel: str) -> bool:
    return Path("/sys/class/net", channel).exists()


def vcan_up(channel: str = DEFAULT_CHANNEL) -> None:
    """Create (if needed) and bring up a CAN FD capable vcan interface. Needs root.

    Only `vcan*` names: a real controller (can0) needs its bit timing set by whoever knows
    the installation (`ip link set can0 type can bitrate 1000000`), never a virtual twin.
    """
    if not channel.startswith("vcan"):
        raise RuntimeError(f"{channel!r} is not a vcan name; configure real CAN interfaces "
                           "with ip link (bit rate) before use")
    if not kernel_has_can():
        raise RuntimeError(
            "this kernel has no CAN support (AF_CAN unavailable); use the unixcan fallback "
            "or run inside the VM: rig vm -- <command>"
        )
    if not interface_exists(channel):
        subprocess.run(["modprobe", "vcan"], check=False, capture_output=True)
        _ip("link", "add", "dev", channel, "type", "vcan")
    _ip("link", "set", "dev", channel, "mtu", "72")  # CANFD_MTU: the interface carries FD
    _ip("link", "set", "dev", channel, "up")


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)} failed: {done.stderr.strip()}")


def select_transport(bus: str | None = None, channel: str | None = None,
                     own: str | None = None) -> tuple[str, str]:
    """The (transport, channel) to use, resolving ``auto`` and the environment. With ``own``
    (what is run: ``run``, ``commission``, ...), a channel nobody named (no argument, no
    ``HIL_CHANNEL``) is, on unixcan, one of this process's own (``own_channel``)."""
    choice = bus or os.environ.get("HIL_BUS") or "auto"
    named = channel or os.environ.get("HIL_CHANNEL")
    chan = named or DEFAULT_CHANNEL
    if choice not in TRANSPORTS:
        raise ValueError(f"unknown bus {choice!r}; choose one of {', '.join(TRANSPORTS)}")
    if choice == "auto":
        if kernel_has_can() and (interface_exists(chan) or _can_create_vcan(chan)):
            choice = "socketcan"
        else:
            choice = "unixcan"
    if choice == "unixcan" and not named and own is not None:
        chan = own_channel(own)
    return choice, chan


def own_channel(what: str) -> str:
    """A unixcan channel of this process's own, named for what it runs and its pid
    (``run-4242``): readable, and apart from every other process's."""
    return f"{what}-{os.getpid()}"


def is_own_channel(channel: str) -> bool:
    """Whether ``channel`` is one ``own_channel`` gave this process."""
    return channel.endswith(f"-{os.getpid()}")


def release_own_channel(channel: str) -> None:
    """Removes the folder of an own unixcan channel once nobody is on it (``rmdir``: a
    folder that still holds a socket stays)."""
    from rig.bus import unixcan

    if is_own_channel(channel):
        with contextlib.suppress(OSError):
            (unixcan.base_dir() / channel).rmdir()


class ChannelInUse(RuntimeError):
    """Another run of the rig holds the channel (``claim_channel``)."""


class ChannelClaim:
    """A run's hold on its channel, until ``release`` (or the process ends): an abstract
    Unix socket named for the channel (its unixcan folder, or the SocketCAN interface), which
    a second process cannot bind while this one holds it. It names the holder's pid."""

    def __init__(self, transport: str, channel: str) -> None:
        from rig.bus import unixcan

        where = (str(unixcan.base_dir() / channel) if transport == "unixcan"
                 else f"socketcan:{channel}")
        digest = hashlib.sha256(where.encode()).hexdigest()[:32]
        self.address = f"\0hil-channel-{digest}"
        self.what = f"{transport} channel {channel!r}"
        self._sock: socket.socket | None = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._sock.bind(self.address)
            self._sock.listen(8)
        except OSError as exc:
            self._sock.close()
            self._sock = None
            if exc.errno != errno.EADDRINUSE:
                raise
            raise ChannelInUse(
                f"{self.what} is in use by another run of the rig{_holder(self.address)}; "
                "refused, nothing started: name another channel (--channel NAME), or leave "
                "the channel unnamed on the fallback bus (each run gets its own)") from None

    def release(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def claim_channel(transport: str, channel: str) -> ChannelClaim:
    """Holds ``channel`` for this run (ChannelInUse when another run of the rig does)."""
    return ChannelClaim(transport, channel)


def _holder(address: str) -> str:
    """`` (pid N)`` of the process holding an abstract socket, when it can be asked."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(1.0)
        probe.connect(address)
        creds = probe.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                 struct.calcsize("3i"))
        pid = struct.unpack("3i", creds)[0]
        return f" (pid {pid})"
    except OSError:
        return ""
    finally:
        probe.close()


def _can_create_vcan(channel: str) -> bool:
    if os.geteuid() != 0 or not channel.startswith("vcan"):
        return False
    try:
        vcan_up(channel)
    except RuntimeError:
        return False
    return True


def open_bus(bus: str | None = None, channel: str | None = None, *, lossless: bool = False,
             **kwargs: Any) -> can.BusABC:
    """A python-can bus on the selected transport, CAN FD enabled. ``lossless``: on unixcan a
    node every sender waits for rather than drop a frame (the nodes of a lockstep run);
    SocketCAN's kernel decides for itself."""
    transport, chan = select_transport(bus, channel)
    if transport == "socketcan":
        return can.Bus(interface="socketcan", channel=chan, fd=True, **kwargs)
    return can.Bus(interface="unixcan", channel=chan, lossless=lossless, **kwargs)


_max_peers: list[int] = []


def unixcan_max_peers(channel: str) -> int:
    """The most other nodes a unixcan node of the C programs sends to (HILBUS_MAX_PEERS in
    hilbus.h, as ``hilbus_tool dir`` reports it on ``channel``: the header is the one place
    it is set). Asked once per process."""
    from rig import _paths

    if not _max_peers:
        done = subprocess.run([str(_paths.binary("hilbus_tool")), "dir", "--bus", "unixcan",
                               "--channel", channel], capture_output=True, text=True,
                              timeout=30, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"hilbus_tool dir: {done.stderr.strip()}")
        _max_peers.append(int(json.loads(done.stdout)["max_peers"]))
    return _max_peers[0]
