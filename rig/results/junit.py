"""A run's verdict as JUnit XML, the result format CI systems read (Jenkins, GitLab, GitHub
test reporters), built with junitparser.

The file says what the rig decided, on every exit path: it has a failure or an error exactly
when ``rig run`` exits non-zero.

- One ``<testsuite>`` per scenario run, one ``<testcase>`` per criterion (``classname`` the
  scenario, ``name`` the criterion) and one for the run itself (``<scenario>: run``).
- A criterion: failed its limit -> ``<failure>``; regressed, changed or stale against its
  baseline (the classes that fail a run: ``rig.regression.baseline.FAILING``) ->
  ``<failure>`` naming the value, the band and the baseline file, even inside its limit; not
  evaluated -> ``<error>``; XFAIL -> ``<skipped type="xfail">`` with its reason; XPASS ->
  passed. Its class against the baseline is a property either way (a class that does not
  fail the run, such as an excursion a confirmation did not confirm, only there).
- The run's testcase fails whenever the run does: a crash, a stall, a capture loss, an
  interrupt, a failed or not evaluated criterion, a baseline it moved against, a required
  baseline missing; a run that could not start, or foreign traffic, is an ``<error>``. A run
  that wrote no result at all (``nothing_ran``) is an error too.
- Every criterion's metric, value, limit, comparison, unit, window and outcome are
  ``<property>`` elements, and the report is attached: a ``report`` property and
  ``[[ATTACHMENT|path]]`` in ``<system-out>`` (the convention Jenkins' and GitLab's attachment
  readers follow). A suite's own verdict and its comparisons are a ``<testsuite>`` of their own.
- Any name makes well-formed XML: characters XML 1.0 cannot hold (control characters such as
  ``\\x01`` or ``\\x1b``) are written as their escape, ``\\x1b``.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rig import outputs
from rig.results import shown

if TYPE_CHECKING:
    from junitparser import JUnitXml, TestCase, TestSuite

RUN_CASE = "run"
DIGITS = 6  # significant digits of the values in messages (the properties hold them all)
# marks a file rig run --junit wrote: the only kind it replaces (rig.commands.run)
MARK = "<!-- the verdict of rig run, as JUnit XML (rig/results/junit.py) -->"
# what XML 1.0 cannot hold, even escaped: C0 controls but tab, LF, CR; surrogates; U+FFFE/F
_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def clean(text: Any) -> str:
    """``text`` as XML can hold it: each character it cannot as a visible escape."""
    return _NOT_XML.sub(lambda m: f"\\x{ord(m.group()):02x}" if ord(m.group()) < 0x100
                        else f"\\u{ord(m.group()):04x}", str(text))


def _text(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    if isinstance(v, list | tuple):
        return ",".join(_text(x) for x in v)
    return str(v)


def criterion_properties(c: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The properties of one criterion (also what the pytest plugin records): its metric,
    value, limit, ... and its class against the baseline."""
    props = [(key, _text(c.get(key))) for key in ("metric", "value", "limit", "comparison",
                                                   "unit", "window", "outcome")
             if c.get(key) is not None]
    props += [(f"param.{k}", _text(v)) for k, v in (c.get("params") or {}).items()]
    b = c.get("baseline") or {}
    props += [(f"baseline.{k}", _text(b[k])) for k in ("class", "value", "lo", "hi",
                                                        "distance", "chance", "note")
              if b.get(k) is not None]
    conf = b.get("confirmation") or {}
    props += [(f"baseline.confirmation.{k}", _text(conf[k]))
              for k in ("seeds", "values", "p", "alpha", "confirmed") if conf.get(k) is not None]
    return props


def failing_classes() -> tuple[str, ...]:
    """The baseline classes that fail a run (rig.regression.baseline owns the list)."""
    from rig.regression.baseline import FAILING

    return tuple(FAILING)


def window_text(c: Mapping[str, Any]) -> str:
    """``over 0.3,0.5 s``: a criterion's window, as the messages say it."""
    return f"over {_text(c.get('window'))} s"


