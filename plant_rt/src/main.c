/* plant_rt: the bench emulator on the bus (docs/design.md section 4, docs/interfaces.md).
 *
 * Receives VIO_PWM, LOAD_CMD, FAULT_CMD, BENCH_STEP and VIO_SYNC_ACK; sends VIO_ADC_x per
 * period (under frame faults through plant_link.h, then with the VIO_SYNC barrier in
 * lockstep), BENCH_TRUTH and BENCH_TRUTH_MAG (decimated on the bus, every period in the
 * trace), BENCH_COUNTERS, BENCH_REJECTS and BENCH_PROGRESS every 100 ms. Lockstep (default)
 * or real-time pacing.
 *
 * Period 0 runs with the start-up command: gates disabled, one SOC at tick 0, so that
 * ADC(0) reaches the firmware, which answers with PWM(1).
 *
 * Counters go to stderr as one JSON line at exit (plant_rt/README.md lists them).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "hil_bench.h"
#include "hil_vio.h"
#include "hil_wire.h"
#include "hilnode.h"
#include "plant_core.h"
#include "plant_link.h"
#include "plant_vio.h"

#define HOUSEKEEPING_NS (100LL * 1000000LL) /* counters, progress: every 100 ms */
#define RESEND_NS (100LL * 1000000LL)       /* lockstep: ADC(k) again after 100 ms */
#define WAKE_HIST_BINS 10000 /* wake-up lateness histogram: 1 us bins, 0 .. 10 ms */

static volatile sig_atomic_t g_stop = 0;

typedef struct options {
    hil_node_opts_t node; /* --bus, --channel, pacing, --trace, --ready-file, ... (hilnode.h) */
    const char *profile;
    const char *profiles_dir;
    int trace_vio;
    uint32_t run_until;
    uint32_t truth_every;
    uint32_t rt_spin_us;
} options_t;

typedef struct counters {
    uint64_t periods, late_cmds, overruns, adc_clipped, resends;
    uint64_t rejects[PLANT_REJ_COUNT];
    uint64_t max_late_us;
    uint64_t load_cmds, steps, sync_acks;
    uint64_t non_data_frames; /* extended, remote or error frames: not this protocol's */
    const char *rt_note;
    /* real time: wake-up lateness after clock_nanosleep, and periods slipped on overruns */
    uint64_t wake_n, wake_sum_ns, wake_max_ns, slipped_periods;
    uint32_t wake_hist[WAKE_HIST_BINS + 1]; /* last bin: 10 ms and more */
} counters_t;

typedef struct app {
    options_t opt;
    plant_t *plant;
    const plant_config_t *cfg;
    hilbus_t *bus;
    hiltrace_t *trace;
    counters_t cnt;
    uint32_t run_until;
    uint8_t step_seq;
    hil_log_limit_t log_limit; /* rejection lines on stderr */
    plant_link_t link;         /* frame faults and the exchange of each period (plant_link.h) */
    plant_pwm_cmd_t current;   /* the command the last period ran on */
    uint8_t sync_seq;
    int waiting_sync;          /* lockstep: VIO_SYNC sent, its VIO_SYNC_ACK not yet here */
    /* what went out for the last period (the lockstep re-send repeats it) */
    struct canfd_frame adc_frames[PLANT_VIO_ADC_FRAMES_MAX + PLANT_LINK_HELD_MAX];
    int n_adc_frames;
    int bus_failed; /* a node that loses no frame stayed full past the bus's stall limit */
} app_t;

/* ------------------------------------------------------------------ logging */

static void log_reject(app_t *a, const char *fmt, ...)
{
    va_list ap;
    if (!hil_log_limit_allow(&a->log_limit, hil_now_ns())) {
        return;
    }
    fputs("plant_rt: rejected: ", stderr);
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
}

static void reject(app_t *a, int reason, uint32_t can_id, uint32_t period)
{
    a->cnt.rejects[reason]++;
    log_reject(a, "%s (id 0x%03X, period %u, expected %u)", plant_reject_name(reason),
               (unsigned)can_id, (unsigned)period, (unsigned)plant_next_period(a->plant));
}

/* ------------------------------------------------------------------ sending */

static void send_frame(app_t *a, uint32_t id, const uint8_t *data, uint8_t len, int to_trace)
{
    struct canfd_frame f;
    memset(&f, 0, sizeof(f));
    f.can_id = id;
    f.len = len;
    memcpy(f.data, data, len);
    if (hilbus_send(a->bus, &f, 1) != 0 && errno == ETIMEDOUT && !a->bus_failed) {
        /* a node of the run (lossless) took no frame within the stall limit: the lockstep
         * cannot go on; other failures are counted by hilbus (tx_errors) and it goes on */
        fprintf(stderr, "plant_rt: %s\n", hilbus_last_error(a->bus));
        a->bus_failed = 1;
        g_stop = 1;
    }
    if (to_trace && a->trace) {
        hiltrace_write(a->trace, &f);
    }
}

static void trace_frame(app_t *a, uint32_t id, const uint8_t *data, uint8_t len)
{
    struct canfd_frame f;
    if (!a->trace || len > CANFD_MAX_DLEN) {
        return; /* (hilbus hands on no longer frame; a record holds 64 data bytes) */
    }
    memset(&f, 0, sizeof(f));
    f.can_id = id;
    f.len = len;
    memcpy(f.data, data, len);
    hiltrace_write(a->trace, &f);
}

