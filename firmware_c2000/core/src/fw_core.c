/* fw_core.c - states, ISR orchestration, commands and status of the control core.
 *
 * ISR k (after the last conversion of PWM period k):
 *   1. bookkeeping: is this the ADC frame of the period the core planned (else: ADC loss)?
 *   2. protection on every sample (over-current) and on the DC link;
 *   3. slopes of the measured states, least-squares estimate, tracker (theta_hat, its stamp);
 *   4. period-mean current from the samples and the slopes, dq currents, online Ld/Lq and
 *      the flux estimator;
 *   5. state machine: idle / polarity / run / fault; 1 kHz tasks on every 10th call;
 *   6. current PI -> voltage for period k+1 -> SVPWM pattern and sampling plan.
 */
#include "fw_internal.h"

#define FW_RPM(omega_e, pp) ((omega_e) / (pp) * FW_RPM_PER_RADS)
#define FW_FLUX_NEG_PERIODS 50   /* 5 ms of lambda_d below -lambda_m / 2: polarity lost */
#define FW_EST_VALID_MAX_RUN 50  /* est_valid drops after 5 ms without a good estimate */
/* start's saliency governor (start_after_motion): filter per two-vector estimate (~1 ms),
 * headroom above the load's current, step of the limit per period (10/20 A/s down/up) */
#define FW_START_GOV_ALPHA FW_REAL(0.2)
#define FW_START_GOV_HEADROOM_A FW_REAL(0.25)
#define FW_START_GOV_STEP_A FW_REAL(0.001)
/* periods after a catch in which the flux-weakening feedback holds while the currents settle */
#define FW_START_FW_HOLD 50
#define FW_FULL_LEARNT_UPDATES 150 /* Lq bin updates before FULL mode stops measuring there */
/* the current loop's response (400 Hz design bandwidth) per period, for the torque model */
#define FW_TE_MODEL_ALPHA ((real_t)0.222)
/* cross-saturation identification: from this speed and q current on (once the Lq bin of the
 * current is learnt), the mean of the turn over ~0.2 s */
#define FW_XSAT_MIN_RPM ((real_t)200.0)
#define FW_XSAT_MIN_IQ_A ((real_t)0.5)
#define FW_XSAT_ALPHA ((real_t)1e-4)
#define FW_XSAT_LEARNT_UPDATES 300

static const fw_core_t fw_core_zero;

static void enter_fault(fw_core_t *c, uint16_t code)
{
    if (c->state != FW_STATE_FAULT) {
        c->fault_code = code;
    }
    c->state = FW_STATE_FAULT;
}

static void reset_estimation(fw_core_t *c)
{
    const real_t *p = c->p;
    c->trk.init = 0;
    c->trk.omega = FW_REAL(0.0);
    c->trk.theta = FW_REAL(0.0);
    c->trk.theta_unwrapped = FW_REAL(0.0);
    c->trk.age_ticks = 0;
    fw_paramest_reset(&c->pe, p[FW_IDX_LD_H], p[FW_IDX_LQ_H], p[FW_IDX_I_MAX_A]);
    fw_flux_reset(&c->flux, p[FW_IDX_LAMBDA_M_WB]);
    c->flux_pos_active = 0;
    c->start_recover = 0;
    c->start_gov = 0;
    c->start_fw_hold = 0;
    c->est_valid = 0;
    c->est_fail_run = 0;
    c->sensor_bad = 0;
    c->vec_proj[0] = c->vec_proj[1] = FW_REAL(0.0);
    c->codes_frozen = 0;
    c->polarity_ok = 0;
    c->flips_in_window = 0;
    c->flip_window_ticks = 0;
    fw_polarity_watch_reset(&c->watch, c->polarity_flips);
    c->watch.decided_north = 0;
}

static void reset_control(fw_core_t *c)
{
    c->pi_d.x = FW_REAL(0.0); /* the PI integrators */
    c->pi_q.x = FW_REAL(0.0);
    c->pi_spd.x = FW_REAL(0.0);
    c->id_ref = c->iq_ref = FW_REAL(0.0);
    c->id_ref_base = FW_REAL(0.0);
    c->vd = c->vq = FW_REAL(0.0);
    c->iq_demand = FW_REAL(0.0);
    c->fluxweak_did = FW_REAL(0.0);
    c->fluxweak_active = 0;
    c->u_mag = FW_REAL(0.0);
    c->v_mag_f = FW_REAL(0.0);
    c->mod.carry = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    c->mod.sector = 0;
}

void fw_core_init(fw_core_t *c)
{
    if (c == 0) {
        return;
    }
    *c = fw_core_zero;
    fw_params_defaults(c);
    fw_params_apply(c);
    c->state = FW_STATE_INIT;
    c->fault_code = FW_FAULT_NONE;
    c->cmd.ctrl_mode = FW_CTRL_SPEED;
    c->cmd.fw_mode = FW_FWMODE_REALTIME;
    c->vdc = c->p[FW_IDX_VDC_NOM_V];
    c->vdc_f = c->vdc;
    fw_svpwm_om_init(c->om_ref, c->om_fund);
    fw_svpwm_plan_off(&c->plan_cur, c->vdc);
    fw_svpwm_plan_off(&c->plan_next, c->vdc);
    reset_estimation(c);
    reset_control(c);
    c->ld_use = c->p[FW_IDX_LD_H];
    c->lq_use = c->p[FW_IDX_LQ_H];
    c->lambda_use = c->p[FW_IDX_LAMBDA_M_WB];
}

void fw_core_note_overrun(fw_core_t *c)
{
    if (c != 0 && c->isr_overruns < 65535u) {
        c->isr_overruns++;
    }
}

/* ---------------------------------------------------------------------------------------- */
/* API: command and limits                                                                   */

int16_t fw_core_command(fw_core_t *c, const fw_cmd_t *cmd)
{
    int16_t st = FW_STATUS_OK;
    if (c == 0 || cmd == 0) {
        return FW_STATUS_BAD_ARG;
    }
    if ((cmd->enable != 0 && cmd->enable != 1) || (cmd->fault_reset != 0 && cmd->fault_reset != 1) ||
        (cmd->ctrl_mode != FW_CTRL_SPEED && cmd->ctrl_mode != FW_CTRL_CURRENT) ||
        (cmd->fw_mode < FW_FWMODE_REALTIME || cmd->fw_mode > FW_FWMODE_ID_ZERO)) {
        st = FW_STATUS_OUT_OF_RANGE;
    } else if (!fw_is_finite(cmd->speed_ref_rpm) || !fw_is_finite(cmd->iq_ref)) {
        st = FW_STATUS_OUT_OF_RANGE;
    } else if (fw_fabs(cmd->speed_ref_rpm) > c->p[FW_IDX_SPEED_MAX_RPM] ||
               fw_fabs(cmd->iq_ref) > c->p[FW_IDX_I_MAX_A]) {
        st = FW_STATUS_OUT_OF_RANGE;
    }
    c->cmd_status = st;
    if (st != FW_STATUS_OK) {
        return st; /* nothing else changes, the time-out keeps counting */
    }
    if (cmd->enable && !c->cmd.enable) {
        c->start_request = 1;
    }
    if (!cmd->enable) {
        c->start_request = 0;
    }
    if (cmd->fault_reset && !c->cmd.fault_reset) {
        c->reset_request = 1;
    }
    c->cmd = *cmd;
    c->ticks_since_cmd = 0;
    c->have_cmd = 1;
    return FW_STATUS_OK;
}

