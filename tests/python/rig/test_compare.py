"""rig compare: sides from run, suite, seed and baseline folders; each criterion judged
against the seed spread; the Markdown table, JSON and plots a reviewer reads."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from PIL import Image

from rig import cli
from rig.regression import baseline, compare
from rig.regression.baseline import Band, Baseline, Entry, Record


def suite_folder(folder: Path, values: dict[str, float], outcome: str = "pass") -> Path:
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps({
        "schema": "hil-suite/1", "suite": "s", "passed": True, "scenarios": [
            {"name": "cell@paper", "profile": "paper", "criteria": [
                {"name": name, "metric": "pos_err_max_deg", "value": v, "unit": "deg",
                 "comparison": "<=", "outcome": outcome} for name, v in values.items()]}]}))
    return folder


def seed_folders(folder: Path, per_seed: list[float]) -> Path:
    for i, v in enumerate(per_seed, 1):
        run = folder / f"seed-{i}" / "cell@paper"
        run.mkdir(parents=True)
        (run / "result.json").write_text(json.dumps({
            "schema": "hil-result/1", "scenario": "cell@paper", "profile": "paper",
            "criteria": [{"name": "pos", "metric": "pos_err_max_deg", "value": v,
                          "unit": "deg", "comparison": "<=", "outcome": "pass"}]}))
    return folder


def test_seed_folders_against_a_run(tmp_path: Path) -> None:
    """A side of eight seeds brings its own spread: a run inside it is unchanged, one four
    times worse regressed, one four times better improved."""
    seeds = seed_folders(tmp_path / "rec", [0.50, 0.47, 0.52, 0.49, 0.55, 0.51, 0.46, 0.53])
    a = compare.load_side(str(seeds))
    assert a.values[("cell@paper", "pos")].n == 8
    for value, cls in ((0.51, "unchanged"), (2.0, "regressed"), (0.12, "improved")):
        b = compare.load_side(str(suite_folder(tmp_path / f"b{value}", {"pos": value})))
        rows = compare.compare(a, b)
        assert [r.cls for r in rows] == [cls], value


def test_without_any_spread_a_difference_is_unknown(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HIL_BASELINE_DIR", str(tmp_path / "none"))
    a = compare.load_side(str(suite_folder(tmp_path / "a", {"pos": 0.5, "gone": 1.0})))
    b = compare.load_side(str(suite_folder(tmp_path / "b", {"pos": 0.9, "new": 1.0})))
    got = {r.key[1]: r.cls for r in compare.compare(a, b)}
    assert got == {"pos": "unknown", "gone": "removed", "new": "added"}


def test_cli_writes_table_json_and_plots(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """Against a committed-style baseline: the regression is named in the table, counted in
    compare.json, drawn in a PNG, and the exit status says so."""
    folder = tmp_path / "baselines"
    folder.mkdir()
    rec = Record("pos", "pos_err_max_deg", (1.0, 2.0), {}, "deg", "lower", "pass",
                 Band.of([0.50, 0.47, 0.52, 0.49, 0.55], "deg"))
    b = Baseline("s", (1, 2, 3, 4, 5), "now", {}, {"cell@paper": Entry("cell@paper", "x",
                                                                     {"pos": rec})})
    (folder / "s.toml").write_text(b.dumps())
    monkeypatch.setenv("HIL_BASELINE_DIR", str(folder))
    run = suite_folder(tmp_path / "run", {"pos": 2.46})
    out = tmp_path / "cmp"
    assert cli.main(["compare", "baseline:s", str(run), "--out", str(out)]) == 1
    text = capsys.readouterr().out
    assert "| cell@paper | pos | `pos_err_max_deg` |" in text and "REGRESSED" in text
    data = json.loads((out / "compare.json").read_text())
    assert data["rows"][0]["class"] == "regressed"
    png = out / "compare-pos_err_max_deg.png"
    with Image.open(png) as im:
        assert im.size[0] > 300 and im.size[1] > 80
    assert "compare-pos_err_max_deg.png" in (out / "compare.md").read_text()
    same = suite_folder(tmp_path / "same", {"pos": 0.5})
    assert cli.main(["compare", "baseline:s", str(same)]) == 0
    assert cli.main(["compare", str(tmp_path / "nothing"), str(same)]) == 2


def test_baselines_compared_to_each_other() -> None:
    """What `rig baseline record` prints against the file it replaces."""
    def one(values: list[float]) -> Baseline:
        rec = Record("pos", "m", (0.0, 1.0), {}, "deg", "lower", "pass", Band.of(values, "deg"))
        return Baseline("s", (1, 2, 3, 4, 5), "", {}, {"k": Entry("k", "x", {"pos": rec})})

    rows = compare.baselines(one([1.0, 1.1, 0.9, 1.0, 1.05]), one([3.0, 3.1, 2.9, 3.0, 3.05]))
    assert rows[0].cls == "regressed"
    assert "1 regressed" in compare.summary_line(rows)
    assert baseline.REGRESSED == "regressed"


# -- what rig compare refuses, and how it ranks (issue 36) ---------------------------------


def _run(folder: Path, name: str, criteria: object, schema: str = "hil-result/1") -> Path:
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps({
        "schema": schema, "scenario": name, "profile": "paper", "criteria": criteria}))
    return folder


def test_nothing_evaluated_or_nothing_in_common_is_not_comparable(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two interrupted runs (nothing evaluated) are not "unchanged"; runs of two different
    scenarios are not "added and removed": both are not comparable, exit 2."""
    empty_a = _run(tmp_path / "ia", "cell", [{"name": "pos", "metric": "m", "value": None,
                                                "outcome": "not_evaluated"}])
    empty_b = _run(tmp_path / "ib", "cell", [{"name": "pos", "metric": "m", "value": None,
                                                "outcome": "not_evaluated"}])
    assert cli.main(["compare", str(empty_a), str(empty_b)]) == 2
    err = capsys.readouterr().err
    assert "not comparable" in err and "evaluated nothing" in err
    one = _run(tmp_path / "x", "cellx", [{"name": "pos", "metric": "m", "value": 1.0,
                                          "outcome": "pass"}])
    other = _run(tmp_path / "y", "celly", [{"name": "pos", "metric": "m", "value": 1.0,
                                            "outcome": "pass"}])
    assert cli.main(["compare", str(one), str(other)]) == 2
    err = capsys.readouterr().err
    assert "no scenario run in common" in err and "cellx@paper" in err


