"""Property tests of the python-can plugin ``unixcan`` (Hypothesis): any message round-trips
through its datagram; any datagram is either a valid frame or None, never an exception; on a
live node arbitrary datagrams are delivered only when they are frames, the rest counted."""

from __future__ import annotations

import socket
import struct
import tempfile
from pathlib import Path

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.bus import unixcan

FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


@st.composite
def messages(draw: st.DrawFn) -> can.Message:
    ext = draw(st.booleans())
    fd = draw(st.booleans())
    n = draw(st.sampled_from(FD_LENGTHS) if fd else st.integers(0, 8))
    return can.Message(
        arbitration_id=draw(st.integers(0, 0x1FFFFFFF if ext else 0x7FF)),
        is_extended_id=ext, is_fd=fd, data=draw(st.binary(min_size=n, max_size=n)),
        bitrate_switch=fd and draw(st.booleans()),
        error_state_indicator=fd and draw(st.booleans()))


@settings(max_examples=400, deadline=None)
@given(messages())
def test_every_message_round_trips(msg: can.Message) -> None:
    datagram = unixcan.pack_frame(msg)
    assert len(datagram) == (72 if msg.is_fd else 16)
    back = unixcan.unpack_frame(datagram, 0.0, "c")
    assert back is not None
    assert back.equals(msg, timestamp_delta=None, check_channel=False, check_direction=False)


def valid(m: can.Message) -> bool:
    return (len(m.data) in FD_LENGTHS) if m.is_fd else len(m.data) <= 8


@settings(max_examples=600, deadline=None)
@given(st.one_of(st.binary(max_size=100), st.binary(min_size=72, max_size=72),
                 st.binary(min_size=16, max_size=16)))
def test_any_datagram_is_a_valid_frame_or_none(datagram: bytes) -> None:
    m = unixcan.unpack_frame(datagram, 0.0, "c")
    if len(datagram) not in (16, 72):
        assert m is None
    elif m is not None:
        assert valid(m) and m.is_fd == (len(datagram) == 72)


@pytest.fixture(scope="module")
def node() -> can.BusABC:
    import os

    base = Path(tempfile.mkdtemp(prefix="ucf-", dir="/tmp"))
    old = os.environ.get("UNIXCAN_DIR")
    os.environ["UNIXCAN_DIR"] = str(base)
    bus = can.Bus(interface="unixcan", channel="f")
    if old is None:
        os.environ.pop("UNIXCAN_DIR")
    else:
        os.environ["UNIXCAN_DIR"] = old
    yield bus
    bus.shutdown()
    import shutil

    shutil.rmtree(base, ignore_errors=True)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=90),
                          st.tuples(st.integers(0, 2**32 - 1), st.integers(0, 255),
                                    st.integers(0, 255), st.booleans()).map(
                              lambda t: struct.pack("<IBBBB", t[0], t[1], t[2], 0, 0)
                              + bytes(64 if t[3] else 8))),
                min_size=1, max_size=8))
def test_a_live_node_delivers_only_frames_and_counts_the_rest(
        node: can.BusABC, datagrams: list[bytes]) -> None:
    target = node.socket_path  # type: ignore[attr-defined]
    before = dict(node.stats)  # type: ignore[attr-defined]
    want = [unixcan.unpack_frame(d, 0.0, "f") for d in datagrams]
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    got: list[can.Message] = []
    try:
        for d in datagrams:
            s.sendto(d, target)
            while (m := node.recv(0.02)) is not None:
                got.append(m)
    finally:
        s.close()
    while (m := node.recv(0.05)) is not None:
        got.append(m)
    expected = [m for m in want if m is not None]
    assert len(got) == len(expected)
    for g, e in zip(got, expected, strict=True):
        assert g.equals(e, timestamp_delta=None, check_direction=False)
    stats = node.stats  # type: ignore[attr-defined]
    assert stats["rx_malformed"] - before["rx_malformed"] == len(datagrams) - len(expected)
