/* Core-level closed loop on the in-process bench (bench/: the real plant, switching-level
 * inverter and ADC): start-up polarity (saturation and motion methods), position tracking with
 * the claimed time stamp, online parameters, flux weakening and recovery from a polarity
 * flip. Expectations are the plant's truth. */
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

/* profile "ideal": linear magnetics (the motion check decides); "paper": magnet-side d-axis
 * saturation (the saturation test decides) */
static void startup(double theta0, const char *profile, int expect_method, const char *name)
{
    sim_t *s = &S;
    double e;
    sim_open(s, profile, theta0, NULL);
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "%s: no RUN (state %d fault %u)", name,
          sim_state(s), s->core->fault_code);
    e = sim_theta_error(s);
    printf("%s: bias %.3f %.3f A, incremental Ld %.3f %.3f mH, ratio %+.2f %% (sigma %.2f %%); ",
           name, (double)s->core->pol.id_pos, (double)s->core->pol.id_neg,
           (double)s->core->pol.l_pos * 1e3, (double)s->core->pol.l_neg * 1e3,
           (double)s->core->pol.ratio * 100.0, (double)s->core->pol.ratio_sigma * 100.0);
    printf("%s: start %.2f rad, RUN after %ld periods, method %d, flipped %d, error %.2f deg\n",
           name, theta0, s->periods, s->core->pol.method_used, s->core->pol.flipped,
           e * 180 / M_PI);
    CHECK(s->core->pol.method_used == expect_method, "%s: method %d", name, s->core->pol.method_used);
    CHECK(fabs(e) < 5.0 * M_PI / 180, "%s: polarity/angle wrong after start-up: %.1f deg", name,
          e * 180 / M_PI);
    CHECK(s->core->polarity_ok, "%s: polarity_ok", name);
    sim_close(s);
}

/* A weak saturation contrast (harsh: 12-bit, 5 mA of noise; a 1 A bias instead of 3 A: the
 * inductance difference is ~1-5 % against a 1-3 % standard error per pair), the saturation
 * test alone (pol_method 1): it must decide only what its data show (POL_K_SIGMA standard
 * errors) and refuse the rest (POLARITY fault), never start on the south pole. Twelve start
 * angles; a test that decided at one standard error started one of them 178 deg off. */
static void weak_contrast(void)
{
    sim_t *s = &S;
    int k, wrong = 0, decided = 0;
    for (k = 0; k < 12; k++) {
        double theta0 = 0.3 + k * 2.0 * M_PI / 12.0;
        sim_open(s, "harsh", theta0, NULL);
        CHECK(fw_param_set(s->core, FW_PID_POL_PULSE_A, 1.0f) == FW_STATUS_OK, "pulse");
        CHECK(fw_param_set(s->core, FW_PID_POL_METHOD, 1.0f) == FW_STATUS_OK, "method");
        s->cmd.enable = 1;
        if (run_until_state(s, FW_STATE_RUN, 40000)) {
            decided++;
            wrong += fabs(sim_theta_error(s)) > M_PI / 2;
        } else {
            CHECK(s->core->fault_code == FW_FAULT_POLARITY, "weak contrast, start %d: state %d "
                  "fault %u", k, sim_state(s), s->core->fault_code);
        }
        sim_close(s);
    }
    printf("weak saturation contrast (harsh, 1 A): %d of 12 starts decided, %d on the wrong "
           "pole\n", decided, wrong);
    CHECK(wrong == 0, "%d starts on the wrong pole", wrong);
    CHECK(decided >= 6, "only %d of 12 starts decided", decided);
}

static void speed_run(void)
{
    sim_t *s = &S;
    double max_e, rms;
    fw_status_t st;
    const plant_truth_t *tr;
    sim_open(s, "paper", 0.7, NULL); /* 16-bit ADC, 1 mA noise, dead time, saturation */
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
    fw_core_status(s->core, &st);
    tr = sil_bench_truth(s->b);
    printf("1000 r/min: state %d fault %u speed %.1f (true %.1f) theta rms %.2f max %.2f deg, "
           "Ld %.2f Lq %.2f mH (true incremental %.2f) lambda %.4f (true %.4f) id %.3f iq %.3f\n",
           st.state, st.fault_code, (double)st.speed_hat_rpm, sim_speed_rpm(s),
           rms * 180 / M_PI, max_e * 180 / M_PI, st.ld_hat * 1e3, st.lq_hat * 1e3,
           tr->lq_inc * 1e3, (double)st.lambda_hat, tr->lambda_m, (double)st.id, (double)st.iq);
    CHECK(st.state == FW_STATE_RUN, "speed: state %d fault %u", st.state, st.fault_code);
    CHECK(fabs(sim_speed_rpm(s) - 1000.0) < 20.0, "speed not reached");
    CHECK(rms < 1.5 * M_PI / 180, "theta rms %.2f deg", rms * 180 / M_PI);
    CHECK(fabs(st.lq_hat - tr->lq_inc) < 0.03 * tr->lq_inc, "Lq %.4f (true %.4f)",
          (double)st.lq_hat, tr->lq_inc);
    CHECK(fabs(st.lambda_hat - tr->lambda_m) < 0.03 * tr->lambda_m, "lambda %.4f (true %.4f)",
          (double)st.lambda_hat, tr->lambda_m);

    /* polarity flip while running: detected and corrected */
    fw_tracker_flip(&s->core->trk);
    {
        long k;
        for (k = 0; k < 3000; k++) {
            sim_step(s);
        }
    }
    rms = rms_error_over(s, 1000, &max_e);
    fw_core_status(s->core, &st);
    printf("after forced flip: state %d flips %u theta rms %.2f deg\n", st.state,
           s->core->polarity_flips, rms * 180 / M_PI);
    CHECK(s->core->polarity_flips == 1, "flips %u", s->core->polarity_flips);
    CHECK(st.state == FW_STATE_RUN && rms < 2.0 * M_PI / 180, "no recovery");
    sim_close(s);
}

static void flux_weakening(void)
{
    sim_t *s = &S;
    double max_e, rms;
    fw_status_t st;
    long k;
    sim_open(s, "ideal", 4.0, NULL);
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "fw: no RUN");
    s->cmd.speed_ref_rpm = 3000.0f;
    for (k = 0; k < 20000; k++) {
        sim_step(s);
    }
    rms = rms_error_over(s, 2000, &max_e);
    fw_core_status(s->core, &st);
    printf("3000 r/min: state %d fault %u speed %.1f (true %.1f) fw %d id %.2f iq %.2f |v| %.1f "
           "theta rms %.2f deg\n",
           st.state, st.fault_code, (double)st.speed_hat_rpm, sim_speed_rpm(s), st.fw_active, (double)st.id, (double)st.iq, hypot(st.vd, st.vq), rms * 180 / M_PI);
    CHECK(st.state == FW_STATE_RUN, "fw: fault %u", st.fault_code);
    CHECK(fabs(sim_speed_rpm(s) - 3000.0) < 60.0, "3000 r/min not held");
    CHECK(st.fw_active && st.id < -1.0f, "flux weakening not active");
    sim_close(s);
}

/* eq. 50 with the paper's sign convention */
static double mtpa_eq50(double iq, double ld, double lq, double lam)
{
    double d = ld - lq;
    return -lam / (2 * d) - sqrt(lam * lam / (4 * d * d) + iq * iq);
}

/* The three MTPA/FW modes with a wrong nominal Lq: real-time uses the online estimates (the
 * plant's true values: its apparent Ld, Lq and lambda_m, linear on `ideal`), conventional the
 * nominal ones, id = 0 none. */
