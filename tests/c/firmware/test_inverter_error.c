/* The core's inverter model (fw_inverter_error: dead time, device drop) against the real
 * plant (plant_core, inverter.c/machine.c). Rotor held at standstill, the core's own
 * pattern (fw_svpwm_plan, both layouts) for a fixed voltage vector at many angles; per
 * period the plant's actual mean alpha-beta voltage is Rs*mean(i) + (psi(end)-psi(start))/Ts
 * (mean current from 16 exact samples). The core's voltage v_applied + fw_inverter_error
 * must match it; the bare pattern voltage is off by the whole inverter error. Points where a
 * phase current sits at zero (the inverter clamps it there: the leg voltage is then anywhere
 * in its band, which no sign model knows) are printed but not judged. */
#include <string.h>

#include "fw_test.h"
#include "fw_internal.h"
#include "plant_core.h"

static fw_core_t C;

typedef struct {
    double re, im;
} cd_t;

static cd_t psi_ab(const plant_truth_t *t)
{
    cd_t r;
    r.re = cos(t->theta_e) * t->psi_d - sin(t->theta_e) * t->psi_q;
    r.im = sin(t->theta_e) * t->psi_d + cos(t->theta_e) * t->psi_q;
    return r;
}

/* one operating point; returns |model - plant| relative to |pattern - plant|, or -1 when a
 * phase current came within the core's sign band (0.05 A) of zero */
static double check_point(double td_us, double vdrop, double vdc, double vmag, double ang_deg,
                          int *layouts)
{
    char err[256];
    char sets[4][64];
    const char *setp[4];
    plant_t *pl;
    plant_pwm_cmd_t cmd;
    plant_samples_t smp;
    plant_truth_t t0, t1;
    fw_plan_t plan;
    fw_pwm_t pwm;
    fw_cplx_t vref;
    const double rs = 1.93;
    const double ts = PLANT_TS_S;
    double ang = ang_deg * M_PI / 180.0;
    double sum_true[2] = {0, 0}, sum_model[2] = {0, 0}, sum_pat[2] = {0, 0};
    double d_model, d_pat, imin = 1e9;
    int k, j, n = 0;

    snprintf(sets[0], sizeof sets[0], "inverter.dead_time_s=%.9g", td_us * 1e-6);
    snprintf(sets[1], sizeof sets[1], "inverter.device_drop_v=%.9g", vdrop);
    snprintf(sets[2], sizeof sets[2], "inverter.vdc_v=%.9g", vdc);
    snprintf(sets[3], sizeof sets[3], "load.mode=1");
    for (j = 0; j < 4; j++) {
        setp[j] = sets[j];
    }
    pl = plant_open(NULL, setp, 4, err, sizeof err);
    CHECK(pl != NULL, "plant_open: %s", err);
    if (pl == NULL) {
        return 1e9;
    }
    CHECK(fabs(plant_config(pl)->machine.rs_ohm - rs) < 1e-12, "default Rs changed");
    plant_set_load(pl, HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE, 0.0, 0.0, 0.0);
    /* start near the steady current (rotor d axis at 0: dq = alpha-beta) */
    plant_set_state(pl, 0.0, 0.0, vmag / rs * cos(ang), vmag / rs * sin(ang));

    fw_core_init(&C);
    fw_param_set(&C, FW_PID_DEADTIME_US, (real_t)td_us);
    fw_param_set(&C, FW_PID_VDROP_V, (real_t)vdrop);
    vref = fw_c((real_t)(vmag * cos(ang)), (real_t)(vmag * sin(ang)));

    for (k = 0; k < 600; k++) {
        cd_t p0, p1;
        double ia = 0, ib = 0;
        fw_cplx_t e;
        memcpy(C.prev_on, C.plan_cur.on, sizeof C.prev_on);
        memcpy(C.prev_off, C.plan_cur.off, sizeof C.prev_off);
        fw_svpwm_plan(&C.pwm_cfg, (real_t)vdc, vref, NULL, (uint32_t)k, &plan);
        fw_svpwm_to_pwm(&plan, (uint32_t)k, 1, &pwm);
        memset(&cmd, 0, sizeof cmd);
        cmd.period = (uint32_t)k;
        for (j = 0; j < 3; j++) {
            cmd.cmp_up[j] = pwm.cmp_up[j];
            cmd.cmp_dn[j] = pwm.cmp_dn[j];
        }
        cmd.n_soc = 16;
        for (j = 0; j < 16; j++) {
            cmd.soc[j] = (uint16_t)(j * (PLANT_PERIOD_TICKS / 16) + PLANT_PERIOD_TICKS / 32);
        }
        cmd.gate_enable = 1;
        plant_step(pl, &cmd, &smp, &t0);
        plant_truth_now(pl, &t1);
        for (j = 0; j < 16; j++) {
            ia += smp.ia_true[j] / 16.0;
            ib += smp.ib_true[j] / 16.0;
        }
        C.plan_cur = plan;
        C.i_avg = fw_c((real_t)ia, (real_t)((ia + 2.0 * ib) / sqrt(3.0)));
        e = fw_inverter_error(&C);
        if (k < 400) {
            continue; /* settle */
        }
        imin = fmin(imin, fmin(fabs(ia), fmin(fabs(ib), fabs(ia + ib))));
        layouts[plan.layout == FW_LAYOUT_STRETCH ? 1 : 0]++;
        p0 = psi_ab(&t0);
        p1 = psi_ab(&t1);
        sum_true[0] += rs * (double)C.i_avg.re + (p1.re - p0.re) / ts;
        sum_true[1] += rs * (double)C.i_avg.im + (p1.im - p0.im) / ts;
        sum_pat[0] += (double)plan.v_applied.re;
        sum_pat[1] += (double)plan.v_applied.im;
        sum_model[0] += (double)(plan.v_applied.re + e.re);
        sum_model[1] += (double)(plan.v_applied.im + e.im);
        n++;
    }
    plant_free(pl);
    d_model = hypot(sum_model[0] - sum_true[0], sum_model[1] - sum_true[1]) / n;
    d_pat = hypot(sum_pat[0] - sum_true[0], sum_pat[1] - sum_true[1]) / n;
    if (td_us > 0.0 || vdrop > 0.0) {
        printf("td %.1f us drop %.2f V |v| %4.1f V at %5.1f deg: plant-pattern %.3f V, "
               "plant-model %.3f V, min |i_ph| %.3f A\n",
               td_us, vdrop, vmag, ang_deg, d_pat, d_model, imin);
        return (imin < 0.05) ? -1.0 : d_model / d_pat;
    }
    CHECK(d_model < 0.02 && d_pat < 0.02, "ideal inverter: pattern %.3f model %.3f V", d_pat,
          d_model);
    return 0.0;
}

