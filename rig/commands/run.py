"""``rig run``, ``rig list``, ``rig view``: scenarios from the command line."""

from __future__ import annotations

import argparse
import contextlib
import fnmatch
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE

if TYPE_CHECKING:
    from rig.results.result import RunResult

EPILOG_RUN = """\
exit status: 0 every criterion passed; 1 a criterion failed or was not evaluated (its
window was not captured), or the run failed (crash, stall, time-out, capture loss); 2 usage
or scenario schema error; 3 the run could not start here (programs not built, bus
unavailable, an output folder that is not a run's), or foreign traffic on its channel (a node
outside the run sent frames; nodes that only listen are welcome); 130 interrupted.

output: DIR/result.json (verdict, criteria, counters, versions), DIR/report.md (with
DIR/figure.png and a DIR/criterion-N.png per criterion that did not pass),
DIR/recording.rrd (open with `rig view DIR`: display series at <= 1 kHz, and every capture
column a criterion read at the full 10 kHz over the rows it read) and the programs' logs.
A scenario that does not pass also keeps DIR/*.trace (every frame) and DIR/capture/ (the
merged full-rate columns); --keep-all keeps them for every scenario. --can-log FORMAT adds
DIR/bus.asc, bus.blf or bus.log: every frame on the channel, live. A suite writes one
sub-folder per scenario plus a summary result.json and report.md in DIR. Without --out:
$HIL_OUT or ./out, plus name and time; `rig clean` lists and removes old runs.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "run", help="run a scenario or a suite and assert on its criteria",
        description="Start plant_rt and fw_host on the bus, run the scenario's speed and load "
        "profile (lockstep by default), capture every PWM period losslessly, evaluate the "
        "pass criteria and write result.json, report.md and recording.rrd.",
        epilog=EPILOG_RUN,
    )
    p.add_argument("target", metavar="SCENARIO|SUITE",
                   help="a scenario or suite name (see `rig list`) or a path to its TOML file")
    cliargs.add_shared(p, "out", type=Path,
                       help="output folder (default: $HIL_OUT or ./out, plus name and time)")
    cliargs.add_shared(p, "bus", choices=cliargs.BUS_WITH_INPROC,
                       help="transport (default: $HIL_BUS, else auto: SocketCAN when "
                       "available); inproc: plant and firmware core in this process, no bus "
                       "(rig.bench.sil; lockstep only)")
    cliargs.add_shared(p, "channel", env="HIL_CHANNEL",
                       help="bus channel (default: $HIL_CHANNEL, else on unixcan one of the "
                       "run's own, run-<pid>, and on SocketCAN vcan0)")
    p.add_argument("--realtime", action="store_true",
                   help="pace the plant on the wall clock instead of lockstep")
    p.add_argument("--live", action="store_true",
                   help="stream decimated telemetry to a spawned Rerun viewer while running")
    p.add_argument("--web", action="store_true",
                   help="with --live: stream to the Rerun web viewer instead (its address is "
                   "printed; it stops with the run: afterwards `rig view --web DIR`)")
    p.add_argument("--web-port", type=cliargs.port, default=None, metavar="PORT",
                   help="with --live --web: the web viewer's HTTP port (default 9090)")
    p.add_argument("--grpc-port", type=cliargs.port, default=None, metavar="PORT",
                   help="with --live --web: the gRPC server's port (default 9876)")
    cliargs.add_shared(p, "timeout",
                       help="wall-clock limit per scenario, s (default: from the scenario)")
    p.add_argument("--stall-s", type=cliargs.number(float, minimum=0.1), default=None,
                   metavar="S", help="on a bus in lockstep: no progress at all for S seconds "
                   "of wall time ends the run as stalled (default 10; a machine that may "
                   "starve the bench longer, e.g. a TCG VM on a loaded host, needs more)")
    p.add_argument("--no-record", action="store_true",
                   help="skip writing recording.rrd (the verdict does not depend on it)")
    p.add_argument("--no-figures", action="store_true",
                   help="skip drawing figure.png and the pictures of the criteria that did not "
                   "pass (shown in report.md)")
    p.add_argument("--failing-figures", action="store_true",
                   help="draw the pictures only for scenarios that do not pass (the gate: a "
                   "passing run's pictures cost about as much CPU as its closed loop)")
    p.add_argument("--keep-all", action="store_true",
                   help="keep the full-rate traces (*.trace) and capture columns (capture/) of "
                   "passing scenarios too (default: only of scenarios that did not pass; "
                   "`rig export` needs them)")
    p.add_argument("--seed", type=cliargs.number(int, minimum=0, maximum=2**31 - 1), default=None,
                   metavar="N",
                   help="the plant's noise seed for every scenario (default: the profile's, "
                   "1); the baselines hold seeds 1-8")
    p.add_argument("--jobs", "-j", type=cliargs.number(int, minimum=1, maximum=64), default=1,
                   metavar="N",
                   help="a suite in process (--bus inproc): run N scenarios at once, one "
                   "worker process each (default 1)")
    p.add_argument("--cluster", default=None, metavar="tcp://HOST:PORT",
                   help="a suite in process: run its scenarios on the Dask cluster whose "
                   "scheduler is at this address (each worker must run this same rig; the "
                   "results come back into --out)")
    p.add_argument("--no-worker-timeout", type=cliargs.number(above=0.0), default=60.0,
                   metavar="S", help="with --cluster: end the suite when the cluster has had "
                   "no worker for S seconds (default 60); its runs not done fail, exit 3")
    p.add_argument("--baseline", default="auto", metavar="auto|require|off|FILE",
                   help="compare every criterion with the committed baseline "
                   "(rig/baselines/): auto where one exists (default), require: a scenario "
                   "or criterion without one fails, off: the limits only, FILE: that "
                   "baseline file, as require")
    p.add_argument("--no-confirm", action="store_true",
                   help="fail on a value beyond its baseline's band at once, without "
                   "confirming it at fresh seeds (rig.regression.confirm; the gate before "
                   "issue 35)")
    p.add_argument("--fail-fast", action="store_true",
                   help="a suite: start no further scenario once one did not pass")
    p.add_argument("--can-log", choices=("asc", "blf", "log"), default=None, metavar="FORMAT",
                   help="on a bus: also log every frame that crosses the run's channel, live, "
                   "by a node of the rig's own (lossless on unixcan in lockstep), into "
                   "DIR/bus.asc, bus.blf or bus.log (candump -L); the file says it is a live "
                   "capture where its format allows (`rig export --can-log` rebuilds one "
                   "from the traces instead)")
    p.add_argument("--junit", type=Path, default=None, metavar="FILE",
                   help="also write the verdicts as JUnit XML for CI systems: a testcase per "
                   "criterion (metric, value, limit as properties, the report attached) and "
                   "one for the run itself")
    cliargs.add_shared(p, "quiet", help="no progress line")
    cliargs.command(p, cmd_run)

    ls = cliargs.verb(
        sub, "list", help="list scenarios and suites (name, profile, duration, description)",
        description="List the scenario and suite files shipped in rig/scenarios "
        "(schema-checked: an invalid file is reported with its file, line and field and the "
        "command exits 2).",
    )
    ls.add_argument("--metrics", action="store_true",
                    help="list the metrics criteria can use instead")
    ls.add_argument("--json", action="store_true", help="machine-readable output")
    cliargs.command(ls, cmd_list)

    v = cliargs.verb(
        sub, "view", help="open a run's recording.rrd in the Rerun viewer",
        description="Open DIR/recording.rrd (or every scenario's recording of a suite "
        "folder, or an .rrd file) in the Rerun viewer.",
    )
    v.add_argument("path", type=Path, metavar="DIR", help="a run folder or an .rrd file")
    v.add_argument("--web", action="store_true",
                   help="serve the recording(s) to the Rerun web viewer and print its address "
                   "(open it in a browser; Ctrl-C stops)")
    v.add_argument("--web-port", type=cliargs.port, default=None, metavar="PORT",
                   help="the web viewer's HTTP port (default 9090)")
    v.add_argument("--grpc-port", type=cliargs.port, default=None, metavar="PORT",
                   help="the port of the gRPC server that holds the data (default 9876)")
    v.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                   help="address the viewer's servers listen on (default 127.0.0.1: this "
                   "machine only)")
    v.add_argument("--screenshot", type=Path, default=None, metavar="PNG",
                   help="with --web: open the viewer in headless Chromium, save a screenshot "
                   "once the blueprint is drawn, and exit (1 if the viewer reported an error)")
    cliargs.command(v, cmd_view)


def _bus_of(args: argparse.Namespace) -> str:
    import os

    return str(args.bus or os.environ.get("HIL_BUS") or "auto")


def with_seed(target: Any, seed: int) -> Any:
    """A scenario or suite with the plant's noise drawn from ``seed`` in every run."""
    from dataclasses import replace

    from rig import scenario

    if isinstance(target, scenario.Suite):
        return replace(target, scenarios=tuple(s.with_seed(seed) for s in target.scenarios))
    return target.with_seed(seed)


