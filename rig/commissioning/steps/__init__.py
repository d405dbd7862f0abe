"""The commissioning steps, in the order ``all`` runs them.

Each step starts from a disabled drive and an idle load machine and leaves them so, so any
step can run alone (``rig commission <step>``); a step that fails stops the run.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from rig.commissioning.results import StepResult
from rig.commissioning.session import BenchSession
from rig.commissioning.steps import connectivity, flux, standstill, start, sweep, xsat


@dataclass(frozen=True)
class Step:
    name: str
    title: str
    run: Callable[[BenchSession, StepResult], None]


STEPS = {s.name: s for s in (
    Step("connectivity", connectivity.TITLE, connectivity.run),
    Step("polarity", standstill.TITLE_POLARITY, standstill.run_polarity),
    Step("standstill", standstill.TITLE, standstill.run),
    Step("start", start.TITLE, start.run),
    Step("flux", flux.TITLE, flux.run),
    Step("xsat", xsat.TITLE, xsat.run),
    Step("sweep", sweep.TITLE, sweep.run),
)}
ALL = ("connectivity", "standstill", "start", "flux", "xsat", "sweep")
