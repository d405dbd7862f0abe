"""rig sweep: the axes and points, the scenario a point runs, and whole sweeps on a local
process pool and on a Dask cluster (a scheduler and two workers on 127.0.0.1) that loses a
worker in the middle: its point is retried elsewhere, a point that cannot run is a row with
its reason, and the table and summary are written."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import dask_support
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import sweep_tasks

from rig import scenario
from rig.sweep import engine, spec, summary, table
from rig.sweep import point as sweep_point


def test_axes_grid_and_sample() -> None:
    rs = spec.parse_axis("rs=1.5:2.5:3")
    assert rs.key == "machine.rs_ohm" and rs.values == (1.5, 2.0, 2.5)
    lq = spec.parse_axis("magnetics.lq_h=0.028,0.032")
    assert lq.values == (0.028, 0.032)
    noise = spec.parse_axis("noise=0:0.004")
    assert noise.is_range and (noise.low, noise.high) == (0.0, 0.004)
    assert len(spec.grid([rs, lq])) == 6
    with pytest.raises(spec.SpecError, match="noise"):
        spec.grid([rs, noise])
    a = spec.sample([rs, noise], 50, seed=3)
    assert a == spec.sample([rs, noise], 50, seed=3) != spec.sample([rs, noise], 50, seed=4)
    assert all(p["rs"] in rs.values and 0.0 <= p["noise"] <= 0.004 for p in a)
    for bad in ("rs", "rs=", "rs=1:2:x", "nonsense=1", "rs=a,b", "rs=1:2:0"):
        with pytest.raises(spec.SpecError):
            spec.parse_axis(bad)


def test_a_point_scales_speed_and_load_and_sets_parameters() -> None:
    sc = scenario.load("fig09_load_step_realtime")
    assert isinstance(sc, scenario.Scenario)
    axes = [spec.parse_axis(t) for t in ("speed_scale=0.5", "load_scale=0.25", "rs=2.2",
                                         "firmware.spd_kp=0.02")]
    p = spec.apply(sc, axes, {"speed_scale": 0.5, "load_scale": 0.25, "rs": 2.2,
                              "firmware.spd_kp": 0.02}, "x")
    targets = [s.to for s in sc.speed if s.to is not None]
    assert [s.to for s in p.speed if s.to is not None] == [0.5 * t for t in targets]
    assert [e.torque for e in p.load] == [0.25 * e.torque for e in sc.load]
    assert p.overrides["machine.rs_ohm"] == 2.2 and p.firmware["spd_kp"] == 0.02
    assert p.name == f"{sc.name}[x]" and p.criteria == sc.criteria


def test_a_seed_axis_on_a_scenario_over_its_own_seeds_is_refused(tmp_path: Path) -> None:
    # load_step_0001rpm runs seeds 1-4 itself: a sensors.seed axis gave identical rows
    own = scenario.load("load_step_0001rpm")
    assert isinstance(own, scenario.Scenario) and own.seeds
    seed_axis = [spec.parse_axis("sensors.seed=1,2")]
    with pytest.raises(spec.SpecError, match=r"sensors\.seed: .*own seeds \(1, 2, 3, 4"):
        spec.check_axes(own, seed_axis)
    with pytest.raises(spec.SpecError):
        spec.apply(own, seed_axis, {"sensors.seed": 2}, "x")
    single = scenario.load("smoke")
    assert isinstance(single, scenario.Scenario) and not single.seeds
    assert spec.apply(single, seed_axis, {"sensors.seed": 2}, "x").seed == 2
    r = subprocess.run(
        [sys.executable, "-m", "rig", "sweep", "load_step_0001rpm", "--param",
         "sensors.seed=1,2", "--out", str(tmp_path / "s"), "--quiet"],
        capture_output=True, text=True, check=False, timeout=120)
    assert r.returncode == 2 and "decided over its own seeds" in r.stderr, r.stderr
    assert not (tmp_path / "s").exists()


def test_the_summary_metric_reads_as_the_scenarios_criterion(tmp_path: Path) -> None:
    # a criterion's parameters: a recovery into 20 r/min, where the metric's own default is
    # 2 % of the 100 r/min it held (2 r/min)
    text = (scenario.SCENARIO_DIR / "load_step_0100rpm.toml").read_text()
    assert text.count("band_rpm = 2 }") == 2
    f = tmp_path / "load_step_wide_band.toml"
    f.write_text(text.replace("band_rpm = 2 }", "band_rpm = 20 }"))
    axes = (spec.parse_axis("load_scale=1"),)
    row = sweep_point.run(sweep_point.Task(0, str(f), axes, {"load_scale": 1.0},
                                           metric="recovery_time_s"))
    crit = row["crit.speed back within 2 r/min within 0.5 s"]
    assert row["status"] == "passed" and crit is not None, row
    assert row["metric_value"] == pytest.approx(crit, abs=1e-12)
    assert "metric_seeds" not in row
    # over its own seeds: each seed's value, and the worst of them, as the criterion's
    own = sweep_point.run(sweep_point.Task(0, "start_load_p2nm_040deg", axes,
                                           {"load_scale": 1.0}, metric="kickback_deg"))
    seeds = [float(x.split(": ")[1]) for x in str(own["metric_seeds"]).split(", ")]
    assert len(seeds) == 8 and len(set(seeds)) > 1, own["metric_seeds"]
    assert own["metric_value"] == pytest.approx(max(seeds), rel=1e-5)
    assert own["metric_value"] == pytest.approx(own["crit.shaft kick-back"], rel=1e-6)


def test_local_pool_sweep_writes_table_and_summary(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    r = subprocess.run(
        [sys.executable, "-m", "rig", "sweep", "smoke", "--param", "rs=1.8,2.1",
         "--param", "noise=0,0.03", "--workers", "2", "--out", str(out), "--quiet"],
        capture_output=True, text=True, check=False, timeout=600)
    rows = table.read(out / "sweep.parquet")
    assert len(rows) == 4, r.stderr
    # 30 mA of current-sensor noise drowns the slopes of a 10 us state on `ideal`: the start
    # loses the pole (measured: ~20 polarity losses, 180 deg, ~300 r/min of speed error, far
    # from every limit; 2, 4 and 8 mA pass)
    assert [bool(x["passed"]) for x in rows] == [True, False, True, False], r.stderr
    assert r.returncode == 1
    failed = [x for x in rows if not x["passed"]]
    assert all(x["failure_kind"] == "criteria" and "speed" in x["failure"] for x in failed)
    assert (out / "sweep.csv").read_text().count("\n") == 5
    assert "Pass rate: 2/4 (50.0 %)" in (out / "summary.md").read_text()
    assert (out / "worst_error.png").stat().st_size > 10_000
    info = json.loads((out / "sweep.json").read_text())
    assert info["points"] == 4 and info["cluster"]["workers_lost"] == 0
    # the last line names every file written, the plot too; the dashboard's address is given
    assert r.stderr.strip().splitlines()[-1].endswith(
        f"-> {out}: summary.md, sweep.csv, sweep.parquet, worst_error.png")
    assert "Dask dashboard at http://127.0.0.1:" in r.stderr
    # the Parquet columns have their types, whatever the rows hold
    schema = pq.read_schema(out / "sweep.parquet")
    assert schema.field("point").type == pa.int64()
    assert schema.field("param.rs").type == pa.float64()
    assert schema.field("passed").type == pa.bool_()
    assert schema.field("crit.position error while turning").type == pa.float64()
    assert pa.types.is_dictionary(schema.field("outcome.position error while turning").type)
    assert schema.field("failure").type == pa.string()  # null in the passing rows


def test_typed_columns_hold_when_no_row_fills_them() -> None:
    rows = [{"point": 0, "param.rs": 2, "status": "passed", "passed": True, "failure": None,
             "crit.x": None, "outcome.x": "not_evaluated"}]
    t = table.to_arrow(rows, ["rs"])
    assert [t.schema.field(c).type for c in ("point", "param.rs", "failure", "crit.x")] == [
        pa.int64(), pa.float64(), pa.string(), pa.float64()]
    empty = table.to_arrow([], ["rs", "noise"])  # an interrupted sweep before any point
    assert empty.num_rows == 0 and {"point", "param.rs", "param.noise", "passed",
                                    "metric_value"} <= set(empty.column_names)


def test_plots_name_their_units() -> None:
    assert [spec.unit_of(n) for n in ("rs", "ld", "lambda_m", "noise", "dead_time", "vdc",
                                      "magnetics.lq_sat_per_a2", "speed_scale")] == [
        "Ω", "H", "Wb", "A", "s", "V", "1/A²", "factor"]
    from rig.drive import params

    assert spec.unit_of("firmware.spd_kp") == params.table().lookup("spd_kp").unit
    rows = [{"point": 0, "param.rs": 1.9, "param.speed_scale": 1.0, "passed": True,
             "metric_value": 0.5}]
    fig = summary.plot(rows, ["rs", "speed_scale"], "pos_err_max_deg")
    labels = [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]
    assert labels == [("rs (Ω)", "pos_err_max_deg (deg)"),
                      ("speed_scale (factor)", "pos_err_max_deg (deg)")]
    # the title fits the picture, with one swept parameter too (it was cut off)
    for swept in (["rs"], ["rs", "speed_scale"]):
        fig = summary.plot(rows, swept, "pos_err_max_deg")
        renderer = fig.canvas.get_renderer()
        fig.canvas.draw()
        box = fig._suptitle.get_window_extent(renderer)
        assert box.x0 >= 0 and box.x1 <= fig.bbox.width and box.y1 <= fig.bbox.height


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A scheduler and two single-threaded workers (with nannies) on 127.0.0.1."""
    with dask_support.cluster(tmp_path_factory.mktemp("dask")) as c:
        yield c.address


