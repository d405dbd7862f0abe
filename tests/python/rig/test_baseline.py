"""Baselines (rig.regression.baseline): the band over seeds, the classification of a run's
values, the file round trip, what a record refuses, and a run judged against a baseline end
to end."""

from __future__ import annotations

import json
import math
import random
from pathlib import Path

import pytest
import scenario_text
from baseline_text import scaled

from rig import cli, scenario
from rig.regression import baseline
from rig.regression.baseline import (
    CHANGED,
    EITHER,
    HIGHER,
    IMPROVED,
    LOWER,
    MISSING,
    NEW,
    REGRESSED,
    STALE,
    UNCHANGED,
    Band,
    SeedResult,
)

# -- the band ----------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(20))
def test_band_holds_every_seed_and_the_prediction_interval(seed: int) -> None:
    """Property: the band holds every value it was made of and is at least as wide as the
    99 % prediction interval of one more value (t(0.995, N-1) sqrt(1 + 1/N) s)."""
    rng = random.Random(seed)
    n = rng.randint(5, 12)
    values = [rng.gauss(3.0, 0.2) for _ in range(n)]
    b = Band.of(values, "deg")
    assert all(b.lo <= v <= b.hi for v in values)
    m = sum(values) / n
    s = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1))
    from scipy import stats

    half_pi = stats.t.ppf(0.995, n - 1) * math.sqrt(1 + 1 / n) * s
    assert b.hi - m >= half_pi * (1 - 1e-9) and m - b.lo >= half_pi * (1 - 1e-9)


def test_band_floor_for_values_the_noise_does_not_move() -> None:
    """Eight identical values get 1 % of the value or the unit's resolution, never zero
    width (except for counts that must stay exact)."""
    b = Band.of([4.0] * 8, "deg")  # (6 significant digits, rounded outwards)
    assert b.lo == pytest.approx(3.96, abs=2e-5) and b.hi == pytest.approx(4.04, abs=2e-5)
    small = Band.of([0.4] * 8, "deg")  # 1 % is below the 0.01 deg resolution
    assert small.lo == pytest.approx(0.39, abs=2e-6) and small.hi == pytest.approx(0.41, abs=2e-6)
    zero = Band.of([0.0] * 8, "periods")  # a count: its unit's resolution
    assert (zero.lo, zero.hi) == (-1.0, 1.0)
    exact = Band.of([0.0] * 8, "")
    assert (exact.lo, exact.hi) == (0.0, 0.0)  # polarity losses: none is none


def test_classify_by_the_better_side() -> None:
    b = Band.of([1.0, 1.1, 0.9, 1.05, 0.95], "deg")
    assert b.classify(1.0, LOWER) == UNCHANGED
    assert b.classify(5.0, LOWER) == REGRESSED
    assert b.classify(0.01, LOWER) == IMPROVED
    assert b.classify(5.0, HIGHER) == IMPROVED
    assert b.classify(0.01, HIGHER) == REGRESSED
    assert b.classify(5.0, EITHER) == CHANGED
    # no number (never detected, no data) is the worst value of its side
    assert b.classify(None, LOWER) == REGRESSED
    assert b.classify(None, HIGHER) == REGRESSED
    never = Band.of([None] * 5, "periods")
    assert never.classify(None, LOWER) == UNCHANGED
    assert never.classify(12.0, LOWER) == IMPROVED


def test_band_catches_a_four_times_worse_cell() -> None:
    """The issue's example: a Table 2 cell at 0.5 deg that a bug moves to 2.46 deg passed the
    2.5 deg limit; against its baseline it regresses."""
    b = Band.of([0.50, 0.47, 0.52, 0.49, 0.55, 0.51, 0.46, 0.53], "deg")
    assert b.classify(2.46, LOWER) == REGRESSED
    assert b.classify(0.56, LOWER) == UNCHANGED


# -- building and the file ---------------------------------------------------------------

SCENARIO = scenario_text.scenario(
    "baseline test scenario", profile="paper", duration=0.3,
    speed=[scenario_text.ramp(300.0, 0.2), scenario_text.hold(0.1)],
    criteria=[scenario_text.criterion("position", "pos_err_max_deg", (0.2, "end"), 5),
              scenario_text.criterion("no polarity loss", "polarity_loss_count", (0.05, "end"),
                                      0, "==")])


