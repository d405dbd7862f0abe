"""A suite: its scenarios one after the other, one folder each, the suite's comparisons
between runs, and the ``hil-suite/1`` summary (``result.json``, ``report.md``)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from rig import capture, metrics, output, report
from rig.run.options import RunOptions
from rig.run.outputs import json_default
from rig.run.result import RunResult
from rig.runner import run_scenario
from rig.scenario import Comparison, Scenario, Suite
from rig.supervisor import Terminated
from rig.verdict import NOT_EVALUATED, outcome, outcome_of

SUITE_SCHEMA = "hil-suite/1"
ENTRY_CRITERION_KEYS = ("name", "metric", "window", "value", "limit", "comparison", "unit",
                        "outcome", "xfail", "note")


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
        "profile": sc.profile, "figure": sc.figure, "tags": list(sc.tags),
        "description": sc.description,
        "criteria": [{k: c.get(k) for k in ENTRY_CRITERION_KEYS} for c in r.criteria],
        "recording": (r.recording or {}).get("path"),
        "figures": [f["path"] for f in (r.figures or {}).get("files") or []],
    }


def run_suite(suite: Suite, opts: RunOptions) -> SuiteResult:
    out = Path(opts.out)
    # (each scenario checks its own room again before it starts)
    output.prepare(out, max((round(sc.duration / capture.TS) for sc in suite.scenarios),
                            default=0))
    results: list[RunResult] = []
    entries: list[dict[str, Any]] = []
    summary: dict[str, Any] = {
        "schema": SUITE_SCHEMA, "suite": suite.name, "suite_file": str(suite.file),
        "description": suite.description, "passed": False, "scenarios": entries,
    }
    interrupted: BaseException | None = None
    try:
        for sc in suite.scenarios:
            r = run_scenario(sc, replace(opts, out=out / sc.name))
            results.append(r)
            entries.append(entry(sc, r))
    except (KeyboardInterrupt, Terminated) as exc:
        interrupted = exc
    summary["comparisons"] = [evaluate_comparison(cmp, entries) for cmp in suite.comparisons]
    summary["passed"] = (
        interrupted is None and len(results) == len(suite.scenarios)
        and all(r.passed for r in results)
        and all(c["outcome"] in ("pass", "xfail") for c in summary["comparisons"])
    )
    summary["complete"] = len(results) == len(suite.scenarios)
    output.write_text(out / "result.json", json.dumps(summary, indent=1, default=json_default))
    output.write_text(out / "report.md", report.suite_report(summary))
    if interrupted is not None:
        raise interrupted
    return SuiteResult(out, summary, results)


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
    return {
        "name": cmp.name, "criterion": cmp.criterion, "a": cmp.a, "b": cmp.b,
        "relation": cmp.relation, "value_a": a, "value_b": b,
        "unit": (ca or cb or {}).get("unit") or "", "passed": passed,
        "outcome": NOT_EVALUATED if missing else outcome_of(passed, cmp.xfail),
        "xfail": cmp.xfail,
        "note": f"not evaluated: no value from {', '.join(missing)}" if missing else "",
    }
