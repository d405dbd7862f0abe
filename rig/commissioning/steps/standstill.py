"""Steps ``polarity`` and ``standstill``: the drive in current control with id = 0
(``fwmode id_zero``), the rotor locked by the load machine (speed hold at 0 r/min) once the
drive runs.

* Polarity: the drive starts on a free shaft (its start-up detection may fall back to a
  motion check), then with the rotor locked a positive q current must give a positive shaft
  torque on the torque sensor - a frame turned by π gives the opposite torque. That verdict
  does not depend on the firmware's detection. If the detection chose the wrong pole (or
  faulted), the step says so (a failed check: the drive would start wrongly in service) and
  starts again with the motion method (``pol_method`` 2, free shaft), checks the torque
  again and restores ``pol_method``. On a virtual bench θ̂ is also compared with the plant's
  true angle.
* Ld, Lq: the slope estimator's online incremental inductances (TLM_PARAM) at zero current.
* rs: steady q-current steps; the firmware applies exactly the volt-seconds it commands
  (pattern carry), so the mean q voltage reference is rs·iq plus the inverter's voltage error
  along the current, which is the same for every step once every phase current is well above
  the ripple. The load machine therefore first turns the rotor until the q axis lies on a
  phase axis (each phase then carries at least half the current). rs is the slope of vq over
  iq, the intercept that error (dead time, device drop). The shaft torque's sign at each
  step shows whether the drive kept its polarity under the steps on the held rotor.
  The shaft torque of the same steps gives kt = 1.5·p·λm (a cross-check of λm).
"""

from __future__ import annotations

import math

import numpy as np

from rig.commissioning.checked_drive import DriveError
from rig.commissioning.results import Quantity, StepResult, Table
from rig.commissioning.session import BenchSession
from rig.commissioning.steps.common import (
    Sample,
    circular_mean_deg,
    measure,
    nominal,
    pole_pairs,
    truth,
)
from rig.commissioning.telemetry import Window

TITLE_POLARITY = "Polarity at standstill (free-shaft start, locked-rotor torque check)"
TITLE = "Standstill identification: polarity, Ld, Lq, rs (locked rotor)"


MOTION_METHOD = 2  # pol_method: motion check only (parameters.csv)


def _start(s: BenchSession, r: StepResult, label: str) -> bool:
    """Enables the drive on a free shaft; False (and a failed check) on a start-up fault."""
    cfg = s.config
    assert s.load is not None
    s.load.off()  # free shaft: the drive's motion check must be able to turn the rotor
    try:
        t = s.drive.enable(ctrl_mode="current", fw_mode="id_zero", iq_ref=0.0,
                           timeout_s=cfg.start_timeout_s)
    except DriveError as exc:
        r.check(f"{label}: start-up", False, str(exc))
        if s.drive.state == "FAULT":
            s.drive.reset_fault()
        return False
    st = s.drive.status
    r.check(f"{label}: start-up", int(st.get("polarity_ok", 0)) == 1,
            f"RUN {1e3 * t:.0f} ms after enable, polarity_ok={int(st.get('polarity_ok', 0))}, "
            f"est_valid={int(st.get('est_valid', 0))}")
    s.load.speed_hold(0.0)  # lock the rotor
    return True


def _attempt(s: BenchSession, r: StepResult, label: str) -> str:
    """One start-up and the torque verdict: 'correct', 'wrong', 'inconclusive' or 'fault'."""
    if not _start(s, r, label):
        return "fault"
    _truth_angle(s, r, measure(s, 0.02, polls=1), label)
    verdict = _polarity_by_torque(s, r, _step(s, s.config.polarity_current_a), label)
    s.drive.command(iq_ref=0.0)
    return verdict


def _start_with_polarity(s: BenchSession, r: StepResult) -> None:
    """The drive running with a verified polarity (recovering once with the motion method);
    raises DriveError when even that fails."""
    s.require()
    s.drive.require_idle("standstill")
    cfg = s.config
    s.drive.set_limits(cfg.i_max_a, cfg.speed_max_rpm, cfg.accel_rpm_s)
    method = s.params.get("pol_method")
    first = _attempt(s, r, f"drive's start-up detection (pol_method {method:g})")
    r.facts["polarity_first"] = first
    r.facts["polarity_method"] = int(method)
    final = first
    if first != "correct" and method != MOTION_METHOD:
        if s.drive.state != "IDLE":
            s.drive.disable()
        r.notes.append(f"The drive's start-up detection (pol_method {method:g}) ended "
                       f"{first} at this rotor position: it would start wrongly in service. "
                       f"Retried with pol_method {MOTION_METHOD} (motion check, free shaft); "
                       f"pol_method is restored to {method:g} at the end of the step.")
        s.params.set("pol_method", MOTION_METHOD)
        r.facts["pol_method_restore"] = method
        final = _attempt(s, r, f"retry with the motion method (pol_method {MOTION_METHOD})")
    r.facts["polarity_final"] = final
    if final != "correct":
        raise DriveError(f"no start-up with a verified polarity ({first}, then {final})")


