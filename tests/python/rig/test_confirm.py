"""Confirming a flag at fresh seeds (rig.regression.confirm): the test's false-alarm rate
under the noise drawn again, its power against a real shift, the classes and verdict it
leaves, and the whole flow on a real scenario: a regression the fresh seeds confirm fails
the run, a value beyond its band that they do not confirm is an excursion and passes."""

from __future__ import annotations

import json
import math
import random
from dataclasses import replace
from pathlib import Path

import pytest
import scenario_text
from baseline_text import scaled

from rig import cli, scenario
from rig.regression import baseline, confirm, stats
from rig.regression.baseline import EXCURSION, LOWER, REGRESSED, Band, Record
from rig.results.result import RunResult, Timing
from rig.run.options import RunOptions

DRAWS = {
    "normal": lambda r: r.gauss(1.0, 0.1),
    "heavy tail": lambda r: math.exp(r.gauss(0.0, 0.8)),
    "discrete": lambda r: float(r.choice([30, 31, 31, 32, 32, 32, 33])),
}


@pytest.mark.parametrize("kind", sorted(DRAWS))
def test_the_noise_drawn_again_is_confirmed_at_most_alpha(kind: str) -> None:
    """Property: baseline and fresh values drawn alike (what a harmless change does), the
    flag is confirmed at most ALPHA of the time, whatever the distribution."""
    rng = random.Random(kind)
    draw = DRAWS[kind]
    trials, hits = 20000, 0
    for _ in range(trials):
        values = [draw(rng) for _ in range(8)]
        rec = Record("c", "m", (0.0, 1.0), {}, "", LOWER, "pass", Band.of(values, ""))
        hits += confirm.shift_p(rec, [draw(rng) for _ in range(8)]) <= confirm.ALPHA
    # binomial: mean at most 20 at ALPHA = 0.001; 4 sd above it
    assert hits <= trials * confirm.ALPHA + 4 * math.sqrt(trials * confirm.ALPHA)


def test_a_real_shift_is_confirmed() -> None:
    """Power: values moved by 3 of their standard deviations at every seed are confirmed in
    at least 85 % of draws; by 5, always."""
    rng = random.Random(3)
    for shift, want in ((3.0, 0.85), (5.0, 0.999)):
        got = 0
        for _ in range(2000):
            values = [rng.gauss(1.0, 0.1) for _ in range(8)]
            rec = Record("c", "m", (0.0, 1.0), {}, "", LOWER, "pass", Band.of(values, ""))
            new = [rng.gauss(1.0 + 0.1 * shift, 0.1) for _ in range(8)]
            got += confirm.shift_p(rec, new) <= confirm.ALPHA
        assert got / 2000 >= want, shift


def test_the_worse_side_and_the_floor() -> None:
    vals = [0.40, 0.41, 0.39, 0.42, 0.40, 0.38, 0.41, 0.40]
    low = Record("c", "m", (0.0, 1.0), {}, "deg", LOWER, "pass", Band.of(vals, "deg"))
    high = replace(low, better="higher")
    either = replace(low, better="either")
    worse = [v + 0.5 for v in vals]
    assert confirm.shift_p(low, worse) <= confirm.ALPHA
    assert confirm.shift_p(high, worse) == pytest.approx(1.0)  # better, for "higher"
    assert confirm.shift_p(either, worse) <= 2 * confirm.ALPHA
    assert confirm.shift_p(either, [v - 0.5 for v in vals]) <= 2 * confirm.ALPHA
    # a move below the unit's resolution (0.01 deg) is not a regression however consistent
    assert confirm.shift_p(low, [v + 0.009 for v in vals]) > confirm.ALPHA
    # no number (never detected) is the worst value
    assert confirm.shift_p(low, [None] * 8) <= confirm.ALPHA


def test_seeds_are_fresh_and_enough() -> None:
    assert confirm.seeds_for([1], 8) == tuple(range(1001, 1009))
    assert not set(confirm.seeds_for([3], 8)) & set(range(1, 9))
    assert confirm.seeds_needed(8) == 8
    n = confirm.seeds_needed(4)  # a scenario over 4 seeds of its own
    assert stats.smallest_shift_p(4, n) <= confirm.ALPHA / 10 < stats.smallest_shift_p(4, n - 1)


def _result(value: float) -> tuple[RunResult, Record]:
    vals = [0.40, 0.41, 0.39, 0.42, 0.40, 0.38, 0.41, 0.40]
    rec = Record("position", "pos_err_max_deg", (0.0, 1.0), {}, "deg", LOWER, "pass",
                 Band.of(vals, "deg"))
    c = {"name": "position", "value": value, "outcome": "pass", "passed": True,
         "baseline": rec.judged(value, 8)}
    r = RunResult(Path("/nonexistent"), scenario="s", profile="paper", status="failed",
                  criteria=[c])
    r.baseline = {"counts": {REGRESSED: 1}, "passed": False}
    return r, rec


