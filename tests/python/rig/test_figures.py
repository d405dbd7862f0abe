"""A run's pictures (rig.results.figures): written into its folder, embedded in report.md,
linked from a suite's report; a criterion that did not pass gets a picture showing its window
and its limit; the envelope that keeps them cheap never drops a peak."""

from __future__ import annotations

import json
import re
import textwrap
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
import scenario_text
from matplotlib.patches import Polygon, Rectangle

from rig import cli
from rig.data import capture
from rig.results import figures

SMOKE = Path(__file__).resolve().parents[3] / "rig" / "scenarios" / "smoke.toml"
TIGHT = scenario_text.tables("criteria", [
    scenario_text.criterion("too tight", "pos_err_max_deg", (0.3, "end"), 0.01),
    scenario_text.criterion("speed too tight", "speed_track_err_max_rpm", (0.35, "end"), 1.0),
])


def test_the_envelope_keeps_every_peak_in_time_order() -> None:
    rng = np.random.default_rng(7)
    t = np.arange(100_003) * 1e-4
    y = rng.normal(size=t.size)
    y[12_345], y[99_999] = 50.0, -60.0
    tt, yy = figures.envelope(t, y, max_points=1000)
    assert len(tt) <= 1000 and np.all(np.diff(tt) >= 0)
    assert yy.max() == 50.0 and yy.min() == -60.0
    assert tt[np.argmax(yy)] == t[12_345] and tt[np.argmin(yy)] == t[99_999]
    _, short_y = figures.envelope(t[:500], y[:500], max_points=1000)
    assert np.array_equal(short_y, y[:500])  # nothing to reduce


@pytest.fixture(scope="module")
def failing_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fig")
    scen = d / "smoke_tight.toml"
    scen.write_text(SMOKE.read_text() + TIGHT)
    assert cli.main(["run", str(scen), "--bus", "inproc", "--quiet", "--keep-all",
                     "--out", str(d / "run")]) == 1
    return d / "run"


def _png(path: Path) -> np.ndarray:
    img = matplotlib.image.imread(path)  # a PNG matplotlib can read back
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 500
    return img


def test_a_run_writes_its_pictures_and_its_report_shows_them(failing_run: Path) -> None:
    result = json.loads((failing_run / "result.json").read_text())
    files = result["figures"]["files"]
    assert [f["shows"] for f in files] == ["overview", "criterion", "criterion"]
    assert [f.get("criterion") for f in files[1:]] == ["too tight", "speed too tight"]
    assert result["figures"]["cpu_s"] > 0  # what they cost, kept in result.json
    report = (failing_run / "report.md").read_text()
    embedded = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report)
    assert embedded == [f["path"] for f in files]
    for f in files:
        _png(failing_run / f["path"])


def test_a_failing_criterion_shows_its_window_and_limit(failing_run: Path) -> None:
    result = json.loads((failing_run / "result.json").read_text())
    cap = capture.Capture(failing_run / "capture")
    by_name = {c["name"]: c for c in result["criteria"]}
    tight = by_name["too tight"]
    fig = figures.draw_criterion(cap, tight, result["counters"])
    (ax,) = fig.axes
    t0, t1 = tight["window"]
    assert _spans(ax) == [(t0, t1)]
    horizontal = sorted(y for y in _horizontal_lines(ax))
    assert horizontal == [-tight["limit"], tight["limit"]]  # max |error| <= limit: +-limit
    (data,) = [ln for ln in ax.get_lines() if ln.get_label() == "pos_err_deg"]
    x, y = data.get_data()
    inside = (x >= t0) & (x <= t1)
    assert np.max(np.abs(y[inside])) == pytest.approx(tight["value"])  # the peak is drawn
    assert x.min() < t0 and t1 - 0.001 < x.max() <= t1  # a margin before the window
    assert str(tight["limit"]) in fig.texts[0].get_text()
    # two columns whose difference the metric bounds: their difference carries the limit
    speed = by_name["speed too tight"]
    fig = figures.draw_criterion(cap, speed, result["counters"])
    assert len(fig.axes) == 3
    assert all(_spans(ax) == [tuple(speed["window"])] for ax in fig.axes)
    assert [sorted(_horizontal_lines(ax)) for ax in fig.axes] == [
        [], [], [-speed["limit"], speed["limit"]]]
    (diff,) = fig.axes[2].get_lines()[:1]
    x, y = diff.get_data()
    inside = (x >= speed["window"][0]) & (x <= speed["window"][1])
    assert np.max(np.abs(y[inside])) == pytest.approx(speed["value"], rel=1e-9)


def _spans(ax: object) -> list[tuple[float, float]]:
    out = []
    for p in ax.patches:  # type: ignore[attr-defined]
        if isinstance(p, Polygon | Rectangle):
            xs = p.get_xy()[:, 0] if isinstance(p, Polygon) else [p.get_x(),
                                                                   p.get_x() + p.get_width()]
            out.append((float(min(xs)), float(max(xs))))
    return out


def _horizontal_lines(ax: object) -> list[float]:
    out = []
    for ln in ax.get_lines():  # type: ignore[attr-defined]
        y = np.asarray(ln.get_ydata(), dtype=float)
        if len(y) == 2 and y[0] == y[1] and ln.get_linestyle() == "--":
            out.append(float(y[0]))
    return out


def test_a_passing_run_has_its_overview_only_and_no_figures_means_none(tmp_path: Path) -> None:
    assert cli.main(["run", "smoke", "--bus", "inproc", "--quiet", "--out",
                     str(tmp_path / "a")]) == 0
    result = json.loads((tmp_path / "a" / "result.json").read_text())
    assert [f["path"] for f in result["figures"]["files"]] == ["figure.png"]
    assert not list((tmp_path / "a").glob("criterion-*.png"))
    assert cli.main(["run", "smoke", "--bus", "inproc", "--quiet", "--no-figures", "--out",
                     str(tmp_path / "b")]) == 0
    assert "figures" not in json.loads((tmp_path / "b" / "result.json").read_text())
    assert not (tmp_path / "b" / "figure.png").exists()
    assert "![" not in (tmp_path / "b" / "report.md").read_text()


def test_a_suite_report_links_its_runs_pictures(tmp_path: Path) -> None:
    suite = tmp_path / "pair.toml"
    suite.write_text(textwrap.dedent(f"""\
        name = "pair"
        description = "smoke, and smoke too tight"
        scenarios = ["{SMOKE}", "{tmp_path / 'smoke_tight.toml'}"]
        """))
    (tmp_path / "smoke_tight.toml").write_text(SMOKE.read_text() + TIGHT)
    cli.main(["run", str(suite), "--bus", "inproc", "--quiet", "--out", str(tmp_path / "s")])
    report = (tmp_path / "s" / "report.md").read_text()
    links = re.findall(r"\]\(([^)]+\.png)\)", report)
    assert "smoke/figure.png" in links and "smoke_tight/figure.png" in links
    assert "smoke_tight/criterion-5.png" in links
    for link in links:
        assert (tmp_path / "s" / link).is_file(), link
