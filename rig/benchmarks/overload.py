"""``rig bench overload``: a suite (default: paper) on the fallback bus in lockstep while CPU
hogs saturate every core, against the same suite in process.

The lockstep loses nothing under overload: every criterion's value and outcome must be the
in-process run's, no node of the run drops a frame for another (they are lossless: a sender
waits for a full node), and every frame of a message the rig listens to reaches it. A
listener on the channel (``hilbus_tool recv``, printing every frame: a candump of sorts) may
fall behind, as on SocketCAN; what it missed is counted. Prints one JSON object: the values
compared, the lockstep's waits (how many, in all, the longest), stall failures, the drops
between the run's nodes, the frames the rig missed, the listener's misses, wall times and the
load average. The hogs and the suite run at the benchmark's own niceness (`nice -n 10 rig
bench overload` on a shared machine keeps other users ahead of both)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rig import _paths, cliargs
from rig import bus as rigbus
from rig.benchmarks import together


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--suite", default="paper", help="the suite to run (default: paper)")
    p.add_argument("--hogs", type=cliargs.number(int, minimum=0, maximum=64), default=None,
                   metavar="N", help="CPU hogs (busy loops) beside the bus run (default: one "
                   "per core)")
    p.add_argument("--no-listener", action="store_true",
                   help="no listener on the channel")
    p.add_argument("--jobs", "-j", type=cliargs.number(int, minimum=1, maximum=64), default=2,
                   metavar="N", help="worker processes of the in-process reference (default 2)")
    cliargs.add_shared(p, "out", type=Path,
                       help="keep both suites' folders here (default: a temporary folder)")


def _suite(name: str, out: Path, *bus: str) -> tuple[int, float]:
    t0 = time.monotonic()
    code, _ = together.finish(together.rig(
        "run", name, *bus, "--out", str(out), "--no-record", "--no-figures", "--baseline",
        "off", "--quiet"))
    return code, time.monotonic() - t0


def measure(args: argparse.Namespace) -> dict[str, Any]:
    hogs_n = (os.cpu_count() or 1) if args.hogs is None else args.hogs
    with tempfile.TemporaryDirectory(prefix="rig-bench-overload-") as tmp:
        root = Path(args.out) if args.out is not None else Path(tmp)
        inproc_code, inproc_wall = _suite(args.suite, root / "inproc", "--bus", "inproc",
                                          "--jobs", str(args.jobs))
        channel = rigbus.own_channel("overload")
        listener = None
        if not args.no_listener:
            listener = subprocess.Popen(
                [str(_paths.binary("hilbus_tool")), "recv", "--bus", "unixcan", "--channel",
                 channel, "--count", "0", "--timeout-ms", "3600000"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                for _ in range(hogs_n)]
        load_before = os.getloadavg()
        try:
            bus_code, bus_wall = _suite(args.suite, root / "bus", "--bus", "unixcan",
                                        "--channel", channel)
            load_after = os.getloadavg()
        finally:
            for proc in [*hogs, *([listener] if listener is not None else [])]:
                proc.terminate()
            for proc in [*hogs, *([listener] if listener is not None else [])]:
                proc.wait(timeout=30)
        rigbus.release_own_channel(channel)
        bus = together.scenario_results(root / "bus")
        runs = together.single_runs(root / "bus")
        inproc = together.scenario_results(root / "inproc")
    values = together.compare(bus, inproc)
    return {
        "benchmark": "overload", "suite": args.suite, "cpus": os.cpu_count(), "hogs": hogs_n,
        "listener": not args.no_listener,
        "load_average_1min": {"before": round(load_before[0], 1),
                              "after": round(load_after[0], 1)},
        "exit": {"inproc": inproc_code, "bus": bus_code},
        "scenarios": {"inproc": together.statuses(inproc), "bus": together.statuses(bus)},
        "values_compared": values["values"], "values_identical": values["identical"],
        "differences": values["differences"],
        **together.bus_figures(runs),
        "wall_s": {"inproc": round(inproc_wall, 1), "bus": round(bus_wall, 1)},
    }
