/* The ISR's cheaper paths compute what the plain computations they replace compute (issue 26:
 * instructions per ISR on an embedded target): each plain computation is kept here as the
 * reference, as the core computed it before, and both run on random inputs that reach every
 * branch (currents near a phase zero for the device drop's and the dead time's soft signs,
 * converters of every width and lsb, patterns of every layout).
 *
 * Equal means equal up to rounding (near(), below): every decision (a flag, a count, a
 * segment, a sample instant) the same, every value within NEAR_ULPS units in the last place of
 * its scale. It was bit for bit; but another association, a reciprocal multiply or a fused
 * multiply-add rounds differently and changes nothing the drive does, and since the gate
 * judges the closed loop over noise seeds (issue 35) such a change must pass: bit for bit,
 * this test failed 2 of the catalogue's 23 rounding-only changes. A wrong term, coefficient or
 * sign is orders of magnitude beyond the limit; the worst difference seen is printed. */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fw_internal.h"
#include "fw_test.h"

static uint32_t rng_state = 12345u;

static uint32_t rnd_u32(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 17;
    rng_state ^= rng_state << 5;
    return rng_state;
}

static real_t rnd(real_t lo, real_t hi) /* uniform in [lo, hi) */
{
    return lo + (hi - lo) * (real_t)(rnd_u32() >> 8) / (real_t)16777216.0f;
}

#define NEAR_ULPS 64.0
#define REAL_EPSILON (sizeof(real_t) == sizeof(float) ? (double)FLT_EPSILON : DBL_EPSILON)
static double worst_ulps; /* the largest difference seen, in units in the last place */

/* a and b equal up to rounding at scale (at least their own magnitude: a value that cancels
 * down from larger terms is judged at their scale); a NaN matches only a NaN, an infinity only
 * itself */
static int near_at(real_t a, real_t b, double scale)
{
    double ulps;
    if (isnan(a) || isnan(b)) {
        return isnan(a) && isnan(b);
    }
    if (isinf(a) || isinf(b)) {
        return a == b;
    }
    scale = fmax(scale, fmax(fabs((double)a), fabs((double)b)));
    if (scale == 0.0) {
        return 1;
    }
    ulps = fabs((double)a - (double)b) / (REAL_EPSILON * scale);
    if (ulps > worst_ulps) {
        worst_ulps = ulps;
    }
    return ulps <= NEAR_ULPS;
}

static int near(real_t a, real_t b) { return near_at(a, b, 0.0); }

/* both parts at the larger modulus, or at scale where that is larger */
static int near_c_at(fw_cplx_t a, fw_cplx_t b, double scale)
{
    scale = fmax(scale, fmax(hypot((double)a.re, (double)a.im), hypot((double)b.re, (double)b.im)));
    return near_at(a.re, b.re, scale) && near_at(a.im, b.im, scale);
}

static int near_c(fw_cplx_t a, fw_cplx_t b) { return near_c_at(a, b, 0.0); }

/* ---- references: the plain computations ------------------------------------------------- */

static fw_cplx_t ref_state_voltage(int16_t s, real_t vdc)
{
    real_t sa = (real_t)(s & 1);
    real_t sb = (real_t)((s >> 1) & 1);
    real_t sc = (real_t)((s >> 2) & 1);
    return fw_c(vdc * (FW_REAL(2.0) / FW_REAL(3.0)) * (sa - FW_REAL(0.5) * (sb + sc)),
                vdc * FW_M_INV_SQRT3 * (sb - sc));
}

static void ref_phase_currents(fw_cplx_t i, real_t iph[3])
{
    iph[0] = i.re;
    iph[1] = FW_REAL(-0.5) * i.re + FW_REAL(0.5) * FW_M_SQRT3 * i.im;
    iph[2] = FW_REAL(-0.5) * i.re - FW_REAL(0.5) * FW_M_SQRT3 * i.im;
}

static fw_cplx_t ref_phase_to_ab(const real_t v[3])
{
    return fw_c((FW_REAL(2.0) / FW_REAL(3.0)) * (v[0] - FW_REAL(0.5) * (v[1] + v[2])),
                (v[1] - v[2]) * FW_M_INV_SQRT3);
}

static uint16_t ref_protection_samples(const fw_adc_t *adc, int32_t adc_half, real_t lsb,
                                       real_t oc_trip, real_t *i_peak)
{
    int16_t k;
    real_t peak = FW_REAL(0.0);
    for (k = 0; k < adc->n_soc && k < FW_MAX_SOC; k++) {
        real_t ia = fw_protection_adc_offset(adc->ia[k], adc_half) * lsb;
        real_t ib = fw_protection_adc_offset(adc->ib[k], adc_half) * lsb;
        real_t ic = -ia - ib;
        peak = fw_max(peak, fw_max(fw_fabs(ia), fw_max(fw_fabs(ib), fw_fabs(ic))));
    }
    *i_peak = peak;
    return (uint16_t)((peak > oc_trip) ? FW_FAULT_OVERCURRENT : FW_FAULT_NONE);
}

static int16_t ref_codes_in_range(const fw_adc_t *adc, int32_t adc_half)
{
    const int32_t top = adc_half - 1 + adc_half;
    int16_t k;
    for (k = 0; k < adc->n_soc && k < FW_MAX_SOC; k++) {
        if (adc->ia[k] < 0 || adc->ia[k] > top || adc->ib[k] < 0 || adc->ib[k] > top) {
            return 0;
        }
    }
    return 1;
}

static fw_cplx_t ref_drop_voltage(const fw_core_t *c, fw_cplx_t i0, fw_cplx_t i1)
{
    real_t a[3], b[3], v[3];
    int16_t x;
    ref_phase_currents(i0, a);
    ref_phase_currents(i1, b);
    for (x = 0; x < 3; x++) {
        real_t d = b[x] - a[x];
        real_t sgn = (fw_fabs(d) > FW_REAL(1e-3))
                         ? (fw_fabs(b[x]) - fw_fabs(a[x])) / d
                         : fw_clamp((a[x] + b[x]) / FW_REAL(2e-3), FW_REAL(-1.0), FW_REAL(1.0));
        v[x] = -c->p[FW_IDX_VDROP_V] * sgn;
    }
    return ref_phase_to_ab(v);
}