def cmd_run(args: argparse.Namespace) -> int:

    if args.junit is not None:
        problem = junit_target_problem(args.junit, args.out)
        if problem is not None:
            print(f"rig run: --junit: {problem}", file=sys.stderr)
            return EXIT_USAGE
    said: list[str] = []  # what stopped a run that wrote nothing (for the JUnit file)
    where: list[Path] = []
    started = time.time()
    from rig.supervisor import VerdictGuard

    guard = VerdictGuard()  # held once the verdict is written: a signal then changes nothing
    try:
        status = _cmd_run(args, said, where, guard)
        if args.junit is not None:
            name = Path(str(args.target)).stem if str(args.target).endswith(".toml") \
                else str(args.target)
            status = _write_junit(args.junit, where[0] if where else None, name, status,
                                  started, said[-1] if said else "")
        return status
    finally:
        guard.release()


def _refuse(said: list[str], message: str, status: int) -> int:
    print(f"rig run: {message}", file=sys.stderr)
    said.append(message)
    return status


def _cmd_run(args: argparse.Namespace, said: list[str], where: list[Path], guard: Any) -> int:
    from rig import scenario
    from rig.run import runner

    try:
        target = scenario.load(args.target)
    except FileNotFoundError as exc:
        return _refuse(said, str(exc), EXIT_USAGE)
    except scenario.ScenarioError as exc:
        return _refuse(said, f"invalid scenario:\n{exc}", EXIT_USAGE)
    if args.seed is not None:
        target = with_seed(target, args.seed)
    from rig.regression import baseline

    try:  # a malformed baseline stops the run before anything starts, not after it
        baseline.check_mode(args.baseline)
    except baseline.BaselineError as exc:
        return _refuse(said, str(exc), EXIT_USAGE)
    scenarios = target.scenarios if isinstance(target, scenario.Suite) else (target,)
    if args.jobs > 1 and _bus_of(args) != "inproc":
        return _refuse(said, "--jobs runs a suite on the in-process bench (--bus inproc); on a "
                       "bus the scenarios share its channel one at a time", EXIT_USAGE)
    if args.cluster is not None and (_bus_of(args) != "inproc"
                                     or not isinstance(target, scenario.Suite)):
        return _refuse(said, "--cluster runs a suite on the in-process bench (--bus inproc "
                       "and a suite)", EXIT_USAGE)
    if args.can_log is not None and _bus_of(args) == "inproc":
        return _refuse(said, "--can-log logs a bus; in process there is none (`rig export DIR "
                       "--can-log FILE` rebuilds a log from a run's traces)", EXIT_USAGE)
    if args.realtime and args.bus == "inproc":
        return _refuse(said, "--realtime needs a bus (the in-process bench runs in lockstep "
                       "only)", EXIT_USAGE)
    if args.realtime:
        bad = [s.name for s in scenarios if not s.realtime_ok]
        if bad:
            return _refuse(said, f"--realtime is not allowed for {', '.join(bad)} "
                           "(run.realtime_ok = false)", EXIT_USAGE)
    out = args.out or runner.default_out(target.name)
    where.append(out)
    try:
        return _run(args, target, out, guard)
    finally:
        if args.out is None:  # runs named by time pile up: say so when they have
            from rig.commands.clean import notice

            with contextlib.suppress(OSError):
                out.rmdir()  # the folder made for a run that did not start (only if empty)

            hint = notice(out.parent)
            if hint:
                print(hint, file=sys.stderr)


