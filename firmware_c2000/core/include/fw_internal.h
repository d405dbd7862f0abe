/* fw_internal.h - module interfaces inside the control core (not for the HAL). */
#ifndef FW_INTERNAL_H
#define FW_INTERNAL_H

#include "fw_core.h"
#include "fw_params_gen.h"

#define FW_TICK_S (FW_REAL(1.0) / FW_TBCLK_HZ)
#define FW_SIX_STEP ((real_t)0.63661977236758134308) /* six-step fundamental per Vdc, 2/pi */
#define FW_FLUX_VALID_UPDATES 2000 /* 0.2 s of plausible flux before MTPA/FW use it */
#define FW_P_TICKS ((int32_t)FW_PERIOD_TICKS)
#define FW_H_TICKS ((int32_t)FW_TBPRD)
#define FW_RPM_PER_RADS ((real_t)9.54929658551372014613) /* 60 / (2 pi) */

/* ---- svpwm.c: pattern, stretching, sampling plan ------------------------------------------ */
/* cos/sin of phi_k = (k-1)*60 deg, k = 1..6 (svpwm.c) and the switching states of V1..V6 */
extern const real_t fw_svpwm_vec_cos[6];
extern const real_t fw_svpwm_vec_sin[6];
extern const int16_t fw_svpwm_vec_bits[6];
/* Unit vector of active vector k (1..6) at phi_k = (k-1)*pi/3 and of 2*phi_k (inline: the
 * estimator and the modulator take them every period). */
static inline fw_cplx_t fw_svpwm_vec_unit(int16_t k)
{
    const int16_t i = (int16_t)((k - 1) % 6);
    return fw_c(fw_svpwm_vec_cos[i], fw_svpwm_vec_sin[i]);
}
static inline fw_cplx_t fw_svpwm_vec_unit2(int16_t k)
{
    const int16_t i = (int16_t)((2 * (k - 1)) % 6);
    return fw_c(fw_svpwm_vec_cos[i], fw_svpwm_vec_sin[i]);
}
/* switching state bits (a = 1, b = 2, c = 4) of active vector k */
static inline int16_t fw_svpwm_vec_state(int16_t k) { return fw_svpwm_vec_bits[(k - 1) % 6]; }
/* alpha-beta voltage of a switching state with an isolated neutral: 2/3 vdc and vdc/sqrt3
 * times the state's multipliers (0, +-1/2, +-1, exact), the bits of the phase sums
 * (sa - (sb + sc)/2, sb - sc) they stand for; inline, as it is in every loop over a pattern */
static inline fw_cplx_t fw_svpwm_state_voltage(int16_t state_bits, real_t vdc)
{
    static const real_t m_re[8] = {FW_REAL(0.0), FW_REAL(1.0),  FW_REAL(-0.5), FW_REAL(0.5),
                                   FW_REAL(-0.5), FW_REAL(0.5), FW_REAL(-1.0), FW_REAL(0.0)};
    static const real_t m_im[8] = {FW_REAL(0.0), FW_REAL(0.0),  FW_REAL(1.0), FW_REAL(1.0),
                                   FW_REAL(-1.0), FW_REAL(-1.0), FW_REAL(0.0), FW_REAL(0.0)};
    const int16_t s = (int16_t)(state_bits & 7);
    return fw_c(vdc * (FW_REAL(2.0) / FW_REAL(3.0)) * m_re[s], vdc * FW_M_INV_SQRT3 * m_im[s]);
}
/* Largest voltage magnitude that still leaves a V7 window of tmin in every direction. */
real_t fw_svpwm_vmax(real_t vdc, uint16_t tmin_ticks);
/* Plan period pattern for average voltage v_ref (alpha-beta, V). mod: carry and last sector
 * (in/out, may be NULL: no carry, no sector hold). parity: the period index; odd periods are the
 * B half of an A/B pair (mirrored layouts, cfg->pairs) and alternate single-vector
 * measurements when needed. */
void fw_svpwm_plan(const fw_pwm_cfg_t *cfg, real_t vdc, fw_cplx_t v_ref, fw_mod_t *mod,
                   uint32_t parity, fw_plan_t *plan);
void fw_svpwm_plan_off(fw_plan_t *plan, real_t vdc);
/* Overmodulation table of the minimum-distance projection: reference magnitudes and their
 * fundamentals, units of Vdc/sqrt3 (1 = the linear limit; six-step is 2*sqrt3/pi = 1.1027). */