def test_a_baseline_is_narrowed_to_the_runs_scenarios(tmp_path: Path) -> None:
    """A suite's baseline against a run of one of its scenarios compares that scenario, not
    "364 removed"."""
    def rec(v: float) -> Record:
        return Record("pos", "pos_err_max_deg", (0.0, 1.0), {}, "deg", "lower", "pass",
                      Band.of([v, v * 1.02, v * 0.98, v * 1.01, v * 0.99], "deg"))

    b = Baseline("s", (1, 2, 3, 4, 5), "now", {}, {
        f"cell{i}@paper": Entry(f"cell{i}@paper", "x", {"pos": rec(0.5)}) for i in range(50)})
    path = tmp_path / "s.toml"
    path.write_text(b.dumps())
    run = _run(tmp_path / "r", "cell7", [{"name": "pos", "metric": "pos_err_max_deg",
                                          "value": 0.5, "outcome": "pass", "unit": "deg",
                                          "comparison": "<="}])
    rows = compare.compare(compare.load_side(str(path)), compare.load_side(str(run)))
    assert [(r.key, r.cls) for r in rows] == [(("cell7@paper", "pos"), "unchanged")]


@pytest.mark.parametrize("bad", [
    [1, 2, 3],                                                          # a list
    {"schema": "hil-result/1", "scenario": "c", "profile": "p", "criteria": "abc"},
    {"schema": "hil-result/1", "scenario": "c", "profile": "p", "criteria": [5]},
    {"schema": "hil-result/1", "scenario": "c", "profile": "p",
     "criteria": [{"name": "x", "value": "abc"}]},
    {"schema": "hil-result/1", "scenario": "c", "profile": "p",
     "criteria": [{"name": "x", "value": 1, "seeds": [{"value": "1.0"}]}]},
    {"schema": "hil-result/1", "scenario": ["c"], "profile": "p", "criteria": []},
    {"schema": "hil-suite/1", "scenarios": "x"},
    {"schema": "hil-suite/1", "scenarios": [3]},
    {"schema": "other"},
])
def test_malformed_result_json_is_a_clear_error(tmp_path: Path, bad: object,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    good = _run(tmp_path / "good", "c", [{"name": "x", "metric": "m", "value": 1.0,
                                          "outcome": "pass"}])
    folder = tmp_path / "bad"
    folder.mkdir()
    (folder / "result.json").write_text(json.dumps(bad))
    assert cli.main(["compare", str(good), str(folder)]) == 2
    err = capsys.readouterr().err
    assert "result.json" in err and "Traceback" not in err


def test_rows_carry_percent_band_widths_and_chance_most_significant_first(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Inside its band an RMS error 29 % lower is still shown (with its change in %), and
    rows come most significant first: the least likely by chance on top."""
    monkeypatch.setenv("HIL_BASELINE_DIR", str(tmp_path / "none"))
    vals = [1.0, 1.3, 0.7, 1.2, 0.8, 1.1, 0.9, 1.0]
    seeds = seed_folders(tmp_path / "rec", vals)
    a = compare.load_side(str(seeds))
    run = suite_folder(tmp_path / "b", {"pos": 0.71})
    rows = compare.compare(a, compare.load_side(str(run)))
    r = rows[0]
    assert r.cls == "unchanged" and r.pct == pytest.approx(-29.0)
    assert r.widths is not None and -1 < r.widths < 0 and r.chance is not None
    table = compare.markdown(rows)
    assert "-29.0 %" in table
    # two moves: the one less likely by chance comes first
    seeds2 = seed_folders(tmp_path / "rec2", vals)
    for f in (seeds2 / f"seed-{i}" / "cell@paper" / "result.json" for i in range(1, 9)):
        d = json.loads(f.read_text())
        d["criteria"].append(dict(d["criteria"][0], name="other"))
        f.write_text(json.dumps(d))
    b = suite_folder(tmp_path / "c", {"pos": 1.5, "other": 3.0})
    rows = compare.compare(compare.load_side(str(seeds2)), compare.load_side(str(b)))
    assert [r.key[1] for r in rows] == ["other", "pos"]
    assert rows[0].chance is not None and rows[1].chance is not None
    assert rows[0].chance < rows[1].chance


def test_exact_asks_every_value_of_b_to_equal_a_to_the_bit(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--exact (the bus's runs against the gate's in process): B may hold fewer runs than A,
    but each of its values must be A's exactly; a change far inside any band still fails, as
    does a criterion A does not hold."""
    def crit(name: str, value: float, outcome: str = "pass") -> dict[str, object]:
        return {"name": name, "metric": "pos_err_max_deg", "value": value, "outcome": outcome,
                "unit": "deg"}

    def suite(folder: Path, runs: dict[str, list[dict[str, object]]]) -> Path:
        for name, crits in runs.items():
            _run(folder / name, name, crits)
        (folder / "result.json").write_text(json.dumps({
            "schema": "hil-suite/1", "suite": "s",
            "scenarios": [{"name": n, "dir": n, "profile": "paper", "criteria": c}
                          for n, c in runs.items()]}))
        return folder

    gate = suite(tmp_path / "gate", {"a": [crit("pos", 0.5)], "b": [crit("pos", 0.25)]})
    same = suite(tmp_path / "same", {"b": [crit("pos", 0.25)]})
    assert cli.main(["compare", str(gate), str(same), "--exact"]) == 0
    assert "1 of 1 criteria of B identical" in capsys.readouterr().err
    nudged = suite(tmp_path / "nudged", {"b": [crit("pos", 0.25 * (1 + 1e-15))]})
    assert cli.main(["compare", str(gate), str(nudged), "--exact"]) == 1
    assert "b@paper pos: A 0.25 (pass), B 0.25" in capsys.readouterr().err
    extra = suite(tmp_path / "extra", {"b": [crit("pos", 0.25), crit("speed", 1.0)]})
    assert cli.main(["compare", str(gate), str(extra), "--exact"]) == 1
    assert "b@paper speed: A absent" in capsys.readouterr().err
    # without --exact the nudge is unchanged (inside any spread): exit 0
    assert cli.main(["compare", str(gate), str(nudged)]) == 0
