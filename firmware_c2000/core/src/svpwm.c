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
 * whose inscribed circle is (1 - Tmin/Ts) * Vdc/sqrt(3) (92.4 V at 200 V, docs/estimator.md §5).
 *
 * A/B pairs. The layouts above are not symmetric about the period centre: their volt-seconds
 * have a dipole Q = sum v_seg len (H - t_mid)/P, and the period-mean current is the mean of
 * the period's start and end currents plus Gamma Q. At standstill STRETCH has Q = -12 us
 * (Vo + Ve): 0.12 A along the sector's middle, pointing another way in every sector. So each
 * change of sector stepped the mean current by up to 0.24 A (opposite sectors, where a near-zero
 * reference flips), the current loop took it out over ~0.5 ms, and that torque impulse moved
 * the shaft (J = 0.0005 kg m^2) by 0.7 r/min: a 230 Hz limit cycle at 1 r/min even on the ideal
 * profile. Both halves of the period can also run the other way round: the first half turns
 * phases on in the order p, m, l (Vo, Ve, V7) and the second half turns them off in the order
 * p, m, l (-Vo, -Ve), so every layout has a mirror B with the same windows and the opposite
 * dipole:
 *   DIRECT B   | Ve | V7 ......centre...... V7 | Vo |  (long vectors split the other way)
 *   STRETCH B  | Vo' | Ve' | V7 ..centre.. V7 | V(-o) | V(-e) |
 * Even periods use A, odd periods B (cfg->pairs), and a B period keeps the sector of the A
 * before it; an A period keeps the last sector while its request lies within sector_hyst of
 * it (a near-zero reference no longer chatters between sectors). A pair then has no net
 * dipole: the start and end currents need not move when the sector changes, the mean current
 * of each period alternates by +-Gamma Q about them, and the current loop feeds back the
 * dipole-free current (fw_core.c).
 *
 * Durations are whole ticks. The rounding error of the requested volt-seconds, and what a held
 * sector could not apply, is carried into the next period, so the applied volt-seconds track
 * the reference without drift.
 */
#include "fw_internal.h"

/* cos/sin of phi_k = (k-1)*60 deg, k = 1..6 (fw_svpwm_vec_unit, fw_svpwm_vec_unit2) */
const real_t fw_svpwm_vec_cos[6] = {FW_REAL(1.0), FW_REAL(0.5), FW_REAL(-0.5),
                                    FW_REAL(-1.0), FW_REAL(-0.5), FW_REAL(0.5)};
const real_t fw_svpwm_vec_sin[6] = {FW_REAL(0.0), FW_REAL(0.86602540378443864676),
                                    FW_REAL(0.86602540378443864676), FW_REAL(0.0),
                                    FW_REAL(-0.86602540378443864676),
                                    FW_REAL(-0.86602540378443864676)};
/* switching states of V1..V6: 100, 110, 010, 011, 001, 101 (bit0 = a, bit1 = b, bit2 = c) */
const int16_t fw_svpwm_vec_bits[6] = {1, 3, 2, 6, 4, 5};

real_t fw_svpwm_vmax(real_t vdc, uint16_t tmin_ticks)
{
    return (FW_REAL(1.0) - (real_t)tmin_ticks / (real_t)FW_P_TICKS) * vdc * FW_M_INV_SQRT3;
}

static uint16_t u16(int32_t x) { return (uint16_t)((x < 0) ? 0 : ((x > 65535) ? 65535 : x)); }

/* Turn the three on-intervals into the time-ordered list of switching states: the edges
 * sorted with the phase each one toggles (an interval from 0 is on from the start, so no
 * edge lies at 0); the state after the last edge of an instant is the state from there on
 * (simultaneous edges make one boundary, a state like the one before makes none). */
