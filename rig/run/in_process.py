"""A scenario run on the in-process bench (``--bus inproc``, ``rig.bench.sil``): no programs
and no bus; the plant_rt/fw_host configuration handed to the bench, the same frames before each
of the same lockstep grants, the programs' counters from the bench."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from rig import _paths, protocols
from rig.bench import sil
from rig.bench.configuration import BenchConfiguration
from rig.link.bench_commands import BenchCommands
from rig.link.bus import BusLink
from rig.link.clock import InprocClock
from rig.link.drive_master import DriveMaster
from rig.link.frame_faults import FrameFaults
from rig.results.result import RunResult
from rig.run.errors import EnvironmentProblem, RunError
from rig.run.execution import TS, Execution
from rig.run.options import RunOptions
from rig.run.pacing import PacedBench
from rig.run.plan import Plan
from rig.run.versions import sha, versions
from rig.scenario import Scenario

if TYPE_CHECKING:  # the live view (rerun) is imported only for --live
    from rig.run.live import LiveFeed


# BENCH_TRUTH for a live view at the telemetry's rate (TLM_* every speed-loop period), as
# plant_rt sends it on the bus unless told otherwise
LIVE_TRUTH_EVERY = protocols.timebase().speed_loop_divider
LIVE_TLM_DIV = 1


class _GrantsTraced:
    """The bench as the in-process clock sees it, each grant also written into the rig's
    trace as the BENCH_STEP frame it is on the bus (sequence numbers as LockstepClock's)."""

    def __init__(self, bench: sil.SilBench, link: BusLink) -> None:
        self.bench, self.link = bench, link
        self.seq = 0

    def run_until(self, run_until: int) -> int:
        self.seq = (self.seq + 1) % 256
        self.link.note("BENCH_STEP", {"run_until": run_until, "seq": self.seq})
        return self.bench.run_until(run_until)


def cost_journal(sc: Scenario, out: Path) -> tuple[Path, list[tuple[int, int]]] | None:
    """Where and over which ISRs the core is journalled for the scenario's criteria of the
    ISR's cost on the target (rig.target_m4.cost): their windows; None without such."""
    from rig.data import metrics
    from rig.target_m4 import cost

    spans = [cr.window for cr in sc.criteria if metrics.needs_target(cr.metric)]
    if not spans:
        return None
    return out / cost.JOURNAL_NAME, cost.journal_windows(spans, sc.duration)


class _LiveInProcess:
    """The live view of an in-process run: the bench's outbox (the frames fw_host and
    plant_rt send the rig on the bus) read by a link of its own after each grant."""

    def __init__(self, feed: LiveFeed, link: BusLink) -> None:
        self.feed, self.link = feed, link

    def show(self) -> None:
        self.link.pump()
        self.feed.flush()

    def close(self) -> None:
        try:
            self.show()
        finally:
            self.feed.close()


def _live_feed(sc: Scenario, opts: RunOptions, bench: sil.SilBench) -> _LiveInProcess | None:
    from rig.run import live
    from rig.run.monitor import Monitor

    view = live.open_view(sc, opts)
    if view is None:
        return None
    bench.outbox(LIVE_TLM_DIV, LIVE_TRUTH_EVERY)
    link = BusLink(sil.OutboxPort(bench))
    feed = live.LiveFeed(view, link, Monitor(link), lambda: bench.next_period)
    return _LiveInProcess(feed, link)


@contextmanager
def sil_bench(sc: Scenario, plan: Plan, config: BenchConfiguration, opts: RunOptions,
              result: RunResult, run: Execution) -> Iterator[PacedBench]:
    """The in-process bench configured as ``config``, ready to be paced through the plan;
    what it counted goes into ``run`` when it closes."""
    out = result.out_dir
    if opts.realtime:
        raise RunError("usage", "--realtime needs the bus: the in-process bench runs in "
                       "lockstep only")
    try:
        lib = _paths.library(sil.LIBRARY)
    except FileNotFoundError as exc:
        raise EnvironmentProblem(str(exc)) from exc
    result.bus, result.channel = sil.INPROC, None
    result.versions = {**versions(), "silbench.sha256": sha(lib)}
    result.command_lines = {"bench": {
        "library": str(lib),
        "profile": str(config.profile_file) if config.profile_file else config.profile,
        "plant_sets": list(config.plant_sets), "fw_sets": list(config.fw_sets)}}
    if config.profile_file is None:
        raise EnvironmentProblem(f"profile {config.profile!r} not found")
    timeout = opts.timeout_s or sc.timeout_s or 60.0 + 300.0 * sc.duration
    try:
        bench = sil.SilBench(config.profile_file, config.plant_sets, config.fw_sets,
                             out / "plant.trace", out / "fw.trace", trace_vio=opts.trace_bus)
    except sil.BenchError as exc:
        raise RunError("config", f"in-process bench: {exc}") from exc
    journal = (opts.core_journal, list(opts.core_journal_windows)) \
        if opts.core_journal is not None else cost_journal(sc, out)
    if journal is not None:
        try:
            bench.journal(*journal)
        except sil.BenchError as exc:
            bench.close()
            raise RunError("config", f"in-process bench: {exc}") from exc
    port = sil.BenchPort(bench)
    link = BusLink(port, frame_faults=FrameFaults(plan.link_windows),
                   trace=out / "rig.trace" if opts.trace_bus else None)
    live = _live_feed(sc, opts, bench) if opts.live else None
    try:
        run.t0 = time.monotonic()
        deadline = run.t0 + timeout
        clock = InprocClock(link, _GrantsTraced(bench, link), grant_s=sc.grant_max_s)

        def check_deadline() -> None:
            if time.monotonic() > deadline:
                raise RunError("timeout", f"run time-out at period {clock.granted}")

        clock.on_idle(check_deadline)
        cpu0 = time.process_time()
        try:
            yield PacedBench(clock, DriveMaster(link), BenchCommands(link),
                             lambda: (clock.granted * TS, None, None),
                             live.show if live is not None else lambda: None)
            run.cpu_s = time.process_time() - cpu0
        finally:
            if live is not None:
                run.counters["rig.live_frames_dropped"] = float(bench.outbox_dropped)
                live.close()
            bench_counters = bench.counters()
            for name in ("plant", "firmware"):
                run.add_counters(name, bench_counters.get(name, {}))
            run.counters["rig.tx_frames"] = float(link.tx)
            run.counters.update(link.faults.counters())
            run.counters["rig.bench_rejected"] = float(len(bench.rejected))
            run.counters["rig.bench_refused_faulted"] = float(len(port.refused_faulted))
    finally:
        link.close()  # (its trace)
        try:
            bench.close()
        except sil.BenchError as exc:
            raise RunError("capture", f"in-process bench: {exc}") from exc
    if bench.rejected:
        raise RunError("rejected", "the bench rejected frames of the rig: "
                       + "; ".join(bench.rejected[:3]))