def junit_target_problem(dest: Path, out: Path | None) -> str | None:
    """Why ``--junit`` cannot write ``dest`` (checked before the run, as ``--save-params``
    does: a user's file is never replaced), or None. It replaces only a file it wrote
    itself, never writes through a link, and never takes the name of one of the run's own
    files in its output folder (``result.json``, ``report.md``, ...)."""
    from rig import outputs
    from rig.results import junit

    if dest.is_symlink():
        return f"{dest} is a symbolic link; refused (nothing is written through a link)"
    if out is not None:
        try:
            inside = dest.resolve().is_relative_to(out.resolve())
        except OSError:
            inside = False
        own = dest.name in (*outputs.RUN_FILES, ".hil-run") or any(
            fnmatch.fnmatch(dest.name, p) for p in outputs.RUN_PATTERNS)
        if inside and own:
            return (f"{dest} is one of the run's own files in its output folder {out}; "
                    "choose another FILE")
    if dest.exists():
        if not dest.is_file():
            return f"{dest} is not a regular file"
        if not junit.is_written_file(dest):
            return (f"{dest} exists and was not written by --junit; refused (remove it or "
                    "choose another FILE)")
    return None


def _run(args: argparse.Namespace, target: Any, out: Path, guard: Any) -> int:
    from rig.results import webview

    if args.web and not args.live:
        print("rig run: --web goes with --live (a finished run: rig view --web DIR)",
              file=sys.stderr)
        return EXIT_USAGE
    if args.live and not args.web and not webview.has_display():
        print(f"rig run: {webview.NO_DISPLAY}: the live view goes to the web viewer",
              file=sys.stderr)
        args.web = True
    if not args.web:
        return _run_with(args, target, out, None, guard)
    try:
        viewer = webview.start(web_port=args.web_port or webview.DEFAULT_WEB_PORT,
                               grpc_port=args.grpc_port or webview.DEFAULT_GRPC_PORT)
    except webview.WebViewerError as exc:
        print(f"rig run: {exc}", file=sys.stderr)
        return EXIT_ENV
    with viewer:
        print(f"rig run: live view in the web viewer at {viewer.url()} (until the run ends)",
              file=sys.stderr)
        return _run_with(args, target, out, viewer.grpc_url, guard)


