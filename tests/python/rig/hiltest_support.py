"""Shared helpers for the rig's tests: synthetic traces encoded with cantools itself."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig import protocols
from rig.data.trace import TraceWriter

TS = protocols.timebase().ts
TICK = 1.0 / protocols.timebase().tbclk_hz


def message(db: str, name: str):  # type: ignore[no-untyped-def]
    return protocols.database(db).get_message_by_name(name)


def signal_defaults(msg) -> dict[str, float]:  # type: ignore[no-untyped-def]
    return {s.name: 0 for s in msg.signals}


@dataclass
class Synthetic:
    """A run in closed form: true θ ramp at a constant speed, θ̂ = θ(claim) + error."""

    n: int = 2000
    speed_rpm: float = 600.0
    pole_pairs: int = 2
    theta0: float = 0.3
    stamp: Callable[[np.ndarray], np.ndarray] = lambda k: np.full(k.shape, 5000)
    error_deg: Callable[[np.ndarray], np.ndarray] = lambda t: np.zeros_like(t)

    @property
    def omega_e(self) -> float:
        return self.speed_rpm * 2 * math.pi / 60 * self.pole_pairs

    def theta_true(self, t: np.ndarray) -> np.ndarray:
        return self.theta0 + self.omega_e * t  # unwrapped

    def write(self, folder: Path, *, drop: Mapping[str, list[int]] | None = None,
              dup: Mapping[str, list[int]] | None = None) -> tuple[Path, Path]:
        drop = drop or {}
        dup = dup or {}
        truth = message("bench", "BENCH_TRUTH")
        mag = message("bench", "BENCH_TRUTH_MAG")
        fw = message("vio", "FW_TRACE")
        k = np.arange(self.n)
        t = k * TS
        stamps = self.stamp(k)
        t_claim = t + stamps * TICK
        th_true = self.theta_true(t)
        th_hat = self.theta_true(t_claim) + np.radians(self.error_deg(t_claim))
        plant_path, fw_path = folder / "plant.trace", folder / "fw.trace"
        with TraceWriter(plant_path) as pw, TraceWriter(fw_path) as fwr:
            for i in range(self.n):
                wrapped = math.remainder(float(th_true[i]), 2 * math.pi)
                tv = signal_defaults(truth) | {
                    "period": i, "theta_e": wrapped,
                    "omega_m": self.omega_e / self.pole_pairs, "id": -0.5, "iq": 1.0 + i * 1e-4,
                    "te": 0.9, "vdc": 200.0,
                }
                mv = signal_defaults(mag) | {
                    "period": i, "ld_inc": 0.015, "lq_inc": 0.032, "lambda_m": 0.216,
                    "ld_app": 0.015, "lq_app": 0.032, "rs": 1.93,
                }
                fv = signal_defaults(fw) | {
                    "period": i, "stamp": int(stamps[i]),
                    "theta_hat": math.remainder(float(th_hat[i]), 2 * math.pi),
                    "omega_hat": self.omega_e, "ld_hat": 0.0153, "lq_hat": 0.0304,
                    "lambda_hat": 0.22, "vd": 3.0, "vq": 4.0, "state": 3, "slopes_ok": 2,
                    "te_hat": 1.0,
                }
                for name, m, vals, w in (("truth", truth, tv, pw), ("mag", mag, mv, pw),
                                         ("fw", fw, fv, fwr)):
                    if i in drop.get(name, []):
                        continue
                    data = m.encode(vals, strict=False)
                    w.write(m.frame_id, data)
                    if i in dup.get(name, []):
                        w.write(m.frame_id, data)
        return plant_path, fw_path
