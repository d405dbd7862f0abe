"""Issue 16.7: a run refuses a channel someone else sends on (exit 3, a clear message) instead
of two runs pacing each other; more nodes than a unixcan node reaches are named too. A node
that only listens (here hilbus_tool recv, a C node) is welcome (issue 25) and counted."""

from __future__ import annotations

import json
import socket
import subprocess
import time
import uuid
from pathlib import Path

import pytest
from waits import EVENT_S

from rig import _paths
from rig.bus import unixcan
from rig.cli import main as rig_main


def _channel() -> str:
    return f"fn{uuid.uuid4().hex[:8]}"


def test_a_node_listening_on_the_channel_is_welcome(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    channel = _channel()
    other = subprocess.Popen([str(_paths.binary("hilbus_tool")), "recv", "--bus", "unixcan",
                              "--channel", channel, "--count", "0", "--timeout-ms", "60000"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        folder = unixcan.base_dir() / channel
        deadline = time.monotonic() + EVENT_S
        while not list(folder.glob("*.sock")) and time.monotonic() < deadline:
            time.sleep(0.01)
        out = tmp_path / "run"
        code = rig_main(["run", "smoke", "--bus", "unixcan", "--channel", channel,
                         "--out", str(out), "--quiet", "--no-record"])
        err = capsys.readouterr().err
        assert code == 0, err
        result = json.loads((out / "result.json").read_text())
        assert result["passed"] and result["counters"]["rig.listeners.start"] == 1
    finally:
        other.kill()
        other.wait()


def test_more_nodes_than_a_node_reaches_are_reported(tmp_path: Path) -> None:
    channel = _channel()
    folder = unixcan.channel_dir(channel)
    socks = []
    try:
        for k in range(70):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            s.bind(str(folder / f"9{k:04d}-0.sock"))
            socks.append(s)
        out = tmp_path / "run"
        assert rig_main(["run", "smoke", "--bus", "unixcan", "--channel", channel,
                         "--out", str(out), "--quiet", "--no-record"]) == 3
        msg = json.loads((out / "result.json").read_text())["failure"]["message"]
        assert "70 other node(s)" in msg and "HILBUS_MAX_PEERS = " in msg
    finally:
        for s in socks:
            s.close()
