/* fw_test_api.c - thin host-only entry points into the core's pure functions, for the Python
 * tests (ctypes). Built into libfwcore.so only, never into the target library. Arguments are
 * doubles and int32 so the Python side needs no struct layouts; the core itself still computes
 * in real_t. */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "fw_internal.h"

int32_t fwt_core_size(void) { return (int32_t)sizeof(fw_core_t); }
int32_t fwt_real_size(void) { return (int32_t)sizeof(real_t); }

/* out: cmp_up[3], cmp_dn[3], n_soc, soc[16], layout, sector, clipped,
 *      3 x (measured, vec, start, end, soc_first, soc_count), t_odd, t_even, vec_odd, vec_even
 *      (48 ints); v_applied: 2 doubles; carry_io: 2 doubles or NULL */
int32_t fwt_svpwm(double vdc, double valpha, double vbeta, double tmin_us, double on_us,
                  double off_us, int32_t n_per_state, int32_t stretch, uint32_t parity,
                  double *carry_io, int32_t *out, double *v_applied)
{
    fw_pwm_cfg_t cfg;
    fw_plan_t pl;
    fw_mod_t mod;
    int32_t i;
    int32_t w;
    memset(&cfg, 0, sizeof cfg); /* one layout family (no A/B pairs), no sector hold */
    cfg.tmin = (uint16_t)(tmin_us * 100.0 + 0.5);
    cfg.soc_on = (uint16_t)(on_us * 100.0 + 0.5);
    cfg.soc_off = (uint16_t)(off_us * 100.0 + 0.5);
    cfg.n_per_state = (int16_t)n_per_state;
    cfg.stretch = (int16_t)stretch;
    mod.carry = fw_c(0.0f, 0.0f);
    mod.sector = 0;
    if (carry_io != NULL) {
        mod.carry = fw_c((real_t)carry_io[0], (real_t)carry_io[1]);
    }
    fw_svpwm_plan(&cfg, (real_t)vdc, fw_c((real_t)valpha, (real_t)vbeta),
                  carry_io != NULL ? &mod : NULL, parity, &pl);
    if (carry_io != NULL) {
        carry_io[0] = mod.carry.re;
        carry_io[1] = mod.carry.im;
    }
    for (i = 0; i < 3; i++) {
        out[i] = pl.cmp_up[i];
        out[3 + i] = pl.cmp_dn[i];
    }
    out[6] = pl.n_soc;
    for (i = 0; i < 16; i++) {
        out[7 + i] = (i < pl.n_soc) ? pl.soc[i] : 0;
    }
    out[23] = pl.layout;
    out[24] = pl.sector;
    out[25] = pl.clipped;
    for (w = 0; w < 3; w++) {
        out[26 + 6 * w + 0] = pl.win[w].measured;
        out[26 + 6 * w + 1] = pl.win[w].vec;
        out[26 + 6 * w + 2] = pl.win[w].start;
        out[26 + 6 * w + 3] = pl.win[w].end;
        out[26 + 6 * w + 4] = pl.win[w].soc_first;
        out[26 + 6 * w + 5] = pl.win[w].soc_count;
    }
    out[44] = pl.t_odd;
    out[45] = pl.t_even;
    out[46] = pl.vec_odd;
    out[47] = pl.vec_even;
    v_applied[0] = pl.v_applied.re;
    v_applied[1] = pl.v_applied.im;
    return 0;
}

double fwt_svpwm_vmax(double vdc, double tmin_us)
{
    return fw_svpwm_vmax((real_t)vdc, (uint16_t)(tmin_us * 100.0 + 0.5));
}

/* LS slope of n samples (ticks, raw codes). out: slope_a, slope_b (alpha, beta A/s),
 * t_mean (ticks), i_alpha, i_beta at t_mean. */
