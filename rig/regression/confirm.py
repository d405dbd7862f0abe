"""Confirming a flag: is a value beyond its band a regression, or the noise drawn again?

A run judged against its baseline flags every criterion whose value lies beyond its band on
the worse side (``regressed``; ``changed`` without a better side). At the firmware and seed
the baseline recorded that never happens. For any other firmware it does, by chance: a
change that only moves rounding decorrelates the closed loop's noise trajectory, so every
value is in effect drawn again, and one more seed's value leaves its 99 % band about once in
a hundred and fifty criteria on the worse side, a few times in a gate of ~1 500 values.

So a flag is put to a test on fresh data. The flagged scenario runs again at ``n`` seeds it
has never run at (``seeds_for``: 1000 s + 1 ... 1000 s + n, s the largest seed of the run
that flagged it), in process, and for each flagged criterion its ``n`` values are ranked
together with the baseline's per-seed values (the exact Wilcoxon-Mann-Whitney rank-sum test,
one-sided toward the worse side, both sides for a criterion without a better side, after
moving the new values back by the band's floor: a shift smaller than the unit's resolution
is no regression). The flag is **confirmed** when an ordering at least that bad has a
probability of at most ``ALPHA`` (0.1 %) among all equally likely ones; otherwise it is an
``excursion``: shown with its p-value, not failing the run.

Why the gate's false-alarm rate is then bounded: the fresh seeds are independent of the run
that raised the flag, so for a harmless change each criterion fails only if it is flagged
(probability f, about 0.5 %) and then confirmed (at most ALPHA), and by the union bound the
whole gate fails with probability at most (the flags expected by chance) x ALPHA: about
10 x 0.1 % = 1 %. A real regression moves the values at every seed, so it is confirmed with
high probability. Spec limits are not put to the test: a failed limit fails the run as
before (the confirmation still runs for it, so that ``rig mutate`` can tell a kill the seeds
confirm from a one-seed one).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from rig.regression import stats
from rig.regression.baseline import (
    EITHER,
    EXCURSION,
    FAILING,
    FLAGGED,
    HIGHER,
    BaselineError,
    Record,
    check_mode,
    entry_key,
)
from rig.results.result import RunResult, write_result
from rig.results.verdict import AGAINST, FAIL, outcome

ALPHA = 0.001  # the probability a flag is confirmed by chance (per flagged criterion)
MIN_SEEDS = 8  # fresh seeds per confirmation (more when the baseline has few values)
SEED_STRIDE = 1000


def seeds_for(screen_seeds: Sequence[int], n: int) -> tuple[int, ...]:
    """The fresh seeds that confirm a run at ``screen_seeds``: never among them, nor among
    the baselines' (1-8) for any screening seed >= 1."""
    s = max(screen_seeds) if screen_seeds else 1
    return tuple(SEED_STRIDE * s + k for k in range(1, n + 1))


def seeds_needed(n_base: int) -> int:
    """How many fresh seeds make a confirmation at ALPHA possible with a margin: the
    smallest p the rank test can give must be at most ALPHA / 10."""
    m = MIN_SEEDS
    while m < 64 and stats.smallest_shift_p(max(n_base, 1), m) > ALPHA / 10:
        m += 1
    return m


def _badness(v: float | None, better: str, up: bool) -> float:
    """A value on a scale where larger is worse (no number: the worst)."""
    if v is None or not math.isfinite(v):
        return math.inf
    x = float(v)
    if better == HIGHER:
        return -x
    if better == EITHER and not up:
        return -x
    return x


def shift_p(rec: Record, values: Sequence[float | None]) -> float:
    """The p-value of the new ``values`` lying worse than the baseline's per-seed values by
    more than the band's floor (either way for a criterion without a better side)."""
    base = rec.band.values
    if not base:
        raise BaselineError("the baseline holds no per-seed values (schema 1): record it "
                            "again to confirm")
    margin = rec.band.floor
    if rec.better != EITHER:
        return stats.shift_p([_badness(v, rec.better, True) for v in base],
                             [_badness(v, rec.better, True) for v in values], margin)
    up = stats.shift_p([_badness(v, EITHER, True) for v in base],
                       [_badness(v, EITHER, True) for v in values], margin)
    down = stats.shift_p([_badness(v, EITHER, False) for v in base],
                         [_badness(v, EITHER, False) for v in values], margin)
    return min(1.0, 2.0 * min(up, down))


@dataclass(frozen=True)
class Flag:
    """A flagged criterion of a run and the record it is judged against."""

    name: str
    record: Record


def flags(result: RunResult, mode: str) -> list[Flag]:
    """The criteria of ``result`` a confirmation decides: flagged against a baseline that
    holds their per-seed values."""
    base = result.baseline or {}
    if not base or base.get("error") or base.get("missing") or mode == "off":
        return []
    try:
        idx = check_mode(mode)
    except BaselineError:
        return []
    key = entry_key(result.scenario, result.profile)
    found = idx.for_key(key) if idx is not None else None
    if found is None or key not in found.entries:
        return []
    entry = found.entries[key]
    out: list[Flag] = []
    for c in result.criteria:
        b = c.get("baseline") or {}
        rec = entry.records.get(str(c.get("name")))
        if b.get("class") in FLAGGED and rec is not None and rec.band.values:
            out.append(Flag(str(c["name"]), rec))
    return out


