"""``rig bench apart``: runs apart by default. A suite (default: paper) and a second one
(default: faults) on the fallback bus and a commissioning session on the virtual bench
(``rig commission all --bench virtual``), started together and none naming a channel, then
the two suites in process and the session alone.

Each gets a channel of its own (``rig.bus.own_channel``; the session's load bench a free
port), so all pass as they pass alone: every criterion value identical to the in-process
run's, the session's identified values identical to the session's alone. Prints one JSON
object (exit statuses, the channels used, the values compared, the lockstep's figures, wall
times); takes about as long as the suites on the bus (the paper suite: minutes)."""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from rig import cliargs
from rig.benchmarks import together


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--suite", default="paper", help="the first suite (default: paper)")
    p.add_argument("--second", default="faults", help="the second suite (default: faults)")
    p.add_argument("--steps", default="all",
                   help="the commissioning steps (default: all)")
    p.add_argument("--jobs", "-j", type=cliargs.number(int, minimum=1, maximum=64), default=2,
                   metavar="N", help="worker processes of the in-process runs (default 2)")
    cliargs.add_shared(p, "out", type=Path,
                       help="keep every folder here (default: a temporary folder)")


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("HIL_CHANNEL", "HIL_BUS")}


def _suite_args(name: str, out: Path, *bus: str) -> list[str]:
    return ["run", name, *bus, "--out", str(out), "--no-record", "--no-figures", "--baseline",
            "off", "--quiet"]


def _commission_args(steps: str, out: Path) -> list[str]:
    return ["commission", *steps.split(","), "--bench", "virtual", "--set",
            "can.transport=unixcan", "--out", str(out), "--quiet"]


def _session(out: Path) -> dict[str, Any]:
    try:
        data: dict[str, Any] = json.loads((out / "commissioning.json").read_text())
    except (OSError, ValueError):
        return {}
    return data


def measure(args: argparse.Namespace) -> dict[str, Any]:
    env = _env()
    with tempfile.TemporaryDirectory(prefix="rig-bench-apart-") as tmp:
        root = Path(args.out) if args.out is not None else Path(tmp)
        t0 = time.monotonic()
        procs = {
            "suite": together.rig(*_suite_args(args.suite, root / "bus-1", "--bus", "unixcan"),
                                  env=env),
            "second": together.rig(*_suite_args(args.second, root / "bus-2", "--bus",
                                                "unixcan"), env=env),
            "commission": together.rig(*_commission_args(args.steps, root / "session"),
                                       env=env),
        }
        exits = {k: together.finish(p)[0] for k, p in procs.items()}
        together_wall = time.monotonic() - t0
        refs = {
            "suite": together.finish(together.rig(*_suite_args(
                args.suite, root / "inproc-1", "--bus", "inproc", "--jobs", str(args.jobs)),
                env=env))[0],
            "second": together.finish(together.rig(*_suite_args(
                args.second, root / "inproc-2", "--bus", "inproc", "--jobs", str(args.jobs)),
                env=env))[0],
            "commission": together.finish(together.rig(
                *_commission_args(args.steps, root / "session-alone"), env=env))[0],
        }
        bus1, bus2 = (together.scenario_results(root / d) for d in ("bus-1", "bus-2"))
        ref1, ref2 = (together.scenario_results(root / d) for d in ("inproc-1", "inproc-2"))
        runs = {f"{k}/{name}": v for k, d in (("1", "bus-1"), ("2", "bus-2"))
                for name, v in together.single_runs(root / d).items()}
        session, alone = _session(root / "session"), _session(root / "session-alone")
    first, second = together.compare(bus1, ref1), together.compare(bus2, ref2)
    ids, ids_alone = session.get("identified") or {}, alone.get("identified") or {}
    channels = sorted({str(d.get("channel")) for d in (*bus1.values(), *bus2.values())})
    return {
        "benchmark": "apart", "suites": [args.suite, args.second], "steps": args.steps,
        "cpus": os.cpu_count(), "exit_together": exits, "exit_alone": refs,
        "channels": {"suites": channels, "commission": session.get("can")},
        "values_compared": first["values"] + second["values"],
        "values_identical": first["identical"] + second["identical"],
        "differences": first["differences"] + second["differences"],
        "commission_passed": bool(session.get("passed")),
        "commission_identified": ids,
        "commission_identical_to_alone": bool(ids) and ids == ids_alone,
        **together.bus_figures(runs),
        "wall_s_together": round(together_wall, 1),
    }
