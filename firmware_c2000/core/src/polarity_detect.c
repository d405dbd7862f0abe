/* polarity_detect.c - magnet polarity at standstill (docs/estimator.md §7).
 *
 * The slope estimator gives theta modulo pi. Two tests resolve the remaining pi:
 *
 * 1. Saturation (incremental inductance under a d bias): the current controller holds
 *    id = +pol_pulse_a and -pol_pulse_a along d_hat in turn (pairs of holds, ramps of
 *    pol_pulse_periods between them), and in the last pol_bias_periods periods of each hold
 *    the core takes the d-axis inverse incremental inductance the slope estimator measured,
 *    Gamma_d = Gamma0 + Re(g exp(-j 2 theta_hat)) = 1/Ld_inc. The bias that adds to the
 *    magnet flux drives the
 *    iron further into saturation: smaller Ld_inc (paper profile: 14.35 mH at +3 A, 15.16 mH
 *    at -3 A). The slopes are measured INSIDE switching states and differenced, so the
 *    volt-second errors of the inverter (dead time at the edges, device drop; both depend on
 *    the pattern layout and on the current signs) do not enter.
 *    The PLL keeps tracking during the test, so the current stays on the estimated d axis and
 *    makes no torque. (With the angle held, a current towards the south pole is an unstable
 *    equilibrium of a free shaft, and Ld < Lq makes the reluctance torque turn the q axis
 *    towards the current: the rotor moved 39 deg (electrical) in 80 ms on the paper profile.)
 *    An earlier version compared the chord inductance of two open-loop volt-second pulses
 *    along +-d_hat. The dead-time error of such a pulse depends on the vectors it uses: with
 *    d_hat on an even vector (V2, V4, V6) the +d pulse lost 12.0 % of its volt-seconds and
 *    the -d pulse 9.9 % (odd vectors the other way round), a 2 % bias against a chord
 *    contrast of 2 %: it picked the south pole at 60, 180 and 300 deg.
 *    Decision after each pair: ratio = (Ld(-) - Ld(+)) / mean, its standard error from the
 *    scatter of the per-period values; conclusive when |ratio| >= pol_ratio_min and
 *    >= POL_K_SIGMA standard errors. Another pair is averaged while that is still possible,
 *    up to POL_MAX_PAIRS; then (or when |ratio| is below pol_ratio_min with confidence, as in
 *    a linear machine) the test is inconclusive: the motion check instead of a guess.
 * 2. Motion (for linear magnetics, e.g. the plant's `ideal` profile, where both inductances
 *    are equal): with id = 0 a q current +iq gives torque 1.5 p lambda_m iq in the TRUE frame
 *    only if d_hat points to the north pole; otherwise the rotor turns backwards. The core
 *    applies +iq then -iq (accelerate, brake) and looks at the sign of the angle travelled.
 *
 * 3. Back-EMF (any profile, whenever the rotor turns: an overhauling load at enable, a shaft
 *    still turning, the motion check itself): the flux linkage of the magnet is
 *    lambda_m exp(j theta) in the true frame. Over a window the volt-seconds less rs i less
 *    the change of the current's own flux L(theta_hat) i (a function of 2 theta: the same in
 *    either frame) is the change of the magnet's flux, lambda_m (exp(j theta1) - exp(j theta0))
 *    when theta_hat points to the north pole and the negative of it when it points south.
 *    Projected on the chord of the tracked angle it gives +-lambda_m; once the chord spans
 *    pol_emf_min_deg and the projection lies within half of +-lambda_m it decides, whichever
 *    test is running. Voltage-model errors integrate as dv t against lambda_m times the angle
 *    turned; the errors along the current (rs, dead time, the saturation test's d current)
 *    are at right angles to the chord while the angle is small.
 *
 * 4. Catch (a shaft turning fast at the enable): from the third period with the gates on the
 *    back-EMF vector of each period comes from its volt-seconds, e = v - rs i less the change
 *    of the current's own flux L(theta) i (saliency axes on a straight line through the raw
 *    angles, turning at |e| / lambda_m one way and the other: two measurements), and is fed
 *    forward into the next period so that the current stays small (with zero volts it rose
 *    by 0.9 A per period at 3000 r/min: 136 V over 15 mH). It turns at the rotor's speed,
 *    omega Ts per period, and points along j omega lambda_m exp(j theta): its angle less
 *    sign(omega) pi/2 is the magnet's angle, polarity included. Decided once the raw angles
 *    show which way the rotor turns, the measurement with the axes turning that way turns the
 *    same way clear of its noise, |e| / lambda_m agrees with that turn, and the turn gives the
 *    speed within 2 % (or 30 vectors have passed, or the back-EMF exceeds the voltage the
 *    start-up may apply: then |e| / lambda_m); given up after POL_CATCH_MAX periods (a slow
 *    shaft: the tests above decide).
 *
 * pol_method 0 runs 1 and falls back to 2 when 1 is inconclusive; 3 and 4 decide in any
 * method.
 */
#include "fw_internal.h"

enum {
    POL_SETTLE = 0,
    POL_BIAS_P = 1, /* ramp to +id, hold, average */
    POL_BIAS_N = 2, /* ramp to -id, hold, average; after it: decide or one more pair */
    POL_REST = 3,   /* back to zero current, decision */
    POL_MOTION_ACC = 4,
    POL_MOTION_BRAKE = 5,
    POL_MOTION_REST = 6
};

/* periods after a ramp before the averaging starts (current loop: 400 Hz, tau = 4 periods) */
#define POL_SKIP 10
/* standard errors the inductance difference must exceed for a decision */
#define POL_K_SIGMA FW_REAL(4.0)
/* +/- pairs of holds at most (a noisy measurement averages longer before it gives up) */
#define POL_MAX_PAIRS 4
/* back-EMF test: the raw angle's slope against the back-EMF's angle is +1 on the north pole,
 * -1 on the south pole; decided within POL_EMF_TOL of one of them with a standard error
 * below POL_EMF_SE_MAX (then the other lies 6 standard errors away), from POL_EMF_MIN_N
 * raw estimates on */