void fw_svpwm_om_init(real_t ref[FW_OM_N], real_t fund[FW_OM_N]);
/* Reference magnitude whose projected pattern has fundamental v1 (same units). */
real_t fw_svpwm_om_ref(const real_t ref[FW_OM_N], const real_t fund[FW_OM_N], real_t v1);
/* the pattern as the PWM command of a period (compares, SOCs, gate enable) */
void fw_svpwm_to_pwm(const fw_plan_t *plan, uint32_t period, int16_t gate, fw_pwm_t *pwm);

/* ---- inverter_model.c: dead time and device drop ------------------------------------------ */
/* phase currents (a, b, c) of an alpha-beta current, and alpha-beta of phase voltages */
static inline real_t fw_inverter_phase_b(fw_cplx_t i)
{
    return FW_REAL(-0.5) * i.re + FW_REAL(0.5) * FW_M_SQRT3 * i.im;
}
static inline real_t fw_inverter_phase_c(fw_cplx_t i)
{
    return FW_REAL(-0.5) * i.re - FW_REAL(0.5) * FW_M_SQRT3 * i.im;
}
static inline void fw_inverter_phase_currents(fw_cplx_t i, real_t iph[3])
{
    iph[0] = i.re;
    iph[1] = fw_inverter_phase_b(i);
    iph[2] = fw_inverter_phase_c(i);
}
static inline fw_cplx_t fw_inverter_phase_to_ab(const real_t v[3])
{
    return fw_c((FW_REAL(2.0) / FW_REAL(3.0)) * (v[0] - FW_REAL(0.5) * (v[1] + v[2])),
                (v[1] - v[2]) * FW_M_INV_SQRT3);
}
/* the device drop over a stretch in which the current moves linearly from i0 to i1, V */
fw_cplx_t fw_inverter_drop_voltage(const fw_core_t *c, fw_cplx_t i0, fw_cplx_t i1);
/* the current of window w of c->plan_cur at its first and last sample (its slope's stretch) */
void fw_inverter_window_span(const fw_core_t *c, int16_t w, fw_cplx_t *i0, fw_cplx_t *i1);
/* the device drop over the sampled stretch of window w of c->plan_cur, V */
fw_cplx_t fw_inverter_window_drop(const fw_core_t *c, int16_t w);
/* Mean inverter voltage error of the period of c->plan_cur at current c->i_avg (dead time
 * deadtime_us, device drop vdrop_v), alpha-beta, V: applied minus pattern voltage. */
fw_cplx_t fw_inverter_error(const fw_core_t *c);

/* ---- current_recon.c: the period's current from its samples ------------------------------- */
/* an angle and its fw_cexpj, once computed, for the others who need it in the same period */
typedef struct {
    int16_t valid; /* e is fw_cexpj(th) (th is always set) */
    real_t th;     /* rad */
    fw_cplx_t e;
} fw_angle_t;
/* fw_cexpj(-a->th) without its own reduction when a is valid: the conjugate of a->e, bit for
 * bit, where both its components are nonzero and finite (fw_sincos is odd in x except where
 * its reduced argument is zero, which leaves one component a zero) */
static inline fw_cplx_t fw_angle_conj(const fw_angle_t *a)
{
    const fw_cplx_t e = a->e;
    if (a->valid && e.re != FW_REAL(0.0) && e.im != FW_REAL(0.0) && fw_is_finite(e.re) &&
        fw_is_finite(e.im)) {
        return fw_cconj(e);
    }
    return fw_cexpj(-a->th);
}
/* c->i_avg (period mean) and c->i_end from the samples of c->plan_cur and the slopes; mid2,
 * when valid: the tracker's angle at the period's middle doubled with its fw_cexpj (else it is
 * predicted here) */
void fw_recon_current(fw_core_t *c, const fw_adc_t *adc, const fw_angle_t *mid2);
/* mean over pattern pl of the product of the dq components of its current ripple, A^2 */
real_t fw_recon_ripple_dq_product(const fw_core_t *c, const fw_plan_t *pl);
/* the same with the tracker's angle at the next period's middle and its fw_cexpj given
 * (the current loop's, fw_core.c) */
real_t fw_recon_ripple_dq_product_at(const fw_core_t *c, const fw_plan_t *pl,
                                     const fw_angle_t *mid_next);