int32_t fwt_slope_window(int32_t n, const int32_t *ticks, const int32_t *ia_codes,
                         const int32_t *ib_codes, int32_t bits, double range_a, double *out)
{
    fw_plan_t pl;
    fw_adc_t adc;
    fw_cplx_t slope, imean;
    real_t tm;
    int32_t k;
    int16_t ok;
    if (n < 2 || n > FW_MAX_SOC || bits < 8 || bits > 24) {
        return 0;
    }
    fw_svpwm_plan_off(&pl, 200.0f);
    pl.win[0].measured = 1;
    pl.win[0].soc_first = 0;
    pl.win[0].soc_count = (int16_t)n;
    adc.period = 0;
    adc.n_soc = (int16_t)n;
    adc.vdc = 0;
    for (k = 0; k < n; k++) {
        pl.soc[k] = (uint16_t)ticks[k];
        adc.ia[k] = ia_codes[k];
        adc.ib[k] = ib_codes[k];
    }
    pl.n_soc = (int16_t)n;
    ok = fw_slope_window(&pl, 0, &adc, (int32_t)1 << (bits - 1),
                         (real_t)(2.0 * range_a / (double)((int32_t)1 << bits)), &slope, &tm, &imean);
    out[0] = slope.re;
    out[1] = slope.im;
    out[2] = tm;
    out[3] = imean.re;
    out[4] = imean.im;
    return ok;
}

/* out: di_alpha, di_beta */
void fwt_slope_diff(double sa_re, double sa_im, double t_active, double s0_re, double s0_im,
                    double t_zero, double omega, double *out)
{
    fw_cplx_t d = fw_slope_diff(fw_c((real_t)sa_re, (real_t)sa_im), (real_t)t_active,
                                fw_c((real_t)s0_re, (real_t)s0_im), (real_t)t_zero, (real_t)omega);
    out[0] = d.re;
    out[1] = d.im;
}

/* di: 2 complex (re, im, re, im); t: 2 times (s). out: theta_raw, gamma0, gamma1, g_re, g_im,
 * residual, t_ref, n_active. Returns ok. */
int32_t fwt_slope_solve(int32_t n_active, const int32_t *vec, const double *di, const double *t,
                      double kv, double omega, double gamma0_prior, double *out)
{
    int16_t v[2];
    fw_cplx_t d[2];
    real_t tt[2];
    fw_est_out_t e;
    int32_t k;
    for (k = 0; k < 2; k++) {
        v[k] = (int16_t)((k < n_active) ? vec[k] : 1);
        d[k] = fw_c((real_t)((k < n_active) ? di[2 * k] : 0.0),
                    (real_t)((k < n_active) ? di[2 * k + 1] : 0.0));
        tt[k] = (real_t)((k < n_active) ? t[k] : 0.0);
    }
    fw_slope_solve((int16_t)n_active, v, d, tt, (real_t)kv, (real_t)omega, (real_t)gamma0_prior, &e);
    out[0] = e.theta_raw;
    out[1] = e.gamma0;
    out[2] = e.gamma1;
    out[3] = e.g.re;
    out[4] = e.g.im;
    out[5] = e.residual;
    out[6] = e.t_ref;
    out[7] = e.n_active;
    return e.ok;
}

/* PLL branch selection / update on a bare tracker (for the Python tracker tests). */
int32_t fwt_tracker_size(void) { return (int32_t)sizeof(fw_tracker_t); }
void fwt_tracker_init(void *pll, double bw_hz, double zeta, double theta, double omega)
{
    fw_tracker_config((fw_tracker_t *)pll, (real_t)bw_hz, (real_t)zeta);
    fw_tracker_reset((fw_tracker_t *)pll, (real_t)theta, (real_t)omega, 0);
}
/* advance one period and update with a raw estimate (mod pi) at stamp; out: theta_meas,
 * eps, theta, omega */
void fwt_tracker_step(void *pll, double theta_raw, int32_t stamp, double *out)
{
    fw_tracker_t *p = (fw_tracker_t *)pll;
    real_t meas;
    real_t eps;
    fw_tracker_advance(p, FW_P_TICKS);
    eps = fw_tracker_update(p, (real_t)theta_raw, (uint16_t)stamp, &meas);
    out[0] = meas;
    out[1] = eps;
    out[2] = p->theta;
    out[3] = p->omega;
}

