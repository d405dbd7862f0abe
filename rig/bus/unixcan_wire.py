"""The wire of the unixcan fallback bus, read from protocols/unixcan.toml at import time: the
datagram layout, the id and CAN FD flag bits, the FD length table, the channel-name rule,
the folder and socket naming and modes, and the timing nodes promise each other. hilbus gets
the same facts generated into hil_unixcan.h (firmware_c2000/tools/gen_unixcan.py)."""

from __future__ import annotations

import os
import struct
import tomllib
from dataclasses import dataclass
from typing import Any

from rig._paths import data_dir


def _runs(chars: str) -> str:
    """The alphabet in a few words: runs of consecutive characters as ``A-Z``."""
    words: list[str] = []
    i = 0
    while i < len(chars):
        j = i
        while j + 1 < len(chars) and ord(chars[j + 1]) == ord(chars[j]) + 1:
            j += 1
        words.append(f"{chars[i]}-{chars[j]}" if j - i >= 2 else " ".join(chars[i:j + 1]))
        i = j + 1
    return " ".join(words)


@dataclass(frozen=True)
class UnixCanWire:
    """protocols/unixcan.toml, its sections flattened (names as there)."""

    classic_size: int
    fd_size: int
    id_offset: int
    len_offset: int
    flags_offset: int
    data_offset: int
    classic_max_len: int
    fd_max_len: int
    fd_lengths: tuple[int, ...]
    eff_flag: int
    rtr_flag: int
    err_flag: int
    sff_mask: int
    eff_mask: int
    brs: int
    esi: int
    fdf: int
    channel_max_length: int
    channel_chars: frozenset[str]
    channel_chars_text: str
    channel_not_first: frozenset[str]
    channel_not_first_text: str
    base_env: str
    runtime_env: str
    runtime_subdir: str
    fallback_base: str
    group_env: str
    folder_mode: int
    group_folder_mode: int
    socket_mode: int
    group_socket_mode: int
    socket_suffix: str
    python_tag: str
    lossless_mark: str
    arbiter: str
    rescan_interval_s: float
    full_peer_grace_s: float
    lossless_stall_s: float

    def frame_struct(self) -> struct.Struct:
        """The CAN FD datagram as a struct: id, len, flags, the reserved bytes, data."""
        return struct.Struct(f"<IBBBB{self.fd_max_len}s")  # load() checked order and offsets

    def channel_name_ok(self, name: str) -> bool:
        return (0 < len(name) <= self.channel_max_length and name[0] not in self.channel_not_first
                and all(c in self.channel_chars for c in name))

    def channel_rule(self) -> str:
        """The rule in words, as hilbus says it (HIL_UNIXCAN_CHANNEL_RULE)."""
        return (f"a plain name of 1 to {self.channel_max_length} of "
                f"{_runs(self.channel_chars_text)}, not starting with "
                f"{' or '.join(self.channel_not_first_text)}")

    def is_lossless(self, socket_name: str) -> bool:
        """Whether a node's socket name says it must lose no frame ([socket] lossless_mark)."""
        return socket_name.endswith(self.lossless_mark + self.socket_suffix)

    @property
    def arbiter_socket(self) -> str:
        """The bit clock's socket name in a channel folder ([socket] arbiter): lossless, so
        that a sender waits for the bus, as a CAN controller does, rather than drop."""
        return self.arbiter + self.lossless_mark + self.socket_suffix

    def fallback_base_path(self) -> str:
        return self.fallback_base.replace("{uid}", str(os.geteuid()))


def load(text: str) -> UnixCanWire:
    """The wire described by a unixcan.toml text (its checks are gen_unixcan.py's, which
    stops the build on a bad description; this side only refuses what it cannot read)."""
    desc: dict[str, Any] = tomllib.loads(text)
    frame, ident, fd_flags = desc["frame"], desc["id"], desc["fd_flags"]
    channel, directory, sock, timing = (desc["channel"], desc["directory"], desc["socket"],
                                        desc["timing"])
    if frame["byte_order"] != "little":
        raise ValueError("protocols/unixcan.toml: only a little-endian wire is supported")
    if (frame["id_offset"], frame["len_offset"], frame["flags_offset"], frame["reserved"],
            frame["data_offset"]) != (0, 4, 5, [6, 7], 8):
        raise ValueError("protocols/unixcan.toml: not the struct can_frame layout (id 0..3, "
                         "len 4, flags 5, reserved 6 and 7, data from 8)")
    return UnixCanWire(
        classic_size=int(frame["classic_size"]), fd_size=int(frame["fd_size"]),
        id_offset=int(frame["id_offset"]), len_offset=int(frame["len_offset"]),
        flags_offset=int(frame["flags_offset"]), data_offset=int(frame["data_offset"]),
        classic_max_len=int(frame["classic_max_len"]), fd_max_len=int(frame["fd_max_len"]),
        fd_lengths=tuple(int(n) for n in frame["fd_lengths"]),
        eff_flag=int(ident["eff_flag"]), rtr_flag=int(ident["rtr_flag"]),
        err_flag=int(ident["err_flag"]), sff_mask=int(ident["sff_mask"]),
        eff_mask=int(ident["eff_mask"]),
        brs=int(fd_flags["brs"]), esi=int(fd_flags["esi"]), fdf=int(fd_flags["fdf"]),
        channel_max_length=int(channel["max_length"]),
        channel_chars=frozenset(channel["chars"]), channel_chars_text=str(channel["chars"]),
        channel_not_first=frozenset(channel["not_first"]),
        channel_not_first_text=str(channel["not_first"]),
        base_env=str(directory["base_env"]), runtime_env=str(directory["runtime_env"]),
        runtime_subdir=str(directory["runtime_subdir"]),
        fallback_base=str(directory["fallback_base"]), group_env=str(directory["group_env"]),
        folder_mode=int(directory["folder_mode"]),
        group_folder_mode=int(directory["group_folder_mode"]),
        socket_mode=int(directory["socket_mode"]),
        group_socket_mode=int(directory["group_socket_mode"]),
        socket_suffix=str(sock["suffix"]), python_tag=str(sock["python_tag"]),
        lossless_mark=str(sock["lossless_mark"]), arbiter=str(sock["arbiter"]),
        rescan_interval_s=int(timing["rescan_interval_ms"]) / 1000.0,
        full_peer_grace_s=int(timing["full_peer_grace_ms"]) / 1000.0,
        lossless_stall_s=int(timing["lossless_stall_ms"]) / 1000.0,
    )


# Not on the wire: the bit above the 32-bit id word that the rig's counts by identity set for
# a CAN FD frame (rig.bus.identity; the datagram's size says it on the wire).
FD_KEY = 1 << 32

WIRE = load((data_dir("protocols") / "unixcan.toml").read_text(encoding="utf-8"))
