"""``rig bench gate``: how long the regression gate takes (wall and CPU, per suite).

The gate is what a developer runs on every firmware change and what CI judges against the
baselines: its time is a target (at most 3 min on 2 idle cores), measured here as a figure,
not asserted by a test that a loaded machine would make flaky. The CPU time includes the
worker processes (RUSAGE_CHILDREN), so the figure says what the gate costs whatever else
the machine is doing."""

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

from rig import cliargs


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--suite", default="gate", help="the suite to time (default: gate)")
    p.add_argument("--jobs", "-j", type=cliargs.number(int, minimum=1, maximum=64), default=2,
                   help="worker processes (default 2)")
    p.add_argument("--baseline", choices=("require", "auto", "off"), default="require",
                   help="as rig run (default require, as CI runs it)")


def measure(args: argparse.Namespace) -> dict[str, Any]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with tempfile.TemporaryDirectory(prefix="rig-bench-gate-") as tmp:
        out = Path(tmp) / "gate"
        t0 = time.monotonic()
        p = subprocess.run([sys.executable, "-m", "rig", "run", args.suite, "--bus", "inproc",
                            "--jobs", str(args.jobs), "--baseline", args.baseline,
                            "--no-record", "--quiet", "--out", str(out)],
                           capture_output=True, text=True, check=False)
        wall = time.monotonic() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        try:
            summary = json.loads((out / "result.json").read_text())
        except (OSError, ValueError):
            summary = {}
    entries = summary.get("scenarios") or []
    slowest = sorted(entries, key=lambda e: -(e.get("wall_s") or 0.0))[:5]
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {
        "suite": args.suite, "jobs": args.jobs, "cpus": os.cpu_count(),
        "exit": p.returncode, "passed": bool(summary.get("passed")),
        "scenarios": len(entries), "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
        "sim_s": round(sum(float(e.get("sim_s") or 0.0) for e in entries), 1),
        "slowest": [{"scenario": e["name"], "wall_s": e.get("wall_s")} for e in slowest],
        "target_wall_s": 180.0,
    }
