"""Generates hil_unixcan.h, hilbus's share of the unixcan wire, from protocols/unixcan.toml
(the datagram layout, the id and CAN FD flag bits, the FD length table, the channel-name
rule, the folder and socket naming and modes, the timing one node promises the others).

Usage: gen_unixcan.py protocols/unixcan.toml OUT_DIR

The description is checked against itself (sizes against offsets and lengths, the length
table, disjoint flag bits, the channel alphabet) and the header checks it at compile time
against the kernel's linux/can.h, whose structs the wire is. Python reads the same file
(rig/bus/unixcan_wire.py)."""

from __future__ import annotations

import itertools
import sys
import tomllib
from pathlib import Path
from typing import Any

import c_codegen

SCRIPT = "gen_unixcan.py"


def _int(table: dict[str, Any], section: str, key: str, lo: int = 0) -> int:
    value = table.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or value < lo:
        raise ValueError(f"[{section}] {key}: an integer >= {lo} expected, got {value!r}")
    return value


def _str(table: dict[str, Any], section: str, key: str) -> str:
    value = table.get(key)
    if not isinstance(value, str):
        raise ValueError(f"[{section}] {key}: a string expected, got {value!r}")
    return value


def read(path: Path) -> dict[str, Any]:
    """The description, checked; ValueError names the fault."""
    try:
        desc = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    for section in ("frame", "id", "fd_flags", "channel", "directory", "socket", "timing"):
        if not isinstance(desc.get(section), dict):
            raise ValueError(f"{path}: section [{section}] missing")
    frame = desc["frame"]
    if frame.get("byte_order") != "little":
        raise ValueError("[frame] byte_order: only \"little\" is supported")
    data = _int(frame, "frame", "data_offset")
    offsets = [_int(frame, "frame", "id_offset"), _int(frame, "frame", "len_offset"),
               _int(frame, "frame", "flags_offset")]
    reserved = frame.get("reserved")
    if offsets != [0, 4, 5] or reserved != [6, 7] or data != 8:
        raise ValueError("[frame] offsets: the struct can_frame layout is id 0..3, len 4, "
                         "flags 5, reserved 6 and 7, data from 8")
    classic_max, fd_max = (_int(frame, "frame", "classic_max_len"),
                           _int(frame, "frame", "fd_max_len"))
    if _int(frame, "frame", "classic_size") != data + classic_max:
        raise ValueError("[frame] classic_size must be data_offset + classic_max_len")
    if _int(frame, "frame", "fd_size") != data + fd_max:
        raise ValueError("[frame] fd_size must be data_offset + fd_max_len")
    lengths = frame.get("fd_lengths")
    if (not isinstance(lengths, list) or len(lengths) != 16
            or any(not isinstance(n, int) for n in lengths) or lengths[0] != 0
            or lengths[-1] != fd_max or any(b <= a for a, b in itertools.pairwise(lengths))
            or lengths[:classic_max + 1] != list(range(classic_max + 1))):
        raise ValueError("[frame] fd_lengths: 16 ascending lengths (one per DLC), 0.."
                         "classic_max_len one by one, ending at fd_max_len")
    bits = [_int(desc["id"], "id", k) for k in ("eff_flag", "rtr_flag", "err_flag")]
    eff_mask = _int(desc["id"], "id", "eff_mask")
    sff_mask = _int(desc["id"], "id", "sff_mask")
    if any(b & (b - 1) for b in bits) or len(set(bits)) != 3 or any(b & eff_mask for b in bits):
        raise ValueError("[id] the flags must be distinct single bits outside eff_mask")
    if sff_mask & ~eff_mask or sff_mask != 0x7FF:
        raise ValueError("[id] sff_mask must be the 11-bit identifier, inside eff_mask")
    fd_bits = [_int(desc["fd_flags"], "fd_flags", k) for k in ("brs", "esi", "fdf")]
    if any(b & (b - 1) or b > 0xFF or b == 0 for b in fd_bits) or len(set(fd_bits)) != 3:
        raise ValueError("[fd_flags] the flags must be distinct single bits of one byte")
    channel = desc["channel"]
    _int(channel, "channel", "max_length", 1)
    chars, not_first = _str(channel, "channel", "chars"), _str(channel, "channel", "not_first")
    if not chars.isascii() or not chars.isprintable() or "/" in chars or "\\" in chars \
            or '"' in chars or "%" in chars or len(set(chars)) != len(chars):
        raise ValueError("[channel] chars: distinct printable ASCII, no '/', '\\', '\"' or '%'")
    if not set(not_first) <= set(chars):
        raise ValueError("[channel] not_first must be characters of chars")
    directory = desc["directory"]
    for key in ("base_env", "runtime_env", "runtime_subdir", "group_env"):
        if not _str(directory, "directory", key) or '"' in directory[key]:
            raise ValueError(f"[directory] {key}: a plain name expected")
    fallback = _str(directory, "directory", "fallback_base")
    if fallback.count("{uid}") != 1 or "%" in fallback or not fallback.startswith("/"):
        raise ValueError("[directory] fallback_base: an absolute path with one {uid}, no '%'")
    for key in ("folder_mode", "group_folder_mode", "socket_mode", "group_socket_mode"):
        if _int(directory, "directory", key) > 0o777:
            raise ValueError(f"[directory] {key}: a permission mode (at most 0o777)")
    sock = desc["socket"]
    suffix = _str(sock, "socket", "suffix")
    tags = (_str(sock, "socket", "c_tag"), _str(sock, "socket", "python_tag"))
    if not suffix.startswith(".") or tags[0] == tags[1] or any(
            not all(c.isascii() and c.isalpha() for c in t) for t in tags):
        raise ValueError("[socket] suffix starts with '.'; c_tag and python_tag are distinct "
                         "letters (or empty), so that no C node's name is a Python node's")
    mark = _str(sock, "socket", "lossless_mark")
    if (len(mark) < 2 or not mark.startswith(".") or not mark[1:].isascii()
            or not mark[1:].isalpha() or mark == suffix):
        raise ValueError("[socket] lossless_mark: '.' and ASCII letters, not the suffix")
    arbiter = _str(sock, "socket", "arbiter")
    if not arbiter.isascii() or not arbiter.isalpha():
        raise ValueError("[socket] arbiter: ASCII letters (no node's <pid>-... name is one)")
    _int(desc["timing"], "timing", "rescan_interval_ms", 1)
    grace = _int(desc["timing"], "timing", "full_peer_grace_ms", 1)
    if _int(desc["timing"], "timing", "lossless_stall_ms", 1) <= grace:
        raise ValueError("[timing] lossless_stall_ms must be longer than full_peer_grace_ms")
    return desc


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