static void modes(void)
{
    sim_t *s = &S;
    fw_status_t st;
    long k;
    int m;
    const plant_truth_t *tr;
    sim_open(s, "ideal", 0.4, NULL);
    /* nominal parameters away from the machine's (Ld 15, Lq 32 mH): conventional MTPA must
     * use them, real-time MTPA what it learnt */
    CHECK(fw_param_set(s->core, FW_PID_LQ_H, 0.024f) == FW_STATUS_OK, "nominal Lq");
    CHECK(fw_param_set(s->core, FW_PID_LD_H, 0.012f) == FW_STATUS_OK, "nominal Ld");
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "modes: no RUN");
    s->cmd.speed_ref_rpm = 1000.0f;
    CHECK(sil_bench_load_cmd(s->b, HIL_BENCH_LOAD_CMD_MODE_TORQUE_CHOICE, 1.5, 0.0, 0.0) == 0, "load 1.5 N*m");
    for (m = 0; m < 3; m++) {
        static const int16_t order[3] = {FW_FWMODE_REALTIME, FW_FWMODE_CONVENTIONAL,
                                         FW_FWMODE_ID_ZERO};
        double expect;
        s->cmd.fw_mode = order[m];
        for (k = 0; k < 15000; k++) {
            sim_step(s);
        }
        fw_core_status(s->core, &st);
        tr = sil_bench_truth(s->b);
        if (order[m] == FW_FWMODE_REALTIME) {
            expect = mtpa_eq50(st.iq_ref, tr->ld_app, tr->lq_app, tr->lambda_m);
        } else if (order[m] == FW_FWMODE_CONVENTIONAL) {
            expect = mtpa_eq50(st.iq_ref, 0.012, 0.024, 0.216);
        } else {
            expect = 0.0;
        }
        printf("mode %d: speed %.1f iq_ref %.3f id_ref %.3f (eq. 50: %.3f) te_hat %.3f "
               "lq_app %.2f mH\n",
               order[m], sim_speed_rpm(s), (double)st.iq_ref, (double)st.id_ref,
               expect, (double)st.te_hat, s->core->pe.lq_app * 1e3);
        CHECK(st.state == FW_STATE_RUN && !st.fw_active, "mode %d state", order[m]);
        CHECK(fabs(st.id_ref - expect) < 0.05 * fabs(expect) + 0.01, "mode %d id_ref %.3f vs %.3f",
              order[m], (double)st.id_ref, expect);
    }
    sim_close(s);
}

/* q-axis self-saturation (docs/design.md section 5: apparent Lq 32 -> 28 mH, incremental about
 * 21 mH at 3 A): the slopes give the incremental value, MTPA gets the apparent one from the
 * integrated incremental curve (docs/estimator.md §4.7). */
static void q_saturation(void)
{
    sim_t *s = &S;
    /* the `paper` q saturation (a = 1/63 A^-2) on ideal sensors and a linear d axis */
    static const char *const qsat[] = {"magnetics.lq_sat_per_a2=0.015873015873015872", NULL};
    double iq_true = 0.0, lq_inc_true = 0.0, lq_app_true = 0.0;
    const long n_mean = 1000;
    fw_status_t st;
    long k;
    sim_open(s, "ideal", 1.3, qsat);
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "qsat: no RUN");
    s->cmd.speed_ref_rpm = 1000.0f;
    /* load in 1 ms steps so every current bin is crossed on the way up; the truth is the
     * plant's, averaged over the last n_mean periods (the current ripple moves it) */
    for (k = 0; k < 40000; k++) {
        if (k % 10 == 0) {
            (void)sil_bench_load_cmd(s->b, HIL_BENCH_LOAD_CMD_MODE_TORQUE_CHOICE, 1.8 * fmin(1.0, (double)k / 30000.0),
                                     0.0, 0.0);
        }
        sim_step(s);
        if (k >= 40000 - n_mean) {
            const plant_truth_t *tr = sil_bench_truth(s->b);
            iq_true += tr->iq / (double)n_mean;
            lq_inc_true += tr->lq_inc / (double)n_mean;
            lq_app_true += tr->lq_app / (double)n_mean;
        }
    }
    fw_core_status(s->core, &st);
    printf("core id %.2f iq %.2f speed %.1f true %.1f theta err %.2f deg\n", (double)st.id,
           (double)st.iq, (double)st.speed_hat_rpm, sim_speed_rpm(s),
           sim_theta_error(s) * 180 / M_PI);
    printf("q saturation: iq %.2f A: Lq incremental %.2f mH (true %.2f), apparent %.2f mH "
           "(true %.2f)\n",
           iq_true, st.lq_hat * 1e3, lq_inc_true * 1e3, s->core->pe.lq_app * 1e3,
           lq_app_true * 1e3);
    CHECK(st.state == FW_STATE_RUN, "qsat state %d fault %u", st.state, st.fault_code);
    CHECK(fabs(st.lq_hat - lq_inc_true) < 0.05 * lq_inc_true, "incremental Lq");
    CHECK(fabs(s->core->pe.lq_app - lq_app_true) < 0.03 * lq_app_true, "apparent Lq");
    sim_close(s);
}

/* The polarity flips and the current plausibility below are closed loops through a noisy plant near standstill: what one
 * flip does depends on the noise trajectory, and any change of the firmware's rounding draws
 * another one. Judged at one seed they were decided by chance: at 30 other seeds the firmware
 * that passed at seed 1 failed some flip check at 24 (the harsh standstill flip at 23), and an
 * ia read 5x was caught after 76-105 periods against 100. So every such check has an id, and each case can run two ways: once at the profile's seed, each
 * check a CHECK (the sanitized build, the robust cases only), or over seeds
 * (--over-seeds), where each check's failures are counted and judged against the
 * same firmware's own rate at other seeds (seeded_base below), as the gate judges its values. */
enum {
    FC_SETTLED,   /* held at the reference, no flip, before the forced one */
    FC_CAUGHT,    /* the flip corrected in time */
    FC_ONE,       /* exactly one correction */
    FC_BOUND,     /* the excursion within its independent bound */
    FC_HALVED,    /* the watch halved the excursion of the run without it */
    FC_OVERSHOOT, /* no overshoot beyond 100 r/min on the way back */
    FC_RESUMED,   /* the drive resumed from the runaway's speed */
    FC_INTEGRAL,  /* the speed loop resumed with the current that held the load */
    FC_RUN,       /* running after the recovery */
    FC_SPEED,     /* back at the reference */
    FC_THETA,     /* the position back within 5 deg */
    FC_DETECTED,  /* an implausible current caught in time */
    FC_FAULT,     /* ... as CURRENT_IMPLAUSIBLE */
    FC_N
};
static const char *const seeded_check_names[FC_N] = {
    "settled before the flip", "corrected in time", "one correction", "excursion bound",
    "watch halves the excursion", "no overshoot", "resumed from the runaway's speed",
    "speed loop's integral kept", "running after", "speed back", "position back",
    "caught in time", "the implausible-current fault"};

static int seeded_tally;          /* 1: count the seeded checks' failures instead of CHECK */
static unsigned seeded_failed;    /* the checks (bits) failed by the case being run */
static int seeded_seed;           /* the noise seed of the seeded cases (0: the profile's) */

#define SEEDED_CHECK(id, cond, ...)                                                         \
    do {                                                                                    \
        if (seeded_tally) {                                                                 \
            if (!(cond)) {                                                                  \
                seeded_failed |= 1u << (id);                                                \
            }                                                                               \
        } else {                                                                            \
            CHECK(cond, __VA_ARGS__);                                                       \
        }                                                                                   \
    } while (0)
