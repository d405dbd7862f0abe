"""``report.md``: a human-readable summary of a run's ``result.json`` (and of a suite's)."""

from __future__ import annotations

import math
import re
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
    pictures = (result.get("figures") or {}).get("files") or []
    overview = [f for f in pictures if f.get("shows") == "overview"]
    if overview:
        lines += ["", f"![{result.get('scenario')}: position error, speed, currents and load; "
                  f"the windows of criteria that did not pass shaded]({overview[0]['path']})"]
    injected = result.get("faults") or []
    if injected:
        lines += ["", "## Faults injected", ""]
        for f in injected:
            what = ", ".join(f"{k} {v}" for k, v in f.items()
                             if k not in ("kind", "at", "duration"))
            until = f"for {f['duration']:g} s" if f.get("duration") else "to the end"
            lines.append(f"- {f.get('kind')} at {f.get('at'):g} s {until}"
                         + (f" ({what})" if what else ""))
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
                f"{_fmt(c.get('limit'))} {unit} | {_OUTCOME.get(_outcome(c), _outcome(c))} |"
            )
            if c.get("note"):
                lines.append(f"| | | | {c['note']} | | |")
            if c.get("xfail"):
                lines.append(f"| | | | expected failure: {c['xfail']} | | |")
    else:
        lines.append("(none)")
    for f in pictures:
        if f.get("shows") == "criterion":
            lines += ["", f"![{f.get('criterion')}: what it read over its window, and its "
                      f"limit]({f['path']})"]
    lines += _baseline_section(result.get("baseline"), crits)
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
            f"{_size(rec.get('bytes_per_sim_s'))} per simulated second",
            f"- display series every {rec.get('display_step')} periods; what the criteria "
            f"read at full rate ({rec.get('evidence_rows')} periods of "
            f"{', '.join(f'`{c}`' for c in rec.get('evidence') or {}) or 'no column'})",
            f"- capture columns: {_size(rec.get('capture_bytes'))}",
            f"- open it: `rig view {result.get('out_dir', '.')}` "
            f"(in a browser: `rig view --web {result.get('out_dir', '.')}`)",
        ]
    kept = result.get("kept") or {}
    if kept:
        lines += ["", "## Kept", ""]
        if kept.get("full_rate"):
            lines.append("- full-rate traces (`*.trace`) and capture columns (`capture/`) kept"
                         f" (policy `{kept.get('policy')}`): `rig export` works on this run")
        elif kept.get("removed"):
            lines.append(f"- {kept.get('note')}: {', '.join(kept['removed'])} "
                         f"({_size(kept.get('removed_bytes'))})")
        else:
            lines.append("- no full-rate traces or capture")
    counters = result.get("counters") or {}
    if "rig.listeners.start" in counters or result.get("bus_report"):
        from rig.run.bus_report import in_words

        foreign = (result.get("failure") or {}).get("kind") == "foreign_traffic"
        lines += ["", "## Bus", ""]
        if "rig.listeners.start" in counters:
            lines.append(_listeners(counters, foreign))
        lines += in_words(result.get("bus_report") or {})
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


def _baseline_section(base: Mapping[str, Any] | None,
                      crits: list[Mapping[str, Any]]) -> list[str]:
    """How the run's criteria stand against the committed baseline (rig.regression.baseline)."""
    if not base:
        return []
    lines = ["", "## Against the baseline", ""]
    if base.get("skipped") or base.get("error") or base.get("missing"):
        verdict = "" if base.get("passed", True) else " (**fails the run**)"
        return [*lines, f"{base.get('skipped') or base.get('error') or base.get('note')}"
                f"{verdict}"]
    counts = ", ".join(f"{n} {k}" for k, n in (base.get("counts") or {}).items())
    lines += [f"`{base.get('file')}` (seeds {_seed_span(base.get('seeds'))}, recorded "
              f"{base.get('recorded')}): {counts or 'nothing compared'}"
              + ("" if base.get("passed") else " — **the run fails on it**"), ""]
    moved = [c for c in crits if (c.get("baseline") or {}).get("class") not in
             (None, "unchanged")]
    if moved:
        lines += ["| criterion | value | baseline | band | against it |", "|---|---|---|---|---|"]
        for c in moved:
            b = c["baseline"]
            unit = c.get("unit") or ""
            band = (f"{_fmt(b.get('lo'))} .. {_fmt(b.get('hi'))} {unit}" if "lo" in b
                    else b.get("note", ""))
            mark = b["class"].upper() if b["class"] in ("regressed", "changed", "stale") \
                else b["class"]
            lines.append(f"| {c['name']} | {_fmt(c.get('value'))} {unit} | "
                         f"{_fmt(b.get('value'))} {unit} | {band} | {mark} |")
    return lines