#define POL_EMF_TOL FW_REAL(0.5)
#define POL_EMF_SE_MAX FW_REAL(0.25)
#define POL_EMF_MIN_N 10
/* catch: the vector's angle must turn at a slope POL_CATCH_K_SIGMA standard errors clear of
 * zero over at least POL_CATCH_MIN_N vectors and agree with |e| / lambda_m within
 * POL_CATCH_AGREE of it, at most POL_CATCH_MAX periods (the vector scatters by ~0.2 rad per
 * period on harsh at 2000 r/min: the dead time of a near-zero current) */
#define POL_CATCH_K_SIGMA FW_REAL(5.0)
#define POL_CATCH_MIN_N 6
#define POL_CATCH_AGREE FW_REAL(0.5)
#define POL_CATCH_MAX 60
/* ... the speed from that turn once its standard error is below POL_CATCH_TURN_REL of it;
 * from |e| / lambda_m (which carries the errors of lambda_m and of the current's modelled
 * flux: -3..-6 % on harsh, +6..+9 % at 3000 r/min on paper) only after POL_CATCH_MAG_N
 * vectors or where the back-EMF exceeds the voltage the start-up may apply (the current
 * then grows while the catch waits) */
#define POL_CATCH_TURN_REL FW_REAL(0.02)
#define POL_CATCH_MAG_N 30
/* ... and the raw angles must turn the same way, POL_CATCH_RAW_K_SIGMA standard errors clear
 * of zero over at least POL_CATCH_RAW_MIN_N of them */
#define POL_CATCH_RAW_K_SIGMA FW_REAL(3.0)
#define POL_CATCH_RAW_MIN_N 3
/* ... and fed forward where its mean magnitude exceeds POL_CATCH_FF_MIN_V or POL_CATCH_FF_K
 * times its scatter per component (a vector of noise alone has a mean magnitude of 1.25 of
 * it; on harsh at standstill the vectors scatter by tens of volts, the dead time of a
 * near-zero current, and fed forward they shook the start-up) */
#define POL_CATCH_FF_MIN_V FW_REAL(60.0)
#define POL_CATCH_FF_K FW_REAL(3.0)
/* ... and never below POL_CATCH_FF_FLOOR_V: the voltage model's own errors at standstill (rs,
 * dead time under the saturation test's 3 A) are a few volts, quiet enough for the test
 * above (~250 r/min of back-EMF on the paper machine) */
#define POL_CATCH_FF_FLOOR_V FW_REAL(12.0)
/* periods of tracking before the window starts (the tracker's convergence, 60 Hz: a reset
 * takes one raw estimate, 10-20 deg off on harsh at standstill) */
#define POL_EMF_WAIT 20
/* the polarity watch's straight line through the q back-EMF: weights decaying by this per
 * period (an effective memory of ~20 periods, 2 ms: at 2 N*m the runaway gains 150 r/min per
 * ms, and the line must give its speed when the watch decides) */
#define POL_WATCH_EW_BETA FW_REAL(0.95)
/* ... and the current magnitude a south verdict needs, A: near zero current the phase
 * currents cross zero within the period and the dead time's voltage is unknown by volts,
 * against a slow shaft's back-EMF of about one (a window at 0.13 A, 27 r/min on paper turned a
 * correct frame round; the runaway of a frame turned without load is first seen at 0.3-0.5 A:
 * with 0.5 it was decided 7 ms and 58 r/min later) */
#define POL_WATCH_I_MIN FW_REAL(0.3)

static void emf_window_clear(fw_emf_window_t *w)
{
    w->on = 0;
    w->psi_i = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    w->phi = w->phi_min = w->phi_max = w->phi_tol = FW_REAL(0.0);
    w->raw = w->raw0 = w->raw_prev = FW_REAL(0.0);
    w->m = 0;
    w->sp = w->spp = w->sr = w->spr = w->srr = FW_REAL(0.0);
    w->s0 = w->s1 = w->s2 = w->sy = w->sny = FW_REAL(0.0);
    w->slope = FW_REAL(0.0);
    w->slope_se = FW_REAL(0.0);
}

void fw_polarity_start(fw_polarity_t *pol)
{
    int16_t h;
    pol->phase = POL_SETTLE;
    pol->count = 0;
    pol->periods = 0;
    pol->id_pos = FW_REAL(0.0);
    pol->id_neg = FW_REAL(0.0);
    pol->l_pos = FW_REAL(0.0);
    pol->l_neg = FW_REAL(0.0);
    pol->ratio = FW_REAL(0.0);
    pol->ratio_sigma = FW_REAL(0.0);
    pol->g_ref = FW_REAL(0.0);
    pol->s1[0] = pol->s1[1] = FW_REAL(0.0);
    pol->s2[0] = pol->s2[1] = FW_REAL(0.0);
    pol->si[0] = pol->si[1] = FW_REAL(0.0);
    pol->n[0] = pol->n[1] = 0;
    pol->pairs = 0;
    pol->emf_wait = 0;
    emf_window_clear(&pol->emf);
    pol->catch_on = 1;
    /* the period the enable sees has the gates off, and the first one with them on starts
     * from a current measured in the off period (pulses through the diodes at high speed):
     * neither counts */
    pol->catch_n = -2;
    pol->catch_k = 0;
    pol->catch_rn = 0;
    pol->catch_rlast = FW_REAL(0.0);
    pol->catch_rj = pol->catch_rjj = pol->catch_rt = pol->catch_rjt = pol->catch_rtt =
        FW_REAL(0.0);
    pol->catch_wax = FW_REAL(0.0);
    pol->catch_i = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    for (h = 0; h < 2; h++) {
        pol->catch_h[h].e = pol->catch_h[h].e2 = pol->catch_i;
        pol->catch_h[h].d2 = pol->catch_h[h].ang = pol->catch_h[h].mag = FW_REAL(0.0);
        pol->catch_h[h].s1 = pol->catch_h[h].s2 = pol->catch_h[h].sp = pol->catch_h[h].skp =
            pol->catch_h[h].spp = FW_REAL(0.0);
    }
    pol->catch_w = FW_REAL(0.0);
    pol->catch_omega = FW_REAL(0.0);
    pol->catch_theta = FW_REAL(0.0);
    pol->theta_start = FW_REAL(0.0);
    pol->moved = FW_REAL(0.0);
    pol->method_used = 0;
    pol->flipped = 0;
    pol->result = 0;
}

static void next_phase(fw_polarity_t *pol, int16_t phase)
{
    pol->phase = phase;
    pol->count = 0;
}

