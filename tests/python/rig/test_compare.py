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
