"""A scenario run on the bus: plant_rt and fw_host started on a channel nobody else sends on
(nodes that only listen are welcome, and counted), the plan paced in lockstep or real time,
the programs stopped, what the rig and the bus counted. A frame from outside the run that
the rig sees (one only the rig sends, a BENCH_PROGRESS the plant cannot have sent) stops the
run as foreign traffic at once; the counts catch the rest afterwards (``rig.run.traffic``)."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import can

from rig import bus as rigbus
from rig.bench import virtual
from rig.bench.configuration import BenchConfiguration
from rig.bus import can_log
from rig.bus.can_log import LiveCapture
from rig.link.bench_commands import BenchCommands
from rig.link.bus import BusLink, ForeignNodes, ForeignTraffic, LinkError
from rig.link.clock import GrantClock, LockstepClock, PlantProgress, WallClock
from rig.link.drive_master import DriveMaster
from rig.link.frame_faults import FrameFaults
from rig.results.result import RunResult
from rig.run import traffic
from rig.run.bus_report import BusNodes
from rig.run.errors import EnvironmentProblem, RunError
from rig.run.execution import TS, Execution
from rig.run.monitor import Monitor
from rig.run.options import RunOptions
from rig.run.pacing import PacedBench
from rig.run.plan import Plan
from rig.run.versions import versions
from rig.scenario import Scenario

if TYPE_CHECKING:  # the live view (rerun) is imported only for --live
    from rig.run.live import LiveFeed

OWN = "run"  # a run's own unixcan channel: run-<pid> (rig.bus.own_channel)
# the bus reader thread (unixcan) must get the GIL within a sender's patience (2 ms)
SWITCH_INTERVAL_S = 0.0005
LOCKSTEP_DRAIN_S = 0.05  # the firmware finishes the last period before the stop signal


_said: set[str] = set()  # the channels chosen for the runs of this process, said once


@contextmanager
def virtual_bench(sc: Scenario, plan: Plan, config: BenchConfiguration, opts: RunOptions,
                  result: RunResult, run: Execution) -> Iterator[PacedBench]:
    """The virtual bench configured as ``config`` on the bus, its programs started and ready
    to be paced through the plan (in lockstep or real time); they are stopped, and what the
    rig and the bus counted goes into ``run``, when it closes. A run that names no channel
    gets one of its own on unixcan (``rig.bus.own_channel``); the channel is held for the run
    (a second run of the rig on it is refused at once: exit 3)."""
    try:
        transport, channel = rigbus.select_transport(opts.bus, opts.channel, own=OWN)
        claim = rigbus.claim_channel(transport, channel)
    except rigbus.ChannelInUse as exc:
        raise EnvironmentProblem(str(exc)) from exc
    except OSError as exc:
        raise EnvironmentProblem(f"cannot hold the run's channel: {exc}") from exc
    if opts.progress and rigbus.is_own_channel(channel) and channel not in _said:
        _said.add(channel)
        print(f"rig run: {transport} channel {channel}, the run's own (--channel NAME or "
              "HIL_CHANNEL to name one)", file=sys.stderr)
    try:
        with _on_channel(sc, plan, config, opts, result, run, transport, channel) as paced:
            yield paced
    finally:
        claim.release()
        rigbus.release_own_channel(channel)


@contextmanager
def _on_channel(sc: Scenario, plan: Plan, config: BenchConfiguration, opts: RunOptions,
                result: RunResult, run: Execution, transport: str, channel: str
                ) -> Iterator[PacedBench]:
    try:
        # traces always, paired from period 0 in lockstep (the plant's first ADC frame is its
        # start-up period 0, so stray frames on the channel cannot become the firmware's
        # first period)
        programs = virtual.BenchPrograms(
            config, lockstep=not opts.realtime, trace=True, trace_vio=opts.trace_bus,
            paired_from_start=not opts.realtime, extra_plant_args=tuple(opts.extra_plant_args),
            extra_fw_args=tuple(opts.extra_fw_args))
        argv = programs.argv(transport, channel, result.out_dir)
    except FileNotFoundError as exc:
        raise EnvironmentProblem(str(exc)) from exc
    result.bus, result.channel = transport, channel
    result.versions = versions(argv[virtual.PLANT][0], argv[virtual.FIRMWARE][0])
    result.command_lines = {"plant": argv[virtual.PLANT], "firmware": argv[virtual.FIRMWARE]}
    try:
        # in lockstep the rig's node loses no frame, as the programs' do (unixcan)
        link = BusLink.open(transport, channel,
                            frame_faults=FrameFaults(plan.link_windows),
                            trace=result.out_dir / "rig.trace" if opts.trace_bus else None,
                            lossless=not opts.realtime)
    except LinkError as exc:
        raise EnvironmentProblem(str(exc)) from exc
    run.where = f"{transport} channel {channel!r}"
    try:
        link.check_channel()
    except ForeignTraffic as exc:
        link.close()
        raise RunError(traffic.KIND, f"foreign traffic: {exc}") from exc
    except ForeignNodes as exc:
        link.close()
        raise EnvironmentProblem(str(exc)) from exc
    except (RuntimeError, FileNotFoundError, OSError) as exc:  # hilbus_tool: not built
        link.close()
        raise EnvironmentProblem(str(exc)) from exc
    if link.listeners_at_start is not None:
        run.counters["rig.listeners.start"] = float(link.listeners_at_start)
        run.bus_nodes = BusNodes(start=dict(link.others_at_start), lossless=not opts.realtime,
                                 own_pids={os.getpid(): "rig"})
    live_log: LiveCapture | None = None
    if opts.can_log is not None:
        try:
            live_log = LiveCapture(transport, channel,
                                   result.out_dir / f"bus{can_log.FORMATS[opts.can_log]}",
                                   lossless=not opts.realtime)
        except (can.CanError, OSError) as exc:
            link.close()
            raise EnvironmentProblem(f"--can-log: cannot open a node on {run.where}: "
                                     f"{exc}") from exc
        if run.bus_nodes is not None:
            run.bus_nodes.can_log_node = Path(live_log.socket_path).name
    run.progress = PlantProgress(link, grants_from_start=not opts.realtime)
    run.monitor = Monitor(link)

    def foreign(what: str) -> None:
        period = run.progress.period if run.progress is not None else None
        raise RunError(traffic.KIND, f"foreign traffic on {run.where} at period {period}: "
                       f"{what}. Another node sends on this channel: the run's data is not "
                       "its own and nothing is judged. Use a channel of its own "
                       "(--channel NAME)")

    link.on_foreign = foreign
    live = _live_view(sc, opts, link, run.monitor, run.progress) if opts.live else None
    switch = sys.getswitchinterval()
    sys.setswitchinterval(min(switch, SWITCH_INTERVAL_S))
    try:
        with _programs_running(sc, opts, programs, link, run, live) as paced:
            yield paced
    finally:
        sys.setswitchinterval(switch)
        link.on_foreign = None  # (the frames of the stop are counted, not raised)
        if transport == "unixcan":
            from rig.bus import unixcan

            own = {str(getattr(link.bus, "socket_path", ""))}
            if live_log is not None:
                own.add(live_log.socket_path)
            others = unixcan.live_nodes(channel, own)
            run.counters["rig.listeners.end"] = float(len(others))
            if run.bus_nodes is not None:
                run.bus_nodes.end = {Path(p).name: unixcan.node_label(p) for p in others}
                run.bus_nodes.add_drops("rig.bus", getattr(link.bus, "listener_drops", {}))
        link.close()
        if live_log is not None:
            run.can_log = live_log.stop()
        stats = getattr(link.bus, "stats", None)
        if isinstance(stats, Mapping):
            run.add_counters("rig.bus", stats)
            run.add_counters("rig.bus", getattr(link.bus, "stall_ms", {}))
        run.rig_tx_ids = dict(link.tx_ids)
        # unixcan: every frame that reached the socket, the filtered ones too
        run.rig_rx_ids = dict(getattr(link.bus, "rx_ids", None) or link.rx_ids)
        if live is not None:
            with contextlib.suppress(Exception):
                live.close()


def _live_view(sc: Scenario, opts: RunOptions, link: BusLink, monitor: Monitor,
               progress: PlantProgress) -> LiveFeed | None:
    from rig.run import live

    view = live.open_view(sc, opts)
    return None if view is None else live.LiveFeed(view, link, monitor, lambda: progress.period)


@contextmanager
def _programs_running(sc: Scenario, opts: RunOptions, programs: virtual.BenchPrograms,
                      link: BusLink, run: Execution, live: LiveFeed | None
                      ) -> Iterator[PacedBench]:
    monitor, progress = run.monitor, run.progress
    assert monitor is not None and progress is not None
    timeout = opts.timeout_s or sc.timeout_s or (
        sc.duration + 30.0 if opts.realtime else 60.0 + 300.0 * sc.duration)
    virtual_bench = virtual.VirtualBench(programs, opts.out, grace_s=opts.grace_s)
    with virtual_bench.sup:
        run.start_preload()  # while the programs start (the rig waits for them)
        virtual_bench.start(link.transport, link.channel, ready_timeout_s=sc.ready_timeout_s,
                            env=opts.env)
        if run.bus_nodes is not None:
            run.bus_nodes.own_pids.update(
                {c.pid: name for name, c in virtual_bench.sup.children.items()})
        run.t0 = time.monotonic()
        deadline = run.t0 + timeout
        drive, bench_cmds = DriveMaster(link), BenchCommands(link)
        clock: LockstepClock | WallClock
        if opts.realtime:
            clock = WallClock(link)
        else:
            clock = LockstepClock(link, grant_s=sc.grant_max_s, stall_s=opts.stall_s,
                                  progress=progress)

        def where() -> tuple[float, float | None, float | None]:
            return ((progress.period or 0) * TS, *monitor.snapshot())

        def check_deadline() -> None:
            if time.monotonic() <= deadline:
                return
            if isinstance(clock, GrantClock):
                raise RunError("timeout", f"run time-out at period {progress.period} "
                               f"(grant to {clock.granted})")
            raise RunError("timeout", "real-time run time-out")

        for hook in (virtual_bench.check, check_deadline):
            clock.on_idle(hook)
        grace = opts.grace_s
        try:
            yield PacedBench(clock, drive, bench_cmds, where,
                             live.flush if live is not None else lambda: None, progress,
                             opts.stall_s)
            if isinstance(clock, LockstepClock):
                virtual_bench.sup.sleep(LOCKSTEP_DRAIN_S)
        except BaseException:
            grace = min(grace, 1.0)  # failing: end quickly
            raise
        finally:
            run.stops = virtual_bench.stop(grace_s=grace)
            if isinstance(clock, LockstepClock):
                run.grant_resends = clock.resends
        run.counters["rig.tx_frames"] = float(link.tx)
        run.counters.update(link.faults.counters())