#define SEEDED_PRINTF(...)                                                                  \
    do {                                                                                    \
        if (!seeded_tally) {                                                                \
            printf(__VA_ARGS__);                                                            \
        }                                                                                   \
    } while (0)

static void seeded_open(sim_t *s, const char *profile)
{
    char set[64];
    const char *sets[] = {set, NULL};
    snprintf(set, sizeof set, "sensors.seed=%d", seeded_seed);
    sim_open(s, profile, 0.7, seeded_seed > 0 ? sets : NULL);
}

/* Brings the bench of a profile to rpm (the polarity watch's window set when watch_window_ms
 * >= 0, as shipped otherwise), applies a torque load after before_load periods, runs
 * after_load more, checks the position is held, then turns the tracked frame round. */
static void settle_then_flip(sim_t *s, const char *profile, double watch_window_ms, float rpm,
                             long before_load, double load, long after_load, const char *name)
{
    long k;
    seeded_open(s, profile);
    if (watch_window_ms >= 0.0) {
        CHECK(fw_param_set(s->core, FW_PID_POL_WATCH_WINDOW_MS, (float)watch_window_ms) ==
                  FW_STATUS_OK, "%s: watch window", name);
    }
    CHECK(sil_bench_drive_limits(s->b, 4.5, 3500.0, 3000.0) == 0, "limits");
    s->cmd.enable = 1;
    SEEDED_CHECK(FC_SETTLED, run_until_state(s, FW_STATE_RUN, 20000), "%s: no RUN", name);
    s->cmd.speed_ref_rpm = rpm;
    for (k = 0; k < before_load; k++) {
        sim_step(s);
    }
    CHECK(sil_bench_load_cmd(s->b, 0, load, 0.0, 0.0) == 0, "load");
    for (k = 0; k < after_load; k++) {
        sim_step(s);
    }
    SEEDED_CHECK(FC_SETTLED, fabs(sim_theta_error(s)) < 5.0 * M_PI / 180 && s->core->polarity_flips == 0,
          "%s: not settled before the flip", name);
    fw_tracker_flip(&s->core->trk);
}

/* After a flip: running, back at the reference within tol, the position within 5 deg */
static void check_recovered(sim_t *s, const fw_status_t *st, double ref_rpm, double tol_rpm,
                            double max_e, const char *name)
{
    SEEDED_CHECK(FC_RUN, st->state == FW_STATE_RUN, "%s: state %d fault %u", name, st->state, st->fault_code);
    SEEDED_CHECK(FC_SPEED, fabs(sim_speed_rpm(s) - ref_rpm) < tol_rpm, "%s: speed %.1f r/min", name,
          sim_speed_rpm(s));
    SEEDED_CHECK(FC_THETA, max_e < 5.0 * M_PI / 180, "%s: theta max %.2f deg", name, max_e * 180 / M_PI);
}

/* Polarity flip at low speed under load (100 r/min, 1 N*m, paper). The flux estimator runs
 * from pol_loss_settled_min_rpm, and once settled its lambda_d turns negative with the frame:
 * the loss is caught after FW_FLUX_NEG_PERIODS (50) periods, before the shaft has turned far.
 * Independent bound: until the correction the flipped frame turns the loop's torque round,
 * so the shaft decelerates at (Te + TL)/J with Te ~ TL = 1 N*m: 2/0.0005 = 4000 rad/s^2, i.e.
 * 38 r/min per ms. Allowing 60 periods (6 ms) it may fall to 100 - 229 = -129 r/min, no lower
 * (-99 r/min, corrected after 50 periods, when this was written; before this detector the
 * loss was caught only when the runaway passed 300 r/min: -781 r/min). */
static void low_speed_flip(void)
{
    sim_t *s = &S;
    const double t_load = 1.0, j = 0.0005, allow_periods = 60.0;
    const double floor_rpm = 100.0 - 2.0 * t_load / j * allow_periods * 1e-4 * 60.0 / (2 * M_PI);
    double min_rpm = 1e9, max_e, rms;
    long k, caught = -1;
    fw_status_t st;
    settle_then_flip(s, "paper", -1.0, 100.0f, 10000, t_load, 10000, "low-speed flip");
    for (k = 0; k < 10000; k++) {
        sim_step(s);
        min_rpm = fmin(min_rpm, sim_speed_rpm(s));
        if (caught < 0 && s->core->polarity_flips >= 1) {
            caught = k + 1;
        }
    }
    rms = rms_error_over(s, 2000, &max_e);
    fw_core_status(s->core, &st);
    SEEDED_PRINTF("low-speed flip (100 r/min, 1 N*m): corrected after %ld periods, flips %u, state %d, "
           "fault %u, lowest speed %.0f r/min (bound %.0f), after 1 s: speed %.1f r/min, theta "
           "rms %.2f max %.2f deg\n",
           caught, s->core->polarity_flips, st.state, st.fault_code, min_rpm, floor_rpm,
           sim_speed_rpm(s), rms * 180 / M_PI, max_e * 180 / M_PI);
    SEEDED_CHECK(FC_CAUGHT, caught > 0 && (double)caught <= allow_periods, "low-speed flip caught after %ld periods",
          caught);
    SEEDED_CHECK(FC_ONE, s->core->polarity_flips == 1, "low-speed flip: %u corrections", s->core->polarity_flips);
    SEEDED_CHECK(FC_BOUND, min_rpm > floor_rpm, "low-speed flip: shaft fell to %.0f r/min", min_rpm);
    check_recovered(s, &st, 100.0, 10.0, max_e, "low-speed flip");
    sim_close(s);
}

/* What one forced flip did (forced_flip) */
typedef struct {
    double min_rpm, max_rpm; /* the true speed's extremes after the flip */
    long caught;             /* periods to the first correction (-1: none) */
    double hold_a;           /* at the correction: the speed PI's integral, A */
    double speed_at, est_at; /* ... the true speed and the drive's, r/min */
    double max_e;            /* position error over the 0.2 s after the first second, rad */
    fw_status_t st;          /* the core's status then */
} flip_run_t;

/* One forced flip while holding rpm against a load, the watch on (window_ms > 0) or off */
static flip_run_t forced_flip(sim_t *s, const char *profile, double rpm, double load,
                              double window_ms, const char *name)
{
    flip_run_t r;
    long k;
    settle_then_flip(s, profile, window_ms, (float)rpm, 10000, load, 20000, name);
    r.min_rpm = 1e9;
    r.max_rpm = -1e9;
    r.caught = -1;
    r.hold_a = r.speed_at = r.est_at = 0.0;
    for (k = 0; k < 10000; k++) {
        sim_step(s);
        r.min_rpm = fmin(r.min_rpm, sim_speed_rpm(s));
        r.max_rpm = fmax(r.max_rpm, sim_speed_rpm(s));
        if (r.caught < 0 && s->core->polarity_flips >= 1) {
            r.caught = k + 1;
            r.hold_a = (double)s->core->pi_spd.x;
            r.speed_at = sim_speed_rpm(s);
            r.est_at = (double)s->core->speed_f_rpm;
        }
    }
    (void)rms_error_over(s, 2000, &r.max_e);
    fw_core_status(s->core, &r.st);
    return r;
}