int16_t fw_core_set_limits(fw_core_t *c, real_t i_max, real_t speed_max_rpm, real_t accel_rpm_s)
{
    const fw_param_info_t *pi_i = &fw_param_table[FW_IDX_I_MAX_A];
    const fw_param_info_t *pi_s = &fw_param_table[FW_IDX_SPEED_MAX_RPM];
    const fw_param_info_t *pi_a = &fw_param_table[FW_IDX_ACCEL_RPM_S];
    if (c == 0) {
        return FW_STATUS_BAD_ARG;
    }
    if (!fw_is_finite(i_max) || !fw_is_finite(speed_max_rpm) || !fw_is_finite(accel_rpm_s) ||
        i_max < pi_i->min || i_max > pi_i->max || !(i_max < c->p[FW_IDX_OC_TRIP_A]) ||
        speed_max_rpm < pi_s->min || speed_max_rpm > pi_s->max || accel_rpm_s < pi_a->min ||
        accel_rpm_s > pi_a->max) {
        return FW_STATUS_OUT_OF_RANGE;
    }
    c->p[FW_IDX_I_MAX_A] = i_max;
    c->p[FW_IDX_SPEED_MAX_RPM] = speed_max_rpm;
    c->p[FW_IDX_ACCEL_RPM_S] = accel_rpm_s;
    return FW_STATUS_OK;
}

/* ---------------------------------------------------------------------------------------- */
/* measurement and estimation of period k                                                    */

/* Slopes, least-squares estimate and tracker for the period just measured; with by_flux the
 * flux estimator updates the tracker this period and only the branch is taken here. Returns 1
 * when the period counted as implausible. mid2: the tracker's angle at the period's middle,
 * doubled, with its fw_cexpj, and mid_conj its fw_cexpj(-angle), valid while the tracker is as
 * they found it (the current reconstruction and the controlled current take them from here). */
static int16_t estimate_position(fw_core_t *c, const fw_adc_t *adc, int16_t by_flux,
                                 fw_angle_t *mid2, fw_cplx_t *mid_conj)
{
    const real_t *p = c->p;
    fw_plan_t *pl = &c->plan_cur;
    int16_t w;
    int16_t n_act = 0;
    int16_t vec[2];
    fw_cplx_t di[2];
    real_t t[2];
    real_t omega = c->trk.init ? c->trk.omega : FW_REAL(0.0);
    int16_t bad = 0;
    int16_t updated = 0;

    mid2->valid = 0;
    for (w = 0; w < 3; w++) {
        c->slope_ok[w] = fw_slope_window(pl, w, adc, c->adc_half, c->adc_i_lsb, &c->slope[w],
                                         &c->slope_t[w], &c->i_win[w]);
    }
    c->est.n_active = 0;
    c->est.ok = 0;
    c->est_param_ok = 0;
    if (c->slope_ok[FW_WIN_ZERO]) {
        /* q saturation: the windows see the incremental inductance at the current of their
         * own instant, which the pattern moves by up to ~0.1 A between them; to first order
         * 1/Lq_inc changes by kappa * diq (kappa from the learnt Lq curve), which adds
         * (kappa diq / 2) (v - exp(j 2 theta) conj(v)) to the slope difference of a window
         * at voltage v. Measured without it on the paper profile at 1 r/min, 2 N*m: a raw
         * bias of +0.95 deg in odd and -0.82 deg in even sectors. */
        real_t kappa = c->trk.init ? fw_paramest_inv_lq_slope(&c->pe, c->iq) : FW_REAL(0.0);
        real_t th_mid = c->trk.init ? fw_tracker_predict(&c->trk, FW_H_TICKS) : FW_REAL(0.0);
        fw_cplx_t rot2 = fw_cexpj(FW_REAL(2.0) * th_mid);
        fw_cplx_t rot_m = fw_cexpj(-th_mid);
        fw_cplx_t u0 = fw_c(FW_REAL(0.0), FW_REAL(0.0)); /* the zero window's drop, once */
        int16_t have_u0 = 0;
        mid2->valid = 1;
        mid2->th = FW_REAL(2.0) * th_mid;
        mid2->e = rot2;
        *mid_conj = rot_m;
        for (w = FW_WIN_ODD; w <= FW_WIN_EVEN; w++) {
            if (c->slope_ok[w]) {
                vec[n_act] = pl->win[w].vec;
                t[n_act] = c->slope_t[w] * FW_TICK_S;
                di[n_act] = fw_slope_diff(c->slope[w], t[n_act], c->slope[FW_WIN_ZERO],
                                          c->slope_t[FW_WIN_ZERO] * FW_TICK_S, omega);
                if (c->p[FW_IDX_VDROP_V] > FW_REAL(0.0)) {
                    /* a phase current of another sign in the active window than in the zero
                     * window: the drop differs by 2 vdrop there (measured without this at 2
                     * N*m, 1 r/min: +-2.5 deg of raw bias for 0.3 s around each phase-current
                     * zero crossing) */
                    fw_cplx_t g_f = fw_cscale(rot2, c->pe.gamma1_f);
                    fw_cplx_t du;
                    if (!have_u0) {
                        u0 = fw_inverter_window_drop(c, FW_WIN_ZERO);
                        have_u0 = 1;
                    }
                    du = fw_csub(fw_inverter_window_drop(c, w), u0);
                    di[n_act] = fw_csub(di[n_act], fw_slope_gamma_times(c->pe.gamma0_f, g_f, du));
                }
                if (kappa != FW_REAL(0.0)) {
                    fw_cplx_t v = fw_cscale(fw_svpwm_vec_unit(vec[n_act]),
                                            FW_REAL(2.0) / FW_REAL(3.0) * pl->vdc);
                    real_t diq = fw_cmul(fw_csub(c->i_win[w], c->i_win[FW_WIN_ZERO]), rot_m).im;
                    fw_cplx_t dv = fw_csub(v, fw_cmul(rot2, fw_cconj(v)));
                    di[n_act] = fw_csub(di[n_act], fw_cscale(dv, FW_REAL(0.5) * kappa * diq));
                }
                {
                    fw_cplx_t v_unit = fw_svpwm_vec_unit(vec[n_act]);
                    real_t v_len = FW_REAL(2.0) / FW_REAL(3.0) * pl->vdc;
                    c->vec_proj[n_act] = (v_len > FW_REAL(0.0))
                        ? (v_unit.re * di[n_act].re + v_unit.im * di[n_act].im) / v_len
                        : FW_REAL(0.0);
                }
                n_act++;
            }
        }
    }
    c->slopes_ok = n_act;
    if (n_act > 0) {
        fw_slope_solve(n_act, vec, di, t, FW_REAL(2.0) / FW_REAL(3.0) * pl->vdc, omega,
                       fw_paramest_gamma0_prior(&c->pe, c->iq), &c->est);
        /* cross-saturation turns the saliency axes the slopes see by a load-dependent angle:
         * remove it (xsat_ldq_per_a, identified at speed: xsat_learn). Measured on the harsh
         * profile at 1 r/min, 2 N*m: +5 deg of bias without it, and the loop crept away */
        c->theta_raw_axes = c->est.theta_raw;
        if (c->est.n_active > 0 && p[FW_IDX_XSAT_LDQ_PER_A] != FW_REAL(0.0)) {
            c->est.theta_raw += fw_paramest_xsat_angle(&c->pe, c->iq, p[FW_IDX_XSAT_LDQ_PER_A]);
        }
        /* plausibility: the residual of the 4th equation; for the position also enough
         * saliency left. The inductances along the tracked d axis need no saliency: while the
         * flux estimator carries the position they are learnt at any load (q saturation takes
         * all of it near 4 A on the paper machine, where the flux angle needs Lq_app most) */
        c->est_param_ok = (int16_t)(c->est.n_active == 2 && c->est.gamma0 > FW_REAL(0.0) &&
                                    fw_fabs(c->est.residual) <=
                                        p[FW_IDX_RESIDUAL_MAX] * c->est.gamma0);
        if (c->est.ok) {
            real_t g1_nom = c->pe.gamma1_f;
            if (!c->est_param_ok || c->est.gamma1 < p[FW_IDX_EST_GAMMA1_MIN] * g1_nom) {
                c->est.ok = 0;
            }
        }
        if (!c->est.ok) {
            bad = 1;
        }
    }
    if (c->est.ok) {
        real_t t_ref_ticks = c->est.t_ref / FW_TICK_S;
        uint16_t stamp = (uint16_t)fw_clamp(t_ref_ticks + FW_REAL(0.5), FW_REAL(0.0),
                                            (real_t)(FW_P_TICKS - 1));
        real_t theta_meas;
        if (!c->trk.init) {
            fw_tracker_reset(&c->trk, c->est.theta_raw, FW_REAL(0.0), stamp);
            c->theta_raw_branch = fw_wrap_2pi(c->est.theta_raw);
            updated = 1;
        } else if (!by_flux) {
            real_t eps = fw_tracker_update(&c->trk, c->est.theta_raw, stamp, &theta_meas);
            c->theta_raw_branch = theta_meas;
            updated = 1;
            if (fw_fabs(eps) > p[FW_IDX_PLL_ERR_MAX_DEG] * (FW_M_PI / FW_REAL(180.0))) {
                bad = 1;
            }
        } else {
            real_t pred = fw_tracker_predict(&c->trk, (int32_t)stamp);
            c->theta_raw_branch =
                fw_wrap_2pi(pred + FW_REAL(0.5) *
                                       fw_wrap_pi(FW_REAL(2.0) * (c->est.theta_raw - pred)));
        }
        if (updated) {
            c->stamp = (int16_t)stamp;
            c->theta_hat = c->trk.theta;
            mid2->valid = 0; /* the tracker moved on */
        }
    }
    if (!updated) {
        c->stamp = (int16_t)FW_H_TICKS;
        /* (half the doubled middle angle is the angle, exactly) */
        c->theta_hat = mid2->valid ? FW_REAL(0.5) * mid2->th
                                   : (c->trk.init ? fw_tracker_predict(&c->trk, FW_H_TICKS)
                                                  : FW_REAL(0.0));
    }
    if (bad) {
        c->est_reject_count++;
    }
    return (int16_t)(bad || (n_act == 0 && pl->layout != FW_LAYOUT_OFF));
}

