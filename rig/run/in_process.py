"""A scenario run on the in-process bench (``--bus inproc``, ``rig.sil``): no programs and
no bus; the plant_rt/fw_host configuration handed to the bench, the same frames before each
of the same lockstep grants, the programs' counters from the bench."""

from __future__ import annotations

import sys
import time

from rig import _paths, drive_link, profiles, sil
from rig.link.bus import BusLink
from rig.link.clock import InprocClock
from rig.link.drive import DriveMaster
from rig.progress import Progress
from rig.run import pacing
from rig.run.bench_commands import BenchCommands
from rig.run.errors import EnvironmentProblem, RunError
from rig.run.execution import TS, Execution
from rig.run.options import RunOptions
from rig.run.plan import Plan
from rig.run.programs import firmware_sets, plant_sets, sha, versions
from rig.run.result import RunResult
from rig.scenario import Scenario


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


def run_in_process(sc: Scenario, plan: Plan, opts: RunOptions, result: RunResult,
                   run: Execution) -> None:
    """Runs the scenario on the in-process bench, filling ``run``."""
    out = result.out_dir
    if opts.realtime:
        raise RunError("usage", "--realtime needs the bus: the in-process bench runs in "
                       "lockstep only")
    try:
        lib = _paths.library(sil.LIBRARY)
        profile_path = profiles.profile_file(sc.profile)
        values = profiles.profile_values(sc.profile, sc.overrides)
    except FileNotFoundError as exc:
        raise EnvironmentProblem(str(exc)) from exc
    psets, fsets = plant_sets(sc), firmware_sets(sc, values)
    result.bus, result.channel = sil.INPROC, None
    result.versions = {**versions(), "silbench.sha256": sha(lib)}
    result.command_lines = {"bench": {
        "library": str(lib), "profile": str(profile_path) if profile_path else sc.profile,
        "plant_sets": psets, "fw_sets": fsets}}
    if profile_path is None:
        raise EnvironmentProblem(f"profile {sc.profile!r} not found")
    if opts.live:
        print("rig: no live view on the in-process bench (no telemetry frames); running "
              "without it", file=sys.stderr)
    prog = Progress(sc.name, sc.duration, enabled=opts.progress)
    timeout = opts.timeout_s or sc.timeout_s or 60.0 + 300.0 * sc.duration
    try:
        bench = sil.SilBench(profile_path, psets, fsets, out / "plant.trace", out / "fw.trace",
                             trace_vio=opts.trace_bus)
    except sil.BenchError as exc:
        raise RunError("config", f"in-process bench: {exc}") from exc
    if opts.core_journal is not None:
        try:
            bench.journal(opts.core_journal, opts.core_journal_windows)
        except sil.BenchError as exc:
            bench.close()
            raise RunError("config", f"in-process bench: {exc}") from exc
    port = sil.BenchPort(bench)
    link = BusLink(port, frame_faults=drive_link.DriveLink(plan.link_windows),
                   trace=out / "rig.trace" if opts.trace_bus else None)
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
            run.periods_done = pacing.lockstep(
                sc, plan, clock, DriveMaster(link), BenchCommands(link), run,
                lambda until: prog.update(until * TS, None, None))
            run.cpu_s = time.process_time() - cpu0
        finally:
            prog.finish()
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