/* The one comparison rule of grants: periods are uint32 and wrap, so "k is before
 * run_until" is a signed difference. A grant is open while the next period is before it. */
static int grant_open(const app_t *a, uint32_t k)
{
    return (int32_t)(a->run_until - k) > 0;
}

static uint64_t total_rejects(const counters_t *c)
{
    uint64_t n = 0;
    int k;
    for (k = 1; k < PLANT_REJ_COUNT; ++k) {
        n += c->rejects[k];
    }
    return n;
}

static uint32_t sat32(uint64_t v)
{
    return v > UINT32_MAX ? UINT32_MAX : (uint32_t)v;
}

static void send_housekeeping(app_t *a, int state)
{
    uint8_t buf[64];
    hilbus_stats_t bs;
    const uint32_t period = plant_next_period(a->plant);
    hilbus_get_stats(a->bus, &bs);
    {
        struct hil_bench_bench_counters_t m;
        memset(&m, 0, sizeof(m));
        m.period = period;
        m.late_cmds = sat32(a->cnt.late_cmds + a->link.st.held);
        m.overruns = sat32(a->cnt.overruns);
        m.rejected = sat32(total_rejects(&a->cnt));
        m.adc_clipped = sat32(a->cnt.adc_clipped);
        m.tx_drops = sat32(bs.tx_drops);
        m.max_late_us = sat32(a->cnt.max_late_us);
        hil_bench_bench_counters_pack(buf, &m, sizeof(buf));
        send_frame(a, HIL_BENCH_BENCH_COUNTERS_FRAME_ID, buf, HIL_BENCH_BENCH_COUNTERS_LENGTH, 0);
    }
    {
        struct hil_bench_bench_rejects_t m;
        memset(&m, 0, sizeof(m));
        m.period = period;
        m.unknown_id = sat32(a->cnt.rejects[PLANT_REJ_UNKNOWN_ID]);
        m.bad_length = sat32(a->cnt.rejects[PLANT_REJ_BAD_LENGTH]);
        m.out_of_range = sat32(a->cnt.rejects[PLANT_REJ_OUT_OF_RANGE]);
        m.stale_period = sat32(a->cnt.rejects[PLANT_REJ_STALE_PERIOD]);
        m.future_period = sat32(a->cnt.rejects[PLANT_REJ_FUTURE_PERIOD]);
        m.too_many_soc = sat32(a->cnt.rejects[PLANT_REJ_TOO_MANY_SOC]);
        m.soc_outside = sat32(a->cnt.rejects[PLANT_REJ_SOC_OUTSIDE]);
        m.malformed = sat32(a->cnt.rejects[PLANT_REJ_MALFORMED]);
        hil_bench_bench_rejects_pack(buf, &m, sizeof(buf));
        send_frame(a, HIL_BENCH_BENCH_REJECTS_FRAME_ID, buf, HIL_BENCH_BENCH_REJECTS_LENGTH, 0);
    }
    {
        struct hil_bench_bench_progress_t m;
        memset(&m, 0, sizeof(m));
        m.period = period;
        m.seq = a->step_seq;
        m.state = (uint8_t)state;
        hil_bench_bench_progress_pack(buf, &m, sizeof(buf));
        send_frame(a, HIL_BENCH_BENCH_PROGRESS_FRAME_ID, buf, HIL_BENCH_BENCH_PROGRESS_LENGTH, 0);
    }
}

static void send_progress(app_t *a, int state)
{
    uint8_t buf[8];
    struct hil_bench_bench_progress_t m;
    memset(&m, 0, sizeof(m));
    m.period = plant_next_period(a->plant);
    m.seq = a->step_seq;
    m.state = (uint8_t)state;
    hil_bench_bench_progress_pack(buf, &m, sizeof(buf));
    send_frame(a, HIL_BENCH_BENCH_PROGRESS_FRAME_ID, buf, HIL_BENCH_BENCH_PROGRESS_LENGTH, 0);
}

static void send_sync(app_t *a)
{
    uint8_t buf[8];
    struct hil_vio_vio_sync_t m;
    memset(&m, 0, sizeof(m));
    m.period = a->link.expect - 1u;
    m.seq = a->sync_seq;
    hil_vio_vio_sync_pack(buf, &m, sizeof(buf));
    send_frame(a, HIL_VIO_VIO_SYNC_FRAME_ID, buf, HIL_VIO_VIO_SYNC_LENGTH, 0);
}

/* The ADC frames of the period as they leave under the frame faults (plant_link.h); in
 * lockstep a faulted exchange ends with the VIO_SYNC barrier. */