static fw_cplx_t ref_window_drop(const fw_core_t *c, int16_t w)
{
    const fw_window_t *win = &c->plan_cur.win[w];
    real_t t0 = (real_t)c->plan_cur.soc[win->soc_first] - c->slope_t[w];
    real_t t1 = (real_t)c->plan_cur.soc[win->soc_first + win->soc_count - 1] - c->slope_t[w];
    fw_cplx_t i0 = fw_cadd(c->i_win[w], fw_cscale(c->slope[w], t0 * FW_TICK_S));
    fw_cplx_t i1 = fw_cadd(c->i_win[w], fw_cscale(c->slope[w], t1 * FW_TICK_S));
    return ref_drop_voltage(c, i0, i1);
}

static void ref_recon_fit(fw_core_t *c, const fw_adc_t *adc)
{
    const fw_plan_t *pl = &c->plan_cur;
    const real_t P = (real_t)FW_P_TICKS;
    real_t th = c->trk.init ? fw_tracker_predict(&c->trk, FW_H_TICKS) : FW_REAL(0.0);
    fw_cplx_t g = fw_cscale(fw_cexpj(FW_REAL(2.0) * th), c->pe.gamma1_f);
    real_t gamma0 = c->pe.gamma0_f;
    fw_cplx_t vbar = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    fw_cplx_t r_at[FW_MAX_SEG + 1];
    fw_cplx_t r_sum = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    fw_cplx_t slope_seg[FW_MAX_SEG];
    fw_cplx_t y_sum = fw_c(FW_REAL(0.0), FW_REAL(0.0)), ty_sum = y_sum;
    real_t t_sum = FW_REAL(0.0), tt_sum = FW_REAL(0.0);
    int16_t s, k, n = 0;
    for (s = 0; s < pl->n_seg; s++) {
        real_t len = (real_t)(pl->seg_t[s + 1] - pl->seg_t[s]);
        vbar = fw_cadd(vbar, fw_cscale(ref_state_voltage(pl->seg_state[s], pl->vdc), len / P));
    }
    r_at[0] = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    for (s = 0; s < pl->n_seg; s++) {
        real_t len = (real_t)(pl->seg_t[s + 1] - pl->seg_t[s]);
        fw_cplx_t dv = fw_csub(ref_state_voltage(pl->seg_state[s], pl->vdc), vbar);
        slope_seg[s] = fw_cscale(fw_cadd(fw_cscale(dv, gamma0), fw_cmul(g, fw_cconj(dv))),
                                 FW_TICK_S);
        r_at[s + 1] = fw_cadd(r_at[s], fw_cscale(slope_seg[s], len));
        r_sum = fw_cadd(r_sum, fw_cscale(fw_cadd(r_at[s], r_at[s + 1]), FW_REAL(0.5) * len));
    }
    for (k = 0; k < adc->n_soc && k < FW_MAX_SOC; k++) {
        real_t t = (real_t)pl->soc[k];
        real_t ia = fw_protection_adc_offset(adc->ia[k], c->adc_half) * c->adc_i_lsb;
        real_t ib = fw_protection_adc_offset(adc->ib[k], c->adc_half) * c->adc_i_lsb;
        fw_cplx_t y = fw_c(ia, (ia + FW_REAL(2.0) * ib) * FW_M_INV_SQRT3);
        fw_cplx_t r = r_at[0];
        for (s = 0; s < pl->n_seg; s++) {
            if (t >= (real_t)pl->seg_t[s] && t < (real_t)pl->seg_t[s + 1]) {
                r = fw_cadd(r_at[s], fw_cscale(slope_seg[s], t - (real_t)pl->seg_t[s]));
            }
        }
        y = fw_csub(y, r);
        y_sum = fw_cadd(y_sum, y);
        ty_sum = fw_cadd(ty_sum, fw_cscale(y, t));
        t_sum += t;
        tt_sum += t * t;
        n++;
    }
    {
        real_t t_bar = t_sum / (real_t)n;
        fw_cplx_t y_bar = fw_cscale(y_sum, FW_REAL(1.0) / (real_t)n);
        real_t stt = tt_sum - (real_t)n * t_bar * t_bar;
        fw_cplx_t slope = fw_c(FW_REAL(0.0), FW_REAL(0.0));
        if (stt > FW_REAL(100.0)) {
            slope = fw_cscale(fw_csub(ty_sum, fw_cscale(y_sum, t_bar)), FW_REAL(1.0) / stt);
        }
        c->i_avg = fw_cadd(fw_cadd(y_bar, fw_cscale(slope, FW_REAL(0.5) * P - t_bar)),
                           fw_cscale(r_sum, FW_REAL(1.0) / P));
        c->i_end = fw_cadd(fw_cadd(y_bar, fw_cscale(slope, P - t_bar)), r_at[pl->n_seg]);
    }
}

static void ref_integrate_segments(const real_t *tb, const fw_cplx_t *slope, int16_t n,
                                   real_t ta, fw_cplx_t i_a, fw_cplx_t *i_mean,
                                   fw_cplx_t *i_end)
{
    const real_t P = (real_t)FW_P_TICKS;
    fw_cplx_t acc_mean = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    fw_cplx_t acc_end = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    int16_t s;
    for (s = 0; s < n; s++) {
        real_t u = tb[s];
        real_t v = tb[s + 1];
        if (v <= u) {
            continue;
        }
        if (v <= ta) {
            acc_mean = fw_cadd(acc_mean, fw_cscale(slope[s], -(v - u) * FW_REAL(0.5) * (u + v)));
        } else if (u >= ta) {
            acc_mean =
                fw_cadd(acc_mean, fw_cscale(slope[s], (v - u) * (P - FW_REAL(0.5) * (u + v))));
            acc_end = fw_cadd(acc_end, fw_cscale(slope[s], v - u));
        } else {
            acc_mean = fw_cadd(acc_mean, fw_cscale(slope[s], -(ta - u) * FW_REAL(0.5) * (u + ta)));
            acc_mean =
                fw_cadd(acc_mean, fw_cscale(slope[s], (v - ta) * (P - FW_REAL(0.5) * (ta + v))));
            acc_end = fw_cadd(acc_end, fw_cscale(slope[s], v - ta));
        }
    }
    *i_mean = fw_cadd(i_a, fw_cscale(acc_mean, FW_REAL(1.0) / P));
    *i_end = fw_cadd(i_a, acc_end);
}

static fw_cplx_t ref_current_at(const real_t *tb, const fw_cplx_t *slope, int16_t n, real_t ta,
                                fw_cplx_t i_a, real_t t)
{
    fw_cplx_t i = i_a;
    int16_t s;
    for (s = 0; s < n; s++) {
        real_t lo = fw_max(tb[s], fw_min(ta, t));
        real_t hi = fw_min(tb[s + 1], fw_max(ta, t));
        if (hi > lo) {
            i = fw_cadd(i, fw_cscale(slope[s], (t >= ta) ? (hi - lo) : (lo - hi)));
        }
    }
    return i;
}

