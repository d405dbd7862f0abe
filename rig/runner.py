"""Runs a scenario end to end: the emulated bench up, the plan's commands in lockstep (or
real time), capture, verdict, outputs. The parts are in ``rig.run``:

- ``plan``: the scenario as commands per PWM period and the grants that deliver them;
- ``on_bus`` / ``in_process``: plant_rt and fw_host on the bus (``rig.link``), or the
  in-process bench (``--bus inproc``, ``rig.sil``) with the same frames before each of the
  same grants; ``pacing`` sends the plan's commands in time;
- ``evaluation``: the traces merged (``rig.capture``), the criteria evaluated on the data
  the run produced (``rig.verdict``, ``rig.metrics``);
- ``record``, ``outputs``: ``recording.rrd``, ``result.json`` (``rig.run.result``) and
  ``report.md``; ``suite``: suites and their comparisons.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Any

from rig import capture, outdirs, sil
from rig.link.bus import LinkError
from rig.link.clock import BenchStall
from rig.run import evaluation, outputs
from rig.run.errors import EnvironmentProblem, RunError
from rig.run.execution import Execution
from rig.run.in_process import run_in_process
from rig.run.on_bus import run_on_bus
from rig.run.options import RunOptions
from rig.run.plan import Plan
from rig.run.record import write_recording
from rig.run.result import Failure, RunResult, Timing
from rig.scenario import Scenario
from rig.supervisor import ChildFailed, Terminated, signals_deferred
from rig.verdict import Coverage

EXIT_PASS = 0
EXIT_FAIL = 1
EXIT_USAGE = 2
EXIT_ENV = 3
EXIT_INTERRUPTED = 130


def _now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


def run_scenario(sc: Scenario, opts: RunOptions) -> RunResult:
    """Runs one scenario into ``opts.out``; always writes result.json and report.md."""
    if sc.seeds:
        from rig.run.multi_seed import run_over_own_seeds

        return run_over_own_seeds(sc, opts)
    out = Path(opts.out)
    outputs.prepare(out, sc)
    result = RunResult(
        out_dir=out, scenario=sc.name, scenario_file=str(sc.file),
        description=sc.description, figure=sc.figure, profile=sc.profile,
        overrides=dict(sc.overrides), firmware_params=dict(sc.firmware),
        faults=[f.to_json() for f in sc.faults], ctrl_mode=sc.ctrl_mode, fw_mode=sc.fw_mode,
        mode="realtime" if opts.realtime else "lockstep", started=_now(),
        timing=Timing(sim_s=sc.duration),
    )
    plan = Plan.build(sc)
    run = Execution(preload=(*(("rig.recording",) if opts.record else ()),
                             *(figures_modules() if opts.figures else ())))
    interrupted: BaseException | None = None
    failure: Failure | None = None
    try:
        if opts.bus == sil.INPROC:
            run_in_process(sc, plan, opts, result, run)
        else:
            run_on_bus(sc, plan, opts, result, run)
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
    cap: capture.Capture | None = None
    try:
        failure = evaluation.program_failure(run, failure, on_bus=opts.bus != sil.INPROC)
        cap, loss, failure = evaluation.merge_capture(sc, plan, out, run, opts.realtime,
                                                      failure, interrupted is not None)
        if loss is not None:
            result.capture_loss = {**loss.to_json(), "summary": loss.summary()}
        result.counters = run.counters
        coverage = evaluation.coverage(plan, cap, loss, run.periods_done, opts.realtime,
                                       interrupted is not None, failure)
        reads = evaluation.judge(result, sc, cap, coverage, failure)
        evaluation.judge_baseline(result, sc, opts.baseline, opts.realtime)
        result.timing = run.timing(wall)
        result.finished = _now()
        if cap is not None and cap.n and opts.record:
            result.recording = write_recording(result, cap, run, reads)
        if cap is not None and cap.n and opts.figures:
            result.figures = write_figures(out, cap, result)
    except (KeyboardInterrupt, Terminated) as exc:
        # interrupted while the results were worked out: the result says so, whole
        cap, interrupted = None, interrupted or exc
        _judge_interrupted(result, sc, plan, run, wall, failure, exc)
    with signals_deferred():  # result.json and report.md are written whole
        result.kept = outputs.prune(out, keep_full=opts.keep == "all" or not result.passed,
                                    keep=opts.keep)
        result.capture = cap if result.kept.full_rate else None
        outputs.write_result(result)
    if interrupted is not None:
        raise interrupted
    return result


def _judge_interrupted(result: RunResult, sc: Scenario, plan: Plan, run: Execution,
                       wall: float, failure: Failure | None, exc: BaseException) -> None:
    """The verdict of a run interrupted after its programs stopped (merging, judging or
    recording): nothing is judged, and the failure says where it stopped."""
    before = f" (after {failure.kind}: {failure.message[:200]})" if failure is not None else ""
    why = (f"interrupted ({type(exc).__name__}) while the results were worked out, before "
           f"any criterion was judged{before}")
    stopped = Failure("interrupted", why)
    result.counters = run.counters
    evaluation.judge(result, sc, None, Coverage(plan.n_periods, None, None, False, why),
                     stopped)
    result.recording = None
    result.timing = run.timing(wall)
    result.finished = _now()


def figures_modules() -> tuple[str, ...]:
    """What drawing the pictures imports (matplotlib: 0.34 s of CPU), to import early."""
    from rig import figures

    return figures.MODULES


def write_figures(out: Path, cap: capture.Capture, result: RunResult) -> dict[str, Any]:
    """The run's pictures (rig.figures); the error instead when they cannot be drawn (the
    verdict stands without them)."""
    from rig import figures

    try:
        return figures.write(out, cap, result.to_json())
    except Exception as exc:  # a picture is never worth a run
        return {"files": [], "error": f"{type(exc).__name__}: {exc}"}


def exit_code(passed: bool, status: str) -> int:
    if passed:
        return EXIT_PASS
    if status == "error":
        return EXIT_ENV
    return EXIT_FAIL


def default_out(name: str) -> Path:
    """``$HIL_OUT`` (else ``./out``) / ``<name>-<YYYYmmdd-HHMMSS>`` (``rig.outdirs``)."""
    return outdirs.default_out(name)