/* Polarity flips below pol_loss_settled_min_rpm under load (paper): no flux estimator runs
 * there; the polarity watch (polarity_detect.c) compares the back-EMF of the runaway with the
 * way the raw angle turns. Independent bound: the flipped frame turns the holding torque
 * round, so the shaft accelerates backwards at a = (Te + TL) / J = 2 TL / J; the watch can
 * decide once it has turned pol_watch_min_deg electrical, after t = sqrt(2 dtheta / (p a)), at
 * a speed a t; until the currents have turned round it may fall as far again. Without the
 * watch the runaway went on to pol_loss_min_rpm (300 r/min), where the flux estimator caught
 * it (-725 r/min at 1 r/min, 1 N*m); with it the excursion must be at most half that. Then:
 * one correction, no overshoot beyond 100 r/min
 * above the reference on the way back (the watch gives the speed loop the runaway's speed:
 * with its sign wrong the shaft overshot to +258 r/min), the speed loop resuming with the
 * current that held the load (its integral; the q current of TL, kt = 1.5 p lambda_m, within
 * 10 %: with MTPA's d current the reluctance torque takes a little of it), back at the
 * reference within 1 s with the position within 5 deg. */
static void slow_flip(const char *profile, double rpm, double load, int bound_by_turn,
                      const char *name)
{
    sim_t *s = &S;
    double j, pp, kt, dtheta, a, t_dec, bound_rpm;
    flip_run_t off, on;
    off = forced_flip(s, profile, rpm, load, 0.0, name);
    sim_close(s);
    on = forced_flip(s, profile, rpm, load, 20.0, name);
    {
        const plant_config_t *pc = plant_config(sil_bench_plant(s->b));
        j = pc->shaft.j_kgm2;
        pp = pc->machine.pole_pairs;
        kt = 1.5 * pp * pc->machine.lambda_m_wb;
    }
    dtheta = (double)s->core->p[FW_IDX_POL_WATCH_MIN_DEG] * M_PI / 180.0;
    a = 2.0 * load / j;
    t_dec = sqrt(2.0 * dtheta / (pp * a));
    bound_rpm = 2.0 * a * t_dec * 60.0 / (2.0 * M_PI);
    SEEDED_PRINTF("%s (%s, %.0f r/min, %.1f N*m): watch off: corrected after %ld periods, excursion to "
           "%.0f r/min, overshoot to %.0f; watch on: after %ld periods (%.1f ms), excursion to "
           "%.0f r/min (bound %.0f below the reference), overshoot to %.0f r/min, flips %u, "
           "after 1 s: speed %.1f r/min, theta max %.2f deg\n",
           name, profile, rpm, load, off.caught, off.min_rpm, off.max_rpm, on.caught,
           (double)on.caught * 0.1, on.min_rpm, bound_rpm, on.max_rpm, s->core->polarity_flips,
           sim_speed_rpm(s), on.max_e * 180 / M_PI);
    SEEDED_PRINTF("%s: at the correction the shaft at %.0f r/min, the drive's speed %.0f r/min, the "
           "speed PI's integral %.2f A (the load's %.2f A)\n", name, on.speed_at, on.est_at,
           on.hold_a, load / kt);
    SEEDED_CHECK(FC_CAUGHT, on.caught > 0 && on.caught <= 200, "%s: corrected after %ld periods (20 ms: 200)",
          name, on.caught);
    SEEDED_CHECK(FC_ONE, s->core->polarity_flips == 1, "%s: %u corrections", name, s->core->polarity_flips);
    if (bound_by_turn) {
        SEEDED_CHECK(FC_BOUND, on.min_rpm > rpm - bound_rpm, "%s: shaft fell to %.0f r/min", name, on.min_rpm);
    }
    SEEDED_CHECK(FC_HALVED, rpm - on.min_rpm < 0.5 * (rpm - off.min_rpm), "%s: the watch did not halve the "
          "excursion (%.0f r/min against %.0f)", name, on.min_rpm, off.min_rpm);
    SEEDED_CHECK(FC_OVERSHOOT, on.max_rpm < rpm + 100.0, "%s: the recovery overshot to %.0f r/min", name, on.max_rpm);
    /* the speed the drive resumes from is the runaway's (the back-EMF's line): the tracker,
     * narrowed to its standstill bandwidth, still said ~1 r/min when the watch decided */
    SEEDED_CHECK(FC_RESUMED, fabs(on.est_at - on.speed_at) < 0.25 * fabs(on.speed_at - rpm), "%s: resumed from "
          "%.0f r/min, the shaft at %.0f", name, on.est_at, on.speed_at);
    /* the speed PI's integral held the load until the frame turned; the watch keeps it */
    SEEDED_CHECK(FC_INTEGRAL, fabs(on.hold_a * kt - load) < 0.1 * load, "%s: the speed loop resumed with %.2f A for "
          "%.1f N*m", name, on.hold_a, load);
    check_recovered(s, &on.st, rpm, 5.0, on.max_e, name);
    sim_close(s);
}

/* A flip with no load near standstill: the flipped frame produces no torque until the speed
 * loop's error asks for some, so the shaft drifts off slowly (the speed loop's positive
 * feedback) and the watch decides once the drift spans pol_watch_min_deg within a window.
 * What must hold: corrected before the shaft has reached 100 r/min backwards, one correction,
 * back at the reference. */
static void slow_flip_no_load(double rpm, const char *name)
{
    sim_t *s = &S;
    flip_run_t r = forced_flip(s, "paper", rpm, 0.0, 20.0, name);
    SEEDED_PRINTF("%s (%.0f r/min, no load): corrected after %ld periods (%.1f ms), excursion to %.0f "
           "r/min, overshoot to %.0f r/min, flips %u, after 1 s: speed %.1f r/min, theta max "
           "%.2f deg\n",
           name, rpm, r.caught, (double)r.caught * 0.1, r.min_rpm, r.max_rpm,
           s->core->polarity_flips, sim_speed_rpm(s), r.max_e * 180 / M_PI);
    SEEDED_CHECK(FC_CAUGHT, r.caught > 0, "%s: not corrected", name);
    SEEDED_CHECK(FC_ONE, s->core->polarity_flips == 1, "%s: %u corrections", name, s->core->polarity_flips);
    SEEDED_CHECK(FC_BOUND, r.min_rpm > rpm - 100.0, "%s: shaft fell to %.0f r/min", name, r.min_rpm);
    SEEDED_CHECK(FC_OVERSHOOT, r.max_rpm < rpm + 100.0, "%s: the recovery overshot to %.0f r/min", name, r.max_rpm);
    check_recovered(s, &r.st, rpm, 5.0, r.max_e, name);
    sim_close(s);
}

/* Opens the bench on a profile at a noise seed (plus one more plant setting, or NULL) with
 * the suites' sampling: 5 samples per switching state, 8 us after the edge */
static void open_seeded(sim_t *s, const char *profile, int seed, const char *extra)
{
    char set[64];
    const char *sets[] = {set, extra, NULL};
    snprintf(set, sizeof set, "sensors.seed=%d", seed);
    sim_open(s, profile, 0.0, sets);
    CHECK(fw_param_set(s->core, FW_PID_SOC_ON_US, 8.0f) == FW_STATUS_OK &&
              fw_param_set(s->core, FW_PID_SOC_OFF_US, 1.0f) == FW_STATUS_OK &&
              fw_param_set(s->core, FW_PID_SOC_PER_STATE, 5.0f) == FW_STATUS_OK,
          "sampling");
}

/* No correction of a correct frame: the shaft accelerating from standstill without load at
 * 1500 r/min/s (the coverage scenario cov_fw_release_3000rpm's start: paper, 5 samples per
 * state 8 us after the edge), seeds 1-8. The current is ~0.13 A there: the phase currents
 * cross zero within the period, the dead time's voltage is unknown by volts and the back-EMF
 * at 25 r/min is 1.1 V; a south verdict from such a window (without the watch's current
 * guard) turned the frame round at seeds 4 and 5 (23-26 r/min), and the watch turned it back
 * at -82 and -86 r/min. */