/* ---- outer_loop.c: the 1 kHz tasks -------------------------------------------------------- */
/* ld_use, lq_use, lambda_use of the selected MTPA/FW mode */
void fw_outer_select_parameters(fw_core_t *c);
/* speed ramp, speed PI, MTPA/FW current references and the voltage feedback */
void fw_outer_step(fw_core_t *c);

/* ---- slope_estimator.c: slopes and the least-squares position estimate --------------------- */
/* LS slope of window w: A/s alpha-beta, mean sample time (ticks), current at that time (A). */
/* Gamma(theta) v = Gamma0 v + g conj(v), g = Gamma1 exp(j 2 theta) */
static inline fw_cplx_t fw_slope_gamma_times(real_t gamma0, fw_cplx_t g, fw_cplx_t v)
{
    return fw_cadd(fw_cscale(v, gamma0), fw_cmul(g, fw_cconj(v)));
}
int16_t fw_slope_window(const fw_plan_t *plan, int16_t w, const fw_adc_t *adc, int32_t adc_half,
                        real_t lsb, fw_cplx_t *slope, real_t *t_mean_ticks, fw_cplx_t *i_mean);
/* Section 4.5: rotate the zero-state slope to the active window's time before differencing. */
fw_cplx_t fw_slope_diff(fw_cplx_t s_active, real_t t_active, fw_cplx_t s_zero, real_t t_zero,
                        real_t omega);
/* Section 3 with the rotation of g between windows; n_active 1 uses gamma0_prior. */
void fw_slope_solve(int16_t n_active, const int16_t vec[2], const fw_cplx_t di[2],
                  const real_t t[2], real_t kv, real_t omega, real_t gamma0_prior,
                  fw_est_out_t *out);

/* ---- position_tracker.c: mechanical observer, speed-scheduled, branch selection --------- */
/* bw_hz: the fastest loop (convergence, high speed), zeta its damping */
void fw_tracker_config(fw_tracker_t *pll, real_t bw_hz, real_t zeta);
/* the floor low_bw_hz (meant for a raw estimate no noisier than noise_ref_deg, electrical;
 * 0: a fixed floor), the speed schedule wn = speed_ratio * |omega_e|, and the disturbance
 * detector's threshold boost_sigma (0: none); without it the loop runs at bw_hz */
void fw_tracker_config_schedule(fw_tracker_t *pll, real_t low_bw_hz, real_t speed_ratio,
                            real_t boost_sigma, real_t noise_ref_deg);
/* once per period before the update: gains for the present speed and convergence state;
 * returns wn, rad/s */
real_t fw_tracker_schedule(fw_tracker_t *pll);
/* acceleration the torque model predicts until the next update, electrical rad/s^2 */
void fw_tracker_set_accel(fw_tracker_t *pll, real_t a_ff);
void fw_tracker_reset(fw_tracker_t *pll, real_t theta, real_t omega, uint16_t stamp);
void fw_tracker_advance(fw_tracker_t *pll, int32_t ticks);
real_t fw_tracker_predict(const fw_tracker_t *pll, int32_t tick_in_period);
/* Branch nearest the prediction (docs/estimator.md §7); returns the error epsilon (rad) and the
 * selected measurement in *theta_meas. */
real_t fw_tracker_update(fw_tracker_t *pll, real_t theta_raw_mod_pi, uint16_t stamp, real_t *theta_meas);
void fw_tracker_flip(fw_tracker_t *pll);

/* ---- param_estimator.c: Ld, Lq (incremental) and the apparent values -------------------- */
void fw_paramest_reset(fw_param_est_t *pe, real_t ld, real_t lq, real_t i_max);
void fw_paramest_update(fw_param_est_t *pe, const fw_est_out_t *est, real_t theta_ref, real_t iq,
                  real_t alpha, real_t l_lo, real_t l_hi);
void fw_paramest_apparent(fw_param_est_t *pe, real_t iq);
/* Gamma0 for the single-vector fallback at q current iq (section 3): the fast-filtered value
 * moved along the learnt Gamma0(iq) curve from the current it was measured at */
real_t fw_paramest_gamma0_prior(const fw_param_est_t *pe, real_t iq);
/* Gamma1 along the d axis at theta: Re(g exp(-j 2 theta)), so 1/Ld_inc = Gamma0 + it and
 * 1/Lq_inc = Gamma0 - it (docs/estimator.md §3) */