static void send_adc(app_t *a, const plant_samples_t *s)
{
    struct canfd_frame raw[PLANT_VIO_ADC_FRAMES_MAX];
    const int n = plant_pack_adc(s, raw);
    int k;
    a->n_adc_frames = plant_link_adc_out(&a->link, s->period, raw, n, a->adc_frames,
                                         (int)(sizeof(a->adc_frames) / sizeof(a->adc_frames[0])));
    for (k = 0; k < a->n_adc_frames; ++k) {
        send_frame(a, a->adc_frames[k].can_id, a->adc_frames[k].data, 64, 0);
    }
    if (a->opt.trace_vio) {
        for (k = 0; k < a->n_adc_frames; ++k) {
            trace_frame(a, a->adc_frames[k].can_id, a->adc_frames[k].data, 64);
        }
    }
    if (!a->opt.node.realtime && plant_link_barrier(&a->link)) {
        a->sync_seq++;
        a->waiting_sync = 1;
        send_sync(a);
    }
}

static void resend_adc(app_t *a)
{
    int k;
    if (a->waiting_sync) {
        send_sync(a); /* the barrier again: the faulted frames themselves went out once */
        a->cnt.resends++;
        return;
    }
    for (k = 0; k < a->n_adc_frames; ++k) {
        send_frame(a, a->adc_frames[k].can_id, a->adc_frames[k].data, 64, 0);
    }
    if (a->n_adc_frames) {
        a->cnt.resends++;
    }
}

static void send_truth(app_t *a, const plant_truth_t *t)
{
    const int on_bus = a->opt.truth_every > 0 && (t->period % a->opt.truth_every) == 0;
    struct canfd_frame f[2];
    int k;
    plant_pack_truth(t, f);
    for (k = 0; k < 2; ++k) {
        if (on_bus) {
            send_frame(a, f[k].can_id, f[k].data, 64, 0);
        }
        trace_frame(a, f[k].can_id, f[k].data, 64);
    }
}

/* ------------------------------------------------------------------ receiving */

typedef struct inbox {
    int have_pwm;
    plant_pwm_cmd_t pwm;
    int64_t pwm_arrival_ns;
} inbox_t;

static int known_id(uint32_t id)
{
    switch (id) {
    case HIL_VIO_VIO_PWM_FRAME_ID:
    case HIL_VIO_VIO_ADC_0_FRAME_ID:
    case HIL_VIO_VIO_ADC_1_FRAME_ID:
    case HIL_VIO_VIO_ADC_2_FRAME_ID:
    case HIL_VIO_FW_TRACE_FRAME_ID:
    case HIL_BENCH_BENCH_TRUTH_FRAME_ID:
    case HIL_BENCH_BENCH_TRUTH_MAG_FRAME_ID:
    case HIL_BENCH_BENCH_COUNTERS_FRAME_ID:
    case HIL_BENCH_BENCH_REJECTS_FRAME_ID:
    case HIL_BENCH_BENCH_STEP_FRAME_ID:
    case HIL_BENCH_BENCH_PROGRESS_FRAME_ID:
    case HIL_BENCH_LOAD_CMD_FRAME_ID:
    case HIL_BENCH_FAULT_CMD_FRAME_ID:
    case HIL_VIO_VIO_SYNC_FRAME_ID:
    case HIL_VIO_VIO_SYNC_ACK_FRAME_ID:
        return 1;
    default:
        return 0;
    }
}