static void no_false_flip_from_standstill(void)
{
    sim_t *s = &S;
    int seed, flipped = 0;
    unsigned north = 0;
    for (seed = 1; seed <= 8; seed++) {
        long k;
        open_seeded(s, "paper", seed, NULL);
        CHECK(sil_bench_drive_limits(s->b, 4.5, 3300.0, 1500.0) == 0, "limits");
        s->cmd.enable = 1;
        s->cmd.speed_ref_rpm = 3000.0f;
        for (k = 0; k < 5000; k++) {
            sim_step(s);
        }
        CHECK(sim_state(s) == FW_STATE_RUN && sim_speed_rpm(s) > 300.0,
              "seed %d: state %d at %.0f r/min", seed, sim_state(s), sim_speed_rpm(s));
        flipped += s->core->polarity_flips != 0;
        north += s->core->watch.decided_north;
        sim_close(s);
    }
    printf("accelerating from standstill without load (paper, seeds 1-8): %d runs with a "
           "correction, %u windows decided north\n", flipped, north);
    CHECK(flipped == 0, "%d of 8 runs turned a correct frame round", flipped);
    CHECK(north > 0, "the watch decided nothing: it did not run"); /* else the test proves nothing */
}

/* No correction of a correct frame on the hot machine: harsh's rs is 30 % above the
 * firmware's rs_ohm, and taking up 2 N*m at 1 r/min puts 3.2 A on q, so the watch's voltage
 * model carries (rs - rs_ohm) iq in the q back-EMF it integrates: the back-EMF of ~40 r/min
 * while the shaft turns at a few. With harsh's own 5 mA of sensor noise the window's
 * regression stayed too uncertain to decide; with a 1 mA sensor every seed 1-8 turned the
 * correct frame round at the end of the load ramp (0.52-0.55 s) and ran away. Expected: no
 * correction, still in RUN, the frame kept (within 20 deg: the cross-saturation, uncompensated
 * here as in held_rotor_steps, turns the saliency axes by ~5 deg at 3 A) and windows decided
 * north (the watch ran). */
static void no_false_flip_hot_machine(void)
{
    sim_t *s = &S;
    int seed, flipped = 0;
    unsigned north = 0;
    double e_max = 0.0, bias_v = 0.0;
    for (seed = 1; seed <= 4; seed++) {
        long k;
        open_seeded(s, "harsh", seed, "sensors.noise_rms_a=0.001");
        CHECK(sil_bench_drive_limits(s->b, 4.5, 3500.0, 3000.0) == 0, "limits");
        s->cmd.enable = 1;
        CHECK(run_until_state(s, FW_STATE_RUN, 20000), "seed %d: no RUN", seed);
        s->cmd.speed_ref_rpm = 1.0f;
        /* the load ramps to 2 N*m over 0.25-0.45 s, held to 0.8 s */
        for (k = 0; k < 8000; k++) {
            double t = (double)k * 1e-4;
            if (k % 10 == 0) {
                double tl = t < 0.25 ? 0.0 : (t < 0.45 ? 2.0 * (t - 0.25) / 0.2 : 2.0);
                CHECK(sil_bench_load_cmd(s->b, 0, tl, 0.0, 0.0) == 0, "load");
            }
            sim_step(s);
            if (k >= 6000) {
                e_max = fmax(e_max, fabs(sim_theta_error(s)));
            }
        }
        {
            const plant_config_t *pc = plant_config(sil_bench_plant(s->b));
            bias_v = (pc->machine.rs_ohm - (double)s->core->p[FW_IDX_RS_OHM]) * (double)s->core->iq;
        }
        CHECK(sim_state(s) == FW_STATE_RUN, "seed %d: state %d fault %u", seed, sim_state(s),
              s->core->fault_code);
        flipped += s->core->polarity_flips != 0;
        north += s->core->watch.decided_north;
        sim_close(s);
    }
    printf("hot machine, 1 mA sensor, 2 N*m taken up at 1 r/min (harsh, seeds 1-4): %d runs "
           "with a correction, %u windows decided north, the rs error's q voltage %.2f V, "
           "position after 0.6 s at most %.2f deg\n", flipped, north, bias_v,
           e_max * 180 / M_PI);
    CHECK(flipped == 0, "%d of 4 runs turned a correct frame round", flipped);
    CHECK(north > 0, "the watch decided nothing: it did not run");
    CHECK(e_max < 20.0 * M_PI / 180, "position error %.2f deg", e_max * 180 / M_PI);
}

/* Current plausibility (fw_core.c current_sensor_check): a current channel that no longer
 * measures what flows bends the inverse inductance matrix the slopes measure out of what any
 * machine has. Independent expectation: ia read k times scales the a-row of the measured
 * matrix, so its mean Gamma0 is ~(k+1)/2 of the true one (3 for k = 5, beyond the 2 allowed);
 * ia stuck at mid-scale zeroes that row (Gamma0 halved, Gamma1 >= Gamma0). Either way every
 * two-vector period counts, and at 1000 r/min at least a third of the periods are such: the
 * 20 of sensor_fail_max within 100 periods. Before the fault, a run with load must not count
 * to it. */
typedef struct {
    int kind; /* 0 off, 1 ia x5, 2 ia stuck at mid-scale, 3 ia x5 in 3 of 4 periods */
    int32_t mid;
    int32_t top;
    uint32_t lcg; /* kind 3: which periods (a fixed pseudo-random draw) */
} plaus_fault_t;

static void plaus_hook(void *ctx, fw_adc_t *adc)
{
    plaus_fault_t *f = (plaus_fault_t *)ctx;
    int16_t k;
    int kind = f->kind;
    if (kind == 3) {
        f->lcg = f->lcg * 1664525u + 1013904223u;
        kind = ((f->lcg >> 24) % 4u != 0u) ? 1 : 0;
    }
    for (k = 0; k < adc->n_soc && kind != 0; k++) {
        int64_t v = (kind == 1) ? f->mid + 5 * ((int64_t)adc->ia[k] - f->mid) : f->mid;
        adc->ia[k] = (int32_t)(v < 0 ? 0 : (v > f->top ? f->top : v));
    }
}

static void current_plausibility(int kind, long within, const char *name)
{
    sim_t *s = &S;
    plaus_fault_t f;
    long k, caught = -1;
    fw_status_t st;
    seeded_open(s, "paper");
    f.kind = 0;
    f.lcg = 12345u;
    f.mid = sim_current_code(s, 0.0);
    f.top = 2 * f.mid - 1;
    sil_bench_set_adc_hook(s->b, plaus_hook, &f);
    s->cmd.enable = 1;
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "%s: no RUN", name);
    s->cmd.speed_ref_rpm = 1000.0f;
    CHECK(sil_bench_load_cmd(s->b, 0, 1.0, 0.0, 0.0) == 0, "load");
    for (k = 0; k < 6000; k++) {
        sim_step(s);
    }
    fw_core_status(s->core, &st);
    SEEDED_CHECK(FC_SETTLED, st.state == FW_STATE_RUN && s->core->sensor_bad < 5,
          "%s: before the fault state %d, count %d", name, st.state, s->core->sensor_bad);
    f.kind = kind;
    for (k = 0; k < 300 && caught < 0; k++) {
        sim_step(s);
        if (s->core->state == FW_STATE_FAULT) {
            caught = k + 1;
        }
    }
    fw_core_status(s->core, &st);
    SEEDED_PRINTF("current plausibility, %s at 1000 r/min, 1 N*m: fault %u after %ld periods\n", name,
           st.fault_code, caught);
    SEEDED_CHECK(FC_DETECTED, caught > 0 && caught <= within, "%s: caught after %ld periods",
                 name, caught);
    SEEDED_CHECK(FC_FAULT, st.fault_code == FW_FAULT_CURRENT_IMPLAUSIBLE, "%s: fault %u", name, st.fault_code);
    sil_bench_set_adc_hook(s->b, NULL, NULL);
    sim_close(s);
}

