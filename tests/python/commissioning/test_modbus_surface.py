"""Issue 16.10 / 15.3: the virtual load bench answers only the register map's function codes
(exception 1 for any other, nothing about the server revealed), a read count of 0 or above
the Modbus limit is exception 3 with the request's function code, and it listens on the
loopback address only. Raw Modbus TCP frames, built here from the standard."""

from __future__ import annotations

import json
import socket
import struct
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_loadbench import Server, start_server

from rig import protocols
from rig.loadbench.server import ServeOptions, serve


@pytest.fixture
def srv(tmp_path: Path, unix_channel: str) -> Iterator[Server]:
    s = start_server(tmp_path, unix_channel)
    yield s
    s.proc.terminate()
    s.proc.wait(10)


def ask(port: int, pdu: bytes, tid: int = 1) -> bytes:
    """One request (MBAP header + PDU, unit 1); the response PDU."""
    with socket.create_connection(("127.0.0.1", port), timeout=5.0) as s:
        s.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu)
        head = b""
        while len(head) < 7:
            chunk = s.recv(7 - len(head))
            assert chunk, "connection closed without an answer"
            head += chunk
        rtid, proto, length, _unit = struct.unpack(">HHHB", head)
        assert (rtid, proto) == (tid, 0)
        body = b""
        while len(body) < length - 1:
            chunk = s.recv(length - 1 - len(body))
            assert chunk, "connection closed inside the answer"
            body += chunk
        return body


def map_function_codes() -> set[int]:
    regmap = json.loads((protocols.path("drive").parent / "modbus_load_bench.json").read_text())
    return {int(fc) for fc in regmap["function_codes"]}


@pytest.mark.parametrize("fc, payload", [
    (7, b""), (8, b"\x00\x00\x12\x34"), (11, b""), (12, b""), (17, b""),
    (20, b"\x07\x06\x00\x01\x00\x00\x00\x01"), (24, b"\x00\x00"), (43, b"\x0e\x01\x00"),
    (22, b"\x00\x01\xff\xff\x00\x00"), (1, b"\x00\x00\x00\x01"), (5, b"\x00\x00\xff\x00"),
])
def test_function_codes_outside_the_map_get_exception_1(srv: Server, fc: int,
                                                        payload: bytes) -> None:
    assert fc not in map_function_codes()
    assert ask(srv.port, bytes([fc]) + payload) == bytes([fc | 0x80, 1])


@pytest.mark.parametrize("fc, count", [(3, 0), (3, 126), (4, 0), (4, 126), (3, 2000)])
def test_a_read_count_outside_1_to_125_is_exception_3(srv: Server, fc: int, count: int) -> None:
    assert ask(srv.port, struct.pack(">BHH", fc, 0, count)) == bytes([fc | 0x80, 3])


def test_the_map_function_codes_work(srv: Server) -> None:
    assert map_function_codes() == {3, 4, 6, 16}
    got = ask(srv.port, struct.pack(">BHH", 3, 0, 1))  # map_version
    assert got[:2] == b"\x03\x02" and struct.unpack(">H", got[2:4])[0] >= 1
    assert ask(srv.port, struct.pack(">BHH", 4, 0, 1))[:2] == b"\x04\x02"
    assert ask(srv.port, struct.pack(">BHH", 6, 3, 7)) == struct.pack(">BHH", 6, 3, 7)
    assert ask(srv.port, struct.pack(">BHHBH", 16, 3, 1, 2, 8)) == struct.pack(">BHH", 16, 3, 1)


def test_it_listens_on_loopback_only(srv: Server) -> None:
    # the ready file names the address it bound; nothing answers on another local address
    host_addrs = {a[4][0] for a in socket.getaddrinfo(socket.gethostname(), None,
                                                      socket.AF_INET)} - {"127.0.0.1"}
    for addr in host_addrs:
        with pytest.raises(OSError):
            socket.create_connection((addr, srv.port), timeout=1.0).close()
    with pytest.raises(ValueError, match=r"127\.0\.0\.1"):
        serve(ServeOptions(host="0.0.0.0", port=0))
