"""The closed-loop runs whose journals the target is compared on, and which stretches of them
(ISR index windows) a short comparison or the benchmark replays."""

from __future__ import annotations

from dataclasses import dataclass

from rig import scenario
from rig.target_m4.record import TS


@dataclass(frozen=True)
class Case:
    what: str
    scenario: str
    # (start s, length s) of the short comparison besides the start (from fw_core_init)
    spans: tuple[tuple[float, float], ...]
    duration: float | None = None  # run only this long (s); None: the whole scenario


# The start from standstill (INIT, IDLE, polarity detection, the first RUN periods) is the
# first window of every case.
START_S = 0.15
CASES = (
    Case("1 r/min, 1 N*m (paper)", "table2_0001rpm_1nm", ((1.9, 0.05),), duration=2.0),
    Case("1000 r/min, 1 N*m load step (paper)", "table2_1000rpm_1nm", ((0.69, 0.05),
                                                                       (1.7, 0.05))),
    Case("3000 r/min, flux weakening, 1 N*m (paper)", "fig10_fw_3000rpm_realtime_1nm",
         ((2.9, 0.05),)),
    Case("phase c open at 1000 r/min: fault (paper)", "fault_open_phase", ((0.495, 0.05),)),
)


def case(name: str) -> Case:
    """A case by scenario name; any scenario not listed is a case of its own (whole run)."""
    for c in CASES:
        if c.scenario == name:
            return c
    scenario.load(name)  # raises for an unknown name
    return Case(name, name, ())


def windows(c: Case, scale: float = 1.0) -> list[tuple[int, int]]:
    """ISR index windows of the short comparison, each ``scale`` times as long."""
    spans = [(0.0, START_S), *c.spans]
    return [(round(t0 / TS), max(1, round(scale * dt / TS))) for t0, dt in spans]
