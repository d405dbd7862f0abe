"""The noise seed as a dimension of a run: `rig run --seed`, scenarios decided over their own
seeds (worst case), suite comparisons decided over seeds (paired differences and their
confidence interval), parallel suites equal to serial ones, and the t quantile they use."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import scenario_text

from rig import cli, scenario
from rig.regression import stats
from rig.run import multi_seed
from rig.run.suite import evaluate_comparison
from rig.scenario import Comparison


def write(folder: Path, name: str, run: str = "", limit: float = 5.0) -> Path:
    path = folder / f"{name}.toml"
    path.write_text(scenario_text.scenario(
        "seed test scenario", profile="paper", duration=0.25,
        speed=[scenario_text.ramp(300.0, 0.15), scenario_text.hold(0.1)], other=run,
        criteria=[scenario_text.criterion("position", "pos_err_max_deg", (0.15, "end"), limit),
                  scenario_text.criterion("mean speed", "speed_mean_rpm", (0.15, "end"), 150,
                                          ">=")]))
    return path


@pytest.mark.parametrize("df", [1, 2, 4, 7, 15, 31])
@pytest.mark.parametrize("p", [0.025, 0.9, 0.975, 0.995])
def test_t_quantile_against_scipy(p: float, df: int) -> None:
    from scipy.stats import t

    assert stats.t_quantile(p, df) == pytest.approx(float(t.ppf(p, df)), rel=1e-8)


def test_mean_ci_covers_like_its_level() -> None:
    """Property: over many samples of a known normal mean, the 95 % interval holds the mean
    about 95 % of the time."""
    import random

    rng = random.Random(7)
    hits = 0
    trials = 400
    for _ in range(trials):
        ci = stats.mean_ci([rng.gauss(1.0, 0.3) for _ in range(8)], 0.95)
        hits += ci.lo <= 1.0 <= ci.hi
    assert 0.92 <= hits / trials <= 0.98


def test_run_seed_changes_the_noise_only(tmp_path: Path) -> None:
    """Two seeds: other values (the noise moved), same verdicts; the same seed twice: the
    same values to the bit."""
    path = write(tmp_path, "sd")
    vals = {}
    for tag, seed in (("a", 3), ("b", 3), ("c", 4)):
        out = tmp_path / tag
        assert cli.main(["run", str(path), "--bus", "inproc", "--seed", str(seed), "--out",
                         str(out), "--no-record", "--quiet", "--baseline", "off"]) == 0
        data = json.loads((out / "result.json").read_text())
        assert data["overrides"][scenario.SEED_KEY] == seed
        vals[tag] = [c["value"] for c in data["criteria"]]
    assert vals["a"] == vals["b"]
    assert vals["a"] != vals["c"]


def test_combine_takes_the_worst_seed() -> None:
    per_seed = [[{"name": "p", "comparison": "<=", "value": v, "passed": v <= 1.0,
                  "outcome": "pass" if v <= 1.0 else "fail"}] for v in (0.5, 1.2, 0.7)]
    got = multi_seed.combine(per_seed, (1, 2, 3), {"p": ""})
    assert got[0]["value"] == 1.2 and got[0]["outcome"] == "fail"
    assert "misses at seeds [2]" in got[0]["note"]
    assert [s["value"] for s in got[0]["seeds"]] == [0.5, 1.2, 0.7]
    got = multi_seed.combine(per_seed, (1, 2, 3), {"p": "measured 1.2: known"})
    assert got[0]["outcome"] == "xfail"
    higher = [[{"name": "s", "comparison": ">=", "value": v, "passed": True,
                "outcome": "pass"}] for v in (300.0, 290.0)]
    assert multi_seed.combine(higher, (1, 2), {"s": ""})[0]["value"] == 290.0


def test_scenario_over_its_own_seeds(tmp_path: Path) -> None:
    """[run] seeds = 3: one run per seed, the verdict on the worst; --seed S moves its seeds
    as a block (S = 1: its own; S = 9: seeds 25-27), the set-up it is judged on unchanged."""
    from rig.regression import baseline

    path = write(tmp_path, "ms", run="[run]\nseeds = 3")
    sc = scenario.load_scenario(path)
    assert sc.seeds == (1, 2, 3) and sc.with_seed(1).seeds == (1, 2, 3)
    assert sc.with_seed(9).seeds == (25, 26, 27)
    assert baseline.setup_digest(sc.with_seed(9)) == baseline.setup_digest(sc)
    out = tmp_path / "ms"
    assert cli.main(["run", str(path), "--bus", "inproc", "--out", str(out), "--no-record",
                     "--quiet", "--baseline", "off"]) == 0
    data = json.loads((out / "result.json").read_text())
    per = [json.loads((out / f"seed-{s}" / "result.json").read_text()) for s in (1, 2, 3)]
    worst = max(p["criteria"][0]["value"] for p in per)
    assert data["criteria"][0]["value"] == worst
    assert [s["value"] for s in data["criteria"][0]["seeds"]] == [
        p["criteria"][0]["value"] for p in per]
    # a limit between the seeds' values fails the scenario, whichever seed is the default
    best = min(p["criteria"][0]["value"] for p in per)
    tight = write(tmp_path, "ms2", run="[run]\nseeds = 3", limit=(best + worst) / 2)
    assert cli.main(["run", str(tight), "--bus", "inproc", "--out", str(tmp_path / "ms2"),
                     "--no-record", "--quiet", "--baseline", "off"]) == 1


@pytest.mark.parametrize(("a", "b", "relation", "passed"), [
    ([1.0, 1.1, 0.9, 1.0], [2.0, 2.1, 1.9, 2.05], "<", True),     # shown less
    ([1.0, 1.1, 0.9, 1.0], [1.02, 1.05, 0.95, 1.01], "<", False),  # not shown
    ([1.0, 1.1, 0.9, 1.0], [1.02, 1.05, 0.95, 1.01], "<=", True),  # not shown greater
    ([2.0, 2.1, 1.9, 2.05], [1.0, 1.1, 0.9, 1.0], "<=", False),   # shown greater
])
def test_comparison_over_seeds(a: list[float], b: list[float], relation: str,
                               passed: bool) -> None:
    def entry(name: str, vals: list[float]) -> dict[str, object]:
        return {"name": name, "criteria": [{
            "name": "drop", "value": max(vals), "outcome": "pass", "unit": "%",
            "seeds": [{"seed": i + 1, "value": v} for i, v in enumerate(vals)]}]}

    cmp = Comparison("c", "drop", "a", "b", relation)
    got = evaluate_comparison(cmp, [entry("a", a), entry("b", b)])
    assert got["passed"] is passed
    assert got["value_a"] == pytest.approx(sum(a) / len(a))
    lo, hi = got["diff_ci95"]
    assert lo < got["diff_mean"] < hi


def test_parallel_suite_equals_serial(tmp_path: Path) -> None:
    """--jobs 2 runs the same scenarios to the same values as one after the other."""
    names = []
    for i, limit in enumerate((5.0, 6.0, 7.0)):
        write(tmp_path, f"p{i}", limit=limit)
        names.append(str(tmp_path / f"p{i}.toml"))
    suite = tmp_path / "ps.toml"
    suite.write_text('name = "ps"\nscenarios = [' + ", ".join(f'"{n}"' for n in names) + "]\n")
    got = {}
    for jobs in (1, 2):
        out = tmp_path / f"j{jobs}"
        assert cli.main(["run", str(suite), "--bus", "inproc", "--jobs", str(jobs), "--out",
                         str(out), "--no-record", "--quiet", "--baseline", "off"]) == 0
        data = json.loads((out / "result.json").read_text())
        got[jobs] = [(e["name"], [c["value"] for c in e["criteria"]])
                     for e in data["scenarios"]]
    assert got[1] == got[2]


def test_jobs_need_the_in_process_bench(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                        ) -> None:
    path = write(tmp_path, "j")
    assert cli.main(["run", str(path), "--bus", "unixcan", "--jobs", "2",
                     "--out", str(tmp_path / "o")]) == 2
    assert "--jobs runs a suite on the in-process bench" in capsys.readouterr().err


def test_the_seed_dithers_the_start_angle(tmp_path: Path) -> None:
    """Seed 1 is the scenario as written; seeds 2-8 move the start by (seed - 1)
    thousandths of a degree on top of the scenario's own start angle, any other seed by an
    amount in the same range, and the set-up a baseline is keyed on does not change with
    it."""
    from rig.regression import baseline
    from rig.run.single import bench_configuration

    sc = scenario.load_scenario(write(tmp_path, "dither"))
    assert sc.with_seed(1).start_theta_deg == sc.initial_theta_deg
    assert sc.with_seed(4).start_theta_deg == pytest.approx(sc.initial_theta_deg + 0.003)
    assert "initial.theta_e_deg=0.003" in " ".join(bench_configuration(sc.with_seed(4)).plant_sets)
    assert baseline.setup_digest(sc.with_seed(4)) == baseline.setup_digest(sc)
    # any other seed stays within the range the baselines' seeds 1-8 span (0 .. 0.008 deg)
    from rig.scenario.model import dither_deg

    others = [dither_deg(s) for s in (*range(9, 200), 1001, 1008, 2**31 - 1)]
    assert all(0.0 <= d < 0.008 for d in others)
    assert len({round(d, 9) for d in others}) == len(others)  # no two the same