static void start_motion(fw_polarity_t *pol, const fw_core_t *c)
{
    pol->method_used = FW_POL_METHOD_MOTION;
    pol->theta_start = c->trk.theta_unwrapped;
    next_phase(pol, POL_MOTION_ACC);
}

/* one period's estimate: deviation of 1/Ld_inc (two-vector estimates only) from g_ref */
static void accumulate(fw_polarity_t *pol, const fw_core_t *c, int16_t neg)
{
    real_t x;
    if (!c->est.ok || c->est.n_active != 2) {
        return;
    }
    x = c->est.gamma0 + fw_paramest_gamma1_at(&c->est, c->theta_hat) - pol->g_ref;
    pol->s1[neg] += x;
    pol->s2[neg] += x * x;
    pol->si[neg] += c->id;
    pol->n[neg]++;
}

/* mean 1/Ld_inc of one sign and the variance of that mean; 0 when too few were usable */
static int16_t sign_mean(const fw_polarity_t *pol, int16_t neg, int32_t n_planned, real_t *g,
                         real_t *var_mean)
{
    int32_t n = pol->n[neg];
    real_t m;
    real_t var;
    if (n < 2 || 2 * n < n_planned) { /* most estimates rejected: no result */
        return 0;
    }
    m = pol->s1[neg] / (real_t)n;
    var = fw_max(pol->s2[neg] / (real_t)n - m * m, FW_REAL(0.0)) * (real_t)n / (real_t)(n - 1);
    *g = pol->g_ref + m;
    *var_mean = var / (real_t)n;
    return (int16_t)(*g > FW_REAL(0.0));
}

/* both averages done: inductances, ratio and its standard error; 0 when unusable */
static int16_t evaluate(fw_polarity_t *pol, int32_t n_meas)
{
    real_t gp = FW_REAL(0.0);
    real_t gn = FW_REAL(0.0);
    real_t vp = FW_REAL(0.0);
    real_t vn = FW_REAL(0.0);
    real_t mean_g;
    if (!sign_mean(pol, 0, n_meas, &gp, &vp) || !sign_mean(pol, 1, n_meas, &gn, &vn)) {
        return 0;
    }
    pol->l_pos = FW_REAL(1.0) / gp;
    pol->l_neg = FW_REAL(1.0) / gn;
    pol->id_pos = pol->si[0] / (real_t)pol->n[0];
    pol->id_neg = pol->si[1] / (real_t)pol->n[1];
    /* (Ln - Lp) / ((Ln + Lp)/2) = (gp - gn) / ((gp + gn)/2) */
    mean_g = FW_REAL(0.5) * (gp + gn);
    pol->ratio = (gp - gn) / mean_g;
    pol->ratio_sigma = fw_sqrt(vp + vn) / mean_g;
    return 1;
}

/* after a +d/-d pair: 1 decided, -1 inconclusive for good (the difference is below
 * pol_ratio_min with confidence, or the estimates are unusable), 0 average one more pair */
static int16_t verdict(fw_polarity_t *pol, const real_t *p)
{
    int32_t n_planned = pol->pairs * (int32_t)p[FW_IDX_POL_BIAS_PERIODS];
    real_t a;
    real_t k_sigma;
    if (!evaluate(pol, n_planned)) {
        return -1;
    }
    a = fw_fabs(pol->ratio);
    k_sigma = POL_K_SIGMA * pol->ratio_sigma;
    if (a >= p[FW_IDX_POL_RATIO_MIN] && a >= k_sigma) {
        return 1;
    }
    if (a + k_sigma < p[FW_IDX_POL_RATIO_MIN] || pol->pairs >= POL_MAX_PAIRS) {
        return -1;
    }
    return 0;
}

/* the flux of current i in the frame whose d axis is u = exp(j theta): Ld along u, Lq across */
static fw_cplx_t current_flux(fw_cplx_t u, fw_cplx_t i, real_t ld, real_t lq)
{
    fw_cplx_t idq = fw_cmul(i, fw_cconj(u));
    return fw_cmul(u, fw_c(ld * idq.re, lq * idq.im));
}

/* a window from this period on (its sums empty; the caller sets the current's flux) */
static void emf_window_open(fw_emf_window_t *w)
{
    emf_window_clear(w);
    w->on = 1;
}

/* this period's magnet flux change across the tracked d axis at mid-period: the q back-EMF,
 * lambda_m omega in a frame on the north pole, its negative on the south pole. psi_i: the
 * current's own flux at the end of the last period, replaced by psi_i1, this period's. */
static real_t emf_q(fw_cplx_t *psi_i, fw_cplx_t psi_i1, const fw_core_t *c)
{
    fw_cplx_t du = fw_cscale(fw_csub(c->v_meas, fw_cscale(c->i_avg, c->p[FW_IDX_RS_OHM])), FW_TS);
    du = fw_csub(du, fw_csub(psi_i1, *psi_i));
    *psi_i = psi_i1;
    return fw_cmul(du, fw_cexpj(-fw_tracker_predict(&c->trk, FW_H_TICKS))).im / FW_TS;
}

/* the current's own flux at the end of this period, in the tracked frame */
static fw_cplx_t emf_current_flux(const fw_core_t *c, real_t ld, real_t lq)
{
    fw_cplx_t u1 = fw_cexpj(fw_tracker_predict(&c->trk, FW_P_TICKS));
    return current_flux(u1, c->i_end, ld, lq);
}

/* one period's q back-EMF into a window (test 3 above): 1 the frame points to the north
 * pole, -1 to the south pole, 0 not decided yet. steps_mod_pi: the raw angle continued by its
 * steps modulo pi rather than on the tracker's branch. */
