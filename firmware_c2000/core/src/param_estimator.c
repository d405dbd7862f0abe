/* param_estimator.c - online Ld, Lq from the slope estimates, and the apparent inductances
 * MTPA/FW need (docs/estimator.md §3 and §4.7).
 *
 * The slopes measure the INCREMENTAL inductance matrix at the operating point
 * (Ld = 1/(Gamma0 + Gamma1), Lq = 1/(Gamma0 - Gamma1)). MTPA (eq. 50) and FW (eq. 53) are
 * derived from psi = L * i and need APPARENT inductances psi/i. Without cross-saturation the
 * q flux is psi_q(iq) = integral_0^iq Lq_inc(x) dx, so the core learns Lq_inc(|iq|) in bins and
 * integrates the curve: Lq_app(iq) = psi_q(iq)/iq. The d axis saturates only mildly on the
 * magnet side (incremental Ld >= 14 mH against 15 mH over +-3 A in the plant profiles) and MTPA
 * keeps |id| small, so the apparent Ld is taken equal to the filtered incremental one.
 * Filtering works on Gamma0 and Gamma1 = Re(g exp(-j2 theta_hat)) (linear in the slopes, so
 * unbiased by noise, unlike |g| or 1/x of a noisy value).
 */
#include "fw_internal.h"

#define FW_LQ_BIN_MIN 50 /* updates before a bin counts as measured */
#define FW_KAPPA_MIN_DX 0.15f /* A: smallest spacing of the points of the Lq-curve slope */
#define FW_GAMMA0_FAST FW_REAL(0.1) /* per two-vector estimate: about 1 ms */
#define FW_XSAT_NEW_POINT_A FW_REAL(0.25) /* A: the cross-saturation turn is learnt anew */

void fw_paramest_reset(fw_param_est_t *pe, real_t ld, real_t lq, real_t i_max)
{
    int16_t b;
    pe->gamma0_f = FW_REAL(0.5) * (FW_REAL(1.0) / ld + FW_REAL(1.0) / lq);
    pe->gamma1_f = FW_REAL(0.5) * (FW_REAL(1.0) / ld - FW_REAL(1.0) / lq);
    pe->gamma0_fast = pe->gamma0_f;
    pe->iq_fast = FW_REAL(0.0);
    pe->ld_inc = ld;
    pe->lq_inc = lq;
    for (b = 0; b < FW_LQ_BINS; b++) {
        pe->lq_bin[b] = FW_REAL(1.0) / lq; /* stored as 1/Lq (filtered linearly) */
        pe->lq_bin_x[b] = ((real_t)b + FW_REAL(0.5)) * fw_max(i_max, FW_REAL(0.5)) /
                          (real_t)FW_LQ_BINS;
        pe->lq_bin_seen[b] = 0;
    }
    pe->bin_width = fw_max(i_max, FW_REAL(0.5)) / (real_t)FW_LQ_BINS;
    pe->lq_app = lq;
    pe->ld_app = ld;
    pe->n_updates = 0;
    pe->xs_g = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    pe->xs_iq = FW_REAL(0.0);
    pe->xs_n = 0;
}

real_t fw_paramest_gamma1_at(const fw_est_out_t *est, real_t theta)
{
    return fw_cmul(est->g, fw_cexpj(FW_REAL(-2.0) * theta)).re;
}

void fw_paramest_update(fw_param_est_t *pe, const fw_est_out_t *est, real_t theta_ref, real_t iq,
                  real_t alpha, real_t l_lo, real_t l_hi)
{
    real_t g1, ld_i, lq_i, inv_lq;
    int16_t b;
    if (est->n_active != 2) {
        return; /* (the caller decides whether the estimate is fit: fw_core.c) */
    }
    g1 = fw_paramest_gamma1_at(est, theta_ref);
    if (!(est->gamma0 - g1 > FW_REAL(0.0)) || !(est->gamma0 + g1 > FW_REAL(0.0))) {
        return;
    }
    ld_i = FW_REAL(1.0) / (est->gamma0 + g1);
    lq_i = FW_REAL(1.0) / (est->gamma0 - g1);
    if (ld_i < l_lo || ld_i > l_hi || lq_i < l_lo || lq_i > l_hi) {
        return; /* range check: an outlier never enters the filters */
    }
    pe->gamma0_f += alpha * (est->gamma0 - pe->gamma0_f);
    pe->gamma0_fast += FW_GAMMA0_FAST * (est->gamma0 - pe->gamma0_fast);
    pe->iq_fast += FW_GAMMA0_FAST * (iq - pe->iq_fast);
    pe->gamma1_f += alpha * (g1 - pe->gamma1_f);
    if (pe->gamma0_f > pe->gamma1_f && pe->gamma1_f > FW_REAL(0.0)) {
        pe->ld_inc = FW_REAL(1.0) / (pe->gamma0_f + pe->gamma1_f);
        pe->lq_inc = FW_REAL(1.0) / (pe->gamma0_f - pe->gamma1_f);
    }
    inv_lq = est->gamma0 - g1;
    b = (int16_t)(fw_fabs(iq) / pe->bin_width);
    if (b >= FW_LQ_BINS) {
        b = FW_LQ_BINS - 1;
    }
    /* running mean over the first visits, then the exponential filter: a bin crossed only
     * briefly is an average of what was seen there, not a partial step from the nominal */
    if (pe->lq_bin_seen[b] < 30000) {
        pe->lq_bin_seen[b]++;
    }
    {
        real_t a_b = fw_max(alpha, FW_REAL(1.0) / (real_t)pe->lq_bin_seen[b]);
        pe->lq_bin[b] += a_b * (inv_lq - pe->lq_bin[b]);
        pe->lq_bin_x[b] += a_b * (fw_fabs(iq) - pe->lq_bin_x[b]); /* where the value belongs */
    }
    pe->ld_app = pe->ld_inc;
    pe->n_updates++;
}

