/* fw_isr_bench - host benchmark of the control core's ISR.
 *
 * Runs the core against tools/mini_plant.h (start-up, then a speed step to 1000 r/min) and
 * times every fw_core_isr() call in the RUN state with CLOCK_MONOTONIC. Calls that ran the
 * 1 kHz tasks (speed loop, MTPA/FW) are reported separately. Prints one JSON object; asserts
 * nothing. Usage: fw_isr_bench [periods_in_run (default 20000)]
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "fw_core.h"
#include "fw_params_gen.h"
#include "mini_plant.h"

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a;
    double y = *(const double *)b;
    return (x > y) - (x < y);
}

static double pct(double *v, long n, double q)
{
    long i;
    if (n <= 0) {
        return 0.0;
    }
    qsort(v, (size_t)n, sizeof(double), cmp_double);
    i = (long)(q * (double)(n - 1) + 0.5);
    return v[i];
}

static double now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

static fw_core_t core;

int main(int argc, char **argv)
{
    long n_run = (argc > 1) ? atol(argv[1]) : 20000;
    long max_total = n_run + 20000;
    double *fast = malloc(sizeof(double) * (size_t)(n_run + 1));
    double *slow = malloc(sizeof(double) * (size_t)(n_run / 5 + 10));
    long n_fast = 0;
    long n_slow = 0;
    long it;
    mini_plant_t m;
    fw_pwm_t pwm;
    fw_adc_t adc;
    fw_cmd_t cmd = {1, 0, FW_CTRL_SPEED, FW_FWMODE_REALTIME, 0.0f, 0.0f};
    fw_status_t st;
    double med_f, p99_f, med_s, p99_s;

    if (fast == NULL || slow == NULL || n_run < 10) {
        return 2;
    }
    mp_default(&m);
    mp_set_angle(&m, 1.0);
    m.noise_a = 0.001;
    fw_core_init(&core);
    pwm.period = 0;
    pwm.gate_enable = 0;
    pwm.n_soc = 0;
    for (it = 0; it < 3; it++) {
        pwm.cmp_up[it] = FW_TBPRD;
        pwm.cmp_dn[it] = FW_TBPRD;
    }
    for (it = 0; it < max_total && n_fast < n_run; it++) {
        double t0;
        double t1;
        int16_t was_run;
        mp_period(&m, &pwm, &adc);
        if (it % 10 == 0) {
            cmd.speed_ref_rpm = (it > 3000) ? 1000.0f : 0.0f;
            (void)fw_core_command(&core, &cmd);
        }
        fw_core_status(&core, &st);
        was_run = (int16_t)(st.state == FW_STATE_RUN);
        t0 = now_ns();
        fw_core_isr(&core, &adc, &pwm);
        t1 = now_ns();
        if (was_run) {
            if (core.isr_count % FW_SPEED_DIVIDER == 0u) {
                slow[n_slow++] = t1 - t0;
            } else {
                fast[n_fast++] = t1 - t0;
            }
        }
    }
    fw_core_status(&core, &st);
    med_f = pct(fast, n_fast, 0.5);
    p99_f = pct(fast, n_fast, 0.99);
    med_s = pct(slow, n_slow, 0.5);
    p99_s = pct(slow, n_slow, 0.99);
    printf("{\"isr_10khz_ns\": {\"median\": %.0f, \"p99\": %.0f, \"n\": %ld}, "
           "\"isr_1khz_ns\": {\"median\": %.0f, \"p99\": %.0f, \"n\": %ld}, "
           "\"final_state\": %d, \"fault_code\": %u, \"speed_hat_rpm\": %.1f, "
           "\"speed_true_rpm\": %.1f, \"core_bytes\": %lu}\n",
           med_f, p99_f, n_fast, med_s, p99_s, n_slow, (int)st.state, (unsigned)st.fault_code,
           (double)st.speed_hat_rpm, m.omega_m * 60.0 / 6.283185307179586,
           (unsigned long)sizeof(fw_core_t));
    free(fast);
    free(slow);
    return 0;
}
