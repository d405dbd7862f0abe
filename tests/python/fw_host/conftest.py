"""Fixtures of the fw_host tests (helpers in fwhost_support.py, imported from this folder)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from rig import bus as rigbus

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fwhost_support import READY_TIMEOUT_S, FwProcess, Peer, StartFw, fw_binary


@pytest.fixture
def start_fw(transport: str, channel: str, tmp_path: Path) -> Iterator[StartFw]:
    """Starts fw_host on the test's channel; waits for its ready file."""
    binary = fw_binary()
    procs: list[FwProcess] = []

    def start(*args: str, console: bool = False, wait: bool = True) -> FwProcess:
        n = len(procs)
        ready = tmp_path / f"fw{n}.ready"
        argv = [str(binary), "--bus", transport, "--channel", channel,
                "--ready-file", str(ready), *args]
        if not console and "--pty-link" not in args:
            argv.append("--no-console")
        err_path = tmp_path / f"fw{n}.stderr"
        with err_path.open("wb") as err:
            proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err,
                                    env=dict(os.environ))
        fw = FwProcess(proc, err_path, argv)
        procs.append(fw)
        if wait:
            deadline = time.monotonic() + READY_TIMEOUT_S
            while not ready.exists():
                if proc.poll() is not None:
                    raise AssertionError(f"fw_host exited ({proc.returncode}):\n{fw.stderr()}")
                if time.monotonic() > deadline:
                    raise AssertionError(f"fw_host not ready:\n{fw.stderr()}")
                time.sleep(0.01)
        return fw

    yield start
    for fw in procs:
        if fw.proc.poll() is None:
            fw.proc.kill()
            fw.proc.wait()


@pytest.fixture
def peer(transport: str, channel: str) -> Iterator[Peer]:
    """Opened before fw_host starts, so it is on the bus from the first frame."""
    bus = rigbus.open_bus(transport, channel)
    try:
        yield Peer(bus)
    finally:
        bus.shutdown()
