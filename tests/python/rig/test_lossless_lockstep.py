"""Issue 36.5: a lockstep run on the fallback bus loses nothing under overload; a listener may
fall behind, and the run says which listener missed how many frames; ``--can-log`` records
what crossed the bus and says which kind of log it is.

End to end on unixcan, `rig run` as a program. Overload is made certain by stopping
processes (SIGSTOP): a stopped node is the limit of a slow one. Before, a node whose queue
stayed full for 2 ms lost the frame: the rig's own node missed frames it should have heard,
and the report said of a listener only "1 other node, listening only".
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import can
import pytest

from rig.bus import unixcan
from rig.bus.unixcan_wire import WIRE

SCENARIO = "table2_1000rpm_1nm"  # 1.8 s simulated: a few seconds on the bus


def _run(out: Path, channel: str, *extra: str, scenario: str = SCENARIO
         ) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "rig", "run", scenario, "--bus", "unixcan", "--channel", channel,
         "--out", str(out), "--quiet", "--no-record", "--no-figures", "--baseline", "off",
         *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=dict(os.environ))


def _result(proc: subprocess.Popen[str], out: Path) -> tuple[int, str, dict[str, Any]]:
    text, _ = proc.communicate(timeout=600)
    return proc.returncode, text, json.loads((out / "result.json").read_text())


def _wait_for(path: Path, proc: subprocess.Popen[str], timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert proc.poll() is None, proc.communicate()[0]
        assert time.monotonic() < deadline, f"{path} never came"
        time.sleep(0.005)


def _child_pid(parent: int, name: str) -> int:
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            comm, fields = stat[stat.index("(") + 1:stat.rindex(")")], stat.rsplit(")", 1)[1]
            if comm == name[:15] and int(fields.split()[1]) == parent:
                return int(entry.name)
    raise AssertionError(f"no {name} child of {parent}")


def _values(data: dict[str, Any]) -> dict[str, Any]:
    return {c["name"]: c["value"] for c in data["criteria"]}


def test_stopped_nodes_make_the_lockstep_wait_and_lose_nothing(tmp_path: Path,
                                                               channel: str) -> None:
    """The rig and then fw_host are stopped for 0.3 s each mid-run: the others wait for them
    (no frame dropped, no stall failure), every frame a node sent reached the rig, and the
    verdict and every value are the in-process run's."""
    out = tmp_path / "bus"
    proc = _run(out, channel)
    _wait_for(out / "fw.ready", proc)
    fw = _child_pid(proc.pid, "fw_host")
    time.sleep(0.5)  # into the closed loop
    for pid in (proc.pid, fw):
        os.kill(pid, signal.SIGSTOP)
        time.sleep(0.3)
        os.kill(pid, signal.SIGCONT)
    code, text, data = _result(proc, out)
    assert code == 0, text
    c = data["counters"]
    for node in ("plant", "firmware", "rig.bus"):
        assert c[f"{node}.tx_drops"] == 0 and c[f"{node}.tx_stall_failures"] == 0, node
    assert c["plant.tx_stall_ms_max"] > 100 or c["firmware.tx_stall_ms_max"] > 100
    for key, heard in c.items():  # the rig heard every frame of every message it listens to
        if key.startswith("rig.rx."):
            name = key.removeprefix("rig.rx.")
            sent = c.get(f"plant.tx.{name}", c.get(f"firmware.tx.{name}"))
            assert heard == sent, (name, heard, sent)
    assert data["bus_report"]["lockstep"]["failures"] == 0
    inproc = tmp_path / "inproc"
    code, text, ref = _result(_run(inproc, channel, "--bus", "inproc"), inproc)
    assert code == 0, text
    # every value of the bus run is the in-process run's; the bus run leaves out only the
    # ISR's cost, measured in process alone (result.json's left_out says so)
    left = {x["name"] for x in data.get("left_out") or []}
    assert left == {c["name"] for c in ref["criteria"]
                    if str(c["metric"]).startswith("isr_instructions")}
    assert _values(data) == {k: v for k, v in _values(ref).items() if k not in left}


