"""What the benchmarks of runs side by side share: starting ``rig`` commands, reading a suite
folder's criterion values and bus figures, comparing two suites value for value."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any


def rig(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    """``rig ARGS`` as a child process, its output in a pipe."""
    return subprocess.Popen([sys.executable, "-m", "rig", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True,
                            env=env if env is not None else dict(os.environ))


def finish(proc: subprocess.Popen[str]) -> tuple[int, str]:
    text, _ = proc.communicate()
    return proc.returncode, text


def scenario_results(suite_dir: Path) -> dict[str, dict[str, Any]]:
    """Each scenario's result.json in a suite folder, by scenario name."""
    try:
        summary = json.loads((suite_dir / "result.json").read_text())
    except (OSError, ValueError):
        return {}
    out = {}
    for entry in summary.get("scenarios") or []:
        try:
            out[entry["name"]] = json.loads((suite_dir / entry["dir"] / "result.json")
                                            .read_text())
        except (OSError, ValueError, KeyError):
            continue
    return out


def single_runs(suite_dir: Path) -> dict[str, dict[str, Any]]:
    """Every single run's result.json of a suite folder: a scenario decided over its own
    seeds gives one per seed (``NAME/seed-N``), the others one each."""
    out = {}
    for name, data in scenario_results(suite_dir).items():
        seeds = data.get("seeds")
        if not seeds:
            out[name] = data
            continue
        for seed in seeds:
            try:
                out[f"{name}/{seed['dir']}"] = json.loads(
                    (suite_dir / name / seed["dir"] / "result.json").read_text())
            except (OSError, ValueError, KeyError, TypeError):
                continue
    return out


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def compare(bus: dict[str, dict[str, Any]], inproc: dict[str, dict[str, Any]]
            ) -> dict[str, Any]:
    """Every criterion's value and outcome of the bus runs against the in-process runs."""
    values = identical = 0
    differences = []
    for name, ref in inproc.items():
        got = bus.get(name)
        if got is None:
            differences.append({"scenario": name, "missing": "no bus run"})
            continue
        by_name = {c["name"]: c for c in got.get("criteria") or []}
        for c in ref.get("criteria") or []:
            values += 1
            other = by_name.get(c["name"], {})
            if _same(c.get("value"), other.get("value")) and c.get("outcome") == other.get(
                    "outcome"):
                identical += 1
            else:
                differences.append({"scenario": name, "criterion": c["name"],
                                    "inproc": c.get("value"), "bus": other.get("value")})
    return {"values": values, "identical": identical, "differences": differences[:20]}


def bus_figures(results: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The lockstep's waits and losses and the listeners' misses over single bus runs
    (``single_runs``):
    every frame a node of the run sent of a message the rig listens to reached the rig
    (``frames_the_rig_missed``), the run's nodes dropped nothing for each other
    (``drops_between_run_nodes``: their transmit drops less those for listeners)."""
    waits = failures = missed_by_rig = listener_missed = own_drops = 0
    wait_ms_total = wait_ms_max = 0.0
    sent = 0
    for data in results.values():
        c = data.get("counters") or {}
        report = data.get("bus_report") or {}
        lock = report.get("lockstep") or {}
        waits += int(lock.get("waits") or 0)
        failures += int(lock.get("failures") or 0)
        wait_ms_total += float(lock.get("wait_ms_total") or 0.0)
        wait_ms_max = max(wait_ms_max, float(lock.get("wait_ms_max") or 0.0))
        sent += int(report.get("frames_sent") or 0)
        to_listeners = sum(int(n.get("missed") or 0) for n in report.get("listeners") or [])
        listener_missed += to_listeners
        own_drops += int(sum(c.get(f"{n}.tx_drops", 0.0)
                             for n in ("plant", "firmware", "rig.bus"))) - to_listeners
        for key, heard in c.items():
            if key.startswith("rig.rx."):
                name = key.removeprefix("rig.rx.")
                sender = c.get(f"plant.tx.{name}", c.get(f"firmware.tx.{name}"))
                if sender is not None:
                    missed_by_rig += max(0, int(sender - heard))
    return {"frames_sent": sent, "lockstep_waits": waits,
            "lockstep_wait_ms_total": round(wait_ms_total, 1),
            "lockstep_wait_ms_max": round(wait_ms_max, 1), "lockstep_stall_failures": failures,
            "drops_between_run_nodes": own_drops, "frames_the_rig_missed": missed_by_rig,
            "listener_missed": listener_missed}


def statuses(results: dict[str, dict[str, Any]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for data in results.values():
        out[str(data.get("status"))] = out.get(str(data.get("status")), 0) + 1
    return out
