"""``rig sweep``: one scenario over a grid or a random sample of overrides."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE

EPILOG = """\
axes (--param NAME=SPEC, repeatable):
  NAME  a plant profile key section.key, firmware.NAME (a firmware parameter),
        speed_scale / load_scale (the scenario's speed targets / load torques times the
        value), or a short name: rs, ld, lq, lambda_m, noise, dead_time, device_drop, vdc
  SPEC  LO:HI:N  N values from LO to HI          (grid or random)
        LO:HI    uniform in [LO, HI]             (random only)
        V1,V2    these values                    (grid or random)

examples:
  rig sweep table2_1000rpm_1nm --param rs=1.7:2.5:5 --param lq=0.028,0.032,0.036
  rig sweep fig09_load_step_realtime --random 200 --param rs=1.6:2.6 --param noise=0:0.005
  rig sweep smoke --param rs=1.5:2.5:9 --scheduler tcp://10.0.0.5:8786

The summary metric takes the parameters of the scenario's criterion on it (a recovery's
band, ...). A scenario decided over its own seeds ([run] seeds) runs all of them at every
point: its row holds each criterion's worst seed, the summary metric's worst seed and every
seed's value (metric_seeds); a sensors.seed axis on it is refused.

Writes sweep.csv and sweep.parquet (one row per point: parameters, verdict, failure reason,
every criterion's value and outcome, the summary metric), summary.md (pass rate, worst
points) and worst_error.png. Exit status: 0 every point passed, 1 some did not, 2 usage,
3 environment (scheduler unreachable), 130 interrupted.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "sweep", help="run a scenario over a grid or random sample of overrides",
        description="Run one scenario at many points of its parameters, on a local process "
        "pool or a Dask cluster (the in-process bench by default: fast).",
        epilog=EPILOG)
    p.add_argument("scenario", metavar="SCENARIO", help="scenario name or file (name@profile)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=SPEC", required=True,
                   help="a swept axis (repeatable; see below)")
    p.add_argument("--random", type=cliargs.number(int, minimum=1), default=0, metavar="N",
                   help="N random points instead of the grid")
    p.add_argument("--seed", type=int, default=1, help="seed of --random (default 1)")
    cliargs.add_shared(p, "bus", choices=cliargs.BUS_WITH_INPROC, default="inproc",
                       help="inproc (default), or a transport to run the points on the bus")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="an existing Dask scheduler (default: a local process pool)")
    p.add_argument("--workers", type=cliargs.number(int, minimum=1),
                   default=os.cpu_count() or 1,
                   help="local pool size (default: the number of CPUs)")
    p.add_argument("--retries", type=cliargs.number(int, minimum=0), default=2,
                   help="times a point is retried when its worker dies (default 2)")
    p.add_argument("--metric", default="pos_err_max_deg",
                   help="summary metric (rig list --metrics; default pos_err_max_deg)")
    p.add_argument("--window", type=cliargs.window, default=None, metavar="T0,T1",
                   help="its window in s (default: the scenario's criterion window on that "
                   "metric, else the second half)")
    p.add_argument("--no-worker-timeout", type=cliargs.number(above=0.0), default=60.0,
                   metavar="S", help="end the sweep when the cluster has had no worker for S "
                   "seconds (default 60); its unfinished points are failed rows")
    cliargs.add_shared(p, "out", type=Path, help="output folder")
    cliargs.add_shared(p, "quiet", help="no progress line")
    cliargs.command(p, cmd_sweep)