def test_sweep_on_a_dask_cluster_survives_a_killed_worker(dask_cluster: str,
                                                           tmp_path: Path) -> None:
    axes = [spec.parse_axis("rs=1.8,2.0,2.2"), spec.parse_axis("sensors.seed=1,-1")]
    points = spec.grid(axes)
    tasks = sweep_point.tasks("smoke", axes, points)
    marker = tmp_path / "killed"
    victim = 2
    task_fn = sweep_tasks.die_once_at(str(marker), victim)
    import cloudpickle

    cloudpickle.register_pickle_by_value(sweep_tasks)  # the workers cannot import tests/
    outcome = engine.Outcome()
    with engine.client(dask_cluster, 0) as c:
        rows = engine.run_tasks(c, tasks, task_fn, retries=2, progress=False, outcome=outcome)
    assert marker.exists(), "the victim's worker was never killed"
    # what the cluster went through is counted: the worker that died, the point run again
    assert len(outcome.workers_lost) == 1 and outcome.rerun >= 1, outcome
    assert outcome.gave_up is None
    assert [r["point"] for r in rows] == list(range(len(points)))
    good = [r for r in rows if r["param.sensors.seed"] == 1]
    bad = [r for r in rows if r["param.sensors.seed"] == -1]
    # the point whose worker died was run again on a live worker, to the same verdict
    assert rows[victim]["passed"] is True and rows[victim]["param.rs"] == 2.0
    assert all(r["passed"] for r in good) and len(good) == 3
    # a point the plant refuses is a row with its reason, never dropped
    assert len(bad) == 3 and all(r["status"] != "passed" for r in bad)
    assert all("sensors.seed" in str(r["failure"]) for r in bad), bad[0]["failure"]
    table.write(rows, tmp_path)
    assert len(pq.read_table(tmp_path / "sweep.parquet")) == 6
    md = summary.markdown(rows, ["rs", "sensors.seed"], {"scenario": "smoke",
                                                         "metric": "pos_err_max_deg"})
    assert "Pass rate: 3/6 (50.0 %)" in md


