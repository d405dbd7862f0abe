"""The fallback bus with a bit clock (``rig bus arbiter``, issue 37.4): classic frames take
their bit times one at a time, the lowest identifier first, from C and Python senders alike;
CAN FD frames (the virtual wires) pass as before. Frame lengths against hand counts and the
CRC's check value; timing only as lower bounds (a loaded machine delivers late, never early).
"""

from __future__ import annotations

import os
import random
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from waits import EVENT_S, wait_until

from rig import _paths
from rig.bus import arbiter, bittime, load, unixcan

SLOW = 200  # bit/s: a frame takes 0.3-0.7 s, far longer than any scheduling delay


# -- frame lengths -------------------------------------------------------------------------

def test_crc15_gives_the_catalogue_check_value() -> None:
    # CRC-15/CAN over the ASCII bytes "123456789": 0x059E (the CRC catalogue's check value)
    bits = [b for c in b"123456789" for b in bittime._bits(c, 8)]
    assert bittime.crc15(bits) == 0x059E


def test_a_frame_of_zeros_counted_by_hand() -> None:
    # id 0, no data: SOF, 11 id bits, RTR, IDE, r0, DLC (4) and the CRC of zeros (15): 34
    # zeros, a stuff bit after every 5 (6), then 13 unstuffed bits: 53
    assert bittime.frame_bits(0, b"") == 53


def test_exact_lengths_lie_between_no_stuffing_and_the_worst_case() -> None:
    rng = random.Random(374)
    for _ in range(5000):
        n = rng.randint(0, 8)
        data = bytes(rng.getrandbits(8) for _ in range(n))
        for extended, ident in ((False, rng.getrandbits(11)), (True, rng.getrandbits(29))):
            bits = bittime.frame_bits(ident, data, extended=extended)
            unstuffed = len(bittime.stuffed_part(ident, data, extended=extended)) + 13
            assert unstuffed <= bits <= load.frame_bits(n, extended)


# -- the bit clock on a channel ------------------------------------------------------------

