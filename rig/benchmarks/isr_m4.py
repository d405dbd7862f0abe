"""``rig bench isr --target cortex-m4f`` (or ``cortex-m3``): instructions per fw_core_isr()
call on the emulated Cortex-M4F (or the soft-float Cortex-M3), by path and by ISR step,
beside the host's callgrind figure.

Each case of ``rig.target_m4.scenarios`` runs in process with the core journalled (its start
through polarity detection and its windows, each ``scale`` times as long; or the whole run),
and the journal is replayed on the image with every executed instruction counted (the C
library's floorf and sqrtf included; the mailbox shim adds about ten). Paths: ``run_10khz``
(RUN, the 10 kHz work), ``run_1khz`` (RUN, the ISRs that also run the 1 kHz tasks),
``startup_polarity`` (the start-up test), ``idle``, ``fault``, ``init``. Per path also the
median and the largest of each step of fw_core_isr (``take_period`` ... ``voltage_mean``,
``entry`` its own code around them; a callee counts for the step that called it) and the
steps of the path's worst ISR. The 1 kHz tasks run in the ISRs whose count (``isr_count``
after its increment) is a multiple of the speed loop's divider: every tenth period, all of
them in that one (``slow_tasks``)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from rig import protocols
from rig.target_m4 import emulator, run, scenarios


def measure(scale: float, full: bool, callgrind: dict[str, Any] | None,
            target: str = emulator.DEFAULT_TARGET) -> dict[str, Any]:
    comps = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in scenarios.CASES:
            comps.append(run.compare_case(case, Path(tmp) / case.scenario, full=full,
                                          scale=scale, count=True, target=target))
    b = run.budget(comps)
    worst_10k = b["paths"].get("run_10khz", {}).get("max", 0)
    divider = protocols.timebase().speed_loop_divider
    report: dict[str, Any] = {
        "benchmark": "isr", "target": target, "what": emulator.TARGETS[target].what,
        "image": str(emulator.image_path(target)), "scale": scale,
        "unit": "instructions per fw_core_isr() call",
        "steps": b["steps"],
        "slow_tasks": {"divider": divider, "periods": f"isr_count % {divider} == 0: the "
                       "outer tasks (speed loop, references, parameter choice) all in one "
                       "period of every ten", "step": "outputs"},
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
