"""``commissioning.md``: identified parameters against nominal (and, on a virtual bench, the
plant's true values), every step's checks and tables, the safe stop, the recording."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from rig.commissioning.results import Quantity, StepResult

SCALE = {"H": (1e3, "mH")}


def _num(v: float | None, unit: str = "") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    factor, shown = SCALE.get(unit, (1.0, unit))
    return f"{v * factor:.5g} {shown}".strip()


def _pct(v: float | None) -> str:
    return "—" if v is None else f"{100.0 * v:+.2f} %"


def _identified_table(quantities: Sequence[Quantity], virtual: bool) -> list[str]:
    head = "| quantity | identified | nominal (parameters.csv) | vs nominal |"
    sep = "|---|---|---|---|"
    if virtual:
        head += " plant truth | vs truth |"
        sep += "---|---|"
    lines = [head + " method |", sep + "---|"]
    for q in quantities:
        row = (f"| {q.label} | {_num(q.value, q.unit)} | {_num(q.nominal, q.unit)} | "
               f"{_pct(q.vs_nominal)} |")
        if virtual:
            row += f" {_num(q.truth, q.unit)} | {_pct(q.vs_truth)} |"
        lines.append(row + f" {q.method} |")
    return lines


def render(run: dict[str, Any], steps: Sequence[StepResult]) -> str:
    virtual = bool(run.get("virtual"))
    verdict = "PASSED" if run.get("passed") else ("INTERRUPTED" if run.get("interrupted")
                                                  else "FAILED")
    lines = [
        f"# Commissioning of bench `{run['bench']}`: {verdict}", "",
        "| | |", "|---|---|",
        f"| bench file | `{run.get('bench_file')}` |",
        f"| steps | {', '.join(run.get('steps_requested', []))} |",
        f"| CAN | {run.get('can')} |",
        f"| console | {run.get('console') or '—'} |",
        f"| load bench | {run.get('modbus') or '—'} |",
        f"| clock | {run.get('clock')} |",
        f"| bench time | {run.get('bench_s', 0.0):.3f} s |",
        f"| wall time | {run.get('wall_s', 0.0):.2f} s |",
        f"| recording | `{run.get('recording')}` (candump format: every frame sent and "
        "received) |",
        f"| results | `{run.get('results')}` |",
    ]
    if run.get("virtual_profile"):
        lines.append(f"| plant profile | {run['virtual_profile']} "
                     f"{run.get('virtual_overrides') or ''} |")
    main = [q for s in steps for q in s.quantities if q.nominal is not None]
    if main:
        lines += ["", "## Identified parameters", "", *_identified_table(main, virtual)]
    for s in steps:
        mark = "passed" if s.passed else "FAILED"
        lines += ["", f"## {s.step}: {s.title} ({mark})", "",
                  f"bench time {s.bench_s:.3f} s, wall {s.wall_s:.2f} s", ""]
        if s.error:
            lines += [f"**Stopped:** {s.error}", ""]
        for c in s.checks:
            lines.append(f"- {'✔' if c.passed else '✘'} **{c.name}**: {c.detail}")
        other = [q for q in s.quantities if q.nominal is None]
        if other:
            lines += ["", "| measured | value | method |", "|---|---|---|"]
            lines += [f"| {q.label} | {_num(q.value, q.unit)} | {q.method} |" for q in other]
        for t in s.tables:
            lines += ["", f"**{t.title}**", "", "| " + " | ".join(t.columns) + " |",
                      "|" + "---|" * len(t.columns)]
            lines += ["| " + " | ".join(str(x) for x in row) + " |" for row in t.rows]
        for n in s.notes:
            lines += ["", f"_{n}_"]
    lines += ["", "## Safe stop", ""]
    lines += [f"- {n}" for n in run.get("safety", [])] or ["- (not reached)"]
    if run.get("error"):
        lines += ["", "## Error", "", f"{run['error']}"]
    return "\n".join(lines) + "\n"