/* 1/Lq of bin b; a bin never visited borrows its nearest visited neighbour (flat
 * extrapolation of the measured curve), the nominal value only when none was visited */
static real_t bin_value(const fw_param_est_t *pe, int16_t b)
{
    int16_t d;
    for (d = 0; d < FW_LQ_BINS; d++) {
        if (b - d >= 0 && pe->lq_bin_seen[b - d] >= FW_LQ_BIN_MIN) {
            return pe->lq_bin[b - d];
        }
        if (b + d < FW_LQ_BINS && pe->lq_bin_seen[b + d] >= FW_LQ_BIN_MIN) {
            return pe->lq_bin[b + d];
        }
    }
    return pe->lq_bin[b];
}

void fw_paramest_apparent(fw_param_est_t *pe, real_t iq)
{
    /* Lq_app(iq) = psi_q(iq)/iq with psi_q = integral_0^|iq| Lq_inc(x) dx; Lq_inc is linear
     * between the measured points (mean current of a bin, its incremental Lq), flat before
     * the first one and continued with the slope of the last two beyond the last one (q
     * saturation goes on where it was seen falling; flat, a load step from 0.5 A to 4.5 A
     * used Lq_app 31.6 mH against 24.3 mH on the paper machine). The continuation stops at the
     * incremental Ld: below it the machine would have no saliency left. */
    real_t a = fw_fabs(iq);
    real_t psi = FW_REAL(0.0);
    real_t x0 = FW_REAL(0.0);
    real_t l0 = FW_REAL(0.0);
    real_t slope = FW_REAL(0.0); /* dLq_inc/d|iq| between the last two measured points, H/A */
    real_t xp = FW_REAL(-1.0), lp = FW_REAL(0.0); /* the point before the last one */
    int16_t first = 1;
    int16_t b;
    if (a < FW_REAL(1e-3)) {
        pe->lq_app = FW_REAL(1.0) / bin_value(pe, 0);
        return;
    }
    for (b = 0; b < FW_LQ_BINS && x0 < a; b++) {
        real_t x1, l1, xe, le;
        if (pe->lq_bin_seen[b] < FW_LQ_BIN_MIN) {
            continue;
        }
        x1 = pe->lq_bin_x[b];
        l1 = FW_REAL(1.0) / pe->lq_bin[b];
        if (xp >= FW_REAL(0.0) && x1 - xp > FW_REAL(0.1)) {
            slope = fw_min((l1 - lp) / (x1 - xp), FW_REAL(0.0));
        }
        xp = x1;
        lp = l1;
        if (first) {
            l0 = l1; /* flat from zero current to the first point */
            first = 0;
        }
        if (x1 <= x0) {
            l0 = l1;
            continue;
        }
        xe = fw_min(x1, a);
        le = l0 + (l1 - l0) * (xe - x0) / (x1 - x0);
        psi += FW_REAL(0.5) * (l0 + le) * (xe - x0);
        x0 = xe;
        l0 = le;
    }
    if (first) {
        pe->lq_app = FW_REAL(1.0) / bin_value(pe, 0); /* nothing measured yet: nominal */
        return;
    }
    if (x0 < a) {
        /* beyond the last measured point (the loop ran out of points, not of current) */
        real_t l_floor = fw_min(pe->ld_inc, l0);
        real_t x_floor = (slope < FW_REAL(0.0)) ? x0 + (l_floor - l0) / slope : a;
        real_t xe = fw_min(a, x_floor);
        psi += (l0 + FW_REAL(0.5) * slope * (xe - x0)) * (xe - x0);
        psi += l_floor * (a - xe);
    }
    pe->lq_app = psi / a;
}

