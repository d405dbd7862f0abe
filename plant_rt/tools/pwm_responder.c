/* pwm_responder: a minimal stand-in for the firmware's PWM/ADC loop, for benchmarks and
 * program-level tests of plant_rt.
 *
 * Answers every complete VIO_ADC(k) with VIO_PWM(k+1) (docs/interfaces.md). The command
 * depends on the period index only, so a repeated ADC(k) gets the same PWM(k+1).
 *   --pattern fixed   gates on, a small constant voltage vector along phase a (about 1.4 A
 *                     of d current at standstill in `paper`), six SOCs (default)
 *   --pattern cycle6  PWM(j) puts the upper gates of pattern j mod 6 on for the first half
 *                     of the period (from tick 0) and the other legs low:
 *                     {a}, {a,b}, {b}, {b,c}, {c}, {c,a}; one SOC at tick 0. The phase
 *                     voltages at each period start reveal which command was loaded.
 * --late-every N --late-us U: PWM(j) with j a multiple of N is sent U µs after its ADC
 * arrived, to provoke late updates in real-time mode; the responder keeps answering the
 * other ADC frames in time meanwhile (a late frame can overtake nothing but its own period).
 *
 * Prints one JSON object on stdout at exit: answers, repeated ADCs, periods per second
 * between the first and the last ADC received.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "hil_vio.h"
#include "hil_wire.h"
#include "hilnode.h" /* clock, stop signals, ready file; the bus */

#define MAX_DEFERRED 64

static volatile sig_atomic_t g_stop = 0;

static uint32_t get_u32(const uint8_t *d)
{
    return (uint32_t)d[0] | ((uint32_t)d[1] << 8) | ((uint32_t)d[2] << 16) | ((uint32_t)d[3] << 24);
}

static void build_pwm(uint32_t period, int cycle6, struct hil_vio_vio_pwm_t *m)
{
    memset(m, 0, sizeof(*m));
    m->period = period;
    m->gate_enable = 1;
    if (cycle6) {
        /* bit x set: phase x high during [0, TBPRD) */
        static const unsigned HIGH[6] = {1u, 3u, 2u, 6u, 4u, 5u};
        const unsigned high = HIGH[period % 6u];
        uint16_t *up[3], *dn[3];
        int x;
        up[0] = &m->cmp_a_up, dn[0] = &m->cmp_a_dn;
        up[1] = &m->cmp_b_up, dn[1] = &m->cmp_b_dn;
        up[2] = &m->cmp_c_up, dn[2] = &m->cmp_c_dn;
        for (x = 0; x < 3; ++x) {
            *up[x] = (high >> x) & 1u ? 0 : HIL_TBPRD; /* TBPRD/TBPRD: an empty on-interval */
            *dn[x] = HIL_TBPRD;
        }
        m->n_soc = 1;
        m->soc_0 = 0;
        return;
    }
    /* duty 0.51 on a, 0.49 on b and c: cmp = TBPRD * (1 - duty) */
    m->cmp_a_up = m->cmp_a_dn = 2450;
    m->cmp_b_up = m->cmp_b_dn = 2550;
    m->cmp_c_up = m->cmp_c_dn = 2550;
    m->n_soc = 6;
    m->soc_0 = 0;
    m->soc_1 = 1000;
    m->soc_2 = 2500;
    m->soc_3 = 5000;
    m->soc_4 = 7500;
    m->soc_5 = 9000;
}

static void usage(FILE *out)
{
    fputs("usage: pwm_responder [--bus T] [--channel C] [--ready-file F] [--count N]\n"
          "                     [--pattern fixed|cycle6] [--late-every N --late-us U]\n"
          "                     [--idle-exit-ms MS] [--rt-priority N]\n"
          "Answers every VIO_ADC(k) with VIO_PWM(k+1); prints one JSON object at exit.\n"
          "  --count N         exit after answering the ADC of period N-1 (0: until SIGTERM)\n"
          "  --idle-exit-ms MS exit when no ADC came for MS ms after the first one (0: never)\n"
          "  --rt-priority N   SCHED_FIFO priority N and mlockall (0, default: unchanged)\n",
          out);
}

