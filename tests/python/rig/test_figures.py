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


def test_a_run_report_opens_with_the_answer(failing_run: Path) -> None:
    report = (failing_run / "report.md").read_text()
    head, _, details = report.partition("## Details")
    lines = head.splitlines()
    assert lines[0] == "# smoke_tight: FAIL"
    assert lines[2] == "**FAIL** (failed): 4 of 6 criteria passed, 2 failed."
    assert lines[4].startswith("- **FAIL** too tight: pos_err_max_deg = ")
    assert lines[5].startswith("- **FAIL** speed too tight: speed_track_err_max_rpm = ")
    assert "![" in head and "(figure.png)" in head  # the figure before the details
    assert "## Criteria" in details and "## Versions" in details


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


def test_failing_figures_draws_only_the_runs_that_do_not_pass(tmp_path: Path) -> None:
    """The gate's --failing-figures: a passing run draws nothing (its pictures cost about as
    much CPU as its closed loop), one that fails draws what a plain run draws."""
    suite = tmp_path / "pair.toml"
    tight = tmp_path / "smoke_tight.toml"
    tight.write_text(SMOKE.read_text() + TIGHT)
    suite.write_text(f'name = "pair"\nscenarios = ["{SMOKE}", "{tight}"]\n')
    assert cli.main(["run", str(suite), "--bus", "inproc", "--quiet", "--failing-figures",
                     "--jobs", "2", "--out", str(tmp_path / "s")]) == 1
    passing = tmp_path / "s" / "smoke"
    assert "figures" not in json.loads((passing / "result.json").read_text())
    assert not list(passing.glob("*.png"))
    failing = tmp_path / "s" / "smoke_tight"
    drawn = json.loads((failing / "result.json").read_text())["figures"]["files"]
    assert cli.main(["run", str(tight), "--bus", "inproc", "--quiet", "--out",
                     str(tmp_path / "plain")]) == 1
    plain = json.loads((tmp_path / "plain" / "result.json").read_text())["figures"]["files"]
    assert drawn == plain and len(drawn) == 3  # the overview and the two tight criteria
    assert all((failing / f["path"]).is_file() for f in drawn)


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
    # it opens with the verdict and a table of every scenario's verdict, linked
    lines = report.splitlines()
    assert lines[0] == "# Suite pair: FAIL" and lines[2].startswith("**FAIL**: 1/2 scenarios")
    table = lines[4:8]
    assert table[0].startswith("| scenario | verdict |")
    assert table[2].startswith("| [smoke](smoke/report.md) | pass |")
    assert table[3].startswith("| [smoke_tight](smoke_tight/report.md) | **FAIL** (failed) | "
                               "too tight, speed too tight")
    assert table[3].endswith("[figure](smoke_tight/figure.png) |")
    links = re.findall(r"\]\(([^)]+\.png)\)", report)
    assert "smoke/figure.png" in links and "smoke_tight/figure.png" in links
    assert "smoke_tight/criterion-5.png" in links
    for link in links:
        assert (tmp_path / "s" / link).is_file(), link


# -- issue 39: every figure shows what its criterion measured --------------------------------

FAULT = Path(__file__).resolve().parents[3] / "rig" / "scenarios" / "fault_adc_frame_loss.toml"
STATE_CRITERION = scenario_text.tables("criteria", [scenario_text.criterion(
    "ends in RUN (it does not)", "fw_state_end", (0.5, "end"), 3, "==")])


@pytest.fixture(scope="module")
def fault_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fault")
    scen = d / "fault_adc_frame_loss.toml"
    scen.write_text(FAULT.read_text() + STATE_CRITERION)
    cli.main(["run", str(scen), "--bus", "inproc", "--quiet", "--keep-all", "--no-record",
              "--baseline", "off", "--out", str(d / "run")])
    return d / "run"


def _by_gid(ax: object, gid: str) -> list[object]:
    return [a for a in ax.get_children() if a.get_gid() == gid]  # type: ignore[attr-defined]


def _flat(ln: object, along: str) -> bool:
    v = np.asarray(ln.get_xdata() if along == "x" else ln.get_ydata(), dtype=float)  # type: ignore[attr-defined]
    return len(v) == 2 and v[0] == v[1]


def _vertical_at(ax: object, gid: str) -> list[float]:
    return sorted(float(np.asarray(ln.get_xdata())[0]) for ln in _by_gid(ax, gid)
                  if _flat(ln, "x"))


def _horizontal_at(ax: object, gid: str) -> list[float]:
    return sorted(float(np.asarray(ln.get_ydata())[0]) for ln in _by_gid(ax, gid)
                  if _flat(ln, "y") and not _flat(ln, "x"))


def _series(ax: object, label: str) -> tuple[np.ndarray, np.ndarray]:
    (line,) = [ln for ln in ax.get_lines() if ln.get_label() == label]  # type: ignore[attr-defined]
    x, y = line.get_data()
    return np.asarray(x, dtype=float), np.asarray(y, dtype=float)


