/* sil_bench: the closed loop in one process, as a program. Prints one JSON object.
 *
 * Starts the drive at standstill (enable from period 0, speed reference 0), steps the speed
 * reference to --speed at --step-period, and runs until --periods ISR calls in the RUN state
 * were made (the last --periods calls are all in RUN unless the drive faulted). Reports the
 * closed loop's simulated seconds per wall second, and with --time-isr the wall time of every
 * fw_core_isr() call in RUN (10 kHz path and the calls that ran the 1 kHz tasks separately)
 * and of plant_step(). Exit 0, 1 when the drive faulted or the loop broke, 2 on bad usage.
 */
#define _POSIX_C_SOURCE 199309L
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fw_core.h"
#include "plant_core.h"
#include "sil_bench.h"

#define MAX_SETS 64

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double quantile(double *v, long n, double q)
{
    if (n <= 0) {
        return 0.0;
    }
    qsort(v, (size_t)n, sizeof(double), cmp_double);
    return v[(long)(q * (double)(n - 1) + 0.5)];
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void usage(FILE *out)
{
    fprintf(out,
            "usage: sil_bench --profile FILE [options]\n"
            "The control core and the plant in one process (bench/): start-up, a speed step,\n"
            "then --periods periods in RUN. One JSON object on stdout.\n"
            "  --profile FILE        plant profile (plant_rt/profiles/*.toml)\n"
            "  --set section.key=v   plant override (repeatable)\n"
            "  --fw-set name=v       firmware parameter after the hardware ones (repeatable)\n"
            "  --speed RPM           speed reference of the step (default 1000)\n"
            "  --step-period N       period of the step (default 3000)\n"
            "  --load NM             load torque from the step on (default 0)\n"
            "  --periods N           RUN-state periods (default 20000)\n"
            "  --time-isr            time every fw_core_isr() and plant_step() call\n"
            "  --plant-trace FILE  --fw-trace FILE   trace files as plant_rt / fw_host write\n");
}

int main(int argc, char **argv)
{
    static const struct option longopts[] = {
        {"profile", required_argument, 0, 'p'}, {"set", required_argument, 0, 's'},
        {"fw-set", required_argument, 0, 'f'},  {"speed", required_argument, 0, 'v'},
        {"step-period", required_argument, 0, 'k'}, {"load", required_argument, 0, 'l'},
        {"periods", required_argument, 0, 'n'}, {"time-isr", no_argument, 0, 't'},
        {"plant-trace", required_argument, 0, 'P'}, {"fw-trace", required_argument, 0, 'F'},
        {"help", no_argument, 0, 'h'},          {0, 0, 0, 0}};
    const char *psets[MAX_SETS], *fsets[MAX_SETS];
    sil_bench_config_t cfg;
    double speed = 1000.0, load = 0.0, t0, wall;
    long n_run = 20000, step_at = 3000, it, max_total, n_fast = 0, n_slow = 0, in_run = 0;
    double *fast, *slow;
    int c, broke = 0, timing = 0;
    char err[1024];
    sil_bench_t *b;
    sil_bench_stats_t st;
    fw_status_t fs;
    const plant_truth_t *tr;

    memset(&cfg, 0, sizeof(cfg));
    cfg.plant_sets = psets;
    cfg.fw_sets = fsets;
    cfg.fw_from_plant = 1;
    while ((c = getopt_long(argc, argv, "h", longopts, NULL)) != -1) {
        switch (c) {
        case 'p': cfg.profile_path = optarg; break;
        case 's':
        case 'f':
            if ((c == 's' ? cfg.n_plant_sets : cfg.n_fw_sets) >= MAX_SETS) {
                fprintf(stderr, "sil_bench: more than %d --set/--fw-set\n", MAX_SETS);
                return 2;
            }
            if (c == 's') {
                psets[cfg.n_plant_sets++] = optarg;
            } else {
                fsets[cfg.n_fw_sets++] = optarg;
            }
            break;
        case 'v': speed = atof(optarg); break;
        case 'k': step_at = atol(optarg); break;
        case 'l': load = atof(optarg); break;
        case 'n': n_run = atol(optarg); break;
        case 't': timing = 1; break;
        case 'P': cfg.plant_trace = optarg; break;
        case 'F': cfg.fw_trace = optarg; break;
        case 'h': usage(stdout); return 0;
        default: usage(stderr); return 2;
        }
    }
    if (cfg.profile_path == NULL || n_run < 10 || optind < argc) {
        usage(stderr);
        return 2;
    }
    b = sil_bench_open(&cfg, err, sizeof(err));
    if (b == NULL) {
        fprintf(stderr, "sil_bench: %s\n", err);
        return 2;
    }
    max_total = n_run + step_at + 40000;
    fast = malloc(sizeof(double) * (size_t)(n_run + 1));
    slow = malloc(sizeof(double) * (size_t)(n_run / 5 + 10));
    if (fast == NULL || slow == NULL) {
        return 1;
    }
    sil_bench_time_isr(b, timing);
    t0 = now_s();
    for (it = 0; it < max_total && in_run < n_run; it++) {
        fw_status_t before;
        if (it % 1000 == 0 || it == step_at) { /* as the rig's grants: at most 100 ms apart */
            const int stepped = it >= step_at;
            sil_bench_drive_cmd(b, 1, 0, FW_CTRL_SPEED, FW_FWMODE_REALTIME, stepped ? speed : 0.0,
                                0.0);
            sil_bench_load_cmd(b, HIL_BENCH_LOAD_CMD_MODE_TORQUE_CHOICE, stepped ? load : 0.0, 0.0, 0.0);
        }
        fw_core_status(sil_bench_core(b), &before);
        if (sil_bench_step(b) != 0) {
            broke = 1;
            break;
        }
        if (before.state == FW_STATE_RUN) {
            in_run++;
            if (timing) {
                /* the 1 kHz tasks run on every FW_SPEED_DIVIDER-th ISR */
                if ((sil_bench_core(b))->isr_count % FW_SPEED_DIVIDER == 0u) {
                    slow[n_slow++] = sil_bench_last_isr_ns(b);
                } else {
                    fast[n_fast++] = sil_bench_last_isr_ns(b);
                }
            }
        }
    }
    wall = now_s() - t0;
    sil_bench_get_stats(b, &st);
    fw_core_status(sil_bench_core(b), &fs);
    tr = sil_bench_truth(b);
    printf("{\"program\": \"sil_bench\", \"profile\": \"%s\", \"periods\": %llu, "
           "\"periods_in_run\": %ld, \"wall_s\": %.4f, \"sim_s\": %.4f, "
           "\"sim_s_per_wall_s\": %.3f, \"wall_us_per_period\": %.3f",
           cfg.profile_path, (unsigned long long)st.periods, in_run, wall,
           (double)st.periods * PLANT_TS_S, (double)st.periods * PLANT_TS_S / wall,
           wall * 1e6 / (double)(st.periods ? st.periods : 1));
    if (timing) {
        const double mf = quantile(fast, n_fast, 0.5), pf = quantile(fast, n_fast, 0.99);
        const double ms = quantile(slow, n_slow, 0.5), pss = quantile(slow, n_slow, 0.99);
        printf(", \"plant_us_per_period\": %.3f, \"isr_us_per_period\": %.3f, "
               "\"isr_10khz_ns\": {\"median\": %.0f, \"p99\": %.0f, \"n\": %ld}, "
               "\"isr_1khz_ns\": {\"median\": %.0f, \"p99\": %.0f, \"n\": %ld}",
               st.plant_ns_total * 1e-3 / (double)st.periods,
               st.isr_ns_total * 1e-3 / (double)st.periods, mf, pf, n_fast, ms, pss, n_slow);
    }
    printf(", \"final_state\": %d, \"fault_code\": %u, \"speed_hat_rpm\": %.1f, "
           "\"speed_true_rpm\": %.1f, \"core_bytes\": %lu, \"loop_broke\": %s}\n",
           (int)fs.state, (unsigned)fs.fault_code, (double)fs.speed_hat_rpm,
           tr->omega_m * 60.0 / 6.283185307179586, (unsigned long)sizeof(fw_core_t),
           broke ? "true" : "false");
    free(fast);
    free(slow);
    if (sil_bench_close(b) != 0) {
        fprintf(stderr, "sil_bench: trace write error\n");
        return 1;
    }
    return broke || fs.state != FW_STATE_RUN ? 1 : 0;
}
