"""Verdicts only on data that exists, end to end (issue 15.2): plant_rt and fw_host on the
bus in lockstep, one of them killed mid-run or the rig interrupted with Ctrl-C. The run
fails (exit 1, or 130 for Ctrl-C), and no criterion whose window the capture does not hold
is reported as passed: it is ``not_evaluated`` with the reason, in result.json and
report.md."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import scenario_text

from rig.data import capture

DURATION = 3.0
SCENARIO = scenario_text.scenario(
    "closed loop on the ideal plant, cut short by the test", profile="ideal",
    duration=DURATION, speed=[scenario_text.ramp(300.0, 0.2)],
    criteria=[
        scenario_text.criterion("early window", "pos_err_max_deg", (0.0, 0.05),
                                comparison="report"),
        scenario_text.criterion("no polarity loss", "polarity_loss_count", (0.1, "end"), 0,
                                "=="),
        scenario_text.criterion(
            "known failure over the whole run", "pos_err_max_deg", (0.5, "end"), 0.0,
            xfail="a limit nothing meets: an XFAIL must not stand in for missing data either"),
        scenario_text.criterion("no capture loss", "capture_lost", limit=0, comparison="=="),
    ])

# the plant's trace is written in 1 MiB blocks of BENCH_TRUTH + BENCH_TRUTH_MAG records: the
# kill comes once two blocks are on disk (about 1.5 s of the 3 s simulated)
KILL_AFTER_BYTES = 2 << 20


def _start(tmp: Path, channel: str) -> tuple[subprocess.Popen[str], Path]:
    path = tmp / "cut.toml"
    path.write_text(SCENARIO)
    out = tmp / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rig", "run", str(path), "--bus", "unixcan", "--channel",
         channel, "--out", str(out), "--no-record", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=dict(os.environ))
    return proc, out


def _wait_for(path: Path, size: int, proc: subprocess.Popen[str], timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not (path.exists() and path.stat().st_size >= size):
        assert proc.poll() is None, proc.communicate()[0]
        assert time.monotonic() < deadline, f"{path} never reached {size} bytes"
        time.sleep(0.01)


def _check_verdicts(data: dict[str, Any]) -> None:
    """Every criterion outside the captured periods is not evaluated; none of those passes."""
    cap = data.get("capture") or {}
    whole = all(m["missing"] == m["duplicates"] == m["outside"] == m["bad_length"] == 0
                for m in cap.get("messages", []))
    held = (cap["first_period"], cap["last_period"]) if cap and whole else None
    by_name = {c["name"]: c for c in data["criteria"]}
    assert set(by_name) == {"early window", "no polarity loss",
                            "known failure over the whole run", "no capture loss"}
    for name in ("no polarity loss", "known failure over the whole run", "no capture loss"):
        c = by_name[name]
        assert (c["outcome"], c["passed"], c["value"]) == ("not_evaluated", False, None), c
        assert c["note"].startswith("not evaluated: "), c
    early = by_name["early window"]
    p1 = round(0.05 / capture.TS)
    if held is not None and held[0] == 0 and held[1] >= p1:
        assert early["outcome"] == "pass" and early["value"] is not None, early
    else:
        assert early["outcome"] == "not_evaluated", early
    assert data["passed"] is False


@pytest.mark.parametrize("victim", ["plant_rt", "fw_host"])
def test_a_killed_program_leaves_its_windows_not_evaluated(tmp_path: Path, channel: str,
                                                           victim: str) -> None:
    proc, out = _start(tmp_path, channel)
    _wait_for(out / "plant.trace", KILL_AFTER_BYTES, proc)
    ready = out / ("plant.ready" if victim == "plant_rt" else "fw.ready")
    os.kill(int(ready.read_text()), signal.SIGKILL)
    text, _ = proc.communicate(timeout=60)
    assert proc.returncode == 1, text
    data = json.loads((out / "result.json").read_text())
    assert data["status"] == "failed"
    assert data["failure"]["kind"] == "crash" and data["failure"]["child"] == victim
    _check_verdicts(data)
    assert "NOT EVALUATED" in text
    md = (out / "report.md").read_text()
    assert md.count("**NOT EVALUATED**") >= 3 and "did not reach its end" in md
    row = next(x for x in md.splitlines() if x.startswith("| no polarity loss |"))
    assert row.endswith("| **NOT EVALUATED** |") and "| — " in row, row


def test_ctrl_c_leaves_every_criterion_not_evaluated(tmp_path: Path, channel: str) -> None:
    proc, out = _start(tmp_path, channel)
    _wait_for(out / "plant.trace", KILL_AFTER_BYTES, proc)
    proc.send_signal(signal.SIGINT)
    text, _ = proc.communicate(timeout=60)
    assert proc.returncode == 130, text
    data = json.loads((out / "result.json").read_text())
    assert data["status"] == "interrupted"
    _check_verdicts(data)
    assert data["criteria"][0]["outcome"] == "not_evaluated"  # no capture after Ctrl-C
    assert all("interrupted" in c["note"] for c in data["criteria"])
