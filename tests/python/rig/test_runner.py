"""The runner end to end over a real bus (unixcan), with stand-in programs for plant and
firmware (tests/python/rig/standins): pacing, exact event timing, capture, verdict, files,
and the failure paths (capture loss, crash, kill, Ctrl-C)."""

from __future__ import annotations

import itertools
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import rerun as rr
import scenario_text
from waits import EVENT_S, RUN_S

from rig import scenario as sc
from rig.results import recording, verdict
from rig.results.result import RunResult
from rig.run import runner
from rig.run.execution import TS
from rig.run.plan import Plan
from rig.run.suite import evaluate_comparison


def _tiny(duration: float, mean_limit: float) -> str:
    return scenario_text.scenario(
        "tiny closed loop for the runner's tests", profile="ideal", duration=duration,
        speed=[scenario_text.ramp(200.0, 0.1)],
        load=[{"at": 0.12, "kind": "step", "torque": 0.2}],
        # the Python stand-ins start slowly inside the (emulated) VM
        other="[run]\nready_timeout_s = 120.0\n",
        criteria=[
            scenario_text.criterion("position error", "pos_err_max_deg", (0.05, "end"), 0.6),
            scenario_text.criterion("error is the stand-in's offset", "pos_err_mean_deg",
                                    (0.05, "end"), mean_limit, ">="),
            scenario_text.criterion("no capture loss", "capture_lost", limit=0,
                                    comparison="=="),
        ])


def _scenario(tmp: Path, name: str = "tiny", duration: float = 0.2,
              mean_limit: float = 0.49) -> Path:
    p = tmp / f"{name}.toml"
    p.write_text(_tiny(duration, mean_limit))
    return p


def _alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _ready_pid(path: Path, timeout: float = EVENT_S) -> int:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.02)
    return int(path.read_text())


def test_plan_grants_end_on_breakpoints() -> None:
    s = sc.parse_scenario(Path("plan.toml"), _tiny(0.35, 0))
    plan = Plan.build(s)
    grants = plan.grants()
    assert grants[0][0] == 0 and grants[-1][1] == 3500
    assert all(b - a <= 1000 for a, b in grants)
    assert all(g[1] == h[0] for g, h in itertools.pairwise(grants))
    starts = {a for a, _ in grants}
    assert {0, 1000, 1200} <= starts  # ramp end (0.1 s) and load step (0.12 s)
    assert plan.load_events[1200].torque == 0.2


def test_live_view_in_process_streams_the_telemetry_and_changes_no_value(
        tmp_path: Path) -> None:
    """``--live`` on ``--bus inproc`` (it printed "no live view" and ran without): the same
    decimated telemetry as on the bus, from the bench's outbox; every value as without it."""
    s = sc.load_scenario(Path(__file__).parents[3] / "rig" / "scenarios" / "smoke.toml")
    live_rec = rr.RecordingStream("live_test")  # stands in for a spawned viewer
    live_rec.save(tmp_path / "live.rrd")
    with_live = runner.run_scenario(s, runner.RunOptions(
        out=tmp_path / "live", bus="inproc", progress=False, record=False, live=True,
        live_stream=live_rec))
    recording._finalize(live_rec)
    without = runner.run_scenario(s, runner.RunOptions(
        out=tmp_path / "plain", bus="inproc", progress=False, record=False))
    assert with_live.passed and without.passed
    assert [(c["name"], c["value"]) for c in with_live.to_json()["criteria"]] == \
        [(c["name"], c["value"]) for c in without.to_json()["criteria"]]
    assert with_live.counters["rig.live_frames_dropped"] == 0
    rows = recording.entity_rows(tmp_path / "live.rrd")
    # TLM_* at 1 kHz of simulated time, one sample per 100 periods: 0.5 s of smoke
    per_entity = round(s.duration / (100 * TS))
    for entity in ("position", "speed", "current", "params", "torque", "speed_ref",
                   "speed_true", "torque_true", "error"):  # error: estimate against truth
        assert rows[f"live/{entity}"] == per_entity, entity


