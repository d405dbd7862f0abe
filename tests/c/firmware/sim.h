/* sim.h - closed-loop harness of the firmware C tests on the in-process bench (bench/): the
 * real plant (plant_rt's plant_core) and the control core, with the bus programs' frame code
 * between them. Commands go in as DRIVE_CMD frames every 10 periods. */
#ifndef FW_SIM_H
#define FW_SIM_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fw_internal.h"
#include "plant_core.h"
#include "sil_bench.h"

#ifndef FW_TEST_PROFILES_DIR
#error "FW_TEST_PROFILES_DIR must name plant_rt/profiles"
#endif

#define SIM_MAX_SETS 8

typedef struct {
    sil_bench_t *b;
    fw_core_t *core;
    fw_cmd_t cmd;
    fw_adc_t adc;       /* ADC data of the last ISR */
    fw_pwm_t pwm;       /* the core's PWM of the last ISR */
    int send_cmd;       /* send cmd every 10 periods */
    double theta_start; /* plant angle at the start of the last simulated period */
    double omega_e;     /* plant electrical speed then */
    long periods;
} sim_t;

/* Opens the bench on a profile with "section.key=value" overrides (NULL-terminated) and the
 * rotor at theta0 (rad); the firmware gets the profile's hardware parameters, as from the rig. */
static inline void sim_close(sim_t *s);

static inline void sim_open(sim_t *s, const char *profile, double theta0, const char *const *sets)
{
    char path[512], err[1024], theta[64];
    const char *psets[SIM_MAX_SETS + 1];
    sil_bench_config_t cfg;
    int n = 0;
    sim_close(s); /* a harness reused without closing: the previous bench goes first */
    memset(s, 0, sizeof *s);
    snprintf(path, sizeof path, "%s/%s.toml", FW_TEST_PROFILES_DIR, profile);
    snprintf(theta, sizeof theta, "initial.theta_e_deg=%.17g", theta0 * 180.0 / 3.14159265358979323846);
    psets[n++] = theta;
    while (sets != NULL && sets[n - 1] != NULL && n <= SIM_MAX_SETS) {
        psets[n] = sets[n - 1];
        n++;
    }
    memset(&cfg, 0, sizeof cfg);
    cfg.profile_path = path;
    cfg.plant_sets = psets;
    cfg.n_plant_sets = n;
    cfg.fw_from_plant = 1;
    s->b = sil_bench_open(&cfg, err, sizeof err);
    if (s->b == NULL) {
        fprintf(stderr, "sil_bench_open %s: %s\n", path, err);
        exit(2);
    }
    s->core = sil_bench_core(s->b);
    s->cmd.enable = 0;
    s->cmd.ctrl_mode = FW_CTRL_SPEED;
    s->cmd.fw_mode = FW_FWMODE_REALTIME;
    s->send_cmd = 1;
}

static inline void sim_close(sim_t *s)
{
    if (s->b == NULL) {
        return;
    }
    sil_bench_close(s->b);
    s->b = NULL;
}

static inline void sim_step(sim_t *s)
{
    plant_truth_t t;
    plant_truth_now(sil_bench_plant(s->b), &t);
    s->theta_start = t.theta_e;
    s->omega_e = t.omega_m * plant_config(sil_bench_plant(s->b))->machine.pole_pairs;
    if (s->send_cmd && s->periods % 10 == 0) {
        (void)sil_bench_drive_cmd(s->b, s->cmd.enable, s->cmd.fault_reset, s->cmd.ctrl_mode,
                                  s->cmd.fw_mode,
                                  (double)s->cmd.speed_ref_rpm, (double)s->cmd.iq_ref);
    }
    if (sil_bench_step(s->b) != 0) {
        fprintf(stderr, "bench loop broke at period %ld\n", s->periods);
        exit(1);
    }
    sil_bench_last_io(s->b, &s->adc, &s->pwm);
    s->periods++;
}

/* ADC code of a current / DC-link voltage on this bench's converter */
static inline int32_t sim_current_code(const sim_t *s, double i_a)
{
    const plant_config_t *c = plant_config(sil_bench_plant(s->b));
    int clipped;
    return plant_adc_current_code(i_a, (int)c->adc.bits, c->adc.range_a, &clipped);
}

static inline int32_t sim_vdc_code(const sim_t *s, double v)
{
    const plant_config_t *c = plant_config(sil_bench_plant(s->b));
    int clipped;
    return plant_adc_vdc_code(v, (int)c->adc.vdc_bits, c->adc.vdc_range_v, &clipped);
}

/* estimate error at the stamp the core claims (rad, wrapped) */
static inline double sim_theta_error(const sim_t *s)
{
    fw_status_t st;
    double truth;
    fw_core_status(s->core, &st);
    truth = s->theta_start + s->omega_e * (double)st.stamp * 1e-8;
    return remainder((double)st.theta_hat - truth, 2.0 * 3.14159265358979323846);
}

static inline int sim_state(const sim_t *s) { return s->core->state; }

/* true mechanical speed at the start of the last period, r/min */
static inline double sim_speed_rpm(const sim_t *s)
{
    return s->omega_e / plant_config(sil_bench_plant(s->b))->machine.pole_pairs * 60.0 /
           (2.0 * 3.14159265358979323846);
}

#endif
