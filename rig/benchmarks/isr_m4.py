"""``rig bench isr --target cortex-m4f``: instructions per fw_core_isr() call on the emulated
Cortex-M4F, by path, beside the host's callgrind figure.

Each case of ``rig.target_m4.scenarios`` runs in process with the core journalled (its start
through polarity detection and its windows, each ``scale`` times as long; or the whole run),
and the journal is replayed on the image with every executed instruction counted (the C
library's floorf and sqrtf included; the mailbox shim adds about ten). Paths: ``run_10khz``
(RUN, the 10 kHz work), ``run_1khz`` (RUN, the ISRs that also run the 1 kHz tasks),
``startup_polarity`` (the start-up test), ``idle``, ``fault``, ``init``."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from rig.target_m4 import emulator, run, scenarios


def measure(scale: float, full: bool, callgrind: dict[str, Any] | None) -> dict[str, Any]:
    comps = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in scenarios.CASES:
            comps.append(run.compare_case(case, Path(tmp) / case.scenario, full=full,
                                          scale=scale, count=True))
    b = run.budget(comps)
    worst_10k = b["paths"].get("run_10khz", {}).get("max", 0)
    report: dict[str, Any] = {
        "benchmark": "isr", "target": "cortex-m4f", "image": str(emulator.image_path()),
        "unit": "instructions per fw_core_isr() call",
        "cases": [c.scenario for c in scenarios.CASES], "whole_runs": full,
        "same_outputs_as_host": all(c.identical for c in comps),
        "periods": sum(c.periods for c in comps),
        "paths": b["paths"],
        "goal_run_10khz_max": run.GOAL_10KHZ,
        "within_goal": worst_10k <= run.GOAL_10KHZ,
        "per_scenario": b["per_scenario"],
    }
    if callgrind is not None:
        report["x86_64_callgrind_1000rpm"] = callgrind
    return report
