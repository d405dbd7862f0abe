"""A CAN frame's whole identity: its identifier with the extended, remote (RTR) and error
flags, and whether it is a CAN FD frame. The rig counts and names frames by it
(``rig.link.bus``, ``rig.run.traffic``): an extended frame 0x11, a remote frame with
DRIVE_STATUS's identifier or a classic frame with a CAN FD message's identifier is none of
the DBC's messages, and is never named like one.

A key is the id word as on the wire (``protocols/unixcan.toml`` [id]: the identifier and the
flag bits) with ``FD`` above its 32 bits for a CAN FD frame.
"""

from __future__ import annotations

import functools

import can

from rig import protocols
from rig.bus.unixcan_wire import FD_KEY, WIRE

EFF, RTR, ERR = WIRE.eff_flag, WIRE.rtr_flag, WIRE.err_flag
FD = FD_KEY
ID_MASK = WIRE.eff_mask


def key(ident: int, *, extended: bool = False, remote: bool = False, error: bool = False,
        fd: bool = False) -> int:
    return ((ident & ID_MASK) | (EFF if extended else 0) | (RTR if remote else 0)
            | (ERR if error else 0) | (FD if fd else 0))


def of_message(msg: can.Message) -> int:
    return key(msg.arbitration_id, extended=msg.is_extended_id, remote=msg.is_remote_frame,
               error=msg.is_error_frame, fd=msg.is_fd)


def of_datagram(id_word: int, fd: bool) -> int:
    """The key of a unixcan datagram: its id word (flags included) and its size's format."""
    return (id_word & 0xFFFFFFFF) | (FD if fd else 0)


@functools.cache
def dbc_keys() -> dict[int, str]:
    """Every message of the bench's protocols by its key (its id, its format)."""
    return {key(int(m.frame_id), extended=bool(m.is_extended_frame), fd=bool(m.is_fd)): m.name
            for db in protocols.DATABASES for m in protocols.database(db).messages}


@functools.cache
def _standard_ids() -> dict[int, int]:
    return {k & ID_MASK: k for k in dbc_keys() if not k & (EFF | RTR | ERR)}


def standard_key(ident: int) -> int:
    """What a C program's count of the 11-bit identifier ``ident`` stands for: hilbus counts
    the standard data frames by identifier (``hilbus_id_received``), so the key of the DBC
    message with that identifier (in its format), else the classic frame of that id."""
    return _standard_ids().get(ident & WIRE.sff_mask, ident & WIRE.sff_mask)


def name(k: int) -> str | None:
    """The DBC message a key is, or None."""
    return dbc_keys().get(k)


def describe(k: int) -> str:
    """``VIO_ADC_0 (0x011)`` for a message of the DBC files; otherwise what the frame is:
    ``extended frame 0x00000011``, ``remote frame (RTR) 0x010``, ``classic frame 0x011
    (VIO_ADC_0 is CAN FD)``, ``error frame``."""
    ident = k & ID_MASK
    known = name(k)
    if known is not None:
        return f"{known} (0x{ident:03X})"
    if k & ERR:
        return "error frame"
    extended = bool(k & EFF)
    shown = f"0x{ident:08X}" if extended else f"0x{ident:03X}"
    kinds = [w for w, on in (("extended", extended), ("remote (RTR)", bool(k & RTR)))
             if on]
    fd = bool(k & FD)
    kinds.append("CAN FD" if fd else "classic")
    what = f"{' '.join(kinds)} frame {shown}"
    if not k & (EFF | RTR):
        other = name(key(ident, fd=not fd))
        if other is not None:
            what += f" ({other} is {'classic' if fd else 'CAN FD'})"
    elif not extended:
        same_id = name(key(ident, fd=False)) or name(key(ident, fd=True))
        if same_id is not None:
            what += f" (the identifier of {same_id})"
    return what