int main(int argc, char **argv)
{
    const char *transport = getenv("HIL_BUS") ? getenv("HIL_BUS") : "unixcan";
    const char *channel = getenv("HIL_CHANNEL") ? getenv("HIL_CHANNEL") : "vcan0";
    const char *ready_file = NULL;
    long long count = 0, late_every = 0, late_us = 0, idle_exit_ms = 0, rt_priority = 0;
    const char *rt_note = "SCHED_OTHER";
    int cycle6 = 0, k;
    char err[256];
    hilbus_t *bus;
    struct can_filter filt[3];
    uint64_t answered = 0, repeats = 0, late_answers = 0, send_errors = 0;
    int64_t first_ns = 0, last_ns = 0;
    uint32_t first_period = 0, last_period = 0;
    int have_last = 0;
    hilbus_stats_t st;
    struct canfd_frame deferred[MAX_DEFERRED];
    int64_t deferred_at[MAX_DEFERRED];
    int n_deferred = 0;

    for (k = 1; k < argc; k += 2) { /* every option takes one value (--help aside) */
        const char *a = argv[k];
        const char *v = k + 1 < argc ? argv[k + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            return 0;
        }
        if (!v) {
            usage(stderr);
            return 2;
        }
        if (strcmp(a, "--bus") == 0) {
            transport = v;
        } else if (strcmp(a, "--channel") == 0) {
            channel = v;
        } else if (strcmp(a, "--ready-file") == 0) {
            ready_file = v;
        } else if (strcmp(a, "--pattern") == 0) {
            if (strcmp(v, "cycle6") == 0) {
                cycle6 = 1;
            } else if (strcmp(v, "fixed") != 0) {
                fprintf(stderr, "pwm_responder: --pattern %s: fixed or cycle6\n", v);
                return 2;
            }
        } else if (strcmp(a, "--count") == 0 || strcmp(a, "--late-every") == 0 ||
                   strcmp(a, "--late-us") == 0 || strcmp(a, "--idle-exit-ms") == 0 ||
                   strcmp(a, "--rt-priority") == 0) {
            char *end;
            const long long n = strtoll(v, &end, 10);
            if (end == v || *end || n < 0) {
                fprintf(stderr, "pwm_responder: %s %s: not a non-negative integer\n", a, v);
                return 2;
            }
            if (strcmp(a, "--count") == 0) {
                count = n;
            } else if (strcmp(a, "--late-every") == 0) {
                late_every = n;
            } else if (strcmp(a, "--late-us") == 0) {
                late_us = n;
            } else if (strcmp(a, "--rt-priority") == 0) {
                rt_priority = n > 99 ? 99 : n;
            } else {
                idle_exit_ms = n;
            }
        } else {
            usage(stderr);
            return 2;
        }
    }

    hil_node_signals(&g_stop, 0);

    if (rt_priority > 0) {
        struct sched_param sp;
        memset(&sp, 0, sizeof(sp));
        sp.sched_priority = (int)rt_priority;
        if (sched_setscheduler(0, SCHED_FIFO, &sp) == 0) {
            rt_note = mlockall(MCL_CURRENT | MCL_FUTURE) == 0 ? "SCHED_FIFO+mlockall" : "SCHED_FIFO";
        } else {
            rt_note = "SCHED_OTHER (SCHED_FIFO not permitted)";
        }
    }
    bus = hilbus_open(transport, channel, err, sizeof(err));
    if (!bus) {
        fprintf(stderr, "pwm_responder: cannot open bus %s/%s: %s\n", transport, channel, err);
        return 1;
    }
    filt[0].can_id = HIL_VIO_VIO_ADC_0_FRAME_ID;
    filt[1].can_id = HIL_VIO_VIO_ADC_1_FRAME_ID;
    filt[2].can_id = HIL_VIO_VIO_ADC_2_FRAME_ID;
    filt[0].can_mask = filt[1].can_mask = filt[2].can_mask = CAN_SFF_MASK | CAN_EFF_FLAG;
    if (hilbus_set_filters(bus, filt, 3) != 0) {
        fprintf(stderr, "pwm_responder: cannot set filters\n");
        hilbus_close(bus);
        return 1;
    }
    if (ready_file && hil_write_ready_file(ready_file) != 0) {
        fprintf(stderr, "pwm_responder: cannot write %s: %s\n", ready_file, strerror(errno));
        hilbus_close(bus);
        return 1;
    }

    while (!g_stop) {
        struct canfd_frame f;
        int fd, r, frame_index;
        uint32_t period, n_soc;
        int64_t t, wait_us = 50000;
        /* deferred (late) answers that are due */
        t = hil_now_ns();
        for (k = 0; k < n_deferred;) {
            if (deferred_at[k] <= t) {
                if (hilbus_send(bus, &deferred[k], 1) != 0) {
                    send_errors++;
                }
                deferred[k] = deferred[n_deferred - 1];
                deferred_at[k] = deferred_at[n_deferred - 1];
                n_deferred--;
            } else {
                if ((deferred_at[k] - t) / 1000 < wait_us) {
                    wait_us = (deferred_at[k] - t) / 1000;
                }
                ++k;
            }
        }
        r = hilbus_recv(bus, &f, &fd, wait_us);
        t = hil_now_ns();
        if (r < 0 && errno != EINTR) {
            fprintf(stderr, "pwm_responder: receive error: %s\n", strerror(errno));
            break;
        }
        if (r != 1) {
            if (idle_exit_ms && have_last && t - last_ns > idle_exit_ms * 1000000LL) {
                break;
            }
            continue;
        }
        if (!fd || f.len != 64) {
            continue;
        }
        frame_index = (int)((f.can_id & CAN_SFF_MASK) - HIL_VIO_VIO_ADC_0_FRAME_ID);
        period = get_u32(f.data);
        n_soc = f.data[4];
        /* the frame that completes the period: ADC_0 for 1..7 SOCs, ADC_1 for 8..14, ADC_2 */
        if (n_soc == 0 || (n_soc + 6u) / 7u != (unsigned)frame_index + 1u) {
            continue;
        }
        if (!have_last) {
            first_ns = t;
            first_period = period;
        } else if (period == last_period) {
            repeats++;
        }
        last_ns = t;
        last_period = period;
        have_last = 1;
        {
            struct hil_vio_vio_pwm_t m;
            struct canfd_frame out;
            const uint32_t next = period + 1u;
            build_pwm(next, cycle6, &m);
            memset(&out, 0, sizeof(out));
            out.can_id = HIL_VIO_VIO_PWM_FRAME_ID;
            out.len = HIL_VIO_VIO_PWM_LENGTH;
            hil_vio_vio_pwm_pack(out.data, &m, sizeof(out.data));
            if (late_every > 0 && late_us > 0 && next % (uint64_t)late_every == 0 &&
                n_deferred < MAX_DEFERRED) {
                deferred[n_deferred] = out;
                deferred_at[n_deferred++] = t + late_us * 1000LL;
                late_answers++;
            } else if (hilbus_send(bus, &out, 1) != 0) {
                send_errors++;
            }
            answered++;
        }
        if (count > 0 && (long long)period + 1 >= count) {
            break;
        }
    }
    hilbus_get_stats(bus, &st);
    {
        const double elapsed = have_last ? (double)(last_ns - first_ns) * 1e-9 : 0.0;
        const double span = have_last ? (double)(last_period - first_period) : 0.0;
        printf("{\"program\": \"pwm_responder\", \"transport\": \"%s\", \"answered\": %llu, "
               "\"repeats\": %llu, \"late_answers\": %llu, \"first_period\": %u, "
               "\"last_period\": %u, \"elapsed_s\": %.6f, \"periods_per_s\": %.1f, "
               "\"send_errors\": %llu, \"tx_drops\": %llu, \"rt\": \"%s\"}\n",
               hilbus_transport(bus), (unsigned long long)answered, (unsigned long long)repeats,
               (unsigned long long)late_answers, (unsigned)first_period, (unsigned)last_period,
               elapsed, elapsed > 0.0 ? span / elapsed : 0.0, (unsigned long long)send_errors,
               (unsigned long long)st.tx_drops, rt_note);
    }
    fflush(stdout);
    hilbus_close(bus);
    return 0;
}