@pytest.fixture
def test_scenario(tmp_path: Path) -> scenario.Scenario:
    path = tmp_path / "blt.toml"
    path.write_text(SCENARIO)
    return scenario.load_scenario(path)


def crit(name: str, value: float | None, outcome: str = "pass",
         comparison: str = "<=") -> dict[str, object]:
    return {"name": name, "value": value, "outcome": outcome, "unit": "deg",
            "comparison": comparison}


def test_build_refuses_seed_dependent_and_failing_verdicts(
        test_scenario: scenario.Scenario) -> None:
    seeds = (1, 2, 3, 4, 5)
    runs = {s: [SeedResult([crit("position", 1.0 + 0.01 * s,
                                 "fail" if s == 3 else "pass"),
                            crit("no polarity loss", 0.0, "fail", "==")])] for s in seeds}
    _, problems = baseline.build("t", seeds, [test_scenario], runs, {})
    assert any("'position' depends on the seed" in p and "FAIL at seeds 3" in p
               for p in problems)
    assert any("'no polarity loss' is FAIL at every seed" in p for p in problems)
    with pytest.raises(baseline.BaselineError, match="at least 5 seeds"):
        baseline.build("t", (1, 2, 3), [test_scenario], runs, {})


def test_file_round_trip_and_judge(test_scenario: scenario.Scenario) -> None:
    seeds = (1, 2, 3, 4, 5, 6, 7, 8)
    runs = {s: [SeedResult([crit("position", 0.4 + 0.01 * (s % 3)),
                            crit("no polarity loss", 0.0, comparison="==")])] for s in seeds}
    b, problems = baseline.build("t", seeds, [test_scenario], runs, {"commit": "x"})
    assert not problems
    again = baseline.Baseline.loads(b.dumps())
    key = baseline.entry_key(test_scenario.name, "paper")
    rec, rec2 = b.entries[key].records["position"], again.entries[key].records["position"]
    assert (rec2.band.lo, rec2.band.hi, rec2.metric, rec2.better) == (
        rec.band.lo, rec.band.hi, "pos_err_max_deg", LOWER)
    assert again.seeds == seeds
    setup = baseline.setup_digest(test_scenario)
    run = [{**crit("position", 3.0), "metric": "pos_err_max_deg", "window": [0.2, 0.3],
            "params": {}},
           {**crit("no polarity loss", 0.0, comparison="=="), "metric": "polarity_loss_count",
            "window": [0.05, 0.3], "params": {}},
           {**crit("brand new", 1.0), "metric": "pos_err_rms_deg", "window": [0, 1]}]
    summary = again.judge(key, setup, None, run)
    assert [c["baseline"]["class"] for c in run] == [REGRESSED, UNCHANGED, NEW]
    assert not summary["passed"]
    # another set-up (here: another plant override) makes the record stale, not silently
    # judged against values of something else
    other = baseline.setup_digest(test_scenario.with_seed(5))  # the seed is not the set-up
    assert other == setup
    from dataclasses import replace

    changed = replace(test_scenario, overrides={"machine.rs": 2.2})
    summary = again.judge(key, baseline.setup_digest(changed), None, run)
    assert run[0]["baseline"]["class"] == STALE and not summary["passed"]
    # any seed is judged: the band describes one more seed's value, recorded or not
    again.judge(key, setup, 42, run)
    assert run[0]["baseline"]["class"] == REGRESSED


def test_a_run_belongs_to_one_baseline_file(tmp_path: Path,
                                            test_scenario: scenario.Scenario) -> None:
    seeds = (1, 2, 3, 4, 5)
    runs = {s: [SeedResult([crit("position", 0.4), crit("no polarity loss", 0.0,
                                                         comparison="==")])] for s in seeds}
    b, _ = baseline.build("a", seeds, [test_scenario], runs, {})
    folder = tmp_path / "baselines"
    folder.mkdir()
    (folder / "a.toml").write_text(b.dumps())
    assert baseline.Index.load(folder).for_key("blt@paper") is not None
    b.suite = "b"
    (folder / "b.toml").write_text(b.dumps())
    with pytest.raises(baseline.BaselineError, match="has a baseline in both"):
        baseline.Index.load(folder)