def criterion_verdict(c: Mapping[str, Any], baseline_file: str | None
                      ) -> tuple[str, str, str, str] | None:
    """What a criterion's testcase holds: (tag, type, message, detail), None when it passed.
    ``tag`` is failure, error or skipped."""
    outcome = str(c.get("outcome") or ("pass" if c.get("passed") else "fail"))
    name = str(c.get("name"))
    if outcome == "not_evaluated":
        note = str(c.get("note") or "not evaluated")
        return "error", "not_evaluated", note, f"{name}: {note}"
    reasons: list[tuple[str, str]] = []
    if outcome == "fail":
        reasons.append(("criterion",
                        f"{shown.measured(c, DIGITS)}, limit {shown.bound(c, DIGITS)}"))
    b = c.get("baseline") or {}
    cls = b.get("class")
    if cls in failing_classes():
        against = f"against {baseline_file}" if baseline_file else "against its baseline"
        if "lo" in b:
            from rig.regression.wording import confirmation, distance

            what = "; ".join(x for x in (
                f"{shown.measured(c, DIGITS)}, {shown.baseline_band(c, DIGITS)}",
                distance(b), confirmation(b)) if x)
        else:
            what = f"{shown.measured(c, DIGITS)}: {b.get('note') or 'no band'}"
        reasons.append((f"baseline_{cls}", f"{str(cls).upper()} {against}: {what}"))
    if reasons:
        message = "; ".join(text for _, text in reasons)
        return ("failure", "+".join(kind for kind, _ in reasons), message,
                f"{name}: {message} ({window_text(c)})")
    if outcome == "xfail":
        return ("skipped", "xfail", f"expected failure: {c.get('xfail')}",
                f"{shown.measured(c, DIGITS)} {window_text(c)} "
                f"(limit {shown.bound(c, DIGITS)}): {c.get('xfail')}")
    return None


def run_verdict(result: Mapping[str, Any]) -> tuple[str, str, str, str] | None:
    """What the run's own testcase holds (tag, type, message, detail); None when it passed."""
    failure = result.get("failure")
    if failure:
        kind = str(failure.get("kind"))
        detail = "\n".join(x for x in (str(failure.get("message", "")),
                                       str(failure.get("log_tail") or "")) if x)
        error = result.get("status") == "error" or kind in ("environment", "foreign_traffic")
        return ("error" if error else "failure", kind, f"{kind}: {failure.get('message')}",
                detail)
    if result.get("passed"):
        return None
    why: list[str] = []
    criteria = list(result.get("criteria") or [])
    failed = [str(c.get("name")) for c in criteria if c.get("outcome") == "fail"]
    missing = [str(c.get("name")) for c in criteria if c.get("outcome") == "not_evaluated"]
    if failed:
        why.append(f"{len(failed)} criteria failed: {', '.join(failed)}")
    if missing:
        why.append(f"{len(missing)} not evaluated: {', '.join(missing)}")
    base = result.get("baseline") or {}
    if base.get("error"):
        why.append(f"baseline: {base['error']}")
    elif base.get("missing") and not base.get("passed", True):
        why.append(f"baseline required: {base.get('note') or 'none found'}")
    elif not base.get("passed", True):
        moved = [f"{n} {k}" for k, n in (base.get("counts") or {}).items()
                 if k in failing_classes()]
        why.append(f"{', '.join(moved) or 'moved'} against {base.get('file')}")
    message = "; ".join(why) or f"the run did not pass ({result.get('status')})"
    return "failure", "verdict", message, message


def _outcome_element(case: TestCase, verdict: tuple[str, str, str, str] | None) -> None:
    from junitparser import Error, Failure, Skipped

    if verdict is None:
        return
    tag, kind, message, detail = verdict
    element = {"failure": Failure, "error": Error, "skipped": Skipped}[tag](
        clean(message), clean(kind))
    element.text = clean(detail)
    case.append(element)


def _case(classname: str, name: str, time_s: float, props: Iterable[tuple[str, str]],
          report: str | None, verdict: tuple[str, str, str, str] | None) -> TestCase:
    from junitparser import Properties, Property, SystemOut, TestCase

    case = TestCase(clean(name), clean(classname), round(time_s, 3))
    pe = Properties()
    for key, value in [*props, *((("report", report),) if report else ())]:
        pe.add_property(Property(clean(key), clean(value)))
    case.append(pe)
    _outcome_element(case, verdict)
    if report:
        case.append(SystemOut(clean(f"[[ATTACHMENT|{report}]]")))
    return case


def scenario_suite(result: Mapping[str, Any], report: str) -> TestSuite:
    """A ``<testsuite>`` for one run's ``result.json`` content."""
    from junitparser import TestSuite

    name = str(result.get("scenario", "?"))
    timing = result.get("timing") or {}
    wall = float(timing.get("wall_s") or 0.0)
    suite = TestSuite(clean(name))
    if result.get("started"):
        suite.timestamp = clean(result["started"])
    versions = result.get("versions") or {}
    base = result.get("baseline") or {}
    for key, value in [("profile", result.get("profile")), ("mode", result.get("mode")),
                       ("bus", result.get("bus")), ("channel", result.get("channel")),
                       ("status", result.get("status")), ("report", report),
                       ("baseline", base.get("file")),
                       *((f"version.{k}", v) for k, v in sorted(versions.items()))]:
        if value is not None:
            suite.add_property(clean(key), clean(_text(value)))
    suite.append(_case(name, f"{name}: {RUN_CASE}", wall,
                       [("status", _text(result.get("status")))], report, run_verdict(result)))
    for c in result.get("criteria") or []:
        # (judged on the run's capture: its time is the run's)
        suite.append(_case(name, f"{name}: {c.get('name')}", 0.0, criterion_properties(c),
                           report, criterion_verdict(c, base.get("file"))))
    suite.update_statistics()
    suite.time = round(wall, 3)
    return suite


