"""After a run (``evaluate``): what went wrong besides the criteria (programs that did not stop
cleanly, nodes beyond the bus's reach, a restarted ADC sequence), the merged capture and its
loss report, and the verdicts on the data the run produced (``rig.results.verdict``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.bench import profiles, sil
from rig.data import capture, metrics
from rig.link.drive_master import accel_max
from rig.results.result import Failure, RunResult
from rig.results.verdict import AGAINST, Coverage, evaluate_one, outcome
from rig.run import bus_report, traffic
from rig.run.execution import TS, Execution
from rig.run.options import RunOptions
from rig.run.plan import Plan
from rig.scenario import Scenario

MAX_POST_FAILURE_PERIODS = 50_000  # after a crash, merge/record only short traces (fast)


@dataclass
class Evaluated:
    """What the evaluation has found, filled in as it goes (an interrupt leaves what it had):
    the first thing that went wrong, the merged capture, the capture rows the criteria
    read (their evidence in the recording)."""

    failure: Failure | None
    capture: capture.Capture | None = None
    reads: list[tuple[str, int, int]] = field(default_factory=list)


def evaluate(found: Evaluated, result: RunResult, sc: Scenario, plan: Plan, run: Execution,
             opts: RunOptions, interrupted: bool) -> None:
    """The run's failure, capture and verdicts, into ``found`` and ``result``."""
    found.failure = program_failure(run, found.failure, on_bus=opts.bus != sil.INPROC)
    found.capture, loss, found.failure = merge_capture(
        sc, plan, result.out_dir, run, opts.realtime, found.failure, interrupted)
    if loss is not None:
        result.capture_loss = {**loss.to_json(), "summary": loss.summary()}
    result.counters = run.counters
    if run.bus_nodes is not None:
        result.bus_report = bus_report.report(run.bus_nodes, run.counters)
    if run.can_log is not None:
        log = dict(run.can_log)
        if run.bus_nodes is not None and log.get("missed") is not None:
            log["missed"] = int(log["missed"]) + bus_report.can_log_missed(run.bus_nodes)
        result.bus_report = {**(result.bus_report or {}), "can_log": log}
    cov = coverage(plan, found.capture, loss, run.periods_done, opts.realtime, interrupted,
                   found.failure)
    on_bench = opts.bus == sil.INPROC
    extra, why, result.isr_cost_differs = isr_cost(
        sc, result.out_dir, found.capture, on_bench and not interrupted
        and opts.core_journal is None)
    found.reads = judge(result, sc, found.capture, cov, found.failure, on_bench=on_bench,
                        extra=extra, extra_missing=why)


def isr_cost(sc: Scenario, out: Path, cap: capture.Capture | None, measured: bool
             ) -> tuple[dict[str, Any], str, str]:
    """The capture-aligned columns of the ISR's cost on the target for the scenario's
    criteria of it (rig.target_m4.cost: the run's journal replayed, or the cache's counts
    for this build and journal), or why there are none; and, when the target's outputs were
    not the host's to the bit but on its path, how they differed."""
    if not any(metrics.needs_target(cr.metric) for cr in sc.criteria):
        return {}, "", ""
    journal = out / "isr.journal"
    if not measured or cap is None or not journal.is_file():
        return {}, "the ISR's cost is measured on the in-process bench from the run's own " \
            "journal (rig.target_m4.cost)", ""
    from rig.target_m4 import cost, emulator, steps

    try:
        costs = cost.measure(journal)
    except FileNotFoundError as exc:
        return {}, f"no Cortex-M4F image ({emulator.ELF_NAME}: ./hil install builds it " \
            f"with arm-none-eabi-gcc): {exc}", ""
    except (cost.TargetMismatch, steps.StepMapError, ValueError, RuntimeError) as exc:
        return {}, f"the ISR's cost could not be measured: {exc}", ""
    finally:
        journal.unlink(missing_ok=True)
    return costs.columns(cap.first_period, cap.n), "", costs.differs


def judge_interrupted(result: RunResult, sc: Scenario, plan: Plan, run: Execution,
                      failure: Failure | None, exc: BaseException) -> None:
    """The verdict of a run interrupted after its programs stopped (merging, judging or
    recording): nothing is judged, and the failure says where it stopped."""
    before = f" (after {failure.kind}: {failure.message[:200]})" if failure is not None else ""
    why = (f"interrupted ({type(exc).__name__}) while the results were worked out, before "
           f"any criterion was judged{before}")
    stopped = Failure("interrupted", why)
    result.counters = run.counters
    judge(result, sc, None, Coverage(plan.n_periods, None, None, False, why), stopped)
    result.recording = None