static void ref_recon_current(fw_core_t *c, const fw_adc_t *adc)
{
    const fw_plan_t *pl = &c->plan_cur;
    real_t ta = c->slope_t[FW_WIN_ZERO];
    real_t td = c->p[FW_IDX_DEADTIME_US] * FW_REAL(100.0);
    real_t tb[FW_MAX_SEG + 1];
    fw_cplx_t slope[FW_MAX_SEG];
    int16_t modelled[FW_MAX_SEG];
    fw_cplx_t g;
    real_t gamma0;
    int16_t s;

    if (!c->slope_ok[FW_WIN_ZERO] && pl->layout != FW_LAYOUT_OFF && adc->n_soc >= 2) {
        ref_recon_fit(c, adc);
        return;
    }
    if (!c->slope_ok[FW_WIN_ZERO]) {
        fw_cplx_t sum = fw_c(FW_REAL(0.0), FW_REAL(0.0));
        int16_t k;
        for (k = 0; k < adc->n_soc && k < FW_MAX_SOC; k++) {
            real_t ia = fw_protection_adc_offset(adc->ia[k], c->adc_half) * c->adc_i_lsb;
            real_t ib = fw_protection_adc_offset(adc->ib[k], c->adc_half) * c->adc_i_lsb;
            sum = fw_cadd(sum, fw_c(ia, (ia + FW_REAL(2.0) * ib) * FW_M_INV_SQRT3));
        }
        c->i_avg = (adc->n_soc > 0) ? fw_cscale(sum, FW_REAL(1.0) / (real_t)adc->n_soc) : sum;
        c->i_end = c->i_avg;
        return;
    }
    if (c->est.n_active == 2 && c->est.ok) {
        gamma0 = c->est.gamma0;
        g = c->est.g;
    } else {
        gamma0 = c->pe.gamma0_f;
        g = fw_cscale(fw_cexpj(FW_REAL(2.0) * c->theta_hat), c->pe.gamma1_f);
    }
    for (s = 0; s < pl->n_seg; s++) {
        int16_t bits = pl->seg_state[s];
        int16_t w;
        int16_t found = -1;
        for (w = 0; w < 3; w++) {
            if (c->slope_ok[w] && pl->win[w].start <= pl->seg_t[s] &&
                pl->win[w].end >= pl->seg_t[s + 1]) {
                found = w;
            }
        }
        if (found >= 0) {
            slope[s] = c->slope[found];
        } else if (bits == 0 || bits == 7) {
            slope[s] = c->slope[FW_WIN_ZERO];
        } else {
            slope[s] = fw_cadd(c->slope[FW_WIN_ZERO],
                               fw_slope_gamma_times(gamma0, g, ref_state_voltage(bits, pl->vdc)));
        }
        slope[s] = fw_cscale(slope[s], FW_TICK_S);
        tb[s] = (real_t)pl->seg_t[s];
        modelled[s] = (int16_t)(found < 0);
    }
    tb[pl->n_seg] = (real_t)pl->seg_t[pl->n_seg];
    if (c->p[FW_IDX_VDROP_V] > FW_REAL(0.0)) {
        fw_cplx_t u0 = ref_window_drop(c, FW_WIN_ZERO);
        fw_cplx_t corr[FW_MAX_SEG];
        for (s = 0; s < pl->n_seg; s++) {
            corr[s] = fw_c(FW_REAL(0.0), FW_REAL(0.0));
            if (modelled[s]) {
                fw_cplx_t i0 =
                    ref_current_at(tb, slope, pl->n_seg, ta, c->i_win[FW_WIN_ZERO], tb[s]);
                fw_cplx_t i1 =
                    ref_current_at(tb, slope, pl->n_seg, ta, c->i_win[FW_WIN_ZERO], tb[s + 1]);
                fw_cplx_t du = fw_csub(ref_drop_voltage(c, i0, i1), u0);
                corr[s] = fw_cscale(fw_slope_gamma_times(gamma0, g, du), FW_TICK_S);
            }
        }
        for (s = 0; s < pl->n_seg; s++) {
            slope[s] = fw_cadd(slope[s], corr[s]);
        }
    }
    if (td > FW_REAL(0.0)) {
        real_t shift[FW_MAX_SEG + 1];
        for (s = 1; s < pl->n_seg; s++) {
            int16_t changed = (int16_t)(pl->seg_state[s] ^ pl->seg_state[s - 1]);
            fw_cplx_t i_b = ref_current_at(tb, slope, pl->n_seg, ta, c->i_win[FW_WIN_ZERO], tb[s]);
            real_t iph[3];
            real_t sum = FW_REAL(0.0);
            int16_t x, cnt = 0;
            ref_phase_currents(i_b, iph);
            for (x = 0; x < 3; x++) {
                if ((changed >> x) & 1) {
                    real_t sgn = fw_clamp(iph[x] / FW_REAL(0.01), FW_REAL(-1.0), FW_REAL(1.0));
                    int16_t rising = (int16_t)((pl->seg_state[s] >> x) & 1);
                    sum += td * FW_REAL(0.5) *
                           (rising ? (FW_REAL(1.0) + sgn) : (FW_REAL(1.0) - sgn));
                    cnt++;
                }
            }
            shift[s] = (cnt > 0) ? sum / (real_t)cnt : FW_REAL(0.0);
        }
        for (s = 1; s < pl->n_seg; s++) {
            tb[s] += shift[s];
        }
    }
    ref_integrate_segments(tb, slope, pl->n_seg, ta, c->i_win[FW_WIN_ZERO], &c->i_avg,
                           &c->i_end);
}