static int16_t emf_add(fw_emf_window_t *w, const fw_core_t *c, real_t e_q, real_t span_min,
                       int16_t steps_mod_pi)
{
    const real_t *p = c->p;
    real_t n, s_pp, s_pr, s_rr, slope, rss, se;
    /* its straight line over the window's periods (the shaft's speed and acceleration) */
    w->s0 += FW_REAL(1.0);
    n = w->s0;
    w->s1 += n;
    w->s2 += n * n;
    w->sy += e_q;
    w->sny += n * e_q;
    /* the angle it says the rotor has turned, with the frame's sign: +-(theta - theta0) */
    w->phi += e_q * FW_TS / p[FW_IDX_LAMBDA_M_WB];
    w->phi_min = fw_min(w->phi_min, w->phi);
    w->phi_max = fw_max(w->phi_max, w->phi);
    if (!c->est.ok) {
        return 0;
    }
    /* the raw slope angle against it, on the branch the tracker chose (its prediction plus
     * the innovation; differences of raw estimates wrapped by pi slipped by pi on harsh,
     * where one scatters by up to 35 deg at zero current), relative to the window start */
    {
        real_t raw_u = c->trk.theta_unwrapped + (FW_REAL(1.0) - c->trk.l1) * c->trk.last_err;
        if (w->m == 0) {
            w->raw0 = raw_u;
            w->raw_prev = raw_u;
        }
        if (steps_mod_pi) {
            /* continued by its steps modulo pi: the branch may change within the window (a
             * frame turned round, or the tracker's branch slipping), the rotor cannot turn by
             * 90 electrical degrees within a period below pol_loss_min_rpm */
            w->raw += FW_REAL(0.5) * fw_wrap_pi(FW_REAL(2.0) * (raw_u - w->raw_prev));
            w->raw_prev = raw_u;
        } else {
            w->raw = raw_u - w->raw0;
        }
    }
    w->m++;
    w->sp += w->phi;
    w->spp += w->phi * w->phi;
    w->sr += w->raw;
    w->spr += w->phi * w->raw;
    w->srr += w->raw * w->raw;
    if (w->m < POL_EMF_MIN_N || w->phi_max - w->phi_min < span_min) {
        return 0;
    }
    n = (real_t)w->m;
    s_pp = w->spp - w->sp * w->sp / n;
    s_pr = w->spr - w->sp * w->sr / n;
    s_rr = w->srr - w->sr * w->sr / n;
    if (!(s_pp > FW_REAL(0.0))) {
        return 0;
    }
    slope = s_pr / s_pp;
    rss = fw_max(s_rr - slope * s_pr, FW_REAL(0.0));
    se = fw_sqrt(rss / ((n - FW_REAL(2.0)) * s_pp));
    w->slope = slope;
    w->slope_se = se;
    if (se > POL_EMF_SE_MAX) {
        return 0;
    }
    if (fw_fabs(slope - FW_REAL(1.0)) < POL_EMF_TOL) {
        return 1;
    }
    if (fw_fabs(slope + FW_REAL(1.0)) < POL_EMF_TOL) {
        return -1;
    }
    return 0;
}

/* the back-EMF test of the start-up: one window from the first period on */
static int16_t emf_step(fw_emf_window_t *w, const fw_core_t *c, real_t span_min)
{
    const real_t *p = c->p;
    fw_cplx_t psi_i1 = emf_current_flux(c, p[FW_IDX_LD_H], p[FW_IDX_LQ_H]);
    if (!w->on) {
        emf_window_open(w);
        w->psi_i = psi_i1;
        return 0;
    }
    return emf_add(w, c, emf_q(&w->psi_i, psi_i1, c), span_min, 0);
}

/* The polarity watch in RUN: the back-EMF test of the start-up, run while the speed is
 * below pol_loss_min_rpm (above it the flux estimator's lambda_d watches). A frame turned
 * round near standstill turns the speed loop's torque round too, and the shaft runs away
 * backwards; the saliency the slopes measure cannot tell (it repeats every pi), but the back-
 * EMF of that motion points the other way than the raw angle moves. Two windows of
 * pol_watch_window_ms, the second started half a window later, each restarted when it ends
 * or decides: a window's voltage-model errors (volts, against the back-EMF's 2.7 V at
 * 60 r/min on the paper machine) integrate only over its length, and a runaway starting
 * anywhere is inside one window's first half. Windows start only below
 * pol_loss_settled_min_rpm, where the flux estimator does not watch (a window runs on while a
 * runaway passes it): in steady running at 250 r/min, 2 N*m on harsh, where the raw angle
 * scatters by tens of degrees per period, a window turned a correct frame round. */
void fw_polarity_watch_reset(fw_polarity_watch_t *wt, uint16_t flips)
{
    int16_t h;
    for (h = 0; h < 2; h++) {
        emf_window_clear(&wt->win[h]);
        wt->age[h] = 0;
    }
    wt->started = 0;
    wt->flips_seen = flips;
    wt->q_on = 0;
    wt->ew_s0 = wt->ew_s1 = wt->ew_s2 = wt->ew_sy = wt->ew_sty = FW_REAL(0.0);
}

