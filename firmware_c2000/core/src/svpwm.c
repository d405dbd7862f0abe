/* svpwm.c - space-vector PWM with measurable states, Tmin stretching and the sampling plan.
 *
 * Compare semantics (docs/interfaces.md): the upper gate of phase x is on during period ticks
 * [cmp_up, 2*TBPRD - cmp_dn). Turn-on edges therefore lie in the up-count half [0, H] and
 * turn-off edges in the down-count half [H, P] (H = TBPRD = 5000, P = 10000). Every non-empty
 * on-interval touches the centre H, so the first half can only visit states in the order
 * "one phase after the other switches on" and the second half in the order "one phase after
 * the other switches off". For a sector with the one-phase-on vector Vo (V1, V3, V5; phase p
 * on), the two-phase-on vector Ve (V2, V4, V6; phases p, m on) and the third phase l:
 *
 *   DIRECT  (both active states >= Tmin, or stretching off):
 *     | Vo (first part) | Ve (rest) | V7 ......centre...... V7 | Ve | Vo (rest) |
 *     Turn-on order p, m, l; turn-off order l, m, p. Vo is put at the start of the period up
 *     to the centre, Ve at the end, V7 in between: each measured state is ONE contiguous
 *     interval of its full length (symmetric 7-segment PWM cuts each one in two halves).
 *     V0 is not used (all the zero time goes to the measured V7 window).
 *   STRETCH (an active state shorter than Tmin has to be measured):
 *     | V(-e) | V(-o) | V7 ..centre.. V7 | Ve' | Vo' |
 *     Turn-on order l, m, p gives the opposite vectors -Ve (l on) and -Vo (m, l on) in the
 *     first half; turn-off order l, m, p gives Ve and Vo in the second half. A short vector is
 *     stretched to Tmin and the same extra time of its opposite vector compensates the
 *     volt-seconds in the same period: net Vo time = Tmin - (Tmin - To) = To.
 *
 * Feasibility (derived in firmware_c2000/core/README.md): STRETCH needs Te' + To' <= H in the second
 * half and a V7 of at least Tmin; at To = Te = 0 that is 5 * Tmin <= Ts (20 us: exactly fits).
 * When both cannot be measured the longer vector is measured alone (single-vector fallback of
 * the estimator). Keeping V7 >= Tmin limits the voltage to the hexagon To + Te <= Ts - Tmin,
 * whose inscribed circle is (1 - Tmin/Ts) * Vdc/sqrt(3) (92.4 V at 200 V, note section 5).
 *
 * Durations are whole ticks. The rounding error of the requested volt-seconds is carried into
 * the next period, so the applied volt-seconds track the reference without drift.
 */
#include "fw_internal.h"

/* cos/sin of phi_k = (k-1)*60 deg and of 2*phi_k, k = 1..6 */
static const real_t vec_cos[6] = {FW_REAL(1.0), FW_REAL(0.5), FW_REAL(-0.5),
                                  FW_REAL(-1.0), FW_REAL(-0.5), FW_REAL(0.5)};
static const real_t vec_sin[6] = {FW_REAL(0.0), FW_REAL(0.86602540378443864676),
                                  FW_REAL(0.86602540378443864676), FW_REAL(0.0),
                                  FW_REAL(-0.86602540378443864676),
                                  FW_REAL(-0.86602540378443864676)};
/* switching states of V1..V6: 100, 110, 010, 011, 001, 101 (bit0 = a, bit1 = b, bit2 = c) */
static const int16_t vec_bits[6] = {1, 3, 2, 6, 4, 5};

fw_cplx_t fw_vec_unit(int16_t k)
{
    int16_t i = (int16_t)((k - 1) % 6);
    return fw_c(vec_cos[i], vec_sin[i]);
}

fw_cplx_t fw_vec_unit2(int16_t k)
{
    int16_t i = (int16_t)((2 * (k - 1)) % 6);
    return fw_c(vec_cos[i], vec_sin[i]);
}

int16_t fw_vec_state(int16_t k) { return vec_bits[(k - 1) % 6]; }

fw_cplx_t fw_state_voltage(int16_t s, real_t vdc)
{
    real_t sa = (real_t)(s & 1);
    real_t sb = (real_t)((s >> 1) & 1);
    real_t sc = (real_t)((s >> 2) & 1);
    return fw_c(vdc * (FW_REAL(2.0) / FW_REAL(3.0)) * (sa - FW_REAL(0.5) * (sb + sc)),
                vdc * FW_INV_SQRT3_R * (sb - sc));
}