/* the time-ordered switching states of a plan's on-intervals and their dipole */
static void ref_plan_segments(fw_plan_t *pl)
{
    uint16_t t[8];
    int16_t n = 0;
    int16_t i, j;
    t[n++] = 0;
    for (i = 0; i < 3; i++) {
        if (pl->on[i] < pl->off[i]) {
            if (pl->on[i] > 0u) {
                t[n++] = pl->on[i];
            }
            if (pl->off[i] < (uint16_t)FW_P_TICKS) {
                t[n++] = pl->off[i];
            }
        }
    }
    for (i = 1; i < n; i++) {
        uint16_t key = t[i];
        j = (int16_t)(i - 1);
        while (j >= 0 && t[j] > key) {
            t[j + 1] = t[j];
            j--;
        }
        t[j + 1] = key;
    }
    pl->n_seg = 0;
    for (i = 0; i < n; i++) {
        uint16_t start = t[i];
        int16_t bits = 0;
        int16_t x;
        if (i + 1 < n && t[i + 1] == start) {
            continue;
        }
        for (x = 0; x < 3; x++) {
            if (pl->on[x] <= start && start < pl->off[x]) {
                bits = (int16_t)(bits | (1 << x));
            }
        }
        if (pl->n_seg > 0 && pl->seg_state[pl->n_seg - 1] == bits) {
            continue;
        }
        pl->seg_t[pl->n_seg] = start;
        pl->seg_state[pl->n_seg] = bits;
        pl->n_seg++;
    }
    pl->seg_t[pl->n_seg] = (uint16_t)FW_P_TICKS;
    pl->dipole = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    for (i = 0; i < pl->n_seg; i++) {
        real_t len = (real_t)(pl->seg_t[i + 1] - pl->seg_t[i]);
        real_t arm = (real_t)FW_H_TICKS - FW_REAL(0.5) * (real_t)(pl->seg_t[i + 1] + pl->seg_t[i]);
        pl->dipole = fw_cadd(pl->dipole, fw_cscale(ref_state_voltage(pl->seg_state[i], pl->vdc),
                                                   len * arm / (real_t)FW_P_TICKS * FW_TICK_S));
    }
}


/* the unit vectors of the active vectors, as svpwm.c had them */
static fw_cplx_t ref_vec_unit(int16_t k)
{
    static const real_t c6[6] = {FW_REAL(1.0), FW_REAL(0.5), FW_REAL(-0.5),
                                 FW_REAL(-1.0), FW_REAL(-0.5), FW_REAL(0.5)};
    static const real_t s6[6] = {FW_REAL(0.0), FW_REAL(0.86602540378443864676),
                                 FW_REAL(0.86602540378443864676), FW_REAL(0.0),
                                 FW_REAL(-0.86602540378443864676),
                                 FW_REAL(-0.86602540378443864676)};
    int16_t i = (int16_t)((k - 1) % 6);
    return fw_c(c6[i], s6[i]);
}

static fw_cplx_t ref_vec_unit2(int16_t k) { return ref_vec_unit((int16_t)((2 * (k - 1)) % 6 + 1)); }

static void ref_slope_solve(int16_t n_active, const int16_t vec[2], const fw_cplx_t di[2],
                  const real_t t[2], real_t kv, real_t omega, real_t gamma0_prior,
                  fw_est_out_t *out)
{
    fw_cplx_t y[2], u[2];
    int16_t k;

    out->n_active = 0;
    out->ok = 0;
    out->residual = FW_REAL(0.0);
    if (n_active < 1 || n_active > 2 || !(kv > FW_REAL(0.0))) {
        return;
    }
    /* y_k = Di_k * exp(+j phi_k) / kv = Gamma0 * u_k + g,  u_k = exp(j 2 phi_k)  (section 3) */
    for (k = 0; k < n_active; k++) {
        y[k] = fw_cscale(fw_cmul(di[k], ref_vec_unit(vec[k])), FW_REAL(1.0) / kv);
        u[k] = ref_vec_unit2(vec[k]);
    }
    if (n_active == 2) {
        /* g rotates at 2*omega between the two windows: with r_k = exp(j 2 omega (t_k - t_ref))
         * the model y_k = Gamma0 u_k + g r_k becomes w_k = Gamma0 v_k + g with w = y conj(r),
         * v = u conj(r): the same closed form, now exact for a rotating rotor. */
        real_t t_ref = FW_REAL(0.5) * (t[0] + t[1]);
        fw_cplx_t w[2], v[2], d, dw;
        real_t d2;
        for (k = 0; k < 2; k++) {
            fw_cplx_t rc = fw_cconj(fw_cexpj(FW_REAL(2.0) * omega * (t[k] - t_ref)));
            w[k] = fw_cmul(y[k], rc);
            v[k] = fw_cmul(u[k], rc);
        }
        d = fw_csub(v[0], v[1]);
        dw = fw_csub(w[0], w[1]);
        d2 = fw_cabs2(d);
        if (!(d2 > FW_REAL(1e-6))) {
            return;
        }
        {
            fw_cplx_t p = fw_cmul(dw, fw_cconj(d));
            out->gamma0 = p.re / d2;
            out->residual = p.im / fw_sqrt(d2); /* the 4th equation, 1/H */
            out->g = fw_csub(fw_cscale(fw_cadd(w[0], w[1]), FW_REAL(0.5)),
                             fw_cscale(fw_cadd(v[0], v[1]), FW_REAL(0.5) * out->gamma0));
        }
        out->t_ref = t_ref;
        out->n_active = 2;
    } else {
        /* single-vector fallback: g = y - Gamma0_bar * u */
        out->gamma0 = gamma0_prior;
        out->g = fw_csub(y[0], fw_cscale(u[0], gamma0_prior));
        out->t_ref = t[0];
        out->n_active = 1;
    }
    out->gamma1 = fw_cabs(out->g);
    out->theta_raw = FW_REAL(0.5) * fw_atan2(out->g.im, out->g.re);
    out->ok = (int16_t)(out->gamma0 > FW_REAL(0.0) && out->gamma1 > FW_REAL(0.0) &&
                        out->gamma1 < out->gamma0);
}

static real_t ref_ripple_at(const fw_core_t *c, const fw_plan_t *pl, real_t th)
{
    const real_t P = (real_t)FW_P_TICKS;
    fw_cplx_t g = fw_cscale(fw_cexpj(FW_REAL(2.0) * th), c->pe.gamma1_f);
    fw_cplx_t rot = fw_cexpj(-th);
    fw_cplx_t vbar = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    fw_cplx_t r0 = fw_c(FW_REAL(0.0), FW_REAL(0.0)); /* ripple at the segment start, dq */
    real_t acc = FW_REAL(0.0);
    int16_t s;
    if (pl->layout == FW_LAYOUT_OFF) {
        return FW_REAL(0.0);
    }
    for (s = 0; s < pl->n_seg; s++) {
        real_t len = (real_t)(pl->seg_t[s + 1] - pl->seg_t[s]);
        vbar = fw_cadd(vbar, fw_cscale(ref_state_voltage(pl->seg_state[s], pl->vdc), len / P));
    }
    for (s = 0; s < pl->n_seg; s++) {
        real_t len = (real_t)(pl->seg_t[s + 1] - pl->seg_t[s]);
        fw_cplx_t dv = fw_csub(ref_state_voltage(pl->seg_state[s], pl->vdc), vbar);
        fw_cplx_t slope = fw_cadd(fw_cscale(dv, c->pe.gamma0_f), fw_cmul(g, fw_cconj(dv)));
        fw_cplx_t r1 = fw_cadd(r0, fw_cmul(fw_cscale(slope, len * FW_TICK_S), rot));
        /* exact integral of the product of two linear segments */
        acc += len * (r0.re * r0.im / FW_REAL(3.0) +
                      (r0.re * r1.im + r1.re * r0.im) / FW_REAL(6.0) + r1.re * r1.im / FW_REAL(3.0));
        r0 = r1;
    }
    return acc / P;
}