def test_a_listener_that_falls_behind_is_named_with_what_it_missed(tmp_path: Path,
                                                                   channel: str) -> None:
    """A can.logger on the channel, stopped for the whole run: it misses frames (as it would
    on SocketCAN), the run passes untouched, and result.json and the report say which
    listener (its pid and command) missed how many of the frames the run's nodes sent."""
    logger = subprocess.Popen([sys.executable, "-m", "can.logger", "-i", "unixcan", "-c",
                               channel, "--fd", "-f", str(tmp_path / "bus.log")],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not unixcan.live_nodes(channel):
            assert logger.poll() is None, logger.communicate()[1]
            assert time.monotonic() < deadline, "can.logger never joined the channel"
            time.sleep(0.05)
        logger.send_signal(signal.SIGSTOP)
        out = tmp_path / "run"
        code, text, data = _result(_run(out, channel, scenario="smoke"), out)
    finally:
        logger.send_signal(signal.SIGCONT)
        logger.terminate()
        logger.communicate(timeout=30)
    assert code == 0, text
    report = data["bus_report"]
    (listener,) = report["listeners"]
    assert listener["pid"] == logger.pid and "can.logger" in listener["who"]
    assert listener["node"] == f"{logger.pid}-{WIRE.python_tag}0{WIRE.socket_suffix}"
    sent = report["frames_sent"]
    c = data["counters"]
    assert sent == c["plant.tx_frames"] + c["firmware.tx_frames"] + c["rig.bus.tx_frames"]
    # it took at most what its queue and its buffer held before it stopped
    assert sent - 1000 < listener["missed"] < sent
    assert listener["missed"] == sum(listener["missed_by_sender"].values())
    assert listener["missed_by_sender"]["plant"] == c["plant.tx_drops"]
    text = (out / "report.md").read_text()
    assert f"missed {listener['missed']:,} of the {sent:,} frames the run's nodes sent" in text
    assert f"pid {logger.pid}" in text and "can.logger" in text


@pytest.mark.parametrize("fmt", ["log", "asc"])
def test_can_log_records_every_frame_that_crossed_the_bus(tmp_path: Path, channel: str,
                                                          fmt: str) -> None:
    """``--can-log``: every frame each node sent, by identity, is in the live log (counted
    against the nodes' own counts), which says it is a live capture; the log rebuilt from
    the traces by ``rig export`` says that it is."""
    out = tmp_path / "run"
    code, text, data = _result(_run(out, channel, "--can-log", fmt, "--keep-all",
                                    scenario="smoke"), out)
    assert code == 0, text
    log = data["bus_report"]["can_log"]
    assert log["kind"] == "live capture" and log["missed"] == 0
    path = out / f"bus.{fmt}"
    reader = can.CanutilsLogReader(path) if fmt == "log" else can.ASCReader(path)
    frames = list(reader)
    assert len(frames) == log["frames"] == data["bus_report"]["frames_sent"]
    c = data["counters"]
    by_id: dict[int, int] = {}
    for m in frames:
        by_id[m.arbitration_id] = by_id.get(m.arbitration_id, 0) + 1
    from rig import protocols

    for db in ("drive", "vio", "bench"):
        for m in protocols.database(db).messages:
            sent = sum(c.get(f"{node}.tx.{m.name}", 0) for node in ("plant", "firmware", "rig"))
            assert by_id.get(m.frame_id, 0) == sent, m.name
    head = path.read_text()[:2000]
    if fmt == "asc":
        assert "// live capture: every frame on unixcan channel" in head
    assert "live capture" in (out / "report.md").read_text()
    rebuilt = tmp_path / "rebuilt.asc"
    done = subprocess.run([sys.executable, "-m", "rig", "export", str(out), "--can-log",
                           str(rebuilt)], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ))
    assert done.returncode == 0, done.stderr
    assert "rebuilt from the traces" in done.stdout
    assert "// rebuilt from the traces:" in rebuilt.read_text()[:2000]