/* Period that a PWM frame has to carry now, and the lateness bookkeeping of real time. */
static void handle_frame(app_t *a, const struct canfd_frame *f, int fd, inbox_t *in,
                         int64_t period_start_ns)
{
    const uint32_t id = f->can_id & CAN_SFF_MASK;
    if (f->can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) {
        a->cnt.non_data_frames++; /* not from this protocol's 11-bit data frame space */
        return;
    }
    if (f->len > (fd ? CANFD_MAX_DLEN : CAN_MAX_DLEN)) {
        reject(a, PLANT_REJ_BAD_LENGTH, id, 0); /* hilbus passes none: checked where used */
        return;
    }
    if (id == HIL_VIO_VIO_PWM_FRAME_ID) {
        const uint32_t expected = plant_next_period(a->plant);
        const uint32_t raw_period = f->len >= 4 ? ((uint32_t)f->data[0] | ((uint32_t)f->data[1] << 8) |
                                                   ((uint32_t)f->data[2] << 16) |
                                                   ((uint32_t)f->data[3] << 24))
                                                : 0u;
        const int r = plant_link_pwm(&a->link, f, fd);
        if (a->opt.trace_vio) {
            trace_frame(a, f->can_id, f->data, f->len);
        }
        if (r == PLANT_REJ_NONE && !a->waiting_sync) { /* under the barrier: at its answer */
            in->have_pwm = 1;
            in->pwm_arrival_ns = hil_now_ns();
        }
        if (r == PLANT_REJ_NONE) {
            return;
        }
        if (r == PLANT_REJ_STALE_PERIOD && a->opt.node.realtime) {
            /* A frame for a period that already ran on the old values: it was due before
             * that period started, (expected - p) periods before the current one. */
            const int64_t due = period_start_ns - (int64_t)(expected - raw_period) * HIL_PERIOD_NS;
            const int64_t late_ns = hil_now_ns() - due;
            if (late_ns > 0 && (uint64_t)(late_ns / 1000) > a->cnt.max_late_us) {
                a->cnt.max_late_us = (uint64_t)(late_ns / 1000);
            }
        }
        reject(a, r, id, raw_period);
        return;
    }
    if (id == HIL_VIO_VIO_SYNC_ACK_FRAME_ID) {
        struct hil_vio_vio_sync_ack_t m;
        if (!fd || f->len != HIL_VIO_VIO_SYNC_ACK_LENGTH) {
            reject(a, fd ? PLANT_REJ_BAD_LENGTH : PLANT_REJ_MALFORMED, id, 0);
            return;
        }
        hil_vio_vio_sync_ack_unpack(&m, f->data, f->len);
        if (a->waiting_sync && m.seq == a->sync_seq && m.period + 1u == a->link.expect) {
            /* everything the firmware sent for this period is here: PWM(k+1) or none */
            plant_link_resolve(&a->link);
            in->have_pwm = 1;
            in->pwm_arrival_ns = hil_now_ns();
            a->waiting_sync = 0;
            a->cnt.sync_acks++;
        }
        return; /* (an answer to an earlier barrier's re-send: nothing left to decide) */
    }
    if (id == HIL_BENCH_FAULT_CMD_FRAME_ID) {
        char why[256];
        const int r = plant_link_fault(&a->link, a->plant, fd, f->data, f->len, why, sizeof(why));
        if (r != PLANT_REJ_NONE) {
            reject(a, r, id, 0);
        }
        return;
    }
    if (id == HIL_BENCH_LOAD_CMD_FRAME_ID) {
        plant_load_cmd_t m;
        const int r = plant_decode_load_cmd(fd, f->data, f->len, &m);
        if (r != PLANT_REJ_NONE) {
            reject(a, r, id, 0);
            return;
        }
        plant_set_load(a->plant, m.mode, m.torque_nm, m.speed_rpm, m.k_speed_nms);
        a->cnt.load_cmds++;
        return;
    }
    if (id == HIL_BENCH_BENCH_STEP_FRAME_ID) {
        struct hil_bench_bench_step_t m;
        if (!fd) {
            reject(a, PLANT_REJ_MALFORMED, id, 0); /* BENCH_STEP is a CAN FD frame */
            return;
        }
        if (f->len != HIL_BENCH_BENCH_STEP_LENGTH) {
            reject(a, PLANT_REJ_BAD_LENGTH, id, 0);
            return;
        }
        hil_bench_bench_step_unpack(&m, f->data, f->len);
        if ((int32_t)(m.run_until - plant_next_period(a->plant)) < 0) {
            /* behind the plant (or 2^31 periods or more ahead: the same thing with wrapping
             * periods): no rig grants that; keep the grant in force */
            reject(a, PLANT_REJ_STALE_PERIOD, id, m.run_until);
            return;
        }
        a->run_until = m.run_until;
        a->step_seq = m.seq;
        a->cnt.steps++;
        if (!a->opt.node.realtime && !grant_open(a, plant_next_period(a->plant))) {
            /* Nothing to simulate (a repeated grant, or one already reached): the grant is
             * used up on arrival, so say so now rather than at the next housekeeping. */
            send_progress(a, 0);
        }
        return;
    }
    if (!known_id(id) && (hil_vio_id_in_range(id) || hil_bench_id_in_range(id))) {
        reject(a, PLANT_REJ_UNKNOWN_ID, id, 0);
    }
    /* anything else (drive protocol, firmware trace, our own kind of frames) is not ours */
}

/* ------------------------------------------------------------------ one period */

static void run_period(app_t *a, const plant_pwm_cmd_t *cmd)
{
    plant_samples_t s;
    plant_truth_t t;
    plant_pwm_cmd_t c = *cmd;
    c.period = plant_next_period(a->plant);
    plant_step(a->plant, &c, &s, &t);
    a->current = c;
    a->cnt.periods++;
    a->cnt.adc_clipped += s.clipped;
    send_adc(a, &s);
    send_truth(a, &t);
}

static int lockstep(app_t *a)
{
    inbox_t in;
    int64_t next_housekeeping = hil_now_ns() + HOUSEKEEPING_NS, adc_sent_ns = 0;
    int waiting_pwm = 0;
    memset(&in, 0, sizeof(in));
    plant_startup_command(&in.pwm);
    in.have_pwm = 1; /* period 0 runs on the start-up command */

    while (!g_stop) {
        const uint32_t k = plant_next_period(a->plant);
        int64_t t = hil_now_ns(), timeout_ns;
        struct canfd_frame f;
        int fd, r;

        if (a->opt.node.max_periods && a->cnt.periods >= a->opt.node.max_periods) {
            break;
        }
        if (t >= next_housekeeping) {
            send_housekeeping(a, grant_open(a, k));
            next_housekeeping = t + HOUSEKEEPING_NS;
        }
        if (in.have_pwm && grant_open(a, k)) {
            plant_pwm_cmd_t cmd;
            /* the command with the faults in force now (the FAULT_CMD of this period came
             * with its grant, the PWM frame may have come before it) */
            const int rc = plant_link_commit(&a->link, &a->current, &cmd);
            if (rc != PLANT_REJ_NONE) {
                reject(a, rc, HIL_VIO_VIO_PWM_FRAME_ID, cmd.period);
            }
            run_period(a, &cmd);
            in.have_pwm = 0;
            waiting_pwm = 1;
            adc_sent_ns = hil_now_ns();
            if (plant_next_period(a->plant) == a->run_until) {
                send_progress(a, 0); /* grant used up */
            }
            /* take whatever has already arrived before deciding to wait */
            while ((r = hilbus_recv(a->bus, &f, &fd, 0)) == 1) {
                handle_frame(a, &f, fd, &in, 0);
            }
            continue;
        }
        timeout_ns = next_housekeeping - t;
        if (waiting_pwm && !in.have_pwm && adc_sent_ns + RESEND_NS - t < timeout_ns) {
            timeout_ns = adc_sent_ns + RESEND_NS - t;
        }
        if (timeout_ns < 0) {
            timeout_ns = 0;
        }
        r = hilbus_recv(a->bus, &f, &fd, timeout_ns / 1000);
        if (r == 1) {
            handle_frame(a, &f, fd, &in, 0);
        } else if (r < 0 && errno != EINTR) {
            fprintf(stderr, "plant_rt: receive error: %s\n", strerror(errno));
            return 1;
        }
        if (in.have_pwm) {
            waiting_pwm = 0;
        }
        t = hil_now_ns();
        if (waiting_pwm && !in.have_pwm && t - adc_sent_ns >= RESEND_NS) {
            resend_adc(a); /* the firmware answers a repeated ADC(k) with the same PWM(k+1) */
            adc_sent_ns = t;
        }
    }
    return 0;
}

