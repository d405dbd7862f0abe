"""Core journals of closed-loop runs: a scenario on the in-process bench (``--bus inproc``)
with every call into the control core journalled (``RunOptions.core_journal``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from rig import scenario
from rig.results.result import RunResult
from rig.run import runner

TS = 1e-4  # s per ISR (checked against the wire's time base in the tests)


def windows_from_seconds(spans: Sequence[tuple[float, float]]) -> list[tuple[int, int]]:
    """(start s, length s) -> ISR index windows (one ISR per PWM period)."""
    return [(round(t0 / TS), max(1, round(dt / TS))) for t0, dt in spans]


def record(name: str, out: Path, windows: Sequence[tuple[int, int]] = (),
           duration: float | None = None) -> RunResult:
    """Runs scenario ``name`` in process into ``out`` (run outputs and ``core.journal``),
    only its first ``duration`` seconds when given (its criteria past that are not
    evaluated)."""
    sc = scenario.load(name)
    if not isinstance(sc, scenario.Scenario):
        raise ValueError(f"{name} is a suite, not a scenario")
    if duration is not None and duration < sc.duration:
        sc = dataclasses.replace(sc, duration=duration)
    return record_scenario(sc, out, windows)


def record_scenario(sc: scenario.Scenario, out: Path,
                    windows: Sequence[tuple[int, int]] = ()) -> RunResult:
    """Runs ``sc`` in process into ``out`` with the core journalled over ``windows``."""
    out.mkdir(parents=True, exist_ok=True)
    opts = runner.RunOptions(out=out, bus="inproc", progress=False, record=False, keep="failing",
                             core_journal=out / "core.journal", core_journal_windows=windows)
    return runner.run_scenario(sc, opts)