def _restore_method(s: BenchSession, r: StepResult) -> None:
    if "pol_method_restore" in r.facts:
        s.params.set("pol_method", float(r.facts.pop("pol_method_restore")))


def _truth_angle(s: BenchSession, r: StepResult, sample: Sample, label: str) -> None:
    errs = sample.theta_err
    if errs.size == 0:
        if not r.notes:
            r.notes.append("no BENCH_TRUTH on the bus (real bench): θ̂ not compared with a "
                           "true angle")
        return
    err = circular_mean_deg(errs)
    r.quantity(Quantity("theta_error_deg", f"θ̂ - θ at standstill, {label} (plant truth)",
                        err, "deg", "TLM_POS vs BENCH_TRUTH, same periods"))
    r.check(f"{label}: θ̂ against the plant's true angle", abs(err) < 90.0,
            f"mean error {err:+.2f}° over {errs.size} periods (|error| ≥ 90° would be a "
            "polarity error)")


def _step(s: BenchSession, iq: float, settle_s: float | None = None,
          window_s: float | None = None) -> Sample:
    s.drive.command(iq_ref=iq)
    s.clock.advance(s.config.step_settle_s if settle_s is None else settle_s)
    return measure(s, s.config.step_window_s if window_s is None else window_s)


def phase_axis_offset_deg(theta_hat_deg: float) -> float:
    """Electrical angle from the q axis (θ̂ + 90°) to the nearest phase axis (±a, ±b, ±c,
    every 60°), in [-30°, 30°)."""
    return (theta_hat_deg + 90.0 + 30.0) % 60.0 - 30.0


def smallest_phase_share(offset_deg: float) -> float:
    """The smallest |phase current| / |current| of a current vector offset_deg from a phase
    axis: 0.5 on the axis, 0 at 30° (one phase then carries no current at all)."""
    return min(abs(math.cos(math.radians(offset_deg - k * 120.0))) for k in range(3))


def _theta_hat_mean(s: BenchSession, seconds: float) -> float | None:
    """θ̂ averaged (circularly) over the next ``seconds``: one telemetry sample scatters by about
    a degree at standstill, enough to stop the rotor several degrees short of the target."""
    with Window(s.link, ("TLM_POS",)) as w:
        s.clock.advance(seconds)
    th = w.values("TLM_POS", "theta_hat")
    return circular_mean_deg(th) % 360.0 if th.size else None


def _align_q_with_a_phase(s: BenchSession, r: StepResult) -> None:
    """Turns the rotor with the load machine (slow speed hold, the drive at zero current)
    until the q axis lies on a phase axis, and locks it there. At an arbitrary angle one phase
    may carry a current inside the ripple; its dead-time error then changes with the step
    current and adds to the vq-over-iq slope (measured: up to +5 % on rs)."""
    cfg = s.config
    assert s.load is not None
    poll_s = 0.01  # the rotor turns 0.6° (electrical) per poll at 5 r/min
    theta = _theta_hat_mean(s, poll_s)
    waited = 0.0
    if theta is None or abs(phase_axis_offset_deg(theta)) > cfg.rs_align_tolerance_deg:
        s.load.set_speed(cfg.rs_align_speed_rpm)
        while waited < cfg.rs_align_timeout_s:
            theta = _theta_hat_mean(s, poll_s)
            waited += poll_s
            if theta is not None and \
                    abs(phase_axis_offset_deg(theta)) <= cfg.rs_align_tolerance_deg:
                break
        s.load.set_speed(0.0)
    theta_end = _theta_hat_mean(s, 0.05)  # after the lock has settled
    if theta_end is None:
        r.check("q axis on a phase axis for rs", False, "no TLM_POS from the drive")
        return
    off = phase_axis_offset_deg(theta_end)
    share = smallest_phase_share(off)
    r.check("q axis on a phase axis for rs", abs(off) <= 2.0 * cfg.rs_align_tolerance_deg,
            f"θ̂ {theta_end:.1f}° after turning {waited:.2f} s at "
            f"{cfg.rs_align_speed_rpm:g} r/min: q axis {off:+.1f}° from a phase axis, "
            f"smallest phase current {share:.2f}·iq")


def _polarity_by_torque(s: BenchSession, r: StepResult, sample: Sample, label: str) -> str:
    cfg = s.config
    pp = pole_pairs(s)
    expected = 1.5 * pp * s.params.get("lambda_m_wb") * sample.iq
    if sample.shaft_torque >= cfg.polarity_torque_fraction * expected:
        verdict, text = "correct", "correct"
    elif sample.shaft_torque <= -cfg.polarity_torque_fraction * expected:
        verdict, text = "wrong", "WRONG (the frame points to the south pole)"
    else:
        verdict, text = "inconclusive", "inconclusive (no torque on the sensor)"
    r.check(f"{label}: polarity by shaft torque", verdict == "correct",
            f"iq {sample.iq:+.3f} A → shaft torque {sample.shaft_torque:+.3f} N·m "
            f"(nominal {expected:+.3f} N·m): {text}")
    return verdict


