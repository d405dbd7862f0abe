/* current_refs.c - current references: MTPA (paper eq. 50), flux weakening (eq. 53), the current
 * circle and the voltage ellipse. Torque is eq. 10: Te = 3P/4 [(Ld - Lq) id iq + lambda iq]
 * with P poles, i.e. 1.5 * pole_pairs * (...).
 * All inductances here are APPARENT (psi/i) ones (docs/estimator.md §4.7).
 */
#include "fw_internal.h"

real_t fw_refs_mtpa_id(real_t iq, real_t ld, real_t lq, real_t lambda)
{
    /* eq. 50: id = -lambda/(2(Ld-Lq)) - sqrt(lambda^2/(4(Ld-Lq)^2) + iq^2); with
     * a = lambda/(2(Lq-Ld)) > 0 this is a - sqrt(a^2 + iq^2) = -iq^2/(a + sqrt(a^2 + iq^2)),
     * the second form free of cancellation at small iq. */
    real_t dl = lq - ld;
    real_t a;
    if (!(dl > FW_REAL(1e-7))) {
        return FW_REAL(0.0); /* no saliency: id = 0 is MTPA */
    }
    a = lambda / (FW_REAL(2.0) * dl);
    return -(iq * iq) / (a + fw_sqrt(a * a + iq * iq));
}

real_t fw_refs_mtpa_id_on_circle(real_t i_max, real_t ld, real_t lq, real_t lambda)
{
    /* MTPA at |i| = I: 2 dL id^2 - lambda id - dL I^2 = 0 (dL = Lq - Ld), negative root */
    real_t dl = lq - ld;
    if (!(dl > FW_REAL(1e-7))) {
        return FW_REAL(0.0);
    }
    return -FW_REAL(2.0) * dl * i_max * i_max /
           (lambda + fw_sqrt(lambda * lambda + FW_REAL(8.0) * dl * dl * i_max * i_max));
}

real_t fw_refs_fluxweak_id(real_t iq, real_t omega, real_t vmax, real_t ld, real_t lq, real_t lambda)
{
    /* eq. 53: id = (-lambda + sqrt((Vsmax/omega)^2 - (Lq iq)^2)) / Ld */
    real_t w = fw_fabs(omega);
    real_t psi_max, r;
    if (w < FW_REAL(1e-3)) {
        return FW_REAL(1e9); /* standstill: no voltage limit */
    }
    psi_max = vmax / w;
    r = psi_max * psi_max - (lq * iq) * (lq * iq);
    if (r < FW_REAL(0.0)) {
        r = FW_REAL(0.0);
    }
    return (-lambda + fw_sqrt(r)) / ld;
}

int16_t fw_refs_circle_ellipse_id(real_t i_max, real_t omega, real_t vmax, real_t ld, real_t lq,
                             real_t lambda, real_t *id)
{
    /* (Ld id + lambda)^2 + Lq^2 (I^2 - id^2) = (V/omega)^2: the more negative root is the
     * edge of the feasible arc of the current circle */
    real_t w = fw_fabs(omega);
    real_t psi2, qa, qb, qc, disc;
    if (w < FW_REAL(1e-3)) {
        return 0;
    }
    psi2 = (vmax / w) * (vmax / w);
    qa = ld * ld - lq * lq;
    qb = FW_REAL(2.0) * ld * lambda;
    qc = lambda * lambda + lq * lq * i_max * i_max - psi2;
    if (fw_fabs(qa) < FW_REAL(1e-12)) {
        if (fw_fabs(qb) < FW_REAL(1e-12)) {
            return 0;
        }
        *id = -qc / qb;
    } else {
        disc = qb * qb - FW_REAL(4.0) * qa * qc;
        if (disc < FW_REAL(0.0)) {
            return 0;
        }
        *id = (-qb + fw_sqrt(disc)) / (FW_REAL(2.0) * qa);
        if (qa > FW_REAL(0.0)) {
            *id = (-qb - fw_sqrt(disc)) / (FW_REAL(2.0) * qa);
        }
    }
    return (int16_t)(*id >= -i_max && *id <= i_max);
}

real_t fw_refs_id_for_torque(real_t iq_demand, real_t iq, real_t ld, real_t lq, real_t lambda)
{
    /* torque/(1.5 p) the MTPA point of iq_demand gives, produced at the smaller q current iq
     * by the reluctance term: lambda iq + (Ld - Lq) id iq = tau  =>  id = (tau/iq - lambda)/(Ld - Lq) */
    real_t dl = ld - lq;
    real_t tau;
    if (!(dl < FW_REAL(-1e-7)) || !(fw_fabs(iq) > FW_REAL(1e-3))) {
        return FW_REAL(0.0);
    }
    tau = (lambda + dl * fw_refs_mtpa_id(iq_demand, ld, lq, lambda)) * iq_demand;
    return fw_min((tau / iq - lambda) / dl, FW_REAL(0.0));
}

real_t fw_refs_torque(real_t id, real_t iq, real_t ld, real_t lq, real_t lambda, real_t pole_pairs)
{
    return FW_REAL(1.5) * pole_pairs * (lambda * iq + (ld - lq) * id * iq);
}

int16_t fw_refs_select(int16_t mode, real_t iq_demand, real_t omega, real_t vmax, real_t i_max,
                        real_t ld, real_t lq, real_t lambda, real_t did_fb, real_t *id_ref,
                        real_t *iq_ref)
{
    real_t iq = fw_clamp(iq_demand, -i_max, i_max);
    real_t sgn = (iq < FW_REAL(0.0)) ? FW_REAL(-1.0) : FW_REAL(1.0);
    real_t id, id_fw;
    int16_t fw = 0;

    if (mode == FW_FWMODE_ID_ZERO) {
        *id_ref = FW_REAL(0.0);
        *iq_ref = iq;
        return 0;
    }
    id = fw_refs_mtpa_id(iq, ld, lq, lambda);
    if (id * id + iq * iq > i_max * i_max) {
        /* MTPA point on the current circle */
        id = fw_refs_mtpa_id_on_circle(i_max, ld, lq, lambda);
        iq = sgn * fw_sqrt(i_max * i_max - id * id);
    }
    /* The voltage feedback's d current moves the ellipse's centre: eq. 53 plus did_fb is the
     * ellipse (Ld id + lambda - Ld did_fb)^2 + (Lq iq)^2 = (V/omega)^2. Both limits then
     * meet on that same ellipse; adding did_fb to the intersection of the unshifted one
     * instead made the two branches disagree where they meet, and the 1 kHz references
     * alternated between them at the current and voltage limit (measured at 2550 r/min,
     * 1.5 N*m: a 3 ms cycle of 0.4 A in id_ref, iq 0.6 A short of its reference). */
    real_t lambda_fb = lambda - ld * did_fb;
    id_fw = fw_refs_fluxweak_id(iq, omega, vmax, ld, lq, lambda_fb);
    if (id_fw < id) {
        fw = 1;
        id = id_fw;
        if (id * id + iq * iq > i_max * i_max) {
            /* both limits: intersection of the current circle and the voltage ellipse */
            real_t idx;
            if (fw_refs_circle_ellipse_id(i_max, omega, vmax, ld, lq, lambda_fb, &idx)) {
                id = idx;
            }
            id = fw_max(id, -i_max);
            iq = sgn * fw_sqrt(fw_max(i_max * i_max - id * id, FW_REAL(0.0)));
        }
    }
    *id_ref = id;
    *iq_ref = iq;
    return fw;
}