def channel_rule(channel: dict[str, Any]) -> str:
    """The rule in words, for error messages (rig/bus/unixcan_wire.py says it the same way)."""
    return (f"a plain name of 1 to {channel['max_length']} of {_runs(channel['chars'])}, "
            f"not starting with {' or '.join(channel['not_first'])}")


def header(desc: dict[str, Any]) -> str:
    frame, ident, fdf = desc["frame"], desc["id"], desc["fd_flags"]
    channel, directory, sock, timing = (desc["channel"], desc["directory"], desc["socket"],
                                        desc["timing"])
    lengths = ", ".join(str(n) for n in frame["fd_lengths"])
    cs = c_codegen.c_string
    lines = [*c_codegen.banner(SCRIPT, "protocols/unixcan.toml"),
        "#ifndef HIL_UNIXCAN_H",
        "#define HIL_UNIXCAN_H",
        "",
        "#include <stddef.h>",
        "#include <linux/can.h>",
        "",
        "/* A datagram is one struct can_frame (classic) or struct canfd_frame (CAN FD). */",
        f"#define HIL_UNIXCAN_CLASSIC_SIZE {frame['classic_size']}",
        f"#define HIL_UNIXCAN_FD_SIZE {frame['fd_size']}",
        f"#define HIL_UNIXCAN_ID_OFFSET {frame['id_offset']}",
        f"#define HIL_UNIXCAN_LEN_OFFSET {frame['len_offset']}",
        f"#define HIL_UNIXCAN_FLAGS_OFFSET {frame['flags_offset']}",
        f"#define HIL_UNIXCAN_DATA_OFFSET {frame['data_offset']}",
        f"#define HIL_UNIXCAN_CLASSIC_MAX_LEN {frame['classic_max_len']}",
        f"#define HIL_UNIXCAN_FD_MAX_LEN {frame['fd_max_len']}",
        "/* the payload lengths of a CAN FD frame, one per DLC */",
        f"#define HIL_UNIXCAN_FD_LENGTHS {{{lengths}}}",
        f"#define HIL_UNIXCAN_FD_LENGTH_COUNT {len(frame['fd_lengths'])}",
        "",
        "/* the id word */",
        f"#define HIL_UNIXCAN_EFF_FLAG 0x{ident['eff_flag']:08X}U",
        f"#define HIL_UNIXCAN_RTR_FLAG 0x{ident['rtr_flag']:08X}U",
        f"#define HIL_UNIXCAN_ERR_FLAG 0x{ident['err_flag']:08X}U",
        f"#define HIL_UNIXCAN_SFF_MASK 0x{ident['sff_mask']:08X}U",
        f"#define HIL_UNIXCAN_EFF_MASK 0x{ident['eff_mask']:08X}U",
        "/* the flags byte of a CAN FD frame */",
        f"#define HIL_UNIXCAN_BRS 0x{fdf['brs']:02X}U",
        f"#define HIL_UNIXCAN_ESI 0x{fdf['esi']:02X}U",
        f"#define HIL_UNIXCAN_FDF 0x{fdf['fdf']:02X}U",
        "",
        "/* a channel name: 1..MAX_LEN of CHARS, the first not one of NOT_FIRST */",
        f"#define HIL_UNIXCAN_CHANNEL_MAX_LEN {channel['max_length']}",
        f"#define HIL_UNIXCAN_CHANNEL_CHARS {cs(channel['chars'])}",
        f"#define HIL_UNIXCAN_CHANNEL_NOT_FIRST {cs(channel['not_first'])}",
        f"#define HIL_UNIXCAN_CHANNEL_RULE {cs(channel_rule(channel))}",
        "",
        "/* the folder: $BASE_ENV, else $RUNTIME_ENV/RUNTIME_SUBDIR, else FALLBACK_BASE_FMT of",
        " * the effective uid (an unsigned long); then <base>/<channel> */",
        f"#define HIL_UNIXCAN_BASE_ENV {cs(directory['base_env'])}",
        f"#define HIL_UNIXCAN_RUNTIME_ENV {cs(directory['runtime_env'])}",
        f"#define HIL_UNIXCAN_RUNTIME_SUBDIR {cs(directory['runtime_subdir'])}",
        "#define HIL_UNIXCAN_FALLBACK_BASE_FMT "
        + cs(directory["fallback_base"].replace("{uid}", "%lu")),
        f"#define HIL_UNIXCAN_GROUP_ENV {cs(directory['group_env'])}",
        f"#define HIL_UNIXCAN_FOLDER_MODE 0{directory['folder_mode']:o}",
        f"#define HIL_UNIXCAN_GROUP_FOLDER_MODE 0{directory['group_folder_mode']:o}",
        f"#define HIL_UNIXCAN_SOCKET_MODE 0{directory['socket_mode']:o}",
        f"#define HIL_UNIXCAN_GROUP_SOCKET_MODE 0{directory['group_socket_mode']:o}",
        "/* a node's socket: <pid>-<C_TAG><serial>[LOSSLESS_MARK]<SUFFIX>; every <...>SUFFIX is",
        " * a peer, one with LOSSLESS_MARK before the suffix a node no sender drops a frame for */",
        f"#define HIL_UNIXCAN_SOCKET_SUFFIX {cs(sock['suffix'])}",
        f"#define HIL_UNIXCAN_C_TAG {cs(sock['c_tag'])}",
        f"#define HIL_UNIXCAN_LOSSLESS_MARK {cs(sock['lossless_mark'])}",
        "/* the bit clock's socket: <ARBITER><LOSSLESS_MARK><SUFFIX>; while it is there,",
        " * classic frames go to it alone, CAN FD frames to every other peer */",
        f"#define HIL_UNIXCAN_ARBITER {cs(sock['arbiter'])}",
        "",
        "/* what a node promises the others (protocols/unixcan.toml [timing]) */",
        f"#define HIL_UNIXCAN_RESCAN_INTERVAL_NS {timing['rescan_interval_ms'] * 1_000_000}LL",
        f"#define HIL_UNIXCAN_FULL_PEER_GRACE_NS {timing['full_peer_grace_ms'] * 1_000_000}LL",
        f"#define HIL_UNIXCAN_LOSSLESS_STALL_NS {timing['lossless_stall_ms'] * 1_000_000}LL",
        "",
        "/* The wire is the kernel's structs: the build stops where linux/can.h disagrees. */",
        "#define HIL_UNIXCAN_CHECK(name, cond) "
        "typedef char hil_unixcan_check_##name[(cond) ? 1 : -1]",
        "#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__",
        "#error \"unixcan: the wire's id word is little-endian (protocols/unixcan.toml)\"",
        "#endif",
        "HIL_UNIXCAN_CHECK(classic_size, sizeof(struct can_frame) == HIL_UNIXCAN_CLASSIC_SIZE && "
        "CAN_MTU == HIL_UNIXCAN_CLASSIC_SIZE);",
        "HIL_UNIXCAN_CHECK(fd_size, sizeof(struct canfd_frame) == HIL_UNIXCAN_FD_SIZE && "
        "CANFD_MTU == HIL_UNIXCAN_FD_SIZE);",
        "HIL_UNIXCAN_CHECK(id_offset, offsetof(struct canfd_frame, can_id) == "
        "HIL_UNIXCAN_ID_OFFSET);",
        "HIL_UNIXCAN_CHECK(len_offset, offsetof(struct canfd_frame, len) == "
        "HIL_UNIXCAN_LEN_OFFSET);",
        "HIL_UNIXCAN_CHECK(flags_offset, offsetof(struct canfd_frame, flags) == "
        "HIL_UNIXCAN_FLAGS_OFFSET);",
        "HIL_UNIXCAN_CHECK(data_offset, offsetof(struct canfd_frame, data) == "
        "HIL_UNIXCAN_DATA_OFFSET && offsetof(struct can_frame, data) == HIL_UNIXCAN_DATA_OFFSET);",
        "HIL_UNIXCAN_CHECK(max_len, CAN_MAX_DLEN == HIL_UNIXCAN_CLASSIC_MAX_LEN && "
        "CANFD_MAX_DLEN == HIL_UNIXCAN_FD_MAX_LEN);",
        "HIL_UNIXCAN_CHECK(id_bits, CAN_EFF_FLAG == HIL_UNIXCAN_EFF_FLAG && CAN_RTR_FLAG == "
        "HIL_UNIXCAN_RTR_FLAG && CAN_ERR_FLAG == HIL_UNIXCAN_ERR_FLAG && CAN_SFF_MASK == "
        "HIL_UNIXCAN_SFF_MASK && CAN_EFF_MASK == HIL_UNIXCAN_EFF_MASK);",
        "HIL_UNIXCAN_CHECK(fd_bits, CANFD_BRS == HIL_UNIXCAN_BRS && CANFD_ESI == HIL_UNIXCAN_ESI);",
        "#ifdef CANFD_FDF",
        "HIL_UNIXCAN_CHECK(fdf_bit, CANFD_FDF == HIL_UNIXCAN_FDF);",
        "#endif",
        "",
        "#endif",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    return c_codegen.generate(argv, __doc__ or "", read, {"hil_unixcan.h": header})


if __name__ == "__main__":
    sys.exit(main(sys.argv))