def _run_with(args: argparse.Namespace, target: Any, out: Path, live_url: str | None,
              guard: Any) -> int:
    import time

    from rig import outputs, scenario
    from rig.run import runner
    from rig.run.cluster import ClusterError
    from rig.run.suite import run_suite
    from rig.supervisor import Terminated, terminate_as_exception

    opts = runner.RunOptions(
        out=out, bus=args.bus, channel=args.channel, realtime=args.realtime, live=args.live,
        live_url=live_url, progress=not args.quiet, timeout_s=args.timeout,
        record=not args.no_record, figures=not args.no_figures,
        figures_failing_only=args.failing_figures,
        keep="all" if args.keep_all else "failing",
        jobs=args.jobs, fail_fast=args.fail_fast, baseline=args.baseline,
        confirm=not args.no_confirm, cluster=args.cluster,
        no_worker_timeout_s=args.no_worker_timeout,
        can_log=args.can_log,
        **({"stall_s": args.stall_s} if args.stall_s is not None else {}),
    )
    started = time.time()
    try:
        with terminate_as_exception():
            if isinstance(target, scenario.Suite):
                suite = run_suite(target, opts)
                guard.hold()
                for r in suite.results:
                    _print_verdict(r)
                ok = suite.passed
                print(f"suite {target.name}: {'PASS' if ok else 'FAIL'} "
                      f"({sum(r.passed for r in suite.results)}/{len(target.scenarios)} passed)"
                      f" -> {out}/report.md", file=sys.stderr)
                worst = max((runner.exit_code(r.passed, r.status) for r in suite.results),
                            default=EXIT_FAIL)
                return EXIT_OK if ok else max(worst, EXIT_FAIL)
            result = runner.run_scenario(target, opts)
            guard.hold()
    except (KeyboardInterrupt, Terminated) as exc:
        status = written_verdict(out, started)
        if status is None:
            print(f"rig run: interrupted; partial results in {out}", file=sys.stderr)
            return EXIT_INTERRUPTED
        guard.hold()
        print(f"rig run: {type(exc).__name__} came after the verdict was written "
              f"({out}/result.json): the exit status is the verdict's ({status})",
              file=sys.stderr)
        return status
    except (outputs.OutputError, ClusterError) as exc:
        print(f"rig run: {exc}", file=sys.stderr)
        return EXIT_ENV
    _print_verdict(result)
    print(f"  -> {out}/report.md", file=sys.stderr)
    return runner.exit_code(result.passed, result.status)


