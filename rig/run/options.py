"""How a scenario runs: where it writes, on which bus, paced how, and what it keeps."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.link.clock import STALL_S


@dataclass
class RunOptions:
    out: Path
    bus: str | None = None  # a transport, auto, or inproc (the in-process bench)
    channel: str | None = None
    realtime: bool = False
    live: bool = False
    live_stream: Any = None  # an rr.RecordingStream to use instead of spawning a viewer
    live_url: str | None = None  # stream the live view to this gRPC server (the web viewer)
    progress: bool = True
    timeout_s: float | None = None
    grace_s: float = 5.0
    stall_s: float = STALL_S
    record: bool = True
    # figure.png and a picture per criterion that did not pass (rig.results.figures)
    figures: bool = True
    # ... only for a run that did not pass (the gate: a passing run's pictures cost 0.2-0.3 s
    # of CPU each, a third of the gate's time, and nobody looks at them)
    figures_failing_only: bool = False
    # every frame of the run into the traces (the plant's VIO frames, rig.trace: the rig's
    # own), so rig export --can-log holds the whole bus
    trace_bus: bool = True
    # on a bus: a live log of every frame on the channel, by a node of the rig's own, into
    # bus.<FORMAT> in the run's folder (rig.bus.can_log: asc, blf or log)
    can_log: str | None = None
    # what a run keeps besides result.json, report.md and recording.rrd: "all" keeps the
    # full-rate traces (*.trace) and capture columns (capture/) of every run, "failing" only
    # of runs that did not pass (rig run's default; the API's is "all": callers read captures),
    # "none" of no run (the confirmation's fresh seeds: their values are all it needs, and a
    # mutation campaign's kills kept 8 seeds' traces each, 5 GB a mutant)
    keep: str = "all"
    extra_plant_args: Sequence[str] = ()
    extra_fw_args: Sequence[str] = ()
    env: Mapping[str, str] = field(default_factory=dict)
    # compare with the committed baselines (rig.regression.baseline): "off" (the API's
    # default), "auto" (rig run's: where a baseline exists), "require" (a run without one
    # fails)
    baseline: str = "off"
    # a value beyond its band is a flag; confirm flags at fresh seeds before they fail the
    # run (rig.regression.confirm); False: every flag fails at once
    confirm: bool = True
    # suites in process: scenarios run on this many worker processes at once
    jobs: int = 1
    # suites in process: their scenarios on the Dask cluster whose scheduler is at this
    # address instead (rig.run.cluster), which ends them when it has had no worker this long
    cluster: str | None = None
    no_worker_timeout_s: float = 60.0
    # suites: no scenario starts after one did not pass (the others' verdicts are not needed)
    fail_fast: bool = False
    # in process only: journal every call into the control core to this file (rig.target_m4
    # replays it on the Cortex-M4F build), in these ISR index windows (start, length; none:
    # the whole run)
    core_journal: Path | None = None
    core_journal_windows: Sequence[tuple[int, int]] = ()
