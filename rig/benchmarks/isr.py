"""Times fw_core_isr() on the host (sil_bench: the core against the real plant in one
process, RUN state at 1000 r/min) and counts instructions per call with callgrind (one dump
per call; the 1 kHz tasks run on a fixed period residue, so calls are grouped by period mod
10 to tell the 10 kHz path from the 1 kHz path)."""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from rig import _paths, cliargs
from rig.benchmarks.plant import PROFILES

HELP = "firmware ISR cost per period: ns on this host, instructions (callgrind)"


def add_arguments(i: argparse.ArgumentParser) -> None:
    i.add_argument("--periods", type=cliargs.number(int, minimum=1), default=20000,
                   help="RUN-state periods timed")
    i.add_argument("--callgrind-periods", type=cliargs.number(int, minimum=0), default=400,
                   help="RUN-state periods under callgrind (0: skip callgrind)")
    i.add_argument("--profile", default="paper", choices=PROFILES,
                   help="plant fidelity profile")
    i.add_argument("--target", choices=("host", "cortex-m4f", "cortex-m3"), default="host",
                   help="cortex-m4f (single-precision FPU) or cortex-m3 (no FPU, soft float): "
                   "instructions per call on the emulated part by path and by ISR step "
                   "(rig.benchmarks.isr_m4), beside the host's callgrind figure")
    i.add_argument("--scale", type=cliargs.number(above=0.0), default=None,
                   help="cortex-m*: each measured stretch this many times the CI test's "
                   "(default 4 on the M4F, 1 on the M3: its soft float is ten times the "
                   "instructions)")
    i.add_argument("--coverage", metavar="SUITE", nargs="?", const="gate", default=None,
                   help="cortex-m4f: instead of the budget, which basic blocks of the ISR the "
                   "gate's cost windows execute of those the event windows of every scenario "
                   "of SUITE (default gate) execute (rig.target_m4.coverage; minutes)")
    i.add_argument("--whole-runs", action="store_true",
                   help="cortex-m*: the cases' whole runs (minutes; hours on the M3)")


def sil_bench_argv(profile: str, periods: int) -> list[str]:
    """The in-process bench program on a fidelity profile, ``periods`` periods in RUN."""
    path = _paths.data_dir("profiles") / f"{profile}.toml"
    return [str(_paths.binary("sil_bench")), "--profile", str(path), "--periods", str(periods)]


def measure(args: argparse.Namespace) -> dict[str, Any]:
    if args.coverage is not None:
        from rig.target_m4 import coverage

        return {"benchmark": "isr", "target": "cortex-m4f",
                "coverage": coverage.measure(args.coverage)}
    if args.target != "host":
        # the emulator (unicorn, 70 ms to import) only for these targets, not on every start
        from rig.benchmarks import isr_m4

        cg = (callgrind_isr(sil_bench_argv(args.profile, args.callgrind_periods),
                            args.callgrind_periods) if args.callgrind_periods > 0 else None)
        scale = args.scale if args.scale is not None else (
            4.0 if args.target == "cortex-m4f" else 1.0)
        return isr_m4.measure(scale, args.whole_runs, cg, args.target)
    argv = sil_bench_argv(args.profile, args.periods)
    timed = subprocess.run([*argv, "--time-isr"], capture_output=True, text=True, check=True)
    report: dict[str, Any] = {"benchmark": "isr", "host_timing": json.loads(timed.stdout)}
    if args.callgrind_periods > 0:
        report["instructions"] = callgrind_isr(
            sil_bench_argv(args.profile, args.callgrind_periods), args.callgrind_periods)
    return report


def callgrind_isr(argv: list[str], periods: int) -> dict[str, Any]:
    """Instructions per fw_core_isr() call, 10 kHz and 1 kHz paths, from callgrind dumps."""
    if shutil.which("valgrind") is None:
        return {"skipped": "valgrind not installed"}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cg.out"
        subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                        "--toggle-collect=fw_core_isr", "--dump-after=fw_core_isr",
                        "--dump-instr=no", *argv],
                       capture_output=True, text=True, check=True)
        dumps = sorted(Path(tmp).glob("cg.out.*"), key=lambda p: int(p.name.rsplit(".", 1)[1]))
        per_call = [_callgrind_total(p) for p in dumps]
    run = per_call[-periods:]  # the bench ends with `periods` calls in the RUN state
    groups: dict[int, list[int]] = {k: run[k::10] for k in range(10)}
    slow_key = max(groups, key=lambda k: statistics.median(groups[k]))
    fast = [v for k, g in groups.items() if k != slow_key for v in g]
    slow = groups[slow_key]
    return {
        "calls_measured": len(run),
        "isr_10khz": {"median": statistics.median(fast), "max": max(fast)},
        "isr_1khz": {"median": statistics.median(slow), "max": max(slow)},
    }


def _callgrind_total(path: Path) -> int:
    for line in path.read_text().splitlines():
        if line.startswith("totals:"):
            return int(line.split()[1])
    return 0