real_t fw_svpwm_vmax(real_t vdc, uint16_t tmin_ticks)
{
    return (FW_REAL(1.0) - (real_t)tmin_ticks / (real_t)FW_P_TICKS) * vdc * FW_INV_SQRT3_R;
}

static uint16_t u16(int32_t x) { return (uint16_t)((x < 0) ? 0 : ((x > 65535) ? 65535 : x)); }

/* Turn the three on-intervals into the time-ordered list of switching states. */
static void plan_segments(fw_plan_t *pl)
{
    uint16_t t[8];
    int16_t n = 0;
    int16_t i;
    int16_t j;
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
    /* insertion sort, at most 7 entries */
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
            continue; /* simultaneous edges */
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
}

static void plan_window(fw_plan_t *pl, int16_t w, int16_t vec, int32_t start, int32_t end,
                        int16_t measured)
{
    pl->win[w].vec = vec;
    pl->win[w].start = u16(start);
    pl->win[w].end = u16(end);
    pl->win[w].measured = measured;
    pl->win[w].soc_first = 0;
    pl->win[w].soc_count = 0;
}

static void plan_socs(fw_plan_t *pl, const fw_pwm_cfg_t *cfg)
{
    int16_t w;
    int16_t n = 0;
    for (w = 0; w < 3; w++) {
        fw_window_t *win = &pl->win[w];
        int32_t first = (int32_t)win->start + (int32_t)cfg->soc_on;
        int32_t last = (int32_t)win->end - (int32_t)cfg->soc_off;
        int16_t k;
        int16_t ns = cfg->n_per_state;
        if (!win->measured) {
            continue;
        }
        if (last <= first || n + ns > FW_MAX_SOC) {
            win->measured = 0;
            continue;
        }
        win->soc_first = n;
        win->soc_count = ns;
        for (k = 0; k < ns; k++) {
            pl->soc[n++] = u16(first + ((last - first) * (int32_t)k) / (int32_t)(ns - 1));
        }
    }
    pl->n_soc = n;
}

void fw_svpwm_plan_off(fw_plan_t *pl, real_t vdc)
{
    int16_t x;
    pl->layout = FW_LAYOUT_OFF;
    pl->sector = 0;
    pl->vec_odd = 1;
    pl->vec_even = 2;
    pl->t_odd = pl->t_even = pl->c_odd = pl->c_even = 0;
    for (x = 0; x < 3; x++) {
        pl->on[x] = (uint16_t)FW_H_TICKS;
        pl->off[x] = (uint16_t)FW_H_TICKS;
        pl->cmp_up[x] = (uint16_t)FW_TBPRD;
        pl->cmp_dn[x] = (uint16_t)FW_TBPRD;
    }
    pl->n_seg = 1;
    pl->seg_t[0] = 0;
    pl->seg_t[1] = (uint16_t)FW_P_TICKS;
    pl->seg_state[0] = 0;
    for (x = 0; x < 3; x++) {
        plan_window(pl, x, 7, 0, 0, 0);
    }
    /* two samples for the current offset / over-current watch while the gates are off */
    pl->n_soc = 2;
    pl->soc[0] = (uint16_t)(FW_H_TICKS / 2);
    pl->soc[1] = (uint16_t)(FW_H_TICKS + FW_H_TICKS / 2);
    pl->v_applied = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    pl->vdc = vdc;
    pl->clipped = 0;
}

/* Edges of the DIRECT layout: Vo [0, o1), Ve [o1, o1+e1), V7 .. centre .., Ve, Vo (rest). */
static void layout_direct(fw_plan_t *pl, int16_t p, int16_t m, int16_t l, int32_t to, int32_t te,
                          int32_t tmin)
{
    const int32_t H = FW_H_TICKS;
    const int32_t P = FW_P_TICKS;
    int32_t o1 = (to < H) ? to : H;
    int32_t o2 = to - o1;
    int32_t e2 = (te < H - o2) ? te : (H - o2);
    int32_t e1 = te - e2;
    int32_t z1 = H - o1 - e1;
    int32_t z2 = H - o2 - e2;
    pl->layout = FW_LAYOUT_DIRECT;
    pl->on[p] = 0;
    pl->off[p] = (uint16_t)P;
    pl->on[m] = u16(o1);
    pl->off[m] = u16(P - o2);
    pl->on[l] = u16(o1 + e1);
    pl->off[l] = u16(H + z2);
    plan_window(pl, FW_WIN_ODD, pl->vec_odd, 0, o1, (int16_t)(o1 >= tmin));
    plan_window(pl, FW_WIN_ZERO, 7, H - z1, H + z2, (int16_t)(z1 + z2 >= tmin));
    plan_window(pl, FW_WIN_EVEN, pl->vec_even, H + z2, P - o2, (int16_t)(e2 >= tmin));
}