def test_decide_sets_classes_and_the_verdict() -> None:
    r, rec = _result(0.6)
    assert r.criteria[0]["baseline"]["class"] == REGRESSED
    assert r.criteria[0]["baseline"]["distance"] > 1.0
    assert 0 < r.criteria[0]["baseline"]["chance"] < 0.005
    same = [[{"name": "position", "value": v}] for v in (0.41, 0.39, 0.40, 0.42, 0.38, 0.40,
                                                         0.41, 0.39)]
    confirm.decide(r, same, confirm.seeds_for([1], 8), [confirm.Flag("position", rec)])
    b = r.criteria[0]["baseline"]
    assert b["class"] == EXCURSION and not b["confirmation"]["confirmed"]
    assert r.passed and r.status == "passed" and r.baseline["passed"]
    r, rec = _result(0.6)
    worse = [[{"name": "position", "value": v + 0.2}] for v in (0.41, 0.39, 0.40, 0.42, 0.38,
                                                                0.40, 0.41, 0.39)]
    confirm.decide(r, worse, confirm.seeds_for([1], 8), [confirm.Flag("position", rec)])
    assert r.criteria[0]["baseline"]["class"] == REGRESSED
    assert r.criteria[0]["baseline"]["confirmation"]["p"] <= confirm.ALPHA
    assert not r.passed and r.status == "failed"


# -- end to end on the in-process bench ---------------------------------------------------

