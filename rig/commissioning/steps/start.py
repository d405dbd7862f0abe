"""Step ``start``: sensorless start at low speed on a free shaft (load machine off).

Speed control from standstill to ``start_speed_rpm``; the load bench's own speed sensor must
agree with the reference (direction included: a polarity error turns the rotor the wrong
way) and with the drive's estimate."""

from __future__ import annotations

from rig.commissioning.results import Quantity, StepResult
from rig.commissioning.session import BenchSession
from rig.commissioning.steps.common import measure, reach_speed

TITLE = "Sensorless start at low speed (free shaft)"


def run(s: BenchSession, r: StepResult) -> None:
    cfg = s.config
    _, lb = s.require()
    s.drive.require_idle("sensorless start")
    lb.off()
    s.drive.set_limits(cfg.i_max_a, cfg.speed_max_rpm, cfg.start_accel_rpm_s)
    t = s.drive.enable(ctrl_mode="speed", fw_mode=cfg.start_fw_mode, speed_ref=0.0,
                       timeout_s=cfg.start_timeout_s)
    r.check("enable", True, f"RUN {1e3 * t:.0f} ms after enable ({cfg.start_fw_mode})")
    ref = cfg.start_speed_rpm
    s.drive.command(speed_ref=ref)
    ramp_s = abs(ref) / cfg.start_accel_rpm_s
    s.clock.advance(ramp_s + cfg.start_hold_s)
    if reach_speed(s, ref, cfg.start_tolerance_rpm, ramp_s) > 0.0:
        s.clock.advance(cfg.start_hold_s)
    m = measure(s, 0.1)
    s.drive.check_no_fault("low-speed run")
    tol = cfg.start_tolerance_rpm
    r.check("direction and speed (load-bench sensor)",
            m.bench_speed * ref > 0 and abs(m.bench_speed - ref) <= tol,
            f"reference {ref:g} r/min, measured {m.bench_speed:.2f} r/min "
            f"(tolerance {tol:g})")
    r.check("speed estimate", abs(m.speed_hat - m.bench_speed) <= tol,
            f"estimate {m.speed_hat:.2f} r/min vs measured {m.bench_speed:.2f} r/min")
    st = s.drive.status
    r.check("estimator valid", int(st.get("est_valid", 0)) == 1,
            f"est_valid={int(st.get('est_valid', 0))}, polarity_ok="
            f"{int(st.get('polarity_ok', 0))}")
    r.quantity(Quantity("start_speed_rpm", "speed at the low-speed point", m.bench_speed,
                        "r/min", "load-bench speed sensor"))
    if m.theta_err.size:
        r.quantity(Quantity("start_theta_err_deg", "largest |θ̂ - θ| (plant truth)",
                            float(abs(m.theta_err).max()), "deg",
                            "TLM_POS vs BENCH_TRUTH (θ at the period start)"))
    s.drive.command(speed_ref=0.0)
    s.clock.advance(abs(ref) / cfg.start_accel_rpm_s + 0.05)
    s.drive.disable()