/* Speed- and load-dependent hand-over (docs/estimator.md §5-§7): above flux_pos_min_rpm and
 * flux_pos_min_iq_a the d axis comes from the flux estimator's active flux psi - Lq_app i
 * (docs/estimator.md §4.6: its direction is the magnet's whatever Ld does), which needs no
 * saliency, so q saturation under load cannot take the position away; the slopes keep
 * feeding the online Ld/Lq. Below it, the current slopes carry the tracker. */
static int16_t flux_carries_position(fw_core_t *c)
{
    const real_t *p = c->p;
    /* only under load (|iq| above flux_pos_min_iq_a, 25 % hysteresis), where q saturation
     * erodes the saliency; at light load the slopes keep the position (measured: the hand-over
     * at no load let the tracker and the flux estimator's speed-dependent filter oscillate) */
    real_t on = p[FW_IDX_FLUX_POS_MIN_IQ_A];
    real_t iq = fw_fabs(c->iq);
    if (iq > on) {
        c->flux_pos_load = 1;
    } else if (iq < p[FW_IDX_FLUX_POS_IQ_HYST] * on) {
        c->flux_pos_load = 0;
    }
    if (!fw_flux_settled(&c->flux, p[FW_IDX_FLUX_SETTLE_TC])) {
        return 0;
    }
    if (c->full_mod) {
        return (int16_t)(c->state == FW_STATE_RUN);
    }
    return (int16_t)(c->state == FW_STATE_RUN && c->flux_pos_load &&
                     p[FW_IDX_FLUX_POS_MIN_RPM] > FW_REAL(0.0) &&
                     fw_fabs(c->speed_f_rpm) >= p[FW_IDX_FLUX_POS_MIN_RPM]);
}

/* Tracker update from the active flux at the end of the period; 1 when plausible */
static int16_t flux_position(fw_core_t *c)
{
    const real_t *p = c->p;
    real_t lam_min = FW_REAL(0.25) * p[FW_IDX_LAMBDA_M_WB];
    fw_cplx_t act;
    real_t meas, eps;
    if (!c->flux.active) {
        return 0;
    }
    act = fw_csub(c->flux.psi, fw_cscale(c->i_end, c->pe.lq_app));
    if (fw_cabs2(act) < lam_min * lam_min) {
        return 0;
    }
    eps = fw_tracker_update(&c->trk, fw_atan2(act.im, act.re), (uint16_t)(FW_P_TICKS - 1), &meas);
    c->theta_raw_branch = meas;
    c->stamp = (int16_t)(FW_P_TICKS - 1);
    c->theta_hat = c->trk.theta;
    return (int16_t)(fw_fabs(eps) <= p[FW_IDX_PLL_ERR_MAX_DEG] * (FW_M_PI / FW_REAL(180.0)));
}

static void update_parameters_and_flux(fw_core_t *c, int16_t run_flux)
{
    const real_t *p = c->p;
    real_t alpha = FW_TS / (p[FW_IDX_PARAM_TAU_MS] * FW_REAL(1e-3));
    real_t ld_nom = p[FW_IDX_LD_H];
    real_t lq_nom = p[FW_IDX_LQ_H];
    if (((c->est.ok && c->est.n_active == 2) || (c->flux_pos_active && c->est_param_ok)) &&
        c->trk.init) {
        fw_paramest_update(&c->pe, &c->est, c->theta_hat, c->iq, alpha,
                           p[FW_IDX_PARAM_L_MIN_RATIO] * ld_nom,
                           p[FW_IDX_PARAM_L_MAX_RATIO] * lq_nom);
    }
    c->v_meas = fw_cadd(c->plan_cur.v_applied, fw_inverter_error(c));
    if (run_flux && c->trk.init) {
        fw_cplx_t u = fw_cscale(fw_csub(c->v_meas, fw_cscale(c->i_avg, p[FW_IDX_RS_OHM])), FW_TS);
        real_t rpm_to_we = p[FW_IDX_POLE_PAIRS] / FW_RPM_PER_RADS;
        real_t omega_learn = p[FW_IDX_FLUX_MIN_RPM] * rpm_to_we;
        /* the model runs from the polarity-loss check's speed when that is lower */
        real_t omega_min = fw_min(omega_learn, p[FW_IDX_POL_LOSS_SETTLED_MIN_RPM] * rpm_to_we);
        real_t theta_end = fw_tracker_predict(&c->trk, FW_P_TICKS);
        real_t omega_gate = c->speed_f_rpm * rpm_to_we;
        (void)fw_flux_update(&c->flux, u, c->trk.omega, omega_gate, p[FW_IDX_FLUX_LPF_RATIO],
                             omega_min, omega_learn, theta_end, c->i_end, c->pe.ld_app,
                             p[FW_IDX_LAMBDA_M_WB], alpha);
    }
}

/* Cross-saturation identification (param_estimator.c, fw_paramest_xsat_learn): at speed, with a
 * settled flux estimator and a two-vector slope estimate in the same period, the active-flux
 * angle less the slope angle (the saliency axes, brought to the period end): the correction
 * that, added to the slope angle, gives the flux angle (harsh profile, 300 r/min, id = 0:
 * -1.05/-2.61/-7.60 deg at +1.8/+2.6/+3.4 A, where the plant's Ldq gives 1.4/2.9/7.3). */
