"""Does the gate's sample of ISR cost windows cover the ISR? (``rig bench isr --coverage``)

The gate judges the ISR's cost on the windows of its scenarios' ``isr_instructions_*``
criteria, not on every period of every scenario (the emulator counts about a thousand
periods per second of CPU; the gate's runs hold seven million). This measures what that
sample leaves out: every scenario of a suite (the gate's by default) is run in process at
seed 1 with the core journalled over its *event windows* — its start (0 … 0.15 s) and 60 ms
from 10 ms before each moment its inputs change (a speed segment's start, a load event, a
fault, the enable) and its last 50 ms — and the journals are replayed on the image with
every basic block of ``fw_core_isr``'s call tree recorded (only inside ISR calls: not the
initialisation, commands or parameters). The same is done for the sample's windows. The
result: the blocks (and their instructions) the sample executes of those the event windows
execute, and the ones it misses, by function.
"""

from __future__ import annotations

import bisect
import dataclasses
import tempfile
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from unicorn import UC_HOOK_BLOCK, Uc

from rig import scenario
from rig.data import metrics
from rig.scenario import Scenario
from rig.target_m4 import cost, emulator, record, replay
from rig.target_m4.journal import Journal

ISR_CALLS = ("m4_isr", "m4_isr_no_data")
EVENT_BEFORE_S, EVENT_AFTER_S = 0.01, 0.05
START_S, END_S = 0.15, 0.05


class _CoverageCore(emulator.M4Core):
    """An emulated core that records the basic blocks its ISR calls execute."""

    def __init__(self) -> None:
        super().__init__()
        self.blocks: dict[int, int] = {}  # address -> instructions
        self._active = False
        self.uc.hook_add(UC_HOOK_BLOCK, self._seen)

    def _seen(self, uc: Uc, address: int, size: int, _user: object) -> None:
        if self._active and address not in self.blocks:
            self.blocks[address] = emulator.thumb_instructions(bytes(uc.mem_read(address,
                                                                                 size)))

    def call(self, function: str) -> None:
        self._active = function in ISR_CALLS
        try:
            super().call(function)
        finally:
            self._active = False


def event_windows(sc: Scenario) -> list[tuple[float, float]]:
    """(t0, t1) s: the start, around each change of the scenario's inputs, the end."""
    moments = [sc.enable_at] + [e.at for e in sc.load] + [f.at for f in sc.faults]
    t = 0.0
    for seg in sc.speed:
        moments.append(t)
        t += seg.duration
    spans = [(0.0, START_S), (max(0.0, sc.duration - END_S), sc.duration)]
    spans += [(max(0.0, m - EVENT_BEFORE_S), min(sc.duration, m + EVENT_AFTER_S))
              for m in moments if m < sc.duration]
    return spans


def sample_windows(sc: Scenario) -> list[tuple[float, float]]:
    """The windows the gate measures the ISR's cost on (its criteria's)."""
    return [cr.window for cr in sc.criteria if metrics.needs_target(cr.metric)]


def _blocks(job: tuple[Scenario, list[tuple[float, float]], str]) -> dict[int, int]:
    """One scenario run journalled over ``windows`` and replayed with blocks recorded."""
    sc, windows, tmp = job
    sc = dataclasses.replace(sc, seeds=())  # one run (at seed 1), not one per own seed
    out = Path(tmp) / f"{sc.name}@{sc.profile}"
    wins = cost.journal_windows(windows, sc.duration)[:16]  # (CORE_JOURNAL_WINDOWS_MAX)
    record.record_scenario(sc, out, wins)
    core = _CoverageCore()
    comp = replay.replay(Journal(out / "core.journal"), core, sc.name)
    (out / "core.journal").unlink(missing_ok=True)
    if not comp.identical:
        raise RuntimeError(f"{sc.name}: the image's outputs differ from the host's")
    return core.blocks


def _functions() -> tuple[list[int], list[tuple[int, int, str]]]:
    m = emulator.M4Core()
    funcs = sorted((s.value & ~1, s.size, n) for n, s in m.sym.items()
                   if s.size > 0 and s.value < emulator.FLASH[1] and not n.startswith("m4_"))
    return [f[0] for f in funcs], funcs


def _by_function(blocks: Iterable[int], starts: list[int],
                 funcs: list[tuple[int, int, str]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for a in blocks:
        i = bisect.bisect_right(starts, a) - 1
        name = funcs[i][2] if i >= 0 and a < funcs[i][0] + funcs[i][1] else f"{a:#x}"
        out[name] = out.get(name, 0) + 1
    return out


def measure(suite: str = "gate", jobs: int = 2) -> dict[str, Any]:
    """The sample's block coverage of the event windows of ``suite``'s scenario runs."""
    s = scenario.load(suite)
    runs: Sequence[Scenario] = s.scenarios if isinstance(s, scenario.Suite) else (s,)
    with tempfile.TemporaryDirectory(prefix="rig-isr-coverage-") as tmp:
        jobs_ref, jobs_sample = [], []
        for sc in runs:
            jobs_ref.append((sc, event_windows(sc), tmp))
            mine = sample_windows(sc)
            if mine:
                jobs_sample.append((sc, mine, tmp + "/sample"))
        Path(tmp, "sample").mkdir()
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            ref_parts = list(pool.map(_blocks, jobs_ref))
            sample_parts = list(pool.map(_blocks, jobs_sample))
    ref: dict[int, int] = {}
    for p in ref_parts:
        ref.update(p)
    sample: dict[int, int] = {}
    for p in sample_parts:
        sample.update(p)
    starts, funcs = _functions()
    missed = [a for a in ref if a not in sample]
    ref_f = _by_function(ref, starts, funcs)
    missed_f = _by_function(missed, starts, funcs)
    extra = [a for a in sample if a not in ref]
    return {
        "suite": suite, "scenario_runs": len(runs),
        "sample_runs": [f"{j[0].name}@{j[0].profile}" for j in jobs_sample],
        "blocks": {"event_windows": len(ref), "sample": len(sample),
                   "sample_of_event_windows": len(ref) - len(missed),
                   "sample_only": len(extra)},
        "instructions_static": {"event_windows": sum(ref.values()),
                                "sample_of_event_windows": sum(ref[a] for a in ref
                                                               if a in sample)},
        "functions": {"event_windows": len(ref_f),
                      "missed_whole": sorted(n for n in missed_f if missed_f[n] == ref_f[n])},
        "missed_by_function": {n: f"{k} of {ref_f[n]} blocks"
                               for n, k in sorted(missed_f.items(), key=lambda x: -x[1])},
    }