static void note_wakeup(counters_t *c, int64_t late_ns)
{
    uint64_t us;
    if (late_ns < 0) {
        late_ns = 0;
    }
    us = (uint64_t)late_ns / 1000u;
    c->wake_n++;
    c->wake_sum_ns += (uint64_t)late_ns;
    if ((uint64_t)late_ns > c->wake_max_ns) {
        c->wake_max_ns = (uint64_t)late_ns;
    }
    c->wake_hist[us < WAKE_HIST_BINS ? us : WAKE_HIST_BINS]++;
}

/* Wake-up lateness quantile q in microseconds (upper edge of its 1 us bin). */
static double wake_quantile_us(const counters_t *c, double q)
{
    uint64_t need, seen = 0;
    int b;
    if (c->wake_n == 0) {
        return 0.0;
    }
    need = (uint64_t)ceil(q * (double)c->wake_n);
    if (need < 1) {
        need = 1;
    }
    for (b = 0; b <= WAKE_HIST_BINS; ++b) {
        seen += c->wake_hist[b];
        if (seen >= need) {
            return b < WAKE_HIST_BINS ? (double)(b + 1) : (double)c->wake_max_ns * 1e-3;
        }
    }
    return (double)c->wake_max_ns * 1e-3;
}

/* Real time: period k starts at start + k*Ts on CLOCK_MONOTONIC. The PWM command of period
 * k is whatever valid VIO_PWM(k) has arrived when the period starts; without one the old
 * compare values stay loaded (late_cmds). A period that ends after the next period's start
 * is an overrun; the plant then does not run the missed periods back to back (that would
 * answer the firmware with a burst of ADC frames it cannot keep up with, and the burst
 * would make the next periods late as well): the period grid slips by whole periods so
 * that the firmware again has up to one period to answer the ADC frame just sent
 * (slipped_periods). Simulated time stays k*Ts; wall time lags it by the slip. */
static int realtime(app_t *a)
{
    const int64_t ts_ns = HIL_PERIOD_NS;
    int64_t start, next_housekeeping;
    plant_pwm_cmd_t current;
    inbox_t in;
    a->cnt.rt_note = hil_node_realtime(&a->opt.node);
    memset(&in, 0, sizeof(in));
    plant_startup_command(&current);
    start = hil_now_ns() + 2 * ts_ns;
    next_housekeeping = start + HOUSEKEEPING_NS;

    while (!g_stop) {
        const uint32_t k = plant_next_period(a->plant);
        const int64_t deadline = start + (int64_t)k * ts_ns;
        const int64_t wake = deadline - (int64_t)a->opt.rt_spin_us * 1000;
        struct timespec ts;
        struct canfd_frame f;
        int fd;
        int64_t t;

        if (a->opt.node.max_periods && a->cnt.periods >= a->opt.node.max_periods) {
            break;
        }
        in.have_pwm = 0;
        ts.tv_sec = (time_t)(wake / HIL_NS_PER_S);
        ts.tv_nsec = (long)(wake % HIL_NS_PER_S);
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR && !g_stop) {
        }
        /* --rt-spin-us: take frames as they come while spinning up to the deadline */
        while (!g_stop && (t = hil_now_ns()) < deadline) {
            if (hilbus_recv(a->bus, &f, &fd, 0) == 1) {
                handle_frame(a, &f, fd, &in, deadline);
            }
        }
        if (g_stop) {
            break;
        }
        note_wakeup(&a->cnt, hil_now_ns() - deadline);
        while (hilbus_recv(a->bus, &f, &fd, 0) == 1) {
            handle_frame(a, &f, fd, &in, deadline);
        }
        if (in.have_pwm || k == 0) {
            const int rc = plant_link_commit(&a->link, &current, &current);
            if (rc != PLANT_REJ_NONE) {
                reject(a, rc, HIL_VIO_VIO_PWM_FRAME_ID, current.period);
            }
        } else {
            a->cnt.late_cmds++; /* the old compare values stay loaded */
        }
        run_period(a, &current);
        t = hil_now_ns();
        if (t > deadline + ts_ns) {
            /* the next period's start has passed: slip the grid by whole periods */
            const int64_t behind = t - (deadline + ts_ns);
            const int64_t slip = (behind + ts_ns - 1) / ts_ns;
            a->cnt.overruns++;
            a->cnt.slipped_periods += (uint64_t)slip;
            start += slip * ts_ns;
            next_housekeeping += slip * ts_ns;
        }
        if (t >= next_housekeeping) {
            send_housekeeping(a, 1);
            next_housekeeping += HOUSEKEEPING_NS;
            if (next_housekeeping < t) {
                next_housekeeping = t + HOUSEKEEPING_NS;
            }
        }
    }
    return 0;
}

