"""Step ``sweep``: speed control at a few speeds, each with a load step (load machine in
torque mode): steady speed error, estimate error, speed drop and recovery after the step,
estimated vs measured torque."""

from __future__ import annotations

import math

import numpy as np

from rig.commissioning.results import Quantity, StepResult, Table
from rig.commissioning.session import BenchSession
from rig.commissioning.steps.common import measure, reach_speed

TITLE = "Speed sweep with load steps"
POLL_S = 0.01


def _recovery(speeds: np.ndarray, ref: float, tol: float, dt: float) -> float:
    """Time after which the speed stays within tol of ref (inf: never)."""
    outside = np.nonzero(np.abs(speeds - ref) > tol)[0]
    if outside.size == 0:
        return 0.0
    last = int(outside[-1])
    return math.inf if last == speeds.size - 1 else (last + 1) * dt


def run(s: BenchSession, r: StepResult) -> None:
    cfg = s.config
    _, lb = s.require()
    s.drive.require_idle("speed sweep")
    lb.torque_mode(0.0)
    s.drive.set_limits(cfg.i_max_a, cfg.speed_max_rpm, cfg.accel_rpm_s)
    s.drive.enable(ctrl_mode="speed", fw_mode=cfg.sweep_fw_mode, speed_ref=0.0,
                   timeout_s=cfg.start_timeout_s)
    tol = cfg.sweep_tolerance_rpm
    rows = []
    worst_theta = 0.0
    speed = 0.0
    for ref in cfg.sweep_speeds_rpm:
        s.drive.command(speed_ref=ref)
        ramp_s = abs(ref - speed) / cfg.accel_rpm_s
        s.clock.advance(ramp_s + cfg.sweep_settle_s)
        if reach_speed(s, ref, tol, ramp_s) > 0.0:
            s.clock.advance(cfg.sweep_settle_s)
        speed = ref
        before = measure(s, 0.1)
        lb.set_torque(cfg.sweep_load_nm)
        n = max(1, round(cfg.sweep_step_s / POLL_S))
        step = measure(s, n * POLL_S, polls=n)
        loaded = measure(s, 0.1)
        lb.set_torque(0.0)
        s.clock.advance(cfg.sweep_settle_s)
        s.drive.check_no_fault(f"load step at {ref:g} r/min")
        drop = float(np.min(step.bench_speeds) - ref) if ref > 0 else \
            float(np.max(step.bench_speeds) - ref)
        rec = _recovery(step.bench_speeds, ref, tol, POLL_S)
        err0 = before.bench_speed - ref
        err1 = loaded.bench_speed - ref
        est = loaded.speed_hat - loaded.bench_speed
        for arr in (before.theta_err, step.theta_err, loaded.theta_err):
            if arr.size:
                worst_theta = max(worst_theta, float(np.max(np.abs(arr))))
        ok = (abs(err0) <= tol and abs(err1) <= tol and abs(est) <= tol
              and rec <= cfg.sweep_recovery_s)
        r.check(f"{ref:g} r/min, {cfg.sweep_load_nm:g} N·m step", ok,
                f"speed error {err0:+.1f} / {err1:+.1f} r/min (unloaded / loaded), estimate "
                f"error {est:+.1f} r/min, drop {drop:+.1f} r/min, back within {tol:g} r/min "
                f"after {rec * 1e3:.0f} ms")
        rows.append([f"{ref:g}", f"{err0:+.2f}", f"{err1:+.2f}", f"{est:+.2f}", f"{drop:+.1f}",
                     f"{rec * 1e3:.0f}", f"{loaded.id:+.3f}", f"{loaded.iq:.3f}",
                     f"{loaded.shaft_torque:.3f}", f"{loaded.te_hat:.3f}"])
    s.drive.command(speed_ref=0.0)
    s.clock.advance(speed / cfg.accel_rpm_s + 0.1)
    s.drive.disable()
    lb.off()
    if worst_theta > 0:
        r.quantity(Quantity("sweep_theta_err_deg", "largest |θ̂ - θ| in the sweep (plant truth)",
                            worst_theta, "deg", "TLM_POS vs BENCH_TRUTH (θ at the period start)"))
    title = f"Speeds and {cfg.sweep_load_nm:g} N·m load steps ({cfg.sweep_fw_mode})"
    r.tables.append(Table(title,
                          ["reference (r/min)", "error unloaded", "error loaded",
                           "estimate - measured", "drop", "recovery (ms)", "id (A)", "iq (A)",
                           "shaft torque (N·m)", "T̂e (N·m)"], rows))