static void xsat_learn(fw_core_t *c)
{
    const real_t *p = c->p;
    fw_cplx_t act;
    real_t th_s, th_f;
    if (!c->flux.active || c->flux.n_valid < FW_FLUX_VALID_UPDATES || !c->est_param_ok ||
        c->est.n_active != 2 || fw_fabs(c->speed_f_rpm) < FW_XSAT_MIN_RPM ||
        fw_fabs(c->iq) < FW_XSAT_MIN_IQ_A ||
        !fw_paramest_iq_learnt(&c->pe, c->iq, FW_XSAT_LEARNT_UPDATES)) {
        return; /* (the model needs Lqq at this current: a new load waits for its Lq bin) */
    }
    act = fw_csub(c->flux.psi, fw_cscale(c->i_end, c->pe.lq_app));
    if (fw_cabs2(act) < FW_REAL(0.0625) * p[FW_IDX_LAMBDA_M_WB] * p[FW_IDX_LAMBDA_M_WB]) {
        return;
    }
    th_f = fw_atan2(act.im, act.re);
    th_s = c->theta_raw_axes + c->trk.omega * ((real_t)FW_P_TICKS - c->est.t_ref / FW_TICK_S) *
                                   FW_TICK_S;
    fw_paramest_xsat_learn(&c->pe, fw_cscale(fw_cexpj(FW_REAL(2.0) * (th_f - th_s)), c->est.gamma1),
                           c->iq, FW_XSAT_ALPHA);
}

/* FULL modulation above full_mod_min_rpm (10 % hysteresis), where the flux estimator carries
 * the position: the zero window is no longer reserved, so the voltage reaches Vdc/sqrt3 in
 * the linear range and the six-step fundamental in overmodulation. Below it the slopes carry
 * the position and every period keeps its measurable windows. */
static void update_full_mod(fw_core_t *c)
{
    const real_t *p = c->p;
    real_t on = p[FW_IDX_FULL_MOD_MIN_RPM];
    real_t spd = fw_fabs(c->speed_f_rpm);
    if (!(on > FW_REAL(0.0)) || c->state != FW_STATE_RUN ||
        !fw_flux_settled(&c->flux, p[FW_IDX_FLUX_SETTLE_TC])) {
        c->full_mod = 0;
    } else if (spd >= on) {
        c->full_mod = 1;
    } else if (spd < FW_REAL(0.9) * on) {
        c->full_mod = 0;
    }
}

/* RUN after the back-EMF decided the polarity while the shaft turned: a start (a load already
 * on it at the enable, a hoist or a conveyor on a slope, has turned it back meanwhile; or it
 * was still turning), or the polarity watch in RUN (a frame turned round near standstill: the
 * shaft ran away backwards under its load and the reversed torque). The back-EMF's straight
 * line (fw_polarity_motion, fw_polarity_watch_motion) gives the shaft's speed now.
 *  - The tracker takes that speed: from the bandwidth a reset leaves it, meant for the noise
 *    at standstill, it lagged by half the speed after 6 ms at 2 N*m.
 *  - The speed reference ramps from the speed the shaft has now back to back_to_rpm (the
 *    speed it had at the enable; the reference when the watch turned the frame), at least as
 *    fast as start_recover_rpm_s, then on to the command (outer_loop.c). Braking at i_max
 *    instead ran the slopes where q saturation takes their saliency (2 N*m on paper: single
 *    periods 40-75 deg off at 4.2 A, the position lost in 1 of 10 starts).
 *  - The flux estimator starts from the flux the test measured, settled for the
 *    polarity-loss check (pol_loss_settle_tc), not for the hand-over (flux_settle_tc): at
 *    2 N*m its angle needs Lq_app at 4 A, which is not learnt yet (17 deg off on paper). */
static void resume_from_motion(fw_core_t *c, real_t w_now, real_t back_to_rpm)
{
    const real_t *p = c->p;
    real_t pp = p[FW_IDX_POLE_PAIRS];
    c->trk.omega = w_now;
    {
        real_t rpm_to_we = pp / FW_RPM_PER_RADS;
        fw_cplx_t u = fw_cexpj(fw_tracker_predict(&c->trk, FW_P_TICKS));
        fw_cplx_t idq = fw_cmul(c->i_end, fw_cconj(u));
        fw_cplx_t psi = fw_cmul(u, fw_c(p[FW_IDX_LAMBDA_M_WB] + c->pe.ld_app * idq.re,
                                        c->pe.lq_app * idq.im));
        fw_flux_seed(&c->flux, psi, w_now, p[FW_IDX_FLUX_LPF_RATIO],
                     fw_min(p[FW_IDX_FLUX_MIN_RPM], p[FW_IDX_POL_LOSS_SETTLED_MIN_RPM]) * rpm_to_we,
                     p[FW_IDX_POL_LOSS_SETTLE_TC]);
    }
    c->speed_f_rpm = FW_RPM(w_now, pp);
    c->speed_ref_ramped = c->speed_f_rpm;
    c->start_speed_rpm = back_to_rpm;
    c->start_recover = 1;
}

/* RUN after a start the back-EMF decided (resume_from_motion), and what only a start needs,
 * where the start-up's currents gave the shaft no torque, so that its acceleration is the
 * load's, J a / p:
 *  - the tracker's disturbance acceleration is the load's;
 *  - the speed PI starts with the current that holds the load (from zero its integral took
 *    ~20 ms while the shaft ran on backwards: 2 N*m on paper to -415 r/min);
 *  - for start_gov_ms the q current follows the saliency the slopes measure, where the
 *    learnt Lq curve (the saliency cap, outer_loop.c) has no data yet: it stops rising while
 *    Gamma1 along d_hat (~1 ms filter) is below saliency_min of the nominal. */
static void start_after_motion(fw_core_t *c)
{
    const real_t *p = c->p;
    real_t pp = p[FW_IDX_POLE_PAIRS];
    real_t kt = FW_REAL(1.5) * pp * p[FW_IDX_LAMBDA_M_WB];
    real_t i_max = p[FW_IDX_I_MAX_A];
    real_t w_start, w_now, accel, te_hold;
    if (!fw_polarity_motion(&c->pol, p[FW_IDX_LAMBDA_M_WB], &w_start, &w_now, &accel)) {
        return;
    }
    c->trk.a_d = accel - c->trk.a_ff;
    c->trk.a_d_lo = FW_REAL(0.0);
    resume_from_motion(c, w_now, FW_RPM(w_start, pp));
    te_hold = c->te_model - p[FW_IDX_INERTIA_KGM2] * accel / pp;
    if (c->cmd.ctrl_mode == FW_CTRL_SPEED) {
        c->pi_spd.x = fw_clamp(te_hold / kt, -i_max, i_max);
    }
    c->start_gov = (int32_t)(p[FW_IDX_START_GOV_MS] * FW_REAL(10.0));
    c->g1_fast = c->pe.gamma1_f;
    c->iq_gov = fw_min(fw_fabs(c->pi_spd.x) + FW_START_GOV_HEADROOM_A, i_max);
}

/* RUN after the catch (a shaft turning fast at the enable, polarity_detect.c): the tracker
 * starts from the magnet's angle and speed the back-EMF gave, the speed loop at that speed,
 * and the flux estimator from the flux they give, settled (above full_mod_min_rpm FULL
 * modulation and the flux hand-over need it at once: the back-EMF exceeds the measurable
 * voltage range from ~2000 r/min) */