def written_verdict(out: Path, since: float) -> int | None:
    """The exit status of the verdict this run wrote into ``out`` (``result.json`` written at
    or after ``since`` that is a whole verdict: not an interrupted run or suite), or None."""
    from rig.run import runner

    result = out / "result.json"
    try:
        if result.stat().st_mtime < since:
            return None
        data = json.loads(result.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict):
        return None
    if data.get("schema") == "hil-suite/1":
        entries = data.get("scenarios") or []
        if not data.get("complete") or not isinstance(entries, list):
            return None
        if data.get("passed"):
            return EXIT_OK
        worst = max((runner.exit_code(bool(e.get("passed")), str(e.get("status")))
                     for e in entries if isinstance(e, dict)), default=EXIT_FAIL)
        return max(worst, EXIT_FAIL)
    if data.get("status") in (None, "interrupted"):
        return None
    return runner.exit_code(bool(data.get("passed")), str(data.get("status")))


def _write_junit(dest: Path, out: Path | None, name: str, status: int, started: float,
                 why: str) -> int:
    """The JUnit file of what the run (or suite) wrote into ``out``, or of a run that wrote
    nothing; it has a failure or an error exactly when ``status`` is not 0. Exit 3 when it
    cannot be written (the run's own status otherwise)."""
    from rig.results import junit

    runs: list[dict[str, Any]] = []
    summary: dict[str, Any] | None = None
    data = _fresh_result(out / "result.json", started) if out is not None else None
    if data is not None and data.get("schema") == "hil-suite/1":
        summary = data
        for entry in data.get("scenarios") or []:
            got = _fresh_result(out / str(entry.get("dir")) / "result.json", started) \
                if out is not None else None
            if got is not None:
                runs.append(got)
    elif data is not None:
        runs = [data]
    try:
        suites = [junit.scenario_suite(r, junit.report_path(Path(str(r.get("out_dir", "."))),
                                                              dest)) for r in runs]
        if summary is not None and out is not None:
            suites.append(junit.suite_suite(name, summary, len(runs),
                                            junit.report_path(out, dest)))
        doc = junit.document(suites, name)
        if status != 0 and doc.failures + doc.errors == 0:
            # the run said no, and nothing it wrote says why: the file says it all the same
            doc = junit.document([*suites, junit.nothing_ran(
                name, status, why or f"rig run exited {status} (see its output)")], name)
        junit.write_document(dest, doc)
    except OSError as exc:  # a full or read-only file system, a folder in the way
        print(f"rig run: --junit: {exc}", file=sys.stderr)
        return max(status, 3)
    print(f"  -> {dest} (JUnit XML)", file=sys.stderr)
    return status


