"""Issue 36.1: the JUnit file is the run's verdict. It has a failure or an error exactly when
``rig run`` exits non-zero, on every exit path; a criterion that moved against its baseline
is a failure naming the value, the band and the baseline file; any name gives well-formed
XML. Read back with junitparser and checked against the schema of the format
(tests/python/rig/data/junit.xsd).

- a property over every shape of result the rig writes (hypothesis): outcomes, baseline
  classes (one the rig does not know yet among them), failures, suites, names with control
  characters;
- end to end, ``rig run`` on each exit path: pass, fail, xfail, stale, regressed,
  interrupted, foreign traffic, crash, and a run refused before it starts;
- ``--junit`` never replaces a user's file, and a file system that cannot take it is exit 3
  with a message, not a traceback.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
import pytest
import scenario_text
import xmlschema
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from junitparser import Error, Failure, JUnitXml, Properties, Skipped

from rig import cli
from rig.regression import baseline
from rig.regression.baseline import FAILING, SeedResult
from rig.results import junit
from rig.run import runner

XSD = xmlschema.XMLSchema(Path(__file__).parent / "data" / "junit.xsd")
ROOT = Path(__file__).resolve().parents[3]
SMOKE = ROOT / "rig" / "scenarios" / "smoke.toml"
TABLE2 = ROOT / "rig" / "scenarios" / "table2_1000rpm_1nm.toml"


def _read(dest: Path) -> JUnitXml:
    XSD.validate(str(dest))  # raises on any departure from the format (and on bad XML)
    return JUnitXml.fromfile(str(dest))


def _bad(xml: JUnitXml) -> int:
    """Failures + errors, counted from the testcases themselves (not the totals' attributes,
    which the same code writes)."""
    return sum(1 for s in xml for c in s for r in c.result if isinstance(r, Failure | Error))


# -- the property, over every shape of result ----------------------------------------------

CONTROL = st.sampled_from(["\x01", "\x1b", "\x00", "\x7f", "\ufffe", "\ud800", "&", "<", "\"",
                           "]]>", "--"])
NAMES = st.lists(st.one_of(st.text(max_size=6), CONTROL), min_size=1, max_size=4).map("".join)
OUTCOMES = ("pass", "fail", "xfail", "xpass", "not_evaluated")
# the classes the rig knows, and one it may learn (an excursion a confirmation did not
# confirm): it does not fail a run, so it must not fail the JUnit file either
CLASSES = (*baseline.CLASSES, "excursion")
FAILURE_KINDS = {"crash": "failed", "stall": "failed", "capture_loss": "failed",
                 "interrupted": "interrupted", "foreign_traffic": "error",
                 "environment": "error"}


@st.composite
def criteria(draw: st.DrawFn) -> dict[str, Any]:
    outcome = draw(st.sampled_from(OUTCOMES))
    value = None if outcome == "not_evaluated" else draw(
        st.one_of(st.none(), st.floats(-1e6, 1e6)))
    c: dict[str, Any] = {
        "name": draw(NAMES), "metric": draw(st.sampled_from(
            ["pos_err_max_deg", "fw_state_end", "firmware.fault_code", "i_phase_peak_a"])),
        "window": [0.1, 0.5], "value": value, "limit": draw(st.one_of(st.none(),
                                                                      st.floats(-10, 10))),
        "comparison": draw(st.sampled_from(["<=", ">=", "==", "report"])), "unit": "deg",
        "passed": outcome in ("pass", "xpass"), "outcome": outcome,
        "xfail": draw(NAMES) if outcome in ("xfail", "xpass") else "", "note": draw(NAMES),
    }
    cls = draw(st.one_of(st.none(), st.sampled_from(CLASSES)))
    if cls is not None:
        c["baseline"] = ({"class": cls, "value": 1.0, "lo": 0.5, "hi": 1.5, "seeds": 8}
                         if draw(st.booleans()) else {"class": cls, "note": draw(NAMES)})
    return c


@st.composite
def results(draw: st.DrawFn) -> dict[str, Any]:
    crits = draw(st.lists(criteria(), max_size=5))
    kind = draw(st.one_of(st.none(), st.sampled_from(sorted(FAILURE_KINDS))))
    base_kind = draw(st.sampled_from(["none", "judged", "missing", "required", "error"]))
    if base_kind != "judged":  # no baseline judged the criteria
        for c in crits:
            c.pop("baseline", None)
    if base_kind == "none":
        base = None
    elif base_kind == "judged":
        counts: dict[str, int] = {}
        for c in crits:
            cls = (c.get("baseline") or {}).get("class")
            if cls:
                counts[cls] = counts.get(cls, 0) + 1
        base = {"file": draw(NAMES), "counts": counts,
                "passed": not any(counts.get(k) for k in FAILING)}
    elif base_kind == "error":
        base = {"passed": False, "error": draw(NAMES)}
    else:
        base = {"passed": base_kind == "missing", "missing": "x@paper", "note": "no baseline"}
    passed = (kind is None and all(c["outcome"] not in ("fail", "not_evaluated") for c in crits)
              and (base is None or bool(base["passed"])))
    status = "passed" if passed else (FAILURE_KINDS[kind] if kind else "failed")
    return {
        "schema": "hil-result/1", "scenario": draw(NAMES), "profile": "paper",
        "status": status, "passed": passed, "out_dir": "run",
        "failure": {"kind": kind, "message": draw(NAMES), "log_tail": draw(NAMES)}
        if kind else None,
        "criteria": crits, "baseline": base, "timing": {"wall_s": 1.0},
        "versions": {"rig": draw(NAMES)},
    }


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(runs=st.lists(results(), min_size=1, max_size=3), as_suite=st.booleans(),
       comparison=st.sampled_from(["pass", "fail", "xfail", "not_evaluated"]),
       complete=st.booleans(), name=NAMES)
def test_failures_and_errors_exactly_when_the_exit_status_is_not_zero(
        tmp_path_factory: pytest.TempPathFactory, runs: list[dict[str, Any]], as_suite: bool,
        comparison: str, complete: bool, name: str) -> None:
    dest = tmp_path_factory.mktemp("j") / "j.xml"
    if as_suite:
        comparisons = [{"name": "cmp", "a": "a", "b": "b", "relation": "<=", "value_a": 1.0,
                        "value_b": 2.0, "outcome": comparison, "xfail": "why"}]
        passed = complete and all(r["passed"] for r in runs) and comparison in ("pass",
                                                                                 "xfail")
        summary = {"passed": passed, "complete": complete, "comparisons": comparisons,
                   "scenarios": [{"name": r["scenario"], "passed": r["passed"]}
                                 for r in runs]}
        junit.write(dest, runs, name, summary, suite_dir=tmp_path_factory.getbasetemp())
        status = 0 if passed else 1
    else:
        junit.write(dest, runs[:1], name)
        status = runner.exit_code(runs[0]["passed"], runs[0]["status"])
    xml = _read(dest)
    assert (_bad(xml) > 0) == (status != 0)
    assert (xml.failures + xml.errors > 0) == (status != 0)
    # every case of a run that did not pass says why; its names are the names, made XML
    for r, suite in zip(runs if as_suite else runs[:1], xml, strict=False):
        assert suite.name == junit.clean(r["scenario"])
        run_case = next(iter(suite))
        assert run_case.is_passed == bool(r["passed"])
        for c, case in zip(r["criteria"], list(suite)[1:], strict=True):
            assert case.name == junit.clean(f"{r['scenario']}: {c['name']}")
            cls = (c.get("baseline") or {}).get("class")
            bad = c["outcome"] == "fail" or (cls in FAILING and c["outcome"] != "not_evaluated")
            assert isinstance(case.result[0] if case.result else None, Failure) == bad
            assert bool(case.result and isinstance(case.result[0], Error)) == (
                c["outcome"] == "not_evaluated")
            if cls is not None:
                props = {p.name: p.value for p in case.child(Properties)}
                assert props["baseline.class"] == cls  # a class that does not fail: shown
            if cls in FAILING and bad:
                message = case.result[0].message
                assert cls.upper() in message
                if "lo" in c["baseline"]:
                    assert "within 0.5 .. 1.5" in message
                if r["baseline"] and r["baseline"].get("file"):
                    assert junit.clean(r["baseline"]["file"]) in message


# -- end to end: rig run on each exit path ---------------------------------------------------

SHORT = scenario_text.scenario(
    "closed loop on the ideal plant for the JUnit exit paths", profile="ideal", duration=0.3,
    speed=[scenario_text.ramp(300.0, 0.2), scenario_text.hold(0.1)],
    criteria=[scenario_text.criterion("position", "pos_err_max_deg", (0.2, "end"), 5.0),
              scenario_text.criterion("no polarity loss", "polarity_loss_count", (0.05, "end"),
                                      0, "==")])
LONG = SHORT.replace("duration = 0.3", "duration = 3.0")


def _scenario(tmp: Path, name: str, text: str) -> Path:
    path = tmp / f"{name}.toml"
    path.write_text(text)
    return path


def _check(dest: Path, code: int) -> JUnitXml:
    xml = _read(dest)
    assert (_bad(xml) > 0) == (code != 0), (code, dest.read_text())
    return xml


def _cases(xml: JUnitXml) -> dict[str, Any]:
    return {c.name: c for s in xml for c in s}


def _run(args: list[str], **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rig", "run", *args], capture_output=True,
                          text=True, timeout=300, check=False,
                          env={**os.environ, **env})


def test_exit_paths_pass_fail_xfail(tmp_path: Path) -> None:
    for name, extra, want in (
            ("pass", "", 0),
            ("fail", scenario_text.tables("criteria", [scenario_text.criterion(
                "too tight", "pos_err_max_deg", (0.2, "end"), 1e-6)]), 1),
            ("xfail", scenario_text.tables("criteria", [scenario_text.criterion(
                "known", "pos_err_max_deg", (0.2, "end"), 1e-6, xfail="a known one")]), 0)):
        path = _scenario(tmp_path, f"jx_{name}", SHORT + extra)
        dest = tmp_path / f"{name}.xml"
        code = cli.main(["run", str(path), "--bus", "inproc", "--quiet", "--no-record",
                         "--no-figures", "--out", str(tmp_path / name), "--junit", str(dest)])
        assert code == want
        xml = _check(dest, code)
        if name == "fail":
            assert isinstance(_cases(xml)["jx_fail: run"].result[0], Failure)
        if name == "xfail":
            assert isinstance(_cases(xml)["jx_xfail: known"].result[0], Skipped)


def test_the_issue_example_stale_baseline_fails_the_junit_file(tmp_path: Path) -> None:
    """Issue 36's example: Table 2's cell with i_max 4.4 A is stale against the paper
    baseline; the run exits 1 and the JUnit file said failures="0"."""
    copy = tmp_path / TABLE2.name
    text = TABLE2.read_text()
    assert "\ni_max = 4.5\n" in text
    copy.write_text(text.replace("\ni_max = 4.5\n", "\ni_max = 4.4\n"))
    dest = tmp_path / "j.xml"
    code = cli.main(["run", str(copy), "--bus", "inproc", "--quiet", "--no-record",
                     "--no-figures", "--out", str(tmp_path / "o"), "--junit", str(dest)])
    assert code == 1
    xml = _check(dest, code)
    stale = [c for c in _cases(xml).values() if c.result
             and isinstance(c.result[0], Failure) and c.result[0].type == "baseline_stale"]
    assert len(stale) >= 6
    for case in stale:
        assert "STALE against rig/baselines/paper.toml" in case.result[0].message
        assert "pos_err" in case.result[0].message or "=" in case.result[0].message
    # the pytest plugin agrees: the test's properties and the explanation say the same
    from rig import pytest_plugin
    from rig.results.result import RunResult

    result = RunResult.load(tmp_path / "o")
    item = types.SimpleNamespace(user_properties=[], stash=pytest.Stash())
    pytest_plugin.record(item, result)  # type: ignore[arg-type]
    props = dict(item.user_properties)
    name = TABLE2.stem
    assert props[f"{name}/passed"] == "false"
    assert props[f"{name}/verdict"] == next(
        c for c in _cases(xml).values() if c.name.endswith(": run")).result[0].message
    assert props[f"{name}/steady-state position error/baseline.class"] == "stale"
    why = result.explain()
    assert why.count("STALE against rig/baselines/paper.toml") == len(stale)
    with pytest.raises(AssertionError, match="STALE against"):
        result.assert_passed()


def test_a_regression_inside_the_limit_is_a_failure_naming_value_band_and_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from rig import scenario

    path = _scenario(tmp_path, "jx_regressed", SHORT)
    sc = scenario.load_scenario(path)
    # a baseline that says the drive did a hundred times better than it does
    seeds = (1, 2, 3, 4, 5)
    crit = {"metric": "pos_err_max_deg", "window": [0.2, 0.3], "params": {}, "unit": "deg",
            "comparison": "<="}
    runs = {s: [SeedResult([{**crit, "name": "position", "value": 1e-4 * (1 + 0.01 * s),
                             "outcome": "pass"},
                            {**crit, "name": "no polarity loss", "metric": "polarity_loss_count",
                             "window": [0.05, 0.3], "unit": "", "comparison": "==",
                             "value": 0.0, "outcome": "pass"}])] for s in seeds}
    b, problems = baseline.build("jx", seeds, [sc], runs, {})
    assert not problems
    folder = tmp_path / "baselines"
    folder.mkdir()
    (folder / "jx.toml").write_text(b.dumps())
    monkeypatch.setenv("HIL_BASELINE_DIR", str(folder))
    dest = tmp_path / "j.xml"
    code = cli.main(["run", str(path), "--bus", "inproc", "--quiet", "--no-record",
                     "--no-figures", "--out", str(tmp_path / "o"), "--junit", str(dest),
                     "--seed", "1"])
    assert code == 1
    xml = _check(dest, code)
    case = _cases(xml)["jx_regressed: position"]
    (failure,) = case.result
    assert isinstance(failure, Failure) and failure.type == "baseline_regressed"
    data = json.loads((tmp_path / "o" / "result.json").read_text())
    c = data["criteria"][0]
    assert c["outcome"] == "pass" and c["baseline"]["class"] == "regressed"
    assert f"pos_err_max_deg = {c['value']:.6g} deg" in failure.message
    assert f"within {c['baseline']['lo']:.6g} .. {c['baseline']['hi']:.6g} deg" in failure.message
    assert str(folder / "jx.toml") in failure.message or "jx.toml" in failure.message


def _start(path: Path, out: Path, dest: Path, channel: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "rig", "run", str(path), "--bus", "unixcan", "--channel",
         channel, "--out", str(out), "--no-record", "--no-figures", "--quiet", "--junit",
         str(dest)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait_for_trace(out: Path, proc: subprocess.Popen[str], size: int = 2 << 20) -> None:
    deadline = time.monotonic() + 120
    trace = out / "plant.trace"
    while not (trace.exists() and trace.stat().st_size >= size):
        assert proc.poll() is None, proc.communicate()[0]
        assert time.monotonic() < deadline, "the run never got going"
        time.sleep(0.01)


@pytest.mark.parametrize("how", ["interrupted", "crash"])
def test_exit_paths_interrupted_and_crash(tmp_path: Path, channel: str, how: str) -> None:
    path = _scenario(tmp_path, f"jx_{how}", LONG)
    out, dest = tmp_path / "o", tmp_path / "j.xml"
    proc = _start(path, out, dest, channel)
    _wait_for_trace(out, proc)
    if how == "interrupted":
        proc.send_signal(signal.SIGINT)
    else:
        os.kill(int((out / "plant.ready").read_text()), signal.SIGKILL)
    text, _ = proc.communicate(timeout=120)
    assert proc.returncode == (130 if how == "interrupted" else 1), text
    xml = _check(dest, proc.returncode)
    run = _cases(xml)[f"jx_{how}: run"]
    assert run.result[0].type == ("interrupted" if how == "interrupted" else "crash")


def test_exit_path_foreign_traffic(tmp_path: Path, channel: str) -> None:
    stop = threading.Event()
    bus = can.Bus(interface="unixcan", channel=channel)

    def chatter() -> None:
        while not stop.is_set():
            bus.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
            time.sleep(0.02)

    talker = threading.Thread(target=chatter, daemon=True)
    talker.start()
    try:
        dest = tmp_path / "j.xml"
        r = _run(["smoke", "--bus", "unixcan", "--channel", channel, "--quiet",
                  "--no-record", "--out", str(tmp_path / "o"), "--junit", str(dest)])
    finally:
        stop.set()
        talker.join()
        bus.shutdown()
    assert r.returncode == 3, r.stderr
    xml = _check(dest, r.returncode)
    run = _cases(xml)["smoke: run"]
    assert isinstance(run.result[0], Error) and run.result[0].type == "foreign_traffic"


def test_a_run_refused_before_it_starts_is_an_error_not_an_old_verdict(tmp_path: Path) -> None:
    """An output folder holding a user's file is refused (exit 3, nothing written); an old
    result.json elsewhere must not stand in for the verdict."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    dest = tmp_path / "j.xml"
    code = cli.main(["run", "smoke", "--bus", "inproc", "--quiet", "--out", str(out),
                     "--junit", str(dest)])
    assert code == 3
    xml = _check(dest, code)
    (case,) = _cases(xml).values()
    assert isinstance(case.result[0], Error) and "exit 3" in case.result[0].message
    # a scenario that does not load: exit 2, an error naming it
    code = cli.main(["run", str(tmp_path / "nope.toml"), "--junit", str(dest)])
    assert code == 2
    xml = _check(dest, code)
    (case,) = _cases(xml).values()
    assert "nope.toml" in case.result[0].message