def decide(result: RunResult, per_seed: Sequence[Sequence[Mapping[str, Any]]],
           seeds: Sequence[int], flagged: Sequence[Flag]) -> None:
    """Each flagged criterion of ``result`` judged on the runs at the fresh ``seeds``
    (``per_seed``: each run's criteria); the run's baseline summary and verdict follow."""
    by_name = {c.get("name"): c for c in result.criteria}
    for f in flagged:
        c = by_name[f.name]
        vals: list[float | None] = []
        for crits in per_seed:
            got = next((x for x in crits if x.get("name") == f.name), None)
            v = None if got is None else got.get("value")
            vals.append(None if v is None else float(v))
        p = shift_p(f.record, vals)
        confirmed = p <= ALPHA
        b = c["baseline"]
        b["confirmation"] = {
            "seeds": list(seeds), "values": vals, "p": p, "alpha": ALPHA,
            "confirmed": confirmed,
        }
        if not confirmed:
            b["screened_class"] = b["class"]
            b["class"] = EXCURSION
    settle(result)


def settle(result: RunResult) -> None:
    """The run's baseline summary and verdict from its criteria's classes."""
    base = result.baseline
    if not base or "counts" not in base:
        return
    counts: dict[str, int] = {}
    for c in result.criteria:
        cls = (c.get("baseline") or {}).get("class")
        if cls is not None:
            counts[cls] = counts.get(cls, 0) + 1
    base["counts"] = counts
    base["passed"] = not any(counts.get(k) for k in FAILING)
    spec_ok = result.failure is None and all(outcome(c) not in AGAINST for c in result.criteria)
    result.passed = spec_ok and base["passed"]
    if result.status in ("passed", "failed"):
        result.status = "passed" if result.passed else "failed"


def confirm(sc: Any, result: RunResult, opts: Any) -> None:
    """Runs the confirmation of ``result`` (a run of scenario ``sc`` with options ``opts``)
    when it has flags, and writes its result again. The fresh runs go to
    ``OUT/confirm/seed-N`` in process, without recordings or figures."""
    from rig.bench import sil
    from rig.run.single import run_single

    flagged = flags(result, str(opts.baseline))
    if not flagged:
        return
    screen = [int(x["seed"]) for x in result.seeds or []] or [sc.seed or 1]
    n = max(seeds_needed(f.record.band.n) for f in flagged)
    seeds = seeds_for(screen, n)
    one = replace(sc, seeds=())
    per_seed: list[list[dict[str, Any]]] = []
    base_opts = replace(opts, bus=sil.INPROC, channel=None, realtime=False, live=False,
                        live_stream=None, live_url=None, progress=False, record=False,
                        figures=False, keep="none", baseline="off", jobs=1,
                        core_journal=None)
    names = ", ".join(f.name for f in flagged)
    if opts.progress:
        print(f"{sc.name}: {len(flagged)} flagged ({names}): confirming at seeds "
              f"{seeds[0]}-{seeds[-1]} in process", file=sys.stderr)
    try:
        for seed in seeds:
            r = run_single(one.with_seed(seed),
                           replace(base_opts, out=opts.out / "confirm" / f"seed-{seed}"))
            per_seed.append(r.criteria)
    except BaseException:
        for f in flagged:
            c = next(x for x in result.criteria if x.get("name") == f.name)
            c["baseline"]["confirmation"] = {"seeds": list(seeds), "interrupted": True}
            c["baseline"]["note"] = "the confirmation was interrupted: not decided"
        write_result(result)
        raise
    decide(result, per_seed, seeds, flagged)
    write_result(result)
    if opts.progress:
        kept = [f.name for f in flagged
                if next(c for c in result.criteria if c.get("name") == f.name)
                ["baseline"]["class"] != EXCURSION]
        print(f"{sc.name}: {len(kept)} of {len(flagged)} confirmed"
              + (f" ({', '.join(kept)})" if kept else ""), file=sys.stderr)


def failure_kind(data: Mapping[str, Any]) -> str:
    """How a run's failure stands over the seeds (a result.json's content): ``confirmed``
    (a confirmed regression, a spec failure the fresh seeds confirm, a crash or stall),
    ``one-seed`` (only limits failed at this seed whose values the fresh seeds do not
    confirm), ``stale`` (the baseline does not judge this set-up), or ``none`` (passed)."""
    if data.get("passed"):
        return "none"
    if data.get("failure"):
        return "confirmed"
    crits = data.get("criteria") or []
    kinds: set[str] = set()
    for c in crits:
        b = c.get("baseline") or {}
        conf = b.get("confirmation") or {}
        cls = b.get("class")
        if cls in FLAGGED:
            kinds.add("confirmed" if conf.get("confirmed") or not conf else "open")
        elif cls in FAILING:
            kinds.add("stale")
        if c.get("outcome") == FAIL or c.get("outcome") == "not_evaluated":
            if c.get("outcome") == "not_evaluated":
                kinds.add("confirmed")
            elif conf.get("confirmed"):
                kinds.add("confirmed")
            else:
                kinds.add("one-seed")
    if "confirmed" in kinds:
        return "confirmed"
    if "one-seed" in kinds or "open" in kinds:
        return "one-seed"
    if "stale" in kinds:
        return "stale"
    return "confirmed" if (data.get("baseline") or {}).get("missing") else "one-seed"


