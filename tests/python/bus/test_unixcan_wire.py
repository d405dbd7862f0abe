"""Both sides of the unixcan wire hold protocols/unixcan.toml, the one description of it.

hilbus (C) has the facts generated into hil_unixcan.h; ``hilbus_tool wire`` prints what it
was built with and its verdict on channel names. rig.bus.unixcan reads the file at import
time. Each is compared with the file itself, read here on its own, and the datagrams a C
node and a Python node send for the same frame are compared byte for byte.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import tempfile
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest

from rig import _paths
from rig.bus import unixcan
from rig.bus.unixcan_wire import WIRE

DESCRIPTION: dict[str, Any] = tomllib.loads(
    (_paths.data_dir("protocols") / "unixcan.toml").read_text(encoding="utf-8"))


def tool() -> str:
    try:
        return str(_paths.binary("hilbus_tool"))
    except FileNotFoundError as exc:
        pytest.skip(f"hilbus_tool not built: {exc}")


def names_to_check() -> list[str]:
    """Every printable ASCII character and a few others alone, first and inside a name,
    the length limit and one past it, and the names that must never be folders."""
    chars = [chr(c) for c in range(1, 128)] + ["é", "\u00a0", "ß"]
    limit = int(DESCRIPTION["channel"]["max_length"])
    return [*chars, *(c + "a" for c in chars), *("a" + c for c in chars),
            "", ".", "..", "../up", "a/b", "-x", ".hidden", "vcan0", "run_1.a-b",
            "x" * limit, "x" * (limit + 1), "é" * 32]


def expected_verdict(name: str) -> bool:
    """The [channel] rule applied literally: 1..max_length characters of `chars`, the first
    not one of `not_first`."""
    rule = DESCRIPTION["channel"]
    return (1 <= len(name) <= rule["max_length"] and name[0] not in rule["not_first"]
            and set(name) <= set(rule["chars"]))


@pytest.fixture(scope="module")
def c_wire() -> dict[str, Any]:
    names = names_to_check()
    done = subprocess.run([tool(), "wire"], input="".join(n.encode().hex() + "\n" for n in names),
                          capture_output=True, text=True, timeout=30, check=True)
    facts: dict[str, Any] = json.loads(done.stdout)
    assert len(facts["names_ok"]) == len(names)
    return facts


def test_the_rule_reads_as_intended() -> None:
    """A few verdicts said by hand, so that the literal reading above is the intended one."""
    assert expected_verdict("vcan0") and expected_verdict("run_1.a-b")
    assert expected_verdict("x" * 63) and not expected_verdict("x" * 64)
    for bad in ("", ".", "..", "../up", "a/b", "-x", ".hidden", "a b", "é"):
        assert not expected_verdict(bad), bad


def test_c_and_python_give_every_channel_name_the_described_verdict(
        c_wire: dict[str, Any]) -> None:
    names = names_to_check()
    for name, c_ok in zip(names, c_wire["names_ok"], strict=True):
        want = expected_verdict(name)
        assert bool(c_ok) == want, f"hilbus on {name!r}"
        assert unixcan.channel_name_ok(name) == want, f"rig.bus.unixcan on {name!r}"
    assert sum(c_wire["names_ok"]) > 100  # the list holds accepted names too
    assert c_wire["channel_rule"] == WIRE.channel_rule()


def test_c_and_python_hold_the_described_frame_layout(c_wire: dict[str, Any]) -> None:
    frame, ident, fd_flags = (DESCRIPTION["frame"], DESCRIPTION["id"],
                              DESCRIPTION["fd_flags"])
    for key in ("classic_size", "fd_size", "id_offset", "len_offset", "flags_offset",
                "data_offset", "classic_max_len", "fd_max_len", "fd_lengths"):
        assert c_wire[key] == frame[key], key
    for key in ("eff_flag", "rtr_flag", "err_flag", "sff_mask", "eff_mask"):
        assert c_wire[key] == ident[key] == getattr(WIRE, key), key
    for key in ("brs", "esi", "fdf"):
        assert c_wire[key] == fd_flags[key] == getattr(WIRE, key), key
    assert (WIRE.classic_size, WIRE.fd_size, WIRE.fd_lengths) == (
        frame["classic_size"], frame["fd_size"], tuple(frame["fd_lengths"]))
    # a payload of n bytes goes in the smallest FD length that holds it
    want = [min(k for k in frame["fd_lengths"] if k >= n) for n in range(frame["fd_max_len"] + 1)]
    assert c_wire["fd_len"] == want
    assert [unixcan.fd_length(n) for n in range(frame["fd_max_len"] + 1)] == want


def test_c_and_python_name_and_time_the_same(c_wire: dict[str, Any]) -> None:
    directory, sock, timing = (DESCRIPTION["directory"], DESCRIPTION["socket"],
                               DESCRIPTION["timing"])
    for key in ("folder_mode", "group_folder_mode", "socket_mode", "group_socket_mode"):
        assert c_wire[key] == directory[key] == getattr(WIRE, key), key
    assert c_wire["socket_suffix"] == sock["suffix"] == WIRE.socket_suffix
    assert c_wire["c_tag"] == sock["c_tag"] != WIRE.python_tag == sock["python_tag"]
    assert c_wire["rescan_interval_ns"] == timing["rescan_interval_ms"] * 1_000_000
    assert c_wire["full_peer_grace_ns"] == timing["full_peer_grace_ms"] * 1_000_000
    assert WIRE.rescan_interval_s == timing["rescan_interval_ms"] / 1000
    assert WIRE.full_peer_grace_s == timing["full_peer_grace_ms"] / 1000
    assert c_wire["lossless_mark"] == sock["lossless_mark"] == WIRE.lossless_mark
    assert c_wire["lossless_stall_ns"] == timing["lossless_stall_ms"] * 1_000_000
    assert WIRE.lossless_stall_s == timing["lossless_stall_ms"] / 1000


def test_c_and_python_nodes_say_lossless_in_their_names_alike(bus_dir: Path) -> None:
    """A lossless node's socket is <pid>-<tag><serial><lossless_mark><suffix> on both sides;
    a listener's carries no mark. Each side reads the other's name the same way."""
    folder = unixcan.channel_dir("names")
    listener = subprocess.Popen([tool(), "recv", "--bus", "unixcan", "--channel", "names",
                                 "--count", "0", "--timeout-ms", "20000"],
                                stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    lossless = subprocess.Popen([tool(), "recv", "--bus", "unixcan", "--channel", "names",
                                 "--count", "0", "--timeout-ms", "20000", "--lossless"],
                                stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    py = unixcan.UnixCanBus("names", lossless=True)
    try:
        deadline = time.monotonic() + 20
        while len(list(folder.iterdir())) < 3:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        names = {p.name for p in folder.iterdir()}
        tail = WIRE.lossless_mark + WIRE.socket_suffix
        assert f"{listener.pid}-{sock_tag()}0{WIRE.socket_suffix}" in names
        assert f"{lossless.pid}-{sock_tag()}0{tail}" in names
        assert re.fullmatch(rf"{os.getpid()}-{WIRE.python_tag}\d+{re.escape(tail)}",
                            Path(py.socket_path).name)
        assert {n for n in names if WIRE.is_lossless(n)} == {
            n for n in names if n.endswith(tail)} and sum(map(WIRE.is_lossless, names)) == 2
    finally:
        py.shutdown()
        for p in (listener, lossless):
            p.terminate()
            p.communicate(timeout=10)


def sock_tag() -> str:
    return str(DESCRIPTION["socket"]["c_tag"])


@pytest.fixture
def bus_dir(monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A fresh unixcan base with a short path (a socket address holds 108 bytes)."""
    path = Path(tempfile.mkdtemp(prefix="ucw-", dir="/tmp"))
    monkeypatch.setenv("UNIXCAN_DIR", str(path))
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.mark.parametrize("ident, data, fd, brs", [
    (0x321, bytes(range(1, 9)), False, False),
    (0x10, b"", False, False),
    (0x1234567, bytes([0xA5, 0x5A, 3]), False, False),
    (0x2A0, bytes(range(64)), True, True),
    (0x2A1, bytes(range(13)), True, False),  # padded to the FD length 16
])
def test_a_c_node_sends_the_bytes_a_python_node_sends(bus_dir: Path, ident: int, data: bytes,
                                                      fd: bool, brs: bool) -> None:
    folder = unixcan.channel_dir("wire")
    raw = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        raw.bind(str(folder / f"raw{WIRE.socket_suffix}"))
        raw.settimeout(10)
        args = ["--id", hex(ident), "--data", data.hex()] + ["--fd"] * fd + ["--brs"] * brs
        subprocess.run([tool(), "send", "--bus", "unixcan", "--channel", "wire", *args],
                       capture_output=True, text=True, timeout=30, check=True,
                       env=dict(os.environ))
        from_c = raw.recv(WIRE.fd_size + 1)
    finally:
        raw.close()
    msg = can.Message(arbitration_id=ident, is_extended_id=ident > WIRE.sff_mask, data=data,
                      is_fd=fd, bitrate_switch=brs)
    from_python = unixcan.pack_frame(msg)
    assert from_c == from_python
    assert len(from_c) == (WIRE.fd_size if fd else WIRE.classic_size)
    back = unixcan.unpack_frame(from_c, 0.0, "wire")
    assert back is not None and back.arbitration_id == ident and back.is_fd == fd
    assert back.bitrate_switch == brs and bytes(back.data[:len(data)]) == data