def test_control_characters_in_names_give_well_formed_xml(tmp_path: Path) -> None:
    path = _scenario(tmp_path, "jx_names", SHORT + scenario_text.tables("criteria", [
        scenario_text.criterion("bell \x01 and escape \x1b[31m", "pos_err_max_deg",
                                (0.2, "end"), 1e-6)]))
    dest = tmp_path / "j.xml"
    code = cli.main(["run", str(path), "--bus", "inproc", "--quiet", "--no-record",
                     "--no-figures", "--out", str(tmp_path / "o"), "--junit", str(dest)])
    assert code == 1
    xml = _check(dest, code)
    assert "jx_names: bell \\x01 and escape \\x1b[31m" in _cases(xml)


# -- --junit never replaces a user's file; a file system that cannot take it -----------------


def _refused(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert cli.main(args) == 2
    return capsys.readouterr().err


def test_junit_refuses_a_users_file_as_save_params_does(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scen = _scenario(tmp_path, "jx_own", SHORT)
    text = scen.read_text()
    out = tmp_path / "d"
    base = ["run", str(scen), "--bus", "inproc", "--quiet", "--no-record", "--out", str(out)]
    # the scenario file itself; a run's own file in its output folder; a link
    assert "was not written by --junit" in _refused([*base, "--junit", str(scen)], capsys)
    assert scen.read_text() == text
    err = _refused([*base, "--junit", str(out / "result.json")], capsys)
    assert "one of the run's own files" in err and not out.exists()
    notes = tmp_path / "notes.xml"
    notes.write_text("<notes/>")
    link = tmp_path / "link.xml"
    link.symlink_to(notes)
    assert "symbolic link" in _refused([*base, "--junit", str(link)], capsys)
    assert "was not written by --junit" in _refused([*base, "--junit", str(notes)], capsys)
    assert notes.read_text() == "<notes/>"
    # a file it wrote itself is replaced
    dest = tmp_path / "j.xml"
    assert cli.main([*base, "--junit", str(dest)]) == 0
    assert cli.main([*base, "--junit", str(dest)]) == 0
    _check(dest, 0)


def _no_traceback(r: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in r.stderr, r.stderr
    assert "--junit" in r.stderr, r.stderr


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Callable[[str], Path]]:
    """Mounts a small tmpfs with the given options (root only; skips elsewhere): a full or
    read-only file system as CI's may be."""
    mounted: list[Path] = []

    def mount(options: str) -> Path:
        if os.geteuid() != 0:
            pytest.skip("mounts a tmpfs (root only)")
        where = tmp_path / f"fs{len(mounted)}"
        where.mkdir()
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                              capture_output=True, text=True, check=False)
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
        mounted.append(where)
        return where

    yield mount
    for where in mounted:
        subprocess.run(["umount", str(where)], check=False)


def test_junit_on_a_full_file_system_is_exit_3_without_a_traceback(
        tmp_path: Path, tmpfs: Callable[[str], Path]) -> None:
    full = tmpfs("size=64k")
    fd = os.open(full / "filler", os.O_WRONLY | os.O_CREAT)
    try:  # fill it to the last byte
        with contextlib.suppress(OSError):
            while True:
                os.write(fd, b"x" * 4096)
        with contextlib.suppress(OSError):
            while True:
                os.write(fd, b"x")
    finally:
        os.close(fd)
    dest = full / "j.xml"
    r = _run(["smoke", "--bus", "inproc", "--quiet", "--no-record", "--no-figures", "--out",
              str(tmp_path / "o"), "--junit", str(dest)])
    assert (tmp_path / "o" / "result.json").is_file(), r.stderr  # the run itself is kept
    assert r.returncode == 3, r.stderr
    _no_traceback(r)
    assert "No space left on device" in r.stderr
    assert sorted(p.name for p in full.iterdir()) == ["filler"]  # nothing left behind


def test_junit_on_a_read_only_file_system_is_exit_3_without_a_traceback(
        tmp_path: Path, tmpfs: Callable[[str], Path]) -> None:
    ro = tmpfs("size=64k,ro")
    r = _run(["smoke", "--bus", "inproc", "--quiet", "--no-record", "--no-figures",
              "--out", str(tmp_path / "o"), "--junit", str(ro / "j.xml")])
    assert r.returncode == 3, r.stderr
    _no_traceback(r)
    assert "Read-only file system" in r.stderr
