"""``report.md``: a human-readable summary of a run's ``result.json`` (and of a suite's)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if math.isnan(v):
            return "n/a"
        if math.isinf(v):
            return "∞"
        return f"{v:.{digits}g}"
    return str(v)


def _size(n: float | None) -> str:
    if n is None or (isinstance(n, float) and not math.isfinite(n)):
        return "n/a"
    for unit in ("B", "kB", "MB", "GB"):
        if abs(n) < 1000 or unit == "GB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{n:.0f} B"
        n /= 1000
    return f"{n:.1f} GB"


def scenario_report(result: Mapping[str, Any]) -> str:
    """Markdown for one scenario run."""
    verdict = "PASS" if result.get("passed") else "FAIL"
    lines = [
        f"# {result.get('scenario', '?')}: {verdict}",
        "",
        f"{result.get('description', '')}",
        "",
        "| | |",
        "|---|---|",
        f"| status | {result.get('status')} |",
        f"| profile | {result.get('profile')} |",
        f"| mode | {result.get('mode')} |",
        f"| bus | {result.get('bus')} / {result.get('channel')} |",
        f"| simulated | {_fmt(result.get('timing', {}).get('sim_s'))} s |",
        f"| wall | {_fmt(result.get('timing', {}).get('wall_s'))} s |",
        f"| speed | {_fmt(result.get('timing', {}).get('speed_x'))}x real time |",
    ]
    if result.get("figure"):
        lines.append(f"| paper | {result['figure']} |")
    failure = result.get("failure")
    if failure:
        lines += ["", "## Failure", "", f"**{failure.get('kind')}**: {failure.get('message')}"]
        if failure.get("log_tail"):
            lines += ["", "```", str(failure["log_tail"]), "```"]
    crits = result.get("criteria", [])
    lines += ["", "## Criteria", ""]
    if crits:
        lines += ["| criterion | metric | window (s) | value | limit | result |",
                  "|---|---|---|---|---|---|"]
        for c in crits:
            w = c.get("window") or [None, None]
            unit = c.get("unit") or ""
            lines.append(
                f"| {c['name']} | `{c['metric']}` | [{_fmt(w[0])}, {_fmt(w[1])}] | "
                f"{_fmt(c.get('value'))} {unit} | {c.get('comparison', '<=')} "
                f"{_fmt(c.get('limit'))} {unit} | {'pass' if c.get('passed') else '**FAIL**'} |"
            )
            if c.get("note"):
                lines.append(f"| | | | {c['note']} | | |")
    else:
        lines.append("(none)")
    cap = result.get("capture") or {}
    if cap:
        lines += [
            "",
            "## Capture",
            "",
            f"{cap.get('summary', '')}",
            "",
            f"- periods: {cap.get('periods')} (first {cap.get('first_period')}, "
            f"last {cap.get('last_period')})",
            f"- lost: {cap.get('lost')}, duplicates: {cap.get('duplicates')}",
        ]
    rec = result.get("recording") or {}
    if rec:
        lines += [
            "",
            "## Recording",
            "",
            f"- `{rec.get('path')}`: {_size(rec.get('bytes'))}, "
            f"{_size(rec.get('bytes_per_sim_s'))} per simulated second"
            + (" (long run: secondary series decimated)" if rec.get("long_run") else ""),
            f"- capture columns: {_size(rec.get('capture_bytes'))}",
            f"- open it: `rig view {result.get('out_dir', '.')}`",
        ]
    counters = result.get("counters") or {}
    if counters:
        lines += ["", "## Counters", "", "| counter | value |", "|---|---|"]
        for k in sorted(counters):
            lines.append(f"| `{k}` | {_fmt(counters[k])} |")
    versions = result.get("versions") or {}
    if versions:
        lines += ["", "## Versions", ""]
        for k in sorted(versions):
            lines.append(f"- {k}: {_fmt(versions[k])}")
    return "\n".join(lines) + "\n"


def suite_report(summary: Mapping[str, Any]) -> str:
    verdict = "PASS" if summary.get("passed") else "FAIL"
    lines = [
        f"# Suite {summary.get('suite')}: {verdict}",
        "",
        f"{summary.get('description', '')}",
        "",
        "| scenario | result | failed criteria / failure | wall (s) |",
        "|---|---|---|---|",
    ]
    for s in summary.get("scenarios", []):
        why = ", ".join(s.get("failed_criteria", [])) or (s.get("failure") or "")
        lines.append(
            f"| [{s['name']}]({s['dir']}/report.md) | {'pass' if s.get('passed') else '**FAIL**'}"
            f" ({s.get('status')}) | {why} | {_fmt(s.get('wall_s'))} |"
        )
    return "\n".join(lines) + "\n"