def suite_suite(suite_name: str, summary: Mapping[str, Any], runs: int,
                report: str | None) -> TestSuite:
    """A ``<testsuite>`` for a suite's own verdict (every scenario ran and passed, its
    comparisons hold) and its comparisons between runs."""
    from junitparser import TestSuite

    suite = TestSuite(clean(f"{suite_name}: suite"))
    comparisons = list(summary.get("comparisons") or [])
    verdict: tuple[str, str, str, str] | None = None
    if not summary.get("passed"):
        listed = len(summary.get("scenarios") or [])
        why = [f"{sum(not s.get('passed') for s in summary.get('scenarios') or [])} of "
               f"{listed} scenarios did not pass"]
        if not summary.get("complete", True):
            why.append("the suite did not run to its end")
        if runs < listed:
            why.append(f"{listed - runs} scenario results could not be read")
        bad = [str(c.get("name")) for c in comparisons if c.get("outcome") not in
               ("pass", "xfail")]
        if bad:
            why.append(f"comparisons not holding: {', '.join(bad)}")
        verdict = ("failure", "suite", "; ".join(why), "; ".join(why))
    suite.append(_case(suite_name, f"{suite_name}: {RUN_CASE}", 0.0,
                       [("passed", _text(summary.get("passed")))], report, verdict))
    for c in comparisons:
        props = [(k, _text(c.get(k))) for k in ("criterion", "a", "b", "relation", "value_a",
                                                 "value_b", "unit", "outcome")]
        message = (f"{c.get('a')}: {_text(c.get('value_a'))} {c.get('relation')} "
                   f"{c.get('b')}: {_text(c.get('value_b'))}")
        detail = str(c.get("note") or c.get("xfail") or message)
        outcome = str(c.get("outcome"))
        cverdict = {"fail": ("failure", "comparison", message, detail),
                    "not_evaluated": ("error", "not_evaluated", message, detail),
                    "xfail": ("skipped", "xfail", f"expected failure: {c.get('xfail')}",
                              detail)}.get(outcome)
        suite.append(_case(suite_name, f"{suite_name}: {c.get('name')}", 0.0, props, report,
                           cverdict))
    suite.update_statistics()
    return suite


def nothing_ran(name: str, status: int, why: str) -> TestSuite:
    """A ``<testsuite>`` for a run that wrote no result (refused before it started, a
    scenario that does not load): its run testcase is an error with the reason."""
    from junitparser import TestSuite

    suite = TestSuite(clean(name))
    suite.append(_case(name, f"{name}: {RUN_CASE}", 0.0, [("exit_status", str(status))],
                       None, ("error", "not_run", f"exit {status}: {why}", why)))
    suite.update_statistics()
    return suite


def document(suites: Sequence[TestSuite], name: str) -> JUnitXml:
    from junitparser import JUnitXml

    xml = JUnitXml(clean(name))
    for s in suites:
        xml.append(s)  # (not add_testsuite: it merges suites that compare equal)
    xml.update_statistics()
    return xml


def report_path(out_dir: Path, dest: Path) -> str:
    """Where the report is, as seen from the JUnit file (relative when it can be)."""
    report = Path(out_dir) / "report.md"
    try:
        return os.path.relpath(report.resolve(), Path(dest).resolve().parent)
    except ValueError:
        return str(report.resolve())


def text_of(xml: JUnitXml) -> str:
    """The file's text: the declaration, the mark, the document."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(xml.tostring())
    ET.indent(root)  # (ElementTree escapes a line break inside an attribute; minidom does not)
    body = ET.tostring(root, encoding="unicode")
    return f'<?xml version="1.0" encoding="utf-8"?>\n{MARK}\n{body}\n'


def write_document(dest: Path, xml: JUnitXml) -> Path:
    """Writes the JUnit file whole or not at all (OutputError when it cannot)."""
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise outputs.OutputError(f"cannot create {dest.parent}: {exc.strerror or exc}"
                                  ) from exc
    outputs.write_text(dest, text_of(xml))
    return dest


def write(dest: Path, results: Sequence[Mapping[str, Any]], name: str,
          summary: Mapping[str, Any] | None = None, suite_dir: Path | None = None) -> Path:
    """Writes the JUnit file (whole or not at all) for the runs' result.json contents and,
    for a suite, its summary."""
    suites = [scenario_suite(r, report_path(Path(str(r.get("out_dir", "."))), dest))
              for r in results]
    if summary is not None:
        suites.append(suite_suite(name, summary, len(results),
                                  report_path(suite_dir, dest) if suite_dir else None))
    return write_document(dest, document(suites, name))


def is_written_file(path: Path) -> bool:
    """A file ``rig run --junit`` wrote (the only kind it replaces)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(200)
    except OSError:
        return False
    return MARK.encode() in head
