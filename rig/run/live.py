"""The live Rerun view of a run on the bus (``rig run --live``): the telemetry the drive
sends (TLM_*, 1 kHz) and the plant's truth, as they arrive."""

from __future__ import annotations

import math

from rig.data import capture
from rig.link.bus import BusLink, Signals
from rig.link.clock import PlantProgress
from rig.results import recording
from rig.run.monitor import Monitor


class LiveFeed:
    def __init__(self, view: recording.LiveView, link: BusLink, monitor: Monitor,
                 progress: PlantProgress) -> None:
        self.view = view
        self.monitor = monitor
        self.progress = progress
        link.on("TLM_POS", self._position)
        link.on("TLM_CUR", self._current)
        link.on("TLM_REF", self._reference)
        link.on("TLM_PARAM", self._parameters)
        link.on("BENCH_TRUTH", self._truth)

    def _full_period(self, p16: int) -> int:
        """The period of a 16-bit period number, next to the plant's own report."""
        base = self.progress.period or 0
        cand = (base & ~0xFFFF) | p16
        if cand > base + 0x8000:
            cand -= 0x10000
        elif cand < base - 0x8000:
            cand += 0x10000
        return max(cand, 0)

    def _position(self, v: Signals) -> None:
        p = self._full_period(int(v["period"]))
        self.view.add("speed", p, {"estimated": float(v["speed_hat"])})
        values = {"θ est": float(v["theta_hat"]), "θ": math.nan}  # θ: when the truth is known
        th = self.monitor.true_angle(int(v["period"]))
        if th is not None:
            true_deg = math.degrees(th) % 360.0
            values["θ"] = true_deg
            err = (float(v["theta_hat"]) - true_deg + 180.0) % 360.0 - 180.0
            self.view.add("error", p, {"θ est - θ": err})
        self.view.add("position", p, values)

    def _current(self, v: Signals) -> None:
        p = self._full_period(int(v["period"]))
        self.view.add("current", p, {"id": float(v["id"]), "iq": float(v["iq"])})
        self.view.add("torque", p, {"Te est": float(v["te_hat"])})

    def _reference(self, v: Signals) -> None:
        p = self._full_period(int(v["period"]))
        self.view.add("speed_ref", p, {"reference": float(v["speed_ref"])})

    def _parameters(self, v: Signals) -> None:
        p = self._full_period(int(v["period"]))
        self.view.add("params", p, {"Ld est (mH)": float(v["ld_hat"]) * 1e3,
                                    "Lq est (mH)": float(v["lq_hat"]) * 1e3,
                                    "λm est": float(v["lambda_hat"])})

    def _truth(self, v: Signals) -> None:
        p = int(v["period"])
        self.view.add("speed_true", p,
                      {"true": float(v["omega_m"]) * capture.RPM_PER_RAD_S})
        self.view.add("torque_true", p, {"Te": float(v["te"]), "TL": float(v["tl"])})

    def flush(self) -> None:
        self.view.flush()

    def close(self) -> None:
        self.view.close()
