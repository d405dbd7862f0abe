"""Verdicts only on data that exists (rig.results.verdict): a criterion whose window the
capture does not hold, or a run metric of a run that did not reach its end, is not
evaluated; a window the capture holds is evaluated as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hiltest_support import Synthetic

from rig import scenario as sc
from rig.data import capture
from rig.results import report, verdict

PLANNED = 2000  # a scenario of 0.2 s


def _capture(tmp: Path, n: int) -> capture.Capture:
    """A capture of periods 0 .. n - 1 with a constant 1.5° position error."""
    syn = Synthetic(n=n, error_deg=lambda t: np.full_like(t, 1.5))
    plant, fw = syn.write(tmp)
    cap, loss = capture.build(tmp / "cap", capture.default_specs(plant, fw), pole_pairs=2)
    assert loss.ok and (cap.first_period, cap.n) == (0, n)
    return cap


def _crit(window: tuple[float, float], metric: str = "pos_err_max_deg",
          limit: float = 2.0, xfail: str = "") -> sc.Criterion:
    return sc.Criterion("c", metric, window, limit, xfail=xfail)


def test_a_window_inside_a_partial_capture_is_evaluated(tmp_path: Path) -> None:
    cap = _capture(tmp_path, 800)  # the run stopped after period 799 (a crash)
    cov = verdict.Coverage(PLANNED, 0, 799, reached_end=False, why="crash: fw_host")
    c = verdict.evaluate_one(_crit((0.01, 0.0799)), cap, {}, cov)
    assert c["outcome"] == "pass" and abs(c["value"] - 1.5) < 1e-3, c
    c = verdict.evaluate_one(_crit((0.01, 0.0799), limit=1.0), cap, {}, cov)
    assert c["outcome"] == "fail"


def test_a_window_past_the_capture_is_not_evaluated_never_passed(tmp_path: Path) -> None:
    cap = _capture(tmp_path, 800)
    cov = verdict.Coverage(PLANNED, 0, 799, reached_end=False, why="crash: fw_host")
    for window in ((0.01, 0.2), (0.0, 0.08), (0.1, 0.15)):
        for xfail in ("", "measured 3°: reason"):
            c = verdict.evaluate_one(_crit(window, xfail=xfail), cap, {}, cov)
            assert (c["outcome"], c["passed"], c["value"]) == ("not_evaluated", False, None)
            assert "not fully captured" in c["note"] and "0 .. 799" in c["note"]
            assert "crash: fw_host" in c["note"]


def test_the_end_of_the_scenario_is_its_last_planned_period(tmp_path: Path) -> None:
    # [t0, "end"] asks for the periods up to duration/Ts - 1: a whole run holds them
    cap = _capture(tmp_path, PLANNED)
    whole = verdict.Coverage(PLANNED, 0, PLANNED - 1, reached_end=True)
    assert whole.window_periods(0.05, 0.2) == (500, PLANNED - 1)
    assert verdict.evaluate_one(_crit((0.05, 0.2)), cap, {}, whole)["outcome"] == "pass"


def test_run_metrics_need_the_run_to_reach_its_end() -> None:
    counters = {"capture.lost": 0.0, "firmware.fault_code": 0.0}
    for metric in ("capture_lost", "firmware.fault_code"):
        crit = sc.Criterion("r", metric, (0.0, 0.2), 0.0, "==")
        cut = verdict.Coverage(PLANNED, 0, 799, reached_end=False, why="interrupted")
        c = verdict.evaluate_one(crit, None, counters, cut)
        assert c["outcome"] == "not_evaluated" and "did not reach its end" in c["note"]
        done = verdict.Coverage(PLANNED, None, None, reached_end=True, why="capture loss")
        assert verdict.evaluate_one(crit, None, counters, done)["outcome"] == "pass"


def test_no_capture_leaves_every_window_not_evaluated() -> None:
    cov = verdict.Coverage(PLANNED, None, None, reached_end=False, why="interrupted")
    c = verdict.evaluate_one(_crit((0.0, 0.01)), None, {}, cov)
    assert c["outcome"] == "not_evaluated" and "no capture (interrupted)" in c["note"]


def test_report_shows_not_evaluated_as_its_own_outcome() -> None:
    cov = verdict.Coverage(PLANNED, None, None, reached_end=False, why="interrupted")
    c = verdict.evaluate_one(_crit((0.0, 0.2)), None, {}, cov)
    text = report.scenario_report({"scenario": "s", "passed": False, "criteria": [c]})
    assert "**NOT EVALUATED**" in text and "no capture (interrupted)" in text
    md = report.suite_report({"suite": "x", "passed": False, "scenarios": [
        {"name": "s", "dir": "s", "passed": False, "status": "interrupted", "criteria": [c]}]})
    assert "1 not evaluated" in md


def _cost_columns(n: int, first: int, journalled: range) -> dict[str, np.ndarray]:
    """The ISR's cost columns of rig.target_m4.cost: period k costs 1000 + k instructions,
    of which `estimate` 600 + k, NaN where the period was not journalled."""
    from rig.target_m4 import cost

    periods = np.array(list(journalled))
    inst = 1000 + periods
    steps = np.stack([400 + 0 * periods, 600 + periods], axis=1)
    return cost.IsrCosts(periods, inst, steps, ("entry", "estimate")).columns(first, n)


def test_the_isr_cost_is_read_from_its_columns_with_its_steps(tmp_path: Path) -> None:
    """Median and worst over the window's periods, each with its steps (the worst: the
    steps of the worst period); a period of the window that was not replayed is no data."""
    cap = _capture(tmp_path, 800)
    cov = verdict.Coverage(PLANNED, 0, 799, reached_end=True)
    extra = _cost_columns(cap.n, cap.first_period, range(100, 300))
    med = verdict.evaluate_one(_crit((0.01, 0.02), "isr_instructions_median", 1e9), cap, {},
                               cov, extra=extra)
    assert med["value"] == 1150 and med["unit"] == "instructions"
    assert med["detail"] == {"entry": 400, "estimate": 750}
    worst = verdict.evaluate_one(_crit((0.01, 0.02), "isr_instructions_max", 1e9), cap, {},
                                 cov, extra=extra)
    assert worst["value"] == 1200 and worst["detail"] == {"entry": 400, "estimate": 800}
    short = verdict.evaluate_one(_crit((0.01, 0.035), "isr_instructions_max", 1e9), cap, {},
                                 cov, extra=extra)
    assert short["value"] is None and short["outcome"] == "fail"  # (period 300 missing)


def test_a_run_on_a_bus_leaves_the_isr_cost_out(tmp_path: Path) -> None:
    from rig.results.result import RunResult
    from rig.run import evaluation

    cap = _capture(tmp_path, 800)
    cov = verdict.Coverage(800, 0, 799, reached_end=True)
    s = sc.Scenario("x", tmp_path / "x.toml", "x", "paper", 0.08, criteria=(
        _crit((0.0, 0.05)), sc.Criterion("cost", "isr_instructions_max", (0.01, 0.02),
                                         float("nan"), "report", better="lower")))
    on_bus = RunResult(tmp_path)
    evaluation.judge(on_bus, s, cap, cov, None, on_bench=False)
    assert [c["name"] for c in on_bus.criteria] == ["c"]
    assert on_bus.left_out and on_bus.left_out[0]["name"] == "cost"
    assert on_bus.passed and "left_out" in on_bus.to_json()
    # on the bench without the image: not evaluated, which fails the run, and says why
    on_bench = RunResult(tmp_path)
    evaluation.judge(on_bench, s, cap, cov, None, extra_missing="no Cortex-M4F image")
    c = on_bench.criteria[1]
    assert c["outcome"] == "not_evaluated" and "no Cortex-M4F image" in c["note"]
    assert not on_bench.passed