def _stop(s: BenchSession, r: StepResult) -> None:
    s.drive.command(iq_ref=0.0)
    s.drive.disable()
    if s.load is not None:
        s.load.off()
    _restore_method(s, r)


def run_polarity(s: BenchSession, r: StepResult) -> None:
    try:
        _start_with_polarity(s, r)
    finally:
        if s.drive.state == "RUN":
            _stop(s, r)
        _restore_method(s, r)


def run(s: BenchSession, r: StepResult) -> None:
    try:
        _identify(s, r)
    finally:
        _restore_method(s, r)


def _identify(s: BenchSession, r: StepResult) -> None:
    cfg = s.config
    _start_with_polarity(s, r)
    s.clock.advance(cfg.ldlq_settle_s)
    zero = measure(s, cfg.ldlq_window_s, polls=1)
    w = zero.window
    method = (f"slope estimator (TLM_PARAM), standstill, i ≈ 0 ({zero.id:+.3f}, "
              f"{zero.iq:+.3f}) A, {w.count('TLM_PARAM')} samples")
    ld = r.quantity(Quantity("ld_h", "Ld (incremental, i = 0)", zero.ld_hat, "H", method,
                             nominal("ld_h"), truth(s, "ld_h")))
    lq = r.quantity(Quantity("lq_h", "Lq (incremental, i = 0)", zero.lq_hat, "H", method,
                             nominal("lq_h"), truth(s, "lq_h")))
    r.check("Ld < Lq (saliency)", ld.value < lq.value,
            f"Ld {1e3 * ld.value:.3f} mH, Lq {1e3 * lq.value:.3f} mH "
            f"(std {1e3 * w.std('TLM_PARAM', 'ld_hat'):.3f} / "
            f"{1e3 * w.std('TLM_PARAM', 'lq_hat'):.3f} mH)")
    s.identified["ld_h"], s.identified["lq_h"] = ld.value, lq.value

    _align_q_with_a_phase(s, r)
    steps = [_step(s, i, cfg.rs_settle_s, cfg.rs_window_s) for i in cfg.rs_currents_a]
    iq = np.asarray([x.iq for x in steps])
    vq = np.asarray([x.vq for x in steps])
    rs, v0 = np.polyfit(iq, vq, 1)
    resid = float(np.max(np.abs(vq - (rs * iq + v0))))
    r.quantity(Quantity("rs_ohm", "rs", float(rs), "Ω",
                        f"slope of vq over iq, locked rotor, q axis on a phase axis, iq = "
                        f"{', '.join(f'{x:.2f}' for x in iq)} A (largest residual "
                        f"{resid:.3f} V)", nominal("rs_ohm"), truth(s, "rs_ohm")))
    r.quantity(Quantity("inverter_v", "inverter voltage error along the current", float(v0),
                        "V", "intercept of vq over iq (dead time and device drop)"))
    s.identified["rs_ohm"] = float(rs)
    torque = np.asarray([x.shaft_torque for x in steps])
    if np.all(np.isfinite(torque)):
        # a drive that lost its position under a current step (its frame turned by π) runs
        # the steps on the south pole: the shaft torque turns against iq
        r.check("polarity kept through the rs steps", bool(np.all(torque * iq > 0.0)),
                "shaft torque " + ", ".join(f"{t:+.3f}" for t in torque) + " N·m at iq "
                + ", ".join(f"{i:+.2f}" for i in iq) + " A")
        kt = float(np.polyfit(iq, torque, 1)[0])
        pp = pole_pairs(s)
        r.quantity(Quantity("lambda_kt_wb", "λm from the torque constant", kt / (1.5 * pp),
                            "Wb", "slope of the shaft torque over iq (id = 0), "
                            "kt / (1.5·p)", nominal("lambda_m_wb"), truth(s, "lambda_m_wb")))
    r.check("rs plausible", math.isfinite(rs) and rs > 0,
            f"rs {rs:.4f} Ω, inverter error {v0:.3f} V")
    r.tables.append(Table("Locked-rotor current steps", [
        "iq (A)", "id (A)", "vq (V)", "vd (V)", "shaft torque (N·m)", "T̂e (N·m)"],
        [[f"{x.iq:.4f}", f"{x.id:+.4f}", f"{x.vq:.3f}", f"{x.vd:+.3f}",
          f"{x.shaft_torque:.4f}", f"{x.te_hat:.4f}"] for x in steps]))
    _stop(s, r)