real_t fw_paramest_gamma1_at(const fw_est_out_t *est, real_t theta);
/* Largest |iq| at which the learnt incremental saliency Gamma1 stays above gamma1_min (linear
 * extrapolation of the measured bins); i_max when no measured bin approaches it. */
/* d(1/Lq_inc)/d iq at iq from the learnt curve, 1/(H*A) (0 until two points are learnt) */
real_t fw_paramest_inv_lq_slope(const fw_param_est_t *pe, real_t iq);
/* 1 when the Lq bin of |iq| has had at least min_updates slope estimates */
int16_t fw_paramest_iq_learnt(const fw_param_est_t *pe, real_t iq, int16_t min_updates);
real_t fw_paramest_saliency_iq_limit(const fw_param_est_t *pe, real_t gamma1_min, real_t i_max);
/* Turn of the saliency axes by cross-saturation at q current iq, rad, for an incremental Ldq
 * of ldq_per_a * iq (H) and the learnt Lq curve */
real_t fw_paramest_xsat_angle(const fw_param_est_t *pe, real_t iq, real_t ldq_per_a);
/* one period's |g| exp(j2 turn) (turn: the saliency axes against the flux angle) at q current
 * iq: into the mean, started anew at another current */
void fw_paramest_xsat_learn(fw_param_est_t *pe, fw_cplx_t sample, real_t iq, real_t alpha);

/* ---- flux_estimator.c -------------------------------------------------------------------- */
void fw_flux_reset(fw_flux_t *f, real_t lambda_nom);
/* One period: u = (v - rs*i)*Ts integral of the period (V*s). Returns 1 when lambda updated. */
/* omega: PLL speed (filter corner, compensation); omega_gate: filtered speed that decides
 * whether the voltage model is usable (|omega_gate| >= omega_min) and whether lambda_m is
 * learnt (|omega_gate| >= omega_learn_min: the voltage errors weigh 1/omega in the flux, so
 * the sign of lambda_d is trusted at lower speeds than its size); lambda_nom bounds the
 * plausible lambda (0.5..1.5 x). */
int16_t fw_flux_update(fw_flux_t *f, fw_cplx_t u, real_t omega, real_t omega_gate, real_t ratio,
                       real_t omega_min, real_t omega_learn_min, real_t theta_end,
                       fw_cplx_t i_end, real_t ld_app, real_t lambda_nom, real_t alpha);
/* active, its start forgotten: exp(-settle_tc) (flux_estimator.c) */
static inline int16_t fw_flux_settled(const fw_flux_t *f, real_t settle_tc)
{
    return (int16_t)(f->active && f->settle_tc >= settle_tc);
}
/* Starts the estimator at the stator flux psi (V*s, alpha-beta) at electrical speed omega, as
 * if it had run settle_tc time constants (the flux is known, e.g. from the start-up's
 * back-EMF test); omega_min, ratio as fw_flux_update. */
void fw_flux_seed(fw_flux_t *f, fw_cplx_t psi, real_t omega, real_t ratio, real_t omega_min,
                  real_t settle_tc);

/* ---- current_refs.c (paper eqs. 10, 50, 53) ----------------------------------------------------- */
real_t fw_refs_mtpa_id(real_t iq, real_t ld, real_t lq, real_t lambda);
real_t fw_refs_mtpa_id_on_circle(real_t i_max, real_t ld, real_t lq, real_t lambda);
real_t fw_refs_fluxweak_id(real_t iq, real_t omega, real_t vmax, real_t ld, real_t lq, real_t lambda);
int16_t fw_refs_circle_ellipse_id(real_t i_max, real_t omega, real_t vmax, real_t ld, real_t lq,
                             real_t lambda, real_t *id);
real_t fw_refs_torque(real_t id, real_t iq, real_t ld, real_t lq, real_t lambda, real_t pole_pairs);
/* d current that makes the q current iq (|iq| <= |iq_demand|, same sign) produce the torque of
 * the MTPA point of iq_demand through the reluctance term (<= 0; 0 without saliency). */
real_t fw_refs_id_for_torque(real_t iq_demand, real_t iq, real_t ld, real_t lq, real_t lambda);
/* Current references from a q-current demand (mode FW_FWMODE_*). Returns 1 when the voltage
 * limit (flux weakening) is active. did_fb: extra d-current from the voltage feedback (<= 0). */
