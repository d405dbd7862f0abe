/* current_recon.c - the current of a period from its samples: the mean (what the current
 * loop and the torque see), the end (the start of the next period), and the product of the
 * ripple's dq components (its reluctance torque).
 */
#include "fw_internal.h"

/* Without a measured zero window (FULL modulation): every sample is i(t) = i0 + s (t - t_bar)
 * + r(t), where r is the ripple of the pattern about its mean voltage, Gamma(theta) (v_seg -
 * v_mean) integrated, which needs no back-EMF; i0 and the mean slope s are fitted by least
 * squares to the samples minus r, and the period mean and end follow from the fit plus r. */
static void recon_fit(fw_core_t *c, const fw_adc_t *adc, const fw_angle_t *mid2)
{
    const fw_plan_t *pl = &c->plan_cur;
    const real_t P = (real_t)FW_P_TICKS;
    fw_cplx_t g;
    real_t gamma0 = c->pe.gamma0_f;
    fw_cplx_t vbar = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    fw_cplx_t v_seg[FW_MAX_SEG];
    fw_cplx_t r_at[FW_MAX_SEG + 1]; /* ripple at the segment starts, A */
    fw_cplx_t r_sum = fw_c(FW_REAL(0.0), FW_REAL(0.0)); /* integral of r over the period, A*tick */
    fw_cplx_t slope_seg[FW_MAX_SEG];
    fw_cplx_t y_sum = fw_c(FW_REAL(0.0), FW_REAL(0.0)), ty_sum = y_sum;
    real_t t_sum = FW_REAL(0.0), tt_sum = FW_REAL(0.0);
    int16_t s, k, n = 0;
    if (mid2 != 0 && mid2->valid) {
        g = fw_cscale(mid2->e, c->pe.gamma1_f);
    } else {
        real_t th = c->trk.init ? fw_tracker_predict(&c->trk, FW_H_TICKS) : FW_REAL(0.0);
        g = fw_cscale(fw_cexpj(FW_REAL(2.0) * th), c->pe.gamma1_f);
    }
    for (s = 0; s < pl->n_seg; s++) {
        real_t len = (real_t)(pl->seg_t[s + 1] - pl->seg_t[s]);
        v_seg[s] = fw_svpwm_state_voltage(pl->seg_state[s], pl->vdc);
        vbar = fw_cadd(vbar, fw_cscale(v_seg[s], len / P));
    }
    r_at[0] = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    for (s = 0; s < pl->n_seg; s++) {
        real_t len = (real_t)(pl->seg_t[s + 1] - pl->seg_t[s]);
        fw_cplx_t dv = fw_csub(v_seg[s], vbar);
        slope_seg[s] = fw_cscale(fw_cadd(fw_cscale(dv, gamma0), fw_cmul(g, fw_cconj(dv))),
                                 FW_TICK_S); /* A per tick */
        r_at[s + 1] = fw_cadd(r_at[s], fw_cscale(slope_seg[s], len));
        r_sum = fw_cadd(r_sum, fw_cscale(fw_cadd(r_at[s], r_at[s + 1]), FW_REAL(0.5) * len));
    }
    for (k = 0; k < adc->n_soc && k < FW_MAX_SOC; k++) {
        uint16_t tk = pl->soc[k];
        real_t t = (real_t)tk;
        real_t ia = fw_protection_adc_offset(adc->ia[k], c->adc_half) * c->adc_i_lsb;
        real_t ib = fw_protection_adc_offset(adc->ib[k], c->adc_half) * c->adc_i_lsb;
        fw_cplx_t y = fw_c(ia, (ia + FW_REAL(2.0) * ib) * FW_M_INV_SQRT3);
        fw_cplx_t r = r_at[0];
        /* the segment holding the sample (the segments are ordered and disjoint) */
        for (s = 0; s < pl->n_seg; s++) {
            if (tk >= pl->seg_t[s] && tk < pl->seg_t[s + 1]) {
                r = fw_cadd(r_at[s], fw_cscale(slope_seg[s], t - (real_t)pl->seg_t[s]));
                break;
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
        if (stt > FW_REAL(100.0)) { /* samples spread over more than ~1 us */
            slope = fw_cscale(fw_csub(ty_sum, fw_cscale(y_sum, t_bar)), FW_REAL(1.0) / stt);
        }
        c->i_avg = fw_cadd(fw_cadd(y_bar, fw_cscale(slope, FW_REAL(0.5) * P - t_bar)),
                           fw_cscale(r_sum, FW_REAL(1.0) / P));
        c->i_end = fw_cadd(fw_cadd(y_bar, fw_cscale(slope, P - t_bar)), r_at[pl->n_seg]);
    }
}

/* Mean and end of the current over the period from an anchor current i_a at tick ta and the
 * slope of every segment between the boundaries tb[0..n] (A per tick). With w(tau) = P - tau
 * after the anchor and -tau before it, mean = i_a + (1/P) sum slope * integral_seg w. */
static void integrate_segments(const real_t *tb, const fw_cplx_t *slope, int16_t n, real_t ta,
                               fw_cplx_t i_a, fw_cplx_t *i_mean, fw_cplx_t *i_end)
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

/* The current at every segment boundary tb[0..n] (ascending) of the trajectory anchored at
 * (ta, i_a), each the sum of the segments from the anchor to the boundary, added from the
 * earliest segment on, as the reconstruction was defined (bit for bit: the order fixes the
 * rounding): after the anchor the sums share their prefixes and run forward; before it each
 * one starts anew at the anchor's current with its own earliest segment (a few terms). Only
 * the boundaries whose sums hold a segment of s_lo..s_hi are (re)computed: the others keep
 * the bits they have when only those segments' slopes changed. */
static void boundary_currents(const real_t *tb, const fw_cplx_t *slope, int16_t n, real_t ta,
                              fw_cplx_t i_a, fw_cplx_t *i_b, int32_t s_lo, int32_t s_hi)
{
    fw_cplx_t back[FW_MAX_SEG]; /* segment s's share between tb[s] and the anchor */
    int16_t has_back[FW_MAX_SEG];
    int32_t kf = 0; /* the first boundary at or after the anchor */
    int32_t k, s, n_back, k_end, k0;
    fw_cplx_t f;
    while (kf <= n && tb[kf] < ta) {
        kf++;
    }
    n_back = (kf < n) ? kf : n;
    /* before the anchor: boundary k holds segments k..n_back-1 */
    k_end = (s_lo < n_back) ? ((s_hi < n_back - 1) ? s_hi : n_back - 1) : -1;
    if (k_end >= 0) {
        for (s = 0; s < n_back; s++) {
            real_t hi = fw_min(tb[s + 1], ta);
            has_back[s] = (int16_t)(hi > tb[s]);
            if (has_back[s]) {
                back[s] = fw_cscale(slope[s], tb[s] - hi);
            }
        }
        for (k = 0; k <= k_end; k++) {
            fw_cplx_t i = i_a;
            for (s = k; s < n_back; s++) {
                if (has_back[s]) {
                    i = fw_cadd(i, back[s]);
                }
            }
            i_b[k] = i;
        }
    }
    /* from the anchor on: boundary k holds segments kf-1..k-1 */
    if (s_hi < kf - 1) {
        return;
    }
    k0 = (s_lo + 1 > kf) ? s_lo + 1 : kf;
    f = (k0 == kf) ? i_a : i_b[k0 - 1];
    for (k = k0; k <= n; k++) {
        if (k > 0) {
            real_t lo = fw_max(tb[k - 1], ta);
            if (tb[k] > lo) {
                f = fw_cadd(f, fw_cscale(slope[k - 1], tb[k] - lo));
            }
        }
        i_b[k] = f;
    }
}

/* Where every phase current of a stretch's two ends lies at least FW_RECON_SIGN_A on one
 * side, the device drop's mean sign of every leg is exactly +-1 (inverter_model.c), so the
 * drop is the same value as that of any other such stretch with the same signs. */
#define FW_RECON_SIGN_A FW_REAL(2e-3)

/* the signs (+-1) of the phase currents of i when all three are clear of zero, else 0 */
static int16_t clear_signs(fw_cplx_t i, real_t sgn[3])
{
    real_t iph[3];
    int16_t x;
    fw_inverter_phase_currents(i, iph);
    for (x = 0; x < 3; x++) {
        if (iph[x] >= FW_RECON_SIGN_A) {
            sgn[x] = FW_REAL(1.0);
        } else if (iph[x] <= -FW_RECON_SIGN_A) {
            sgn[x] = FW_REAL(-1.0);
        } else {
            return 0;
        }
    }
    return 1;
}

/* 1 when the phase currents iph have the signs sgn, each clear of zero */
static int16_t has_signs(const real_t iph[3], const real_t sgn[3])
{
    return (int16_t)(sgn[0] * iph[0] >= FW_RECON_SIGN_A && sgn[1] * iph[1] >= FW_RECON_SIGN_A &&
                     sgn[2] * iph[2] >= FW_RECON_SIGN_A);
}

/* phase current x (0 a, 1 b, 2 c) of an alpha-beta current, as fw_inverter_phase_currents */
static real_t phase_current(fw_cplx_t i, int16_t x)
{
    return (x == 0) ? i.re : ((x == 1) ? fw_inverter_phase_b(i) : fw_inverter_phase_c(i));
}

/* dead time's soft sign of a phase current over 10 mA, as fw_clamp(i / 0.01, -1, 1) */
static real_t soft_sign_10ma(real_t i)
{
    if (i >= FW_REAL(0.01)) {
        return FW_REAL(1.0);
    }
    if (i <= FW_REAL(-0.01)) {
        return FW_REAL(-1.0);
    }
    return fw_clamp(i / FW_REAL(0.01), FW_REAL(-1.0), FW_REAL(1.0));
}

/* Period-mean and period-end current from the zero-window anchor and the slope of every
 * segment: measured slopes where measured, else s0 + Gamma*v (Gamma from the estimate). With
 * w(tau) = P - tau after the anchor and -tau before it, mean = i(t_a) + (1/P) sum s_seg *
 * integral_seg w. */
void fw_recon_current(fw_core_t *c, const fw_adc_t *adc, const fw_angle_t *mid2)
{
    const fw_plan_t *pl = &c->plan_cur;
    const int16_t n = pl->n_seg;
    real_t ta = c->slope_t[FW_WIN_ZERO];
    real_t td = c->p[FW_IDX_DEADTIME_US] * FW_REAL(100.0); /* ticks */
    real_t tb[FW_MAX_SEG + 1];
    fw_cplx_t slope[FW_MAX_SEG];
    fw_cplx_t i_b[FW_MAX_SEG + 1]; /* current at the boundaries */
    int16_t modelled[FW_MAX_SEG];
    int16_t have_i_b = 0;
    fw_cplx_t g;
    real_t gamma0;
    int16_t s;

    if (!c->slope_ok[FW_WIN_ZERO] && pl->layout != FW_LAYOUT_OFF && adc->n_soc >= 2) {
        recon_fit(c, adc, mid2);
        return;
    }
    if (!c->slope_ok[FW_WIN_ZERO]) {
        /* no zero window (gates off): plain mean of the samples */
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
        /* theta_hat is the middle's angle when the tracker was not updated (fw_core.c) */
        g = fw_cscale((mid2 != 0 && mid2->valid && FW_REAL(2.0) * c->theta_hat == mid2->th)
                          ? mid2->e
                          : fw_cexpj(FW_REAL(2.0) * c->theta_hat),
                      c->pe.gamma1_f);
    }
    /* the slope of every switching state: measured where it was (the last measured window
     * that covers it: windows and segments are both in time order, so each window's covered
     * segments are found from its start on), else s0 + Gamma(theta) v */
    {
        int16_t found[FW_MAX_SEG];
        int16_t w;
        for (s = 0; s < FW_MAX_SEG; s++) { /* (a fixed count: stores, not a memset call) */
            found[s] = -1;
        }
        for (w = 0; w < 3; w++) {
            if (c->slope_ok[w]) {
                const uint16_t start = pl->win[w].start, end = pl->win[w].end;
                for (s = 0; s < n && pl->seg_t[s] < start; s++) {
                }
                for (; s < n && pl->seg_t[s + 1] <= end; s++) {
                    found[s] = w;
                }
            }
        }
        for (s = 0; s < n; s++) {
            int16_t bits = pl->seg_state[s];
            if (found[s] >= 0) {
                slope[s] = c->slope[found[s]];
            } else if (bits == 0 || bits == 7) {
                slope[s] = c->slope[FW_WIN_ZERO];
            } else {
                slope[s] = fw_cadd(c->slope[FW_WIN_ZERO],
                                   fw_slope_gamma_times(gamma0, g,
                                                        fw_svpwm_state_voltage(bits, pl->vdc)));
            }
            slope[s] = fw_cscale(slope[s], FW_TICK_S); /* A per tick */
            tb[s] = (real_t)pl->seg_t[s];
            modelled[s] = (int16_t)(found[s] < 0);
        }
    }
    tb[n] = (real_t)pl->seg_t[n];
    /* a modelled state whose phase currents have other signs than in the zero window sees
     * another device drop than the s0 it was built on. Where a segment's ends and the zero
     * window's stretch have the same three clear signs the two drops are the same value and
     * their difference exactly zero: the drop model runs only near a current zero. */
    if (c->p[FW_IDX_VDROP_V] > FW_REAL(0.0)) {
        real_t sgn0[3];
        int16_t clear0 = 0;
        int32_t ch_lo = n, ch_hi = -1; /* the segments whose slope bits change */
        fw_cplx_t u0 = fw_c(FW_REAL(0.0), FW_REAL(0.0));
        int16_t have_u0 = 0;
        int16_t same_prev = 0; /* boundary s has the zero window's signs */
        {
            fw_cplx_t z0, z1;
            real_t sgn1[3];
            fw_inverter_window_span(c, FW_WIN_ZERO, &z0, &z1);
            clear0 = (int16_t)(clear_signs(z0, sgn0) && clear_signs(z1, sgn1) &&
                               sgn0[0] == sgn1[0] && sgn0[1] == sgn1[1] && sgn0[2] == sgn1[2]);
        }
        boundary_currents(tb, slope, n, ta, c->i_win[FW_WIN_ZERO], i_b, 0, n - 1);
        have_i_b = 1;
        for (s = 0; s < n; s++) {
            int16_t same_next;
            if (s == 0 || !modelled[s - 1]) {
                real_t iph[3];
                fw_inverter_phase_currents(i_b[s], iph);
                same_prev = (int16_t)(clear0 && has_signs(iph, sgn0));
            }
            if (!modelled[s]) {
                /* x + (0, 0) below: x, unless x has a zero (its sign) */
                if (slope[s].re == FW_REAL(0.0) || slope[s].im == FW_REAL(0.0)) {
                    ch_lo = (s < ch_lo) ? s : ch_lo;
                    ch_hi = s;
                }
                slope[s] = fw_cadd(slope[s], fw_c(FW_REAL(0.0), FW_REAL(0.0)));
                continue;
            }
            {
                real_t iph[3];
                fw_cplx_t du, corr;
                fw_inverter_phase_currents(i_b[s + 1], iph);
                same_next = (int16_t)(clear0 && has_signs(iph, sgn0));
                if (same_prev && same_next) {
                    du = fw_c(FW_REAL(0.0), FW_REAL(0.0)); /* the same drop: u - u */
                } else {
                    if (!have_u0) {
                        u0 = fw_inverter_window_drop(c, FW_WIN_ZERO);
                        have_u0 = 1;
                    }
                    du = fw_csub(fw_inverter_drop_voltage(c, i_b[s], i_b[s + 1]), u0);
                }
                corr = fw_cscale(fw_slope_gamma_times(gamma0, g, du), FW_TICK_S);
                /* a zero correction leaves a slope without zeros as it was */
                if (!(corr.re == FW_REAL(0.0) && corr.im == FW_REAL(0.0) &&
                      slope[s].re != FW_REAL(0.0) && slope[s].im != FW_REAL(0.0))) {
                    ch_lo = (s < ch_lo) ? s : ch_lo;
                    ch_hi = s;
                }
                slope[s] = fw_cadd(slope[s], corr);
                same_prev = same_next;
            }
        }
        /* the boundary currents of the changed slopes again (those of the others stand) */
        if (ch_hi >= 0 && td > FW_REAL(0.0)) {
            boundary_currents(tb, slope, n, ta, c->i_win[FW_WIN_ZERO], i_b, ch_lo, ch_hi);
        }
    }
    /* Dead time: a leg's turn-on edge takes effect td late when its current flows out of the
     * leg (the lower diode holds it low), its turn-off edge td late when the current flows in
     * (the upper diode holds it high). The states between the edges are the planned ones, so
     * the trajectory keeps its slopes and moves its corners; the anchor's own samples sit
     * soc_on >= td after their edge. Unmodelled, the shifted corners of the unmeasured states
     * put up to 5 mA of pattern-dependent bias into the period mean (paper profile, 2 us),
     * torque noise the position tracker cannot see at low speed. The current at each edge
     * comes from the trajectory without dead time (a soft sign over 10 mA). */
    if (td > FW_REAL(0.0)) {
        real_t shift[FW_MAX_SEG + 1];
        const real_t td_half = td * FW_REAL(0.5);
        if (!have_i_b) {
            boundary_currents(tb, slope, n, ta, c->i_win[FW_WIN_ZERO], i_b, 0, n - 1);
        }
        for (s = 1; s < n; s++) {
            const int16_t state = pl->seg_state[s];
            const int16_t changed = (int16_t)(state ^ pl->seg_state[s - 1]);
            if (changed == 1 || changed == 2 || changed == 4) {
                /* one leg switched (every layout's edges but simultaneous ones): the mean of
                 * one term, 0 + y = y and y / 1 = y for the y >= 0 it is */
                const int16_t x = (int16_t)((changed == 1) ? 0 : ((changed == 2) ? 1 : 2));
                real_t sgn = soft_sign_10ma(phase_current(i_b[s], x));
                shift[s] = td_half * (((state >> x) & 1) ? (FW_REAL(1.0) + sgn)
                                                         : (FW_REAL(1.0) - sgn));
            } else {
                real_t sum = FW_REAL(0.0);
                int16_t x, cnt = 0;
                for (x = 0; x < 3; x++) {
                    if ((changed >> x) & 1) {
                        real_t sgn = soft_sign_10ma(phase_current(i_b[s], x));
                        int16_t rising = (int16_t)((state >> x) & 1);
                        sum += td_half * (rising ? (FW_REAL(1.0) + sgn) : (FW_REAL(1.0) - sgn));
                        cnt++;
                    }
                }
                shift[s] = (cnt > 0) ? sum / (real_t)cnt : FW_REAL(0.0);
            }
        }
        for (s = 1; s < n; s++) {
            tb[s] += shift[s];
        }
    }
    integrate_segments(tb, slope, n, ta, c->i_win[FW_WIN_ZERO], &c->i_avg, &c->i_end);
}

/* Mean over a pattern of r_d * r_q, the product of the dq components of its current ripple
 * r(t) = Gamma(theta) * integral (v - v_mean) (A^2): with saliency a ripple makes torque of its
 * own, 1.5 p (Ld - Lq) <r_d r_q> (the products of the two axes' excursions do not average
 * out). The A and B halves of a pair have opposite ripples and the same product. At
 * standstill it is ~1e-4 N*m and changes with the sector: unmodelled, it moved the shaft by
 * ~1 r/min against a position tracker of 0.5 Hz. */
static real_t ripple_dq_product(const fw_core_t *c, const fw_plan_t *pl,
                                const fw_angle_t *mid_next)
{
    const real_t P = (real_t)FW_P_TICKS;
    real_t th;
    fw_cplx_t g, rot;
    fw_cplx_t vbar = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    fw_cplx_t r0 = fw_c(FW_REAL(0.0), FW_REAL(0.0)); /* ripple at the segment start, dq */
    real_t p00 = FW_REAL(0.0); /* r0.re * r0.im / 3 (the end's term of the segment before) */
    fw_cplx_t v_seg[FW_MAX_SEG];
    real_t len_seg[FW_MAX_SEG];
    real_t acc = FW_REAL(0.0);
    int16_t s;
    if (pl->layout == FW_LAYOUT_OFF) {
        return FW_REAL(0.0);
    }
    if (mid_next != 0) {
        th = mid_next->th;
        rot = fw_angle_conj(mid_next);
    } else {
        th = c->trk.init ? fw_tracker_predict(&c->trk, FW_P_TICKS + FW_H_TICKS) : FW_REAL(0.0);
        rot = fw_cexpj(-th);
    }
    g = fw_cscale(fw_cexpj(FW_REAL(2.0) * th), c->pe.gamma1_f);
    for (s = 0; s < pl->n_seg; s++) {
        len_seg[s] = (real_t)(pl->seg_t[s + 1] - pl->seg_t[s]);
        v_seg[s] = fw_svpwm_state_voltage(pl->seg_state[s], pl->vdc);
        vbar = fw_cadd(vbar, fw_cscale(v_seg[s], len_seg[s] / P));
    }
    for (s = 0; s < pl->n_seg; s++) {
        real_t len = len_seg[s];
        fw_cplx_t dv = fw_csub(v_seg[s], vbar);
        fw_cplx_t slope = fw_cadd(fw_cscale(dv, c->pe.gamma0_f), fw_cmul(g, fw_cconj(dv)));
        fw_cplx_t r1 = fw_cadd(r0, fw_cmul(fw_cscale(slope, len * FW_TICK_S), rot));
        /* exact integral of the product of two linear segments */
        real_t p11 = r1.re * r1.im / FW_REAL(3.0);
        acc += len * (p00 + (r0.re * r1.im + r1.re * r0.im) / FW_REAL(6.0) + p11);
        r0 = r1;
        p00 = p11;
    }
    return acc / P;
}

real_t fw_recon_ripple_dq_product(const fw_core_t *c, const fw_plan_t *pl)
{
    return ripple_dq_product(c, pl, 0);
}

real_t fw_recon_ripple_dq_product_at(const fw_core_t *c, const fw_plan_t *pl,
                                     const fw_angle_t *mid_next)
{
    return ripple_dq_product(c, pl, mid_next);
}