int16_t fw_polarity_watch_step(fw_polarity_watch_t *wt, const fw_core_t *c)
{
    const real_t *p = c->p;
    int32_t len = (int32_t)(p[FW_IDX_POL_WATCH_WINDOW_MS] * (FW_REAL(1e-3) / FW_TS));
    real_t span_min = p[FW_IDX_POL_WATCH_MIN_DEG] * (FW_M_PI / FW_REAL(180.0));
    fw_cplx_t psi_i1;
    real_t e_q, s0, tol_step;
    int16_t h, slow = (int16_t)(fw_fabs(c->speed_f_rpm) < p[FW_IDX_POL_LOSS_SETTLED_MIN_RPM]);
    real_t i_avg2 = fw_cabs2(c->i_avg);
    int16_t loaded = (int16_t)(i_avg2 >= POL_WATCH_I_MIN * POL_WATCH_I_MIN);
    if (len < 2 * POL_EMF_MIN_N || !(span_min > FW_REAL(0.0)) || !c->trk.init ||
        !(fw_fabs(c->speed_f_rpm) < p[FW_IDX_POL_LOSS_MIN_RPM]) ||
        c->polarity_flips != wt->flips_seen || (!slow && !wt->win[0].on && !wt->win[1].on)) {
        fw_polarity_watch_reset(wt, c->polarity_flips);
        return 0;
    }
    psi_i1 = emf_current_flux(c, c->ld_use, c->lq_use);
    if (!wt->q_on) {
        wt->q_on = 1;
        wt->psi_i = psi_i1;
        return 0;
    }
    e_q = emf_q(&wt->psi_i, psi_i1, c);
    /* the back-EMF's angle an rs error could make this period: the voltage model takes
     * rs_ohm, the machine's may be pol_watch_rs_tol off (harsh runs 30 % hot), and under load
     * the current is along q, so that error is all in e_q: 0.58 ohm at 3.2 A on harsh is
     * 1.8 V, the back-EMF of 40 r/min. A window at 1 r/min then integrated 5-10 deg of angle
     * the rotor never turned and, with a quiet current sensor (1-3 mA), turned a correct
     * frame round at the end of a 2 N*m load ramp. */
    tol_step = p[FW_IDX_POL_WATCH_RS_TOL] * p[FW_IDX_RS_OHM] * fw_sqrt(i_avg2) * FW_TS /
               p[FW_IDX_LAMBDA_M_WB];
    /* the q back-EMF's straight line over the last 20 periods or so (weights decaying by
     * POL_WATCH_EW_BETA per period, time 0 at this period): the shaft's speed when the watch
     * decides, which a window's own line, started before the runaway, underestimates */
    s0 = wt->ew_s0;
    wt->ew_s0 = POL_WATCH_EW_BETA * s0 + FW_REAL(1.0);
    wt->ew_s2 = POL_WATCH_EW_BETA * (wt->ew_s2 - FW_REAL(2.0) * wt->ew_s1 + s0);
    wt->ew_s1 = POL_WATCH_EW_BETA * (wt->ew_s1 - s0);
    wt->ew_sty = POL_WATCH_EW_BETA * (wt->ew_sty - wt->ew_sy);
    wt->ew_sy = POL_WATCH_EW_BETA * wt->ew_sy + e_q;
    for (h = 0; h < 2; h++) {
        fw_emf_window_t *w = &wt->win[h];
        int16_t r;
        if (h == 1 && !wt->started) {
            if (wt->age[0] < len / 2) {
                break;
            }
            wt->started = 1;
        }
        if (w->on && wt->age[h] >= len) {
            emf_window_clear(w);
            wt->age[h] = 0;
        }
        if (!w->on) {
            if (slow) {
                emf_window_open(w);
                wt->age[h] = 1;
            }
            continue;
        }
        wt->age[h]++;
        w->phi_tol += tol_step;
        r = emf_add(w, c, e_q, span_min, 1);
        if (r < 0 && !(fw_fabs(w->phi) > w->phi_tol)) {
            /* the back-EMF has not yet turned further than the rs error could: no verdict yet,
             * the window runs on (a runaway's angle grows with t^2, the error's with t) */
            r = 0;
        }
        if (r < 0 && !loaded) {
            /* near zero current the dead time's voltage is unknown by volts while a slow
             * shaft's back-EMF is one (27 r/min: 1.2 V); a turned frame with no current
             * turns no torque round either: no verdict, the window restarts */
            r = 0;
            emf_window_clear(w);
            wt->age[h] = 0;
        }
        if (r < 0) {
            return -1; /* counted by the caller's polarity_flips */
        }
        if (r > 0) {
            if (wt->decided_north < 65535u) {
                wt->decided_north++;
            }
            emf_window_clear(w);
            wt->age[h] = 0;
        }
    }
    return 0;
}

int16_t fw_polarity_watch_motion(const fw_polarity_watch_t *wt, real_t lambda_m, real_t *omega_now)
{
    real_t det = wt->ew_s0 * wt->ew_s2 - wt->ew_s1 * wt->ew_s1;
    real_t b0, b1;
    if (wt->ew_s0 < FW_REAL(POL_EMF_MIN_N) || !(det > FW_REAL(0.0))) {
        return 0;
    }
    b1 = (wt->ew_s0 * wt->ew_sty - wt->ew_s1 * wt->ew_sy) / det;
    b0 = (wt->ew_sy - b1 * wt->ew_s1) / wt->ew_s0;
    /* measured in the frame on the south pole: the speed is the negative of e_q / lambda_m;
     * b0 is this period's mean, half a period before its end */
    *omega_now = -(b0 + FW_REAL(0.5) * b1) / lambda_m;
    return 1;
}

/* The catch's raw angles: each period's (if the slopes gave one) at the period's end,
 * continued modulo pi, on a straight line against the period index. Returns the way they
 * turn, +1 or -1, once that is POL_CATCH_RAW_K_SIGMA standard errors clear of zero, else 0
 * (the rotor's direction: the slopes see the saliency, which turns with the rotor; only its
 * polarity is ambiguous). */
static int16_t catch_raw(fw_polarity_t *pol, const fw_core_t *c)
{
    real_t rn, k = (real_t)pol->catch_k;
    if (c->est.ok) {
        /* (its reference instant lies within the period) */
        real_t r = c->est.theta_raw +
                   pol->catch_wax * (real_t)(FW_P_TICKS - c->stamp) / (real_t)FW_P_TICKS;
        if (pol->catch_rn == 0) {
            pol->catch_rlast = r;
        } else {
            pol->catch_rlast += FW_REAL(0.5) * fw_wrap_pi(FW_REAL(2.0) * (r - pol->catch_rlast));
        }
        pol->catch_rn++;
        pol->catch_rj += k;
        pol->catch_rjj += k * k;
        pol->catch_rt += pol->catch_rlast;
        pol->catch_rjt += k * pol->catch_rlast;
        pol->catch_rtt += pol->catch_rlast * pol->catch_rlast;
    }
    rn = (real_t)pol->catch_rn;
    if (pol->catch_rn >= POL_CATCH_RAW_MIN_N) {
        real_t s_kk = pol->catch_rjj - pol->catch_rj * pol->catch_rj / rn;
        real_t s_kr = pol->catch_rjt - pol->catch_rj * pol->catch_rt / rn;
        real_t s_rr = pol->catch_rtt - pol->catch_rt * pol->catch_rt / rn;
        if (s_kk > FW_REAL(0.0)) {
            real_t sl = s_kr / s_kk;
            real_t se = fw_sqrt(fw_max(s_rr - sl * s_kr, FW_REAL(0.0)) / ((rn - FW_REAL(2.0)) * s_kk));
            if (fw_fabs(sl) > POL_CATCH_RAW_K_SIGMA * se) {
                return (sl > FW_REAL(0.0)) ? 1 : -1;
            }
        }
    }
    return 0;
}

