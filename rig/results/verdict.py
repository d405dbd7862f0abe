"""Verdicts of criteria, only on data that exists.

A criterion is evaluated only when the run produced the data it asserts on:

- a window metric needs every period of its window in the capture (a run that crashed, was
  killed or interrupted has a capture that stops early, or none; a capture with a loss has
  holes nobody can place);
- a run metric (counters, capture loss) needs the run to have reached its planned end (the
  programs' exit counters and the loss report cover the whole run only then).

Anything else is ``not_evaluated``: its own outcome, never a pass, and it fails the run.
Otherwise the outcome is ``pass`` or ``fail``, or for a criterion with a known failure
(``xfail``) ``xfail`` or ``xpass``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from rig.data import capture, metrics
from rig.scenario import Criterion

TS = capture.TS

PASS = "pass"
FAIL = "fail"
XFAIL = "xfail"
XPASS = "xpass"
NOT_EVALUATED = "not_evaluated"
OUTCOMES = (PASS, FAIL, XFAIL, XPASS, NOT_EVALUATED)
# outcomes that count against a run
AGAINST = (FAIL, NOT_EVALUATED)


@dataclass(frozen=True)
class Coverage:
    """The data a run produced: the captured period range and whether the run got to its end.

    ``planned``: the scenario's periods (0 .. planned - 1). ``first``/``last``: the inclusive
    range of periods every traced message holds (None: no usable capture). ``reached_end``:
    every planned period ran and the run was not interrupted (exit counters and the loss
    report are final). ``why``: what cut the data short, for the notes."""

    planned: int
    first: int | None
    last: int | None
    reached_end: bool
    why: str = ""

    @classmethod
    def whole(cls, planned: int) -> Coverage:
        """A run that produced all its data (every window captured, counters final)."""
        return cls(planned, 0, planned - 1, True)

    def window_periods(self, t0: float, t1: float) -> tuple[int, int]:
        """The periods a window [t0, t1] asks for (its end capped at the last planned)."""
        p0 = math.ceil(t0 / TS - 1e-6)
        p1 = min(math.floor(t1 / TS + 1e-6), self.planned - 1)
        return p0, p1

    def missing(self, cr: Criterion) -> str:
        """Why the criterion cannot be evaluated ('' when its data exists)."""
        cut = f" ({self.why})" if self.why else ""
        if metrics.is_counter(cr.metric) or (
                cr.metric in metrics.METRICS and metrics.METRICS[cr.metric].scope == "run"):
            if self.reached_end:
                return ""
            return f"run metric: the run did not reach its end{cut}"
        p0, p1 = self.window_periods(*cr.window)
        if self.first is None or self.last is None:
            return f"window [{cr.window[0]:g}, {cr.window[1]:g}] s not captured: no capture{cut}"
        if p0 < self.first or p1 > self.last:
            return (f"window [{cr.window[0]:g}, {cr.window[1]:g}] s (periods {p0} .. {p1}) not "
                    f"fully captured: the capture holds periods {self.first} .. {self.last}"
                    f"{cut}")
        return ""


def outcome_of(passed: bool, xfail: str) -> str:
    """pass/fail, or for a known failure (xfail reason given) xfail/xpass."""
    if xfail:
        return XPASS if passed else XFAIL
    return PASS if passed else FAIL


def outcome(c: Mapping[str, Any]) -> str:
    """pass | fail | xfail (known failure, reason in the scenario) | xpass (a known failure
    that passed: its xfail should be removed) | not_evaluated (its data does not exist)."""
    if "outcome" in c:
        return str(c["outcome"])
    return PASS if c.get("passed") else FAIL


def evaluate_one(cr: Criterion, cap: capture.Capture | None, counters: Mapping[str, float],
                 coverage: Coverage,
                 reads: list[tuple[str, int, int]] | None = None,
                 extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One criterion's entry of result.json; the capture rows it read are added to
    ``reads`` (the recording keeps them at full rate as the criterion's evidence).
    ``extra``: capture-aligned columns that are not in the capture (the ISR's cost per
    period, rig.target_m4.cost); a metric's detail (numbers by name) goes into the entry."""
    entry: dict[str, Any] = {
        "name": cr.name,
        "metric": cr.metric,
        "window": [cr.window[0], cr.window[1]],
        "value": None,
        "limit": cr.limit if math.isfinite(cr.limit) else None,
        "comparison": cr.comparison,
        "better": cr.side(),
        "unit": metrics.unit_of(cr.metric),
        "params": dict(cr.params),
        "passed": False,
        "outcome": NOT_EVALUATED,
        "xfail": cr.xfail,
        "note": "",
    }
    missing = coverage.missing(cr)
    if missing:
        entry["note"] = f"not evaluated: {missing}"
        return entry
    note = ""
    value = math.nan
    if cap is None and not metrics.is_counter(cr.metric) and \
            metrics.METRICS[cr.metric].scope != "run":
        note = "no capture"
    else:
        cols: metrics.ColumnSource = cap if cap is not None else {}
        if extra:
            cols = metrics.Overlay(cols, extra)
        first = cap.first_period if cap is not None else 0
        read: list[tuple[str, int, int]] = []
        w = metrics.Window(cols, cr.window[0], cr.window[1], ts=TS, first_period=first,
                           counters=counters, reads=read)
        try:
            value = metrics.compute(cr.metric, w, cr.params)
            detail = metrics.detail(cr.metric, w, cr.params)
            if detail:
                entry["detail"] = detail
        except KeyError as exc:
            note = f"missing data: {exc}"
        if reads is not None:  # the capture's rows (the added columns are not recorded)
            reads.extend(r for r in read if not extra or r[0] not in extra)
        if math.isnan(value) and not note:
            note = "no data in the window"
        elif math.isinf(value):
            note = metrics.INFINITE_NOTES.get(cr.metric, "infinite")
    passed = metrics.compare(value, cr.comparison, cr.limit)
    entry.update(value=value if math.isfinite(value) else None, passed=passed,
                 outcome=outcome_of(passed, cr.xfail), note=note)
    return entry