def test_scenario_runs_and_writes_every_output(with_fakes: Path, channel: str,
                                               tmp_path: Path) -> None:
    s = sc.load_scenario(_scenario(tmp_path))
    out = tmp_path / "out"
    live_rec = rr.RecordingStream("live_test")  # stands in for a spawned viewer
    live_rec.save(tmp_path / "live.rrd")
    r = runner.run_scenario(s, runner.RunOptions(out=out, bus="unixcan", channel=channel,
                                                 progress=False, live=True,
                                                 live_stream=live_rec))
    assert r.passed, r.explain()
    recording._finalize(live_rec)
    live_rows = recording.entity_rows(tmp_path / "live.rrd")
    # TLM_POS at 1 kHz of simulated time, decimated to one sample per 100 periods
    assert 15 <= live_rows["live/position"] <= 21 and 15 <= live_rows["live/speed"] <= 21
    data = json.loads((out / "result.json").read_text())
    assert data == json.loads(json.dumps(r.to_json()))
    for key in ("scenario", "profile", "bus", "channel", "mode", "status", "passed", "criteria",
                "counters", "capture", "recording", "timing", "versions"):
        assert key in data, key
    assert (data["scenario"], data["bus"], data["channel"], data["mode"]) == (
        "tiny", "unixcan", channel, "lockstep")
    for c in data["criteria"]:
        assert set(c) >= {"name", "metric", "window", "value", "limit", "passed"}
    # the stand-in firmware's estimate is off by exactly 0.5 deg
    assert r.criterion("position error")["value"] == pytest.approx(0.5, abs=1e-3)
    # every period captured once; the plant's and the firmware's own counts agree
    assert data["capture"]["periods"] == 2000 and data["capture"]["lost"] == 0
    assert data["counters"]["plant.periods"] == 2000
    assert data["counters"]["firmware.isr"] >= 1999
    assert data["timing"]["grants"] == len(Plan.build(s).grants())
    # the load step reached the plant exactly at period 1200 (t = 0.12 s)
    assert r.capture is not None
    tl = np.asarray(r.capture["truth.tl"])
    assert np.all(tl[:1200] == 0.0) and np.all(tl[1200:] == np.float32(0.2))
    # the speed reference column is the scenario's ramp
    ref = np.asarray(r.capture["speed_ref_rpm"])
    assert ref[500] == pytest.approx(100.0) and ref[1500] == pytest.approx(200.0)
    rows = recording.entity_rows(out / "recording.rrd")
    assert rows["position/error"] == 200 and rows["speed/rpm"] == 200  # display: 1 kHz
    assert rows[recording.EVIDENCE_ENTITY] == 1500  # pos_err_deg over [0.05 s, end]
    assert data["recording"]["evidence"] == {"pos_err_deg": [[500, 2000]]}
    assert data["recording"]["bytes"] == (out / "recording.rrd").stat().st_size
    assert "# tiny: PASS" in (out / "report.md").read_text()
    assert "fake plant" not in (out / "plant_rt.stderr.log").read_text()
    again = RunResult.load(out)
    assert again.metric("pos_err_max_deg", (0.05, 0.2)) == pytest.approx(0.5, abs=1e-3)


def test_capture_loss_fails_the_run(with_fakes: Path, channel: str, tmp_path: Path) -> None:
    s = sc.load_scenario(_scenario(tmp_path, duration=0.15))
    r = runner.run_scenario(s, runner.RunOptions(
        out=tmp_path / "out", bus="unixcan", channel=channel, progress=False, record=False,
        env={"FAKE_PLANT_DROP": "500,501"}))
    assert not r.passed and r.status == "failed"
    assert r.failure.kind == "capture_loss"
    # two periods, two plant messages each
    assert "4 missing period records" in r.failure.message
    assert r.counters["capture.lost"] == 4
    assert not r.criterion("no capture loss")["passed"]
    assert runner.exit_code(r.passed, r.status) == 1


def test_failing_criterion_reports_its_value(with_fakes: Path, channel: str,
                                             tmp_path: Path) -> None:
    s = sc.load_scenario(_scenario(tmp_path, duration=0.15, mean_limit=0.6))
    r = runner.run_scenario(s, runner.RunOptions(out=tmp_path / "out", bus="unixcan",
                                                 channel=channel, progress=False, record=False))
    assert r.status == "failed" and r.failure is None
    bad = r.failed_criteria()
    assert [c["name"] for c in bad] == ["error is the stand-in's offset"]
    assert bad[0]["value"] == pytest.approx(0.5, abs=1e-3)
    assert "FAIL error is the stand-in's offset" in r.explain()


def test_lost_grant_is_sent_again(with_fakes: Path, channel: str, tmp_path: Path) -> None:
    s = sc.load_scenario(_scenario(tmp_path, duration=0.15))
    r = runner.run_scenario(s, runner.RunOptions(
        out=tmp_path / "out", bus="unixcan", channel=channel, progress=False, record=False,
        env={"FAKE_PLANT_LOSE_STEP": "2"}))
    assert r.passed, r.explain()
    assert r.counters["rig.grant_resends"] == 1
    assert r.counters["plant.steps"] == r.timing.grants + 1


