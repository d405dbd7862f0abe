"""A run's verdicts as JUnit XML, the result format CI systems read (Jenkins, GitLab, GitHub
test reporters, junitparser).

One ``<testsuite>`` per scenario run, one ``<testcase>`` per criterion (``classname`` the
scenario, ``name`` the criterion), and one for the run itself (``<scenario>: run``: a crash, a
stall, a capture loss fails it, an environment problem is an error). Outcomes map as pytest
maps its own: fail -> ``<failure>``, not evaluated -> ``<error>``, xfail -> ``<skipped
type="xfail">`` with the reason, xpass -> passed. Every criterion's metric, value, limit,
comparison, unit, window and outcome are ``<property>`` elements, and the report it is judged
in is attached: a ``report`` property and ``[[ATTACHMENT|path]]`` in ``<system-out>`` (the
convention Jenkins' and GitLab's attachment readers follow). A suite's comparisons are a
``<testsuite>`` of their own.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from rig import outputs

RUN_CASE = "run"


def _text(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    if isinstance(v, list | tuple):
        return ",".join(_text(x) for x in v)
    return str(v)


def criterion_properties(c: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The properties of one criterion (also what the pytest plugin records)."""
    return [(key, _text(c.get(key))) for key in ("metric", "value", "limit", "comparison",
                                                  "unit", "window", "outcome")
            if c.get(key) is not None] + [(f"param.{k}", _text(v))
                                          for k, v in (c.get("params") or {}).items()]


def _bound(c: Mapping[str, Any]) -> str:
    if c.get("limit") is None:
        return "reported"
    return f"{c.get('comparison', '<=')} {c['limit']:g} {c.get('unit') or ''}".strip()


def _case(suite: ET.Element, classname: str, name: str, time_s: float,
          props: Iterable[tuple[str, str]], report: str) -> ET.Element:
    case = ET.SubElement(suite, "testcase", classname=classname, name=name,
                         time=f"{time_s:.3f}")
    pe = ET.SubElement(case, "properties")
    for key, value in [*props, ("report", report)]:
        ET.SubElement(pe, "property", name=key, value=value)
    return case


def _outcome(case: ET.Element, outcome: str, message: str, detail: str) -> None:
    if outcome == "fail":
        ET.SubElement(case, "failure", message=message, type="criterion").text = detail
    elif outcome == "not_evaluated":
        ET.SubElement(case, "error", message=message, type="not_evaluated").text = detail
    elif outcome == "xfail":
        ET.SubElement(case, "skipped", message=message, type="xfail").text = detail


def scenario_suite(result: Mapping[str, Any], report: str) -> ET.Element:
    """A ``<testsuite>`` for one run's ``result.json`` content."""
    name = str(result.get("scenario", "?"))
    timing = result.get("timing") or {}
    wall = float(timing.get("wall_s") or 0.0)
    suite = ET.Element("testsuite", name=name)
    if result.get("started"):
        suite.set("timestamp", str(result["started"]))
    props = ET.SubElement(suite, "properties")
    versions = result.get("versions") or {}
    for key, value in [("profile", result.get("profile")), ("mode", result.get("mode")),
                       ("bus", result.get("bus")), ("channel", result.get("channel")),
                       ("status", result.get("status")), ("report", report),
                       *((f"version.{k}", v) for k, v in sorted(versions.items()))]:
        if value is not None:
            ET.SubElement(props, "property", name=key, value=_text(value))
    criteria = list(result.get("criteria") or [])
    run_case = _case(suite, name, f"{name}: {RUN_CASE}", wall,
                     [("status", _text(result.get("status")))], report)
    failure = result.get("failure")
    if failure:
        kind = str(failure.get("kind"))
        detail = "\n".join(x for x in (str(failure.get("message", "")),
                                       str(failure.get("log_tail") or "")) if x)
        tag = "error" if result.get("status") == "error" else "failure"
        ET.SubElement(run_case, tag, message=f"{kind}: {failure.get('message')}",
                      type=kind).text = detail
    for c in criteria:
        outcome = str(c.get("outcome") or ("pass" if c.get("passed") else "fail"))
        case = _case(suite, name, f"{name}: {c.get('name')}", 0.0, criterion_properties(c),
                     report)  # (judged on the run's capture: its time is the run's)
        value = c.get("value")
        shown = "n/a" if value is None else f"{value:.6g}"
        what = f"{c.get('metric')} = {shown} {c.get('unit') or ''}".strip()
        where = f"over {_text(c.get('window'))} s"
        if outcome == "fail":
            _outcome(case, outcome, f"{what}, limit {_bound(c)}",
                     f"{c.get('name')}: {what} {where}, limit {_bound(c)}")
        elif outcome == "not_evaluated":
            _outcome(case, outcome, str(c.get("note") or "not evaluated"), str(c.get("note")))
        elif outcome == "xfail":
            _outcome(case, outcome, f"expected failure: {c.get('xfail')}",
                     f"{what} {where} (limit {_bound(c)}): {c.get('xfail')}")
        ET.SubElement(case, "system-out").text = f"[[ATTACHMENT|{report}]]"
    ET.SubElement(run_case, "system-out").text = f"[[ATTACHMENT|{report}]]"
    _count(suite, wall)
    return suite