static void plan_segments(fw_plan_t *pl)
{
    uint16_t t[6];
    int16_t mask[6];
    int32_t n = 0;
    int32_t i, j;
    int16_t state = 0;
    int16_t n_seg;
    for (i = 0; i < 3; i++) {
        if (pl->on[i] < pl->off[i]) {
            if (pl->on[i] > 0u) {
                t[n] = pl->on[i];
                mask[n++] = (int16_t)(1 << i);
            } else {
                state = (int16_t)(state | (1 << i)); /* on from the start */
            }
            if (pl->off[i] < (uint16_t)FW_P_TICKS) {
                t[n] = pl->off[i];
                mask[n++] = (int16_t)(1 << i);
            }
        }
    }
    /* insertion sort, at most 6 edges */
    for (i = 1; i < n; i++) {
        uint16_t key = t[i];
        int16_t key_mask = mask[i];
        j = i - 1;
        while (j >= 0 && t[j] > key) {
            t[j + 1] = t[j];
            mask[j + 1] = mask[j];
            j--;
        }
        t[j + 1] = key;
        mask[j + 1] = key_mask;
    }
    pl->seg_t[0] = 0;
    pl->seg_state[0] = state;
    n_seg = 1;
    for (i = 0; i < n; i++) {
        state = (int16_t)(state ^ mask[i]);
        if (i + 1 < n && t[i + 1] == t[i]) {
            continue; /* simultaneous edges */
        }
        if (pl->seg_state[n_seg - 1] == state) {
            continue;
        }
        pl->seg_t[n_seg] = t[i];
        pl->seg_state[n_seg] = state;
        n_seg++;
    }
    pl->n_seg = n_seg;
    pl->seg_t[n_seg] = (uint16_t)FW_P_TICKS;
    /* dipole of the volt-seconds about the centre (see the header) */
    pl->dipole = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    for (i = 0; i < n_seg; i++) {
        real_t len = (real_t)(pl->seg_t[i + 1] - pl->seg_t[i]);
        real_t arm = (real_t)FW_H_TICKS - FW_REAL(0.5) * (real_t)(pl->seg_t[i + 1] + pl->seg_t[i]);
        pl->dipole = fw_cadd(pl->dipole, fw_cscale(fw_svpwm_state_voltage(pl->seg_state[i], pl->vdc),
                                                   len * arm / (real_t)FW_P_TICKS * FW_TICK_S));
    }
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
        {
            /* first <= every instant <= last, both within 0..65535: no clamping */
            const int32_t span = last - first;
            const int32_t den = (int32_t)(ns - 1);
            int32_t num = 0;
            for (k = 0; k < ns; k++) {
                pl->soc[n + k] = (uint16_t)(first + num / den);
                num += span;
            }
            n = (int16_t)(n + ns);
        }
    }
    pl->n_soc = n;
    pl->n_soc_windows = n;
}

/* FULL modulation without a measured zero window: current samples soc_on after the start
 * and soc_off before the end of every switching state long enough for them (the edges and
 * their ringing stay clear), so the period-mean current can be fitted (fw_core.c). */
static void plan_current_socs(fw_plan_t *pl, const fw_pwm_cfg_t *cfg)
{
    int16_t s;
    int16_t n = pl->n_soc;
    for (s = 0; s < pl->n_seg && n < FW_MAX_SOC; s++) {
        int32_t first = (int32_t)pl->seg_t[s] + (int32_t)cfg->soc_on;
        int32_t last = (int32_t)pl->seg_t[s + 1] - (int32_t)cfg->soc_off;
        if (last < first) {
            continue;
        }
        pl->soc[n++] = u16(first);
        if (last - first >= (int32_t)cfg->soc_on && n < FW_MAX_SOC) {
            pl->soc[n++] = u16(last);
        }
    }
    pl->n_soc = n;
}

/* Fundamental of the minimum-distance overmodulation for a reference of magnitude r (units
 * of the hexagon's inscribed radius Vdc/sqrt3): the mean over one sector of the projected
 * vector's component along the reference (by symmetry the fundamental is in phase). */