def test_stalled_lockstep_fails_with_the_period(with_fakes: Path, channel: str,
                                                tmp_path: Path) -> None:
    s = sc.load_scenario(_scenario(tmp_path, duration=0.15))
    t0 = time.monotonic()
    r = runner.run_scenario(s, runner.RunOptions(
        out=tmp_path / "out", bus="unixcan", channel=channel, progress=False, record=False,
        stall_s=0.8, env={"FAKE_PLANT_FREEZE_AT": "700"}))
    assert time.monotonic() - t0 < EVENT_S  # (a stall never noticed would hang here)
    assert r.status == "failed" and r.failure.kind == "stall"
    assert "plant at period 700, granted 1000" in r.failure.message


def test_realtime_mode(with_fakes: Path, channel: str, tmp_path: Path) -> None:
    """A real-time run follows the wall clock and accounts for every period.

    The stand-in firmware is Python: on a machine loaded by other tests it can fall behind
    the wall clock and miss periods, or join the bus only after the plant's clock has run
    past the criteria's windows (real time waits for nobody). Those are real-time failures
    the rig must report, not hide: either the capture is complete and the criteria are
    judged, or the run fails with the loss counted exactly, or with the criteria whose
    windows the capture does not hold not evaluated.
    (Loss detection itself is tested deterministically in test_capture.py; the plant's
    late-update and overrun counting in tests/python/plant_program/test_realtime.py.)
    """
    s = sc.load_scenario(_scenario(tmp_path, duration=0.15))
    r = runner.run_scenario(s, runner.RunOptions(out=tmp_path / "out", bus="unixcan",
                                                 channel=channel, realtime=True,
                                                 progress=False, record=False,
                                                 env={"FAKE_RT_SCALE": "0.2"}))
    assert r.mode == "realtime"
    assert r.counters["plant.periods"] >= 1500
    cap = r.capture_loss
    missing = sum(m["missing"] for m in cap["messages"])
    assert cap["lost"] == missing + cap["short_end"]
    window = (500, 1499)  # the criteria's window [0.05, 0.15] s in periods
    if cap["lost"] == 0 and cap["first_period"] <= window[0] <= window[1] <= cap["last_period"]:
        assert r.criterion("position error")["passed"], r.explain()
        return
    assert r.status == "failed", r.explain()
    if cap["lost"]:  # periods missing inside the capture
        assert r.failure.kind == "capture_loss", r.explain()
        assert f"{cap['lost']} missing" in r.failure.message
        return
    c = r.criterion("position error")
    assert c["outcome"] == "not_evaluated" and not c["passed"], r.explain()
    assert f"the capture holds periods {cap['first_period']} .. {cap['last_period']}" \
        in c["note"], r.explain()
    if cap["last_period"] < window[1]:  # the stand-in firmware fell behind and stopped short
        assert r.failure.kind == "capture_loss", r.explain()
        assert f"the capture ends at period {cap['last_period']}" in r.failure.message
    # else its trace starts after the window began: it joined the bus late


# A rig that missed a crash or a kill would notice only when the lockstep stalls (its stall
# time-out without progress); one that watches its children ends within ~0.3 s of CPU, 1-2.5 s
# of wall time on a loaded 2-core machine. The rig under test gets a stall time-out of
# LONG_STALL_S (rig.link.clock.STALL_S, 10 s, set before the run's options are imported), so
# half of it tells the two apart on any machine, however slow.
LONG_STALL_S = RUN_S
PROMPT_S = LONG_STALL_S / 2
RIG_WITH_LONG_STALL = ("import sys; import rig.link.clock as clock; "
                       "clock.STALL_S = float(sys.argv.pop(1)); "
                       "from rig.cli import main; sys.exit(main())")


