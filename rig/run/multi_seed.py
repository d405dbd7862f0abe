"""A scenario decided over its own noise seeds (``[run] seeds``): one run per seed into
``seed-N/`` and one verdict over all of them, so no outcome rests on one draw of the noise.

Each criterion passes only when it passes at every seed (the worst case: a limit is a
promise for every run, not for a lucky one); its value is the worst seed's by the
criterion's comparison (the largest for ``<=``, the smallest for ``>=``; for ``==`` the first
value that misses, else the common one), with every seed's value beside it
(``seeds``). A criterion not evaluated at any seed is not evaluated; a run that failed
(crash, stall, ...) fails the scenario with that failure. Suite comparisons between two
such scenarios are decided on the paired per-seed values (rig.run.suite)."""

from __future__ import annotations

import contextlib
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

from rig import outputs
from rig.regression import baseline
from rig.regression.baseline import EITHER, HIGHER, LOWER, better_side
from rig.results.result import Failure, RunResult, Timing, write_result
from rig.results.verdict import NOT_EVALUATED, outcome_of
from rig.run import progress
from rig.run.options import RunOptions
from rig.run.single import run_single
from rig.scenario import Scenario


def seed_folder(seed: int) -> str:
    return f"seed-{seed}"


def _worst(values: list[float | None], passed: list[bool], better: str) -> float | None:
    nums = [v for v in values if v is not None and math.isfinite(v)]
    if any(v is None for v in values) and better != EITHER:
        return None  # no number (never reached, no data) is the worst of its side
    if not nums:
        return None
    if better == LOWER:
        return max(nums)
    if better == HIGHER:
        return min(nums)
    for v, ok in zip(values, passed, strict=True):
        if not ok:
            return v
    return values[0]


def combine(criteria_per_seed: list[list[dict[str, Any]]], seeds: tuple[int, ...],
            xfails: dict[str, str]) -> list[dict[str, Any]]:
    """The criteria of the per-seed runs as one list: worst value, verdict over all seeds."""
    out: list[dict[str, Any]] = []
    for k, first in enumerate(criteria_per_seed[0]):
        entries = [cs[k] for cs in criteria_per_seed]
        merged = dict(first)
        merged["seeds"] = [{"seed": s, "value": e.get("value"), "outcome": e.get("outcome")}
                           for s, e in zip(seeds, entries, strict=True)]
        missing = [s for s, e in zip(seeds, entries, strict=True)
                   if e.get("outcome") == NOT_EVALUATED]
        if missing:
            merged.update(value=None, passed=False, outcome=NOT_EVALUATED,
                          note=f"not evaluated at seeds {missing}: "
                          f"{entries[seeds.index(missing[0])].get('note', '')}")
            out.append(merged)
            continue
        passed = [bool(e.get("passed")) for e in entries]
        better = better_side(first)
        value = _worst([e.get("value") for e in entries], passed, better)
        all_ok = all(passed)
        failing = [s for s, ok in zip(seeds, passed, strict=True) if not ok]
        merged.update(
            value=value, passed=all_ok,
            outcome=outcome_of(all_ok, xfails.get(str(first.get("name")), "")),
            note=(f"worst of {len(seeds)} seeds" + (f"; misses at seeds {failing}"
                                                     if failing else "")))
        out.append(merged)
    return out


def run_over_own_seeds(sc: Scenario, opts: RunOptions) -> RunResult:
    """Runs ``sc`` once per seed of ``sc.seeds`` and writes the combined result."""
    out = opts.out
    with outputs.claim(out, sc.periods, sc.file) as claimed:
        return _over_seeds(sc, opts, out, claimed)


def _over_seeds(sc: Scenario, opts: RunOptions, out: Path, claimed: outputs.Claim
                ) -> RunResult:
    one = replace(sc, seeds=())
    results: list[RunResult] = []
    interrupted: BaseException | None = None
    outer = progress.active()  # a suite's: the seeds are one of its items
    own = progress.Display(sc.name, len(sc.seeds), unit="seed", enabled=opts.progress,
                           work=[sc.duration] * len(sc.seeds)) if outer is None else None
    try:
        with own or contextlib.nullcontext():
            for seed in sc.seeds:
                r = run_single(one.with_seed(seed),
                               replace(opts, out=out / seed_folder(seed), baseline="off",
                                       live=False, progress=False))
                results.append(r)
                line = f"{sc.name}: seed {seed}: {r.status}"
                if own is not None:
                    own.done(f"seed {seed}", r.passed, line)
                elif outer is not None:
                    outer.say(line)
    except BaseException as exc:  # interrupted: combine what finished
        interrupted = exc
    first = results[0] if results else None
    result = RunResult.of_scenario(
        sc, out, mode=first.mode if first else "lockstep", bus=first.bus if first else None,
        channel=first.channel if first else None, started=first.started if first else "",
        versions=first.versions if first else {},
        command_lines=first.command_lines if first else None,
        finished=results[-1].finished if results else "",
        counters=first.counters if first else {},
        capture_loss=first.capture_loss if first else None,
        recording=first.recording if first else None,
        bus_report=first.bus_report if first else None,  # (as the counters: the first seed's)
        timing=Timing(sim_s=sc.duration * len(results),
                      wall_s=sum((r.timing.wall_s or 0.0) for r in results if r.timing)),
        seeds=[{"seed": s, "dir": seed_folder(s), "status": r.status}
               for s, r in zip(sc.seeds, results, strict=False)],
    )
    done = len(results) == len(sc.seeds)
    failed = next((r for r in results if r.failure is not None), None)
    if done and results:
        xfails = {cr.name: cr.xfail for cr in sc.criteria}
        result.criteria = combine([r.criteria for r in results], sc.seeds, xfails)
        ok = all(c.get("outcome") not in ("fail", NOT_EVALUATED) for c in result.criteria)
        if failed is not None:
            result.failure = failed.failure
            result.status = failed.status
            result.passed = False
        else:
            result.status = "passed" if ok else "failed"
            result.passed = ok
        baseline.judge_result(result, sc, opts.baseline, opts.realtime)
    else:
        result.status = "interrupted" if interrupted is not None else "failed"
        result.failure = failed.failure if failed is not None else None
        if result.failure is None:
            result.failure = Failure("interrupted", f"only {len(results)} of "
                                     f"{len(sc.seeds)} seeds ran")
    claimed.record()
    write_result(result)
    if interrupted is not None:
        raise interrupted
    return result