/* ------------------------------------------------------------------ start-up */

static void usage(FILE *out)
{
    fputs("usage: plant_rt [options]\n"
          "Emulates the IPMSM bench (machine, inverter, sensors, ADC, shaft, load) on the bus.\n"
          "\n",
          out);
    hil_node_usage(out);
    fputs("  --lockstep | --realtime        pacing (default lockstep). Real time: a PWM frame\n"
          "                                 not there when its period starts leaves the old\n"
          "                                 command loaded (late_cmds); an overrun slips the\n"
          "                                 period grid by whole periods (slipped_periods)\n"
          "  --trace FILE                   per-period binary trace (BENCH_TRUTH, _MAG)\n"
          "  --trace-vio                    also trace VIO_PWM received and VIO_ADC sent\n"
          "  --profile NAME|FILE            fidelity profile (default paper); a NAME is looked\n"
          "                                 up as NAME.toml in the profiles folder\n"
          "  --config FILE                  same as --profile FILE\n"
          "  --profiles-dir DIR             profiles folder (default: ../_data/profiles next\n"
          "                                 to the binary when installed, else the source tree)\n"
          "  --set section.key=value        override a profile field (repeatable)\n"
          "  --seed N                       noise seed (= --set sensors.seed=N)\n"
          "  --theta0 RAD                   initial electrical angle\n"
          "  --speed0 RPM                   initial speed\n"
          "  --load-mode torque|speed|off   load machine default (or 0, 1, 2)\n"
          "  --load-torque NM  --load-speed RPM  --load-k NMS   load machine defaults\n"
          "  --run-until N                  initial lockstep grant (periods < N)\n"
          "  --truth-every N                BENCH_TRUTH on the bus every N periods (default 10;\n"
          "                                 the trace has every period)\n"
          "  --rt-spin-us N                 real time: wake N us before each period start and\n"
          "                                 poll the bus until it (less timer jitter, one busy\n"
          "                                 core; default 0)\n"
          "  --help                         this text\n"
          "\n"
          "Profile keys:",
          out);
    {
        int k;
        for (k = 0; k < plant_config_key_count(); ++k) {
            fprintf(out, "%s%s", (k % 4) ? "  " : "\n  ", plant_config_key_name(k));
        }
    }
    fprintf(out, "\n\nExit: 0 on a clean stop, 2 on a bad configuration, 1 on other faults.\n");
}

static int profile_file(const options_t *o, char *out, size_t outlen)
{
    const char *p = o->profile ? o->profile : "paper";
    size_t len = strlen(p);
    if (strchr(p, '/') || (len > 5 && strcmp(p + len - 5, ".toml") == 0)) {
        snprintf(out, outlen, "%s", p);
        return 0;
    }
    if (o->profiles_dir) {
        snprintf(out, outlen, "%s/%s.toml", o->profiles_dir, p);
        return 0;
    }
    {
        char exe[PATH_MAX];
        ssize_t n = readlink("/proc/self/exe", exe, sizeof(exe) - 1);
        if (n > 0) {
            char *slash;
            exe[n] = '\0';
            slash = strrchr(exe, '/');
            if (slash) {
                *slash = '\0';
                snprintf(out, outlen, "%s/../_data/profiles/%s.toml", exe, p);
                if (access(out, R_OK) == 0) {
                    return 0;
                }
            }
        }
    }
    snprintf(out, outlen, "%s/%s.toml", PLANT_SOURCE_PROFILES_DIR, p);
    return 0;
}