/* Feasibility of the STRETCH layout for the given measured durations. */
static int16_t stretch_fits(int32_t to_m, int32_t te_m, int32_t co, int32_t ce, int32_t tmin)
{
    const int32_t H = FW_H_TICKS;
    int32_t r2 = H - te_m - to_m;
    int32_t r1 = H - ce - co;
    return (int16_t)(r2 >= 0 && r1 >= 0 && r1 + r2 >= tmin);
}

/* Edges of the STRETCH layout: V(-e) [0, ce), V(-o) [ce, ce+co), V7, Ve', Vo' (to the end). */
static void layout_stretch(fw_plan_t *pl, int16_t p, int16_t m, int16_t l, int32_t to_m,
                           int32_t te_m, int32_t co, int32_t ce, int16_t meas_o, int16_t meas_e)
{
    const int32_t H = FW_H_TICKS;
    const int32_t P = FW_P_TICKS;
    int32_t z2 = H - te_m - to_m;
    pl->layout = FW_LAYOUT_STRETCH;
    pl->c_odd = co;
    pl->c_even = ce;
    pl->on[l] = 0;
    pl->off[l] = u16(H + z2);
    pl->on[m] = u16(ce);
    pl->off[m] = u16(H + z2 + te_m);
    pl->on[p] = u16(ce + co);
    pl->off[p] = (uint16_t)P;
    plan_window(pl, FW_WIN_ZERO, 7, ce + co, H + z2, 1);
    plan_window(pl, FW_WIN_EVEN, pl->vec_even, H + z2, H + z2 + te_m, meas_e);
    plan_window(pl, FW_WIN_ODD, pl->vec_odd, H + z2 + te_m, P, meas_o);
}

