"""What the execution of a run left behind for its evaluation, filled in as it goes (so a
run that fails half-way still tells what it did): the periods simulated, the programs' stop
reports, the counters, what the rig heard, and the wall-clock timing of the grants."""

from __future__ import annotations

import importlib
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from rig.data import capture
from rig.link.clock import PlantProgress
from rig.results.result import Timing
from rig.run.bus_report import BusNodes
from rig.run.monitor import Monitor
from rig.supervisor import StopReport

if TYPE_CHECKING:  # rerun (0.3 s to import) only once a recording is written
    from rig.results import recording

TS = capture.TS


@dataclass
class Execution:
    periods_done: int = 0
    stops: dict[str, StopReport] = field(default_factory=dict)
    counters: dict[str, float] = field(default_factory=dict)
    monitor: Monitor | None = None  # on the bus: what the rig heard
    progress: PlantProgress | None = None  # on the bus: the plant's own report
    t0: float = field(default_factory=time.monotonic)
    grants: list[tuple[int, float, float]] = field(default_factory=list)  # (run_until,
    # wall s since t0 at its end, the grant's own wall s)
    cpu_s: float | None = None  # in process: CPU time of the closed loop
    grant_resends: int = 0  # lockstep grants the plant did not take at once (lost frames)
    # on the bus: the frames per identifier the rig sent and received (rig.run.traffic)
    rig_tx_ids: dict[int, int] | None = None
    rig_rx_ids: dict[int, int] | None = None
    where: str = ""  # "unixcan channel 'x'": for the messages
    # unixcan: the other nodes of the channel and what the run's senders dropped for them
    bus_nodes: BusNodes | None = None
    can_log: dict[str, Any] | None = None  # the rig's live log of the bus (rig.bus.can_log)
    # modules the post-processing needs (rerun, matplotlib: ~0.5 s to import), imported in
    # the background once the closed loop runs: not in the start-up, not after a crash
    preload: tuple[str, ...] = ()
    _preloading: threading.Thread | None = field(default=None, repr=False)

    def start_preload(self) -> None:
        """Imports ``preload`` in a background thread (once; the run goes on meanwhile: the
        bench and the bus wait outside the interpreter lock)."""
        if self._preloading is not None or not self.preload:
            return

        def load() -> None:
            for name in self.preload:
                try:
                    importlib.import_module(name)
                except Exception:  # imported again where used: an error shows there
                    return

        self._preloading = threading.Thread(target=load, name="rig-preload", daemon=True)
        self._preloading.start()

    def wall(self) -> float:
        return time.monotonic() - self.t0

    def add_counters(self, prefix: str, values: Any) -> None:
        """Numbers of a nested mapping as ``prefix.key.key`` counters (floats)."""
        if isinstance(values, Mapping):
            for k, v in values.items():
                self.add_counters(f"{prefix}.{k}", v)
        elif isinstance(values, bool | int | float):
            self.counters[prefix] = float(values)

    def reached(self) -> int:
        """The periods the run got through (the plant's last report when it failed)."""
        heard = self.progress.period if self.progress is not None else 0
        return self.periods_done or heard or 0

    def timing(self, wall_s: float) -> Timing:
        sim_s = self.reached() * TS
        grant_walls = [g[2] for g in self.grants]
        cpu = self.cpu_s or None
        return Timing(
            sim_s=sim_s, wall_s=wall_s,
            speed_x=sim_s / wall_s if wall_s > 0 and sim_s > 0 else None,
            grants=len(self.grants),
            grant_wall_ms_mean=1e3 * float(np.mean(grant_walls)) if grant_walls else None,
            grant_wall_ms_max=1e3 * float(np.max(grant_walls)) if grant_walls else None,
            cpu_s=cpu, speed_x_cpu=(sim_s / cpu if sim_s > 0 else None) if cpu else None,
        )

    def grant_samples(self) -> recording.TimedSamples | None:
        """Each grant's wall time and speed over real time, for the recording."""
        from rig.results import recording

        if not self.grants:
            return None
        g = np.asarray(self.grants, dtype=np.float64)
        walls = np.diff(np.concatenate([[0.0], g[:, 1]]))
        sims = np.diff(np.concatenate([[0.0], g[:, 0]])) * TS
        return recording.TimedSamples(
            [int(x) for x in g[:, 0]],
            {"grant_wall_ms": list(g[:, 2] * 1e3),
             "speed_x": list(np.where(walls > 0, sims / np.maximum(walls, 1e-12), 0.0))},
        )