# -- end to end: rig baseline record, rig run against it ----------------------------------


def test_record_then_run_catches_a_regression(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              test_scenario: scenario.Scenario) -> None:
    """Record a one-scenario suite over 5 seeds in process, run it: unchanged, exit 0. Then
    hand the run a baseline that says the drive did four times better: the same run is a
    regression and exits 1 though every limit passes."""
    suite = tmp_path / "blsuite.toml"
    suite.write_text(f'name = "blsuite"\nscenarios = ["{tmp_path / "blt.toml"}"]\n')
    folder = tmp_path / "baselines"
    folder.mkdir()
    monkeypatch.setenv("HIL_BASELINE_DIR", str(folder))
    target = folder / "blsuite.toml"
    assert cli.main(["baseline", "record", str(suite), "--seeds", "1-5", "--jobs", "2",
                     "--out", str(tmp_path / "rec"), "--to", str(target)]) == 0
    b = baseline.Baseline.load(target)
    key = baseline.entry_key("blt", "paper")
    rec = b.entries[key].records["position"]
    assert rec.band.seeds_min is not None and rec.band.seeds_max is not None
    assert rec.band.seeds_max > rec.band.seeds_min  # the paper profile's noise moves it
    out = tmp_path / "run"
    assert cli.main(["run", str(suite), "--bus", "inproc", "--out", str(out),
                     "--no-record", "--quiet", "--jobs", "2"]) == 0
    summary = json.loads((out / "result.json").read_text())
    classes = {c["name"]: c["baseline"]["class"] for c in summary["scenarios"][0]["criteria"]}
    assert classes == {"position": UNCHANGED, "no polarity loss": UNCHANGED}
    # a baseline four times better than what the drive does: the run regresses (and the
    # fresh seeds confirm it)
    target.write_text(scaled(target.read_text(), "position", 0.25))
    out2 = tmp_path / "run2"
    assert cli.main(["run", str(suite), "--bus", "inproc", "--out", str(out2),
                     "--no-record", "--quiet"]) == 1
    summary = json.loads((out2 / "result.json").read_text())
    assert summary["baseline"]["counts"].get(REGRESSED) == 1
    assert summary["scenarios"][0]["criteria"][0]["outcome"] == "pass"  # within its limit
    assert "REGRESSED" in (out2 / "report.md").read_text()
    # --baseline off: the limits only
    assert cli.main(["run", str(suite), "--bus", "inproc", "--out", str(tmp_path / "run3"),
                     "--no-record", "--quiet", "--baseline", "off"]) == 0


def test_a_scenario_over_its_own_seeds_is_held_to_its_mean(tmp_path: Path) -> None:
    """Its value is the worst of its seeds (a noisy statistic); the baseline compares the
    mean of the per-seed values, with the band of such a mean."""
    path = tmp_path / "own.toml"
    path.write_text(SCENARIO.replace("[[speed]]", "[run]\nseeds = 4\n[[speed]]", 1))
    sc = scenario.load_scenario(path)
    per = [0.4, 0.9, 0.5, 0.6]

    def c(vals: list[float]) -> dict[str, object]:
        return {**crit("position", max(vals)),
                "seeds": [{"seed": i + 1, "value": v} for i, v in enumerate(vals)]}

    runs = {s: [SeedResult([c(per), crit("no polarity loss", 0.0, comparison="==")])]
            for s in (1, 2, 3, 4, 5)}
    b, problems = baseline.build("t", (1, 2, 3, 4, 5), [sc], runs, {})
    assert not problems
    rec = b.entries["own@paper"].records["position"]
    assert rec.stat == "mean" and rec.band.value == pytest.approx(0.6)
    rec = baseline.Baseline.loads(b.dumps()).entries["own@paper"].records["position"]
    assert rec.stat == "mean"
    # the same seeds drawn again after a change of rounding: the worst moved, the mean not
    again = [0.45, 0.85, 0.55, 0.55]
    assert rec.band.classify(rec.statistic(c(again)), LOWER) == UNCHANGED
    worse = [v * 3 for v in per]
    assert rec.band.classify(rec.statistic(c(worse)), LOWER) == REGRESSED