def _seed_span(seeds: Any) -> str:
    s = sorted(seeds or [])
    return f"{s[0]}-{s[-1]}" if len(s) > 2 and s == list(range(s[0], s[-1] + 1)) else \
        ", ".join(map(str, s))


def _listeners(counters: dict[str, Any], foreign: bool) -> str:
    """Other nodes on a unixcan channel: welcome while they only listen (rig.run.traffic)."""
    start = int(counters["rig.listeners.start"])
    end = int(counters.get("rig.listeners.end", start))
    nodes = (f"- {start} other node{'' if start == 1 else 's'} on the channel at the start, "
             f"{end} at the end")
    if foreign:
        return f"{nodes}; a node outside the run sent frames (see the failure)"
    return (f"{nodes}, listening only (the frame counts add up: a node that sent would have "
            "failed the run as foreign traffic)")


_OUTCOME = {"pass": "pass", "fail": "**FAIL**", "xfail": "XFAIL", "xpass": "**XPASS**",
            "not_evaluated": "**NOT EVALUATED**"}
_TABLE2 = re.compile(r"table2_(\d+)rpm_([0-9p]+)nm")


def _outcome(c: Mapping[str, Any]) -> str:
    o = c.get("outcome") or ("pass" if c.get("passed") else "fail")
    return str(o)


def _verdict(s: Mapping[str, Any]) -> str:
    crits = s.get("criteria") or []
    if not s.get("passed"):
        return "**FAIL**" if s.get("status") != "error" else "**ERROR**"
    if any(_outcome(c) == "xpass" for c in crits):
        return "pass (XPASS)"
    if any(_outcome(c) == "xfail" for c in crits):
        return "pass (XFAIL)"
    return "pass"


def _metric(s: Mapping[str, Any], metric: str) -> Mapping[str, Any] | None:
    for c in s.get("criteria") or []:
        if c.get("metric") == metric:
            return c
    return None


def _cell(c: Mapping[str, Any] | None) -> str:
    if c is None:
        return "—"
    mark = {"fail": " ✗", "xfail": " (xfail)", "xpass": " (XPASS)",
            "not_evaluated": " (not evaluated)"}.get(_outcome(c), "")
    return f"{_fmt(c.get('value'), 3)}{mark}"


def _bound(c: Mapping[str, Any]) -> str:
    if c.get("limit") is None:
        return "reported"
    return f"{c.get('comparison', '<=')} {_fmt(c.get('limit'))} {c.get('unit') or ''}".strip()


def _table2(entries: list[Mapping[str, Any]]) -> list[str]:
    rows: dict[str, list[tuple[float, float, Mapping[str, Any]]]] = {}
    for s in entries:
        m = _TABLE2.match(str(s.get("name", "")))
        if not m:
            continue
        speed = float(m.group(1))
        load = float(m.group(2).replace("p", "."))
        rows.setdefault(str(s.get("profile")), []).append((speed, load, s))
    if not rows:
        return []
    lines = ["## Table 2: steady-state position error", "",
             "max |θ error| over the steady window: ≤ 0.5° on ideal, ≤ 2.5° on paper, "
             "reported on harsh (paper: ±2.5°). Electrical degrees against the plant's truth.",
             ""]
    for profile in ("ideal", "paper", "harsh", *sorted(set(rows) - {"ideal", "paper", "harsh"})):
        cells = sorted(rows.get(profile, []), key=lambda x: (x[0], x[1]))
        if not cells:
            continue
        lines += [f"### profile `{profile}`", "",
                  "| r/min | N·m | max (°) | RMS (°) | speed track (r/min) | polarity loss | "
                  "result |", "|---|---|---|---|---|---|---|"]
        for speed, load, s in cells:
            lines.append(
                f"| {speed:g} | {load:g} | {_cell(_metric(s, 'pos_err_max_deg'))} | "
                f"{_cell(_metric(s, 'pos_err_rms_deg'))} | "
                f"{_cell(_metric(s, 'speed_track_err_max_rpm'))} | "
                f"{_cell(_metric(s, 'polarity_loss_count'))} | "
                f"[{_verdict(s)}]({s['dir']}/report.md) |"
            )
        lines.append("")
    return lines


