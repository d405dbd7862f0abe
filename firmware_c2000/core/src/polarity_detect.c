/* polarity_detect.c - magnet polarity at standstill (estimator-math.md section 7).
 *
 * The slope estimator gives theta modulo pi. Two tests resolve the remaining pi:
 *
 * 1. Saturation: equal volt-second pulses along +d_hat and -d_hat, each starting from zero
 *    mean current held by the current controller. The pulse that adds to the magnet flux
 *    drives the iron further into saturation and ends with the larger current rise. The
 *    comparison is made on the chord inductance of each pulse, L = delta psi_d / delta i_d,
 *    between the zero-window current (mean of its samples, no slope involved) of the period
 *    before the pulse and that of the last pulse period; delta psi_d is the exact volt-seconds
 *    of the pattern between those two instants (whole periods plus the partial ones) minus
 *    rs times the mean current. Comparing raw peaks is biased by about 1 % in a LINEAR
 *    machine: the stretched patterns leave a pattern-dependent ripple offset at the pulse
 *    start, which then decays through rs during the pulse; slope-based period-end currents
 *    carry the slope noise (several % with a 12-bit, 5 mA converter). The chord on direct
 *    sample means avoids all three.
 * 2. Motion (for linear magnetics, e.g. the plant's `ideal` profile, where both peaks are
 *    equal): with id = 0 a q current +iq gives torque 1.5 p lambda_m iq in the TRUE frame only
 *    if d_hat points to the north pole; otherwise the rotor turns backwards. The core applies
 *    +iq then -iq (accelerate, brake) and looks at the sign of the angle travelled.
 *
 * pol_method 0 runs 1 and falls back to 2 when the peak difference is below pol_ratio_min.
 */
#include "fw_internal.h"

enum {
    POL_SETTLE = 0,
    POL_REST_0,
    POL_PULSE_P,
    POL_REST_P,
    POL_PULSE_N,
    POL_REST_N,
    POL_MOTION_ACC,
    POL_MOTION_BRAKE,
    POL_MOTION_REST,
    POL_END
};

void fw_pol_start(fw_polarity_t *pol)
{
    pol->phase = POL_SETTLE;
    pol->count = 0;
    pol->peak_pos = FW_REAL(0.0);
    pol->peak_neg = FW_REAL(0.0);
    pol->l_pos = FW_REAL(0.0);
    pol->l_neg = FW_REAL(0.0);
    pol->psi_acc = FW_REAL(0.0);
    pol->theta_d = FW_REAL(0.0);
    pol->vpulse = FW_REAL(0.0);
    pol->theta_start = FW_REAL(0.0);
    pol->base = FW_REAL(0.0);
    pol->moved = FW_REAL(0.0);
    pol->method_used = 0;
    pol->flipped = 0;
    pol->result = 0;
}

/* d_hat component of an alpha-beta vector */
static real_t along(fw_cplx_t v, fw_cplx_t dhat) { return v.re * dhat.re + v.im * dhat.im; }

/* flux change along d_hat over period ticks [t0, t1) of the period just measured: pattern
 * volt-seconds, the inverter correction pro rata, minus the drop of the period-mean current */
static real_t flux_part(const fw_core_t *c, fw_cplx_t dhat, real_t t0, real_t t1)
{
    fw_cplx_t vs = fw_plan_volt_seconds(&c->plan_cur, t0, t1);
    fw_cplx_t corr = fw_csub(c->v_meas, c->plan_cur.v_applied);
    fw_cplx_t u = fw_cadd(vs, fw_cscale(fw_csub(corr, fw_cscale(c->i_avg, c->p[FW_PI_RS_OHM])),
                                        (t1 - t0) * FW_TICK_S));
    return along(u, dhat);
}

static real_t flux_step(const fw_core_t *c, fw_cplx_t dhat)
{
    return flux_part(c, dhat, FW_REAL(0.0), (real_t)FW_P_TICKS);
}

/* zero-window current along d_hat and its instant (ticks); 0 when not measured */
static int16_t anchor(const fw_core_t *c, fw_cplx_t dhat, real_t *i_d, real_t *t)
{
    if (!c->slope_ok[FW_WIN_ZERO]) {
        return 0;
    }
    *i_d = along(c->i_win[FW_WIN_ZERO], dhat);
    *t = c->slope_t[FW_WIN_ZERO];
    return 1;
}

static void next_phase(fw_polarity_t *pol, int16_t phase)
{
    pol->phase = phase;
    pol->count = 0;
}

