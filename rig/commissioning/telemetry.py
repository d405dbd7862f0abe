"""Telemetry windows: what the drive (TLM_*) and, on a virtual bench, the plant (BENCH_TRUTH)
said while the bench clock advanced.

    with Window(link) as w:
        clock.advance(0.1)
    vq = w.mean("TLM_VOLT", "vq")
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from types import TracebackType

import numpy as np

from rig.link.bus import BusLink, Signals

NAMES = ("TLM_POS", "TLM_CUR", "TLM_REF", "TLM_PARAM", "TLM_VOLT", "BENCH_TRUTH",
         "DRIVE_STATUS")


class NoData(RuntimeError):
    """A window without a single frame of the message it was asked about."""


class Window:
    def __init__(self, link: BusLink, names: Sequence[str] = NAMES) -> None:
        self.link = link
        self.names = tuple(names)
        self.frames: dict[str, list[Signals]] = {n: [] for n in self.names}
        self._removers: list[object] = []

    def __enter__(self) -> Window:
        self.link.pump(0.0)  # what arrived before the window is not part of it
        for n in self.names:
            self._removers.append(self.link.on(n, self.frames[n].append))
        return self

    def __exit__(self, et: type[BaseException] | None, e: BaseException | None,
                 tb: TracebackType | None) -> None:
        for remove in self._removers:
            remove()  # type: ignore[operator]
        self._removers.clear()

    def values(self, name: str, signal: str) -> np.ndarray:
        return np.asarray([float(f[signal]) for f in self.frames[name]], dtype=np.float64)

    def count(self, name: str) -> int:
        return len(self.frames[name])

    def mean(self, name: str, signal: str) -> float:
        v = self.values(name, signal)
        if v.size == 0:
            raise NoData(f"no {name} frame in the window (is the drive sending telemetry?)")
        return float(np.mean(v))

    def std(self, name: str, signal: str) -> float:
        v = self.values(name, signal)
        return float(np.std(v)) if v.size else math.nan

    def has(self, name: str) -> bool:
        return bool(self.frames.get(name))

    def angle_error_deg(self) -> np.ndarray:
        """θ̂ (TLM_POS) minus the true angle (BENCH_TRUTH) of the same period, wrapped to
        ±180°; empty without truth on the bus (a real bench)."""
        truth = {int(f["period"]) & 0xFFFF: math.degrees(float(f["theta_e"])) % 360.0
                 for f in self.frames.get("BENCH_TRUTH", [])}
        errs = [(float(f["theta_hat"]) - truth[int(f["period"])] + 180.0) % 360.0 - 180.0
                for f in self.frames.get("TLM_POS", []) if int(f["period"]) in truth]
        return np.asarray(errs, dtype=np.float64)