static real_t ref_ripple_dq_product(const fw_core_t *c, const fw_plan_t *pl)
{
    return ref_ripple_at(c, pl,
                         c->trk.init ? fw_tracker_predict(&c->trk, FW_P_TICKS + FW_H_TICKS)
                                     : FW_REAL(0.0));
}

/* the learnt Lq curve's slope as param_estimator.c computed it (its constants: 50 updates
 * make a bin learnt, 0.15 A the least spacing of the two points) */
static real_t ref_inv_lq_slope(const fw_param_est_t *pe, real_t iq)
{
    real_t a = fw_fabs(iq);
    int16_t lo = -1, hi = -1;
    int16_t b;
    real_t k, lim;
    for (b = 0; b < FW_LQ_BINS; b++) {
        if (pe->lq_bin_seen[b] < 50) {
            continue;
        }
        if (pe->lq_bin_x[b] <= a) {
            if (lo < 0 || pe->lq_bin_x[b] > pe->lq_bin_x[lo]) {
                lo = b;
            }
        } else if (hi < 0 || pe->lq_bin_x[b] < pe->lq_bin_x[hi]) {
            hi = b;
        }
    }
    if (lo < 0 || hi < 0) {
        int16_t n1 = (lo >= 0) ? lo : hi;
        int16_t n2 = -1;
        if (n1 < 0) {
            return FW_REAL(0.0);
        }
        for (b = 0; b < FW_LQ_BINS; b++) {
            if (b != n1 && pe->lq_bin_seen[b] >= 50 &&
                (n2 < 0 || fw_fabs(pe->lq_bin_x[b] - pe->lq_bin_x[n1]) <
                               fw_fabs(pe->lq_bin_x[n2] - pe->lq_bin_x[n1]))) {
                n2 = b;
            }
        }
        if (n2 < 0) {
            return FW_REAL(0.0);
        }
        lo = (pe->lq_bin_x[n1] < pe->lq_bin_x[n2]) ? n1 : n2;
        hi = (lo == n1) ? n2 : n1;
    }
    if (!(pe->lq_bin_x[hi] - pe->lq_bin_x[lo] >= 0.15f)) {
        return FW_REAL(0.0);
    }
    k = (pe->lq_bin[hi] - pe->lq_bin[lo]) / (pe->lq_bin_x[hi] - pe->lq_bin_x[lo]);
    lim = FW_REAL(0.6) * fw_max(pe->lq_bin[lo], pe->lq_bin[hi]);
    k = fw_clamp(k, -lim, lim);
    return (iq < FW_REAL(0.0)) ? -k : k;
}

/* ---- the checks ------------------------------------------------------------------------- */

static void state_voltages(void)
{
    int16_t s;
    int k;
    const real_t vdcs[] = {FW_REAL(200.0), FW_REAL(0.0), FW_REAL(-3.5), FW_REAL(1e-30),
                           FW_REAL(311.7)};
    for (k = 0; k < (int)(sizeof vdcs / sizeof vdcs[0]); k++) {
        for (s = 0; s < 16; s++) {
            CHECK(near_c(fw_svpwm_state_voltage(s, vdcs[k]), ref_state_voltage(s, vdcs[k])),
                  "state %d at vdc %g", s, (double)vdcs[k]);
        }
    }
}

static void protection(void)
{
    /* every converter width, lsb from the default (5 * 2^-14, exact products) to ranges whose
     * lsb has all 24 bits, codes all over the scale, near mid-scale and out of range */
    int it;
    for (it = 0; it < 200000; it++) {
        fw_adc_t a;
        int16_t bits = (int16_t)(8 + rnd_u32() % 17);
        int32_t half = (int32_t)1 << (bits - 1);
        real_t range = (rnd_u32() % 2) ? (real_t)(1u + rnd_u32() % 20u) : rnd(0.1f, 1000.0f);
        real_t lsb = FW_REAL(2.0) * range / ((real_t)half * FW_REAL(2.0));
        int32_t spread = (rnd_u32() % 3 == 0) ? 3 : (int32_t)(rnd_u32() % (uint32_t)half) + 1;
        real_t p_ref, p_new;
        uint16_t f_ref, f_new;
        int16_t k;
        memset(&a, 0, sizeof a);
        a.n_soc = (int16_t)(rnd_u32() % 18) - 1;
        for (k = 0; k < FW_MAX_SOC; k++) {
            a.ia[k] = half + (int32_t)(rnd_u32() % (uint32_t)(2 * spread)) - spread;
            a.ib[k] = half + (int32_t)(rnd_u32() % (uint32_t)(2 * spread)) - spread;
            if (rnd_u32() % 64 == 0) {
                a.ia[k] = half; /* mid-scale: zero current */
                a.ib[k] = half;
            }
        }
        if (rnd_u32() % 50 == 0 && a.n_soc > 0) {
            a.ib[rnd_u32() % (uint32_t)a.n_soc] = (rnd_u32() % 2) ? -1 : 2 * half; /* out */
        }
        if (rnd_u32() % 50 == 0) {
            for (k = 0; k < FW_MAX_SOC; k++) {
                a.ia[k] = a.ib[k] = half; /* all zero: the sign of the zero */
            }
        }
        f_ref = ref_protection_samples(&a, half, lsb, FW_REAL(5.0), &p_ref);
        f_new = fw_protection_samples(&a, half, lsb, FW_REAL(5.0), &p_new);
        CHECK(f_ref == f_new && near(p_ref, p_new), "peak %.9g vs %.9g (bits %d, lsb %.9g)",
              (double)p_new, (double)p_ref, bits, (double)lsb);
        CHECK(ref_codes_in_range(&a, half) == fw_protection_codes_in_range(&a, half),
              "codes in range (bits %d)", bits);
    }
    {
        /* any int32 code, no overflow (UBSan watches) */
        fw_adc_t a;
        real_t p_ref, p_new;
        memset(&a, 0, sizeof a);
        a.n_soc = 2;
        a.ia[0] = INT32_MIN;
        a.ib[0] = INT32_MAX;
        a.ia[1] = INT32_MAX;
        a.ib[1] = INT32_MIN;
        (void)ref_protection_samples(&a, 32768, FW_REAL(20.0) / FW_REAL(65536.0), 10.0f, &p_ref);
        (void)fw_protection_samples(&a, 32768, FW_REAL(20.0) / FW_REAL(65536.0), 10.0f, &p_new);
        CHECK(near(p_ref, p_new), "extreme codes");
        CHECK(fw_protection_codes_in_range(&a, 32768) == 0, "extreme codes in range");
    }
    {
        /* a stuck converter: one code in every sample; one code moved is not stuck */
        fw_adc_t a;
        int16_t k, m;
        memset(&a, 0, sizeof a);
        a.n_soc = FW_MAX_SOC;
        for (k = 0; k < FW_MAX_SOC; k++) {
            a.ia[k] = 32768;
            a.ib[k] = 30000 + 17 * k;
        }
        CHECK(fw_protection_codes_frozen(&a) == 1, "ia stuck: %d", fw_protection_codes_frozen(&a));
        for (m = 0; m < FW_MAX_SOC; m++) {
            a.ia[m] = 32769;
            CHECK(fw_protection_codes_frozen(&a) == 0, "ia moved at sample %d", m);
            a.ia[m] = 32768;
        }
        for (k = 0; k < FW_MAX_SOC; k++) {
            a.ib[k] = 0;
        }
        CHECK(fw_protection_codes_frozen(&a) == 3, "both stuck");
        a.n_soc = 1;
        CHECK(fw_protection_codes_frozen(&a) == 0, "one sample says nothing");
    }
}

