"""python-can's own tools work on the unixcan interface (entry point `can.interface`)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can


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
        deadline = time.monotonic() + 20
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
            time.sleep(0.3)
        finally:
            bus.shutdown()
            os.environ.pop("UNIXCAN_DIR", None)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
    text = log.read_text()
    assert "123#DEAD" in text
    assert "456##" in text and bytes(range(16)).hex().upper() in text