def test_rig_sweep_cli_on_the_cluster(dask_cluster: str, tmp_path: Path) -> None:
    out = tmp_path / "cli"
    r = subprocess.run(
        [sys.executable, "-m", "rig", "sweep", "smoke", "--param", "rs=1.9,2.0",
         "--scheduler", dask_cluster, "--out", str(out), "--quiet"],
        capture_output=True, text=True, check=False, timeout=600)
    assert r.returncode == 0, r.stderr
    rows = table.read(out / "sweep.parquet")
    assert [x["passed"] for x in rows] == [True, True]
    assert "Pass rate: 2/2" in (out / "summary.md").read_text()


@pytest.mark.timeout(300)
def test_a_cluster_without_workers_ends_the_sweep_instead_of_waiting() -> None:
    from distributed import Client, LocalCluster

    tasks = sweep_point.tasks("smoke", [spec.parse_axis("rs=1.9,2.0")],
                              spec.grid([spec.parse_axis("rs=1.9,2.0")]))
    outcome = engine.Outcome()
    with LocalCluster(n_workers=0, processes=True, dashboard_address=None,
                      host="127.0.0.1") as cluster, Client(cluster) as c:
        t0 = time.monotonic()
        rows = engine.run_tasks(c, tasks, progress=False, no_worker_timeout_s=3.0,
                                outcome=outcome)
        waited = time.monotonic() - t0
    assert 3.0 <= waited < 60.0
    assert [r["failure_kind"] for r in rows] == ["no_workers", "no_workers"]
    assert outcome.gave_up is not None and "no worker for 3 s" in outcome.gave_up
    assert all(outcome.gave_up == r["failure"] for r in rows)


def test_an_interrupted_sweep_keeps_its_table_and_leaves_no_scratch(tmp_path: Path) -> None:
    scratch_root = tmp_path / "tmp"
    scratch_root.mkdir()
    out = tmp_path / "sweep"
    env = {**os.environ, "TMPDIR": str(scratch_root)}
    p = subprocess.Popen(
        [sys.executable, "-m", "rig", "sweep", "table2_1000rpm_1nm", "--param",
         "rs=1.8,1.9,2.0,2.1", "--workers", "2", "--out", str(out), "--quiet"],
        stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 120
    while not any(scratch_root.glob("rig-sweep-*/rig-sweep-*")):  # points running
        assert time.monotonic() < deadline and p.poll() is None, p.stderr
        time.sleep(0.2)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "interrupted after" in err and f"are in {out}" in err
    assert (out / "sweep.csv").is_file() and (out / "sweep.parquet").is_file()
    assert (out / "summary.md").is_file()
    n_rows = len(table.read(out / "sweep.parquet"))
    assert f"; their {n_rows} rows are in" in err
    assert list(scratch_root.glob("rig-sweep-*")) == []  # (dask-scratch-space is Dask's)