int16_t fw_refs_select(int16_t mode, real_t iq_demand, real_t omega, real_t vmax, real_t i_max,
                        real_t ld, real_t lq, real_t lambda, real_t did_fb, real_t *id_ref,
                        real_t *iq_ref);

/* ---- current_ctrl.c / speed_ctrl.c --------------------------------------------------------- */
/* dq current PI with decoupling, vector voltage limit and anti-windup (the integral held where
 * it alone reaches the limit); u_mag: the demand's magnitude before the limit. */
void fw_current_ctrl(fw_pi_t *pid, fw_pi_t *piq, real_t id_ref, real_t iq_ref, real_t id,
                     real_t iq, real_t omega, real_t ld, real_t lq, real_t lambda, real_t rs,
                     real_t v_lim, real_t ts, real_t *vd, real_t *vq, real_t *u_mag);
real_t fw_speed_ctrl_ramp(real_t y, real_t target, real_t step);
real_t fw_speed_ctrl(fw_pi_t *pi, real_t ref_rpm, real_t speed_rpm, real_t iq_lim, real_t ts);

/* ---- protection.c ------------------------------------------------------------------------- */
/* A code minus the mid-scale code, for any int32 input: the subtraction is done in real_t (an
 * int32 difference overflows for codes near INT32_MIN). Exact for every code of a converter of
 * up to 24 bits (the float mantissa). */
static inline real_t fw_protection_adc_offset(int32_t code, int32_t adc_half)
{
    return (real_t)code - (real_t)adc_half;
}
int16_t fw_protection_codes_in_range(const fw_adc_t *adc, int32_t adc_half); /* all in 0..2^N-1 */
int16_t fw_protection_codes_frozen(const fw_adc_t *adc); /* bit 0: ia, bit 1: ib one code */
uint16_t fw_protection_samples(const fw_adc_t *adc, int32_t adc_half, real_t lsb, real_t oc_trip,
                            real_t *i_peak);
uint16_t fw_protection_vdc(real_t vdc, real_t ov, real_t uv, int16_t check_uv);

/* ---- polarity_detect.c -------------------------------------------------------------------- */
typedef struct {
    real_t id, iq;     /* current references along the estimated frame, A */
    fw_cplx_t v_ff;    /* alpha-beta voltage added to the current loop's (the catch), V */
} fw_polarity_out_t;
#define FW_POL_METHOD_SATURATION 1
#define FW_POL_METHOD_MOTION 2
#define FW_POL_METHOD_EMF 3 /* the back-EMF test: the shaft was turning */
#define FW_POL_METHOD_CATCH 4 /* the catch: the shaft turned fast, its back-EMF gave the angle */
void fw_polarity_start(fw_polarity_t *pol);
/* After a decision: the shaft's electrical speed at the enable (the straight line through the
 * back-EMF window's q back-EMF, extended back from the window's first period), now (the end of
 * the last period) and its acceleration; 0 when the window is too short. */
int16_t fw_polarity_motion(const fw_polarity_t *pol, real_t lambda_m, real_t *omega_start,
                           real_t *omega_now, real_t *accel);
/* One period; returns pol->result (0 running, 1 done, -1 failed). */
int16_t fw_polarity_step(fw_polarity_t *pol, const fw_core_t *c, const fw_adc_t *adc,
                    fw_polarity_out_t *out);
/* The polarity watch in RUN, once per period with data: -1 when the tracked frame points to
 * the south pole (the caller turns it round), else 0. */
void fw_polarity_watch_reset(fw_polarity_watch_t *wt, uint16_t flips);
int16_t fw_polarity_watch_step(fw_polarity_watch_t *wt, const fw_core_t *c);
/* After a -1: the shaft's electrical speed now, from the weighted straight line through the
 * last ~2 ms of q back-EMF (measured in the frame before it was turned round); 0 when too
 * short. */
int16_t fw_polarity_watch_motion(const fw_polarity_watch_t *wt, real_t lambda_m, real_t *omega_now);

/* ---- params.c ----------------------------------------------------------------------------- */
extern const fw_param_info_t fw_param_table[FW_PARAM_COUNT];
void fw_params_defaults(fw_core_t *c);
void fw_params_apply(fw_core_t *c); /* recompute derived values */
int16_t fw_param_index(uint16_t id);

#endif /* FW_INTERNAL_H */