static void drop_voltages(void)
{
    fw_core_t *c = (fw_core_t *)calloc(1, sizeof *c);
    int it;
    fw_core_init(c);
    for (it = 0; it < 200000; it++) {
        /* currents within a few mA of a phase zero half of the time */
        real_t scale = (it % 2) ? FW_REAL(0.006) : FW_REAL(2.0);
        fw_cplx_t i0 = fw_c(rnd(-scale, scale), rnd(-scale, scale));
        fw_cplx_t i1 = (it % 5 == 0) ? i0 : fw_c(i0.re + rnd(-0.003f, 0.003f), i0.im + rnd(-scale, scale));
        c->p[FW_IDX_VDROP_V] = (it % 7 == 0) ? FW_REAL(0.0) : rnd(0.1f, 3.0f);
        CHECK(near_c(fw_inverter_drop_voltage(c, i0, i1), ref_drop_voltage(c, i0, i1)),
              "drop at (%g, %g) -> (%g, %g)", (double)i0.re, (double)i0.im, (double)i1.re,
              (double)i1.im);
    }
    free(c);
}

/* a random pattern through the modulator (every layout, both halves of a pair, FULL) */
static void random_plan(fw_core_t *c, fw_plan_t *pl, uint32_t period)
{
    fw_mod_t mod;
    real_t mag = (rnd_u32() % 4 == 0) ? rnd(0.0f, 3.0f) : rnd(0.0f, 130.0f);
    real_t ang = rnd(0.0f, FW_M_2PI);
    fw_pwm_cfg_t cfg = c->pwm_cfg;
    mod.carry = fw_c(rnd(-2000.0f, 2000.0f), rnd(-2000.0f, 2000.0f));
    mod.sector = (int16_t)(rnd_u32() % 7);
    cfg.full_range = (int16_t)(rnd_u32() % 4 == 0);
    fw_svpwm_plan(&cfg, rnd(150.0f, 250.0f), fw_c(mag * fw_cos(ang), mag * fw_sin(ang)), &mod,
                  period, pl);
}

static void segments_and_socs(void)
{
    fw_core_t *c = (fw_core_t *)calloc(1, sizeof *c);
    int it;
    fw_core_init(c);
    for (it = 0; it < 100000; it++) {
        fw_plan_t pl, ref;
        int16_t s, w;
        random_plan(c, &pl, (uint32_t)it);
        ref = pl;
        ref_plan_segments(&ref);
        CHECK(pl.n_seg == ref.n_seg, "n_seg %d vs %d", pl.n_seg, ref.n_seg);
        for (s = 0; s <= pl.n_seg && s <= FW_MAX_SEG; s++) {
            CHECK(pl.seg_t[s] == ref.seg_t[s] && (s == pl.n_seg || pl.seg_state[s] == ref.seg_state[s]),
                  "segment %d", s);
        }
        /* a sum of terms that largely cancel: at the scale of its largest possible term */
        CHECK(near_c_at(pl.dipole, ref.dipole, (double)pl.vdc * FW_H_TICKS * (double)FW_TICK_S),
              "dipole");
        for (w = 0; w < 3; w++) {
            const fw_window_t *win = &pl.win[w];
            int32_t first = (int32_t)win->start + (int32_t)c->pwm_cfg.soc_on;
            int32_t last = (int32_t)win->end - (int32_t)c->pwm_cfg.soc_off;
            int16_t k, ns = win->soc_count;
            if (!win->measured) {
                continue;
            }
            for (k = 0; k < ns; k++) {
                int32_t t = first + ((last - first) * (int32_t)k) / (int32_t)(ns - 1);
                CHECK(pl.soc[win->soc_first + k] == (uint16_t)t, "soc %d of window %d", k, w);
            }
        }
        {
            fw_pwm_t pwm;
            int16_t k;
            memset(&pwm, 0xA5, sizeof pwm);
            fw_svpwm_to_pwm(&pl, (uint32_t)it, 1, &pwm);
            for (k = 0; k < FW_MAX_SOC; k++) {
                CHECK(pwm.soc[k] == ((k < pl.n_soc) ? pl.soc[k] : 0u), "pwm soc %d", k);
            }
            CHECK(pwm.n_soc == pl.n_soc && pwm.period == (uint32_t)it && pwm.gate_enable == 1 &&
                      memcmp(pwm.cmp_up, pl.cmp_up, sizeof pwm.cmp_up) == 0 &&
                      memcmp(pwm.cmp_dn, pl.cmp_dn, sizeof pwm.cmp_dn) == 0,
                  "pwm fields");
        }
    }
    free(c);
}

/* the mean sample tick of window w (as fw_slope_window computes it) */
static real_t window_t_mean(const fw_plan_t *pl, int16_t w)
{
    real_t t_sum = FW_REAL(0.0);
    int16_t k;
    for (k = 0; k < pl->win[w].soc_count; k++) {
        t_sum += (real_t)pl->soc[pl->win[w].soc_first + k];
    }
    return t_sum / (real_t)pl->win[w].soc_count;
}