static void print_counters(app_t *a)
{
    static char buf[8192];
    hil_json_t j;
    plant_stats_t ps;
    char link[512];
    plant_get_stats(a->plant, &ps);
    hil_json_init(&j, buf, sizeof(buf));
    hil_node_json_begin(&j, &a->opt.node, a->bus);
    hil_json_u64(&j, "periods", a->cnt.periods);
    hil_json_u64(&j, "next_period", plant_next_period(a->plant));
    hil_json_u64(&j, "late_cmds", a->cnt.late_cmds + a->link.st.held);
    hil_json_u64(&j, "overruns", a->cnt.overruns);
    hil_json_u64(&j, "max_late_us", a->cnt.max_late_us);
    hil_json_u64(&j, "rejected", total_rejects(&a->cnt));
    hil_json_counts(&j, "rejects", plant_reject_name, a->cnt.rejects, 1, PLANT_REJ_COUNT);
    hil_json_u64(&j, "adc_clipped", a->cnt.adc_clipped);
    hil_json_u64(&j, "resends", a->cnt.resends);
    hil_node_json_bus(&j, a->bus, a->cnt.non_data_frames);
    hil_json_u64(&j, "load_cmds", a->cnt.load_cmds);
    hil_json_u64(&j, "steps", a->cnt.steps);
    hil_json_u64(&j, "conduction_events", ps.conduction_events);
    hil_json_u64(&j, "newton_failures", ps.newton_failures);
    hil_json_u64(&j, "mode_loops_cut", ps.mode_loops_cut);
    hil_json_str(&j, "rt", a->cnt.rt_note ? a->cnt.rt_note : HIL_NODE_RT_NONE);
    plant_link_stats_json(&a->link, link, sizeof(link));
    hil_json_member(&j, link);
    hil_json_u64(&j, "sync_acks", a->cnt.sync_acks);
    if (a->opt.node.realtime) {
        const counters_t *c = &a->cnt;
        hil_json_u64(&j, "slipped_periods", c->slipped_periods);
        hil_json_open(&j, "wake_late_us");
        hil_json_u64(&j, "n", c->wake_n);
        hil_json_fmt(&j, "mean", "%.2f",
                     c->wake_n ? (double)c->wake_sum_ns * 1e-3 / (double)c->wake_n : 0.0);
        hil_json_fmt(&j, "p99", "%.0f", wake_quantile_us(c, 0.99));
        hil_json_fmt(&j, "max", "%.1f", (double)c->wake_max_ns * 1e-3);
        hil_json_close(&j);
    }
    hil_json_end(&j);
    fprintf(stderr, "%s\n", buf);
    fflush(stderr);
}

/* The profile's overrides in command-line order: --set and the flags that stand for one. */
typedef struct {
    char **items;
    int n;
} sets_t;

static void free_sets(sets_t *sets)
{
    int k;
    for (k = 0; k < sets->n; ++k) {
        free(sets->items[k]);
    }
    free(sets->items);
}

enum {
    O_PROFILE = HIL_OPT_NODE_END, O_CONFIG, O_PROFILES_DIR, O_SET, O_SEED, O_THETA0, O_SPEED0,
    O_LOAD_MODE, O_LOAD_TORQUE, O_LOAD_SPEED, O_LOAD_K, O_TRACE_VIO, O_RUN_UNTIL,
    O_TRUTH_EVERY, O_RT_SPIN, O_HELP
};

/* A flag that stands for a profile override (--seed, --theta0, --load-mode, ...) as
 * "section.key=value" in buf; 0, or -1 after a message. */
static int flag_override(int c, const char *arg, char *buf, size_t len)
{
    static const char *const keys[] = {"sensors.seed", "initial.theta_e_deg", "initial.speed_rpm",
                                       "load.torque_nm", "load.speed_rpm", "load.k_speed_nms"};
    if (c == O_THETA0) {
        char *end;
        const double rad = strtod(arg, &end);
        if (end == arg || *end) {
            fprintf(stderr, "plant_rt: --theta0 %s: not a number\n", arg);
            return -1;
        }
        snprintf(buf, len, "%s=%.17g", keys[1], rad * 180.0 / 3.14159265358979323846);
    } else if (c == O_LOAD_MODE) {
        const int mode = strcmp(arg, "torque") == 0 ? (int)HIL_BENCH_LOAD_CMD_MODE_TORQUE_CHOICE
                       : strcmp(arg, "speed") == 0 ? (int)HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE
                       : strcmp(arg, "off") == 0   ? (int)HIL_BENCH_LOAD_CMD_MODE_OFF_CHOICE
                                                   : -1;
        if (mode >= 0) {
            snprintf(buf, len, "load.mode=%d", mode);
        } else {
            snprintf(buf, len, "load.mode=%s", arg);
        }
    } else {
        const int idx = c == O_SEED ? 0 : c == O_SPEED0 ? 2 : c == O_LOAD_TORQUE ? 3
                      : c == O_LOAD_SPEED ? 4 : 5;
        snprintf(buf, len, "%s=%s", keys[idx], arg);
    }
    return 0;
}

