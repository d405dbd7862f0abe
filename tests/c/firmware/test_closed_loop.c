/* Core-level closed-loop simulation against tools/mini_plant.h: start-up polarity (saturation
 * and motion methods), position tracking with the claimed time stamp, online parameters,
 * flux weakening and recovery from a polarity flip. Expectations are the plant's truth. */
#include "fw_test.h"
#include "sim.h"

static sim_t S;

static double rms_error_over(sim_t *s, long n, double *max_err)
{
    double sum = 0.0;
    long k;
    *max_err = 0.0;
    for (k = 0; k < n; k++) {
        double e;
        sim_step(s);
        e = sim_theta_error(s);
        sum += e * e;
        *max_err = fmax(*max_err, fabs(e));
    }
    return sqrt(sum / (double)n);
}

static int run_until_state(sim_t *s, int state, long max_periods)
{
    long k;
    for (k = 0; k < max_periods; k++) {
        sim_step(s);
        if (sim_state(s) == state || sim_state(s) == FW_STATE_FAULT) {
            break;
        }
    }
    return sim_state(s) == state;
}

static void startup(double theta0, double sat_k, int expect_method, const char *name)
{
    sim_t *s = &S;
    double e;
    sim_init(s, theta0);
    s->plant.bits = 24;
    s->plant.vdc_bits = 23;
    s->plant.sat_k = sat_k;
    sim_sync_adc_params(s);
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "%s: no RUN (state %d fault %u)", name,
          sim_state(s), s->core.fault_code);
    e = sim_theta_error(s);
    printf("%s: bias %.3f %.3f A, incremental Ld %.3f %.3f mH, ratio %+.2f %% (sigma %.2f %%); ",
           name, (double)s->core.pol.id_pos, (double)s->core.pol.id_neg,
           (double)s->core.pol.l_pos * 1e3, (double)s->core.pol.l_neg * 1e3,
           (double)s->core.pol.ratio * 100.0, (double)s->core.pol.ratio_sigma * 100.0);
    printf("%s: start %.2f rad, RUN after %ld periods, method %d, flipped %d, error %.2f deg\n",
           name, theta0, s->periods, s->core.pol.method_used, s->core.pol.flipped,
           e * 180 / M_PI);
    CHECK(s->core.pol.method_used == expect_method, "%s: method %d", name, s->core.pol.method_used);
    CHECK(fabs(e) < 5.0 * M_PI / 180, "%s: polarity/angle wrong after start-up: %.1f deg", name,
          e * 180 / M_PI);
    CHECK(s->core.polarity_ok, "%s: polarity_ok", name);
}

static void speed_run(void)
{
    sim_t *s = &S;
    double max_e, rms;
    fw_status_t st;
    sim_init(s, 0.7);
    s->plant.bits = 16;
    s->plant.noise_a = 0.001;
    s->plant.sat_k = 40.0;
    sim_sync_adc_params(s);
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "speed: no RUN");
    s->cmd.speed_ref_rpm = 1000.0f;
    {
        long k;
        for (k = 0; k < 12000; k++) {
            sim_step(s);
        }
    }
    rms = rms_error_over(s, 3000, &max_e);
    fw_core_status(&s->core, &st);
    printf("1000 r/min: state %d fault %u speed %.1f (true %.1f) theta rms %.2f max %.2f deg, "
           "Ld %.2f Lq %.2f mH lambda %.4f id %.3f iq %.3f\n",
           st.state, st.fault_code, (double)st.speed_hat_rpm, s->plant.omega_m * 60 / (2 * M_PI),
           rms * 180 / M_PI, max_e * 180 / M_PI, st.ld_hat * 1e3, st.lq_hat * 1e3,
           (double)st.lambda_hat, (double)st.id, (double)st.iq);
    CHECK(st.state == FW_STATE_RUN, "speed: state %d fault %u", st.state, st.fault_code);
    CHECK(fabs(s->plant.omega_m * 60 / (2 * M_PI) - 1000.0) < 20.0, "speed not reached");
    CHECK(rms < 1.5 * M_PI / 180, "theta rms %.2f deg", rms * 180 / M_PI);
    CHECK(fabs(st.lq_hat - 0.032) < 0.03 * 0.032, "Lq %.4f", (double)st.lq_hat);
    CHECK(fabs(st.lambda_hat - 0.216) < 0.03 * 0.216, "lambda %.4f", (double)st.lambda_hat);

    /* polarity flip while running: detected and corrected */
    fw_pll_flip(&s->core.pll);
    {
        long k;
        for (k = 0; k < 3000; k++) {
            sim_step(s);
        }
    }
    rms = rms_error_over(s, 1000, &max_e);
    fw_core_status(&s->core, &st);
    printf("after forced flip: state %d flips %u theta rms %.2f deg\n", st.state,
           s->core.polarity_flips, rms * 180 / M_PI);
    CHECK(s->core.polarity_flips == 1, "flips %u", s->core.polarity_flips);
    CHECK(st.state == FW_STATE_RUN && rms < 2.0 * M_PI / 180, "no recovery");
}

static void flux_weakening(void)
{
    sim_t *s = &S;
    double max_e, rms;
    fw_status_t st;
    long k;
    sim_init(s, 4.0);
    s->plant.bits = 24;
    s->plant.vdc_bits = 23;
    sim_sync_adc_params(s);
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "fw: no RUN");
    s->cmd.speed_ref_rpm = 3000.0f;
    for (k = 0; k < 20000; k++) {
        sim_step(s);
    }
    rms = rms_error_over(s, 2000, &max_e);
    fw_core_status(&s->core, &st);
    printf("3000 r/min: state %d fault %u speed %.1f (true %.1f) fw %d id %.2f iq %.2f |v| %.1f "
           "theta rms %.2f deg\n",
           st.state, st.fault_code, (double)st.speed_hat_rpm, s->plant.omega_m * 60 / (2 * M_PI),
           st.fw_active, (double)st.id, (double)st.iq, hypot(st.vd, st.vq), rms * 180 / M_PI);
    CHECK(st.state == FW_STATE_RUN, "fw: fault %u", st.fault_code);
    CHECK(fabs(s->plant.omega_m * 60 / (2 * M_PI) - 3000.0) < 60.0, "3000 r/min not held");
    CHECK(st.fw_active && st.id < -1.0f, "flux weakening not active");
}