static real_t om_fundamental(real_t r)
{
    const int16_t n = 60;
    const real_t s60 = FW_REAL(0.86602540378443864676);
    const real_t vtx = FW_REAL(2.0) * FW_M_INV_SQRT3; /* vertex distance */
    real_t acc = FW_REAL(0.0);
    int16_t k;
    for (k = 0; k < n; k++) {
        real_t phi = (FW_M_PI / FW_REAL(3.0)) * ((real_t)k + FW_REAL(0.5)) / (real_t)n;
        real_t xr = r * fw_cos(phi);
        real_t xi = r * fw_sin(phi);
        /* coefficients along the vertices at 0 and 60 deg, in vertex units */
        real_t a = (xr * s60 - xi * FW_REAL(0.5)) / s60 / vtx;
        real_t b = xi / s60 / vtx;
        real_t sum = a + b;
        if (sum > FW_REAL(1.0)) {
            real_t d = FW_REAL(0.5) * (sum - FW_REAL(1.0));
            a -= d;
            b -= d;
            if (a < FW_REAL(0.0)) {
                a = FW_REAL(0.0);
                b = FW_REAL(1.0);
            } else if (b < FW_REAL(0.0)) {
                b = FW_REAL(0.0);
                a = FW_REAL(1.0);
            }
        }
        /* projected vector (a*v1 + b*v2) * vtx, component along exp(j phi) */
        acc += vtx * (a * fw_cos(phi) + b * (FW_REAL(0.5) * fw_cos(phi) + s60 * fw_sin(phi)));
    }
    return acc / (real_t)n;
}

void fw_svpwm_om_init(real_t ref[FW_OM_N], real_t fund[FW_OM_N])
{
    int16_t k;
    for (k = 0; k < FW_OM_N; k++) {
        real_t q = (real_t)k / (real_t)(FW_OM_N - 1);
        ref[k] = FW_REAL(1.0) + FW_REAL(9.0) * q * q; /* dense near the linear limit */
        fund[k] = (k == 0) ? FW_REAL(1.0) : om_fundamental(ref[k]);
    }
}

real_t fw_svpwm_om_ref(const real_t ref[FW_OM_N], const real_t fund[FW_OM_N], real_t v1)
{
    int16_t k;
    if (v1 <= FW_REAL(1.0)) {
        return v1;
    }
    for (k = 1; k < FW_OM_N; k++) {
        if (v1 <= fund[k]) {
            real_t f = (v1 - fund[k - 1]) / fw_max(fund[k] - fund[k - 1], FW_REAL(1e-9));
            return ref[k - 1] + f * (ref[k] - ref[k - 1]);
        }
    }
    return ref[FW_OM_N - 1];
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
    pl->n_soc_windows = 0;
    pl->soc[0] = (uint16_t)(FW_H_TICKS / 2);
    pl->soc[1] = (uint16_t)(FW_H_TICKS + FW_H_TICKS / 2);
    pl->v_applied = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    pl->vdc = vdc;
    pl->clipped = 0;
    pl->mirror = 0;
    pl->dipole = fw_c(FW_REAL(0.0), FW_REAL(0.0));
}

/* Edges of the DIRECT layout: Vo [0, o1), Ve [o1, o1+e1), V7 .. centre .., Ve [.., P-o2),
 * Vo [P-o2, P). A puts Vo first and Ve last (o1 = To, e2 = Te up to half a period each), B the
 * other way round (e1 = Te, o2 = To); the longer part of each vector is its window. */