double fwt_refs_mtpa_id(double iq, double ld, double lq, double lambda)
{
    return fw_refs_mtpa_id((real_t)iq, (real_t)ld, (real_t)lq, (real_t)lambda);
}

double fwt_refs_fluxweak_id(double iq, double omega, double vmax, double ld, double lq, double lambda)
{
    return fw_refs_fluxweak_id((real_t)iq, (real_t)omega, (real_t)vmax, (real_t)ld, (real_t)lq,
                    (real_t)lambda);
}

double fwt_refs_torque(double id, double iq, double ld, double lq, double lambda, double pp)
{
    return fw_refs_torque((real_t)id, (real_t)iq, (real_t)ld, (real_t)lq, (real_t)lambda, (real_t)pp);
}

/* out: id_ref, iq_ref; returns fw_active */
int32_t fwt_refs_select(int32_t mode, double iq_demand, double omega, double vmax, double i_max,
                         double ld, double lq, double lambda, double did_fb, double *out)
{
    real_t id;
    real_t iq;
    int16_t fw = fw_refs_select((int16_t)mode, (real_t)iq_demand, (real_t)omega, (real_t)vmax,
                                 (real_t)i_max, (real_t)ld, (real_t)lq, (real_t)lambda,
                                 (real_t)did_fb, &id, &iq);
    out[0] = id;
    out[1] = iq;
    return fw;
}

/* flux estimator on a bare state */
int32_t fwt_flux_size(void) { return (int32_t)sizeof(fw_flux_t); }
void fwt_flux_reset(void *f, double lambda_nom) { fw_flux_reset((fw_flux_t *)f, (real_t)lambda_nom); }
/* out: lambda_inst, lambda_f, psi_re, psi_im; returns 1 when updated */
int32_t fwt_flux_update(void *f, double u_re, double u_im, double omega, double ratio,
                        double omega_min, double theta_end, double i_re, double i_im, double ld,
                        double lambda_nom, double alpha, double *out)
{
    fw_flux_t *fl = (fw_flux_t *)f;
    int16_t r = fw_flux_update(fl, fw_c((real_t)u_re, (real_t)u_im), (real_t)omega, (real_t)omega,
                               (real_t)ratio, (real_t)omega_min, (real_t)omega_min, (real_t)theta_end,
                               fw_c((real_t)i_re, (real_t)i_im), (real_t)ld, (real_t)lambda_nom,
                               (real_t)alpha);
    out[0] = fl->lambda_inst;
    out[1] = fl->lambda_f;
    out[2] = fl->psi.re;
    out[3] = fl->psi.im;
    return r;
}

/* parameter estimator on a bare state: feed one estimate; out: ld_inc, lq_inc, lq_app(iq) */
int32_t fwt_paramest_size(void) { return (int32_t)sizeof(fw_param_est_t); }
void fwt_paramest_reset(void *pe, double ld, double lq, double i_max)
{
    fw_paramest_reset((fw_param_est_t *)pe, (real_t)ld, (real_t)lq, (real_t)i_max);
}
void fwt_paramest_update(void *pe, double gamma0, double g_re, double g_im, double theta_ref, double iq,
                   double alpha, double *out)
{
    fw_param_est_t *p = (fw_param_est_t *)pe;
    fw_est_out_t e;
    e.n_active = 2;
    e.ok = 1;
    e.gamma0 = (real_t)gamma0;
    e.g = fw_c((real_t)g_re, (real_t)g_im);
    e.gamma1 = fw_cabs(e.g);
    e.theta_raw = 0.0f;
    e.residual = 0.0f;
    e.t_ref = 0.0f;
    fw_paramest_update(p, &e, (real_t)theta_ref, (real_t)iq, (real_t)alpha, 1e-4f, 1.0f);
    fw_paramest_apparent(p, (real_t)iq);
    out[0] = p->ld_inc;
    out[1] = p->lq_inc;
    out[2] = p->lq_app;
}
void fwt_paramest_apparent(void *pe, double iq, double *out)
{
    fw_param_est_t *p = (fw_param_est_t *)pe;
    fw_paramest_apparent(p, (real_t)iq);
    out[0] = p->lq_app;
}