# -- require requires; a malformed file stops a run before it starts (issue 36) -----------


def _recorded(test_scenario: scenario.Scenario) -> baseline.Baseline:
    seeds = (1, 2, 3, 4, 5, 6, 7, 8)
    runs = {s: [SeedResult([crit("position", 0.4 + 0.01 * (s % 3)),
                            crit("no polarity loss", 0.0, comparison="==")])] for s in seeds}
    b, problems = baseline.build("t", seeds, [test_scenario], runs, {"commit": "x"})
    assert not problems
    return b


def test_require_fails_a_criterion_without_its_line(test_scenario: scenario.Scenario) -> None:
    """A baseline with one criterion's line deleted: under require that criterion is
    missing and fails the run (auto: new, passes)."""
    b = _recorded(test_scenario)
    key = baseline.entry_key(test_scenario.name, "paper")
    text = "\n".join(line for line in b.dumps().splitlines()
                     if not line.startswith('"no polarity loss"'))
    again = baseline.Baseline.loads(text)
    run = [{**crit("position", 0.41), "metric": "pos_err_max_deg", "window": [0.2, 0.3],
            "params": {}},
           {**crit("no polarity loss", 0.0, comparison="=="), "metric": "polarity_loss_count",
            "window": [0.05, 0.3], "params": {}}]
    setup = baseline.setup_digest(test_scenario)
    summary = again.judge(key, setup, 1, run, require=True)
    assert [c["baseline"]["class"] for c in run] == [UNCHANGED, MISSING]
    assert not summary["passed"] and MISSING in baseline.FAILING
    summary = again.judge(key, setup, 1, run, require=False)
    assert run[1]["baseline"]["class"] == NEW and summary["passed"]


@pytest.mark.parametrize(("edit", "why"), [
    (lambda t: t.replace('seeds = [1, 2, 3, 4, 5, 6, 7, 8]', "seeds = 5"), "seeds must be"),
    (lambda t: t.replace("sd = ", "sd = 1" + "0" * 400 + " + 0*", 1), "not TOML"),
    (lambda t: t.replace("sd = ", "sd = 1" + "0" * 400 + ".0, xsd = ", 1), "not a finite"),
    (lambda t: t.replace('metric = "pos_err_max_deg"', "metric = 3"), "metric must be"),
    (lambda t: t.replace("lo = ", "lo = 0.425, xlo = ", 1), "does not hold its own value"),
    (lambda t: t.replace("values = [", "values = [9.0, ", 1), "values has 9 entries"),
    (lambda t: t.replace('schema = "hil-baseline/2"', 'schema = "x"'), "schema"),
])
def test_a_malformed_baseline_names_file_and_line(test_scenario: scenario.Scenario,
                                                   edit: object, why: str) -> None:
    text = _recorded(test_scenario).dumps()
    bad = edit(text)  # type: ignore[operator]
    assert bad != text
    with pytest.raises(baseline.BaselineError, match=why) as info:
        baseline.Baseline.loads(bad, Path("/x/t.toml"))
    assert str(info.value).startswith("/x/t.toml")


def test_a_malformed_baseline_stops_the_run_before_it_starts(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, test_scenario: scenario.Scenario,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Exit 2 with the file and line, nothing simulated, no result.json; the same for a
    named file (--baseline FILE), which is judged like require."""
    folder = tmp_path / "baselines"
    folder.mkdir()
    text = _recorded(test_scenario).dumps()
    (folder / "t.toml").write_text(text.replace("lo = ", "lo = 0.425, xlo = ", 1))
    monkeypatch.setenv("HIL_BASELINE_DIR", str(folder))
    out = tmp_path / "run"
    assert cli.main(["run", "smoke", "--bus", "inproc", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{folder / 't.toml'}:" in err and "does not hold its own value" in err
    assert not (out / "result.json").exists()
    assert cli.main(["run", "smoke", "--bus", "inproc", "--out", str(out), "--quiet",
                     "--baseline", str(tmp_path / "nope.toml")]) == 2
    assert "no such file" in capsys.readouterr().err