def program_failure(run: Execution, failure: Failure | None, on_bus: bool) -> Failure | None:
    """The programs' exit counters into the run's counters; the first thing that went wrong
    with the programs or the bus, when nothing went wrong before; foreign traffic on the
    channel before anything else (``rig.run.traffic``: the run's data is not its own)."""
    if failure is None and not run.stops and on_bus:
        failure = Failure("error", "run ended without stopping its programs")
    frames = traffic.Traffic()
    # a program that did not stop cleanly is a failure too (after a good run)
    for rep in run.stops.values():
        if rep.counters:
            node = "plant" if rep.name == "plant_rt" else "firmware"
            frames.add_program(node, rep.counters)
            run.add_counters(node, {k: v for k, v in rep.counters.items()
                                    if k not in ("tx_ids", "rx_ids", "listener_drops")})
            if run.bus_nodes is not None:
                run.bus_nodes.add_drops(node, rep.counters.get("listener_drops"))
        if failure is None and not rep.clean:
            what = ("did not stop within the grace period (killed)" if rep.killed
                    else f"stopped with exit status {rep.returncode}")
            failure = Failure("crash", f"{rep.name}: {what}", rep.log_tail, rep.name)
    counters = run.counters
    beyond = max(counters.get("plant.peers_beyond_limit", 0.0),
                 counters.get("firmware.peers_beyond_limit", 0.0))
    if failure is None and beyond > 0:
        failure = Failure("environment", f"{beyond:g} node(s) on the channel beyond the "
                          "HILBUS_MAX_PEERS (hilbus.h) a unixcan node reaches: frames were not "
                          "delivered")
    resyncs = counters.get("firmware.resyncs", 0.0)
    if failure is None and resyncs > 0:
        # the firmware followed an ADC sequence that restarted at period 0: another plant
        # on the channel, or ours restarted; the data after it is not this run's
        failure = Failure("lockstep", f"fw_host followed a restarted ADC sequence "
                          f"{resyncs:g} time(s) (another plant on the channel?)")
    if run.monitor is not None:
        counters.update(run.monitor.counters())
        counters["rig.grants"] = float(len(run.grants))
        counters["rig.rx_frames"] = float(run.monitor.link.rx)
        counters["rig.drive_faults"] = float(run.monitor.faults)
        counters["rig.grant_resends"] = float(run.grant_resends)
    if on_bus and run.rig_tx_ids is not None and run.rig_rx_ids is not None:
        frames.add_rig(run.rig_tx_ids, run.rig_rx_ids)
        counters.update(frames.named_counters())
        foreign = frames.problem(run.where)
        if foreign is not None and (failure is None or failure.kind not in (
                traffic.KIND, "interrupted")):
            before = (f" (the run itself reported {failure.kind}: {failure.message[:300]})"
                      if failure is not None else "")
            failure = Failure(traffic.KIND, foreign + before)
    return failure