static void reconstruction(void)
{
    fw_core_t *c = (fw_core_t *)calloc(1, sizeof *c);
    fw_core_t *r = (fw_core_t *)calloc(1, sizeof *r);
    int it, slow = 0, fit = 0;
    fw_core_init(c);
    for (it = 0; it < 100000; it++) {
        fw_adc_t adc;
        int16_t w, k;
        /* currents near a phase zero a third of the time: the drop's and the dead time's
         * soft signs, the drop model's exact path */
        real_t i_scale = (it % 3 == 0) ? FW_REAL(0.004) : FW_REAL(3.0);
        real_t s_scale = (it % 2 == 0) ? FW_REAL(100.0) : FW_REAL(30000.0); /* A/s */
        fw_cplx_t i0 = fw_c(rnd(-i_scale, i_scale), rnd(-i_scale, i_scale));
        random_plan(c, &c->plan_cur, (uint32_t)it);
        c->p[FW_IDX_VDROP_V] = (it % 5 == 0) ? FW_REAL(0.0) : rnd(0.5f, 2.0f);
        c->p[FW_IDX_DEADTIME_US] = (it % 7 == 0) ? FW_REAL(0.0) : rnd(0.5f, 3.0f);
        for (w = 0; w < 3; w++) {
            c->slope_ok[w] = (int16_t)(c->plan_cur.win[w].measured && rnd_u32() % 8 != 0);
            c->slope[w] = fw_c(rnd(-s_scale, s_scale), rnd(-s_scale, s_scale));
            if (rnd_u32() % 40 == 0) {
                c->slope[w].im = FW_REAL(0.0); /* a zero slope component (its sign) */
            }
            c->slope_t[w] = c->plan_cur.win[w].measured ? window_t_mean(&c->plan_cur, w)
                                                        : FW_REAL(0.0);
            c->i_win[w] = fw_cadd(i0, fw_c(rnd(-0.002f, 0.002f), rnd(-0.002f, 0.002f)));
        }
        c->est.n_active = (int16_t)(rnd_u32() % 3);
        c->est.ok = (int16_t)(rnd_u32() % 2);
        c->est.gamma0 = rnd(50.0f, 80.0f);
        c->est.g = fw_c(rnd(-5.0f, 5.0f), rnd(-5.0f, 5.0f));
        c->pe.gamma0_f = rnd(50.0f, 80.0f);
        c->pe.gamma1_f = rnd(1.0f, 6.0f);
        if (it % 2 == 0) { /* small modelled slopes too (s0 + Gamma v near s0) */
            c->est.gamma0 = rnd(0.0f, 0.05f);
            c->est.g = fw_c(rnd(-0.01f, 0.01f), rnd(-0.01f, 0.01f));
            c->pe.gamma0_f = rnd(0.0f, 0.05f);
            c->pe.gamma1_f = rnd(0.0f, 0.01f);
        }
        c->theta_hat = rnd(0.0f, FW_M_2PI);
        c->trk.init = (int16_t)(rnd_u32() % 2);
        c->trk.theta = rnd(0.0f, FW_M_2PI);
        c->trk.omega = rnd(-2000.0f, 2000.0f);
        c->trk.age_ticks = -(int32_t)(rnd_u32() % 10000u);
        memset(&adc, 0, sizeof adc);
        adc.n_soc = c->plan_cur.n_soc;
        for (k = 0; k < FW_MAX_SOC; k++) {
            adc.ia[k] = c->adc_half + (int32_t)(rnd_u32() % 4000u) - 2000;
            adc.ib[k] = c->adc_half + (int32_t)(rnd_u32() % 4000u) - 2000;
        }
        if (!c->slope_ok[FW_WIN_ZERO]) {
            fit++;
        }
        *r = *c;
        {
            /* the middle angle handed over as fw_core.c does (when the tracker kept it) */
            fw_angle_t mid2 = {0, FW_REAL(0.0), {FW_REAL(0.0), FW_REAL(0.0)}};
            if (it % 2 == 0) {
                real_t th = c->trk.init ? fw_tracker_predict(&c->trk, FW_H_TICKS) : FW_REAL(0.0);
                mid2.valid = 1;
                mid2.th = FW_REAL(2.0) * th;
                mid2.e = fw_cexpj(mid2.th);
                if (it % 4 == 0) {
                    c->theta_hat = th;
                    r->theta_hat = th;
                }
            }
            fw_recon_current(c, &adc, &mid2);
        }
        ref_recon_current(r, &adc);
        /* the end current at the scale of the period's (it can be near zero) */
        CHECK(near_c(c->i_avg, r->i_avg) &&
                  near_c_at(c->i_end, r->i_end,
                            hypot((double)r->i_avg.re, (double)r->i_avg.im)),
              "case %d: mean (%.9g, %.9g) vs (%.9g, %.9g), end (%.9g, %.9g) vs (%.9g, %.9g)", it,
              (double)c->i_avg.re, (double)c->i_avg.im, (double)r->i_avg.re,
              (double)r->i_avg.im, (double)c->i_end.re, (double)c->i_end.im,
              (double)r->i_end.re, (double)r->i_end.im);
        if (it % 3 == 0) {
            slow++;
        }
    }
    printf("reconstruction: %d cases (%d near a phase zero, %d without a zero window)\n", it,
           slow, fit);
    free(c);
    free(r);
}


static int near_est(const fw_est_out_t *a, const fw_est_out_t *b)
{
    /* the fit's outputs at the scale of the largest of them (the residual and a small part
     * of g are differences of the large ones), the angle at a half turn */
    const double fit = fmax(fmax(fabs((double)b->gamma0), fabs((double)b->gamma1)),
                            fmax(hypot((double)b->g.re, (double)b->g.im), fabs((double)b->residual)));
    return a->n_active == b->n_active && a->ok == b->ok &&
           near_at(a->theta_raw, b->theta_raw, (double)FW_M_PI) && near_at(a->gamma0, b->gamma0, fit) &&
           near_at(a->gamma1, b->gamma1, fit) && near_at(a->g.re, b->g.re, fit) &&
           near_at(a->g.im, b->g.im, fit) && near_at(a->residual, b->residual, fit) &&
           near(a->t_ref, b->t_ref);
}