int main(void)
{
    static const double cases[][2] = {{0.0, 0.0}, {0.0, 1.2}, {2.0, 0.0}, {2.0, 1.2}, {3.0, 1.5}};
    static const double mags[] = {6.0, 14.0};
    int c, m, a;
    int layouts[2] = {0, 0};
    for (c = 0; c < 5; c++) {
        double worst = 0.0;
        int judged = 0;
        for (m = 0; m < 2; m++) {
            for (a = 0; a < 360; a += 20) {
                double r = check_point(cases[c][0], cases[c][1], 60.0, mags[m], (double)a + 3.0,
                                       layouts);
                if (r >= 0.0) {
                    worst = fmax(worst, r);
                    judged++;
                }
            }
        }
        if (cases[c][0] > 0.0 || cases[c][1] > 0.0) {
            /* with the error model the voltage is right to a fraction of the error itself */
            CHECK(worst < 0.02, "td %.1f us drop %.2f V: model leaves %.1f %% of the inverter "
                  "error", cases[c][0], cases[c][1], 100.0 * worst);
            CHECK(judged >= 12, "td %.1f us drop %.2f V: only %d points judged", cases[c][0],
                  cases[c][1], judged);
        }
    }
    printf("layouts: direct %d stretch %d periods\n", layouts[0], layouts[1]);
    CHECK(layouts[0] > 0 && layouts[1] > 0, "both layouts must be exercised");
    TEST_DONE();
}
