"""One run of a scenario at one seed, end to end: the emulated bench configured and up, the
plan's commands in lockstep (or real time), capture, verdict, outputs. The parts are in
``rig.run``:

- ``plan``: the scenario as commands per PWM period and the grants that deliver them;
- ``on_bus`` / ``in_process``: plant_rt and fw_host on the bus (``rig.link``), or the
  in-process bench (``--bus inproc``, ``rig.bench.sil``) with the same configuration
  (``bench_configuration``) and the same frames before each of the same grants; ``pacing``
  sends the plan's commands in time;
- ``evaluation``: the traces merged (``rig.data.capture``), the criteria evaluated on the data
  the run produced (``rig.results.verdict``, ``rig.data.metrics``);
- ``record``: ``recording.rrd``; ``rig.results.result``: ``result.json`` and ``report.md``.

A scenario decided over its own seeds runs this once per seed (``rig.run.multi_seed``);
``rig.run.runner.run_scenario`` chooses.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Any

from rig import outputs
from rig.bench import sil
from rig.bench.configuration import BenchConfiguration, configure
from rig.data import capture
from rig.drive import commissioned
from rig.link.bus import LinkError
from rig.link.clock import BenchStall
from rig.regression import baseline
from rig.results.result import Failure, RunResult, Timing, write_result
from rig.run import evaluation, in_process, on_bus, pacing, progress
from rig.run.errors import EnvironmentProblem, RunError
from rig.run.execution import Execution
from rig.run.options import RunOptions
from rig.run.plan import Plan
from rig.run.record import write_recording
from rig.scenario import Scenario
from rig.supervisor import ChildFailed, Terminated, signals_deferred


def _now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


def bench_configuration(sc: Scenario) -> BenchConfiguration:
    """The emulated bench of a scenario: its profile with its overrides and initial rotor
    state; the firmware's parameters over the profile's hardware: what commissioning
    identified on the profile's virtual bench (``rig.drive.commissioned``), then the
    scenario's own."""
    try:
        drive = commissioned.parameters(sc.profile)
    except commissioned.CommissionedError as exc:
        raise EnvironmentProblem(str(exc)) from exc  # a broken installation: exit 3
    return configure(sc.profile, sc.overrides, {**drive, **sc.firmware},
                     {"theta_e_deg": sc.start_theta_deg, "speed_rpm": sc.initial_speed_rpm})


def run_single(sc: Scenario, opts: RunOptions) -> RunResult:
    """Runs one scenario at one seed into ``opts.out``; always writes result.json and
    report.md."""
    out = Path(opts.out)
    with outputs.claim(out, sc.periods, sc.file) as claimed:
        return _run_claimed(sc, opts, out, claimed)


def _run_claimed(sc: Scenario, opts: RunOptions, out: Path, claimed: outputs.Claim
                 ) -> RunResult:
    result = RunResult.of_scenario(
        sc, out, mode="realtime" if opts.realtime else "lockstep", started=_now(),
        timing=Timing(sim_s=sc.duration))
    plan = Plan.build(sc)
    run = Execution(preload=(*(("rig.results.recording",) if opts.record else ()),
                             *(figures_modules() if opts.figures and
                               not opts.figures_failing_only else ())))
    interrupted: BaseException | None = None
    failure: Failure | None = None
    try:
        config = bench_configuration(sc)
        if opts.bus == sil.INPROC:
            bench = in_process.sil_bench(sc, plan, config, opts, result, run)
        else:
            bench = on_bus.virtual_bench(sc, plan, config, opts, result, run)
        with progress.item(sc.name, sc.duration, enabled=opts.progress) as line, \
                bench as paced:
            run.periods_done = pacing.pace(plan, paced, run, line)
    except ChildFailed as exc:
        failure = Failure("crash", f"{exc.name}: {exc.what}", exc.log_tail, exc.name)
    except RunError as exc:
        failure = Failure(exc.kind, str(exc), exc.log_tail)
    except BenchStall as exc:
        failure = Failure("stall", str(exc))
    except LinkError as exc:
        failure = Failure("bus", str(exc))
    except EnvironmentProblem as exc:
        failure = Failure("environment", str(exc))
    except (KeyboardInterrupt, Terminated) as exc:
        interrupted = exc
        failure = Failure("interrupted", f"interrupted ({type(exc).__name__})")
    wall = run.wall()
    found = evaluation.Evaluated(failure)
    try:
        evaluation.evaluate(found, result, sc, plan, run, opts, interrupted is not None)
        baseline.judge_result(result, sc, opts.baseline, opts.realtime)
        result.timing = run.timing(wall)
        result.finished = _now()
        cap = found.capture
        if cap is not None and cap.n and opts.record:
            result.recording = write_recording(result, cap, run, found.reads)
        if cap is not None and cap.n and opts.figures and not (
                opts.figures_failing_only and result.passed):
            result.figures = write_figures(out, cap, result)
    except (KeyboardInterrupt, Terminated) as exc:
        # interrupted while the results were worked out: the result says so, whole
        cap, interrupted = None, interrupted or exc
        evaluation.judge_interrupted(result, sc, plan, run, found.failure, exc)
        _kept_before(out, result)
        result.timing = run.timing(wall)
        result.finished = _now()
    with signals_deferred():  # result.json and report.md are written whole
        result.kept = outputs.prune(out, keep_full=opts.keep == "all" or (
            opts.keep == "failing" and not result.passed),
                                    keep=opts.keep)
        result.capture = cap if result.kept.full_rate else None
        claimed.record()
        write_result(result)
    if interrupted is not None:
        raise interrupted
    return result


def _kept_before(out: Path, result: RunResult) -> None:
    """What the run wrote whole before a signal stopped its post-processing (the recording and
    pictures are renamed into place only when complete: rig.results.whole): said in
    result.json, not left beside a ``recording: null``."""
    rrd = out / "recording.rrd"
    if rrd.is_file():
        result.recording = {"path": rrd.name, "bytes": rrd.stat().st_size,
                            "note": "written before the run was interrupted"}
    from rig.results import figures

    pictures = [p.name for p in (out / figures.OVERVIEW, *sorted(out.glob("criterion-*.png")))
                if p.is_file()]
    if pictures:
        result.figures = {"files": [{"path": n, "shows": "overview" if n == figures.OVERVIEW
                                     else "criterion"} for n in pictures],
                          "note": "drawn before the run was interrupted"}


def figures_modules() -> tuple[str, ...]:
    """What drawing the pictures imports (matplotlib: 0.34 s of CPU), to import early."""
    from rig.results import figures

    return figures.MODULES


def write_figures(out: Path, cap: capture.Capture, result: RunResult) -> dict[str, Any]:
    """The run's pictures (``rig.results.figures``); the error instead when they cannot be
    drawn (the verdict stands without them)."""
    from rig.results import figures

    try:
        return figures.write(out, cap, result.to_json())
    except Exception as exc:  # a picture is never worth a run
        return {"files": [], "error": f"{type(exc).__name__}: {exc}"}
