/* flux_estimator.c - stator flux from the voltage model and the PM flux lambda_m
 * (docs/estimator.md §4.6).
 *
 * Per period the core knows the exact integral of v - rs*i over the period: the realised
 * volt-seconds of the pattern (corrected for dead time and device drop) minus rs times the
 * period-mean current. A pure integrator drifts with any offset, so a low-pass filter with a
 * corner omega_c = ratio*|omega| is used instead. Its gain and phase error at the fundamental
 * are removed exactly: for a flux rotating as z^k (z = exp(j omega Ts)) the trapezoidal filter
 * psi_f(k+1) = a psi_f(k) + b u(k) settles at psi_f = psi * b (z - 1)/(z - a), so
 * psi = psi_f * (z - a)/(b (z - 1)). A DC offset decays with omega_c.
 *
 * lambda_m is NOT |psi| (the paper's eqs. 42-48 use Lq*Di, the active flux, whose magnitude is
 * lambda_m + (Ld - Lq) id): in the estimated rotor frame psi_d = Ld_app id + lambda_m, so
 * lambda_m = psi_d - Ld_app id. A negative lambda_d means the estimated frame points to the
 * south pole: the polarity-loss detector uses it.
 */
#include "fw_internal.h"

void fw_flux_reset(fw_flux_t *f, real_t lambda_nom)
{
    f->psi_f = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    f->psi = f->psi_f;
    f->lambda_f = lambda_nom;
    f->lambda_inst = lambda_nom;
    f->lq_app_flux = FW_REAL(0.0);
    f->active = 0;
    f->neg_count = 0;
    f->n_valid = 0;
    f->settle_tc = FW_REAL(0.0);
}

/* The low-pass estimate forgets its start (zero, or the flux of another speed) as
 * exp(-settle_tc): before a few time constants its angle is not the rotor's. Measured on the
 * paper profile, 2 N*m load step at 1 r/min: the speed swept through 300 r/min backwards within
 * 12 ms, the hand-over took the unsettled angle (66 deg off) and the drive tripped. Hence
 * fw_flux_settled (inline in fw_internal.h): active for settle_tc time constants. */

void fw_flux_seed(fw_flux_t *f, fw_cplx_t psi, real_t omega, real_t ratio, real_t omega_min,
                  real_t settle_tc)
{
    /* the filter state whose compensated output (fw_flux_update) is psi at this speed:
     * psi_f = psi b (z - 1) / (z - a) */
    real_t w_abs = fw_max(fw_fabs(omega), omega_min);
    real_t wc_half = FW_REAL(0.5) * ratio * w_abs * FW_TS;
    real_t a = (FW_REAL(1.0) - wc_half) / (FW_REAL(1.0) + wc_half);
    real_t b = FW_REAL(1.0) / (FW_REAL(1.0) + wc_half);
    fw_cplx_t z = fw_cexpj(omega * FW_TS);
    fw_cplx_t num = fw_cscale(fw_c(z.re - FW_REAL(1.0), z.im), b);
    fw_cplx_t den = fw_c(z.re - a, z.im);
    real_t den2 = fw_cabs2(den);
    if (!(den2 > FW_REAL(0.0))) {
        return;
    }
    f->psi_f = fw_cmul(psi, fw_cscale(fw_cmul(num, fw_cconj(den)), FW_REAL(1.0) / den2));
    f->psi = psi;
    f->active = 1;
    f->neg_count = 0;
    f->settle_tc = settle_tc;
}

int16_t fw_flux_update(fw_flux_t *f, fw_cplx_t u, real_t omega, real_t omega_gate, real_t ratio,
                       real_t omega_min, real_t omega_learn_min, real_t theta_end,
                       fw_cplx_t i_end, real_t ld_app, real_t lambda_nom, real_t alpha)
{
    real_t w_abs = fw_max(fw_fabs(omega), omega_min);
    real_t wc_half = FW_REAL(0.5) * ratio * w_abs * FW_TS;
    real_t a = (FW_REAL(1.0) - wc_half) / (FW_REAL(1.0) + wc_half);
    real_t b = FW_REAL(1.0) / (FW_REAL(1.0) + wc_half);
    fw_cplx_t z, num, den, comp, rot, psi_dq, i_dq;
    real_t den2, lam;
    int16_t learn = (int16_t)(fw_fabs(omega_gate) >= omega_learn_min);

    if (fw_fabs(omega_gate) < omega_min || fw_fabs(omega) < FW_REAL(0.5) * omega_min) {
        /* below the gate the filter does not integrate: near standstill it would only hold
         * the voltage errors over its corner (0.1 Wb from 0.4 V on harsh, half the magnet),
         * and started from zero the estimate's error is the rotating flux's own transient,
         * at most |psi| exp(-settle_tc) */
        f->psi_f = fw_c(FW_REAL(0.0), FW_REAL(0.0));
        f->active = 0;
        f->neg_count = 0;
        f->settle_tc = FW_REAL(0.0);
        return 0;
    }
    f->psi_f = fw_cadd(fw_cscale(f->psi_f, a), fw_cscale(u, b));
    f->settle_tc = fw_min(f->settle_tc + FW_REAL(2.0) * wc_half, FW_REAL(1000.0));
    z = fw_cexpj(omega * FW_TS);
    num = fw_c(z.re - a, z.im);
    den = fw_cscale(fw_c(z.re - FW_REAL(1.0), z.im), b);
    den2 = fw_cabs2(den);
    if (!(den2 > FW_REAL(0.0))) {
        return 0;
    }
    comp = fw_cscale(fw_cmul(num, fw_cconj(den)), FW_REAL(1.0) / den2);
    f->psi = fw_cmul(f->psi_f, comp);
    rot = fw_cexpj(-theta_end);
    psi_dq = fw_cmul(f->psi, rot);
    i_dq = fw_cmul(i_end, rot);
    lam = psi_dq.re - ld_app * i_dq.re;
    f->lambda_inst = lam;
    f->active = 1;
    /* a frame turned by pi sees about -lambda_m; about 0 says only that the rotor does not turn
     * as fast as the tracker says. That is what a held rotor gives when a torque step makes the
     * tracker's prediction run off (down to -0.023 Wb measured on harsh), and counting any
     * negative value turned a correct frame there. The verdict's range mirrors the learning's. */
    if (lam < -FW_REAL(0.5) * lambda_nom) {
        if (f->neg_count < 30000) {
            f->neg_count++;
        }
    } else {
        f->neg_count = 0;
        if (learn && lam > FW_REAL(0.5) * lambda_nom && lam < FW_REAL(1.5) * lambda_nom) {
            f->lambda_f += alpha * (lam - f->lambda_f); /* range-checked before filtering */
            if (f->n_valid < 1000000) {
                f->n_valid++;
            }
        }
    }
    if (learn && fw_fabs(i_dq.im) > FW_REAL(0.3)) {
        f->lq_app_flux = psi_dq.im / i_dq.im;
    }
    return 1;
}
