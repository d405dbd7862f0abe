/* sim.h - core + mini plant harness for the firmware C tests. */
#ifndef FW_SIM_H
#define FW_SIM_H

#include <string.h>

#include "fw_internal.h"
#include "mini_plant.h"

typedef struct {
    fw_core_t core;
    mini_plant_t plant;
    fw_pwm_t pwm;
    fw_adc_t adc;
    fw_cmd_t cmd;
    int send_cmd;       /* send cmd every 10 periods */
    double theta_start; /* plant angle at the start of the last simulated period */
    double omega_e;     /* plant electrical speed during it */
    long periods;
} sim_t;

static inline void sim_init(sim_t *s, double theta0)
{
    int x;
    memset(s, 0, sizeof *s);
    mp_default(&s->plant);
    mp_set_angle(&s->plant, theta0);
    fw_core_init(&s->core);
    s->pwm.period = 0;
    s->pwm.gate_enable = 0;
    for (x = 0; x < 3; x++) {
        s->pwm.cmp_up[x] = FW_TBPRD;
        s->pwm.cmp_dn[x] = FW_TBPRD;
    }
    s->cmd.enable = 0;
    s->cmd.ctrl_mode = FW_CTRL_SPEED;
    s->cmd.fw_mode = FW_FWMODE_REALTIME;
    s->send_cmd = 1;
}

/* match the core's ADC scaling to the plant */
static inline void sim_sync_adc_params(sim_t *s)
{
    fw_param_set(&s->core, FW_PID_ADC_BITS, (real_t)s->plant.bits);
    fw_param_set(&s->core, FW_PID_ADC_RANGE_A, (real_t)s->plant.range_a);
    fw_param_set(&s->core, FW_PID_ADC_VDC_BITS, (real_t)s->plant.vdc_bits);
    fw_param_set(&s->core, FW_PID_ADC_VDC_RANGE_V, (real_t)s->plant.vdc_range);
}

static inline void sim_step(sim_t *s)
{
    s->theta_start = s->plant.theta;
    s->omega_e = s->plant.omega_m * s->plant.pp;
    mp_period(&s->plant, &s->pwm, &s->adc);
    if (s->send_cmd && s->periods % 10 == 0) {
        (void)fw_core_command(&s->core, &s->cmd);
    }
    fw_core_isr(&s->core, &s->adc, &s->pwm);
    s->periods++;
}

/* estimate error at the stamp the core claims (rad, wrapped) */
static inline double sim_theta_error(const sim_t *s)
{
    fw_status_t st;
    double truth;
    fw_core_status(&s->core, &st);
    truth = s->theta_start + s->omega_e * (double)st.stamp * 1e-8;
    return remainder((double)st.theta_hat - truth, 2.0 * 3.14159265358979323846);
}

static inline int sim_state(const sim_t *s) { return s->core.state; }

#endif