static void start_after_catch(fw_core_t *c)
{
    const real_t *p = c->p;
    real_t pp = p[FW_IDX_POLE_PAIRS];
    real_t w = c->pol.catch_omega;
    fw_cplx_t u = fw_cexpj(c->pol.catch_theta);
    fw_cplx_t idq = fw_cmul(c->i_end, fw_cconj(u));
    fw_cplx_t psi = fw_cmul(u, fw_c(p[FW_IDX_LAMBDA_M_WB] + c->pe.ld_app * idq.re,
                                    c->pe.lq_app * idq.im));
    fw_tracker_reset(&c->trk, c->pol.catch_theta, w, (uint16_t)(FW_P_TICKS - 1));
    fw_flux_seed(&c->flux, psi, w, p[FW_IDX_FLUX_LPF_RATIO],
                 fw_min(p[FW_IDX_FLUX_MIN_RPM], p[FW_IDX_POL_LOSS_SETTLED_MIN_RPM]) * pp /
                     FW_RPM_PER_RADS,
                 fw_max(p[FW_IDX_FLUX_SETTLE_TC], p[FW_IDX_POL_LOSS_SETTLE_TC]));
    c->theta_hat = c->pol.catch_theta;
    if (c->cmd.ctrl_mode == FW_CTRL_SPEED) {
        /* the torque that holds a coasting shaft at its speed: its friction */
        c->pi_spd.x = fw_clamp(p[FW_IDX_FRICTION_NMS] * w / pp /
                                   (FW_REAL(1.5) * pp * p[FW_IDX_LAMBDA_M_WB]),
                               -p[FW_IDX_I_MAX_A], p[FW_IDX_I_MAX_A]);
    }
    c->speed_f_rpm = FW_RPM(w, pp);
    c->speed_ref_ramped = c->speed_f_rpm;
    c->start_speed_rpm = c->speed_f_rpm;
    c->start_fw_hold = FW_START_FW_HOLD;
    update_full_mod(c);
}

/* the q-current limit of the start's saliency governor (start_after_motion), per period */
static void start_governor(fw_core_t *c, int16_t data_ok)
{
    const real_t *p = c->p;
    real_t g1_nom = FW_REAL(0.5) * (FW_REAL(1.0) / p[FW_IDX_LD_H] - FW_REAL(1.0) / p[FW_IDX_LQ_H]);
    if (c->start_gov <= 0) {
        return;
    }
    c->start_gov--;
    if (data_ok && c->est.n_active == 2 && c->est_param_ok) {
        c->g1_fast += FW_START_GOV_ALPHA *
                      (fw_paramest_gamma1_at(&c->est, c->theta_hat) - c->g1_fast);
    }
    if (c->g1_fast < p[FW_IDX_SALIENCY_MIN] * g1_nom) {
        c->iq_gov = fw_max(fw_min(c->iq_gov, fw_fabs(c->iq)) - FW_START_GOV_STEP_A, FW_REAL(0.0));
    } else {
        c->iq_gov = fw_min(c->iq_gov + FW_START_GOV_STEP_A * FW_REAL(2.0), p[FW_IDX_I_MAX_A]);
    }
}

/* The tracked frame points to the south pole: turn it round; the PI integrators hold dq
 * voltages of the old frame, which are the negatives in the new one. Too many corrections
 * within pol_loss_window_ms make the loss a fault. */
static void turn_frame_round(fw_core_t *c)
{
    const real_t *p = c->p;
    fw_tracker_flip(&c->trk);
    c->theta_hat = fw_wrap_2pi(c->theta_hat + FW_M_PI);
    c->pi_d.x = -c->pi_d.x;
    c->pi_q.x = -c->pi_q.x;
    c->flux.neg_count = 0;
    if (c->polarity_flips < 65535u) {
        c->polarity_flips++;
    }
    c->flips_in_window++;
    if ((real_t)c->flips_in_window > p[FW_IDX_POL_LOSS_FLIPS_MAX]) {
        enter_fault(c, FW_FAULT_POLARITY_LOST);
    }
}

static void polarity_lost_check(fw_core_t *c, int16_t data_ok)
{
    const real_t *p = c->p;
    real_t spd = fw_fabs(c->speed_f_rpm);
    int16_t trusted;
    c->flip_window_ticks++;
    if ((real_t)c->flip_window_ticks >= p[FW_IDX_POL_LOSS_WINDOW_MS] * FW_REAL(10.0)) {
        c->flip_window_ticks = 0;
        c->flips_in_window = 0;
    }
    /* two regimes: from pol_loss_settled_min_rpm the estimator's verdict is taken once its
     * zero start has decayed (a loss while running slowly: caught in 50 periods, before the
     * shaft has turned round); from pol_loss_min_rpm at once, which is what a runaway after a
     * loss near standstill needs (it reaches 300 r/min within ~10 ms, before a settled
     * filter, and there the back-EMF is ~14 V against volt-level model errors) */
    trusted = (int16_t)((spd > p[FW_IDX_POL_LOSS_SETTLED_MIN_RPM] &&
                         fw_flux_settled(&c->flux, p[FW_IDX_POL_LOSS_SETTLE_TC])) ||
                        (spd > p[FW_IDX_POL_LOSS_MIN_RPM] && c->flux.active));
    if (trusted && c->flux.neg_count >= FW_FLUX_NEG_PERIODS) {
        turn_frame_round(c);
        return;
    }
    /* below pol_loss_min_rpm, the back-EMF of the motion against the raw angle's; the shaft
     * has run away meanwhile, and the tracker, the speed loop and the flux estimator resume
     * from the motion that window's back-EMF measured, as after a start against a load, back
     * to the speed the reference had */
    if (data_ok && fw_polarity_watch_step(&c->watch, c) < 0) {
        real_t back_to = c->speed_ref_ramped, w_now;
        int16_t moved = fw_polarity_watch_motion(&c->watch, p[FW_IDX_LAMBDA_M_WB], &w_now);
        turn_frame_round(c);
        if (moved && c->state == FW_STATE_RUN) {
            /* the speed PI's integral and the tracker's disturbance stay: they held the load
             * until the frame turned, and the watch decides within ms, before the lagging
             * speed estimate has moved them (a preload from the back-EMF's acceleration came
             * out 40 % short, the first ms of it carrying the currents' reversal) */
            resume_from_motion(c, w_now, back_to);
        }
    }
}

/* Current-sensor plausibility. The difference of two states' current slopes is Gamma(theta)
 * times the difference of their voltages: the back-EMF and the drop cancel, and what is left
 * is the machine's inverse inductance matrix, whatever the rotor angle. A channel with a wrong
 * gain, stuck, lost or clipped bends it out of what any machine can have: its mean Gamma0 far
 * from the nominal, or Gamma1 >= Gamma0 (a negative incremental inductance). Measured per
 * two-vector period: paper 0.91-1.29 of the nominal Gamma0 (q saturation at 2 N*m), harsh
 * 0.56-1.63 with Gamma1/Gamma0 up to 1.1 in single noisy periods (12-bit ADC, 5 mA), a leaky
 * count of at most 2; ia read 5x: 2.3-3.9 at once; ia stuck at mid-scale: 0.31, then
 * Gamma1 > Gamma0. The over-current check cannot see these: the current loop regulates the
 * false reading to its reference and the true current goes where it will.
 * Two-vector periods alone came too rarely and too mildly: after a stuck ia or a lost ib most
 * periods measured one vector (slopes_ok 1), and a sector could pass the mean Gamma0 for 30
 * periods while one of its vectors was plainly wrong; detection took 19-142 periods as the
 * noise fell (faults suite, seeds 1-160) and a lost ib let the true current reach 23 A before
 * the over-current trip. So every measured vector is judged on its own (v.Gamma.v/|v|^2 within
 * the machine's 1/Lq..1/Ld, widened by the same ratios), and a converter stuck on one code is
 * implausible in every period it is: both faults are now caught in 19-25 periods. */