int16_t fw_pol_step(fw_polarity_t *pol, const fw_core_t *c, const fw_adc_t *adc,
                    fw_pol_out_t *out)
{
    const real_t *p = c->p;
    int32_t n_pulse = (int32_t)p[FW_PI_POL_PULSE_PERIODS];
    int32_t n_settle = (int32_t)p[FW_PI_POL_SETTLE_PERIODS];
    /* zero-current rest under current control: ten current-loop time constants at least */
    int32_t n_rest = 2 * (int32_t)p[FW_PI_POL_PULSE_PERIODS] + 40;
    int32_t n_motion = (int32_t)(p[FW_PI_POL_MOTION_MS] * FW_REAL(1e-3) / FW_TS);
    int16_t method = (int16_t)p[FW_PI_POL_METHOD];
    fw_cplx_t dhat = fw_cexpj(pol->theta_d);

    out->kind = FW_POL_OUT_VOLTAGE;
    out->v = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    out->id = FW_REAL(0.0);
    out->iq = FW_REAL(0.0);
    out->pll_freeze = 0;
    if (pol->result != 0) {
        return pol->result;
    }
    if (n_rest > 2000) {
        n_rest = 2000;
    }
    if (n_motion < 1) {
        n_motion = 1;
    }
    pol->count++;
    (void)adc; /* the measurements come from the core's per-period results */

    switch (pol->phase) {
    case POL_SETTLE:
        /* zero current (any frame will do for a zero reference) while the PLL settles */
        out->kind = FW_POL_OUT_CURRENT;
        if (pol->count >= n_settle) {
            if (!c->pll.init || !c->est_valid) {
                if (pol->count > 4 * n_settle) {
                    pol->result = -1; /* no position estimate at standstill */
                }
                break;
            }
            pol->theta_d = fw_pll_predict(&c->pll, FW_P_TICKS + FW_H_TICKS);
            pol->vpulse = p[FW_PI_LD_H] * p[FW_PI_POL_PULSE_A] / ((real_t)n_pulse * FW_TS);
            pol->vpulse = fw_min(pol->vpulse, FW_REAL(0.9) * c->v_lim);
            if (method == 2) {
                pol->method_used = 2;
                pol->theta_start = c->pll.theta_unwrapped;
                next_phase(pol, POL_MOTION_ACC);
            } else {
                pol->method_used = 1;
                next_phase(pol, POL_REST_0);
            }
        }
        break;
    case POL_REST_0:
        out->kind = FW_POL_OUT_CURRENT;
        out->pll_freeze = 1;
        if (pol->count >= n_rest) {
            next_phase(pol, POL_PULSE_P);
        }
        break;
    case POL_PULSE_P:
    case POL_PULSE_N: {
        int16_t pos = (int16_t)(pol->phase == POL_PULSE_P);
        if (pol->count == 1) {
            /* data of the period before the pulse: base current and the flux after it */
            real_t t_a = FW_REAL(0.0);
            pol->psi_acc = FW_REAL(0.0);
            if (anchor(c, dhat, &pol->base, &t_a)) {
                pol->psi_acc = flux_part(c, dhat, t_a, (real_t)FW_P_TICKS);
            } else {
                pol->result = -1;
            }
        } else {
            pol->psi_acc += flux_step(c, dhat);
        }
        out->v = fw_cscale(dhat, pos ? pol->vpulse : -pol->vpulse);
        out->pll_freeze = 1;
        if (pol->count >= n_pulse) {
            next_phase(pol, pos ? POL_REST_P : POL_REST_N);
        }
        break;
    }
    case POL_REST_P:
        out->kind = FW_POL_OUT_CURRENT;
        out->pll_freeze = 1;
        if (pol->count == 1) { /* data of the last pulse period (one period of delay) */
            real_t i_d = FW_REAL(0.0);
            real_t t_a = FW_REAL(0.0);
            if (!anchor(c, dhat, &i_d, &t_a)) {
                pol->result = -1;
                break;
            }
            pol->psi_acc += flux_part(c, dhat, FW_REAL(0.0), t_a);
            pol->peak_pos = i_d - pol->base;
            pol->l_pos = (pol->peak_pos > FW_REAL(0.0)) ? pol->psi_acc / pol->peak_pos : FW_REAL(0.0);
        }
        if (pol->count >= n_rest) {
            next_phase(pol, POL_PULSE_N);
        }
        break;
    case POL_REST_N:
        out->kind = FW_POL_OUT_CURRENT;
        out->pll_freeze = 1;
        if (pol->count == 1) {
            real_t i_d = FW_REAL(0.0);
            real_t t_a = FW_REAL(0.0);
            if (!anchor(c, dhat, &i_d, &t_a)) {
                pol->result = -1;
                break;
            }
            pol->psi_acc += flux_part(c, dhat, FW_REAL(0.0), t_a);
            pol->peak_neg = pol->base - i_d;
            pol->l_neg = (pol->peak_neg > FW_REAL(0.0)) ? -pol->psi_acc / pol->peak_neg : FW_REAL(0.0);
        }
        if (pol->count >= n_rest) {
            real_t mean = FW_REAL(0.5) * (pol->l_pos + pol->l_neg);
            /* the magnet side saturates: smaller chord inductance */
            real_t ratio = (mean > FW_REAL(0.0)) ? (pol->l_neg - pol->l_pos) / mean : FW_REAL(0.0);
            if (fw_fabs(ratio) >= p[FW_PI_POL_RATIO_MIN]) {
                pol->flipped = (int16_t)(ratio < FW_REAL(0.0));
                pol->result = 1;
            } else if (method == 0) {
                pol->method_used = 2;
                pol->theta_start = c->pll.theta_unwrapped;
                next_phase(pol, POL_MOTION_ACC);
            } else {
                pol->result = -1;
            }
        }
        break;
    case POL_MOTION_ACC:
        out->kind = FW_POL_OUT_CURRENT;
        out->iq = p[FW_PI_POL_MOTION_IQ_A];
        if (pol->count >= n_motion) {
            next_phase(pol, POL_MOTION_BRAKE);
        }
        break;
    case POL_MOTION_BRAKE:
        out->kind = FW_POL_OUT_CURRENT;
        out->iq = -p[FW_PI_POL_MOTION_IQ_A];
        if (pol->count >= n_motion) {
            next_phase(pol, POL_MOTION_REST);
        }
        break;
    case POL_MOTION_REST:
        out->kind = FW_POL_OUT_CURRENT;
        if (pol->count >= n_motion) {
            real_t min_move = p[FW_PI_POL_MOTION_MIN_DEG] * (FW_PI_R / FW_REAL(180.0));
            pol->moved = c->pll.theta_unwrapped - pol->theta_start;
            if (fw_fabs(pol->moved) >= min_move) {
                pol->flipped = (int16_t)(pol->moved < FW_REAL(0.0));
                pol->result = 1;
            } else {
                pol->result = -1;
            }
        }
        break;
    default:
        pol->result = -1;
        break;
    }
    return pol->result;
}
