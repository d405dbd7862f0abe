"""Measurement helpers shared by the commissioning steps."""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np

from rig.commissioning.session import BenchSession
from rig.commissioning.telemetry import Window
from rig.drive import params as paramtable
from rig.link.clock import BenchTimeout
from rig.loadbench.client import BenchMeasurement

RAMP_DT_S = 0.01  # load-machine speed ramps: one setpoint per 10 ms of bench time
REACH_POLL_S = 0.05  # reach_speed: a load-bench reading every 50 ms of bench time
REACH_CEILING_MIN_S = 2.0  # reach_speed: a ceiling, not a wait


def nominal(key: str) -> float:
    """The parameters.csv default of a parameter (the drive's nominal value)."""
    return paramtable.table().lookup(key).default


def truth(s: BenchSession, key: str) -> float | None:
    return None if s.truth is None else s.truth.get(key)


@dataclass
class Sample:
    """Means over one measuring window: drive telemetry and load-bench measurements."""

    iq: float
    id: float
    vq: float
    vd: float
    speed_hat: float
    lambda_hat: float
    ld_hat: float
    lq_hat: float
    te_hat: float
    shaft_torque: float
    bench_speed: float
    bench_speeds: np.ndarray
    theta_err: np.ndarray
    window: Window


def measure(s: BenchSession, seconds: float, polls: int = 5) -> Sample:
    """Advances the bench by ``seconds`` in ``polls`` pieces, reading the load bench after
    each; means of the telemetry over the whole window."""
    lb = s.load
    got: list[BenchMeasurement] = []
    with Window(s.link) as w:
        for _ in range(max(1, polls)):
            s.clock.advance(seconds / max(1, polls))
            if lb is not None:
                got.append(lb.measure())
    torque = float(np.mean([m.shaft_torque for m in got])) if got else math.nan
    speeds = np.asarray([m.speed_rpm for m in got], dtype=np.float64)
    return Sample(
        iq=w.mean("TLM_CUR", "iq"), id=w.mean("TLM_CUR", "id"), vq=w.mean("TLM_VOLT", "vq"),
        vd=w.mean("TLM_VOLT", "vd"), speed_hat=w.mean("TLM_POS", "speed_hat"),
        lambda_hat=w.mean("TLM_PARAM", "lambda_hat"), ld_hat=w.mean("TLM_PARAM", "ld_hat"),
        lq_hat=w.mean("TLM_PARAM", "lq_hat"), te_hat=w.mean("TLM_CUR", "te_hat"),
        shaft_torque=torque, bench_speed=float(np.mean(speeds)) if speeds.size else math.nan,
        bench_speeds=speeds, theta_err=w.angle_error_deg(), window=w)


def reach_speed(s: BenchSession, ref: float, tol: float, ramp_s: float) -> float:
    """After a speed ramp's own time: waits until the load bench measures the speed within
    tol of ref, for at most 10 ramps (REACH_CEILING_MIN_S at least); the time it waited (0:
    the drive was there, as a drive that keeps its ramp is). On a real bench a slower drive,
    on a free-running virtual bench one that lags the wall clock (a loaded machine), gets the
    time it needs, where a fixed time measured it half-way; a drive that never gets there is
    left to the step's check of the speed."""
    lb = s.load
    assert lb is not None
    t0 = s.clock.now()
    with contextlib.suppress(BenchTimeout):
        s.clock.wait(lambda: abs(lb.measure().speed_rpm - ref) <= tol,
                     max(REACH_CEILING_MIN_S, 10.0 * ramp_s),
                     f"speed {ref:g} r/min within {tol:g} r/min", step_s=REACH_POLL_S)
    return s.clock.now() - t0


def ramp_load_speed(s: BenchSession, start: float, stop: float, rate_rpm_s: float) -> None:
    """Speed-hold setpoints from start to stop at rate_rpm_s, one every RAMP_DT_S."""
    lb = s.load
    assert lb is not None
    step = rate_rpm_s * RAMP_DT_S
    n = max(1, math.ceil(abs(stop - start) / step))
    for k in range(1, n + 1):
        lb.set_speed(start + (stop - start) * k / n)
        s.clock.advance(RAMP_DT_S)


def start_at_speed_zero_held(s: BenchSession) -> None:
    """Enables the drive in current control (id = 0, iq = 0) on the free shaft, then has the
    load machine hold it at 0 r/min: when the saturation test cannot decide the polarity
    (harsh: 9 of 72 start angles and noise seeds with the default sampling), the drive's
    motion check needs the rotor to turn."""
    cfg = s.config
    lb = s.load
    assert lb is not None
    s.drive.set_limits(cfg.i_max_a, cfg.speed_max_rpm, cfg.accel_rpm_s)
    s.drive.enable(ctrl_mode="current", fw_mode="id_zero", iq_ref=0.0,
                   timeout_s=cfg.start_timeout_s)
    lb.speed_hold(0.0)


def pole_pairs(s: BenchSession) -> int:
    return round(s.params.get("pole_pairs"))


def circular_mean_deg(errs: np.ndarray) -> float:
    if errs.size == 0:
        return math.nan
    r = np.mean(np.exp(1j * np.radians(errs)))
    return float(np.degrees(np.angle(r)))