def comparisons_suite(suite_name: str, comparisons: Sequence[Mapping[str, Any]],
                      report: str) -> ET.Element:
    """A ``<testsuite>`` for a suite's comparisons between runs."""
    suite = ET.Element("testsuite", name=f"{suite_name}: comparisons")
    for c in comparisons:
        props = [(k, _text(c.get(k))) for k in ("criterion", "a", "b", "relation", "value_a",
                                                 "value_b", "unit", "outcome")]
        case = _case(suite, suite_name, f"{suite_name}: {c.get('name')}", 0.0, props, report)
        message = (f"{c.get('a')}: {_text(c.get('value_a'))} {c.get('relation')} "
                   f"{c.get('b')}: {_text(c.get('value_b'))}")
        detail = str(c.get("note") or c.get("xfail") or message)
        _outcome(case, str(c.get("outcome")), message if c.get("outcome") != "xfail"
                 else f"expected failure: {c.get('xfail')}", detail)
        ET.SubElement(case, "system-out").text = f"[[ATTACHMENT|{report}]]"
    _count(suite, 0.0)
    return suite


def _count(suite: ET.Element, wall: float) -> None:
    cases = suite.findall("testcase")
    suite.set("tests", str(len(cases)))
    for attr, tag in (("failures", "failure"), ("errors", "error"), ("skipped", "skipped")):
        suite.set(attr, str(sum(1 for c in cases if c.find(tag) is not None)))
    suite.set("time", f"{wall:.3f}")


def document(suites: Sequence[ET.Element], name: str) -> ET.ElementTree:
    root = ET.Element("testsuites", name=name)
    for s in suites:
        root.append(s)
    for attr in ("tests", "failures", "errors", "skipped"):
        root.set(attr, str(sum(int(s.get(attr, "0")) for s in suites)))
    root.set("time", f"{sum(float(s.get('time', '0')) for s in suites):.3f}")
    ET.indent(root)
    return ET.ElementTree(root)


def report_path(out_dir: Path, dest: Path) -> str:
    """Where the report is, as seen from the JUnit file (relative when it can be)."""
    report = Path(out_dir) / "report.md"
    try:
        return os.path.relpath(report.resolve(), Path(dest).resolve().parent)
    except ValueError:
        return str(report.resolve())


def write(dest: Path, results: Sequence[Mapping[str, Any]], name: str,
          comparisons: Sequence[Mapping[str, Any]] = (), suite_dir: Path | None = None
          ) -> Path:
    """Writes the JUnit file (whole or not at all) for the runs' result.json contents."""
    suites = [scenario_suite(r, report_path(Path(str(r.get("out_dir", "."))), dest))
              for r in results]
    if comparisons and suite_dir is not None:
        suites.append(comparisons_suite(name, comparisons, report_path(suite_dir, dest)))
    tree = document(suites, name)
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise outputs.OutputError(f"cannot create {dest.parent}: {exc.strerror or exc}"
                                 ) from exc
    outputs.write_text(dest, ET.tostring(tree.getroot(), encoding="unicode",
                                        xml_declaration=True) + "\n")
    return dest