/* One period's back-EMF vector with the saliency axes turning by dth per period: v - rs i
 * less the current's own flux change L(theta) i at the period's end less at its start
 * (either frame: L depends on 2 theta), both ends on the straight line with that slope
 * through the raw angles; with no raw angle yet, the mean inductance. Both ends from one
 * line: the flux term changes by (Lq - Ld)/2 |i| 2 dtheta where the axes jump by dtheta,
 * 420 V per rad at 2.5 A on the paper machine, so neither the raw angle's jitter from period
 * to period (1-3 deg at 3000 r/min) nor axes turned at a wrong speed may enter it. */
static fw_cplx_t catch_vector(const fw_polarity_t *pol, const fw_core_t *c, real_t dth)
{
    const real_t *p = c->p;
    real_t ld = p[FW_IDX_LD_H], lq = p[FW_IDX_LQ_H];
    fw_cplx_t di;
    if (pol->catch_rn > 0) {
        real_t rn = (real_t)pol->catch_rn;
        real_t th = (pol->catch_rt - dth * pol->catch_rj) / rn + dth * (real_t)pol->catch_k;
        fw_cplx_t u1 = fw_cexpj(th), u0 = fw_cexpj(th - dth);
        fw_cplx_t i1 = fw_cmul(c->i_end, fw_cconj(u1)), i0 = fw_cmul(pol->catch_i, fw_cconj(u0));
        di = fw_csub(fw_cmul(u1, fw_c(ld * i1.re, lq * i1.im)),
                     fw_cmul(u0, fw_c(ld * i0.re, lq * i0.im)));
    } else {
        di = fw_cscale(fw_csub(c->i_end, pol->catch_i), FW_REAL(0.5) * (ld + lq));
    }
    return fw_csub(fw_csub(c->v_meas, fw_cscale(c->i_avg, p[FW_IDX_RS_OHM])),
                   fw_cscale(di, FW_REAL(1.0) / FW_TS));
}

/* The catch (test 4 above), once per period with data: 1 when decided, 0 otherwise; the
 * feed-forward for the next period in *v_ff. The vectors are measured twice, with the
 * saliency axes turning forwards and backwards at the speed their own magnitude gives; the
 * raw angles' turn picks one (turned at the vector's own turn instead, a first few vectors
 * that seemed to turn the wrong way, the start's transient, turned the axes that way and the
 * vectors after them further: 3000 r/min read as +3340 on paper, 1 seed in 8, 10 A and the
 * position lost) */
static int16_t catch_step(fw_polarity_t *pol, const fw_core_t *c, fw_cplx_t *v_ff)
{
    const real_t *p = c->p;
    real_t lambda = p[FW_IDX_LAMBDA_M_WB];
    fw_cplx_t e_ff[2];
    real_t n, slope[2], dth[2];
    int16_t sgn, h, pick, ff[2];
    *v_ff = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    if (!pol->catch_on) {
        return 0;
    }
    sgn = catch_raw(pol, c);
    pick = (sgn > 0) ? 0 : 1;
    for (h = 0; h < 2; h++) {
        real_t w = (pol->catch_n > 0) ? pol->catch_h[h].mag / (real_t)pol->catch_n
                                      : fw_cabs(pol->catch_h[h].e);
        fw_cplx_t e;
        dth[h] = ((h == 0) ? FW_REAL(1.0) : FW_REAL(-1.0)) * w / lambda * FW_TS;
        e = catch_vector(pol, c, dth[h]);
        e_ff[h] = fw_cscale(fw_cadd(e, pol->catch_h[h].e), FW_REAL(0.5));
        if (pol->catch_n >= 2) {
            /* the scatter of the vectors: same-parity differences two periods apart */
            pol->catch_h[h].d2 += fw_cabs2(fw_csub(e, pol->catch_h[h].e2));
        }
        pol->catch_h[h].e2 = pol->catch_h[h].e;
        pol->catch_h[h].e = e;
    }
    pol->catch_wax = (sgn != 0) ? dth[pick] : FW_REAL(0.0);
    pol->catch_i = c->i_end;
    pol->catch_k++;
    if (pol->catch_n < 0) {
        pol->catch_n++;
        return 0;
    }
    /* the angle of each, continued across periods, against the period index: a straight
     * line whose slope is omega Ts */
    n = (real_t)pol->catch_n;
    for (h = 0; h < 2; h++) {
        fw_cplx_t e = pol->catch_h[h].e;
        real_t ang = fw_atan2(e.im, e.re);
        real_t s_kk, s_kp;
        if (pol->catch_n == 0) {
            pol->catch_h[h].ang = ang;
        } else {
            pol->catch_h[h].ang += fw_wrap_pi(ang - fw_wrap_pi(pol->catch_h[h].ang));
        }
        pol->catch_h[h].mag += fw_cabs(e);
        pol->catch_h[h].s1 += n;
        pol->catch_h[h].s2 += n * n;
        pol->catch_h[h].sp += pol->catch_h[h].ang;
        pol->catch_h[h].skp += n * pol->catch_h[h].ang;
        pol->catch_h[h].spp += pol->catch_h[h].ang * pol->catch_h[h].ang;
        s_kk = pol->catch_h[h].s2 - pol->catch_h[h].s1 * pol->catch_h[h].s1 / (n + FW_REAL(1.0));
        s_kp = pol->catch_h[h].skp - pol->catch_h[h].s1 * pol->catch_h[h].sp / (n + FW_REAL(1.0));
        slope[h] = (s_kk > FW_REAL(0.0)) ? s_kp / s_kk : FW_REAL(0.0);
        /* fed forward where its mean magnitude stands out (POL_CATCH_FF_*) */
        ff[h] = (int16_t)(pol->catch_h[h].mag >= POL_CATCH_FF_MIN_V * (n + FW_REAL(1.0)) ||
                          (pol->catch_n >= 3 &&
                           pol->catch_h[h].mag >= POL_CATCH_FF_FLOOR_V * (n + FW_REAL(1.0)) &&
                           pol->catch_h[h].mag / (n + FW_REAL(1.0)) >=
                               POL_CATCH_FF_K * fw_sqrt(pol->catch_h[h].d2 /
                                                        (FW_REAL(4.0) * (n - FW_REAL(1.0))))));
    }
    pol->catch_n++;
    n = (real_t)pol->catch_n;
    if (sgn != 0) {
        pol->catch_w = slope[pick] / FW_TS;
    }
    /* the next period's mean voltage sits 1.5 periods after this one's middle; the mean of
     * two periods (an A/B pair, svpwm.c: their volt-second errors differ) half a period
     * before it; while the turn's way is unknown, the mean of both measurements and no lead */
    if (sgn != 0 && ff[pick]) {
        real_t lead = (pol->catch_n >= POL_CATCH_MIN_N) ? FW_REAL(2.0) * slope[pick]
                                                         : FW_REAL(0.0);
        *v_ff = fw_cmul(e_ff[pick], fw_cexpj(lead));
    } else if (sgn == 0 && (ff[0] || ff[1])) {
        *v_ff = fw_cscale(fw_cadd(e_ff[0], e_ff[1]), FW_REAL(0.5));
    }
    if (sgn != 0 && pol->catch_n >= POL_CATCH_MIN_N &&
        pol->catch_h[pick].mag >= POL_CATCH_FF_FLOOR_V * n &&
        ((slope[pick] > FW_REAL(0.0)) ? 1 : -1) == sgn) {
        /* (a slower shaft, e.g. one a load accelerates from rest, is the back-EMF test's:
         * the start after it holds the load) */
        real_t sl = slope[pick];
        real_t s_kk = pol->catch_h[pick].s2 - pol->catch_h[pick].s1 * pol->catch_h[pick].s1 / n;
        real_t s_kp = sl * s_kk;
        real_t s_pp = pol->catch_h[pick].spp - pol->catch_h[pick].sp * pol->catch_h[pick].sp / n;
        real_t w_mag = pol->catch_h[pick].mag / n / lambda;
        real_t se = fw_sqrt(fw_max(s_pp - sl * s_kp, FW_REAL(0.0)) / ((n - FW_REAL(2.0)) * s_kk));
        int16_t turn_ok = (int16_t)(se <= POL_CATCH_TURN_REL * fw_fabs(sl));
        int16_t mag_ok = (int16_t)(pol->catch_n >= POL_CATCH_MAG_N || w_mag * lambda >= c->v_lim);
        if (s_kk > FW_REAL(0.0) && fw_fabs(sl) >= POL_CATCH_K_SIGMA * se &&
            fw_fabs(fw_fabs(sl) / FW_TS - w_mag) <= POL_CATCH_AGREE * w_mag &&
            (turn_ok || mag_ok)) {
            /* e is j omega lambda exp(j theta) at mid-period: the magnet half a period on,
             * on the fitted line. The speed from the vector's turn where that is known to
             * 2 %, else from its magnitude: with current flowing |e| / lambda_m carries the
             * errors of the current's modelled flux (nominal L) and of lambda_m (3324 r/min
             * at 3000 with 2.5 A from the diodes of the idle inverter; the turn gave 3000) */
            real_t w = turn_ok ? sl / FW_TS : (real_t)sgn * w_mag;
            real_t th = pol->catch_h[pick].sp / n +
                        sl * (n - FW_REAL(1.0) - pol->catch_h[pick].s1 / n) +
                        FW_REAL(0.5) * w * FW_TS - (real_t)sgn * FW_REAL(0.5) * FW_M_PI;
            pol->catch_omega = w;
            pol->catch_theta = fw_wrap_2pi(th);
            pol->catch_on = 0;
            return 1;
        }
    }
    if (pol->catch_n >= POL_CATCH_MAX) {
        pol->catch_on = 0; /* slow: the standstill tests decide */
        *v_ff = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    }
    return 0;
}

