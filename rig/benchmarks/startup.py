"""``rig bench startup``: what a scenario run costs before its closed loop starts.

Runs ``rig run SCENARIO --bus inproc --no-record`` in a new Python process ``--repeat``
times (after one run that fills the bytecode cache) and prints one JSON object:

- ``startup_cpu_s``: the process's CPU time when the closed loop starts (its first grant):
  interpreter, imports, scenario, plan, bench; median, min and max over the runs;
- ``process_cpu_s``, ``wall_s``: the whole process, for comparison;
- ``imports``: from ``python -X importtime`` of one more run, the imports before the loop
  starts: their total and the largest top-level ones (cumulative ms);
- ``loaded_at_start``: which of the heavy libraries a run needs only afterwards (recording,
  figures, export, sweeps) were loaded by then: all should be false.

The child is ``python -m rig`` with a probe around the in-process bench's first grant; the
bytecode cache is written (``PYTHONDONTWRITEBYTECODE`` is removed for the children), as it
is for an installed rig after its first run.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rig import cliargs

DEFAULT_SCENARIO = "smoke"
MARK = "rig-bench-startup:"
HEAVY = ("asammdf", "pandas", "pyarrow", "rerun", "matplotlib", "distributed", "scipy")
PROBE = f"""
import sys, time
from rig.bench import sil
_first = sil.SilBench.run_until
def _probe(self, until):
    if not getattr(_probe, "done", False):
        _probe.done = True
        import json
        print({MARK!r} + json.dumps({{"cpu_s": time.process_time(),
              "loaded": [m for m in {HEAVY!r} if m in sys.modules]}}),
              file=sys.stderr, flush=True)
    return _first(self, until)
sil.SilBench.run_until = _probe
from rig.cli import main
sys.exit(main(sys.argv[1:]))
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default=DEFAULT_SCENARIO,
                   help=f"scenario to start (default {DEFAULT_SCENARIO})")
    p.add_argument("--repeat", type=cliargs.number(int, minimum=1), default=5,
                   help="measured runs (default 5)")
    p.add_argument("--imports", type=cliargs.number(int, minimum=0), default=12,
                   help="largest top-level imports listed (default 12)")


def _child(argv: list[str], importtime: bool = False) -> tuple[dict[str, Any], str, float,
                                                                float]:
    """Runs the probe; (its mark, stderr before the mark, process CPU s, wall s)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    cmd = [sys.executable, *(["-X", "importtime"] if importtime else []), "-c", PROBE, *argv]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    head, sep, tail = done.stderr.partition(MARK)
    if not sep:
        raise RuntimeError(f"rig bench startup: the run did not start its loop "
                           f"(exit {done.returncode}): {done.stderr.strip()[-800:]}")
    mark: dict[str, Any] = json.loads(tail.splitlines()[0])
    if done.returncode not in (0, 1):
        raise RuntimeError(f"rig bench startup: the run failed (exit {done.returncode}): "
                           f"{done.stderr.strip()[-800:]}")
    return mark, head, cpu, wall


def largest_imports(importtime: str, n: int) -> tuple[float, list[dict[str, Any]]]:
    """(total ms, the n largest top-level imports) from ``-X importtime`` lines."""
    top: list[tuple[str, float]] = []
    for line in importtime.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        _self, cumulative, name = line[len("import time:"):].split("|", 2)
        if not name.startswith(" ") or name.startswith("  "):
            continue  # nested: counted in its top-level import
        top.append((name.strip(), int(cumulative) / 1000.0))
    total = sum(ms for _, ms in top)
    top.sort(key=lambda x: -x[1])
    return round(total, 1), [{"module": m, "cumulative_ms": round(ms, 1)} for m, ms in top[:n]]


def _stats(values: list[float]) -> dict[str, float]:
    return {"median": round(statistics.median(values), 4), "min": round(min(values), 4),
            "max": round(max(values), 4)}


def measure(args: argparse.Namespace) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="rig-bench-startup-") as tmp:
        def argv(k: int) -> list[str]:
            return ["run", args.scenario, "--bus", "inproc", "--no-record", "--quiet",
                    "--out", str(Path(tmp) / f"run{k}")]

        _child(argv(0))  # fills the bytecode cache
        runs = [_child(argv(k + 1)) for k in range(args.repeat)]
        mark, importtime, _cpu, _wall = _child(argv(args.repeat + 1), importtime=True)
    total_ms, largest = largest_imports(importtime, args.imports)
    return {
        "benchmark": "startup", "scenario": args.scenario, "repeat": args.repeat,
        "python": sys.version.split()[0], "host_cpus": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "startup_cpu_s": _stats([m["cpu_s"] for m, _, _, _ in runs]),
        "process_cpu_s": _stats([c for _, _, c, _ in runs]),
        "wall_s": _stats([w for _, _, _, w in runs]),
        "imports": {"before_loop_ms": total_ms, "largest": largest},
        "loaded_at_start": {m: m in mark["loaded"] for m in HEAVY},
    }