static void layout_direct(fw_plan_t *pl, int16_t p, int16_t m, int16_t l, int32_t to, int32_t te,
                          int32_t tmin, int16_t mirror)
{
    const int32_t H = FW_H_TICKS;
    const int32_t P = FW_P_TICKS;
    int32_t o1, o2, e1, e2, z1, z2;
    if (!mirror) {
        o1 = (to < H) ? to : H;
        o2 = to - o1;
        e2 = (te < H - o2) ? te : (H - o2);
        e1 = te - e2;
    } else {
        o2 = (to < H) ? to : H;
        o1 = to - o2;
        e1 = (te < H - o1) ? te : (H - o1);
        e2 = te - e1;
    }
    z1 = H - o1 - e1;
    z2 = H - o2 - e2;
    pl->layout = FW_LAYOUT_DIRECT;
    pl->on[p] = 0;
    pl->off[p] = (uint16_t)P;
    pl->on[m] = u16(o1);
    pl->off[m] = u16(P - o2);
    pl->on[l] = u16(o1 + e1);
    pl->off[l] = u16(H + z2);
    if (o1 >= o2) {
        plan_window(pl, FW_WIN_ODD, pl->vec_odd, 0, o1, (int16_t)(o1 >= tmin));
    } else {
        plan_window(pl, FW_WIN_ODD, pl->vec_odd, P - o2, P, (int16_t)(o2 >= tmin));
    }
    plan_window(pl, FW_WIN_ZERO, 7, H - z1, H + z2, (int16_t)(z1 + z2 >= tmin));
    if (e2 >= e1) {
        plan_window(pl, FW_WIN_EVEN, pl->vec_even, H + z2, P - o2, (int16_t)(e2 >= tmin));
    } else {
        plan_window(pl, FW_WIN_EVEN, pl->vec_even, o1, o1 + e1, (int16_t)(e1 >= tmin));
    }
}

/* Feasibility of the STRETCH layout for the given measured durations. */
static int16_t stretch_fits(int32_t to_m, int32_t te_m, int32_t co, int32_t ce, int32_t tmin)
{
    const int32_t H = FW_H_TICKS;
    int32_t r2 = H - te_m - to_m;
    int32_t r1 = H - ce - co;
    return (int16_t)(r2 >= 0 && r1 >= 0 && r1 + r2 >= tmin);
}

/* Edges of the STRETCH layout. A: V(-e) [0, ce), V(-o) [ce, ce+co), V7, Ve', Vo' (to the end).
 * B: Vo' [0, to'), Ve' [to', to'+te'), V7, V(-o), V(-e) (to the end). */
static void layout_stretch(fw_plan_t *pl, int16_t p, int16_t m, int16_t l, int32_t to_m,
                           int32_t te_m, int32_t co, int32_t ce, int16_t meas_o, int16_t meas_e,
                           int16_t mirror)
{
    const int32_t H = FW_H_TICKS;
    const int32_t P = FW_P_TICKS;
    pl->layout = FW_LAYOUT_STRETCH;
    pl->c_odd = co;
    pl->c_even = ce;
    if (!mirror) {
        int32_t z2 = H - te_m - to_m;
        pl->on[l] = 0;
        pl->off[l] = u16(H + z2);
        pl->on[m] = u16(ce);
        pl->off[m] = u16(H + z2 + te_m);
        pl->on[p] = u16(ce + co);
        pl->off[p] = (uint16_t)P;
        plan_window(pl, FW_WIN_ZERO, 7, ce + co, H + z2, 1);
        plan_window(pl, FW_WIN_EVEN, pl->vec_even, H + z2, H + z2 + te_m, meas_e);
        plan_window(pl, FW_WIN_ODD, pl->vec_odd, H + z2 + te_m, P, meas_o);
    } else {
        int32_t z2 = H - co - ce;
        pl->on[p] = 0;
        pl->off[p] = u16(H + z2);
        pl->on[m] = u16(to_m);
        pl->off[m] = u16(H + z2 + co);
        pl->on[l] = u16(to_m + te_m);
        pl->off[l] = (uint16_t)P;
        plan_window(pl, FW_WIN_ODD, pl->vec_odd, 0, to_m, meas_o);
        plan_window(pl, FW_WIN_EVEN, pl->vec_even, to_m, to_m + te_m, meas_e);
        plan_window(pl, FW_WIN_ZERO, 7, to_m + te_m, H + z2, 1);
    }
}

