/* inverter_model.c - what the inverter does to the pattern's voltage, as the core models it:
 * dead time on the edges (deadtime_us) and the devices' forward drop (vdrop_v), for the current
 * reconstruction (current_recon.c), the slope differences (fw_core.c) and the flux estimator's
 * voltage model. Currents are positive out of the leg into the machine.
 */
#include "fw_internal.h"

/* The devices' forward drop over a stretch of time in which the current moves linearly from
 * i0 to i1 (alpha-beta): every leg loses vdrop in the direction of its current in every
 * switching state (transistor or diode), so it only shapes the current where a phase current
 * changes sign within the period. Per leg the mean of sign(i) over a linear stretch is
 * (|i1| - |i0|) / (i1 - i0); within 1 mA of a zero the sign goes soft. */
/* mean sign of a leg's current moving linearly from a to b near a zero (leg_sign) */
static real_t leg_sign_near_zero(real_t a, real_t b)
{
    real_t d = b - a;
    return (fw_fabs(d) > FW_REAL(1e-3))
               ? (fw_fabs(b) - fw_fabs(a)) / d
               : fw_clamp((a + b) / FW_REAL(2e-3), FW_REAL(-1.0), FW_REAL(1.0));
}

/* mean sign of a leg's current moving linearly from a to b: with both ends at least 2 mA on
 * one side the formula gives exactly +-1 */
static inline real_t leg_sign(real_t a, real_t b)
{
    if (a >= FW_REAL(2e-3) && b >= FW_REAL(2e-3)) {
        return FW_REAL(1.0);
    }
    if (a <= FW_REAL(-2e-3) && b <= FW_REAL(-2e-3)) {
        return FW_REAL(-1.0);
    }
    return leg_sign_near_zero(a, b);
}

fw_cplx_t fw_inverter_drop_voltage(const fw_core_t *c, fw_cplx_t i0, fw_cplx_t i1)
{
    const real_t vdrop = c->p[FW_IDX_VDROP_V];
    real_t v[3];
    v[0] = -vdrop * leg_sign(i0.re, i1.re);
    v[1] = -vdrop * leg_sign(fw_inverter_phase_b(i0), fw_inverter_phase_b(i1));
    v[2] = -vdrop * leg_sign(fw_inverter_phase_c(i0), fw_inverter_phase_c(i1));
    return fw_inverter_phase_to_ab(v);
}

/* the current of window w at its first and last sample (the stretch its slope was fitted on) */
static inline void window_span(const fw_core_t *c, int16_t w, fw_cplx_t *i0, fw_cplx_t *i1)
{
    const fw_window_t *win = &c->plan_cur.win[w];
    real_t t0 = (real_t)c->plan_cur.soc[win->soc_first] - c->slope_t[w];
    real_t t1 = (real_t)c->plan_cur.soc[win->soc_first + win->soc_count - 1] - c->slope_t[w];
    *i0 = fw_cadd(c->i_win[w], fw_cscale(c->slope[w], t0 * FW_TICK_S));
    *i1 = fw_cadd(c->i_win[w], fw_cscale(c->slope[w], t1 * FW_TICK_S));
}

void fw_inverter_window_span(const fw_core_t *c, int16_t w, fw_cplx_t *i0, fw_cplx_t *i1)
{
    window_span(c, w, i0, i1);
}

/* drop voltage over the sampled stretch of window w */
fw_cplx_t fw_inverter_window_drop(const fw_core_t *c, int16_t w)
{
    fw_cplx_t i0, i1;
    window_span(c, w, &i0, &i1);
    return fw_inverter_drop_voltage(c, i0, i1);
}

/* Average voltage error of the inverter in the period of plan_cur (dead time on every rising
 * edge of a switching leg, device drop), alpha-beta: APPLIED MINUS PATTERN voltage, so a
 * positive phase current gives a negative error (it loses volt-seconds). It is ADDED to the
 * ideal pattern voltage; c->i_avg must be the mean current of that same period. */
fw_cplx_t fw_inverter_error(const fw_core_t *c)
{
    const fw_plan_t *pl = &c->plan_cur;
    real_t td = c->p[FW_IDX_DEADTIME_US] * FW_REAL(1e-6);
    real_t vdrop = c->p[FW_IDX_VDROP_V];
    real_t iph[3];
    real_t dv[3];
    int16_t x;
    if (td <= FW_REAL(0.0) && vdrop <= FW_REAL(0.0)) {
        return fw_c(FW_REAL(0.0), FW_REAL(0.0));
    }
    fw_inverter_phase_currents(c->i_avg, iph);
    for (x = 0; x < 3; x++) {
        int16_t nonempty = (int16_t)(pl->on[x] < pl->off[x]);
        int16_t prev_on_at_end = (int16_t)(c->prev_on[x] < c->prev_off[x] &&
                                           c->prev_off[x] >= (uint16_t)FW_P_TICKS);
        int16_t rising = (int16_t)(nonempty && (pl->on[x] > 0u || !prev_on_at_end));
        real_t sgn = fw_clamp(iph[x] / c->p[FW_IDX_INV_SIGN_A], FW_REAL(-1.0), FW_REAL(1.0));
        dv[x] = -sgn * (td * pl->vdc * (real_t)rising / FW_TS + vdrop);
    }
    return fw_inverter_phase_to_ab(dv);
}