def _fresh_result(path: Path, started: float) -> dict[str, Any] | None:
    """A result.json this command wrote (not one an earlier run left there), else None."""
    try:
        if path.stat().st_mtime < started - 1.0:
            return None
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _print_verdict(result: RunResult) -> None:
    from rig.results import shown

    verdict = "PASS" if result.passed else "FAIL"
    print(f"{result.scenario}: {verdict} ({result.status})", file=sys.stderr)
    failure = result.failure
    if failure is not None:
        print(f"  {failure.kind}: {failure.message}", file=sys.stderr)
        for line in failure.log_tail.splitlines()[-15:]:
            print(f"    | {line}", file=sys.stderr)
    base = result.baseline or {}
    if base.get("error") or (base.get("missing") and not base.get("passed")):
        print(f"  BASELINE: {base.get('error') or base.get('note')}", file=sys.stderr)
    elif base.get("counts") and not base.get("passed"):
        print(f"  BASELINE: {_counts(base['counts'])} against {base.get('file')}",
              file=sys.stderr)
    for c in result.criteria:
        mark = {"pass": "ok   ", "fail": "FAIL ", "xfail": "XFAIL", "xpass": "XPASS",
                "not_evaluated": "NOT EVALUATED"}.get(
            str(c.get("outcome")), "ok   " if c.get("passed") else "FAIL ")
        value = c.get("value")
        print(f"  {mark} {c['name']}: {shown.measured(c)} ({shown.bound(c)}) over "
              f"{c['window']}{_baseline_mark(c)}", file=sys.stderr)
        if c.get("outcome") == "not_evaluated" or (value is None and c.get("note")):
            note = str(c.get("note"))
            if failure is not None:  # the failure is printed once, above
                note = note.replace(f"({failure.kind}: {failure.message})", "(see above)")
            print(f"        {note}", file=sys.stderr)
        if c.get("xfail") and c.get("outcome") != "not_evaluated":
            print(f"        expected failure: {c['xfail']}", file=sys.stderr)


def _counts(counts: dict[str, int]) -> str:
    return ", ".join(f"{n} {k}" for k, n in counts.items())


def _baseline_mark(c: dict[str, Any]) -> str:
    """The criterion against its baseline, when it is not simply unchanged."""
    from rig.regression.wording import against_baseline

    text = against_baseline(c)
    return f"  [{text}]" if text else ""


def cmd_list(args: argparse.Namespace) -> int:
    from rig import scenario
    from rig.data import metrics

    if args.metrics:
        rows: list[dict[str, Any]] = [
            {"name": m.name, "unit": m.unit, "scope": m.scope, "params": dict(m.params),
             "description": m.description}
            for m in metrics.METRICS.values()
        ]
        if args.json:
            print(json.dumps(rows, indent=1))
        else:
            for r in rows:
                params = ", ".join(f"{k}={v:g}" for k, v in r["params"].items())
                print(f"{r['name']:<26} {r['unit']:<6} {r['description']}"
                      + (f" [params: {params}]" if params else ""))
            print("\ncounters: plant.<key>, firmware.<key> (exit JSON), bench.<signal> "
                  "(BENCH_COUNTERS), rejects.<signal> (BENCH_REJECTS), rig.<key>")
        return 0
    rows_out: list[dict[str, Any]] = []
    errors: list[str] = []
    for path in scenario.scenario_files():
        try:
            s = scenario.load_scenario(path)
            rows_out.append({"name": s.name, "kind": "scenario", "profile": s.profile,
                             "duration": s.duration, "description": s.description,
                             "figure": s.figure})
        except scenario.ScenarioError as exc:
            errors.append(str(exc))
            rows_out.append({"name": path.stem, "kind": "scenario", "profile": "?",
                             "duration": None, "description": "INVALID (see below)"})
    for path in scenario.suite_files():
        try:
            su = scenario.load_suite(path)
            total = sum(s.duration for s in su.scenarios)
            rows_out.append({"name": su.name, "kind": "suite", "profile": "mixed",
                             "duration": total,
                             "description": f"{su.description} ({len(su.scenarios)} scenarios)"})
        except scenario.ScenarioError as exc:
            errors.append(str(exc))
            rows_out.append({"name": path.stem, "kind": "suite", "profile": "?",
                             "duration": None, "description": "INVALID (see below)"})
    if args.json:
        print(json.dumps({"entries": rows_out, "errors": errors}, indent=1))
    else:
        print(f"{'NAME':<30} {'KIND':<8} {'PROFILE':<7} {'DURATION':>9}  DESCRIPTION")
        for r in rows_out:
            dur = "" if r["duration"] is None else f"{r['duration']:.3g} s"
            print(f"{r['name']:<30} {r['kind']:<8} {r['profile']:<7} {dur:>9}  "
                  f"{r['description']}")
        for e in errors:
            print(e, file=sys.stderr)
    return 2 if errors else 0


