"""A suite: its scenarios one after the other, one folder each, the suite's comparisons
between runs, and the ``hil-suite/1`` summary (``result.json``, ``report.md``)."""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from rig import outputs
from rig.bench import sil
from rig.data import capture, metrics
from rig.outputs import json_default
from rig.regression import stats
from rig.results import report
from rig.results.result import RunResult
from rig.results.verdict import NOT_EVALUATED, outcome, outcome_of
from rig.run import parallel, progress
from rig.run.options import RunOptions
from rig.run.runner import run_scenario
from rig.scenario import Comparison, Scenario, Suite
from rig.supervisor import Terminated, signals_deferred

SUITE_SCHEMA = "hil-suite/1"
ENTRY_CRITERION_KEYS = ("name", "metric", "window", "value", "limit", "comparison", "unit",
                        "outcome", "xfail", "note", "baseline", "seeds", "better")


@dataclass
class SuiteResult:
    out_dir: Path
    data: dict[str, Any]  # the summary: the content of the suite's result.json
    results: list[RunResult]

    @property
    def passed(self) -> bool:
        return bool(self.data.get("passed"))


def entry(sc: Scenario, r: RunResult) -> dict[str, Any]:
    """A scenario's line in the summary."""
    return {
        "name": sc.name, "dir": sc.name, "passed": r.passed, "status": r.status,
        "failed_criteria": [c["name"] for c in r.failed_criteria()],
        "failure": r.failure.message if r.failure is not None else None,
        "wall_s": r.timing.wall_s if r.timing is not None else None,
        "sim_s": r.timing.sim_s if r.timing is not None else None,
        "profile": sc.profile, "figure": sc.figure, "tags": list(sc.tags),
        "description": sc.description,
        "criteria": [{k: c.get(k) for k in ENTRY_CRITERION_KEYS} for c in r.criteria],
        "recording": (r.recording or {}).get("path"),
        "baseline": r.baseline,
        "figures": [f["path"] for f in (r.figures or {}).get("files") or []],
    }


def run_suite(suite: Suite, opts: RunOptions) -> SuiteResult:
    out = Path(opts.out)
    # (each scenario checks its own room again before it starts)
    with outputs.claim_suite(out, [sc.name for sc in suite.scenarios],
                             max((round(sc.duration / capture.TS)
                                  for sc in suite.scenarios), default=0)) as claimed:
        return _run_claimed(suite, opts, out, claimed)


def _run_claimed(suite: Suite, opts: RunOptions, out: Path, claimed: outputs.Claim
                 ) -> SuiteResult:
    results: list[RunResult] = []
    entries: list[dict[str, Any]] = []
    summary: dict[str, Any] = {
        "schema": SUITE_SCHEMA, "suite": suite.name, "suite_file": str(suite.file),
        "description": suite.description, "passed": False, "scenarios": entries,
    }
    interrupted: BaseException | None = None
    display = progress.Display(suite.name, len(suite.scenarios), enabled=opts.progress,
                               work=[sc.duration * max(1, len(sc.seeds))
                                     for sc in suite.scenarios])
    try:
        with display:
            if (opts.jobs > 1 or opts.cluster) and opts.bus == sil.INPROC:
                _run_parallel(suite, opts, out, results, entries, display)
            else:
                for sc in suite.scenarios:
                    r = run_scenario(sc, replace(opts, out=out / sc.name))
                    results.append(r)
                    entries.append(entry(sc, r))
                    display.done(sc.name, r.passed)
                    if opts.fail_fast and _stops(r):
                        break
    except (KeyboardInterrupt, Terminated) as exc:
        interrupted = exc
    summary["comparisons"] = [evaluate_comparison(cmp, entries) for cmp in suite.comparisons]
    summary["passed"] = (
        interrupted is None and len(results) == len(suite.scenarios)
        and all(r.passed for r in results)
        and all(c["outcome"] in ("pass", "xfail") for c in summary["comparisons"])
    )
    summary["complete"] = len(results) == len(suite.scenarios)
    summary["baseline"] = baseline_summary(entries)
    with signals_deferred():  # the summary is written whole
        claimed.record()
        outputs.write_text(out / "result.json",
                          json.dumps(summary, indent=1, default=json_default))
        outputs.write_text(out / "report.md", report.suite_report(summary))
    if interrupted is not None:
        raise interrupted
    return SuiteResult(out, summary, results)


