"""The plan's commands in time: lockstep grants (on the bus or in process) or the wall
clock (real time).

Lockstep: before each grant the rig sends DRIVE_LIMITS, DRIVE_CMD, LOAD_CMD and the
FAULT_CMDs of faults that start or end on its first period (the clock's cycle, after the
frames a fault held back until then), then the grant; DRIVE_CMD with every grant also
keeps the firmware's command time-out alive. Real time: the same commands on the wall clock
against the plant's period (estimated from BENCH_PROGRESS), DRIVE_CMD every 10 ms.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from rig.data import capture
from rig.link.bench_commands import BenchCommands, LoadSetting
from rig.link.clock import GrantClock, PlantProgress, WallClock
from rig.link.drive_master import DriveMaster
from rig.run.errors import RunError
from rig.run.execution import Execution
from rig.run.plan import Plan
from rig.run.progress import Display

TS = capture.TS
REALTIME_SLICE_S = 0.002  # real time: how often the rig looks at the plan


@dataclass(frozen=True)
class PacedBench:
    """A bench as pacing drives it (``rig.run.in_process.sil_bench``,
    ``rig.run.on_bus.virtual_bench``): its clock, the drive master and the bench commands on
    its link, where the run is for the progress line (simulated seconds, speed in r/min,
    position error in degrees; None where the bench does not tell) and what else happens
    when the line is drawn, and in real time the plant's reported progress and how long it
    may stall."""

    clock: GrantClock | WallClock
    drive: DriveMaster
    commands: BenchCommands
    where: Callable[[], tuple[float, float | None, float | None]]
    on_show: Callable[[], None] = lambda: None
    progress: PlantProgress | None = None
    stall_s: float = 0.0


def pace(plan: Plan, bench: PacedBench, run: Execution, line: Display) -> int:
    """The plan through ``bench``: by grants when its clock grants, else on the wall clock;
    returns the periods simulated (lockstep) or the last period commanded (real time). The
    progress line is drawn while the bench is idle and after each grant."""

    def show() -> None:
        line.at(*bench.where())
        bench.on_show()

    bench.clock.on_idle(show)
    if isinstance(bench.clock, GrantClock):
        return lockstep(plan, bench.clock, bench.drive, bench.commands, run,
                        lambda _until: show())
    assert bench.progress is not None
    return realtime(plan, bench.clock, bench.drive, bench.commands, bench.progress,
                    bench.stall_s, run)


def lockstep(plan: Plan, clock: GrantClock, drive: DriveMaster,
             bench: BenchCommands, run: Execution, after_grant: Callable[[int], None]) -> int:
    """Runs every grant of the plan; returns the number of periods simulated."""
    drive.cmd, limits = plan.initial_cmd, plan.initial_limits
    load = LoadSetting()

    def grant_frames() -> None:
        drive.send_limits(limits)
        drive.send_command()
        bench.load(load)
        for values in plan.fault_cmds.get(clock.period, []):
            bench.fault(values)

    clock.on_cycle(grant_frames)
    for start, until in plan.grants():
        for change in plan.drive_events.get(start, []):
            drive.cmd, limits = change.apply(drive.cmd, limits)
        load = plan.load_events.get(start, load)
        t_grant = time.monotonic()
        clock.grant(until)
        run.grants.append((until, run.wall(), time.monotonic() - t_grant))
        run.start_preload()  # the loop runs: now the post-processing's imports
        after_grant(until)
    return plan.n_periods


def realtime(plan: Plan, clock: WallClock, drive: DriveMaster,
             bench: BenchCommands, progress: PlantProgress, stall_s: float,
             run: Execution | None = None) -> int:
    """Sends the plan's commands on the wall clock; returns the last period commanded."""
    drive.cmd, limits = plan.initial_cmd, plan.initial_limits
    load = LoadSetting()
    events = sorted(set(plan.drive_events) | set(plan.load_events) | set(plan.fault_cmds))
    t_origin = time.monotonic()

    def period_now() -> float:
        if progress.period is not None:
            return progress.period + (time.monotonic() - progress.wall) / TS
        return (time.monotonic() - t_origin) / TS

    drive.send_limits(limits)
    drive.send_command()
    bench.load(load)
    clock.on_cycle(drive.send_command)
    if run is not None:
        run.start_preload()
    last_period, last_change = progress.period, time.monotonic()
    i = 0
    # the plant's own report ends the run (an estimate could run ahead of a lagging plant)
    while (progress.period or 0) < plan.n_periods:
        now_p = period_now()
        clock.link.at(int(now_p))
        changed_drive = changed_load = False
        fault_now: list[dict[str, float | int]] = []
        while i < len(events) and events[i] <= now_p:
            p = events[i]
            for change in plan.drive_events.get(p, []):
                drive.cmd, limits = change.apply(drive.cmd, limits)
                changed_drive = True
            if p in plan.load_events:
                load = plan.load_events[p]
                changed_load = True
            fault_now += plan.fault_cmds.get(p, [])
            i += 1
        for values in fault_now:
            bench.fault(values)
        if changed_drive:
            drive.send_limits(limits)
            drive.send_command()
        if changed_load:
            bench.load(load)
        clock.advance(REALTIME_SLICE_S)
        if progress.period != last_period:
            last_period, last_change = progress.period, time.monotonic()
        elif time.monotonic() - last_change > stall_s:
            raise RunError("stall", f"real-time plant stopped reporting progress at period "
                           f"{progress.period} for {stall_s:g} s")
    return plan.n_periods