/* The whole core's status, fw_status_t by names: its fields (FW_STATUS_FIELDS, fw_core.h) as
 * rows of name, byte offset and C type, from which tests/python/firmware/fwlib.py builds its
 * ctypes mirror of the struct; no order is agreed on across the boundary. */
#define FWT_STATUS_ROW(type, name) {#name, (int32_t)offsetof(fw_status_t, name), #type},
static const struct {
    const char *name;
    int32_t offset;
    const char *type;
} STATUS_ROWS[] = {FW_STATUS_FIELDS(FWT_STATUS_ROW)};

int32_t fwt_status_size(void) { return (int32_t)sizeof(fw_status_t); }

/* field i of fw_status_t: its name, *offset (bytes) and *type ("int16_t", "real_t", ...);
 * NULL past the last */
const char *fwt_status_field(int32_t i, int32_t *offset, const char **type)
{
    if (i < 0 || i >= (int32_t)(sizeof(STATUS_ROWS) / sizeof(STATUS_ROWS[0]))) {
        return NULL;
    }
    *offset = STATUS_ROWS[i].offset;
    *type = STATUS_ROWS[i].type;
    return STATUS_ROWS[i].name;
}

void fwt_status(const fw_core_t *c, fw_status_t *out)
{
    fw_core_status(c, out);
}

/* command without struct layouts */
int32_t fwt_command(fw_core_t *c, int32_t enable, int32_t fault_reset, int32_t ctrl_mode,
                    int32_t fw_mode, double speed_ref_rpm, double iq_ref)
{
    fw_cmd_t cmd;
    cmd.enable = (int16_t)enable;
    cmd.fault_reset = (int16_t)fault_reset;
    cmd.ctrl_mode = (int16_t)ctrl_mode;
    cmd.fw_mode = (int16_t)fw_mode;
    cmd.speed_ref_rpm = (real_t)speed_ref_rpm;
    cmd.iq_ref = (real_t)iq_ref;
    return fw_core_command(c, &cmd);
}

int32_t fwt_param_set(fw_core_t *c, int32_t id, double value)
{
    return fw_param_set(c, (uint16_t)id, (real_t)value);
}

int32_t fwt_param_get(const fw_core_t *c, int32_t id, double *value)
{
    real_t v = 0.0f;
    int16_t st = fw_param_get(c, (uint16_t)id, &v);
    *value = v;
    return st;
}

/* one ISR with flat arrays: adc_ia/ib codes[n_soc]; adc_null != 0 passes NULL.
 * pwm_out: period(low 31 bits), cmp_up[3], cmp_dn[3], n_soc, soc[16], gate (24 ints) */
void fwt_isr(fw_core_t *c, int32_t adc_null, uint32_t period, int32_t n_soc, const int32_t *ia,
             const int32_t *ib, int32_t vdc_code, int32_t *pwm_out)
{
    fw_adc_t adc;
    fw_pwm_t pwm;
    int32_t k;
    adc.period = period;
    adc.n_soc = (int16_t)n_soc;
    adc.vdc = vdc_code;
    for (k = 0; k < FW_MAX_SOC; k++) {
        adc.ia[k] = (k < n_soc) ? ia[k] : 0;
        adc.ib[k] = (k < n_soc) ? ib[k] : 0;
    }
    fw_core_isr(c, adc_null ? NULL : &adc, &pwm);
    pwm_out[0] = (int32_t)pwm.period;
    for (k = 0; k < 3; k++) {
        pwm_out[1 + k] = pwm.cmp_up[k];
        pwm_out[4 + k] = pwm.cmp_dn[k];
    }
    pwm_out[7] = pwm.n_soc;
    for (k = 0; k < FW_MAX_SOC; k++) {
        pwm_out[8 + k] = pwm.soc[k];
    }
    pwm_out[24] = pwm.gate_enable;
}