/* x = a*e1 + b*e2 in the basis of sector s (cross products; e1 x e2 = sin 60 deg), V*ticks */
static void sector_coeffs(int16_t s, fw_cplx_t x, real_t *a, real_t *b)
{
    fw_cplx_t e1 = fw_svpwm_vec_unit(s);
    fw_cplx_t e2 = fw_svpwm_vec_unit((int16_t)(s % 6 + 1));
    *a = (x.re * e2.im - x.im * e2.re) / FW_REAL(0.86602540378443864676);
    *b = (e1.re * x.im - e1.im * x.re) / FW_REAL(0.86602540378443864676);
}

void fw_svpwm_plan(const fw_pwm_cfg_t *cfg, real_t vdc, fw_cplx_t v_ref, fw_mod_t *mod,
                   uint32_t parity, fw_plan_t *pl)
{
    const int32_t P = FW_P_TICKS;
    const int32_t H = FW_H_TICKS;
    const int32_t tmin = (int32_t)cfg->tmin;
    const real_t kv = FW_REAL(2.0) / FW_REAL(3.0) * vdc; /* active vector magnitude */
    const int16_t mirror = (int16_t)(cfg->pairs && (parity & 1u) != 0u);
    fw_cplx_t x;        /* requested volt-ticks */
    fw_cplx_t e1, e2;   /* unit vectors of the sector */
    real_t a, b, sum, limit;
    int32_t ta, tb, to, te, limit_ticks;
    int16_t n, s, k1, k2, p, m, l, x_ph;
    fw_cplx_t applied;

    if (!(vdc > FW_REAL(1.0))) {
        fw_svpwm_plan_off(pl, vdc);
        if (mod) {
            mod->carry = fw_c(FW_REAL(0.0), FW_REAL(0.0));
            mod->sector = 0;
        }
        return;
    }
    x = fw_cscale(v_ref, (real_t)P);
    if (mod) {
        x = fw_cadd(x, mod->carry);
    }
    limit_ticks = cfg->full_range ? P : P - tmin;
    limit = (real_t)limit_ticks;
    /* sector from three sign tests (no trigonometry) */
    {
        real_t r1 = x.im;
        real_t r2 = FW_REAL(0.5) * (FW_M_SQRT3 * x.re - x.im);
        real_t r3 = FW_REAL(0.5) * (-FW_M_SQRT3 * x.re - x.im);
        static const int16_t sector_of_n[8] = {1, 2, 6, 1, 4, 3, 5, 1};
        n = (int16_t)((r1 > FW_REAL(0.0) ? 1 : 0) + (r2 > FW_REAL(0.0) ? 2 : 0) +
                      (r3 > FW_REAL(0.0) ? 4 : 0));
        s = sector_of_n[n];
    }
    /* the last sector is kept while the request lies close enough to it: always within Tmin
     * in a B period (the pair shares one sector), within sector_hyst in an A period; what the
     * held sector cannot apply (a negative share of a vector) stays in the carry */
    if (mod && mod->sector >= 1 && mod->sector <= 6 && mod->sector != s && !cfg->full_range) {
        real_t ah, bh;
        real_t h = kv * (real_t)(mirror ? tmin : (int32_t)cfg->sector_hyst);
        sector_coeffs(mod->sector, x, &ah, &bh);
        if (ah >= -h && bh >= -h &&
            fw_max(ah, FW_REAL(0.0)) + fw_max(bh, FW_REAL(0.0)) <= kv * limit) {
            s = mod->sector;
        }
    }
    k1 = s;
    k2 = (int16_t)(s % 6 + 1);
    e1 = fw_svpwm_vec_unit(k1);
    e2 = fw_svpwm_vec_unit(k2);
    sector_coeffs(s, x, &a, &b);
    a = fw_max(a, FW_REAL(0.0)) / kv; /* ticks */
    b = fw_max(b, FW_REAL(0.0)) / kv;
    sum = a + b;
    /* a reference within half a tick of the hexagon is on it (float rounding), not beyond */
    pl->clipped = (int16_t)(sum > limit + FW_REAL(0.5));
    if (sum > limit && cfg->full_range) {
        /* overmodulation: the nearest point of the hexagon edge a + b = P (moving along
         * e1 + e2, which is normal to the edge), a vertex when that leaves the sector */
        real_t d = FW_REAL(0.5) * (sum - limit);
        a -= d;
        b -= d;
        if (a < FW_REAL(0.0)) {
            a = FW_REAL(0.0);
            b = limit;
        } else if (b < FW_REAL(0.0)) {
            b = FW_REAL(0.0);
            a = limit;
        }
    } else if (sum > limit) {
        a *= limit / sum;
        b *= limit / sum;
    }
    ta = (int32_t)(a + FW_REAL(0.5));
    tb = (int32_t)(b + FW_REAL(0.5));
    while (ta + tb > limit_ticks) { /* rounding up at the limit: at most 1 iteration each */
        if (ta >= tb) {
            ta--;
        } else {
            tb--;
        }
    }
    applied = fw_cscale(fw_cadd(fw_cscale(e1, (real_t)ta), fw_cscale(e2, (real_t)tb)), kv);
    if (mod) {
        if (pl->clipped && !cfg->carry_clipped) {
            mod->carry = fw_c(FW_REAL(0.0), FW_REAL(0.0)); /* no wind-up of a clipped reference */
        } else {
            mod->carry = fw_csub(x, applied);
        }
        mod->sector = s;
    }
    pl->mirror = mirror;
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
        if (x_ph != p && ((fw_svpwm_vec_state(pl->vec_even) >> x_ph) & 1) != 0) {
            m = x_ph;
        }
    }
    l = (int16_t)(3 - p - m);

    if ((to >= tmin && te >= tmin) || !cfg->stretch || cfg->full_range) {
        layout_direct(pl, p, m, l, to, te, tmin, mirror);
    } else {
        int32_t to_m = (to < tmin) ? tmin : to;
        int32_t te_m = (te < tmin) ? tmin : te;
        if (stretch_fits(to_m, te_m, to_m - to, te_m - te, tmin)) {
            layout_stretch(pl, p, m, l, to_m, te_m, to_m - to, te_m - te, 1, 1, mirror);
        } else if (to >= tmin || te >= tmin) {
            /* the long vector alone (single-vector estimate) */
            layout_direct(pl, p, m, l, to, te, tmin, mirror);
        } else if ((parity & 1u) == 0u && stretch_fits(tmin, te, tmin - to, 0, tmin)) {
            layout_stretch(pl, p, m, l, tmin, te, tmin - to, 0, 1, 0, mirror);
        } else if (stretch_fits(to, tmin, 0, tmin - te, tmin)) {
            layout_stretch(pl, p, m, l, to, tmin, 0, tmin - te, 0, 1, mirror);
        } else {
            layout_direct(pl, p, m, l, to, te, tmin, mirror);
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
    if (cfg->full_range && !pl->win[FW_WIN_ZERO].measured) {
        plan_current_socs(pl, cfg);
    }
}

void fw_svpwm_to_pwm(const fw_plan_t *pl, uint32_t period, int16_t gate, fw_pwm_t *pwm)
{
    const int32_t n = (pl->n_soc < 0) ? 0 : ((pl->n_soc > FW_MAX_SOC) ? FW_MAX_SOC : pl->n_soc);
    int32_t i;
    pwm->period = period;
    pwm->cmp_up[0] = pl->cmp_up[0];
    pwm->cmp_up[1] = pl->cmp_up[1];
    pwm->cmp_up[2] = pl->cmp_up[2];
    pwm->cmp_dn[0] = pl->cmp_dn[0];
    pwm->cmp_dn[1] = pl->cmp_dn[1];
    pwm->cmp_dn[2] = pl->cmp_dn[2];
    pwm->n_soc = pl->n_soc;
    for (i = 0; i < n; i++) {
        pwm->soc[i] = pl->soc[i];
    }
    for (; i < FW_MAX_SOC; i++) {
        pwm->soc[i] = 0u;
    }
    pwm->gate_enable = gate;
}