static void slope_solutions(void)
{
    int it;
    for (it = 0; it < 200000; it++) {
        fw_est_out_t o_new, o_ref;
        int16_t vec[2];
        fw_cplx_t di[2];
        real_t t[2];
        const int16_t n = (int16_t)(1 + rnd_u32() % 2);
        const real_t omega = (it % 9 == 0) ? FW_REAL(0.0) : rnd(-3000.0f, 3000.0f);
        const real_t kv = rnd(100.0f, 170.0f), g0 = rnd(40.0f, 90.0f);
        vec[0] = (int16_t)(1 + rnd_u32() % 6);
        vec[1] = (int16_t)((vec[0] % 6) + 1);
        di[0] = fw_c(rnd(-2e6f, 2e6f), rnd(-2e6f, 2e6f));
        di[1] = fw_c(rnd(-2e6f, 2e6f), rnd(-2e6f, 2e6f));
        /* mean sample times (s), whole ticks or not: t0 + t1 exact or not */
        t[0] = (real_t)(rnd_u32() % 10000u) * FW_TICK_S;
        t[1] = (it % 2) ? (real_t)(rnd_u32() % 10000u) * FW_TICK_S : rnd(0.0f, 1e-4f);
        memset(&o_new, 0x5A, sizeof o_new);
        memset(&o_ref, 0x5A, sizeof o_ref);
        fw_slope_solve(n, vec, di, t, kv, omega, g0, &o_new);
        ref_slope_solve(n, vec, di, t, kv, omega, g0, &o_ref);
        CHECK(near_est(&o_new, &o_ref), "solve case %d", it);
    }
}

static void window_drops(void)
{
    fw_core_t *c = (fw_core_t *)calloc(1, sizeof *c);
    int it;
    fw_core_init(c);
    for (it = 0; it < 100000; it++) {
        int16_t w;
        do {
            random_plan(c, &c->plan_cur, (uint32_t)it);
        } while (c->plan_cur.n_soc_windows == 0);
        c->p[FW_IDX_VDROP_V] = rnd(0.5f, 2.0f);
        for (w = 0; w < 3; w++) {
            if (!c->plan_cur.win[w].measured) {
                continue;
            }
            c->slope[w] = fw_c(rnd(-3000.0f, 3000.0f), rnd(-3000.0f, 3000.0f));
            c->slope_t[w] = window_t_mean(&c->plan_cur, w);
            c->i_win[w] = fw_c(rnd(-0.01f, 0.01f), rnd(-0.01f, 0.01f));
            CHECK(near_c(fw_inverter_window_drop(c, w), ref_window_drop(c, w)), "window %d", w);
        }
    }
    free(c);
}

static void ripple_products(void)
{
    fw_core_t *c = (fw_core_t *)calloc(1, sizeof *c);
    int it;
    fw_core_init(c);
    for (it = 0; it < 100000; it++) {
        fw_plan_t pl;
        random_plan(c, &pl, (uint32_t)it);
        if (it % 50 == 0) {
            fw_svpwm_plan_off(&pl, FW_REAL(200.0));
        }
        c->trk.init = (int16_t)(rnd_u32() % 4 != 0);
        c->trk.theta = rnd(0.0f, FW_M_2PI);
        c->trk.omega = rnd(-2000.0f, 2000.0f);
        c->trk.age_ticks = -(int32_t)(rnd_u32() % 10000u);
        c->pe.gamma0_f = rnd(50.0f, 80.0f);
        c->pe.gamma1_f = rnd(-6.0f, 6.0f);
        CHECK(near(fw_recon_ripple_dq_product(c, &pl), ref_ripple_dq_product(c, &pl)),
              "ripple case %d", it);
        {
            /* with the current loop's angle and its fw_cexpj (fw_core.c), also at zero and
             * whole quarter turns, where the conjugate differs from the rotation in a zero's
             * sign (fw_angle_conj computes it there; the product hides that sign anyway) */
            fw_angle_t at;
            at.th = c->trk.init ? fw_tracker_predict(&c->trk, FW_P_TICKS + FW_H_TICKS) : FW_REAL(0.0);
            if (it % 10 == 0) {
                at.th = (real_t)(it % 40 / 10) * FW_REAL(1.57080078125);
                c->trk.init = 0;
            }
            at.e = fw_cexpj(at.th);
            at.valid = 1;
            if (it % 10 == 0) {
                /* the reference predicts: give it the same angle */
                CHECK(near(fw_recon_ripple_dq_product_at(c, &pl, &at),
                           ref_ripple_at(c, &pl, at.th)),
                      "ripple at a quarter turn, case %d", it);
            } else {
                CHECK(near(fw_recon_ripple_dq_product_at(c, &pl, &at),
                           ref_ripple_dq_product(c, &pl)),
                      "ripple with the loop's angle, case %d", it);
            }
        }
    }
    free(c);
}

static void lq_slopes(void)
{
    fw_param_est_t pe;
    int it;
    memset(&pe, 0, sizeof pe);
    pe.bin_width = FW_REAL(4.5) / (real_t)FW_LQ_BINS;
    for (it = 0; it < 200000; it++) {
        int16_t b;
        const int kind = it % 5; /* 0-1 points rising with the bin, 2 any order, 3 ties, 4 near */
        for (b = 0; b < FW_LQ_BINS; b++) {
            pe.lq_bin_seen[b] = (int16_t)((rnd_u32() % 3 == 0) ? 50 + rnd_u32() % 100 : rnd_u32() % 60);
            pe.lq_bin[b] = rnd(30.0f, 80.0f);
            pe.lq_bin_x[b] = ((real_t)b + rnd(0.0f, 1.0f)) * pe.bin_width;
            if (kind == 2) {
                pe.lq_bin_x[b] = rnd(0.0f, 4.5f);
            } else if (kind == 3 && b > 0 && rnd_u32() % 3 == 0) {
                pe.lq_bin_x[b] = pe.lq_bin_x[b - 1];
            } else if (kind == 4) {
                /* rising points a unit in the last place apart, and the last one far: their
                 * distances to it round alike (the lowest bin of equal ones counts) */
                pe.lq_bin_x[b] = (b == FW_LQ_BINS - 1) ? FW_REAL(4.4)
                                                       : FW_REAL(0.5) + (real_t)b * 6.0e-8f;
            }
        }
        {
            const real_t iq = (kind == 4)     ? FW_REAL(4.6)
                              : (it % 7 == 0) ? pe.lq_bin_x[rnd_u32() % FW_LQ_BINS]
                                              : rnd(-5.0f, 5.0f);
            CHECK(near(fw_paramest_inv_lq_slope(&pe, iq), ref_inv_lq_slope(&pe, iq)),
                  "Lq slope case %d at %g", it, (double)iq);
        }
    }
}

int main(void)
{
    state_voltages();
    protection();
    drop_voltages();
    segments_and_socs();
    reconstruction();
    slope_solutions();
    window_drops();
    ripple_products();
    lq_slopes();
    printf("worst rounding difference from the plain computations: %.1f ulps (limit %.0f)\n",
           worst_ulps, NEAR_ULPS);
    TEST_DONE();
}