/* Start against a load: tl (N*m, opposing positive rotation) on the shaft from the enable, no
 * speed command. The drive makes no torque it knows the sign of until the polarity is
 * decided, so the light shaft (J = 0.0005 kg*m^2) accelerates at a1 = tl/J; the back-EMF
 * test must decide it (the saturation test needs ~76 ms on paper, the motion check its own
 * motion) and the torque must hold the load within 20 ms. Independent bound on the kick-back:
 * the shaft reaches a1 t_run by the decision and is brought back at the recovery ramp
 * (start_recover_rpm_s, 3000 r/min/s = 314 rad/s^2 here): it turns back by at most
 * a1 t_run^2 / 2 + (a1 t_run)^2 / (2 a_rec), times 1.3 for the torque's rise and the
 * speed loop's lag. Before the back-EMF test 2 N*m on paper tripped on over-current at
 * -2270 r/min after the 76 ms of the saturation test. */
static void load_start(const char *profile, double tl, double theta0_deg, const char *name)
{
    sim_t *s = &S;
    const double j = 0.0005;
    double a1 = fabs(tl) / j, back = 0.0, ang = 0.0, bound, back_to_rpm = 0.0;
    double ref_prev = 0.0, ref_step = 0.0, rec_rpm_s, a_rec;
    long k, k_run = -1, k_torque = -1, pol_err = 0;
    plant_truth_t tr;
    sim_open(s, profile, theta0_deg * M_PI / 180.0, NULL);
    rec_rpm_s = (double)s->core->p[FW_IDX_START_RECOVER_RPM_S];
    a_rec = rec_rpm_s * 2 * M_PI / 60.0; /* rad/s^2 */
    /* the command's ramp as fast as the bus allows, as the rig sets it (it ramps itself) */
    CHECK(sil_bench_drive_limits(s->b, 4.5, 3500.0, 100000.0) == 0, "limits");
    CHECK(sil_bench_load_cmd(s->b, 0, tl, 0.0, 0.0) == 0, "load");
    s->cmd.enable = 1;
    for (k = 0; k < 5000; k++) {
        sim_step(s);
        plant_truth_now(sil_bench_plant(s->b), &tr);
        ang += tr.omega_m * 1e-4; /* mechanical rad, from the enable */
        back = fmax(back, (tl > 0 ? -ang : ang));
        if (k_run < 0 && sim_state(s) == FW_STATE_RUN) {
            k_run = k + 1;
            back_to_rpm = s->core->start_speed_rpm;
        } else if (k_run >= 0) {
            ref_step = fmax(ref_step, fabs(s->core->speed_ref_ramped - ref_prev));
        }
        ref_prev = s->core->speed_ref_ramped;
        if (k_torque < 0 && tr.te * tl >= 0.5 * tl * tl) {
            k_torque = k + 1;
        }
        if (k_run >= 0 && fabs(sim_theta_error(s)) > M_PI / 2) {
            pol_err++;
        }
        if (sim_state(s) == FW_STATE_FAULT) {
            break;
        }
    }
    bound = 1.3 * (0.5 * a1 * pow(k_run * 1e-4, 2) + pow(a1 * k_run * 1e-4, 2) / (2 * a_rec));
    printf("%s: %+.1f N*m, RUN after %.1f ms (method %d), torque after %.1f ms, kick-back %.1f "
           "deg (bound %.1f), back to %+.1f r/min, reference steps <= %.2f r/min, polarity "
           "errors %ld periods, state %d fault %u\n",
           name, tl, k_run * 0.1, s->core->pol.method_used, k_torque * 0.1, back * 180 / M_PI,
           bound * 180 / M_PI, back_to_rpm, ref_step, pol_err, sim_state(s), s->core->fault_code);
    CHECK(sim_state(s) == FW_STATE_RUN, "%s: state %d fault %u", name, sim_state(s),
          s->core->fault_code);
    CHECK(s->core->pol.method_used == FW_POL_METHOD_EMF, "%s: method %d", name,
          s->core->pol.method_used);
    CHECK(k_torque > 0 && k_torque <= 200, "%s: torque after %ld periods", name, k_torque);
    CHECK(back < bound, "%s: kick-back %.1f deg", name, back * 180 / M_PI);
    /* the recovery returns to the speed at the enable, 0 here; the back-EMF line extended
     * from its first period back to the enable finds it within 15 % of the speed the load
     * has given the shaft by the decision (measured 1-8 %; the line's own start, ~2.5 ms after
     * the enable, was 15-37 % of it: the reference then stepped by that at the return's end) */
    CHECK(fabs(back_to_rpm) < 0.15 * a1 * k_run * 1e-4 * 60.0 / (2 * M_PI),
          "%s: back to %+.1f r/min, the shaft at rest at the enable", name, back_to_rpm);
    /* and from the return on to the command (0 here) no faster than the return itself, at
     * start_recover_rpm_s per 1 ms speed-loop step, whatever the command's ramp: the enable's
     * speed is an estimate, and a step from it to the command brakes at once */
    CHECK(ref_step <= rec_rpm_s * FW_SPEED_DIVIDER * FW_TS + 1e-3,
          "%s: the speed reference stepped by %.2f r/min", name, ref_step);
    CHECK(pol_err == 0, "%s: %ld periods of polarity error", name, pol_err);
    CHECK(fabs(sim_theta_error(s)) < 5.0 * M_PI / 180, "%s: theta error %.1f deg", name,
          sim_theta_error(s) * 180 / M_PI);
    sim_close(s);
}

/* Flying start: the load machine holds the shaft at rpm when the drive is enabled (and lets it
 * go 30 ms later). Zero volts
 * against the back-EMF (136 V at 3000 r/min over 15-32 mH) would raise the current by up to
 * 0.9 A per period: the catch must find angle and speed within 5 ms (the back-EMF test, for
 * a slow shaft, within 10 ms), keep the current within i_max plus the PWM ripple allowed at
 * the voltage limit (4.7 A), and run in the right frame (the shaft's speed imposed, the
 * position error small 50 ms on). Before the catch 3000 r/min tripped on over-current
 * (10.3 A). */