static int16_t period_implausible(fw_core_t *c)
{
    const real_t *p = c->p;
    real_t inv_ld = FW_REAL(1.0) / p[FW_IDX_LD_H], inv_lq = FW_REAL(1.0) / p[FW_IDX_LQ_H];
    real_t g0_nom = FW_REAL(0.5) * (inv_ld + inv_lq);
    real_t lo = p[FW_IDX_SENSOR_G0_MIN_RATIO] * fw_min(inv_ld, inv_lq);
    real_t hi = p[FW_IDX_SENSOR_G0_MAX_RATIO] * fw_max(inv_ld, inv_lq);
    int16_t k;
    if (c->codes_frozen) {
        return 1; /* a converter stuck on one code while the windows it measured slewed */
    }
    if (c->slopes_ok == 2 && c->est.n_active == 2) {
        real_t ratio = c->est.gamma0 / g0_nom;
        if (!(ratio >= p[FW_IDX_SENSOR_G0_MIN_RATIO] && ratio <= p[FW_IDX_SENSOR_G0_MAX_RATIO]) ||
            !(c->est.gamma1 < c->est.gamma0)) {
            return 1;
        }
    }
    /* each vector: its slope difference projected on its own voltage is v.Gamma.v / |v|^2,
     * between the machine's smallest and largest inverse inductance whatever the angle. Two
     * vectors' mean Gamma0 alone let a lost ib pass for 30 periods in a sector where one
     * vector's projection was 0 and the other's twice the nominal */
    for (k = 0; k < c->slopes_ok; k++) {
        if (!(c->vec_proj[k] >= lo && c->vec_proj[k] <= hi)) {
            return 1;
        }
    }
    return 0;
}

static void current_sensor_check(fw_core_t *c)
{
    const real_t *p = c->p;
    if (c->slopes_ok < 1) {
        return; /* this period measured no active vector */
    }
    if (period_implausible(c)) {
        if (c->sensor_bad < 30000) {
            c->sensor_bad++;
        }
    } else if (c->sensor_bad > 0) {
        c->sensor_bad--;
    }
    if ((real_t)c->sensor_bad >= p[FW_IDX_SENSOR_FAIL_MAX]) {
        enter_fault(c, FW_FAULT_CURRENT_IMPLAUSIBLE);
    }
}

static void output_off(fw_core_t *c, uint32_t next_period, fw_pwm_t *pwm)
{
    fw_svpwm_plan_off(&c->plan_next, c->vdc);
    fw_svpwm_to_pwm(&c->plan_next, next_period, 0, pwm);
    c->mod.carry = fw_c(FW_REAL(0.0), FW_REAL(0.0));
    c->mod.sector = 0;
}

static void output_voltage(fw_core_t *c, fw_cplx_t v_ab, uint32_t next_period, fw_pwm_t *pwm)
{
    int16_t every = (int16_t)c->p[FW_IDX_FULL_MEAS_EVERY];
    c->pwm_cfg.full_range = c->full_mod;
    c->pwm_cfg.carry_clipped = 0;
    if (c->full_mod && every > 0 && (next_period % (uint32_t)every) == 0u) {
        /* a measurement period: the measurable pattern keeps the online Ld/Lq learning (the
         * flux estimator's active flux needs Lq_app at the present load; measured: without
         * it 1.9 deg of bias at 2500 r/min, 1.5 N*m). Every Nth period while the others can
         * make up its volt-second deficit inside the linear range; beyond that only while the
         * Lq curve at the present q current is still unlearnt (the deficit then costs some of
         * the overmodulation voltage: measured 2373 instead of 2522 r/min at 1.5 N*m) */
        real_t v_meas = fw_svpwm_vmax(c->vdc, c->pwm_cfg.tmin);
        real_t v_lin = c->vdc * FW_M_INV_SQRT3;
        if (fw_cabs(v_ab) * (real_t)every <= v_meas + (real_t)(every - 1) * v_lin ||
            !fw_paramest_iq_learnt(&c->pe, c->iq, FW_FULL_LEARNT_UPDATES)) {
            c->pwm_cfg.full_range = 0;
            c->pwm_cfg.carry_clipped = 1;
        }
    }
    if (c->pwm_cfg.full_range && c->vdc > FW_REAL(1.0)) {
        /* beyond the hexagon: ask for the reference whose projection has the wanted
         * fundamental (the current loop then sees the voltage it asked for, on average) */
        real_t unit = c->vdc * FW_M_INV_SQRT3;
        real_t m = fw_cabs(v_ab) / unit;
        if (m > FW_REAL(1.0)) {
            v_ab = fw_cscale(v_ab, fw_svpwm_om_ref(c->om_ref, c->om_fund, m) / m);
        }
    }
    fw_svpwm_plan(&c->pwm_cfg, c->vdc, v_ab, &c->mod, next_period, &c->plan_next);
    fw_svpwm_to_pwm(&c->plan_next, next_period, 1, pwm);
}

/* current control in the estimated frame -> alpha-beta voltage for the next period; the
 * angle it is rotated with (the middle of the next period) and its fw_cexpj into *apply */
static fw_cplx_t current_loop(fw_core_t *c, int16_t have_data, fw_angle_t *apply)
{
    const real_t *p = c->p;
    real_t theta_apply;
    real_t vd = c->vd;
    real_t vq = c->vq;
    real_t u_mag = c->u_mag;
    if (have_data) {
        fw_current_ctrl(&c->pi_d, &c->pi_q, c->id_ref, c->iq_ref, c->id, c->iq, c->trk.omega,
                        c->ld_use, c->lq_use, c->lambda_use, p[FW_IDX_RS_OHM], c->v_lim, FW_TS,
                        &vd, &vq, &u_mag);
    }
    c->u_mag = u_mag;
    c->vd = vd;
    c->vq = vq;
    c->v_mag_f += FW_REAL(0.05) * (u_mag - c->v_mag_f);
    /* the voltage acts during period k+1: rotate with the angle at its middle */
    theta_apply = c->trk.init ? fw_tracker_predict(&c->trk, FW_P_TICKS + FW_H_TICKS) : FW_REAL(0.0);
    apply->th = theta_apply;
    apply->e = fw_cexpj(theta_apply);
    apply->valid = 1;
    return fw_cmul(fw_c(vd, vq), apply->e);
}

/* 1. Which period this is and whether its data is complete: the period k the ADC frame
 * names (the next one when none came), the tracker advanced to it, the plan that ran in it
 * made current; a missing or incomplete period counts towards ADC_LOSS. */
static int16_t take_period(fw_core_t *c, const fw_adc_t *adc, uint32_t *period)
{
    const real_t *p = c->p;
    int16_t data_ok = 0;
    uint32_t k;
    if (adc == 0) {
        k = c->have_period ? c->period + 1u : 0u;
    } else if (!c->have_period) {
        k = adc->period; /* first frame: nothing was planned for it */
        c->have_period = 1;
        c->adc_loss_run = 0;
    } else {
        k = adc->period;
        data_ok = (int16_t)(adc->period == c->period + 1u && adc->n_soc == c->plan_next.n_soc &&
                            adc->n_soc >= 0 && adc->n_soc <= FW_MAX_SOC &&
                            fw_protection_codes_in_range(adc, c->adc_half));
        c->codes_frozen = (data_ok && c->state == FW_STATE_RUN) ? fw_protection_codes_frozen(adc) : 0;
    }
    if (c->have_period && c->trk.init) {
        uint32_t gap = k - c->period;
        fw_tracker_advance(&c->trk, (gap >= 1u && gap < 100u) ? (int32_t)gap * FW_P_TICKS : FW_P_TICKS);
    }
    c->prev_on[0] = c->plan_cur.on[0];
    c->prev_on[1] = c->plan_cur.on[1];
    c->prev_on[2] = c->plan_cur.on[2];
    c->prev_off[0] = c->plan_cur.off[0];
    c->prev_off[1] = c->plan_cur.off[1];
    c->prev_off[2] = c->plan_cur.off[2];
    if (data_ok) {
        c->plan_cur = c->plan_next;
        c->adc_loss_run = 0;
    } else {
        fw_svpwm_plan_off(&c->plan_cur, c->vdc);
        if (c->have_period && !(adc != 0 && c->state == FW_STATE_INIT)) {
            c->adc_loss_count++;
            c->adc_loss_run++;
            if (c->adc_loss_run >= (int16_t)p[FW_IDX_ADC_LOSS_MAX] && c->state != FW_STATE_INIT) {
                enter_fault(c, FW_FAULT_ADC_LOSS);
            }
        }
    }
    c->period = k;
    if (c->state == FW_STATE_INIT) {
        c->state = FW_STATE_IDLE;
    }
    *period = k;
    return data_ok;
}

