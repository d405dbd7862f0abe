"""A run's ``recording.rrd`` (``rig.results.recording``): the display series of the capture, the
grants' timing, the bench counters as the bus carried them, and at full rate what every
criterion read."""

from __future__ import annotations

import math
from typing import Any

from rig.data import capture
from rig.outputs import dir_size
from rig.results import report
from rig.results.result import RunResult
from rig.run.execution import TS, Execution


def write_recording(result: RunResult, cap: capture.Capture, run: Execution,
                    reads: list[tuple[str, int, int]]) -> dict[str, Any]:
    """Writes the recording; what result.json says of it (the error when it failed: the
    verdict stands without the recording)."""
    from rig.results import recording  # rerun: imported when a recording is written, not at start

    rrd = result.out_dir / "recording.rrd"
    try:
        counter_log = run.monitor.counter_log if run.monitor is not None else []
        counter_samples = None
        if counter_log:
            keys = sorted({k for _, v in counter_log for k in v if k != "period"})
            counter_samples = recording.TimedSamples(
                [p for p, _ in counter_log],
                {k: [v.get(k, math.nan) for _, v in counter_log] for k in keys})
        info = recording.write(
            rrd, cap, title=f"{result.scenario} ({result.mode}, {result.bus})",
            report_markdown=report.scenario_report(result.to_json()),
            timing=run.grant_samples(), counters=counter_samples,
            evidence=recording.evidence_ranges(reads),
        )
        size = rrd.stat().st_size
        return {
            "path": rrd.name, "bytes": size,
            "bytes_per_sim_s": size / (cap.n * TS) if cap.n else None,
            "display_step": info["display_step"],
            "evidence_rows": info["evidence_rows"], "evidence": info["evidence"],
            "capture_bytes": dir_size(result.out_dir / "capture"),
        }
    except Exception as exc:  # the verdict stands without the recording
        return {"path": None, "error": f"{type(exc).__name__}: {exc}"}