/* 0, 1 after --help, 2 on a bad argument. */
static int parse_options(int argc, char **argv, options_t *o, sets_t *sets)
{
    static const struct option longopts[] = {
        HIL_NODE_LONGOPTS,
        {"profile", required_argument, 0, O_PROFILE},
        {"config", required_argument, 0, O_CONFIG},
        {"profiles-dir", required_argument, 0, O_PROFILES_DIR},
        {"set", required_argument, 0, O_SET},
        {"seed", required_argument, 0, O_SEED},
        {"theta0", required_argument, 0, O_THETA0},
        {"speed0", required_argument, 0, O_SPEED0},
        {"load-mode", required_argument, 0, O_LOAD_MODE},
        {"load-torque", required_argument, 0, O_LOAD_TORQUE},
        {"load-speed", required_argument, 0, O_LOAD_SPEED},
        {"load-k", required_argument, 0, O_LOAD_K},
        {"trace-vio", no_argument, 0, O_TRACE_VIO},
        {"run-until", required_argument, 0, O_RUN_UNTIL},
        {"truth-every", required_argument, 0, O_TRUTH_EVERY},
        {"rt-spin-us", required_argument, 0, O_RT_SPIN},
        {"help", no_argument, 0, O_HELP},
        {0, 0, 0, 0},
    };
    int c;
    hil_node_opts_init(&o->node, "plant_rt");
    o->truth_every = 10;
    sets->items = (char **)calloc((size_t)argc + 1, sizeof(char *));
    sets->n = 0;
    if (!sets->items) {
        return 2;
    }
    while ((c = getopt_long(argc, argv, "h", longopts, NULL)) != -1) {
        const int node = hil_node_option(&o->node, c, optarg);
        uint64_t v;
        char buf[256];
        if (node != 0) {
            if (node < 0) {
                return 2;
            }
            continue;
        }
        switch (c) {
        case O_PROFILE:
        case O_CONFIG: o->profile = optarg; break;
        case O_PROFILES_DIR: o->profiles_dir = optarg; break;
        case O_SET: sets->items[sets->n++] = strdup(optarg); break;
        case O_SEED:
        case O_THETA0:
        case O_SPEED0:
        case O_LOAD_MODE:
        case O_LOAD_TORQUE:
        case O_LOAD_SPEED:
        case O_LOAD_K:
            if (flag_override(c, optarg, buf, sizeof(buf)) != 0) {
                return 2;
            }
            sets->items[sets->n++] = strdup(buf);
            break;
        case O_TRACE_VIO: o->trace_vio = 1; break;
        case O_RUN_UNTIL:
        case O_TRUTH_EVERY:
        case O_RT_SPIN: {
            const char *flag = c == O_RUN_UNTIL ? "--run-until" : c == O_TRUTH_EVERY
                             ? "--truth-every" : "--rt-spin-us";
            if (hil_node_u64_arg(&o->node, flag, optarg, UINT32_MAX, &v) != 0) {
                return 2;
            }
            if (c == O_RUN_UNTIL) {
                o->run_until = (uint32_t)v;
            } else if (c == O_TRUTH_EVERY) {
                o->truth_every = (uint32_t)v;
            } else if (v >= (uint64_t)(HIL_PERIOD_NS / 1000)) {
                fprintf(stderr, "plant_rt: --rt-spin-us %s: must be below the period (%lld)\n",
                        optarg, HIL_PERIOD_NS / 1000);
                return 2;
            } else {
                o->rt_spin_us = (uint32_t)v;
            }
            break;
        }
        case O_HELP:
        case 'h':
            usage(stdout);
            return 1;
        default:
            usage(stderr);
            return 2;
        }
    }
    if (optind < argc) {
        fprintf(stderr, "plant_rt: unexpected argument '%s'\n", argv[optind]);
        return 2;
    }
    return 0;
}

/* The plant of the profile and the overrides in order: 0, or 2 after a message. */
static int make_plant(app_t *a, const sets_t *sets)
{
    char path[PATH_MAX + 64], err[1024];
    plant_config_t cfg;
    int k;
    plant_config_defaults(&cfg);
    profile_file(&a->opt, path, sizeof(path));
    if (plant_config_load(&cfg, path, err, sizeof(err)) != 0) {
        fprintf(stderr, "plant_rt: bad configuration: %s\n", err);
        return 2;
    }
    for (k = 0; k < sets->n; ++k) {
        if (!sets->items[k] || plant_config_set(&cfg, sets->items[k], err, sizeof(err)) != 0) {
            fprintf(stderr, "plant_rt: bad configuration: %s\n",
                    sets->items[k] ? err : "out of memory");
            return 2;
        }
    }
    a->plant = plant_new(&cfg, err, sizeof(err));
    if (!a->plant) {
        fprintf(stderr, "plant_rt: bad configuration: %s (after --set)\n", err);
        return 2;
    }
    return 0;
}

int main(int argc, char **argv)
{
    static app_t a; /* large (the link's held frames): static storage */
    sets_t sets;
    int rc, trace_failed;

    hil_log_limit_init(&a.log_limit, "plant_rt", 10, hil_now_ns());
    rc = parse_options(argc, argv, &a.opt, &sets);
    if (rc == 0) {
        rc = make_plant(&a, &sets);
    }
    free_sets(&sets);
    if (rc != 0) {
        plant_free(a.plant);
        return rc == 1 ? 0 : rc; /* 1: --help */
    }
    a.cfg = plant_config(a.plant);
    a.run_until = a.opt.run_until;
    plant_link_init(&a.link);
    plant_startup_command(&a.current);
    hil_node_signals(&g_stop, 0);

    a.bus = hil_node_open_bus(&a.opt.node);
    if (!a.bus) {
        plant_free(a.plant);
        return 1;
    }
    a.trace = hil_node_open_trace(&a.opt.node, &trace_failed);
    if (trace_failed) {
        hilbus_close(a.bus);
        plant_free(a.plant);
        return 1;
    }
    rc = hil_node_ready(&a.opt.node) != 0 ? 1 : 0;
    if (rc == 0) {
        rc = a.opt.node.realtime ? realtime(&a) : lockstep(&a);
    }
    send_housekeeping(&a, 2);
    if (hil_node_close_trace(&a.opt.node, a.trace) != 0 || a.bus_failed) {
        rc = 1;
    }
    print_counters(&a);
    hilbus_close(a.bus);
    plant_free(a.plant);
    return rc;
}