/* the straight line through a window's q back-EMF: the electrical speed at line index
 * n_start (sample n is the mean of the window's n-th period, n = 0 the period it opened), now
 * (the end of the last period) and the acceleration; sign: +1 when the window's frame pointed
 * to the north pole, -1 south */
static int16_t emf_motion(const fw_emf_window_t *w, real_t sign, real_t lambda_m, real_t n_start,
                          real_t *omega_start, real_t *omega_now, real_t *accel)
{
    real_t n = w->s0;
    real_t det = n * w->s2 - w->s1 * w->s1;
    real_t b0, b1, k;
    if (!w->on || n < FW_REAL(10.0) || !(det > FW_REAL(0.0))) {
        return 0;
    }
    b1 = (n * w->sny - w->s1 * w->sy) / det;
    b0 = (w->sy - b1 * w->s1) / n;
    k = sign / lambda_m;
    *omega_start = k * (b0 + b1 * n_start);
    *omega_now = k * (b0 + b1 * (n + FW_REAL(0.5)));
    *accel = k * b1 / FW_TS;
    return 1;
}

/* The speed at the enable is the line's at the enable, not at the window's first period: the
 * window opens only once the tracker runs (POL_EMF_WAIT periods and more after the enable),
 * and a load already on the shaft has accelerated it meanwhile (2 N*m on paper: ~100 r/min in
 * the ~2.5 ms, which the speed reference's return after the start took for the speed to go
 * back to and then stepped from to the command: 1 A more of q current at once, into the q
 * saturation that takes the slopes' saliency; the position was lost in 1 start of 8). The
 * start-up makes no torque before the decision, so the load's acceleration is the line's
 * from the enable on. The enable is the start of the start-up's first period: pol->periods
 * periods before the end of the decision's, which is the window's sample s0. */
int16_t fw_polarity_motion(const fw_polarity_t *pol, real_t lambda_m, real_t *omega_start,
                           real_t *omega_now, real_t *accel)
{
    if (pol->result != 1) {
        return 0;
    }
    return emf_motion(&pol->emf, pol->flipped ? -FW_REAL(1.0) : FW_REAL(1.0), lambda_m,
                      pol->emf.s0 + FW_REAL(0.5) - (real_t)pol->periods, omega_start, omega_now,
                      accel);
}