/* 2. Protection: the DC link and this period's phase currents, the command time-out; then
 * the modulation range and the voltage the current loop may ask for. */
static void protect(fw_core_t *c, const fw_adc_t *adc, int16_t data_ok)
{
    const real_t *p = c->p;
    if (data_ok) {
        uint16_t f;
        real_t vdc = (real_t)adc->vdc * c->adc_v_lsb;
        int16_t enabled = (int16_t)(c->state == FW_STATE_POLARITY || c->state == FW_STATE_RUN);
        f = fw_protection_vdc(vdc, p[FW_IDX_OV_TRIP_V], p[FW_IDX_UV_TRIP_V], enabled);
        if (f != FW_FAULT_NONE) {
            enter_fault(c, f);
        }
        if (vdc > FW_REAL(1.0)) {
            c->vdc = vdc;
            c->vdc_f += FW_REAL(0.01) * (vdc - c->vdc_f);
        }
        f = fw_protection_samples(adc, c->adc_half, c->adc_i_lsb, p[FW_IDX_OC_TRIP_A], &c->i_peak);
        if (f != FW_FAULT_NONE) {
            enter_fault(c, f);
        }
    }
    if ((c->state == FW_STATE_POLARITY || c->state == FW_STATE_RUN) &&
        c->ticks_since_cmd > c->cmd_timeout_ticks) {
        enter_fault(c, FW_FAULT_CMD_TIMEOUT);
    }
    update_full_mod(c);
    c->v_lim = (c->full_mod ? p[FW_IDX_FULL_VLIM_FRACTION] * FW_SIX_STEP * c->vdc
                            : fw_svpwm_vmax(c->vdc, c->pwm_cfg.tmin)) *
               p[FW_IDX_VLIM_FRACTION];
}

/* The controlled current: the period mean without the ripple the pattern's dipole adds
 * (Gamma(theta) Q, svpwm.c), i.e. the mean of the period's start and end currents; an A/B
 * pair's dipoles cancel, so its mean torque is this current's. */
static void controlled_current(fw_core_t *c, const fw_angle_t *mid2, fw_cplx_t mid_conj)
{
    fw_cplx_t q = c->plan_cur.dipole;
    fw_cplx_t rot2, rot_m, g, i_ctl, idq;
    if (mid2->valid) { /* the tracker is as estimate_position found it */
        rot2 = mid2->e;
        rot_m = mid_conj;
    } else {
        real_t th_mid = c->trk.init ? fw_tracker_predict(&c->trk, FW_H_TICKS) : FW_REAL(0.0);
        rot2 = fw_cexpj(FW_REAL(2.0) * th_mid);
        rot_m = fw_cexpj(-th_mid);
    }
    g = fw_cscale(rot2, c->pe.gamma1_f);
    i_ctl = fw_csub(c->i_avg, fw_cadd(fw_cscale(q, c->pe.gamma0_f), fw_cmul(g, fw_cconj(q))));
    idq = fw_cmul(i_ctl, rot_m);
    c->id = idq.re;
    c->iq = idq.im;
}

/* 3.-4. Estimation (the tracker's gains for the present speed first): the position from this
 * period's slopes, or from the flux above the hand-over speed; the current in the estimated
 * frame; the machine's parameters and flux. Returns 1 when the estimate was implausible. */
static int16_t estimate(fw_core_t *c, const fw_adc_t *adc, int16_t data_ok)
{
    int16_t bad_est = 0;
    fw_angle_t mid2 = {0, FW_REAL(0.0), {FW_REAL(0.0), FW_REAL(0.0)}};
    fw_cplx_t mid_conj = {FW_REAL(0.0), FW_REAL(0.0)};
    (void)fw_tracker_schedule(&c->trk);
    /* (the polarity test runs with the tracker running: polarity_detect.c) */
    if (data_ok) {
        int16_t by_flux = flux_carries_position(c);
        c->flux_pos_active = by_flux;
        bad_est = estimate_position(c, adc, by_flux, &mid2, &mid_conj);
        fw_recon_current(c, adc, &mid2);
        controlled_current(c, &mid2, mid_conj);
        update_parameters_and_flux(c, (int16_t)(c->plan_cur.layout != FW_LAYOUT_OFF));
        xsat_learn(c);
        if (by_flux) {
            bad_est = (int16_t)!flux_position(c);
        }
    } else {
        c->slopes_ok = 0;
        c->slope_ok[0] = c->slope_ok[1] = c->slope_ok[2] = 0;
        c->stamp = (int16_t)FW_H_TICKS;
        c->theta_hat = c->trk.init ? fw_tracker_predict(&c->trk, FW_H_TICKS) : FW_REAL(0.0);
    }
    return bad_est;
}

/* The estimate's health: the current sensors (RUN), a run of implausible periods faults
 * ESTIMATOR; the filtered speed and the over-speed trip. */
static void supervise_estimate(fw_core_t *c, int16_t data_ok, int16_t bad_est)
{
    const real_t *p = c->p;
    if (c->state == FW_STATE_RUN && data_ok) {
        current_sensor_check(c);
    }
    if (c->state == FW_STATE_POLARITY || c->state == FW_STATE_RUN) {
        if (bad_est) {
            c->est_fail_run++;
        } else if (data_ok && c->est.ok) {
            c->est_fail_run = 0;
        }
        if ((real_t)c->est_fail_run >= p[FW_IDX_EST_FAIL_MAX]) {
            enter_fault(c, FW_FAULT_ESTIMATOR);
        }
    }
    c->est_valid = (int16_t)(c->trk.init && c->est_fail_run < FW_EST_VALID_MAX_RUN);
    if (c->trk.init) {
        real_t rpm = FW_RPM(c->trk.omega, p[FW_IDX_POLE_PAIRS]);
        c->speed_f_rpm += c->speed_alpha * (rpm - c->speed_f_rpm);
        if (fw_fabs(c->speed_f_rpm) > p[FW_IDX_OVERSPEED_RPM] && c->state == FW_STATE_RUN) {
            enter_fault(c, FW_FAULT_OVERSPEED);
        }
    } else {
        c->speed_f_rpm = FW_REAL(0.0);
    }
}

/* 5. States: a disable, a fault reset, a start (the DC link checked first). */
static void next_state(fw_core_t *c, int16_t data_ok)
{
    const real_t *p = c->p;
    if (!c->cmd.enable && (c->state == FW_STATE_POLARITY || c->state == FW_STATE_RUN)) {
        c->state = FW_STATE_IDLE;
    }
    if (c->state == FW_STATE_FAULT && c->reset_request) {
        c->reset_request = 0;
        c->start_request = 0;
        c->adc_loss_run = 0;
        c->fault_code = FW_FAULT_NONE;
        c->state = FW_STATE_IDLE;
    }
    c->reset_request = 0;
    if (c->state == FW_STATE_IDLE && c->start_request && c->cmd.enable && data_ok) {
        c->start_request = 0;
        if (c->vdc < p[FW_IDX_UV_TRIP_V]) {
            enter_fault(c, FW_FAULT_DC_UNDERVOLTAGE);
        } else {
            c->state = FW_STATE_POLARITY;
            reset_estimation(c);
            reset_control(c);
            fw_polarity_start(&c->pol);
        }
    }
}

/* 6. The outputs for period k+1 by state: the polarity test's (and the hand-over to RUN),
 * the current loop's, or all off; *apply gets the angle the voltage is rotated with. */