/* eq. 50 with the paper's sign convention */
static double mtpa_eq50(double iq, double ld, double lq, double lam)
{
    double d = ld - lq;
    return -lam / (2 * d) - sqrt(lam * lam / (4 * d * d) + iq * iq);
}

/* The three MTPA/FW modes with a wrong nominal Lq: real-time uses the online estimates (the
 * plant's true values), conventional the nominal ones, id = 0 none. */
static void modes(void)
{
    sim_t *s = &S;
    fw_status_t st;
    long k;
    int m;
    sim_init(s, 0.4);
    s->plant.bits = 24;
    s->plant.vdc_bits = 23;
    sim_sync_adc_params(s);
    CHECK(fw_param_set(&s->core, FW_PID_LQ_H, 0.024f) == FW_STATUS_OK, "nominal Lq");
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "modes: no RUN");
    s->cmd.speed_ref_rpm = 1000.0f;
    s->plant.load_nm = 1.5;
    for (m = 0; m < 3; m++) {
        static const int16_t order[3] = {FW_FWMODE_REALTIME, FW_FWMODE_CONVENTIONAL,
                                         FW_FWMODE_ID_ZERO};
        double expect;
        s->cmd.fw_mode = order[m];
        for (k = 0; k < 15000; k++) {
            sim_step(s);
        }
        fw_core_status(&s->core, &st);
        if (order[m] == FW_FWMODE_REALTIME) {
            expect = mtpa_eq50(st.iq_ref, 0.015, 0.032, 0.216);
        } else if (order[m] == FW_FWMODE_CONVENTIONAL) {
            expect = mtpa_eq50(st.iq_ref, 0.015, 0.024, 0.216);
        } else {
            expect = 0.0;
        }
        printf("mode %d: speed %.1f iq_ref %.3f id_ref %.3f (eq. 50: %.3f) te_hat %.3f "
               "lq_app %.2f mH\n",
               order[m], s->plant.omega_m * 60 / (2 * M_PI), (double)st.iq_ref, (double)st.id_ref,
               expect, (double)st.te_hat, s->core.pe.lq_app * 1e3);
        CHECK(st.state == FW_STATE_RUN && !st.fw_active, "mode %d state", order[m]);
        CHECK(fabs(st.id_ref - expect) < 0.05 * fabs(expect) + 0.01, "mode %d id_ref %.3f vs %.3f",
              order[m], (double)st.id_ref, expect);
    }
}

/* q-axis self-saturation (DESIGN.md section 5: apparent Lq 32 -> 28 mH, incremental about
 * 21 mH at 3 A): the slopes give the incremental value, MTPA gets the apparent one from the
 * integrated incremental curve (estimator-math.md section 4.7). */
static void q_saturation(void)
{
    sim_t *s = &S;
    const double a = (0.032 / 0.028 - 1.0) / 9.0;
    double iq_true, lq_inc_true, lq_app_true;
    fw_status_t st;
    long k;
    sim_init(s, 1.3);
    s->plant.bits = 24;
    s->plant.vdc_bits = 23;
    s->plant.qsat_a = a;
    sim_sync_adc_params(s);
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "qsat: no RUN");
    s->cmd.speed_ref_rpm = 1000.0f;
    /* load in steps so every current bin is crossed on the way up */
    for (k = 0; k < 40000; k++) {
        s->plant.load_nm = 1.8 * fmin(1.0, (double)k / 30000.0);
        sim_step(s);
    }
    fw_core_status(&s->core, &st);
    {
        double th = s->plant.theta;
        iq_true = -sin(th) * s->plant.ia_mean + cos(th) * s->plant.ib_mean;
    }
    lq_inc_true = 0.032 * (1 - a * iq_true * iq_true) / pow(1 + a * iq_true * iq_true, 2);
    lq_app_true = 0.032 / (1 + a * iq_true * iq_true);
    printf("core id %.2f iq %.2f speed %.1f true %.1f theta err %.2f deg\n", (double)st.id, (double)st.iq, (double)st.speed_hat_rpm, s->plant.omega_m * 60 / (2 * M_PI), sim_theta_error(s) * 180 / M_PI);
    printf("q saturation: iq %.2f A: Lq incremental %.2f mH (true %.2f), apparent %.2f mH "
           "(true %.2f)\n",
           iq_true, st.lq_hat * 1e3, lq_inc_true * 1e3, s->core.pe.lq_app * 1e3,
           lq_app_true * 1e3);
    CHECK(st.state == FW_STATE_RUN, "qsat state %d fault %u", st.state, st.fault_code);
    CHECK(fabs(st.lq_hat - lq_inc_true) < 0.05 * lq_inc_true, "incremental Lq");
    CHECK(fabs(s->core.pe.lq_app - lq_app_true) < 0.03 * lq_app_true, "apparent Lq");
}

int main(void)
{
    startup(2.0, 0.0, 2, "linear");
    startup(5.5, 0.0, 2, "linear 2");
    startup(2.0, 800.0, 1, "saturating");
    startup(4.2, 800.0, 1, "saturating 2");
    speed_run();
    flux_weakening();
    modes();
    q_saturation();
    TEST_DONE();
}
