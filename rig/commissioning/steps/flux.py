"""Step ``flux``: λm at speed from the q voltage, the load machine holding the speed.

At a held speed ωe with id = 0, the mean q voltage the drive applies is
``vq = rs·iq + ωe·(λm + Ld·id) + e_q(i)``, with e_q the inverter's voltage error along the
current. With the drive in current control at +I and then -I (motoring, then braking against
the load machine), rs·iq and the error e_q (odd in the current) cancel in the mean:
``λm = (vq(+I) + vq(-I)) / (2·ωe) - Ld·id_mean``. The inverter error of this firmware depends
on the switching pattern, which changes with the voltage, so a single speed or the slope
between two speeds is biased; the ± mean at each speed is not, and the median over the
speeds is reported. ωe comes from the load bench's speed sensor. The drive's own online
estimate (flux estimator, TLM_PARAM) and the apparent Lq from vd are reported beside it.
"""

from __future__ import annotations

import math

import numpy as np

from rig.commissioning.results import Quantity, StepResult, Table
from rig.commissioning.session import BenchSession
from rig.commissioning.steps.common import (
    measure,
    nominal,
    pole_pairs,
    ramp_load_speed,
    start_at_speed_zero_held,
    truth,
)

TITLE = "λm at speed (load machine holds the speed, ±iq, id = 0)"


def run(s: BenchSession, r: StepResult) -> None:
    cfg = s.config
    _, lb = s.require()
    s.drive.require_idle("flux identification")
    pp = pole_pairs(s)
    ld = s.identified.get("ld_h", s.params.get("ld_h"))
    start_at_speed_zero_held(s)
    rows, lams, lq_apps, lam_hats = [], [], [], []
    speed = 0.0
    current = cfg.flux_current_a
    for target in cfg.flux_speeds_rpm:
        s.drive.command(iq_ref=0.0)
        ramp_load_speed(s, speed, target, cfg.flux_ramp_rpm_s)
        speed = target
        s.clock.advance(cfg.step_settle_s)
        got = []
        for i in (current, -current):
            s.drive.command(iq_ref=i)
            s.clock.advance(cfg.step_settle_s)
            got.append(measure(s, cfg.step_window_s))
            s.drive.check_no_fault(f"flux test at {target:g} r/min")
        pos, neg = got
        bench = 0.5 * (pos.bench_speed + neg.bench_speed)
        we = pp * bench * 2.0 * math.pi / 60.0
        lam = (0.5 * (pos.vq + neg.vq) - we * ld * 0.5 * (pos.id + neg.id)) / we
        lq_app = -(pos.vd - neg.vd) / (we * (pos.iq - neg.iq))
        lam_hat = 0.5 * (pos.lambda_hat + neg.lambda_hat)
        lams.append(lam)
        lq_apps.append(lq_app)
        lam_hats.append(lam_hat)
        rows.append([f"{bench:.1f}", f"{pos.vq:.3f}", f"{neg.vq:.3f}", f"{pos.iq:+.3f}",
                     f"{neg.iq:+.3f}", f"{lam:.5f}", f"{lq_app * 1e3:.2f}",
                     f"{pos.lambda_hat:.5f} / {neg.lambda_hat:.5f}"])
    s.drive.command(iq_ref=0.0)
    ramp_load_speed(s, speed, 0.0, cfg.flux_ramp_rpm_s)
    s.drive.disable()
    lb.off()
    lam_m = float(np.median(lams))
    spread = float(np.max(lams) - np.min(lams))
    r.quantity(Quantity("lambda_m_wb", "λm", lam_m, "Wb",
                        f"median over {len(lams)} held speeds of (vq(+I) + vq(-I))/(2ωe), "
                        f"I = {current:g} A (spread {spread * 1e3:.2f} mWb)",
                        nominal("lambda_m_wb"), truth(s, "lambda_m_wb")))
    r.quantity(Quantity("lambda_hat_wb", "λ̂m of the drive's flux estimator",
                        float(np.median(lam_hats)), "Wb",
                        "TLM_PARAM median (uses the drive's deadtime_us / vdrop_v correction)",
                        nominal("lambda_m_wb"), truth(s, "lambda_m_wb")))
    r.quantity(Quantity("lq_app_h", f"Lq apparent at |iq| = {current:g} A",
                        float(np.median(lq_apps)), "H", "-Δvd / (ωe·Δiq) at the held speeds"))
    s.identified["lambda_m_wb"] = lam_m
    r.check("λm consistent over the speeds", spread <= 0.05 * lam_m,
            f"λm per speed {', '.join(f'{x:.4f}' for x in lams)} Wb")
    r.tables.append(Table("Held speeds", [
        "speed (r/min)", "vq(+I) (V)", "vq(-I) (V)", "iq+ (A)", "iq- (A)", "λm (Wb)",
        "Lq app (mH)", "λ̂m drive +I / -I (Wb)"], rows))
