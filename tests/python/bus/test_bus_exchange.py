"""Frame exchange between C and Python nodes on each available transport.

Natively only unixcan is available; inside the VM (`rig vm -- pytest -m vcan`) the same
tests also run on SocketCAN vcan0.
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from waits import EVENT_S, wait_until

from rig import _paths
from rig import bus as rigbus

pytestmark = pytest.mark.vcan


def tool() -> str:
    return str(_paths.binary("hilbus_tool"))


def start_c_node(mode: str, transport: str, channel: str, tmp_path: Path,
                 *extra: str) -> subprocess.Popen[str]:
    ready = tmp_path / f"{mode}-{time.monotonic_ns()}.ready"
    proc = subprocess.Popen([tool(), mode, "--bus", transport, "--channel", channel,
                             "--ready-file", str(ready), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + EVENT_S
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            err = proc.stderr.read() if proc.stderr else ""
            raise RuntimeError(f"hilbus_tool {mode} did not start: {err}")
        time.sleep(0.005)
    return proc


def json_lines(text: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


@pytest.fixture
def py_bus(transport: str, channel: str) -> Iterator[can.BusABC]:
    b = rigbus.open_bus(transport, channel)
    yield b
    b.shutdown()


def frames(n: int) -> list[can.Message]:
    out = []
    for i in range(n):
        fd = i % 2 == 1
        size = 64 if fd else 8
        out.append(can.Message(arbitration_id=0x100 + i % 16, is_extended_id=False, is_fd=fd,
                               data=bytes((i + k) % 256 for k in range(size))))
    return out


def test_python_to_python(transport: str, channel: str) -> None:
    a = rigbus.open_bus(transport, channel)
    b = rigbus.open_bus(transport, channel)
    try:
        sent = frames(400)
        got: list[can.Message] = []
        for start in range(0, len(sent), 8):  # in chunks a receive queue always holds
            for m in sent[start:start + 8]:
                a.send(m)
            for _ in range(8):
                g = b.recv(timeout=EVENT_S)
                assert g is not None, f"frame {len(got)} not received"
                got.append(g)
        assert [(g.arbitration_id, g.is_fd, bytes(g.data)) for g in got] == [
            (m.arbitration_id, m.is_fd, bytes(m.data)) for m in sent]
        assert b.recv(timeout=0.05) is None
    finally:
        a.shutdown()
        b.shutdown()


def test_c_to_python(transport: str, channel: str, py_bus: can.BusABC, tmp_path: Path) -> None:
    for fd, data in ((False, "0102030405060708"), (True, "aa" * 20)):
        args = ["--id", "0x321", "--data", data, "--count", "3"] + (["--fd"] if fd else [])
        out = subprocess.run([tool(), "send", "--bus", transport, "--channel", channel, *args],
                             capture_output=True, text=True, timeout=EVENT_S, check=True)
        stats = json_lines(out.stdout)[-1]["stats"]
        assert isinstance(stats, dict) and stats["tx_frames"] == 3 and stats["tx_drops"] == 0
        for _ in range(3):
            msg = py_bus.recv(timeout=EVENT_S)
            assert msg is not None and msg.arbitration_id == 0x321 and msg.is_fd == fd
            # FD payloads are padded to the next valid FD length (20 -> 20, exact here)
            assert bytes(msg.data).hex() == data


def test_python_to_c_with_filter(transport: str, channel: str, py_bus: can.BusABC,
                                 tmp_path: Path) -> None:
    recv = start_c_node("recv", transport, channel, tmp_path, "--count", "2",
                        "--timeout-ms", str(round(EVENT_S * 1e3)), "--filter", "7F0:7FF")
    py_bus.send(can.Message(arbitration_id=0x7E0, data=b"\x09", is_extended_id=False))
    py_bus.send(can.Message(arbitration_id=0x7F0, data=b"\x01\x02", is_extended_id=False))
    py_bus.send(can.Message(arbitration_id=0x7F0, data=bytes(range(12)), is_fd=True,
                            is_extended_id=False))
    out, _ = recv.communicate(timeout=2 * EVENT_S)
    lines = json_lines(out)
    got = [ln for ln in lines if "id" in ln]
    assert [(g["id"], g["fd"], g["data"]) for g in got] == [
        (0x7F0, False, "0102"), (0x7F0, True, bytes(range(12)).hex())]
    assert recv.returncode == 0


def test_c_to_c_ping_pong(transport: str, channel: str, tmp_path: Path) -> None:
    echo = start_c_node("echo", transport, channel, tmp_path)
    try:
        for fd in ([], ["--fd"]):
            out = subprocess.run([tool(), "ping", "--bus", transport, "--channel", channel,
                                  "--count", "2000", "--window", "4", *fd],
                                 capture_output=True, text=True, timeout=60)
            res = json_lines(out.stdout)[-1]
            assert out.returncode == 0, out.stderr
            assert res["received"] == 2000 and res["lost"] == 0
    finally:
        echo.send_signal(signal.SIGTERM)
        echo.wait(timeout=5)


def test_receive_timeout(transport: str, channel: str, py_bus: can.BusABC,
                         tmp_path: Path) -> None:
    # the time-out is waited (a loaded machine may take longer: the ceiling only ends a hang)
    t0 = time.monotonic()
    assert py_bus.recv(timeout=0.2) is None
    assert 0.19 <= time.monotonic() - t0 < EVENT_S
    t0 = time.monotonic()
    out = subprocess.run([tool(), "recv", "--bus", transport, "--channel", channel,
                          "--count", "1", "--timeout-ms", "200"],
                         capture_output=True, text=True, timeout=EVENT_S)
    assert out.returncode == 3  # time-out, documented exit status
    assert 0.19 <= time.monotonic() - t0 < EVENT_S


def test_killed_node_does_not_block_others(transport: str, channel: str, py_bus: can.BusABC,
                                           tmp_path: Path) -> None:
    victim = start_c_node("recv", transport, channel, tmp_path, "--count", "0",
                          "--timeout-ms", "100000")
    listener = rigbus.open_bus(transport, channel)
    try:
        victim.kill()
        victim.wait(timeout=EVENT_S)
        for i in range(50):  # (a send that blocked on the dead node would never return)
            py_bus.send(can.Message(arbitration_id=0x10, data=bytes([i]), is_extended_id=False))
        got = []
        # every frame either reaches the listener or is counted as dropped by the sender
        def dropped() -> int:
            return int(py_bus.stats["tx_drops"]) if transport == "unixcan" else 0  # type: ignore[attr-defined]

        deadline = time.monotonic() + EVENT_S
        while len(got) + dropped() < 50 and time.monotonic() < deadline:
            if (g := listener.recv(timeout=0.1)) is not None:
                got.append(g.data[0])
        assert listener.recv(timeout=0.2) is None  # and nothing more
        # in order, and every frame the listener missed was counted by the sender
        assert got == sorted(got) and len(set(got)) == len(got)
        if transport == "unixcan":
            stats = py_bus.stats  # type: ignore[attr-defined]
            assert stats["peers_removed"] == 1 and stats["tx_errors"] == 0
            assert len(got) + stats["tx_drops"] == 50
        else:
            assert len(got) == 50
    finally:
        listener.shutdown()


def test_full_receiver_is_a_counted_drop(transport: str, channel: str, tmp_path: Path) -> None:
    """A receiver that stops reading loses frames, and every lost frame is counted."""
    n = 2000
    recv = start_c_node("recv", transport, channel, tmp_path, "--count", "0",
                        "--timeout-ms", "1000")
    recv.send_signal(signal.SIGSTOP)
    try:
        out = subprocess.run([tool(), "send", "--bus", transport, "--channel", channel,
                              "--id", "0x42", "--fd", "--data", "11" * 64,
                              "--count", str(n)], capture_output=True, text=True, timeout=30)
        sender = json_lines(out.stdout)[-1]["stats"]
    finally:
        recv.send_signal(signal.SIGCONT)
    rout, _ = recv.communicate(timeout=15)
    lines = json_lines(rout)
    received = sum(1 for ln in lines if "id" in ln)
    receiver = lines[-1]["stats"]
    assert isinstance(sender, dict) and isinstance(receiver, dict)
    assert received < n
    # unixcan counts at the sender, SocketCAN at the receiving socket (SO_RXQ_OVFL)
    dropped = int(sender["tx_drops"]) + int(receiver["rx_overflows"])
    assert received + dropped == n


def test_python_filters(transport: str, channel: str) -> None:
    """Only matching frames come out; on unixcan the rest never become Messages."""
    a = rigbus.open_bus(transport, channel)
    b = rigbus.open_bus(transport, channel,
                        can_filters=[{"can_id": 0x300, "can_mask": 0x7F0, "extended": False}])
    try:
        # one frame at a time: the kernel queues ~10 datagrams per socket, and on a loaded
        # machine a burst can outrun b's reader thread (a counted drop, not this test's topic)
        got = []
        for i in range(32):
            a.send(can.Message(arbitration_id=0x300 + i, data=bytes([i]), is_extended_id=False))
            if i < 16:
                m = b.recv(timeout=EVENT_S)
                got.append(None if m is None else m.arbitration_id)
            elif transport == "unixcan":
                wait_until(lambda i=i: b.stats["rx_filtered"] == i - 15,  # type: ignore[attr-defined]
                           "the filter counting the frame")
        assert got == list(range(0x300, 0x310))
        assert b.recv(timeout=0.5) is None
        if transport == "unixcan":
            assert a.stats["tx_drops"] == 0  # type: ignore[attr-defined]
            assert b.stats["rx_filtered"] == 16  # type: ignore[attr-defined]
    finally:
        a.shutdown()
        b.shutdown()


def _unixcan_only(transport: str) -> None:
    if transport != "unixcan":
        pytest.skip("lossless nodes and per-listener drops are the fallback bus's")


def test_a_c_sender_waits_for_a_python_lossless_node(transport: str, channel: str) -> None:
    """A lossless Python node whose buffer is full: the C sender waits, nothing is dropped."""
    _unixcan_only(transport)
    n = 3000
    py = rigbus.open_bus(transport, channel, lossless=True, receive_buffer=16)
    try:
        sender = subprocess.Popen([tool(), "send", "--bus", transport, "--channel", channel,
                                   "--id", "0x42", "--fd", "--data", "11" * 64,
                                   "--count", str(n)],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(0.3)  # (not a wait for an event: the time the sender meets a full node)
        got = 0
        while got < n and py.recv(timeout=EVENT_S) is not None:
            got += 1
        out, err = sender.communicate(timeout=60)
    finally:
        py.shutdown()
    stats = json_lines(out)[-1]["stats"]
    assert isinstance(stats, dict)
    assert sender.returncode == 0, err
    assert got == n
    assert stats["tx_drops"] == 0 and stats["tx_stall_failures"] == 0
    assert stats["tx_stalls"] > 0 and stats["tx_stall_ms_max"] > 0


def test_a_python_sender_waits_for_a_c_lossless_node(transport: str, channel: str,
                                                     tmp_path: Path) -> None:
    _unixcan_only(transport)
    n = 500
    recv = start_c_node("recv", transport, channel, tmp_path, "--count", str(n),
                        "--timeout-ms", "20000", "--lossless")
    py = rigbus.open_bus(transport, channel)
    recv.send_signal(signal.SIGSTOP)
    resume = threading.Timer(0.3, recv.send_signal, (signal.SIGCONT,))
    resume.start()
    try:
        for i in range(n):
            py.send(can.Message(arbitration_id=0x43, data=i.to_bytes(2, "little"),
                                is_extended_id=False))
        stats = dict(py.stats)  # type: ignore[attr-defined]
    finally:
        resume.join()
        recv.send_signal(signal.SIGCONT)
        py.shutdown()
    out, _ = recv.communicate(timeout=30)
    frames = [ln for ln in json_lines(out) if "id" in ln]
    assert [int(str(f["data"])[2:4] + str(f["data"])[:2], 16) for f in frames] == list(range(n))
    assert stats["tx_drops"] == 0 and stats["tx_stalls"] > 0


def test_a_lossless_node_that_takes_nothing_fails_the_send_naming_it(
        transport: str, channel: str, tmp_path: Path) -> None:
    """The wait is bounded: it ends in an error naming the node (its socket, its pid)."""
    _unixcan_only(transport)
    from rig.bus.unixcan_wire import WIRE

    recv = start_c_node("recv", transport, channel, tmp_path, "--count", "0",
                        "--timeout-ms", "60000", "--lossless")
    recv.send_signal(signal.SIGSTOP)
    py = rigbus.open_bus(transport, channel)
    try:
        t0 = time.monotonic()
        with pytest.raises(can.CanOperationError) as failed:
            for i in range(200):
                py.send(can.Message(arbitration_id=0x44, data=bytes([i % 256]),
                                    is_extended_id=False))
        waited = time.monotonic() - t0
        stats = dict(py.stats)  # type: ignore[attr-defined]
    finally:
        recv.send_signal(signal.SIGCONT)
        recv.terminate()
        recv.communicate(timeout=10)
        py.shutdown()
    message = str(failed.value)
    assert f"node {recv.pid}-0{WIRE.lossless_mark}{WIRE.socket_suffix} (pid {recv.pid})" in \
        message and "loses no frame" in message, message
    assert WIRE.lossless_stall_s * 0.99 <= waited < WIRE.lossless_stall_s + EVENT_S
    assert stats["tx_stall_failures"] == 1 and stats["tx_drops"] == 0


def test_a_listener_that_falls_behind_is_counted_by_name(transport: str, channel: str,
                                                         tmp_path: Path) -> None:
    """Listeners (no lossless mark) may miss frames, as on SocketCAN; each sender counts what
    it dropped for each of them by socket name: a C listener under a Python sender, a
    listener that never reads under a C sender."""
    _unixcan_only(transport)
    from rig.bus import unixcan

    recv = start_c_node("recv", transport, channel, tmp_path, "--count", "0",
                        "--timeout-ms", "60000")
    recv.send_signal(signal.SIGSTOP)
    py = rigbus.open_bus(transport, channel, lossless=True)
    try:
        for i in range(200):
            py.send(can.Message(arbitration_id=0x45, data=bytes([i]), is_extended_id=False))
        drops = dict(py.listener_drops)  # type: ignore[attr-defined]
        tx_drops = py.stats["tx_drops"]  # type: ignore[attr-defined]
    finally:
        recv.send_signal(signal.SIGCONT)
        recv.terminate()
        recv.communicate(timeout=10)
        py.shutdown()
    assert drops == {f"{recv.pid}-0.sock": tx_drops} and tx_drops > 100
    # a C sender and a listener that never reads (a bare socket of the channel)
    import socket as so

    deaf = so.socket(so.AF_UNIX, so.SOCK_DGRAM)
    deaf.bind(str(unixcan.channel_dir(channel) / "deaf.sock"))
    try:
        out = subprocess.run([tool(), "send", "--bus", transport, "--channel", channel,
                              "--id", "0x46", "--count", "100", "--data", "01"],
                             capture_output=True, text=True, timeout=60, check=True)
    finally:
        deaf.close()
    stats = json_lines(out.stdout)[-1]["stats"]
    assert isinstance(stats, dict)
    assert stats["listener_drops"] == {"deaf.sock": stats["tx_drops"]} and stats["tx_drops"] > 50
