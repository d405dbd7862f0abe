"""Record a case and replay it on the target: the comparison (``rig target compare``, the CI
test) and the instruction budget (``rig bench isr --target cortex-m4f``) both start here."""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rig.target_m4 import emulator, record, replay
from rig.target_m4.journal import Journal
from rig.target_m4.scenarios import Case, windows

GOAL_10KHZ = 5000  # instructions: half the period of a 100 MHz part at 10 kHz


def compare_case(c: Case, out: Path, full: bool = False, scale: float = 1.0,
                 count: bool = False, target: str = emulator.DEFAULT_TARGET
                 ) -> replay.Comparison:
    """Runs the case's scenario in process with the core journalled (the whole run with
    ``full``, else its windows) and replays the journal on the emulated target."""
    result = record.record(c.scenario, out, () if full else windows(c, scale),
                           None if full else c.duration)
    if result.status not in ("passed", "failed"):
        raise RuntimeError(f"{c.scenario}: {result.explain()}")
    m4 = emulator.M4Core(count=count, target=target)
    return replay.replay(Journal(out / "core.journal"), m4, c.scenario)


def path_of(cost: replay.IsrCost) -> str:
    if cost.state == "RUN":
        return "run_1khz" if cost.slow else "run_10khz"
    if cost.state == "POLARITY":
        return "startup_polarity"
    return cost.state.lower()


def stats(values: Sequence[int]) -> dict[str, Any]:
    v = sorted(values)
    return {"n": len(v), "median": statistics.median(v),
            "p99": v[min(len(v) - 1, round(0.99 * (len(v) - 1)))], "max": v[-1]}


def step_stats(costs: Sequence[replay.IsrCost], names: Sequence[str]) -> dict[str, Any]:
    """Per step of fw_core_isr: the median and the largest of its instructions over
    ``costs``, and its share of the whole ISR's (the mean of each over all of them)."""
    if not costs or not names:
        return {}
    total = sum(c.instructions for c in costs) or 1
    out: dict[str, Any] = {}
    for i, name in enumerate(names):
        v = [c.steps[i] for c in costs]
        out[name] = {"median": statistics.median(v), "max": max(v),
                     "mean": round(sum(v) / len(v), 1), "share": round(sum(v) / total, 4)}
    return out


def budget(comparisons: Sequence[replay.Comparison]) -> dict[str, Any]:
    """Instructions per ISR by path over all comparisons, and per comparison; per path also
    by step of fw_core_isr (counted replays), and the steps of its worst ISR."""
    paths: dict[str, list[int]] = {}
    worst: dict[str, str] = {}  # the last ISR that reached the path's largest count
    most: dict[str, int] = {}  # (a running maximum: the whole runs have 412 000 ISRs)
    per_case: dict[str, dict[str, Any]] = {}
    for comp in comparisons:
        mine: dict[str, list[int]] = {}
        for cost in comp.costs:
            p = path_of(cost)
            mine.setdefault(p, []).append(cost.instructions)
            if cost.instructions >= most.get(p, 0):
                most[p] = cost.instructions
                worst[p] = f"{comp.name} ISR {cost.isr}"
            paths.setdefault(p, []).append(cost.instructions)
        per_case[comp.name] = {p: stats(v) for p, v in sorted(mine.items())}
    fp: dict[str, list[int]] = {}
    div_sqrt: dict[str, list[int]] = {}
    for comp in comparisons:
        for cost in comp.costs:
            fp.setdefault(path_of(cost), []).append(cost.fp)
            div_sqrt.setdefault(path_of(cost), []).append(cost.div_sqrt)
    out: dict[str, Any] = {p: {**stats(v), "worst_at": worst[p],
                               "fp_median": statistics.median(fp[p]),
                               "div_sqrt_median": statistics.median(div_sqrt[p])}
                           for p, v in sorted(paths.items())}
    names = next((c.steps for c in comparisons if c.steps), ())
    if names:
        by_path: dict[str, list[replay.IsrCost]] = {}
        worst_isr: dict[str, replay.IsrCost] = {}
        for comp in comparisons:
            for cost in comp.costs:
                p = path_of(cost)
                by_path.setdefault(p, []).append(cost)
                if p not in worst_isr or cost.instructions >= worst_isr[p].instructions:
                    worst_isr[p] = cost
        for p, costs in by_path.items():
            out[p]["steps"] = step_stats(costs, names)
            out[p]["worst_steps"] = dict(zip(names, worst_isr[p].steps, strict=True))
    return {"paths": out, "per_scenario": per_case, "steps": list(names)}
