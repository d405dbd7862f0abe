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
    figures: bool = True  # figure.png and a picture per criterion that did not pass (rig.figures)
    # every frame of the run into the traces (the plant's VIO frames, rig.trace: the rig's
    # own), so rig export --can-log holds the whole bus
    trace_bus: bool = True
    # what a run keeps besides result.json, report.md and recording.rrd: "all" keeps the
    # full-rate traces (*.trace) and capture columns (capture/) of every run, "failing" only
    # of runs that did not pass (rig run's default; the API's is "all": callers read captures)
    keep: str = "all"
    extra_plant_args: Sequence[str] = ()
    extra_fw_args: Sequence[str] = ()
    env: Mapping[str, str] = field(default_factory=dict)