void fw_svpwm_plan(const fw_pwm_cfg_t *cfg, real_t vdc, fw_cplx_t v_ref, fw_cplx_t *carry,
                   uint32_t parity, fw_plan_t *pl)
{
    const int32_t P = FW_P_TICKS;
    const int32_t H = FW_H_TICKS;
    const int32_t tmin = (int32_t)cfg->tmin;
    const real_t kv = FW_REAL(2.0) / FW_REAL(3.0) * vdc; /* active vector magnitude */
    fw_cplx_t x;        /* requested volt-ticks */
    fw_cplx_t e1, e2;   /* unit vectors of the sector */
    real_t a, b, sum, limit;
    int32_t ta, tb, to, te;
    int16_t n, s, k1, k2, p, m, l, x_ph;
    fw_cplx_t applied;

    if (!(vdc > FW_REAL(1.0))) {
        fw_svpwm_plan_off(pl, vdc);
        if (carry) {
            *carry = fw_c(FW_REAL(0.0), FW_REAL(0.0));
        }
        return;
    }
    x = fw_cscale(v_ref, (real_t)P);
    if (carry) {
        x = fw_cadd(x, *carry);
    }
    /* sector from three sign tests (no trigonometry) */
    {
        real_t r1 = x.im;
        real_t r2 = FW_REAL(0.5) * (FW_SQRT3_R * x.re - x.im);
        real_t r3 = FW_REAL(0.5) * (-FW_SQRT3_R * x.re - x.im);
        static const int16_t sector_of_n[8] = {1, 2, 6, 1, 4, 3, 5, 1};
        n = (int16_t)((r1 > FW_REAL(0.0) ? 1 : 0) + (r2 > FW_REAL(0.0) ? 2 : 0) +
                      (r3 > FW_REAL(0.0) ? 4 : 0));
        s = sector_of_n[n];
    }
    k1 = s;
    k2 = (int16_t)(s % 6 + 1);
    e1 = fw_vec_unit(k1);
    e2 = fw_vec_unit(k2);
    /* x = a*e1 + b*e2 (cross products; e1 x e2 = sin 60 deg) */
    a = (x.re * e2.im - x.im * e2.re) / FW_REAL(0.86602540378443864676);
    b = (e1.re * x.im - e1.im * x.re) / FW_REAL(0.86602540378443864676);
    a = fw_max(a, FW_REAL(0.0)) / kv; /* ticks */
    b = fw_max(b, FW_REAL(0.0)) / kv;
    sum = a + b;
    limit = (real_t)(P - tmin);
    /* a reference within half a tick of the hexagon is on it (float rounding), not beyond */
    pl->clipped = (int16_t)(sum > limit + FW_REAL(0.5));
    if (sum > limit) {
        a *= limit / sum;
        b *= limit / sum;
    }
    ta = (int32_t)(a + FW_REAL(0.5));
    tb = (int32_t)(b + FW_REAL(0.5));
    while (ta + tb > P - tmin) { /* rounding up at the limit: at most 1 iteration each */
        if (ta >= tb) {
            ta--;
        } else {
            tb--;
        }
    }
    applied = fw_cscale(fw_cadd(fw_cscale(e1, (real_t)ta), fw_cscale(e2, (real_t)tb)), kv);
    if (carry) {
        if (pl->clipped) {
            *carry = fw_c(FW_REAL(0.0), FW_REAL(0.0)); /* no wind-up of a clipped reference */
        } else {
            *carry = fw_csub(x, applied);
        }
    }
    pl->v_applied = fw_cscale(applied, FW_REAL(1.0) / (real_t)P);
    pl->vdc = vdc;
    pl->sector = s;
    if ((k1 & 1) != 0) {
        pl->vec_odd = k1;
        pl->vec_even = k2;
        to = ta;
        te = tb;
    } else {
        pl->vec_odd = k2;
        pl->vec_even = k1;
        to = tb;
        te = ta;
    }
    pl->t_odd = to;
    pl->t_even = te;
    pl->c_odd = 0;
    pl->c_even = 0;
    /* phase roles: p on in Vo, m the other phase of Ve, l the third */
    p = (int16_t)((pl->vec_odd - 1) / 2);
    m = -1;
    for (x_ph = 0; x_ph < 3; x_ph++) {
        if (x_ph != p && ((fw_vec_state(pl->vec_even) >> x_ph) & 1) != 0) {
            m = x_ph;
        }
    }
    l = (int16_t)(3 - p - m);

    if ((to >= tmin && te >= tmin) || !cfg->stretch) {
        layout_direct(pl, p, m, l, to, te, tmin);
    } else {
        int32_t to_m = (to < tmin) ? tmin : to;
        int32_t te_m = (te < tmin) ? tmin : te;
        if (stretch_fits(to_m, te_m, to_m - to, te_m - te, tmin)) {
            layout_stretch(pl, p, m, l, to_m, te_m, to_m - to, te_m - te, 1, 1);
        } else if (to >= tmin || te >= tmin) {
            /* the long vector alone (single-vector estimate) */
            layout_direct(pl, p, m, l, to, te, tmin);
        } else if ((parity & 1u) == 0u && stretch_fits(tmin, te, tmin - to, 0, tmin)) {
            layout_stretch(pl, p, m, l, tmin, te, tmin - to, 0, 1, 0);
        } else if (stretch_fits(to, tmin, 0, tmin - te, tmin)) {
            layout_stretch(pl, p, m, l, to, tmin, 0, tmin - te, 0, 1);
        } else {
            layout_direct(pl, p, m, l, to, te, tmin);
        }
    }
    (void)H;
    for (x_ph = 0; x_ph < 3; x_ph++) {
        if (pl->on[x_ph] >= pl->off[x_ph]) { /* empty interval: off all period */
            pl->on[x_ph] = (uint16_t)FW_H_TICKS;
            pl->off[x_ph] = (uint16_t)FW_H_TICKS;
        }
        pl->cmp_up[x_ph] = pl->on[x_ph];
        pl->cmp_dn[x_ph] = (uint16_t)(P - (int32_t)pl->off[x_ph]);
    }
    plan_segments(pl);
    plan_socs(pl, cfg);
}

void fw_plan_to_pwm(const fw_plan_t *pl, uint32_t period, int16_t gate, fw_pwm_t *pwm)
{
    int16_t i;
    pwm->period = period;
    for (i = 0; i < 3; i++) {
        pwm->cmp_up[i] = pl->cmp_up[i];
        pwm->cmp_dn[i] = pl->cmp_dn[i];
    }
    pwm->n_soc = pl->n_soc;
    for (i = 0; i < FW_MAX_SOC; i++) {
        pwm->soc[i] = (i < pl->n_soc) ? pl->soc[i] : 0u;
    }
    pwm->gate_enable = gate;
}
