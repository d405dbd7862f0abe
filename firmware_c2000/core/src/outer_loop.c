/* outer_loop.c - the 1 kHz tasks: the parameter set of the selected MTPA/FW mode, the speed
 * ramp and speed PI, the current references (MTPA, flux weakening with its voltage feedback,
 * the saliency limit of the q current).
 */
#include "fw_internal.h"

/* parameter set of the selected MTPA/FW mode */
void fw_outer_select_parameters(fw_core_t *c)
{
    const real_t *p = c->p;
    if (c->cmd.fw_mode == FW_FWMODE_REALTIME) {
        c->ld_use = c->pe.ld_app;
        c->lq_use = c->pe.lq_app;
        /* the online flux only once the voltage model has settled (FW_FLUX_VALID_UPDATES) */
        c->lambda_use = (p[FW_IDX_LAMBDA_MODE] > FW_REAL(0.5) &&
                         c->flux.n_valid >= FW_FLUX_VALID_UPDATES)
                            ? c->flux.lambda_f
                            : p[FW_IDX_LAMBDA_M_WB];
    } else {
        c->ld_use = p[FW_IDX_LD_H];
        c->lq_use = p[FW_IDX_LQ_H];
        c->lambda_use = p[FW_IDX_LAMBDA_M_WB];
    }
}

/* 1 kHz: speed ramp, speed PI, MTPA/FW references, voltage feedback */
void fw_outer_step(fw_core_t *c)
{
    const real_t *p = c->p;
    const real_t ts = FW_TS * (real_t)FW_SPEED_DIVIDER;
    real_t i_max = p[FW_IDX_I_MAX_A];
    real_t vmax_fw = c->full_mod ? p[FW_IDX_FULL_VS_FRACTION] * FW_SIX_STEP * c->vdc
                                 : p[FW_IDX_FW_VMARGIN] * c->v_lim;
    real_t target = fw_clamp(c->cmd.speed_ref_rpm, -p[FW_IDX_SPEED_MAX_RPM], p[FW_IDX_SPEED_MAX_RPM]);
    real_t iq_lim, iq_sal, iq_use, to, rate;

    fw_paramest_apparent(&c->pe, c->iq);
    fw_outer_select_parameters(c);
    /* the speed ramp at accel_rpm_s; after a load start (start_recover 1) back from the speed
     * it left the shaft at to the speed it had at the enable, at start_recover_rpm_s whatever
     * the command's ramp: a scenario's ramp of a few r/min per second would hold the shaft
     * there for seconds, and braking at i_max (a step command) ran the slopes where q
     * saturation takes their saliency (2 N*m on paper: the tracker slipped by 180 deg at 4.3 A
     * in 1 of 8 seeds). Then (2) on to the command at its own ramp but no faster than the
     * return: the enable's speed is a line's estimate (off by up to ~25 r/min at 2 N*m on
     * paper), and a step command would step the reference by that error, the braking at once
     * that the return is there to avoid. */
    to = target;
    rate = p[FW_IDX_ACCEL_RPM_S];
    if (c->start_recover == 1) {
        to = fw_clamp(target, fw_min(c->start_speed_rpm, c->speed_ref_ramped),
                      fw_max(c->start_speed_rpm, c->speed_ref_ramped));
        rate = p[FW_IDX_START_RECOVER_RPM_S];
    } else if (c->start_recover == 2) {
        rate = fw_min(rate, p[FW_IDX_START_RECOVER_RPM_S]);
    }
    c->speed_ref_ramped = fw_speed_ctrl_ramp(c->speed_ref_ramped, to, rate * ts);
    if (c->start_recover != 0 && c->speed_ref_ramped == to) {
        c->start_recover = (int16_t)((c->start_recover == 1 && to != target) ? 2 : 0);
    }
    /* voltage feedback: integrate the excess of |v| over the flux-weakening voltage */
    if (c->cmd.fw_mode != FW_FWMODE_ID_ZERO) {
        /* (not while a catch's currents settle: the loop's demand is then its error, 300 V
         * at 3000 r/min, and the feedback wound up to -1.6 A of extra d current in 1.5 ms) */
        if (c->start_fw_hold == 0) {
            c->fluxweak_did += p[FW_IDX_FW_FB_KI] * ts * (vmax_fw - c->v_mag_f);
        }
        c->fluxweak_did = fw_clamp(c->fluxweak_did, -i_max, FW_REAL(0.0));
    } else {
        c->fluxweak_did = FW_REAL(0.0);
    }
    /* the q room the MTPA/FW d current leaves on the current circle; the d current the
     * reluctance extension adds below must not shrink it, or the next cycle's demand falls
     * under the saliency limit, the extension drops out and the two alternate at 500 Hz */
    iq_lim = fw_sqrt(fw_max(i_max * i_max - c->id_ref_base * c->id_ref_base, FW_REAL(0.0)));
    iq_sal = iq_lim;
    if (p[FW_IDX_SALIENCY_MIN] > FW_REAL(0.0) && !c->flux_pos_active) {
        /* keep the q current where the saliency the slope estimator lives on is still there;
         * not while the flux estimator carries the position (it needs no saliency): there the
         * cap only made the reluctance extension below fight the speed loop (measured: a
         * growing 24 Hz limit cycle, 3.2 deg and +-50 r/min at 1000 r/min, 2 N*m) */
        real_t g1_nom = FW_REAL(0.5) * (FW_REAL(1.0) / p[FW_IDX_LD_H] - FW_REAL(1.0) / p[FW_IDX_LQ_H]);
        iq_sal = fw_min(iq_lim, fw_paramest_saliency_iq_limit(&c->pe, p[FW_IDX_SALIENCY_MIN] * g1_nom,
                                                        i_max));
    }
    if (c->start_gov > 0) {
        iq_sal = fw_min(iq_sal, c->iq_gov);
    }
    c->iq_sal_lim = iq_sal;
    /* the demand may exceed the saliency limit: the torque beyond it comes from more
     * negative d current (reluctance torque) inside the current circle */
    if (c->cmd.ctrl_mode == FW_CTRL_SPEED) {
        c->iq_demand = fw_speed_ctrl(&c->pi_spd, c->speed_ref_ramped, c->speed_f_rpm, iq_lim, ts);
    } else {
        c->iq_demand = fw_clamp(c->cmd.iq_ref, -i_max, i_max);
        c->pi_spd.x = c->iq_demand; /* bumpless change to speed mode */
    }
    iq_use = fw_clamp(c->iq_demand, -iq_sal, iq_sal);
    c->fluxweak_active = fw_refs_select(c->cmd.fw_mode, iq_use, c->trk.omega, vmax_fw, i_max,
                                        c->ld_use, c->lq_use, c->lambda_use, c->fluxweak_did,
                                        &c->id_ref, &c->iq_ref);
    c->id_ref_base = c->id_ref;
    if (c->cmd.fw_mode != FW_FWMODE_ID_ZERO && fw_fabs(c->iq_demand) > fw_fabs(iq_use)) {
        real_t id_t = fw_refs_id_for_torque(c->iq_demand, c->iq_ref, c->ld_use, c->lq_use,
                                       c->lambda_use);
        if (id_t < c->id_ref) {
            c->id_ref = fw_max(id_t, -fw_sqrt(fw_max(i_max * i_max - c->iq_ref * c->iq_ref,
                                                     FW_REAL(0.0))));
        }
    }
}
