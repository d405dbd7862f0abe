"""python-can's own tools work on the unixcan interface (entry point `can.interface`)."""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest
from waits import EVENT_S, ceiling


def test_interface_is_registered() -> None:
    from can.interfaces import BACKENDS

    assert "unixcan" in BACKENDS


def test_can_logger_records_unixcan(tmp_path: Path) -> None:
    env = dict(os.environ, UNIXCAN_DIR=str(tmp_path / "uc"))
    log = tmp_path / "capture.log"
    # can.logger stops on KeyboardInterrupt: give it SIGINT's default disposition even when
    # the tests run as a background job (which starts with SIGINT ignored)
    proc = subprocess.Popen([sys.executable, "-m", "can.logger", "-i", "unixcan", "-c", "logch",
                             "--fd", "-f", str(log)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        chan_dir = tmp_path / "uc" / "logch"
        deadline = time.monotonic() + EVENT_S
        while not (chan_dir.is_dir() and any(chan_dir.glob("*.sock"))):
            assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            assert time.monotonic() < deadline, "can.logger did not join the channel"
            time.sleep(0.05)
        os.environ["UNIXCAN_DIR"] = env["UNIXCAN_DIR"]
        bus = can.Bus(interface="unixcan", channel="logch")
        try:
            bus.send(can.Message(arbitration_id=0x123, data=b"\xde\xad", is_extended_id=False))
            bus.send(can.Message(arbitration_id=0x456, data=bytes(range(16)), is_fd=True,
                                 is_extended_id=False))
            # (not a wait for an event: can.logger shows nothing of a frame until it closes its
            # file, and frames it has not read when SIGINT comes are lost, so it gets time,
            # generous and scaled like every ceiling)
            time.sleep(ceiling(3.0))
        finally:
            bus.shutdown()
            os.environ.pop("UNIXCAN_DIR", None)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=EVENT_S)
    text = log.read_text()
    assert "123#DEAD" in text
    assert "456##" in text and bytes(range(16)).hex().upper() in text


def _stalled_receiver(folder: Path) -> socket.socket:
    """A node that never reads (a stopped process): its socket in the channel folder."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.bind(str(folder / f"{os.getpid()}-stalled.sock"))
    return s


def test_drops_are_reported_when_a_python_node_shuts_down(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    """Issue 25: a replay with can.player to a python-can receiver lost 481 of 60 000 frames
    without a word. The sender counted them (stats["tx_drops"]); now it says so when it
    shuts down (logger can.unixcan, a warning)."""
    monkeypatch.setenv("UNIXCAN_DIR", str(tmp_path / "uc"))
    bus = can.Bus(interface="unixcan", channel="drops")
    stalled = _stalled_receiver(tmp_path / "uc" / "drops")
    try:
        for k in range(300):
            bus.send(can.Message(arbitration_id=0x100 + k % 16, data=bytes(8),
                                 is_extended_id=False))
    finally:
        with caplog.at_level(logging.WARNING, logger="can.unixcan"):
            bus.shutdown()
        stalled.close()
    drops = bus.stats["tx_drops"]
    assert drops > 0
    assert f"{drops} deliveries of the 300 frames sent were dropped" in caplog.text


def test_can_player_says_how_many_frames_it_could_not_deliver(tmp_path: Path) -> None:
    log = tmp_path / "replay.log"
    writer = can.Logger(str(log))
    for k in range(2000):
        writer(can.Message(timestamp=1.0 + k * 1e-4, arbitration_id=0x123, data=bytes(8),
                           is_extended_id=False, channel="x"))
    writer.stop()
    env = dict(os.environ, UNIXCAN_DIR=str(tmp_path / "uc"))
    (tmp_path / "uc" / "replay").mkdir(parents=True, mode=0o700)
    (tmp_path / "uc").chmod(0o700)
    stalled = _stalled_receiver(tmp_path / "uc" / "replay")
    try:
        done = subprocess.run([sys.executable, "-m", "can.player", "-i", "unixcan", "-c",
                               "replay", "--ignore-timestamps", str(log)], env=env,
                              capture_output=True, text=True, timeout=120)
    finally:
        stalled.close()
    assert done.returncode == 0, done.stderr
    assert "deliveries of the 2000 frames sent were dropped" in done.stderr, done.stderr
