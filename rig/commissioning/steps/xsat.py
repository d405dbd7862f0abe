"""Step ``xsat``: cross-saturation at speed (the load machine holds the speed, iq of both signs).

Cross-saturation (an incremental Ldq that grows with the q current) turns the saliency axes the
slope estimator sees away from the rotor's: at 1 r/min and 2 N*m on the harsh profile by
~5 degrees. At standstill nothing tells the two apart; at speed the flux estimator's angle
does: the drive reports the flux angle less the slope angle at the present current
(``xsat_turn_deg``, read-only). This step holds a speed with the load machine, runs the drive
in current control (id = 0) at q currents of both signs and reads the turn and the drive's
incremental Ld and Lq at each. The turn is 1/2 atan2(2 Ldq, Lqq - Ldd) with Ldq = k iq, so
(Lqq - Ldd) tan(2 turn) / 2 = k iq + c: a straight line in iq whose slope is k (c takes what
does not change sign with the current). k is written to ``xsat_ldq_per_a``, which corrects the
slope angle at every speed. On a virtual bench the plant's own Ldq per ampere is reported.

The speed (1000 r/min by default) is where the voltage model is good to a fraction of a degree
and two-vector slope periods are still frequent; the drive's rs must be right (the standstill
step identifies it; this step writes it to the drive when the session has it).
"""

from __future__ import annotations

import math

import numpy as np

from rig.commissioning.results import Quantity, StepResult, Table
from rig.commissioning.session import BenchSession
from rig.commissioning.steps.common import (
    measure,
    ramp_load_speed,
    start_at_speed_zero_held,
    truth,
)

TITLE = "cross-saturation at speed (load machine holds the speed, iq of both signs)"


def run(s: BenchSession, r: StepResult) -> None:
    cfg = s.config
    _, lb = s.require()
    s.drive.require_idle("cross-saturation identification")
    # the drive learns with the correction off (it measures the slope angle as seen)
    s.params.set("xsat_ldq_per_a", 0.0)
    # The flux angle comes from the voltage model v - rs i: an rs error tilts it by
    # drs iq / (omega lambda), which changes sign with iq like the turn itself (harsh, hot
    # machine: rs +30 % looked like -8 % of Ldq at 1000 r/min, -50 % at 300 r/min). The rs
    # this session identified at standstill goes to the drive first.
    rs = s.identified.get("rs_ohm")
    rs_before = s.params.get("rs_ohm")
    if rs is not None:
        s.params.set("rs_ohm", rs)
    r.facts["rs_ohm_used"] = rs if rs is not None else rs_before
    start_at_speed_zero_held(s)
    ramp_load_speed(s, 0.0, cfg.xsat_speed_rpm, cfg.flux_ramp_rpm_s)
    s.clock.advance(cfg.xsat_dwell_s)  # the flux estimator settles
    rows, xs, ys = [], [], []
    for current in cfg.xsat_currents_a:
        s.drive.command(iq_ref=current)
        s.clock.advance(cfg.xsat_dwell_s)
        got = measure(s, cfg.step_window_s)
        s.drive.check_no_fault(f"cross-saturation test at iq = {current:g} A")
        turn = math.radians(s.params.get("xsat_turn_deg"))
        ld, lq = s.params.get("ld_hat_h"), s.params.get("lq_hat_h")
        xs.append(got.iq)
        ys.append((lq - ld) * math.tan(2.0 * turn) / 2.0)
        rows.append([f"{current:+g}", f"{got.iq:+.3f}", f"{got.bench_speed:.1f}",
                     f"{math.degrees(turn):+.3f}", f"{ld * 1e3:.2f}", f"{lq * 1e3:.2f}"])
    k, c = np.polyfit(np.asarray(xs), np.asarray(ys), 1)
    k = float(k)
    rs_origin = "identified" if rs is not None else "the drive's own: run standstill first"
    s.drive.command(iq_ref=0.0)
    ramp_load_speed(s, cfg.xsat_speed_rpm, 0.0, cfg.flux_ramp_rpm_s)
    s.drive.disable()
    lb.off()
    s.params.set("rs_ohm", rs_before)  # (only this step's measurement needed it)
    s.params.set("xsat_ldq_per_a", k)
    s.identified["xsat_ldq_per_a"] = k
    s.written["xsat_ldq_per_a"] = k
    r.quantity(Quantity("xsat_ldq_per_a", "incremental Ldq per ampere of q current", k, "H/A",
                        f"(Lq - Ld) tan(2 turn)/2 against iq at "
                        f"{', '.join(f'{x:+g}' for x in cfg.xsat_currents_a)} A, "
                        f"{cfg.xsat_speed_rpm:g} r/min (offset {c * 1e3:+.3f} mH*A), rs "
                        f"{r.facts['rs_ohm_used']:.4g} ohm ({rs_origin}); "
                        "written to xsat_ldq_per_a",
                        0.0, truth(s, "xsat_ldq_per_a")))
    resid = float(np.sqrt(np.mean((np.asarray(ys) - (k * np.asarray(xs) + c)) ** 2)))
    bound = max(cfg.xsat_fit_rms_ha, cfg.xsat_fit_rms_rel * abs(k) * max(abs(x) for x in xs))
    r.check("the turns lie on a line in iq", resid <= bound,
            f"rms deviation {resid * 1e3:.4f} mH*A (bound {bound * 1e3:.3g}); turns "
            + ", ".join(f"{row[3]} deg at {row[1]} A" for row in rows))
    r.tables.append(Table("Currents held", [
        "iq ref (A)", "iq (A)", "speed (r/min)", "turn (deg)", "Ld (mH)", "Lq (mH)"], rows))
