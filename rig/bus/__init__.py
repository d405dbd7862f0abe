"""The rig's CAN bus: SocketCAN where the kernel has it, the unixcan fallback elsewhere.

Selection order: an explicit argument, then ``HIL_BUS`` / ``HIL_CHANNEL``, then ``auto``:
SocketCAN when the kernel supports CAN and the interface exists (or, as root, can be
created), else unixcan.
"""

from __future__ import annotations

import json
import os
import socket
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


def select_transport(bus: str | None = None, channel: str | None = None) -> tuple[str, str]:
    """The (transport, channel) to use, resolving ``auto`` and the environment."""
    choice = bus or os.environ.get("HIL_BUS") or "auto"
    chan = channel or os.environ.get("HIL_CHANNEL") or DEFAULT_CHANNEL
    if choice not in TRANSPORTS:
        raise ValueError(f"unknown bus {choice!r}; choose one of {', '.join(TRANSPORTS)}")
    if choice == "auto":
        if kernel_has_can() and (interface_exists(chan) or _can_create_vcan(chan)):
            choice = "socketcan"
        else:
            choice = "unixcan"
    return choice, chan


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