SCENARIO = scenario_text.scenario(
    "confirmation test scenario", profile="paper", duration=0.3,
    speed=[scenario_text.ramp(300.0, 0.2), scenario_text.hold(0.1)],
    criteria=[scenario_text.criterion("position", "pos_err_max_deg", (0.2, "end"), 5)])


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A one-scenario suite and its baseline over seeds 1-8 (in process)."""
    tmp = tmp_path_factory.mktemp("confirm")
    (tmp / "cft.toml").write_text(SCENARIO)
    suite = tmp / "cftsuite.toml"
    suite.write_text(f'name = "cftsuite"\nscenarios = ["{tmp / "cft.toml"}"]\n')
    target = tmp / "baselines" / "cftsuite.toml"
    target.parent.mkdir()
    assert cli.main(["baseline", "record", str(suite), "--seeds", "1-8", "--jobs", "2",
                     "--out", str(tmp / "rec"), "--to", str(target)]) == 0
    return suite, target


def test_a_regression_at_every_seed_is_confirmed(recorded: tuple[Path, Path], tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """A baseline four times better than the drive: the run at seed 1 is flagged, the
    fresh seeds 1001-1008 confirm it, the run fails (exit 1) though its limit passes."""
    suite, target = recorded
    folder = tmp_path / "b"
    folder.mkdir()
    (folder / "cftsuite.toml").write_text(scaled(target.read_text(), "position", 0.25))
    monkeypatch.setenv("HIL_BASELINE_DIR", str(folder))
    out = tmp_path / "run"
    assert cli.main(["run", str(suite), "--bus", "inproc", "--out", str(out), "--no-record",
                     "--no-figures", "--quiet"]) == 1
    data = json.loads((out / "cft" / "result.json").read_text())
    c = data["criteria"][0]
    assert c["outcome"] == "pass" and c["baseline"]["class"] == REGRESSED
    conf = c["baseline"]["confirmation"]
    assert conf["confirmed"] and conf["p"] <= confirm.ALPHA
    assert conf["seeds"] == list(range(1001, 1009))
    assert all(v is not None for v in conf["values"])
    # the same values as a run at each of those seeds on its own
    sc = scenario.load_scenario(suite.parent / "cft.toml").with_seed(1004)
    from rig.run.runner import run_scenario

    alone = run_scenario(sc, RunOptions(out=tmp_path / "alone", bus="inproc", progress=False,
                                        record=False, figures=False))
    assert alone.criteria[0]["value"] == pytest.approx(conf["values"][3], rel=1e-12)
    # --no-confirm: the flag fails at once, as the gate before did
    assert cli.main(["run", str(suite), "--bus", "inproc", "--out", str(tmp_path / "nc"),
                     "--no-record", "--no-figures", "--quiet", "--no-confirm"]) == 1
    nc = json.loads((tmp_path / "nc" / "cft" / "result.json").read_text())
    assert "confirmation" not in nc["criteria"][0]["baseline"]


def test_noise_beyond_the_band_is_an_excursion(recorded: tuple[Path, Path],
                                               tmp_path: Path) -> None:
    """A run whose value lies beyond its band at its seed, as a redraw of the noise can
    leave it: the fresh seeds (real runs) rank like the baseline's, so it is not confirmed:
    an excursion, the run passes, and what it saw is in result.json and report.md."""
    suite, target = recorded
    b = baseline.Baseline.load(target)
    key = baseline.entry_key("cft", "paper")
    rec = b.entries[key].records["position"]
    sc = scenario.load_scenario(suite.parent / "cft.toml")
    out = tmp_path / "exc"
    out.mkdir()
    r = RunResult.of_scenario(sc, out, status="passed", passed=True, timing=Timing(0.3))
    beyond = rec.band.hi + 0.5 * (rec.band.hi - rec.band.lo)
    r.criteria = [{"name": "position", "metric": "pos_err_max_deg", "value": beyond,
                   "outcome": "pass", "passed": True, "unit": "deg", "window": [0.2, 0.3],
                   "comparison": "<=", "limit": 5.0, "params": {}}]
    r.baseline = b.judge(key, baseline.setup_digest(sc), 1, r.criteria)
    assert r.criteria[0]["baseline"]["class"] == REGRESSED and not r.baseline["passed"]
    opts = RunOptions(out=out, bus="inproc", progress=False, record=False, figures=False,
                      baseline=str(target))
    confirm.confirm(sc, r, opts)
    c = r.criteria[0]["baseline"]
    assert c["class"] == EXCURSION, c["confirmation"]
    assert c["confirmation"]["p"] > confirm.ALPHA
    assert r.passed and r.baseline["passed"]
    saved = json.loads((out / "result.json").read_text())
    assert saved["criteria"][0]["baseline"]["class"] == EXCURSION
    report = (out / "report.md").read_text()
    assert "excursion" in report and "not confirmed at seeds 1001-1008" in report


def test_the_gate_false_alarm_bound_from_the_committed_baselines() -> None:
    """The bound the README states, computed from the committed baselines: each criterion is
    flagged by chance with the probability that one more seed lands beyond its band on the
    worse side (the band's own prediction distribution at its edge), and a flag is confirmed
    by chance at most ALPHA of the time; so a harmless change fails the gate with probability
    at most the sum of those flag probabilities times ALPHA. It must stay within the 5 % the
    gate promises (4.2 flags expected, 0.4 %, with the baselines of issue 35; what is
    measured: docs/status.md)."""
    idx = baseline.index()
    expected_flags = 0.0
    n = 0
    for b in idx.baselines:
        assert b.path is not None and b.entries
        for e in b.entries.values():
            for rec in e.records.values():
                band = rec.band
                if band.value is None or not band.values:
                    continue
                n += 1
                if band.sd == 0 and band.floor == 0:
                    continue  # an exact value (a count that must stay 0) moves by no chance
                edge = band.hi if rec.better != "higher" else band.lo
                expected_flags += band.chance(edge, rec.better)
    assert n > 800  # the gate's criteria, every one with its per-seed values
    assert 1.0 < expected_flags < 0.01 * n  # at most 0.5 % per criterion on its worse side
    assert expected_flags * confirm.ALPHA <= 0.05


def test_confirmation_runs_keep_no_traces_even_when_they_fail(tmp_path: Path) -> None:
    """keep="none" (the confirmation's fresh seeds) removes the full-rate traces and the
    capture of a run that fails its limit too: a mutation campaign's kills kept 8 seeds'
    traces a flag, 5 GB a mutant, and filled the disk. "failing" keeps them."""
    from rig.run.runner import run_scenario

    text = SCENARIO.replace("limit = 5", "limit = 0.0001")
    assert text != SCENARIO
    (tmp_path / "tight.toml").write_text(text)
    sc = scenario.load_scenario(tmp_path / "tight.toml")
    runs = {}
    for keep in ("none", "failing"):
        out = tmp_path / keep
        runs[keep] = run_scenario(sc, RunOptions(out=out, bus="inproc", progress=False,
                                                 record=False, figures=False, keep=keep))
        assert not runs[keep].passed
    assert not list((tmp_path / "none").glob("*.trace"))
    assert not (tmp_path / "none" / "capture").exists()
    assert not runs["none"].kept.full_rate
    assert list((tmp_path / "failing").glob("*.trace")) and runs["failing"].kept.full_rate
    assert runs["none"].criteria[0]["value"] == runs["failing"].criteria[0]["value"]
    assert (tmp_path / "none" / "result.json").exists()