def cmd_view(args: argparse.Namespace) -> int:
    path: Path = args.path
    if path.is_file():
        files = [path]
    elif (path / "recording.rrd").is_file():
        files = [path / "recording.rrd"]
    else:
        files = sorted(path.glob("*/recording.rrd"))
    if not files:
        print(f"rig view: no recording.rrd in {path}", file=sys.stderr)
        return 2
    if args.screenshot is not None and not args.web:
        print("rig view: --screenshot needs --web", file=sys.stderr)
        return 2
    if not args.web:
        from rig.results import webview

        if not webview.has_display():
            print(f"rig view: {webview.NO_DISPLAY}: use `rig view --web {path}` and open the "
                  "address it prints in a browser", file=sys.stderr)
            return 3
        port = ["--port", str(args.grpc_port)] if args.grpc_port else []
        try:
            viewer = webview.rerun_binary()
        except webview.WebViewerError as e:
            print(f"rig view: {e}", file=sys.stderr)
            return 2
        # the viewer takes this process's place: a signal meant for `rig view` (Ctrl-C, a
        # test's or a supervisor's SIGTERM) reaches the window itself, none is left behind
        sys.stdout.flush()
        sys.stderr.flush()
        os.execv(viewer, [viewer, "--bind", args.bind, *port, *map(str, files)])
    return _view_web(args, files)


# signals whose default action ends the rig: each stops the web viewer first (a SIGKILL,
# which no handler sees, ends it through the kernel: rig.results.webview)
STOPPING = ("SIGQUIT", "SIGUSR1", "SIGUSR2", "SIGALRM", "SIGVTALRM", "SIGPROF")


def _view_web(args: argparse.Namespace, files: list[Path]) -> int:
    import signal

    from rig.supervisor import Terminated, terminate_as_exception

    def stop(signum: int, frame: object) -> None:
        raise Terminated(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, stop) for sig in
                (getattr(signal, name) for name in STOPPING)}
    try:
        with terminate_as_exception():  # SIGTERM/SIGHUP stop the server too (its own session)
            return _serve_web(args, files)
    except Terminated:
        return 130
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _serve_web(args: argparse.Namespace, files: list[Path]) -> int:
    import time

    from rig.results import webview

    try:
        viewer = webview.start(files, web_port=args.web_port or webview.DEFAULT_WEB_PORT,
                               grpc_port=args.grpc_port or webview.DEFAULT_GRPC_PORT,
                               bind=args.bind)
    except webview.WebViewerError as exc:
        print(f"rig view: {exc}", file=sys.stderr)
        return 3
    with viewer:
        if args.screenshot is not None:
            return _screenshot(viewer, files, args.screenshot)
        print(f"rig view: the web viewer is at {viewer.url()}\n"
              f"          (data on {viewer.grpc_url}; Ctrl-C stops)", file=sys.stderr)
        try:
            while viewer.running():
                time.sleep(0.5)
        except KeyboardInterrupt:
            return 0
        return 0 if viewer.proc.returncode in (0, None) else 1


def _screenshot(viewer: Any, files: list[Path], png: Path) -> int:
    from rig.results import browser, recording

    expect = [f"hil-{f.parent.name}" for f in files if f.name == "recording.rrd"]
    expect += recording.VIEW_NAMES
    try:
        seen = browser.look(viewer.url(renderer="webgl"), png, expect=expect)
    except browser.BrowserError as exc:
        print(f"rig view: {exc}", file=sys.stderr)
        return 3
    print(f"rig view: screenshot -> {png} ({seen.seconds:.0f} s; {len(seen.blocked_requests)} "
          "requests outside this machine blocked)", file=sys.stderr)
    for e in ([seen.panic] if seen.panic else []) + seen.errors:
        print(f"rig view: the viewer reported: {e}", file=sys.stderr)
    return 0 if seen.ok else 1
