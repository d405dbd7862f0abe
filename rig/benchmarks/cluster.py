"""``rig bench cluster``: a suite on a local Dask cluster of 1, 2 and 4 workers (``rig run
SUITE --bus inproc --cluster``), each count timed (wall and CPU), the speed-up over one
worker, and the speed-up expected.

What bounds the speed-up: the cores (a worker runs one scenario at a time on one core: on
this machine's ``host_cpus`` cores no more than that many workers gain), and the longest run
of the suite (the runs start longest first, so ``n`` workers need at least max(total work /
n, longest run)): ``expected_speedup`` is min(n, cores, total / longest) for workers on one
machine, ``expected_speedup_machines`` the same with one core per worker (n machines). The
coordination costs a little on top: each run's folder travels back packed, and each worker
starts its Python once. The load average is printed beside: on a shared machine the other
processes take cores away from the workers."""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rig import scenario
from rig.benchmarks import machine

DEFAULT_SUITE = "table2_paper"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--suite", default=DEFAULT_SUITE,
                   help=f"the suite to run (default {DEFAULT_SUITE}: 14 runs, 26 simulated s)")
    p.add_argument("--workers", type=_counts, default=(1, 2, 4), metavar="N,N,...",
                   help="worker counts to time (default 1,2,4)")
    p.add_argument("--baseline", choices=("require", "auto", "off"), default="auto",
                   help="as rig run (default auto)")


def _counts(text: str) -> tuple[int, ...]:
    try:
        counts = tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        counts = ()
    if not counts or min(counts) < 1 or max(counts) > 64:
        raise argparse.ArgumentTypeError(f"{text!r}: worker counts from 1 to 64, e.g. 1,2,4")
    return counts


def expected(n: int, cores: int | None, total: float, longest: float) -> float:
    """The speed-up ``n`` workers can reach at best: ``cores`` of them at once (None: one
    core each), and no faster than the longest run."""
    by_jobs = total / longest if longest > 0 else float(n)
    return round(min(float(n), float(cores or n), by_jobs), 2)


def _timed(suite: str, workers: int, baseline: str, out: Path) -> dict[str, Any]:
    from distributed import LocalCluster

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None, host="127.0.0.1") as lc:
        started = time.monotonic() - t0
        t1 = time.monotonic()
        p = subprocess.run([sys.executable, "-m", "rig", "run", suite, "--bus", "inproc",
                            "--cluster", lc.scheduler_address, "--baseline", baseline,
                            "--no-record", "--failing-figures", "--quiet", "--out", str(out)],
                           capture_output=True, text=True, check=False)
        wall = time.monotonic() - t1
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        passed = bool(json.loads((out / "result.json").read_text()).get("passed"))
    except (OSError, ValueError):
        passed = False
    return {"workers": workers, "exit": p.returncode, "passed": passed,
            "wall_s": round(wall, 1), "cluster_start_s": round(started, 1),
            "cpu_s": round((after.ru_utime - before.ru_utime)
                           + (after.ru_stime - before.ru_stime), 1),
            "load_average": machine.load_average()}


def measure(args: argparse.Namespace) -> dict[str, Any]:
    counts = list(args.workers)
    suite = scenario.load(args.suite)
    if not isinstance(suite, scenario.Suite):
        raise SystemExit(f"rig bench cluster: {args.suite} is not a suite")
    work = [sc.duration * max(1, len(sc.seeds)) for sc in suite.scenarios]
    total, longest = sum(work), max(work)
    cores = os.cpu_count()
    report: dict[str, Any] = {"benchmark": "cluster", **machine.described(),
                              "suite": suite.name, "runs": len(work),
                              "sim_s": round(total, 1), "longest_run_sim_s": round(longest, 1)}
    runs = []
    with tempfile.TemporaryDirectory(prefix="rig-bench-cluster-") as tmp:
        for n in counts:
            runs.append(_timed(suite.name, n, args.baseline, Path(tmp) / f"w{n}"))
    base = next((r["wall_s"] for r in runs if r["workers"] == 1), runs[0]["wall_s"])
    for r in runs:
        r["speedup"] = round(base / r["wall_s"], 2) if r["wall_s"] else None
        r["expected_speedup"] = expected(r["workers"], cores, total, longest)
        r["expected_speedup_machines"] = expected(r["workers"], None, total, longest)
    report["by_workers"] = runs
    report["load_average_after"] = machine.load_average()
    return report

