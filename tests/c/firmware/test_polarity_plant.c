/* Start-up polarity of the core against the real plant library (plant_rt/, switching-level
 * inverter with dead time and device drop, ADC noise), every 15 deg of start angle on the
 * `paper` and `harsh` profiles and a few on `ideal` (linear magnetics: the motion check).
 * Expectations are the plant's truth: after POLARITY the estimated angle is on the north
 * pole. The pulse/chord method this replaced picked the south pole at 60, 180 and 300 deg on
 * `paper` (d_hat on an even SVPWM vector: a layout-dependent dead-time volt-second error).
 * The loop is the in-process bench (bench/, tests/c/firmware/sim.h). */
#include "fw_test.h"
#include "sim.h"

static sim_t S;

typedef struct {
    int state;        /* core state when the run ended */
    int fault;        /* its fault code (FAULT) */
    int method;       /* 1 saturation, 2 motion */
    double err_deg;   /* theta_hat - theta at the first RUN period, wrapped */
    double ratio;     /* saturation test: |Ld(-id) - Ld(+id)| / mean */
    double z;         /* ratio / its standard error */
    double move_deg;  /* largest rotor excursion from the start angle while in POLARITY */
    long periods;     /* periods from enable to RUN */
} pol_result_t;

static int run_start(const char *profile, double theta0_deg, pol_result_t *res)
{
    sim_t *s = &S;
    fw_core_t *core;
    plant_truth_t tr;
    long k;
    const long t_enable = 20;

    sim_open(s, profile, theta0_deg * M_PI / 180.0, NULL);
    core = s->core;
    s->cmd.ctrl_mode = FW_CTRL_CURRENT;
    memset(res, 0, sizeof *res);
    for (k = 0; k < 20000; k++) {
        s->cmd.enable = (int16_t)(k >= t_enable);
        sim_step(s);
        plant_truth_now(sil_bench_plant(s->b), &tr);
        if (core->state == FW_STATE_POLARITY) {
            double mv = fabs(remainder(tr.theta_e - theta0_deg * M_PI / 180.0, 2.0 * M_PI));
            res->move_deg = fmax(res->move_deg, mv * 180.0 / M_PI);
        }
        if (core->state == FW_STATE_RUN || core->state == FW_STATE_FAULT) {
            /* theta_hat is valid at the stamp of the period just measured: compare with the
             * angle at the end of it (standstill: the difference is far below the tolerance) */
            res->err_deg = remainder((double)core->theta_hat - tr.theta_e, 2.0 * M_PI) * 180.0 / M_PI;
            break;
        }
    }
    res->state = core->state;
    res->fault = core->fault_code;
    res->method = core->pol.method_used;
    res->periods = k - t_enable;
    /* margin of the saturation test: |ratio| and |ratio| / standard error (whether the pole
     * it chose is the right one is err_deg) */
    res->ratio = fabs((double)core->pol.ratio);
    res->z = (core->pol.ratio_sigma > 0.0f) ? res->ratio / (double)core->pol.ratio_sigma : 0.0;
    sim_close(s);
    return 1;
}

static void sweep(const char *profile, int step_deg, int need_saturation)
{
    int a;
    int n_sat = 0;
    int n = 0;
    double z_min = 1e9;
    double move_max = 0.0;
    for (a = 0; a < 360; a += step_deg) {
        pol_result_t r;
        if (!run_start(profile, (double)a, &r)) {
            CHECK(0, "%s: plant did not open", profile);
            return;
        }
        n++;
        printf("%s %3d deg: state %d method %d ratio %.2f %% z %.1f err %+.1f deg move %.1f deg "
               "RUN after %ld periods\n",
               profile, a, r.state, r.method, r.ratio * 100.0, r.z, r.err_deg, r.move_deg,
               r.periods);
        CHECK(r.state == FW_STATE_RUN, "%s %d deg: state %d (fault %d)", profile, a, r.state,
              r.fault);
        CHECK(fabs(r.err_deg) < 20.0, "%s %d deg: wrong pole, theta_hat - theta = %.1f deg",
              profile, a, r.err_deg);
        if (r.method == 1) {
            n_sat++;
            z_min = fmin(z_min, r.z);
        }
        move_max = fmax(move_max, r.move_deg);
    }
    printf("%s: %d/%d starts decided by saturation (min z %.1f), largest excursion %.1f deg\n",
           profile, n_sat, n, z_min, move_max);
    if (need_saturation) {
        CHECK(n_sat == n, "%s: %d of %d starts needed the motion check", profile, n - n_sat, n);
    }
}

static void linear_machine(void)
{
    static const double angles[] = {10.0, 100.0, 250.0};
    size_t i;
    for (i = 0; i < sizeof angles / sizeof angles[0]; i++) {
        pol_result_t r;
        if (!run_start("ideal", angles[i], &r)) {
            CHECK(0, "ideal: plant did not open");
            return;
        }
        printf("ideal %3.0f deg: state %d method %d ratio %.3f %% err %+.1f deg\n", angles[i],
               r.state, r.method, r.ratio * 100.0, r.err_deg);
        CHECK(r.state == FW_STATE_RUN && r.method == 2, "ideal %.0f deg: state %d method %d",
              angles[i], r.state, r.method);
        CHECK(fabs(r.err_deg) < 20.0, "ideal %.0f deg: theta_hat - theta = %.1f deg", angles[i],
              r.err_deg);
    }
}

int main(void)
{
    sweep("paper", 15, 1);
    sweep("harsh", 15, 0);
    linear_machine();
    TEST_DONE();
}