int16_t fw_polarity_step(fw_polarity_t *pol, const fw_core_t *c, const fw_adc_t *adc,
                    fw_polarity_out_t *out)
{
    const real_t *p = c->p;
    int32_t n_settle = (int32_t)p[FW_IDX_POL_SETTLE_PERIODS];
    int32_t n_ramp = (int32_t)p[FW_IDX_POL_PULSE_PERIODS];
    int32_t n_meas = (int32_t)p[FW_IDX_POL_BIAS_PERIODS];
    int32_t n_motion = (int32_t)(p[FW_IDX_POL_MOTION_MS] * FW_REAL(1e-3) / FW_TS);
    int16_t method = (int16_t)p[FW_IDX_POL_METHOD];
    real_t i_bias = p[FW_IDX_POL_PULSE_A];

    out->id = FW_REAL(0.0);
    out->iq = FW_REAL(0.0);
    out->v_ff = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    if (pol->result != 0) {
        return pol->result;
    }
    if (n_motion < 1) {
        n_motion = 1;
    }
    if (n_ramp < 1) {
        n_ramp = 1;
    }
    pol->count++;
    pol->periods++;
    /* the measurements come from the core's per-period results (adc == 0: none this period) */
    if (adc != 0 && catch_step(pol, c, &out->v_ff)) {
        pol->method_used = FW_POL_METHOD_CATCH;
        pol->flipped = 0; /* the catch's angle is the magnet's: the tracker starts from it */
        pol->result = 1;
        return pol->result;
    }
    /* (not while the motion check runs: the rotor turns because the check turns it, and the
     * check decides by the angle it travelled) */
    if (adc != 0 && pol->phase < POL_MOTION_ACC) {
        int16_t emf = 0;
        if (p[FW_IDX_POL_EMF_MIN_DEG] > FW_REAL(0.0) && c->trk.init) {
            if (pol->emf_wait < POL_EMF_WAIT) {
                pol->emf_wait++; /* the tracked frame first converges (its q axis projects
                                    the EMF) */
            } else {
                emf = emf_step(&pol->emf, c, p[FW_IDX_POL_EMF_MIN_DEG] * (FW_M_PI / FW_REAL(180.0)));
            }
        }
        if (emf != 0) {
            pol->method_used = FW_POL_METHOD_EMF;
            pol->flipped = (int16_t)(emf < 0);
            pol->result = 1;
            return pol->result;
        }
    }

    switch (pol->phase) {
    case POL_SETTLE:
        /* zero current (any frame will do for a zero reference) while the PLL settles */
        if (pol->count >= n_settle) {
            if (!c->trk.init || !c->est_valid) {
                if (pol->count > 4 * n_settle) {
                    pol->result = -1; /* no position estimate at standstill */
                }
                break;
            }
            if (method == 2) {
                start_motion(pol, c);
            } else {
                pol->method_used = FW_POL_METHOD_SATURATION;
                pol->g_ref = FW_REAL(1.0) / p[FW_IDX_LD_H];
                next_phase(pol, POL_BIAS_P);
                pol->count = 1;
                out->id = i_bias / (real_t)n_ramp;
            }
        }
        break;
    case POL_BIAS_P:
    case POL_BIAS_N: {
        int16_t neg = (int16_t)(pol->phase == POL_BIAS_N);
        int32_t d = pol->count - 2; /* reference index (in this phase) of this ISR's estimate */
        int32_t r;
        real_t to;
        real_t from;
        if (adc != 0 && d >= n_ramp + POL_SKIP) {
            accumulate(pol, c, neg);
        }
        if (pol->count > n_ramp + POL_SKIP + n_meas) {
            if (neg) {
                pol->pairs++;
                if (verdict(pol, p) != 0) {
                    next_phase(pol, POL_REST);
                    pol->count = 1;
                    out->id = -i_bias * (FW_REAL(1.0) - FW_REAL(1.0) / (real_t)n_ramp);
                    break;
                }
            }
            next_phase(pol, neg ? POL_BIAS_P : POL_BIAS_N);
            pol->count = 1;
            neg = (int16_t)!neg;
        }
        r = pol->count - 1;
        to = neg ? -i_bias : i_bias;
        from = (pol->phase == POL_BIAS_P && pol->pairs == 0) ? FW_REAL(0.0) : -to;
        out->id = (r < n_ramp) ? from + (to - from) * (real_t)(r + 1) / (real_t)n_ramp : to;
        break;
    }
    case POL_REST:
        /* ramp back to zero current before the decision (the motion check starts from rest) */
        out->id = (pol->count < n_ramp)
                      ? -i_bias * (FW_REAL(1.0) - (real_t)pol->count / (real_t)n_ramp)
                      : FW_REAL(0.0);
        if (pol->count >= n_ramp + POL_SKIP) {
            /* the magnet side saturates: smaller incremental inductance */
            if (verdict(pol, p) > 0) {
                pol->flipped = (int16_t)(pol->ratio < FW_REAL(0.0));
                pol->result = 1;
            } else if (method == 0) {
                start_motion(pol, c);
            } else {
                pol->result = -1;
            }
        }
        break;
    case POL_MOTION_ACC:
        out->iq = p[FW_IDX_POL_MOTION_IQ_A];
        if (pol->count >= n_motion) {
            next_phase(pol, POL_MOTION_BRAKE);
        }
        break;
    case POL_MOTION_BRAKE:
        out->iq = -p[FW_IDX_POL_MOTION_IQ_A];
        if (pol->count >= n_motion) {
            next_phase(pol, POL_MOTION_REST);
        }
        break;
    case POL_MOTION_REST: {
        /* the brake returns the rotor to rest only when both currents came up alike: damp
         * what is left (on the ideal profile 70 r/min after 20 ms of 1 A each way, which the
         * speed ramp then took seconds to bring down at a 1 r/min reference). Damping gain for
         * a time constant of a quarter of the rest, with the nominal torque constant; the
         * angle travelled keeps its sign */
        real_t kt = FW_REAL(1.5) * p[FW_IDX_POLE_PAIRS] * p[FW_IDX_LAMBDA_M_WB];
        real_t tau = FW_REAL(0.25) * (real_t)n_motion * FW_TS;
        real_t w_mech = c->trk.omega / p[FW_IDX_POLE_PAIRS];
        out->iq = fw_clamp(-p[FW_IDX_INERTIA_KGM2] / (kt * tau) * w_mech,
                           -p[FW_IDX_POL_MOTION_IQ_A], p[FW_IDX_POL_MOTION_IQ_A]);
        if (pol->count >= n_motion) {
            real_t min_move = p[FW_IDX_POL_MOTION_MIN_DEG] * (FW_M_PI / FW_REAL(180.0));
            pol->moved = c->trk.theta_unwrapped - pol->theta_start;
            if (fw_fabs(pol->moved) >= min_move) {
                pol->flipped = (int16_t)(pol->moved < FW_REAL(0.0));
                pol->result = 1;
            } else {
                pol->result = -1;
            }
        }
        break;
    }
    default:
        pol->result = -1;
        break;
    }
    return pol->result;
}