static void outputs(fw_core_t *c, const fw_adc_t *adc, int16_t data_ok, int16_t slow,
                    uint32_t k, fw_pwm_t *pwm, fw_angle_t *apply)
{
    fw_polarity_out_t pol_out;
    switch (c->state) {
    case FW_STATE_POLARITY: {
        int16_t r = fw_polarity_step(&c->pol, c, data_ok ? adc : 0, &pol_out);
        if (r < 0) {
            enter_fault(c, FW_FAULT_POLARITY);
            output_off(c, k + 1u, pwm);
            break;
        }
        if (r > 0) {
            if (c->pol.flipped) {
                fw_tracker_flip(&c->trk);
                c->theta_hat = fw_wrap_2pi(c->theta_hat + FW_M_PI);
            }
            c->polarity_ok = 1;
            c->state = FW_STATE_RUN;
            reset_control(c);
            c->speed_ref_ramped = c->speed_f_rpm;
            if (c->pol.method_used == FW_POL_METHOD_EMF) {
                start_after_motion(c);
                fw_outer_step(c); /* the load's current now, not at the next 1 kHz tick */
            } else if (c->pol.method_used == FW_POL_METHOD_CATCH) {
                start_after_catch(c);
                fw_outer_step(c);
            } else {
                fw_outer_select_parameters(c);
            }
            output_voltage(c, current_loop(c, data_ok, apply), k + 1u, pwm);
            break;
        }
        fw_outer_select_parameters(c);
        c->id_ref = pol_out.id;
        c->iq_ref = pol_out.iq;
        output_voltage(c, fw_cadd(current_loop(c, data_ok, apply), pol_out.v_ff), k + 1u, pwm);
        break;
    }
    case FW_STATE_RUN:
        start_governor(c, data_ok);
        if (c->start_fw_hold > 0) {
            c->start_fw_hold--;
        }
        polarity_lost_check(c, data_ok);
        if (c->state != FW_STATE_RUN) {
            output_off(c, k + 1u, pwm);
            break;
        }
        if (slow) {
            fw_outer_step(c);
        }
        output_voltage(c, current_loop(c, data_ok, apply), k + 1u, pwm);
        break;
    default:
        reset_control(c);
        output_off(c, k + 1u, pwm);
        break;
    }
}

/* The torque the tracker predicts the rotor with until the next update: the current loop's,
 * the ripple's reluctance torque, less the known viscous friction. */
static void torque_model(fw_core_t *c, fw_angle_t *apply)
{
    const real_t *p = c->p;
    if (c->state == FW_STATE_RUN || c->state == FW_STATE_POLARITY) {
        c->te_hat = fw_refs_torque(c->id, c->iq, c->ld_use, c->lq_use, c->lambda_use,
                                   p[FW_IDX_POLE_PAIRS]);
        /* the torque the current loop is delivering: its references through the loop's
         * first-order response (the measured currents carry the ripple and noise of the
         * per-period reconstruction, which would shake the tracker's prediction) */
        c->te_model += FW_TE_MODEL_ALPHA *
                       (fw_refs_torque(c->id_ref, c->iq_ref, c->ld_use, c->lq_use,
                                       c->lambda_use, p[FW_IDX_POLE_PAIRS]) - c->te_model);
        /* plus the reluctance torque of the next pattern's current ripple (its mean over the
         * period, with the incremental inductances the ripple sees) */
        c->te_ripple = FW_REAL(1.5) * p[FW_IDX_POLE_PAIRS] * (c->pe.ld_inc - c->pe.lq_inc) *
                       (apply->valid ? fw_recon_ripple_dq_product_at(c, &c->plan_next, apply)
                                    : fw_recon_ripple_dq_product(c, &c->plan_next));
    } else {
        c->te_hat = FW_REAL(0.0);
        c->te_model = FW_REAL(0.0);
        c->te_ripple = FW_REAL(0.0);
    }
    /* the tracker predicts the rotor with this torque, less the known viscous friction, until
     * the next update (the load and any model error are its disturbance state) */
    {
        const real_t te_friction = p[FW_IDX_FRICTION_NMS] * c->trk.omega / p[FW_IDX_POLE_PAIRS];
        fw_tracker_set_accel(&c->trk, (c->te_model + c->te_ripple - te_friction) *
                                          p[FW_IDX_POLE_PAIRS] / p[FW_IDX_INERTIA_KGM2]);
    }
}

/* The d-q voltage averaged over the slow task's FW_SPEED_DIVIDER periods (vd_mean, vq_mean). */
static void voltage_mean(fw_core_t *c)
{
    c->vdq_sum = fw_cadd(c->vdq_sum, fw_c(c->vd, c->vq));
    c->vdq_sum_n++;
    if (c->vdq_sum_n >= FW_SPEED_DIVIDER) {
        c->vdq_mean = fw_cscale(c->vdq_sum, FW_REAL(1.0) / (real_t)c->vdq_sum_n);
        c->vdq_sum = fw_c(FW_REAL(0.0), FW_REAL(0.0));
        c->vdq_sum_n = 0;
    }
}

/* One PWM period (docs/one-period.md): the ADC data of period k in, the PWM of period k+1
 * out, in the steps above. */
void fw_core_isr(fw_core_t *c, const fw_adc_t *adc, fw_pwm_t *pwm)
{
    uint32_t k;
    int16_t data_ok;
    int16_t bad_est;
    int16_t slow;
    fw_angle_t apply = {0, FW_REAL(0.0), {FW_REAL(0.0), FW_REAL(0.0)}};

    if (c == 0 || pwm == 0) {
        return;
    }
    /* a repeated ADC(k) gets the same PWM(k+1) (docs/interfaces.md, lockstep re-send) */
    if (adc != 0 && c->have_period && c->pwm_valid && adc->period == c->period) {
        *pwm = c->pwm_last;
        return;
    }
    c->isr_count++;
    slow = (int16_t)((c->isr_count % (uint32_t)FW_SPEED_DIVIDER) == 0u);
    if (c->ticks_since_cmd < 0xFFFFFFF0u) {
        c->ticks_since_cmd++;
    }
    data_ok = take_period(c, adc, &k);
    protect(c, adc, data_ok);
    bad_est = estimate(c, adc, data_ok);
    supervise_estimate(c, data_ok, bad_est);
    next_state(c, data_ok);
    outputs(c, adc, data_ok, slow, k, pwm, &apply);
    torque_model(c, &apply);
    voltage_mean(c);
    c->pwm_last = *pwm;
    c->pwm_valid = 1;
}

void fw_core_status(const fw_core_t *c, fw_status_t *s)
{
    const real_t *p;
    if (c == 0 || s == 0) {
        return;
    }
    p = c->p;
    s->state = c->state;
    s->fault_code = c->fault_code;
    s->ctrl_mode = c->cmd.ctrl_mode;
    s->fw_mode = c->cmd.fw_mode;
    s->cmd_status = c->cmd_status;
    s->period = c->period;
    s->stamp = c->stamp;
    s->theta_hat = fw_wrap_2pi(c->theta_hat);
    s->omega_hat = c->trk.init ? c->trk.omega : FW_REAL(0.0);
    s->speed_hat_rpm = FW_RPM(s->omega_hat, p[FW_IDX_POLE_PAIRS]);
    s->id = c->id;
    s->iq = c->iq;
    s->id_ref = c->id_ref;
    s->iq_ref = c->iq_ref;
    s->vd = c->vd;
    s->vq = c->vq;
    s->vd_mean = c->vdq_mean.re;
    s->vq_mean = c->vdq_mean.im;
    s->ld_hat = c->pe.ld_inc;
    s->lq_hat = c->pe.lq_inc;
    s->lambda_hat = c->flux.lambda_f;
    s->te_hat = c->te_hat;
    s->theta_raw = c->theta_raw_branch;
    s->residual = c->est.residual;
    s->sector = c->plan_cur.sector;
    s->slopes_ok = c->slopes_ok;
    s->fw_active = c->fluxweak_active;
    s->speed_ref_ramped_rpm = c->speed_ref_ramped;
    s->polarity_ok = c->polarity_ok;
    s->est_valid = c->est_valid;
    s->isr_overruns = c->isr_overruns;
}