static void flying_start(const char *profile, double rpm, int expect_method, double e_lim_deg,
                         const char *name)
{
    sim_t *s = &S;
    char spd[64], hold[64];
    const char *sets[4];
    double ipk = 0.0, emax = 0.0;
    long k, k_run = -1;
    plant_truth_t tr;
    snprintf(spd, sizeof spd, "initial.speed_rpm=%g", rpm);
    snprintf(hold, sizeof hold, "load.speed_rpm=%g", rpm);
    sets[0] = spd;
    sets[1] = "load.mode=1";
    sets[2] = hold;
    sets[3] = NULL;
    sim_open(s, profile, 1.1, sets);
    CHECK(sil_bench_drive_limits(s->b, 4.5, 3500.0, 3000.0) == 0, "limits");
    /* the sampling the scenarios use (Table 2, suite starts): the slope windows from 8 us
     * after a turn-on to 1 us before a turn-off, 5 samples each */
    CHECK(fw_param_set(s->core, FW_PID_SOC_ON_US, 8.0f) == FW_STATUS_OK, "soc_on_us");
    CHECK(fw_param_set(s->core, FW_PID_SOC_OFF_US, 1.0f) == FW_STATUS_OK, "soc_off_us");
    CHECK(fw_param_set(s->core, FW_PID_SOC_PER_STATE, 5.0f) == FW_STATUS_OK, "soc_per_state");
    s->cmd.speed_ref_rpm = (float)rpm;
    s->cmd.enable = 1;
    for (k = 0; k < 3000; k++) {
        if (k == 300) {
            CHECK(sil_bench_load_cmd(s->b, 0, 0.0, 0.0, 0.0) == 0, "release"); /* let go */
        }
        sim_step(s);
        plant_truth_now(sil_bench_plant(s->b), &tr);
        ipk = fmax(ipk, hypot(tr.id, tr.iq));
        if (k_run < 0 && sim_state(s) == FW_STATE_RUN) {
            k_run = k + 1;
        }
        if (k_run >= 0 && k > k_run + 500) {
            emax = fmax(emax, fabs(sim_theta_error(s)));
        }
        if (sim_state(s) == FW_STATE_FAULT) {
            break;
        }
    }
    printf("%s: %+.0f r/min, RUN after %.1f ms (method %d), current peak %.2f A, position "
           "error after 50 ms of RUN at most %.2f deg, state %d fault %u\n",
           name, rpm, k_run * 0.1, s->core->pol.method_used, ipk, emax * 180 / M_PI,
           sim_state(s), s->core->fault_code);
    CHECK(sim_state(s) == FW_STATE_RUN, "%s: state %d fault %u", name, sim_state(s),
          s->core->fault_code);
    CHECK(s->core->pol.method_used == expect_method, "%s: method %d", name,
          s->core->pol.method_used);
    CHECK(k_run > 0 && k_run <= (expect_method == FW_POL_METHOD_CATCH ? 50 : 100),
          "%s: RUN after %ld periods", name, k_run);
    CHECK(ipk <= 4.7, "%s: current peak %.2f A", name, ipk);
    CHECK(emax < e_lim_deg * M_PI / 180, "%s: position error %.2f deg", name, emax * 180 / M_PI);
    sim_close(s);
}

/* A rotor the load machine holds (a locked-rotor test, a brake, a jammed load) while the drive
 * steps its q current, as the commissioning's rs measurement does. The tracker predicts the
 * acceleration the torque would give a free shaft; the held rotor does not make it, and the
 * estimate runs off for tens of ms (+290 r/min within 20 ms at 1.5 A on harsh) before the raw
 * angle pulls it back. Over a rotor that does not turn, the flux estimate then sees no back-EMF:
 * about 0, where a turned frame shows about -lambda_m. When any negative value counted as a
 * turned frame, the flux check turned the harsh drive's frame by pi under these steps at every
 * start angle tried. */
static void held_rotor_steps(const char *profile, double theta0_deg, const char *name)
{
    static const float steps_a[] = {1.5f, 2.25f, 3.0f};
    sim_t *s = &S;
    double e_end;
    long k;
    int j;
    sim_open(s, profile, theta0_deg * M_PI / 180.0, NULL);
    CHECK(sil_bench_drive_limits(s->b, 4.0, 3000.0, 3000.0) == 0, "limits");
    s->cmd.ctrl_mode = FW_CTRL_CURRENT;
    s->cmd.fw_mode = FW_FWMODE_ID_ZERO;
    s->cmd.iq_ref = 0.0f;
    s->cmd.enable = 1; /* on the free shaft, as the commissioning starts */
    CHECK(run_until_state(s, FW_STATE_RUN, 20000), "%s: no RUN", name);
    CHECK(sil_bench_load_cmd(s->b, HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE, 0.0, 0.0, 0.0) == 0,
          "hold");
    /* 1.5 s at zero current, as long as the commissioning measures and aligns before its rs
     * steps: the tracker's bandwidth has come down to its floor (after 0.3 s it had not, and
     * the steps did not turn the frame even with the old check) */
    for (k = 0; k < 15000; k++) {
        sim_step(s);
    }
    for (j = 0; j < 3; j++) {
        s->cmd.iq_ref = steps_a[j];
        for (k = 0; k < 5000; k++) {
            sim_step(s);
        }
    }
    e_end = sim_theta_error(s);
    printf("%s: q current steps 1.5/2.25/3 A on the held rotor: frame turned %u times, position "
           "error at the end %+.1f deg, state %d\n", name, s->core->polarity_flips,
           e_end * 180 / M_PI, sim_state(s));
    CHECK(sim_state(s) == FW_STATE_RUN, "%s: state %d fault %u", name, sim_state(s),
          s->core->fault_code);
    CHECK(s->core->polarity_flips == 0, "%s: the frame was turned %u times", name,
          s->core->polarity_flips);
    /* kept: a turned frame is 180 deg off; the harsh machine's cross-saturation, uncompensated
     * here (xsat_ldq_per_a 0), turns the saliency axes by ~5 deg at 3 A */
    CHECK(fabs(e_end) < 20.0 * M_PI / 180.0, "%s: position error %.1f deg", name,
          e_end * 180 / M_PI);
    sim_close(s);
}

/* The cases judged over seeds, each a closed loop of a second or a few */
static void flip_low_speed(void) { low_speed_flip(); }
static void flip_paper_1_05(void) { slow_flip("paper", 1.0, 0.5, 1, "standstill flip"); }
static void flip_paper_1_1(void) { slow_flip("paper", 1.0, 1.0, 1, "standstill flip"); }
static void flip_paper_1_2(void) { slow_flip("paper", 1.0, 2.0, 1, "standstill flip"); }
static void flip_paper_10_1(void) { slow_flip("paper", 10.0, 1.0, 1, "slow flip"); }
/* harsh (12-bit, 5 mA): the raw angle's scatter makes the watch wait for ~twice the turn
 * (10.7 ms at 1 N*m), so it is held to halving the excursion, not to the bound */
static void flip_harsh_1_1(void) { slow_flip("harsh", 1.0, 1.0, 0, "standstill flip"); }
static void flip_no_load_10(void) { slow_flip_no_load(10.0, "slow flip"); }
static void plaus_gain(void) { current_plausibility(1, 100, "ia read 5x"); }
static void plaus_stuck(void) { current_plausibility(2, 100, "ia stuck at mid-scale"); }
/* an intermittent fault: the count leaks (one good period takes one off), so three bad
 * periods in four still add up: 20 net within 40 two-vector periods, 120 periods at a third
 * of them; a count that a good period reset would never get there */
static void plaus_intermittent(void) { current_plausibility(3, 200, "ia read 5x in 3 of 4"); }

#define SEEDED_CASES 10
static const struct {
    const char *name;
    void (*run)(void);
} seeded_cases[SEEDED_CASES] = {
    {"paper 100 r/min 1 N*m", flip_low_speed},  {"paper 1 r/min 0.5 N*m", flip_paper_1_05},
    {"paper 1 r/min 1 N*m", flip_paper_1_1},    {"paper 1 r/min 2 N*m", flip_paper_1_2},
    {"paper 10 r/min 1 N*m", flip_paper_10_1},  {"harsh 1 r/min 1 N*m", flip_harsh_1_1},
    {"paper 10 r/min no load", flip_no_load_10}, {"ia read 5x", plaus_gain},
    {"ia stuck at mid-scale", plaus_stuck},       {"ia read 5x 3 of 4", plaus_intermittent},
};

/* The firmware's own failure counts per case and check at SEEDED_BASE_N seeds that a judged
 * sweep does not use (SEEDED_BASE_FIRST on), as printed by
 *   fw_test_closed_loop --seed-rates 101 140
 * The table is the firmware's behaviour, like a gate baseline: re-measure it when a change to
 * the firmware is meant to move it, and say so in the commit. */
#define SEEDED_BASE_FIRST 101
#define SEEDED_BASE_N 40
static const unsigned char seeded_base[SEEDED_CASES][FC_N] = {
#include "seeded_base.inc"
};