/* 1/Lq_inc at |iq| from the bins, linear between bin centres */
static real_t inv_lq_at(const fw_param_est_t *pe, real_t iq)
{
    real_t x = fw_fabs(iq) / pe->bin_width - FW_REAL(0.5);
    int16_t b;
    real_t f;
    if (x <= FW_REAL(0.0)) {
        return bin_value(pe, 0);
    }
    if (x >= (real_t)(FW_LQ_BINS - 1)) {
        return bin_value(pe, FW_LQ_BINS - 1);
    }
    b = (int16_t)x;
    f = x - (real_t)b;
    return (FW_REAL(1.0) - f) * bin_value(pe, b) + f * bin_value(pe, (int16_t)(b + 1));
}

real_t fw_paramest_gamma0_prior(const fw_param_est_t *pe, real_t iq)
{
    /* Gamma0 = (1/Ld + 1/Lq_inc(iq))/2 changes with the load under q saturation */
    return pe->gamma0_fast + FW_REAL(0.5) * (inv_lq_at(pe, iq) - inv_lq_at(pe, pe->iq_fast));
}

real_t fw_paramest_saliency_iq_limit(const fw_param_est_t *pe, real_t gamma1_min, real_t i_max)
{
    /* Gamma1(bin) = (1/Ld - 1/Lq_inc(bin))/2 falls with |iq| under q saturation; sensorless
     * operation needs it (docs/estimator.md §7: the noise grows as 1/Gamma1, and at
     * Lq_inc = Ld the position is unobservable). */
    real_t inv_ld = FW_REAL(1.0) / pe->ld_inc;
    real_t prev_g1 = FW_REAL(0.0);
    real_t prev_x = FW_REAL(0.0);
    int16_t have_prev = 0;
    int16_t b;
    for (b = 0; b < FW_LQ_BINS; b++) {
        real_t x = ((real_t)b + FW_REAL(0.5)) * pe->bin_width; /* bin centre */
        real_t g1;
        if (pe->lq_bin_seen[b] < FW_LQ_BIN_MIN) {
            continue;
        }
        g1 = FW_REAL(0.5) * (inv_ld - pe->lq_bin[b]);
        if (g1 < gamma1_min) {
            if (have_prev && prev_g1 > g1) { /* crossing between the two bin centres */
                return prev_x + (x - prev_x) * (prev_g1 - gamma1_min) / (prev_g1 - g1);
            }
            return fw_max(x - pe->bin_width, FW_REAL(0.0));
        }
        prev_g1 = g1;
        prev_x = x;
        have_prev = 1;
    }
    return i_max;
}

int16_t fw_paramest_iq_learnt(const fw_param_est_t *pe, real_t iq, int16_t min_updates)
{
    int16_t b = (int16_t)(fw_fabs(iq) / pe->bin_width);
    if (b >= FW_LQ_BINS) {
        b = FW_LQ_BINS - 1;
    }
    return (int16_t)(pe->lq_bin_seen[b] >= min_updates);
}

/* the learnt bin (not n1) whose point lies nearest to n1's, the lowest of equally near ones */
static int16_t nearest_learnt(const fw_param_est_t *pe, const int16_t *learnt, int16_t n,
                              int16_t n1)
{
    int16_t n2 = -1;
    int16_t j;
    for (j = 0; j < n; j++) {
        int16_t b = learnt[j];
        if (b != n1 && (n2 < 0 || fw_fabs(pe->lq_bin_x[b] - pe->lq_bin_x[n1]) <
                                      fw_fabs(pe->lq_bin_x[n2] - pe->lq_bin_x[n1]))) {
            n2 = b;
        }
    }
    return n2;
}