def _figures(entries: list[Mapping[str, Any]]) -> list[str]:
    lines: list[str] = []
    for s in entries:
        if _TABLE2.match(str(s.get("name", ""))):
            continue
        title = f"{s.get('figure')}: {s['name']}" if s.get("figure") else str(s["name"])
        lines += [f"## {title} ({s.get('profile')}): {_verdict(s)}", ""]
        if s.get("description"):
            lines += [str(s["description"]), ""]
        crits = s.get("criteria") or []
        if crits:
            lines += ["| criterion | value | bound | result |", "|---|---|---|---|"]
            for c in crits:
                lines.append(f"| {c.get('name')} | {_fmt(c.get('value'))} {c.get('unit') or ''}"
                             f" | {_bound(c)} | {_OUTCOME.get(_outcome(c), _outcome(c))} |")
            for c in crits:
                if _outcome(c) == "not_evaluated":
                    lines.append(f"\n- {c.get('name')}: {c.get('note')}")
                elif c.get("xfail"):
                    lines.append(f"\n- {c.get('name')}: expected failure: {c['xfail']}")
        if s.get("failure"):
            lines += ["", f"run failure: {s['failure']}"]
        lines += ["", f"recording: `rig view {s['dir']}`"
                  + (f" ({s['recording']})" if s.get("recording") else "")
                  + "".join(f"; [{p}]({s['dir']}/{p})" for p in s.get("figures") or []), ""]
    return lines


def _comparisons(comps: list[Mapping[str, Any]]) -> list[str]:
    if not comps:
        return []
    lines = ["## Comparisons between runs", "",
             "| comparison | a | b | a ? b | result |", "|---|---|---|---|---|"]
    for c in comps:
        unit = f" {c['unit']}" if c.get("unit") else ""
        lines.append(
            f"| {c['name']} | {c['a']}: {_fmt(c.get('value_a'))}{unit} | "
            f"{c['b']}: {_fmt(c.get('value_b'))}{unit} | {c['relation']} | "
            f"{_OUTCOME.get(c['outcome'], c['outcome'])} |")
    for c in comps:
        if c.get("note"):
            lines.append(f"\n- {c['name']}: {c['note']}")
        elif c.get("xfail"):
            lines.append(f"\n- {c['name']}: expected failure: {c['xfail']}")
    return [*lines, ""]


def _suite_baseline(base: Mapping[str, Any] | None) -> list[str]:
    """The suite's criteria against their baselines: counts and what moved."""
    if not base:
        return []
    counts = ", ".join(f"{n} {k}" for k, n in (base.get("counts") or {}).items())
    lines = ["## Against the baseline", "",
             f"{counts or 'nothing compared'}"
             + ("" if base.get("passed") else " — **the suite fails on it**"), ""]
    moved = base.get("moved") or []
    if moved:
        lines += ["| scenario | criterion | value | baseline | band | against it |",
                  "|---|---|---|---|---|---|"]
        for m in moved:
            unit = m.get("unit") or ""
            band = (f"{_fmt(m.get('lo'))} .. {_fmt(m.get('hi'))} {unit}"
                    if m.get("lo") is not None else m.get("note", ""))
            mark = m["class"].upper() if m["class"] in ("regressed", "changed", "stale") \
                else m["class"]
            lines.append(f"| [{m['scenario']}]({m['scenario']}/report.md) | {m['criterion']} | "
                         f"{_fmt(m.get('value'))} {unit} | {_fmt(m.get('baseline'))} {unit} | "
                         f"{band} | {mark} |")
        lines.append("")
    return lines


def suite_report(summary: Mapping[str, Any]) -> str:
    verdict = "PASS" if summary.get("passed") else "FAIL"
    entries = list(summary.get("scenarios", []))
    counts = {"pass": 0, "fail": 0, "xfail": 0, "xpass": 0, "not_evaluated": 0}
    for s in entries:
        for c in s.get("criteria") or []:
            o = _outcome(c)
            counts[o] = counts.get(o, 0) + 1
    for c in summary.get("comparisons") or []:
        counts[c["outcome"]] = counts.get(c["outcome"], 0) + 1
    lines = [
        f"# Suite {summary.get('suite')}: {verdict}",
        "",
        f"{summary.get('description', '')}",
        "",
        f"{sum(1 for s in entries if s.get('passed'))}/{len(entries)} scenarios passed; "
        f"criteria: {counts['pass']} pass, {counts['fail']} fail, {counts['xfail']} xfail, "
        f"{counts['xpass']} xpass, {counts['not_evaluated']} not evaluated.",
        "",
    ]
    lines += _suite_baseline(summary.get("baseline"))
    lines += _table2(entries)
    lines += _figures(entries)
    lines += _comparisons(list(summary.get("comparisons") or []))
    lines += [
        "## Runs",
        "",
        "| scenario | result | failed criteria / failure | wall (s) | pictures |",
        "|---|---|---|---|---|",
    ]
    for s in entries:
        why = ", ".join(s.get("failed_criteria", [])) or (s.get("failure") or "")
        pictures = ", ".join(f"[{p}]({s['dir']}/{p})" for p in s.get("figures") or [])
        lines.append(
            f"| [{s['name']}]({s['dir']}/report.md) | {'pass' if s.get('passed') else '**FAIL**'}"
            f" ({s.get('status')}) | {why} | {_fmt(s.get('wall_s'))} | {pictures} |"
        )
    return "\n".join(lines) + "\n"
