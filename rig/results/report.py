"""``report.md``: a human-readable summary of a run's ``result.json`` (and of a suite's).

A run's report opens with the answer (the verdict, what decided it, the figures), then the
details; a suite's with the table of its scenarios and their verdicts, linked.

Built as lists of lines, not with a template engine (Jinja2 is installed, with Dask's
dashboard): nearly every line holds a choice made from the result (a verdict, a class against
the baseline, a value by its DBC name, a section left out), which a template would move into
a second language without making the module shorter."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from rig.results import shown


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


def metrics_named(name: str) -> bool:
    """A counter whose values a DBC value table names."""
    from rig.data import metrics

    return metrics.enumerated(name) is not None


def answer(result: Mapping[str, Any]) -> list[str]:
    """The report's opening: the verdict, what decided it (the run's failure, each criterion
    that failed, was not evaluated or moved against its baseline), the known failures."""
    verdict = "PASS" if result.get("passed") else "FAIL"
    crits = list(result.get("criteria") or [])
    base = result.get("baseline") or {}
    counts = {o: sum(1 for c in crits if _outcome(c) == o) for o in _OUTCOME}
    said = [f"{counts['pass'] + counts['xpass']} of {len(crits)} criteria passed"]
    said += [f"{counts[o]} {_OUTCOME_WORD[o]}" for o in ("fail", "not_evaluated", "xfail",
                                                          "xpass") if counts[o]]
    moved = [f"{n} {k}" for k, n in (base.get("counts") or {}).items()
             if k in ("regressed", "changed", "stale") and n]
    if moved:
        said.append(f"{', '.join(moved)} against the baseline")
    lines = [f"**{verdict}** ({result.get('status')}): {', '.join(said)}."]
    failure = result.get("failure")
    bullets: list[str] = []
    if failure:
        bullets.append(f"**{failure.get('kind')}**: {failure.get('message')}")
    if base.get("error") or (base.get("missing") and not base.get("passed", True)):
        bullets.append(f"**baseline**: {base.get('error') or base.get('note')} (fails the run)")
    for c in crits:
        o = _outcome(c)
        b = c.get("baseline") or {}
        moved = b.get("class") in ("regressed", "changed", "stale")
        where = f"over [{_fmt((c.get('window') or [None])[0])}, " \
            f"{_fmt((c.get('window') or [None, None])[1])}] s"
        if o in ("fail", "not_evaluated"):
            why = c.get("note") if o == "not_evaluated" else \
                f"{shown.measured(c)}, limit {shown.bound(c)} {where}"
            bullets.append(f"{_OUTCOME[o]} {c.get('name')}: {why}")
        if moved:
            bullets.append(f"**{str(b['class']).upper()}** {c.get('name')}: {shown.measured(c)}"
                           f", {shown.baseline_band(c)} (`{base.get('file')}`)")
        elif o in ("xfail", "xpass"):
            bullets.append(f"{_OUTCOME[o]} {c.get('name')}: {shown.measured(c)}, limit "
                           f"{shown.bound(c)} {where}")
    if bullets:
        lines += ["", *(f"- {x}" for x in bullets)]
    return lines


def scenario_report(result: Mapping[str, Any]) -> str:
    """Markdown for one scenario run: the answer first (verdict, what decided it, the
    figure), then the details."""
    verdict = "PASS" if result.get("passed") else "FAIL"
    lines = [f"# {result.get('scenario', '?')}: {verdict}", "", *answer(result)]
    pictures = (result.get("figures") or {}).get("files") or []
    overview = [f for f in pictures if f.get("shows") == "overview"]
    if overview:
        lines += ["", f"![{result.get('scenario')}: position error, speed, currents and load; "
                  f"the windows of criteria that did not pass shaded]({overview[0]['path']})"]
    for f in pictures:
        if f.get("shows") == "criterion":
            lines += ["", f"![{f.get('criterion')}: what it read over its window, and its "
                      f"limit]({f['path']})"]
    lines += [
        "",
        "## Details",
        "",
        f"{result.get('description', '')}",
        "",
        "| | |",
        "|---|---|",
        f"| status | {result.get('status')} |",
        f"| profile | {result.get('profile')} |",
        f"| mode | {result.get('mode')} |",
        f"| bus | {result.get('bus')} / {result.get('channel')} |",
        f"| simulated | {_fmt((result.get('timing') or {}).get('sim_s'))} s |",
        f"| wall | {_fmt((result.get('timing') or {}).get('wall_s'))} s |",
        f"| speed | {_fmt((result.get('timing') or {}).get('speed_x'))}x real time |",
    ]
    if result.get("figure"):
        lines.append(f"| paper | {result['figure']} |")
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
            value = "—" if c.get("value") is None else shown.with_unit(
                str(c["metric"]), c.get("value"), unit)
            limit = "—" if c.get("limit") is None else shown.with_unit(
                str(c["metric"]), c.get("limit"), unit)
            lines.append(
                f"| {c['name']} | `{c['metric']}` | [{_fmt(w[0])}, {_fmt(w[1])}] | "
                f"{value} | {c.get('comparison', '<=')} {limit} | "
                f"{_OUTCOME.get(_outcome(c), _outcome(c))} |"
            )
            if c.get("note"):
                lines.append(f"| | | | {c['note']} | | |")
            if c.get("xfail"):
                lines.append(f"| | | | expected failure: {c['xfail']} | | |")
    else:
        lines.append("(none)")
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
    if result.get("isr_cost_differs"):
        lines += ["", "## The ISR's cost", "", f"- counted, though {result['isr_cost_differs']}"]
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
            v = counters[k]
            lines.append(f"| `{k}` | {shown.value(k, v) if metrics_named(k) else _fmt(v)} |")
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
    from rig.regression import wording  # (rig.regression reads results: imported late)

    moved = [c for c in crits if (c.get("baseline") or {}).get("class") not in
             (None, "unchanged")]
    moved.sort(key=lambda c: _by_chance(c.get("baseline") or {}))
    if moved:
        lines += ["| criterion | value | baseline | band | against it | how far (chance) | "
                  "at fresh seeds |", "|---|---|---|---|---|---|---|"]
        for c in moved:
            b = c["baseline"]
            unit = c.get("unit") or ""
            band = (f"{_fmt(b.get('lo'))} .. {_fmt(b.get('hi'))} {unit}" if "lo" in b
                    else b.get("note", ""))
            mark = b["class"].upper() if b["class"] in wording.FAILING else b["class"]
            metric = str(c.get("metric"))
            lines.append(f"| {c['name']} | {shown.with_unit(metric, c.get('value'), unit)} | "
                         f"{shown.with_unit(metric, b.get('value'), unit)} | {band} | {mark} | "
                         f"{wording.distance(b) or '—'} | {wording.confirmation(b) or '—'} |")
        if any(c["baseline"]["class"] == "excursion" for c in moved):
            lines += ["", "An *excursion* is a value beyond its band at this seed that the same "
                      "scenario at fresh seeds did not confirm (rig.regression.confirm): the "
                      "noise drawn again, not a regression; it does not fail the run."]
    return lines


def _by_chance(b: Mapping[str, Any]) -> tuple[int, float]:
    """Failing classes first, then the least likely by chance."""
    from rig.regression import wording

    chance = b.get("chance")
    return (0 if b.get("class") in wording.FAILING else 1,
            chance if isinstance(chance, int | float) else 1.0)


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
_OUTCOME_WORD = {"fail": "failed", "not_evaluated": "not evaluated", "xfail": "XFAIL (known)",
                 "xpass": "XPASS (a known failure passed: remove its xfail)"}
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
    value = "—" if c.get("value") is None else shown.value(str(c.get("metric")),
                                                          c.get("value"), 3)
    return f"{value}{mark}"


def _bound(c: Mapping[str, Any]) -> str:
    return shown.bound(c)


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
                value = shown.with_unit(str(c.get("metric")), c.get("value"), c.get("unit"))
                lines.append(f"| {c.get('name')} | {value} | {_bound(c)} | "
                             f"{_OUTCOME.get(_outcome(c), _outcome(c))} |")
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
    from rig.regression import wording

    moved = sorted(base.get("moved") or [], key=_by_chance)
    if moved:
        lines += ["| scenario | criterion | value | baseline | band | against it | how far "
                  "(chance) | at fresh seeds |", "|---|---|---|---|---|---|---|---|"]
        for m in moved:
            unit = m.get("unit") or ""
            band = (f"{_fmt(m.get('lo'))} .. {_fmt(m.get('hi'))} {unit}"
                    if m.get("lo") is not None else m.get("note", ""))
            mark = m["class"].upper() if m["class"] in wording.FAILING else m["class"]
            metric = str(m.get("metric"))
            lines.append(f"| [{m['scenario']}]({m['scenario']}/report.md) | {m['criterion']} | "
                         f"{shown.with_unit(metric, m.get('value'), unit)} | "
                         f"{shown.with_unit(metric, m.get('baseline'), unit)} | "
                         f"{band} | {mark} | {wording.distance(m) or '—'} | "
                         f"{wording.confirmation(m) or '—'} |")
        lines.append("")
    return lines


def _scenarios_table(entries: list[Mapping[str, Any]]) -> list[str]:
    """Every scenario and its verdict, linked to its report and figure: the suite at a
    glance."""
    lines = ["| scenario | verdict | failed / not evaluated / moved against the baseline | "
             "wall (s) | figure |", "|---|---|---|---|---|"]
    for s in entries:
        why = ", ".join(s.get("failed_criteria", [])) or (s.get("failure") or "")
        moved = [f"{c.get('name')} ({(c.get('baseline') or {}).get('class')})"
                 for c in s.get("criteria") or []
                 if (c.get("baseline") or {}).get("class") in ("regressed", "changed",
                                                               "stale")]
        why = "; ".join(x for x in (why, ", ".join(moved)) if x)
        figure = next((p for p in s.get("figures") or [] if p == "figure.png"), None)
        verdict = _verdict(s) if s.get("passed") else (
            f"**FAIL** ({s.get('status')})" if s.get("status") != "error"
            else f"**ERROR** ({s.get('status')})")
        lines.append(
            f"| [{s['name']}]({s['dir']}/report.md) | {verdict} | {why} | "
            f"{_fmt(s.get('wall_s'))} | "
            + (f"[figure]({s['dir']}/{figure})" if figure else "") + " |")
    return lines


def suite_report(summary: Mapping[str, Any]) -> str:
    """Markdown for a suite: its verdict and a table of every scenario's verdict first, then
    the details (Table 2, the figures, comparisons, the baseline)."""
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
        f"**{verdict}**: {sum(1 for s in entries if s.get('passed'))}/{len(entries)} scenarios "
        f"passed; criteria: {counts['pass']} pass, {counts['fail']} fail, {counts['xfail']} "
        f"xfail, {counts['xpass']} xpass, {counts['not_evaluated']} not evaluated."
        + ("" if summary.get("complete", True) else " The suite did not run to its end."),
        "",
        *_scenarios_table(entries),
        "",
        f"{summary.get('description', '')}",
        "",
    ]
    lines += _suite_baseline(summary.get("baseline"))
    lines += _table2(entries)
    lines += _figures(entries)
    lines += _comparisons(list(summary.get("comparisons") or []))
    pictures = [(s, p) for s in entries for p in s.get("figures") or [] if p != "figure.png"]
    if pictures:
        lines += ["## Pictures of the criteria that did not pass", ""]
        lines += [f"- [{s['name']}: {p}]({s['dir']}/{p})" for s, p in pictures]
    return "\n".join(lines) + "\n"
