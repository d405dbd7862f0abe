/* plant_bench: compute cost of one simulated PWM period per fidelity profile.
 *
 * Runs each profile in speed hold at 1500 r/min with an open-loop SVPWM pattern that
 * holds about 2 A on the q axis (dead time, zero crossings and ringing included), six
 * SOCs per period, and prints one JSON object: median and 99th percentile of the wall time
 * per period in microseconds, and the work per period (right-hand-side evaluations, Newton
 * iterations, located conduction events).
 * Usage: plant_bench [PROFILES_DIR] [PERIODS] [PROFILE...]   (default: ideal paper harsh)
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "plant_core.h"

static double now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec * 1e-3;
}

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Min-max (SVPWM-equivalent) compare values for a voltage vector (v_alpha, v_beta). */
static void svpwm(double va, double vb, double vdc, plant_pwm_cmd_t *cmd)
{
    const double ph[3] = {va, -0.5 * va + 0.5 * sqrt(3.0) * vb, -0.5 * va - 0.5 * sqrt(3.0) * vb};
    double mx = ph[0], mn = ph[0];
    int k;
    for (k = 1; k < 3; ++k) {
        mx = ph[k] > mx ? ph[k] : mx;
        mn = ph[k] < mn ? ph[k] : mn;
    }
    for (k = 0; k < 3; ++k) {
        double duty = 0.5 + (ph[k] - 0.5 * (mx + mn)) / vdc;
        long c;
        duty = duty < 0.0 ? 0.0 : (duty > 1.0 ? 1.0 : duty);
        c = lround(PLANT_TBPRD * (1.0 - duty));
        cmd->cmp_up[k] = (uint16_t)c;
        cmd->cmp_dn[k] = (uint16_t)c;
    }
}

int main(int argc, char **argv)
{
    const char *dir = argc > 1 ? argv[1] : PLANT_SOURCE_PROFILES_DIR;
    const int periods = argc > 2 ? atoi(argv[2]) : 20000;
    static const char *const all[3] = {"ideal", "paper", "harsh"};
    const char *const *names = argc > 3 ? (const char *const *)(argv + 3) : all;
    const int n_names = argc > 3 ? argc - 3 : 3;
    double *cost = (double *)malloc(sizeof(double) * (size_t)(periods > 0 ? periods : 1));
    int p;

    if (!cost || periods <= 0) {
        fprintf(stderr, "plant_bench: bad period count\n");
        return 2;
    }
    printf("{");
    for (p = 0; p < n_names; ++p) {
        char path[4096], err[512];
        const char *sets[2] = {"load.mode=1", "load.speed_rpm=1500"};
        plant_t *plant;
        plant_pwm_cmd_t cmd;
        plant_samples_t smp;
        plant_truth_t truth;
        plant_stats_t st;
        const double we = 1500.0 / 60.0 * 2.0 * 3.14159265358979 * 2.0;
        int k;
        snprintf(path, sizeof(path), "%s/%s.toml", dir, names[p]);
        plant = plant_open(path, sets, 2, err, sizeof(err));
        if (!plant) {
            fprintf(stderr, "plant_bench: %s\n", err);
            return 2;
        }
        memset(&cmd, 0, sizeof(cmd));
        cmd.gate_enable = 1;
        cmd.n_soc = 6;
        cmd.soc[0] = 500;
        cmd.soc[1] = 1500;
        cmd.soc[2] = 3000;
        cmd.soc[3] = 5000;
        cmd.soc[4] = 7000;
        cmd.soc[5] = 9000;
        for (k = -1000; k < periods; ++k) {
            double t0;
            const double th = fmod(we * (k + 1000) * PLANT_TS_S, 2.0 * 3.14159265358979);
            /* steady state for iq = 2 A, id = 0 (nominal parameters) */
            const double vd = -we * 0.032 * 2.0, vq = 1.93 * 2.0 + we * 0.216;
            svpwm(vd * cos(th) - vq * sin(th), vd * sin(th) + vq * cos(th), 200.0, &cmd);
            cmd.period = plant_next_period(plant);
            t0 = now_us();
            plant_step(plant, &cmd, &smp, &truth);
            if (k >= 0) {
                cost[k] = now_us() - t0;
            }
        }
        plant_get_stats(plant, &st);
        qsort(cost, (size_t)periods, sizeof(double), cmp_double);
        printf("%s\"%s\": {\"median_us\": %.3f, \"p99_us\": %.3f, \"rhs_per_period\": %.1f, "
               "\"newton_per_rhs\": %.3f, \"events_per_period\": %.3f, \"final_iq_a\": %.3f}",
               p ? ", " : "", names[p], cost[periods / 2], cost[(int)(0.99 * (periods - 1))],
               (double)st.rhs_evals / (double)st.periods,
               (double)st.newton_iterations / (double)(st.rhs_evals ? st.rhs_evals : 1),
               (double)st.conduction_events / (double)st.periods, truth.iq);
        plant_free(plant);
    }
    printf("}\n");
    free(cost);
    return 0;
}