real_t fw_paramest_inv_lq_slope(const fw_param_est_t *pe, real_t iq)
{
    /* the two learnt points nearest |iq| (one on each side when there are), at least
     * FW_KAPPA_MIN_DX apart so that bin noise does not become a steep slope. The learnt bins
     * are listed once; their points normally rise with the bin (each is a mean of currents
     * within its bin), and then the nearest ones on each side are neighbours in the list. */
    const real_t *x = pe->lq_bin_x;
    real_t a = fw_fabs(iq);
    real_t x_prev = FW_REAL(0.0);
    int16_t learnt[FW_LQ_BINS];
    int32_t n = 0, below = 0; /* learnt bins, of them at or below |iq| */
    int16_t rising = 1;
    int16_t lo = -1, hi = -1;
    int32_t b, j;
    real_t k, lim;
    for (b = 0; b < FW_LQ_BINS; b++) {
        if (pe->lq_bin_seen[b] >= FW_LQ_BIN_MIN) {
            const real_t xb = x[b];
            if (n > 0 && !(xb > x_prev)) {
                rising = 0;
            }
            below += (xb <= a) ? 1 : 0;
            x_prev = xb;
            learnt[n++] = (int16_t)b;
        }
    }
    if (rising) {
        /* the last point at or below |iq| and the first above it (no two are equal) */
        lo = (below > 0) ? learnt[below - 1] : (int16_t)-1;
        hi = (below < n) ? learnt[below] : (int16_t)-1;
    } else {
        for (j = 0; j < n; j++) {
            int16_t lb = learnt[j];
            if (x[lb] <= a) {
                if (lo < 0 || x[lb] > x[lo]) {
                    lo = lb;
                }
            } else if (hi < 0 || x[lb] < x[hi]) {
                hi = lb;
            }
        }
    }
    if (lo < 0 || hi < 0) {
        /* one side only: the two nearest learnt points on it */
        int16_t n1 = (lo >= 0) ? lo : hi;
        int16_t n2;
        if (n1 < 0 || n < 2) {
            return FW_REAL(0.0);
        }
        if (rising && hi >= 0) {
            /* n1 the first point: its distances to the next ones grow (rounded: do not
             * fall), and equal ones go to the lower bin, the next one */
            n2 = learnt[1];
        } else if (rising && (n < 3 || !(fw_fabs(x[learnt[n - 3]] - x[n1]) ==
                                        fw_fabs(x[learnt[n - 2]] - x[n1])))) {
            /* n1 the last point: the one before it is nearest unless an earlier one rounds
             * to the same distance (then the lowest of those: the search below) */
            n2 = learnt[n - 2];
        } else {
            n2 = nearest_learnt(pe, learnt, (int16_t)n, n1);
        }
        lo = (x[n1] < x[n2]) ? n1 : n2;
        hi = (lo == n1) ? n2 : n1;
    }
    if (!(x[hi] - x[lo] >= FW_KAPPA_MIN_DX)) {
        return FW_REAL(0.0);
    }
    k = (pe->lq_bin[hi] - pe->lq_bin[lo]) / (x[hi] - x[lo]);
    /* a plausible saturation slope: below 0.6 of 1/Lq per ampere */
    lim = FW_REAL(0.6) * fw_max(pe->lq_bin[lo], pe->lq_bin[hi]);
    k = fw_clamp(k, -lim, lim);
    return (iq < FW_REAL(0.0)) ? -k : k;
}

real_t fw_paramest_xsat_angle(const fw_param_est_t *pe, real_t iq, real_t ldq_per_a)
{
    /* the incremental matrix [[Ldd, Ldq], [Ldq, Lqq]] has its principal axes turned by
     * 1/2 atan2(2 Ldq, Lqq - Ldd) from the rotor's: the slopes see those axes */
    real_t lqq = FW_REAL(1.0) / inv_lq_at(pe, iq);
    return FW_REAL(0.5) * fw_atan2(FW_REAL(2.0) * ldq_per_a * iq, lqq - pe->ld_inc);
}

/* Cross-saturation at speed: the flux estimator's active flux psi - Lq_app i points along the
 * rotor's d axis whatever the incremental matrix does, the slopes see the matrix's principal
 * axes. The flux angle less the slope angle is the turn of the axes, 1/2 atan2(2 Ldq, Lqq -
 * Ldd) (plus what both methods share at that speed: a commissioning step compares currents
 * of both signs and fits Ldq per ampere, rig/commissioning/steps/xsat.py). */
void fw_paramest_xsat_learn(fw_param_est_t *pe, fw_cplx_t sample, real_t iq, real_t alpha)
{
    /* the mean of the complex sample |g| exp(j2 turn), not of the angle: a raw estimate
     * scatters by tens of degrees where q saturation leaves little saliency (harsh, 3 A), and
     * the mean of angles folded into +-90 deg shrinks towards zero (measured at 300 r/min,
     * 3 A: 3.3 deg where the axes turn by 4.7) while g is linear in the slopes. The mean
     * starts again at another q current (the turn belongs to the current): a running mean
     * over the visit, then an exponential one */
    real_t a;
    if (pe->xs_n == 0 || fw_fabs(iq - pe->xs_iq) > FW_XSAT_NEW_POINT_A) {
        pe->xs_n = 0;
        pe->xs_iq = iq;
    }
    a = fw_max(alpha, FW_REAL(1.0) / (real_t)(pe->xs_n + 1));
    pe->xs_g = fw_cadd(pe->xs_g, fw_cscale(fw_csub(sample, pe->xs_g), a));
    if (pe->xs_n < 1000000) {
        pe->xs_n++;
    }
}