def baseline_summary(entries: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """How the suite's criteria stand against their baselines: counts per class and the
    criteria that moved (None when no scenario was compared)."""
    counts: dict[str, int] = {}
    moved: list[dict[str, Any]] = []
    compared = False
    for e in entries:
        if e.get("baseline"):
            compared = True
        for c in e.get("criteria") or []:
            b = c.get("baseline") or {}
            cls = b.get("class")
            if cls is None:
                continue
            counts[cls] = counts.get(cls, 0) + 1
            if cls not in ("unchanged", "new"):
                moved.append({"scenario": e["name"], "criterion": c["name"], "class": cls,
                              "metric": c.get("metric"),
                              "value": c.get("value"), "baseline": b.get("value"),
                              "lo": b.get("lo"), "hi": b.get("hi"), "unit": c.get("unit"),
                              "distance": b.get("distance"), "chance": b.get("chance"),
                              "confirmation": b.get("confirmation"),
                              "note": b.get("note", "")})
    if not compared:
        return None
    return {"counts": counts, "moved": moved,
            "passed": all(not e.get("baseline") or e["baseline"].get("passed", True)
                          for e in entries)}


def _stops(r: RunResult) -> bool:
    """With --fail-fast: a run whose failure holds over the seeds (a confirmed regression, a
    crash, a stale baseline, a limit the fresh seeds confirm) stops the suite; a limit that
    failed at this seed alone does not (the suite still fails on it, but a later scenario may
    show what the seeds confirm)."""
    from rig.regression.confirm import failure_kind

    return not r.passed and failure_kind(r.to_json()) != "one-seed"


def _run_parallel(suite: Suite, opts: RunOptions, out: Path, results: list[RunResult],
                  entries: list[dict[str, Any]], display: progress.Display) -> None:
    """The suite's scenarios on ``opts.jobs`` worker processes or on ``opts.cluster`` (in
    process only: each run has its own bench); ``results`` and ``entries`` in the suite's
    order, up to the first run missing when interrupted. ``opts.fail_fast``: no new run
    starts after one failed in a way the seeds confirm (``_stops``)."""
    jobs = [parallel.Job(sc, replace(opts, out=out / sc.name, progress=False, jobs=1,
                                     cluster=None))
            for sc in suite.scenarios]

    def done(job: parallel.Job, r: RunResult | None) -> None:
        verdict = "?" if r is None else "PASS" if r.passed else "FAIL"
        display.done(job.scenario.name, r is not None and r.passed,
                     f"{job.scenario.name}: {verdict}")

    def stop(job: parallel.Job, r: RunResult | None) -> bool:
        return opts.fail_fast and (r is None or _stops(r))

    got: list[RunResult | None] = [None] * len(jobs)
    try:
        parallel.run_jobs(jobs, opts.jobs, got, on_done=done, stop=stop,
                          cluster=opts.cluster, no_worker_timeout_s=opts.no_worker_timeout_s)
    finally:
        for sc, r in zip(suite.scenarios, got, strict=True):
            if r is not None:
                _keep_error(r)
                results.append(r)
                entries.append(entry(sc, r))


def _keep_error(r: RunResult) -> None:
    """A run that ended in an error before it wrote its result (its worker died or raised,
    the cluster never ran it) gets its result.json all the same: the scenario's folder says
    what happened, as the suite's summary does."""
    from rig.results.result import write_result

    if r.status != "error" or (Path(r.out_dir) / "result.json").exists():
        return
    try:
        Path(r.out_dir).mkdir(parents=True, exist_ok=True)
        write_result(r)
    except OSError as exc:  # the suite's summary still says it
        print(f"rig run: {r.scenario}: its error could not be written ({exc})", file=sys.stderr)


def evaluate_comparison(cmp: Comparison,
                        entries: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """A suite comparison on the criterion values recorded in the entries of two runs. A run
    that is missing (interrupted suite) or whose criterion was not evaluated leaves the
    comparison not evaluated; a criterion without a value fails it."""

    def criterion(run: str) -> Mapping[str, Any] | None:
        return next((c for e in entries if e["name"] == run
                     for c in e.get("criteria") or [] if c.get("name") == cmp.criterion), None)

    ca, cb = criterion(cmp.a), criterion(cmp.b)
    a = ca.get("value") if ca is not None else None
    b = cb.get("value") if cb is not None else None
    passed = a is not None and b is not None and metrics.compare(a, cmp.relation, b)
    missing = [run for run, c in ((cmp.a, ca), (cmp.b, cb))
               if c is None or outcome(c) == NOT_EVALUATED]
    out: dict[str, Any] = {
        "name": cmp.name, "criterion": cmp.criterion, "a": cmp.a, "b": cmp.b,
        "relation": cmp.relation, "value_a": a, "value_b": b,
        "unit": (ca or cb or {}).get("unit") or "", "passed": passed,
        "outcome": NOT_EVALUATED if missing else outcome_of(passed, cmp.xfail),
        "xfail": cmp.xfail,
        "note": f"not evaluated: no value from {', '.join(missing)}" if missing else "",
    }
    if not missing and ca is not None and cb is not None and (ca.get("seeds") or cb.get("seeds")):
        out.update(_over_seeds(cmp, ca, cb))
    return out


def _over_seeds(cmp: Comparison, ca: Mapping[str, Any], cb: Mapping[str, Any]
                ) -> dict[str, Any]:
    """A comparison between two scenarios decided over their seeds: the paired differences
    a - b per seed, their mean and 95 % confidence interval. ``<``/``>`` pass when the whole
    interval is on that side of zero (the difference is shown); ``<=``/``>=`` pass unless the
    whole interval is on the wrong side (the opposite is shown). The values are the means."""
    sa = {int(x["seed"]): x.get("value") for x in ca.get("seeds") or []}
    sb = {int(x["seed"]): x.get("value") for x in cb.get("seeds") or []}
    common = sorted(k for k in set(sa) & set(sb) if sa[k] is not None and sb[k] is not None)
    if len(common) < 3 or len(common) != len(sa) or len(common) != len(sb):
        return {"passed": False, "outcome": outcome_of(False, cmp.xfail),
                "note": "decided over seeds needs both runs over the same seeds, each with a "
                        f"value (a: {sorted(sa)}, b: {sorted(sb)})"}
    diffs = [float(sa[k]) - float(sb[k]) for k in common]
    ci = stats.mean_ci(diffs, 0.95)
    rel = cmp.relation
    if rel == "<":
        passed = ci.hi < 0
    elif rel == ">":
        passed = ci.lo > 0
    elif rel == "<=":
        passed = not ci.lo > 0
    else:
        passed = not ci.hi < 0
    mean_a = sum(float(sa[k]) for k in common) / len(common)
    mean_b = sum(float(sb[k]) for k in common) / len(common)
    return {
        "value_a": mean_a, "value_b": mean_b, "passed": passed,
        "outcome": outcome_of(passed, cmp.xfail), "seeds": common,
        "diff_mean": ci.mean, "diff_ci95": [ci.lo, ci.hi],
        "note": f"over seeds {common[0]}-{common[-1]}: a - b = {ci.mean:.4g} "
                f"(95 % CI {ci.lo:.4g} .. {ci.hi:.4g})",
    }