def _rig(args: list[str], env_extra: dict[str, str]) -> subprocess.Popen[str]:
    env = dict(os.environ, **env_extra)
    return subprocess.Popen([sys.executable, "-c", RIG_WITH_LONG_STALL, str(LONG_STALL_S),
                             "run", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_firmware_crash_ends_the_run_before_the_stall_timeout(with_fakes: Path, channel: str,
                                               tmp_path: Path) -> None:
    path = _scenario(tmp_path, duration=1.0)
    out = tmp_path / "out"
    proc = _rig([str(path), "--bus", "unixcan", "--channel", channel, "--out", str(out)],
                {"FAKE_FW_CRASH_AT": "3000"})
    text, _ = proc.communicate(timeout=LONG_STALL_S + EVENT_S)
    t_end = time.time()
    assert proc.returncode == 1, text
    crash = re.search(r"injected crash at period 3000 \(t=([0-9.]+)\)",
                      (out / "fw_host.stderr.log").read_text())
    assert crash is not None
    assert t_end - float(crash.group(1)) < PROMPT_S
    assert "fw_host: exited unexpectedly (exit status 3)" in text
    assert "injected crash at period 3000" in text  # the log tail
    data = json.loads((out / "result.json").read_text())
    assert data["failure"]["kind"] == "crash" and data["failure"]["child"] == "fw_host"
    assert not _alive(int((out / "plant.ready").read_text()))


@pytest.mark.parametrize("target", ["plant", "rig"])
def test_kill_mid_run_ends_before_the_stall_timeout(with_fakes: Path, channel: str, tmp_path: Path,
                                     target: str) -> None:
    path = _scenario(tmp_path, duration=5.0)
    out = tmp_path / "out"
    proc = _rig([str(path), "--bus", "unixcan", "--channel", channel, "--out", str(out)], {})
    plant_pid = _ready_pid(out / "plant.ready")
    fw_pid = _ready_pid(out / "fw.ready")
    time.sleep(0.7)  # mid-run
    t0 = time.monotonic()
    if target == "plant":
        os.kill(plant_pid, signal.SIGKILL)
    else:
        proc.send_signal(signal.SIGINT)  # Ctrl-C
    text, _ = proc.communicate(timeout=LONG_STALL_S + EVENT_S)
    elapsed = time.monotonic() - t0
    print(f"ended {elapsed:.3f} s after the {target} event")
    assert elapsed < PROMPT_S, text
    data = json.loads((out / "result.json").read_text())
    if target == "plant":
        assert proc.returncode == 1
        assert "plant_rt: exited unexpectedly (killed by SIGKILL)" in text
        assert data["failure"]["child"] == "plant_rt"
    else:
        assert proc.returncode == 130
        assert data["status"] == "interrupted"
    for pid in (plant_pid, fw_pid):
        deadline = time.monotonic() + EVENT_S
        while _alive(pid) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not _alive(pid)


def test_missing_programs_are_an_environment_error(tmp_path: Path, channel: str,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HIL_BIN_DIR", str(tmp_path / "empty"))
    monkeypatch.setattr("rig._paths._installed_pkg_dir", lambda: None)
    monkeypatch.setattr("rig._paths._PKG", tmp_path / "nopkg")
    s = sc.load_scenario(_scenario(tmp_path, duration=0.15))
    r = runner.run_scenario(s, runner.RunOptions(out=tmp_path / "out", bus="unixcan",
                                                 channel=channel, progress=False))
    assert r.status == "error" and r.failure.kind == "environment"
    assert "plant_rt not found" in r.failure.message
    assert runner.exit_code(r.passed, r.status) == 3


def test_suite_writes_one_folder_per_scenario_and_a_summary(
    with_fakes: Path, channel: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    from rig.cli import main as rig_main

    _scenario(tmp_path, "good", duration=0.15)
    _scenario(tmp_path, "bad", duration=0.15, mean_limit=0.7)
    suite = tmp_path / "mini.toml"
    suite.write_text('description = "two tiny runs"\nscenarios = ["good", "bad"]\n')
    out = tmp_path / "out"
    code = rig_main(["run", str(suite), "--bus", "unixcan", "--channel", channel,
                     "--out", str(out), "--quiet", "--no-record"])
    assert code == 1
    summary = json.loads((out / "result.json").read_text())
    assert summary["suite"] == "mini" and summary["passed"] is False and summary["complete"]
    by = {s["name"]: s for s in summary["scenarios"]}
    assert by["good"]["passed"] and not by["bad"]["passed"]
    assert by["bad"]["failed_criteria"] == ["error is the stand-in's offset"]
    for name in ("good", "bad"):
        assert json.loads((out / name / "result.json").read_text())["scenario"] == name
    assert "[bad](bad/report.md) | **FAIL**" in (out / "report.md").read_text()
    err = capsys.readouterr().err
    assert "suite mini: FAIL (1/2 passed)" in err


@pytest.mark.vcan
def test_scenario_over_socketcan(with_fakes: Path, tmp_path: Path) -> None:
    from rig import bus as rigbus

    if not rigbus.kernel_has_can():
        pytest.skip("this kernel has no CAN (run inside the VM: rig vm -- pytest -m vcan)")
    chan = "vcan0"
    if not rigbus.interface_exists(chan):
        if os.geteuid() != 0:
            pytest.skip(f"{chan} does not exist and creating it needs root")
        rigbus.vcan_up(chan)
    s = sc.load_scenario(_scenario(tmp_path, duration=0.15))
    r = runner.run_scenario(s, runner.RunOptions(out=tmp_path / "out", bus="socketcan",
                                                 channel=chan, progress=False, record=False))
    assert r.bus == "socketcan"
    assert r.passed, r.explain()
    assert r.capture_loss["periods"] == 1500


def test_xfail_xpass_and_report_outcomes() -> None:
    from rig.results import report

    counters = {"rig.x": 3.0}
    fail = sc.Criterion("a", "rig.x", (0.0, 1.0), 1.0)
    xfail = sc.Criterion("b", "rig.x", (0.0, 1.0), 1.0, xfail="measured 3: reason")
    xpass = sc.Criterion("c", "rig.x", (0.0, 1.0), 5.0, xfail="measured 6 once: reason")
    rep = sc.Criterion("d", "rig.x", (0.0, 1.0), float("nan"), "report")
    whole = verdict.Coverage.whole(10000)
    out = [verdict.evaluate_one(c, None, counters, whole) for c in (fail, xfail, xpass, rep)]
    assert [verdict.outcome(c) for c in out] == ["fail", "xfail", "xpass", "pass"]
    assert out[3]["limit"] is None and out[3]["value"] == 3.0
    res = RunResult(Path("."), criteria=out)
    assert [c["name"] for c in res.failed_criteria()] == ["a"]
    assert [c["name"] for c in res.expected_failures()] == ["b", "c"]
    text = report.scenario_report({"scenario": "s", "criteria": out})
    assert "XFAIL" in text and "XPASS" in text and "measured 3: reason" in text
    entries = [
        {"name": "table2_1000rpm_2nm@paper", "dir": "t", "profile": "paper", "passed": True,
         "status": "passed", "criteria": [
             {"name": "e", "metric": "pos_err_max_deg", "value": 1.25, "limit": 2.5,
              "comparison": "<=", "outcome": "pass"},
             {"name": "r", "metric": "pos_err_rms_deg", "value": 0.5, "limit": 1.5,
              "comparison": "<=", "outcome": "xpass", "xfail": "why"}]},
        {"name": "fig06_2000rpm", "dir": "f", "profile": "paper", "figure": "Fig. 6",
         "passed": False, "status": "failed", "failed_criteria": ["e"], "criteria": [
             {"name": "e", "metric": "pos_err_max_deg", "value": 3.0, "limit": 2.0,
              "comparison": "<=", "outcome": "fail"}], "recording": "recording.rrd"},
    ]
    md = report.suite_report({"suite": "paper", "passed": False, "scenarios": entries})
    assert md.index("## Table 2") < md.index("### profile `paper`") < md.index("## Fig. 6")
    assert "| 1000 | 2 | 1.25 | 0.5 (XPASS) |" in md
    assert "rig view f" in md and "**FAIL**" in md


def test_suite_comparison_outcomes() -> None:
    def entry(name: str, value: float | None) -> dict[str, object]:
        return {"name": name, "criteria": [{"name": "drop", "value": value, "unit": "%"}]}

    cmp = sc.Comparison("a drops less", "drop", "a", "b", "<")
    r = evaluate_comparison(cmp, [entry("a", 18.0), entry("b", 21.8)])
    assert (r["outcome"], r["value_a"], r["value_b"], r["unit"]) == ("pass", 18.0, 21.8, "%")
    assert evaluate_comparison(cmp, [entry("a", 21.8), entry("b", 18.0)])["outcome"] \
        == "fail"
    # a criterion without a value fails it; a run missing from an interrupted suite, or a
    # criterion that was not evaluated, leaves it not evaluated (never a pass)
    assert evaluate_comparison(cmp, [entry("a", None), entry("b", 1.0)])["outcome"] \
        == "fail"
    assert evaluate_comparison(cmp, [entry("b", 1.0)])["outcome"] == "not_evaluated"
    unseen = {"name": "a", "criteria": [{"name": "drop", "value": None,
                                         "outcome": "not_evaluated"}]}
    r = evaluate_comparison(cmp, [unseen, entry("b", 1.0)])
    assert (r["outcome"], r["passed"]) == ("not_evaluated", False)
    assert "no value from a" in r["note"]
    known = sc.Comparison("a drops less", "drop", "a", "b", "<", xfail="measured 30 vs 20")
    assert evaluate_comparison(known, [entry("a", 30.0), entry("b", 20.0)])["outcome"] \
        == "xfail"
    assert evaluate_comparison(known, [entry("a", 1.0), entry("b", 20.0)])["outcome"] \
        == "xpass"