@pytest.fixture
def channel(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    base = tmp_path_factory.mktemp("unixcan")
    base.chmod(0o700)
    old = os.environ.get("UNIXCAN_DIR")
    os.environ["UNIXCAN_DIR"] = str(base)
    try:
        yield "clocked"
    finally:
        if old is None:
            os.environ.pop("UNIXCAN_DIR", None)
        else:
            os.environ["UNIXCAN_DIR"] = old


@pytest.fixture
def clock(channel: str) -> Iterator[arbiter.Arbiter]:
    c = arbiter.Arbiter(channel, SLOW)
    stop = threading.Event()
    t = threading.Thread(target=c.run, args=(stop,), daemon=True)
    t.start()
    yield c
    stop.set()
    t.join(timeout=5)
    c.close()


def _bus(channel: str) -> can.BusABC:
    return unixcan.UnixCanBus(channel=channel)


def _classic(ident: int, fill: int = 0) -> can.Message:
    return can.Message(arbitration_id=ident, data=bytes([fill] * 8), is_extended_id=False)


def _bits(ident: int, fill: int = 0) -> int:
    return bittime.frame_bits(ident, bytes([fill] * 8))


def test_frames_take_the_bus_in_priority_order_each_for_its_bits(
        channel: str, clock: arbiter.Arbiter) -> None:
    rx, tx = _bus(channel), _bus(channel)
    try:
        t0 = time.monotonic()
        tx.send(_classic(0x7FF))  # takes the idle bus
        wait_until(lambda: clock.stats.started == 1, "0x7FF on the wire")
        tx.send(_classic(0x200, 0x55))  # both wait for it; 0x100 wins the next arbitration
        tx.send(_classic(0x100, 0xFF))
        tx.send(can.Message(arbitration_id=0x300, data=bytes(64), is_fd=True,
                            is_extended_id=False))  # a virtual wire: not on the clock
        tx.send(_classic(0x200, 0x55))  # its mailbox still full: refused, counted
        got = []
        while len(got) < 4:
            m = rx.recv(timeout=EVENT_S + 3.0)
            assert m is not None, got
            got.append((m.arbitration_id, time.monotonic() - t0))
        assert [i for i, _ in got] == [0x300, 0x7FF, 0x100, 0x200]
        # never earlier than the bits of the frames before and including each
        ends = 0.0
        for ident, fill, (_, at) in zip((0x7FF, 0x100, 0x200), (0, 0xFF, 0x55), got[1:],
                                        strict=True):
            ends += _bits(ident, fill) / SLOW
            assert at >= ends, (hex(ident), at, ends)
        assert tx.recv(timeout=0.2) is None  # the sender does not hear its own frames
        assert clock.stats.frames == 3 and sum(clock.stats.overruns.values()) == 1
        assert clock.stats.malformed == 0
    finally:
        rx.shutdown()
        tx.shutdown()


def test_a_c_node_sends_its_classic_frames_through_the_clock(
        channel: str, clock: arbiter.Arbiter, tmp_path: Path) -> None:
    rx = _bus(channel)
    try:
        t0 = time.monotonic()
        for args in (["--id", "0x300", "--count", "3"],  # 2 refused: one mailbox per id
                     ["--id", "0x301", "--fd", "--data", "00" * 64]):
            done = subprocess.run([str(_paths.binary("hilbus_tool")), "send", "--bus",
                                   "unixcan", "--channel", channel, *args],
                                  capture_output=True, text=True, timeout=60,
                                  env={**os.environ})
            assert done.returncode == 0, done.stderr
        got = []
        while len(got) < 2:
            m = rx.recv(timeout=EVENT_S + 3.0)
            assert m is not None, got
            got.append((m.arbitration_id, m.is_fd, time.monotonic() - t0))
        assert rx.recv(timeout=1.0) is None
        assert sorted((i, fd) for i, fd, _ in got) == [(0x300, False), (0x301, True)]
        classic_at = next(at for i, _, at in got if i == 0x300)
        assert classic_at >= bittime.frame_bits(0x300, b"") / SLOW
        assert clock.stats.frames == 1 and sum(clock.stats.overruns.values()) == 2
        assert all(":0x300" in k for k in clock.stats.overruns)
    finally:
        rx.shutdown()


def test_one_clock_per_channel(channel: str, clock: arbiter.Arbiter) -> None:
    with pytest.raises(arbiter.ArbiterError, match="has a bit clock already"):
        arbiter.Arbiter(channel, SLOW)


def test_a_dead_clocks_socket_is_taken_over(channel: str) -> None:
    first = arbiter.Arbiter(channel, SLOW)
    first._sock.close()  # died without removing its socket
    assert first.path.exists()
    second = arbiter.Arbiter(channel, SLOW)
    try:
        assert second.path.exists()
    finally:
        second.close()


def test_a_sender_that_waited_for_the_clock_is_still_known_to_it(channel: str) -> None:
    """More frames than the clock's socket queues (net.unix.max_dgram_qlen) before it runs:
    the sender waits for it (it is lossless), and the frames it sent while waiting still come
    from its own socket, so none is delivered back to it."""
    qlen = int(Path("/proc/sys/net/unix/max_dgram_qlen").read_text())
    ids = [0x100 + k for k in range(qlen + 5)]
    clock = arbiter.Arbiter(channel, 100_000)
    rx, tx = _bus(channel), _bus(channel)
    stop = threading.Event()
    runner = threading.Thread(target=clock.run, args=(stop,), daemon=True)
    try:
        sender = threading.Thread(target=lambda: [tx.send(_classic(i)) for i in ids],
                                  daemon=True)
        sender.start()
        sender.join(timeout=0.5)
        assert sender.is_alive()  # waiting for the clock, whose queue is full
        runner.start()
        sender.join(timeout=EVENT_S)
        assert not sender.is_alive()
        got = []
        while len(got) < len(ids):
            m = rx.recv(timeout=EVENT_S)
            assert m is not None, got
            got.append(m.arbitration_id)
        assert sorted(got) == ids
        assert tx.recv(timeout=0.5) is None  # nothing came back to the sender
        assert clock.stats.frames == len(ids) and not clock.stats.overruns
    finally:
        stop.set()
        if runner.is_alive():
            runner.join(timeout=5)
        clock.close()
        rx.shutdown()
        tx.shutdown()


def test_a_c_sender_that_waited_for_the_clock_is_still_known_to_it(channel: str) -> None:
    """The same from C (hilbus): one identifier, more frames than the clock's queue holds,
    sent before it runs; every frame beyond the first is an overrun of that C node's own
    mailbox, the ones it sent while it waited too."""
    qlen = int(Path("/proc/sys/net/unix/max_dgram_qlen").read_text())
    clock = arbiter.Arbiter(channel, 100_000)
    stop = threading.Event()
    runner = threading.Thread(target=clock.run, args=(stop,), daemon=True)
    proc = subprocess.Popen([str(_paths.binary("hilbus_tool")), "send", "--bus", "unixcan",
                             "--channel", channel, "--id", "0x300", "--count", str(qlen + 5)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(0.5)  # (if it is not waiting yet, the check below holds all the same)
        runner.start()
        _, err = proc.communicate(timeout=EVENT_S)
        assert proc.returncode == 0, err
        deadline = time.monotonic() + EVENT_S
        while clock.stats.frames < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert clock.stats.frames == 1
        assert sum(clock.stats.overruns.values()) == qlen + 4
        assert [k.split("-", 1)[0] for k in clock.stats.overruns] == [str(proc.pid)]
    finally:
        stop.set()
        if runner.is_alive():
            runner.join(timeout=5)
        clock.close()
        if proc.poll() is None:
            proc.kill()