/* A sweep is judged per case and check: k failing seeds of n against the base rate
 * (b + 1) / (SEEDED_BASE_N + 2) (one failure more than seen, so a rate never seen is not taken
 * for zero); the check fails when k or more failures are that unlikely, P(X >= k) <=
 * SEEDED_ALPHA. At eight seeds a check that fails at every seed is caught while its base rate is
 * below 42 %. The chance that the unchanged firmware fails some check at a fresh draw of seeds
 * (the sum over the checks at their base rates) is printed with the table. */
#define SEEDED_ALPHA 1e-3

static double binomial_tail(int n, int k, double p)
{
    double tail = 0.0;
    int j;
    for (j = k; j <= n; j++) {
        double c = 1.0;
        int i;
        for (i = 0; i < j; i++) {
            c = c * (double)(n - i) / (double)(i + 1);
        }
        tail += c * pow(p, j) * pow(1.0 - p, n - j);
    }
    return tail;
}

/* Runs every flip case at seeds first..last, counting each check's failing seeds */
static void seeded_sweep(int first, int last, int counts[SEEDED_CASES][FC_N])
{
    int c, seed, id;
    seeded_tally = 1;
    memset(counts, 0, sizeof(int) * SEEDED_CASES * FC_N);
    for (c = 0; c < SEEDED_CASES; c++) {
        for (seed = first; seed <= last; seed++) {
            seeded_seed = seed;
            seeded_failed = 0;
            seeded_cases[c].run();
            for (id = 0; id < FC_N; id++) {
                counts[c][id] += (int)((seeded_failed >> id) & 1u);
            }
        }
    }
    seeded_tally = 0;
    seeded_seed = 0;
}

/* --seed-rates FIRST LAST: the base table (seeded_base.inc) */
static int seeded_rates(int first, int last)
{
    int counts[SEEDED_CASES][FC_N], c, id;
    seeded_sweep(first, last, counts);
    printf("/* fw_test_closed_loop --seed-rates %d %d: failing seeds of %d per case and check, in "
           "the order of the FC_ ids */\n", first, last, last - first + 1);
    for (c = 0; c < SEEDED_CASES; c++) {
        printf("{");
        for (id = 0; id < FC_N; id++) {
            printf("%d%s", counts[c][id], id + 1 < FC_N ? ", " : "");
        }
        printf("}, /* %s */\n", seeded_cases[c].name);
    }
    return 0;
}

/* --over-seeds FIRST LAST: every flip case at those seeds, judged against seeded_base */
static int over_seeds(int first, int last)
{
    int counts[SEEDED_CASES][FC_N], c, id, n = last - first + 1;
    double false_alarm = 0.0;
    if (last >= SEEDED_BASE_FIRST) {
        fprintf(stderr, "--over-seeds %d %d: the seeds must lie below the base's (%d on)\n",
                first, last, SEEDED_BASE_FIRST);
        return 2;
    }
    seeded_sweep(first, last, counts);
    printf("polarity flips and current plausibility at seeds %d-%d, judged against seeds %d-%d (P: the chance of so many "
           "failing seeds at the base rate; a check fails at P <= %g)\n", first, last,
           SEEDED_BASE_FIRST, SEEDED_BASE_FIRST + SEEDED_BASE_N - 1, SEEDED_ALPHA);
    for (c = 0; c < SEEDED_CASES; c++) {
        for (id = 0; id < FC_N; id++) {
            double rate = (seeded_base[c][id] + 1.0) / (SEEDED_BASE_N + 2.0);
            double pk = binomial_tail(n, counts[c][id], rate);
            int kcrit = 0;
            while (kcrit <= n && binomial_tail(n, kcrit, rate) > SEEDED_ALPHA) {
                kcrit++;
            }
            if (kcrit <= n) {
                false_alarm += binomial_tail(n, kcrit, (double)seeded_base[c][id] / SEEDED_BASE_N);
            }
            if (counts[c][id] > 0 || seeded_base[c][id] > 0) {
                printf("  %-24s %-34s %d of %d (base %2u of %d) P %.2g%s\n", seeded_cases[c].name,
                       seeded_check_names[id], counts[c][id], n, seeded_base[c][id], SEEDED_BASE_N,
                       counts[c][id] > 0 ? pk : 1.0,
                       counts[c][id] > 0 && pk <= SEEDED_ALPHA ? "  FAILED" : "");
            }
            CHECK(counts[c][id] == 0 || pk > SEEDED_ALPHA, "%s: %s failed at %d of %d seeds (base "
                  "%u of %d: P %.2g)", seeded_cases[c].name, seeded_check_names[id], counts[c][id],
                  n, seeded_base[c][id], SEEDED_BASE_N, pk);
        }
    }
    printf("the chance that the unchanged firmware fails this sweep at fresh seeds (the sum over "
           "the checks at their base rates): %.2g\n", false_alarm);
    TEST_DONE();
}

int main(int argc, char **argv)
{
    if (argc == 4 && (strcmp(argv[1], "--over-seeds") == 0 ||
                      strcmp(argv[1], "--seed-rates") == 0)) {
        int first = atoi(argv[2]), last = atoi(argv[3]);
        if (first < 1 || last < first) {
            fprintf(stderr, "%s FIRST LAST: seeds from 1, FIRST <= LAST\n", argv[1]);
            return 2;
        }
        return strcmp(argv[1], "--seed-rates") == 0 ? seeded_rates(first, last)
                                                     : over_seeds(first, last);
    }
    if (argc != 1) {
        fprintf(stderr, "usage: %s [--over-seeds FIRST LAST | --seed-rates FIRST LAST]\n",
                argv[0]);
        return 2;
    }
    startup(2.0, "ideal", 2, "linear");
    startup(5.5, "ideal", 2, "linear 2");
    startup(2.0, "paper", 1, "saturating");
    startup(4.2, "paper", 1, "saturating 2");
    weak_contrast();
    speed_run();
    /* at the profile's seed, each check a CHECK: the cases that passed every check at the 40
     * base seeds (seeded_base); every case is judged over seeds by fw_closed_loop_over_seeds */
    flip_paper_1_05();
    flip_paper_1_1();
    flip_paper_10_1();
    no_false_flip_from_standstill();
    no_false_flip_hot_machine();
    /* (a stuck ia is caught after 20 periods at every base seed; a gain error's detection
     * moves with the noise: over seeds only, with the flips above) */
    plaus_stuck();
    flux_weakening();
    modes();
    q_saturation();
    load_start("paper", 2.0, 40.0, "load start paper");
    load_start("paper", -2.0, 200.0, "load start paper reverse");
    load_start("ideal", 1.0, 110.0, "load start ideal");
    load_start("harsh", 1.0, 290.0, "load start harsh");
    /* the position within the usual limits: 2.5 deg on paper, 5 deg on harsh */
    flying_start("paper", 3000.0, FW_POL_METHOD_CATCH, 2.5, "flying start");
    flying_start("paper", -3000.0, FW_POL_METHOD_CATCH, 2.5, "flying start reverse");
    flying_start("harsh", -1000.0, FW_POL_METHOD_CATCH, 5.0, "flying start harsh");
    flying_start("paper", 300.0, FW_POL_METHOD_EMF, 2.5, "flying start slow");
    /* the rotor where the commissioning turns it for rs: the q axis on a phase axis */
    held_rotor_steps("harsh", 30.0, "held rotor harsh");
    held_rotor_steps("harsh", 147.1, "held rotor harsh 2");
    held_rotor_steps("harsh", 327.1, "held rotor harsh 3");
    held_rotor_steps("paper", 300.0, "held rotor paper");
    TEST_DONE();
}