def merge_capture(sc: Scenario, plan: Plan, out: Path, run: Execution, realtime: bool,
                  failure: Failure | None, interrupted: bool,
                  ) -> tuple[capture.Capture | None, capture.LossReport | None, Failure | None]:
    """The traces merged into the capture (``rig.data.capture``): the capture, its loss report
    and what failed when the traces are missing, unreadable or have holes."""
    plant_trace, fw_trace = out / "plant.trace", out / "fw.trace"
    traces_exist = plant_trace.exists() and fw_trace.exists()
    small = traces_exist and (
        plant_trace.stat().st_size + fw_trace.stat().st_size
        < MAX_POST_FAILURE_PERIODS * 3 * 72
    )
    cap: capture.Capture | None = None
    loss: capture.LossReport | None = None
    if traces_exist and (failure is None or small) and not interrupted:
        try:
            # lockstep: exactly the granted periods. Real time: the plant runs from its
            # start, before the firmware is on the bus; the overlap counts, and it must reach
            # the end of the scenario.
            expected = (0, run.periods_done - 1) if failure is None and not realtime else None
            cap, loss = capture.build(
                out / "capture", capture.default_specs(plant_trace, fw_trace),
                expected=expected,
                pole_pairs=profiles.pole_pairs(profiles.profile_values(sc.profile,
                                                                       sc.overrides)),
                speed_reference=lambda t: sc.speed_reference(t, accel_max()),
                # memory per period is bounded by what the run can have produced: the
                # scenario's periods and a minute (real time starts before the firmware)
                max_span=plan.n_periods + int(60.0 / TS),
            )
        except (ValueError, OSError) as exc:
            if failure is None:
                failure = Failure("capture", f"cannot read the traces: {exc}")
    elif failure is None:
        failure = Failure("capture", "trace files missing "
                          f"({plant_trace.name}: {plant_trace.exists()}, "
                          f"{fw_trace.name}: {fw_trace.exists()})")
    if loss is not None:
        run.counters["capture.lost"] = float(loss.lost)
        run.counters["capture.duplicates"] = float(loss.duplicates)
        if failure is None and not loss.ok:
            failure = Failure("capture_loss", loss.summary())
        elif failure is None and realtime and loss.last_period < run.periods_done - 2:
            failure = Failure("capture_loss", f"the capture ends at period {loss.last_period}, "
                              f"before the end of the scenario ({run.periods_done - 1})")
    return cap, loss, failure


def coverage(plan: Plan, cap: capture.Capture | None, loss: capture.LossReport | None,
             periods_done: int, realtime: bool, interrupted: bool,
             failure: Failure | None) -> Coverage:
    """What data the run produced, for the verdicts (rig.results.verdict): the periods the capture
    holds without a hole and whether the run reached its planned end."""
    reached = not interrupted and periods_done >= plan.n_periods
    why = "" if failure is None else f"{failure.kind}: {failure.message[:200]}"
    if failure is not None and failure.kind == traffic.KIND:
        return Coverage(plan.n_periods, None, None, False, why)  # not the run's own data
    # a hole (missing, duplicate, stray or short records) could be anywhere; a partial
    # record at the end of a trace is where a killed writer stopped: the range holds before it
    holes = loss is None or not all(m.ok for m in loss.messages)
    if cap is None or loss is None or holes or cap.n == 0:
        if loss is not None and holes:
            why = why or loss.summary()
        return Coverage(plan.n_periods, None, None, reached, why or "no capture")
    first, last = cap.first_period, cap.first_period + cap.n - 1
    if reached and loss.ok and not realtime:
        last = plan.n_periods - 1  # complete by the loss report (the firmware's last ISR)
    return Coverage(plan.n_periods, first, last, reached, why)


def judge(result: RunResult, sc: Scenario, cap: capture.Capture | None, cov: Coverage,
          failure: Failure | None, on_bench: bool = True,
          extra: Mapping[str, Any] | None = None, extra_missing: str = ""
          ) -> list[tuple[str, int, int]]:
    """The criteria's verdicts and the run's status into ``result``; the capture rows the
    criteria read (their evidence in the recording). A criterion of the ISR's cost on the
    target is judged on the in-process bench only (``on_bench``): a run on a bus leaves it
    out (the bus's fw_host is the host build, its cost is not the target's), and says so."""
    reads: list[tuple[str, int, int]] = []
    criteria = [cr for cr in sc.criteria if on_bench or not metrics.needs_target(cr.metric)]
    if len(criteria) < len(sc.criteria):
        result.left_out = [{"name": cr.name, "why": "the ISR's cost on the Cortex-M4F is "
                            "measured on the in-process bench only (--bus inproc)"}
                           for cr in sc.criteria if cr not in criteria]
    result.criteria = [evaluate_one(cr, cap, result.counters, cov, reads, extra)
                       for cr in criteria]
    if extra_missing:
        for c in result.criteria:
            if metrics.needs_target(str(c["metric"])) and c["outcome"] != "not_evaluated":
                c.update(value=None, passed=False, outcome="not_evaluated",
                         note=f"not evaluated: {extra_missing}")
    all_ok = all(outcome(c) not in AGAINST for c in result.criteria)
    if failure is None:
        result.status = "passed" if all_ok else "failed"
        result.passed = all_ok
    else:
        result.status = "interrupted" if failure.kind == "interrupted" else (
            "error" if failure.kind in ("environment", traffic.KIND) else "failed")
        result.passed = False
    result.failure = failure
    return reads