def cmd_sweep(args: argparse.Namespace) -> int:
    from rig import scenario
    from rig.data import metrics
    from rig.run import runner
    from rig.supervisor import Terminated, terminate_as_exception
    from rig.sweep import engine, spec
    from rig.sweep import point as sweep_point

    try:
        sc = scenario.load(args.scenario)
        if not isinstance(sc, scenario.Scenario):
            raise spec.SpecError(f"{args.scenario} is a suite: sweep one scenario")
        axes = [spec.parse_axis(a) for a in args.param]
        if len({a.name for a in axes}) != len(axes):
            raise spec.SpecError("an axis is given twice")
        spec.check_axes(sc, axes)
        points = (spec.sample(axes, args.random, args.seed) if args.random > 0
                  else spec.grid(axes))
        window = args.window
        if window is not None and window[1] > sc.duration:
            raise spec.SpecError(f"--window {window[0]:g},{window[1]:g}: {sc.name} lasts "
                                 f"{sc.duration:g} s")
        if not metrics.known(args.metric):
            raise spec.SpecError(f"--metric {args.metric}: unknown (rig list --metrics)")
    except (FileNotFoundError, scenario.ScenarioError, spec.SpecError, ValueError) as exc:
        print(f"rig sweep: {exc}", file=sys.stderr)
        return EXIT_USAGE
    out = args.out or runner.default_out(f"sweep-{sc.name}")
    out.mkdir(parents=True, exist_ok=True)
    # the points' scratch folders, under one this process removes whatever ends the sweep
    # (a worker killed mid-point cannot clean its own; remote workers use their own temp)
    scratch = None if args.scheduler else Path(tempfile.mkdtemp(prefix="rig-sweep-"))
    tasks = sweep_point.tasks(args.scenario, axes, points, bus=args.bus, metric=args.metric,
                              window=window, scratch=str(scratch) if scratch else None)
    info: dict[str, Any] = {
        "schema": "hil-sweep/1", "scenario": sc.name, "points": len(tasks),
        "mode": f"random {args.random} (seed {args.seed})" if args.random else "grid",
        "axes": [{"name": a.name, "key": a.key, "values": list(a.values), "low": a.low,
                  "high": a.high} for a in axes],
        "bus": args.bus, "metric": args.metric, "window": window,
        "engine": f"dask {args.scheduler}" if args.scheduler
        else f"local process pool ({args.workers} workers)",
    }
    (out / "sweep.json").write_text(json.dumps(info, indent=1))
    print(f"rig sweep: {len(tasks)} points of {sc.name} on {info['engine']} -> {out}",
          file=sys.stderr)
    done: list[dict[str, Any]] = []
    outcome = engine.Outcome()
    try:
        with terminate_as_exception(), engine.client(args.scheduler, args.workers) as c:
            link = engine.dashboard_link(c)
            print(f"rig sweep: Dask dashboard at {link}" if link else
                  "rig sweep: no Dask dashboard (the scheduler serves none; locally it needs "
                  "bokeh)", file=sys.stderr)
            rows = engine.run_tasks(c, tasks, retries=args.retries, progress=not args.quiet,
                                    on_row=done.append,
                                    no_worker_timeout_s=args.no_worker_timeout,
                                    outcome=outcome)
    except (OSError, TimeoutError) as exc:
        print(f"rig sweep: cannot reach the cluster: {exc}", file=sys.stderr)
        return EXIT_ENV
    except (KeyboardInterrupt, Terminated):
        # the points that finished are kept: the table of what there is (perhaps no row)
        info["interrupted_after"] = len(done)
        info["cluster"] = outcome.to_json()
        (out / "sweep.json").write_text(json.dumps(info, indent=1))
        rows = sorted(done, key=lambda r: int(r["point"]))
        files = _write(rows, axes, info, out)
        print(f"rig sweep: interrupted after {len(done)} of {len(tasks)} points; their "
              f"{len(rows)} rows are in {out} ({', '.join(files)})", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    info["cluster"] = outcome.to_json()
    (out / "sweep.json").write_text(json.dumps(info, indent=1))
    files = _write(rows, axes, info, out)
    passed = sum(1 for r in rows if r.get("passed"))
    print(f"rig sweep: {passed}/{len(rows)} points passed -> {out}: {', '.join(files)}",
          file=sys.stderr)
    if outcome.workers_lost or outcome.rerun or outcome.gave_up:
        print(f"rig sweep: {len(outcome.workers_lost)} workers lost, {outcome.rerun} points "
              "run again on another worker"
              + (f"; {outcome.gave_up}" if outcome.gave_up else ""), file=sys.stderr)
    return EXIT_OK if passed == len(rows) else EXIT_FAIL


def _write(rows: list[dict[str, Any]], axes: list[Any], info: dict[str, Any],
           out: Path) -> list[str]:
    """The table and the summary (an empty table when no point finished); the file names."""
    from rig.sweep import summary, table

    names = [a.name for a in axes]
    csv_path, parquet_path = table.write(rows, out, params=names)
    files = [csv_path.name, parquet_path.name]
    report = summary.write(rows, names, info, out)
    files.insert(0, report.name)
    if (out / summary.PLOT).exists():
        files.append(summary.PLOT)
    return files