def test_a_phase_current_peak_is_drawn_on_the_three_phase_currents(fault_run: Path) -> None:
    """fault_adc_frame_loss's peak is 20.96 A on phase c; the figure drew ia, ib and ia - ib
    (peaks about 15 A) with the 9.5 A limit on ia - ib."""
    result = json.loads((fault_run / "result.json").read_text())
    cap = capture.Capture(fault_run / "capture")
    peak = next(c for c in result["criteria"] if c["metric"] == "i_phase_peak_a")
    fig = figures.draw_criterion(cap, peak, result["counters"], figures.fault_events(result))
    (ax,) = fig.axes
    x, ia = _series(ax, "ia (true)")
    _, ib = _series(ax, "ib (true)")
    _, ic = _series(ax, "ic = -ia - ib (true)")
    t0, t1 = peak["window"]
    inside = (x >= t0) & (x <= t1)
    biggest = max(np.max(np.abs(v[inside])) for v in (ia, ib, ic))
    assert biggest == pytest.approx(peak["value"], rel=1e-6)  # the value is on the figure
    assert np.max(np.abs(ic[inside])) == pytest.approx(peak["value"], rel=1e-6)  # phase c
    # ic is the capture's -ia - ib, sample for sample where the envelope kept them
    t = np.asarray(cap["period"], dtype=float) * cap.ts
    full_ia = np.interp(x, t, np.asarray(cap["truth.ia"], dtype=float))
    np.testing.assert_allclose(ia, full_ia, atol=1e-5)
    assert _horizontal_at(ax, "limit") == [-peak["limit"], peak["limit"]]  # on |ia|, |ib|, |ic|
    (marker,) = _by_gid(ax, "peak")
    assert abs(float(marker.get_ydata()[0])) == pytest.approx(peak["value"], rel=1e-6)
    # the fault: its start and end on the panel
    assert _vertical_at(ax, "fault-start") == [0.5]
    assert _vertical_at(ax, "fault-end") == [pytest.approx(0.51)]


def test_the_safe_state_shows_the_state_strip_by_name_and_its_count_in_time(
        fault_run: Path) -> None:
    result = json.loads((fault_run / "result.json").read_text())
    cap = capture.Capture(fault_run / "capture")
    safe = next(c for c in result["criteria"] if c["metric"] == "safe_state_periods")
    fig = figures.draw_criterion(cap, safe, result["counters"], figures.fault_events(result))
    currents, strip = fig.axes
    assert _horizontal_at(currents, "limit") == [-0.1, 0.1]  # i_safe_a on the currents
    t0 = safe["window"][0]
    for ax in fig.axes:  # the count from the window's start as a time, and its limit
        assert _vertical_at(ax, "value") == [pytest.approx(t0 + safe["value"] * cap.ts)]
        assert _vertical_at(ax, "limit") == [pytest.approx(t0 + safe["limit"] * cap.ts)]
        assert _vertical_at(ax, "fault-start") == [0.5]
    (state,) = _by_gid(strip, "fw-state")
    x, y = np.asarray(state.get_xdata(), float), np.asarray(state.get_ydata(), float)
    t = np.asarray(cap["period"], dtype=float) * cap.ts
    np.testing.assert_array_equal(y, np.interp(x, t, np.asarray(cap["fw.state"], float)))
    names = {tick.get_text() for tick in strip.get_yticklabels()}
    assert names == {"RUN (3)", "FAULT (4)"}
    assert "safe_state_periods = 121 periods" in fig.texts[0].get_text() or \
        f"{safe['value']:g} periods" in fig.texts[0].get_text()


def test_an_enumerated_criterion_reads_by_name(fault_run: Path) -> None:
    result = json.loads((fault_run / "result.json").read_text())
    cap = capture.Capture(fault_run / "capture")
    state = next(c for c in result["criteria"] if c["metric"] == "fw_state_end")
    assert state["outcome"] == "fail" and state["value"] == 4
    fig = figures.draw_criterion(cap, state, result["counters"], figures.fault_events(result))
    (strip,) = fig.axes
    assert _horizontal_at(strip, "limit") == [3.0]
    assert "fw_state_end = FAULT (4) (limit == RUN (3))" in fig.texts[0].get_text()
    report = (fault_run / "report.md").read_text()
    assert "FAULT (4)" in report and "ADC_LOSS (6)" in report


def test_a_fault_scenarios_overview_marks_the_fault_and_shows_the_state(fault_run: Path,
                                                                      failing_run: Path
                                                                      ) -> None:
    result = json.loads((fault_run / "result.json").read_text())
    fig = figures.draw_overview(capture.Capture(fault_run / "capture"), result)
    assert len(fig.axes) >= 4
    panels = [ax for ax in fig.axes if ax.get_ylabel() != "load (N·m)"]
    for ax in panels:
        assert _vertical_at(ax, "fault-start") == [0.5]
        assert _vertical_at(ax, "fault-end") == [pytest.approx(0.51)]
    assert len(_by_gid(panels[-1], "fw-state")) == 1
    assert {"IDLE (1)", "RUN (3)", "FAULT (4)"} <= {
        tick.get_text() for tick in panels[-1].get_yticklabels()}
    # a scenario without faults: no marks, no strip
    plain = json.loads((failing_run / "result.json").read_text())
    fig = figures.draw_overview(capture.Capture(failing_run / "capture"), plain)
    assert not any(_by_gid(ax, "fault-start") or _by_gid(ax, "fw-state") for ax in fig.axes)


def test_enumerated_values_read_by_name_on_the_terminal_and_in_shown(
        fault_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from rig.commands import run as run_command
    from rig.results import shown
    from rig.results.result import RunResult

    assert shown.value("fw_state_end", 4.0) == "FAULT (4)"
    assert shown.value("firmware.fault_code", 6) == "ADC_LOSS (6)"
    assert shown.value("firmware.fault_code", 99) == "99"  # no name: the number alone
    assert shown.value("i_phase_peak_a", 20.9612) == "20.96"
    run_command._print_verdict(RunResult.load(fault_run))
    err = capsys.readouterr().err
    assert "fw_state_start = RUN (3) (== RUN (3))" in err
    assert "firmware.fault_code = ADC_LOSS (6) (== ADC_LOSS (6))" in err
    assert "fw_state_end = FAULT (4) (== RUN (3))" in err
