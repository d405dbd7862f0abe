/* sil_bench.c - see sil_bench.h. The glue between the plant's and the firmware's frame code;
 * everything that decides a value lives in the units the bus programs link: the firmware side
 * is fw_host's own state and frame handlers (fw_host.h), sending through a sink into this
 * bench instead of onto a bus. */
#define _POSIX_C_SOURCE 199309L /* clock_gettime */
#include "sil_bench.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "core_journal.h"
#include "drive_codec.h"
#include "fw_core.h"
#include "fw_host.h"
#include "hil_bench.h"
#include "hil_drive.h"
#include "hil_vio.h"
#include "hil_wire.h"
#include "hiltrace.h"
#include "param_file.h"
#include "plant_core.h"
#include "plant_link.h"
#include "plant_vio.h"
#include "vio_codec.h"

struct sil_bench {
    fwh_t fw; /* first (holds the large control core): fw_host's state, handlers' sink here */
    plant_t *plant;
    plant_link_t link;      /* frame faults and the exchange of each period (plant_link.h) */
    /* the ADC frames of a period as they leave the plant (with held-back ones now due) */
    struct canfd_frame out[PLANT_VIO_ADC_FRAMES_MAX + PLANT_LINK_HELD_MAX];
    plant_pwm_cmd_t pwm;    /* command of the plant's next period */
    plant_truth_t truth;    /* at the start of the last simulated period */
    hiltrace_t *plant_trace;
    int trace_vio;
    struct canfd_frame pwm_out; /* VIO_PWM the firmware sent while handling a frame */
    int pwm_sent;
    uint32_t sync_seq;
    char line[256];          /* the firmware's last rejection or log line */
    int timing;
    double last_isr_ns;
    uint8_t alive;
    sil_bench_adc_hook_t hook;
    void *hook_ctx;
    fw_adc_t last_adc;
    fw_pwm_t last_pwm;
    sil_bench_stats_t st;   /* the plant's side and the timings (the firmware's: fw.cnt) */
    uint64_t plant_rejects[PLANT_REJ_COUNT];
    core_journal_t *journal; /* every core call (sil_bench_journal_open), or NULL */
    /* what the bus programs would send to the rig, oldest first (sil_bench_outbox) */
    struct {
        struct canfd_frame f[SIL_BENCH_OUTBOX_FRAMES];
        unsigned head, count;
        uint32_t truth_every; /* BENCH_TRUTH every N periods; 0: none */
        int on;
        uint64_t dropped;
    } outbox;
};

static fwh_param_list_t fw_sets; /* large: not on the stack (one bench opens at a time) */

/* firmware parameter <- plant configuration (see sil_bench_hardware_param) */
static const struct {
    const char *param, *key;
    double factor;
} HARDWARE[] = {
    {"adc_bits", "adc.bits", 1.0},
    {"adc_range_a", "adc.range_a", 1.0},
    {"adc_vdc_range_v", "adc.vdc_range_v", 1.0},
    {"adc_vdc_bits", "adc.vdc_bits", 1.0},
    {"deadtime_us", "inverter.dead_time_s", 1e6},
    {"vdrop_v", "inverter.device_drop_v", 1.0},
};
#define N_HARDWARE ((int)(sizeof(HARDWARE) / sizeof(HARDWARE[0])))

const char *sil_bench_hardware_param(int i, const char **profile_key, double *factor)
{
    if (i < 0 || i >= N_HARDWARE) {
        return NULL;
    }
    *profile_key = HARDWARE[i].key;
    *factor = HARDWARE[i].factor;
    return HARDWARE[i].param;
}

static double plant_value(const plant_config_t *c, const char *key)
{
    if (strcmp(key, "adc.bits") == 0) {
        return c->adc.bits;
    }
    if (strcmp(key, "adc.range_a") == 0) {
        return c->adc.range_a;
    }
    if (strcmp(key, "adc.vdc_range_v") == 0) {
        return c->adc.vdc_range_v;
    }
    if (strcmp(key, "adc.vdc_bits") == 0) {
        return c->adc.vdc_bits;
    }
    if (strcmp(key, "inverter.dead_time_s") == 0) {
        return c->inverter.dead_time_s;
    }
    return c->inverter.device_drop_v; /* "inverter.device_drop_v" */
}

static double now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

static void fail(char *err, size_t errlen, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* The reason of a refusal, for a caller that asked for one (err may be NULL). */
static void fail(char *err, size_t errlen, const char *fmt, ...)
{
    va_list ap;
    if (err == NULL || errlen == 0) {
        return;
    }
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
}

/* The handlers' calls into the core (fwh_core_calls_t), each journalled when a journal is
 * open; the ISR timed (sil_bench_time_isr) and its ADC data first handed to the hook. */
static void core_isr(void *ctx, fw_core_t *core, const fw_adc_t *adc, fw_pwm_t *pwm)
{
    sil_bench_t *b = (sil_bench_t *)ctx;
    if (adc != NULL) {
        b->last_adc = *adc;
        if (b->hook != NULL) {
            b->hook(b->hook_ctx, &b->last_adc);
        }
        adc = &b->last_adc;
    }
    core_journal_before(b->journal, core);
    if (b->timing) {
        const double t0 = now_ns();
        fw_core_isr(core, adc, pwm);
        b->last_isr_ns = now_ns() - t0;
        b->st.isr_ns_total += b->last_isr_ns;
    } else {
        fw_core_isr(core, adc, pwm);
    }
    core_journal_isr(b->journal, core, adc, pwm);
    if (adc != NULL) {
        b->last_pwm = *pwm;
    }
}

static int16_t core_command(void *ctx, fw_core_t *core, const fw_cmd_t *cmd)
{
    sil_bench_t *b = (sil_bench_t *)ctx;
    int16_t st;
    core_journal_before(b->journal, core);
    st = fw_core_command(core, cmd);
    core_journal_command(b->journal, cmd, st);
    return st;
}

static int16_t core_limits(void *ctx, fw_core_t *core, real_t i_max, real_t speed_max,
                           real_t accel)
{
    sil_bench_t *b = (sil_bench_t *)ctx;
    int16_t st;
    core_journal_before(b->journal, core);
    st = fw_core_set_limits(core, i_max, speed_max, accel);
    core_journal_limits(b->journal, i_max, speed_max, accel, st);
    return st;
}

static void outbox_put(sil_bench_t *b, const struct canfd_frame *f)
{
    if (b->outbox.count == SIL_BENCH_OUTBOX_FRAMES) {
        b->outbox.dropped++; /* not taken in time: the oldest stays, as a full queue keeps it */
        return;
    }
    b->outbox.f[(b->outbox.head + b->outbox.count) % SIL_BENCH_OUTBOX_FRAMES] = *f;
    b->outbox.count++;
}

/* The handlers' sink: VIO_PWM kept for the plant; the rest (DRIVE_STATUS, TLM_*, VIO_SYNC_ACK)
 * into the outbox when it is on, else nowhere (the bench is in lockstep by construction). */
static int sink_send(void *ctx, const struct canfd_frame *f, int fd)
{
    sil_bench_t *b = (sil_bench_t *)ctx;
    (void)fd;
    if ((f->can_id & CAN_SFF_MASK) == HIL_VIO_VIO_PWM_FRAME_ID) {
        b->pwm_out = *f;
        b->pwm_sent = 1;
    } else if (b->outbox.on) {
        outbox_put(b, f);
    }
    return 0;
}

static void sink_log(void *ctx, const char *line)
{
    sil_bench_t *b = (sil_bench_t *)ctx;
    snprintf(b->line, sizeof(b->line), "%s", line);
}

static int open_plant(sil_bench_t *b, const sil_bench_config_t *cfg, char *err, size_t errlen)
{
    plant_config_t pc;
    char msg[768];
    int k;
    plant_config_defaults(&pc);
    if (cfg->profile_path != NULL &&
        plant_config_load(&pc, cfg->profile_path, msg, sizeof(msg)) != 0) {
        fail(err, errlen, "plant: %s", msg);
        return -1;
    }
    for (k = 0; k < cfg->n_plant_sets; k++) {
        if (plant_config_set(&pc, cfg->plant_sets[k], msg, sizeof(msg)) != 0) {
            fail(err, errlen, "plant: %s", msg);
            return -1;
        }
    }
    b->plant = plant_new(&pc, msg, sizeof(msg));
    if (b->plant == NULL) {
        fail(err, errlen, "plant: %s (after the overrides)", msg);
        return -1;
    }
    return 0;
}

static int open_firmware(sil_bench_t *b, const sil_bench_config_t *cfg, char *err,
                         size_t errlen)
{
    char msg[512];
    int k, failed = 0, changed = 0;
    int16_t st;
    fw_core_init(&b->fw.core);
    fwh_adc_init(&b->fw.adc);
    fwh_adc_lockstep(&b->fw.adc); /* as fw_host in lockstep: periods skip only behind a barrier */
    b->fw.pty.master = -1;        /* no console */
    b->fw.sink.send = sink_send;
    b->fw.sink.log = sink_log;
    b->fw.sink.ctx = b;
    b->fw.calls.isr = core_isr;
    b->fw.calls.command = core_command;
    b->fw.calls.limits = core_limits;
    b->fw.calls.ctx = b;
    if (cfg->n_fw_sets + N_HARDWARE > FWH_PARAM_ITEMS_MAX) {
        fail(err, errlen, "firmware: more than %d parameters", FWH_PARAM_ITEMS_MAX - N_HARDWARE);
        return -1;
    }
    fw_sets.n = 0;
    if (cfg->fw_from_plant) {
        for (k = 0; k < N_HARDWARE; k++) {
            char text[96];
            const double v = plant_value(plant_config(b->plant), HARDWARE[k].key) *
                             HARDWARE[k].factor;
            snprintf(text, sizeof(text), "%s=%.9g", HARDWARE[k].param, v);
            if (fwh_params_parse_assignment(text, &fw_sets.items[fw_sets.n], msg,
                                            sizeof(msg)) != 0) {
                fail(err, errlen, "firmware (from the plant): %s", msg);
                return -1;
            }
            fw_sets.items[fw_sets.n].line = fw_sets.n + 1;
            fw_sets.n++;
        }
    }
    for (k = 0; k < cfg->n_fw_sets; k++) {
        if (fwh_params_parse_assignment(cfg->fw_sets[k], &fw_sets.items[fw_sets.n], msg,
                                        sizeof(msg)) != 0) {
            fail(err, errlen, "firmware: %s", msg);
            return -1;
        }
        fw_sets.items[fw_sets.n].line = fw_sets.n + 1;
        fw_sets.n++;
    }
    st = fw_sets.n > 0 ? fwh_params_apply(&b->fw.core, &fw_sets, &failed, &changed) : FW_STATUS_OK;
    if (st != FW_STATUS_OK) {
        fail(err, errlen,
             "firmware: %s: rejected by the control core (status %d: not a whole number, or "
             "inconsistent with other parameters)",
             fw_sets.items[failed].name, (int)st);
        return -1;
    }
    b->st.param_sets = (uint64_t)changed;
    return 0;
}

sil_bench_t *sil_bench_open(const sil_bench_config_t *cfg, char *err, size_t errlen)
{
    sil_bench_t *b = (sil_bench_t *)calloc(1, sizeof(*b));
    if (b == NULL) {
        fail(err, errlen, "out of memory");
        return NULL;
    }
    if (open_plant(b, cfg, err, errlen) != 0 || open_firmware(b, cfg, err, errlen) != 0) {
        sil_bench_close(b);
        return NULL;
    }
    b->trace_vio = cfg->trace_vio;
    if (cfg->plant_trace != NULL && (b->plant_trace = hiltrace_open(cfg->plant_trace)) == NULL) {
        fail(err, errlen, "trace: cannot create %s: %s", cfg->plant_trace, strerror(errno));
        sil_bench_close(b);
        return NULL;
    }
    if (cfg->fw_trace != NULL && (b->fw.trace = hiltrace_open(cfg->fw_trace)) == NULL) {
        fail(err, errlen, "trace: cannot create %s: %s", cfg->fw_trace, strerror(errno));
        sil_bench_close(b);
        return NULL;
    }
    plant_startup_command(&b->pwm); /* period 0 runs on the start-up command */
    plant_link_init(&b->link);
    return b;
}

int sil_bench_close(sil_bench_t *b)
{
    int rc = 0;
    if (b == NULL) {
        return 0;
    }
    if (core_journal_close(b->journal) != 0) {
        rc = -1;
    }
    if (b->plant_trace != NULL && hiltrace_close(b->plant_trace) != 0) {
        rc = -1;
    }
    if (b->fw.trace != NULL && hiltrace_close(b->fw.trace) != 0) {
        rc = -1;
    }
    plant_free(b->plant);
    free(b);
    return rc;
}

/* ------------------------------------------------------------------------ frames in */

/* A drive-protocol frame through fw_host's handler (drive_protocol.c). PARAM_REQ is not
 * served here: parameters are set at open, and the bench has no way back to the requester. */
static int drive_frame(sil_bench_t *b, const struct canfd_frame *f, int fd, char *err,
                       size_t errlen)
{
    char why[160];
    int reason = 0;
    const int kind = fwh_drive_classify(f, fd, &reason, why, sizeof(why));
    const uint64_t rejected = fwh_rejected_total(&b->fw);
    if (kind == FWH_DRIVE_PARAM_REQ) {
        fail(err, errlen, "PARAM_REQ: not served by the in-process bench (parameters are set "
                          "at open)");
        return 1;
    }
    fwh_drive_frame(&b->fw, f, fd);
    if (fwh_rejected_total(&b->fw) != rejected) {
        fail(err, errlen, "firmware %s", b->line);
        return -1;
    }
    return kind == FWH_DRIVE_NOT_OURS ? 1 : 0; /* what a drive sends */
}

int sil_bench_frame(sil_bench_t *b, uint32_t can_id, int fd, const uint8_t *data, uint8_t len,
                    char *err, size_t errlen)
{
    struct canfd_frame f;
    const uint32_t id = can_id & CAN_SFF_MASK;
    if (len > sizeof(f.data)) {
        fail(err, errlen, "frame of %u bytes: longer than 64", (unsigned)len);
        return -1;
    }
    memset(&f, 0, sizeof(f));
    f.can_id = can_id;
    f.len = len;
    memcpy(f.data, data, len);
    if (id == HIL_BENCH_FAULT_CMD_FRAME_ID) {
        char why[256] = "";
        const int r = plant_link_fault(&b->link, b->plant, fd, f.data, f.len, why, sizeof(why));
        if (r != PLANT_REJ_NONE) {
            b->plant_rejects[r]++;
            b->st.plant_rejected++;
            fail(err, errlen, "plant rejected FAULT_CMD: %s%s%s", plant_reject_name(r),
                 why[0] ? ": " : "", why);
            return -1;
        }
        return 0;
    }
    if (id == HIL_BENCH_LOAD_CMD_FRAME_ID) {
        plant_load_cmd_t m;
        const int r = plant_decode_load_cmd(fd, f.data, f.len, &m);
        if (r != PLANT_REJ_NONE) {
            b->plant_rejects[r]++;
            b->st.plant_rejected++;
            fail(err, errlen, "plant rejected LOAD_CMD: %s", plant_reject_name(r));
            return -1;
        }
        plant_set_load(b->plant, m.mode, m.torque_nm, m.speed_rpm, m.k_speed_nms);
        b->st.load_cmds++;
        return 0;
    }
    if (hil_drive_id_in_range(id)) {
        return drive_frame(b, &f, fd, err, errlen);
    }
    return 1;
}

int sil_bench_drive_cmd(sil_bench_t *b, int enable, int fault_reset, int ctrl_mode,
                        int fw_mode, double speed_ref_rpm, double iq_ref_a)
{
    struct hil_drive_drive_cmd_t m;
    uint8_t buf[8];
    memset(&m, 0, sizeof(m));
    m.enable = (uint8_t)enable;
    m.fault_reset = (uint8_t)fault_reset;
    m.ctrl_mode = (uint8_t)ctrl_mode;
    m.fw_mode = (uint8_t)fw_mode;
    m.alive = b->alive++;
    m.speed_ref = hil_drive_drive_cmd_speed_ref_encode(speed_ref_rpm);
    m.iq_ref = hil_drive_drive_cmd_iq_ref_encode(iq_ref_a);
    hil_drive_drive_cmd_pack(buf, &m, sizeof(buf));
    return sil_bench_frame(b, HIL_DRIVE_DRIVE_CMD_FRAME_ID, 0, buf, HIL_DRIVE_DRIVE_CMD_LENGTH,
                           NULL, 0);
}

int sil_bench_drive_limits(sil_bench_t *b, double i_max_a, double speed_max_rpm,
                           double accel_rpm_s)
{
    struct hil_drive_drive_limits_t m;
    uint8_t buf[8];
    memset(&m, 0, sizeof(m));
    m.i_max = hil_drive_drive_limits_i_max_encode(i_max_a);
    m.speed_max = hil_drive_drive_limits_speed_max_encode(speed_max_rpm);
    m.accel_max = hil_drive_drive_limits_accel_max_encode(accel_rpm_s);
    hil_drive_drive_limits_pack(buf, &m, sizeof(buf));
    return sil_bench_frame(b, HIL_DRIVE_DRIVE_LIMITS_FRAME_ID, 0, buf,
                           HIL_DRIVE_DRIVE_LIMITS_LENGTH, NULL, 0);
}

int sil_bench_load_cmd(sil_bench_t *b, int mode, double torque_nm, double speed_rpm,
                       double k_speed_nms)
{
    struct hil_bench_load_cmd_t m;
    uint8_t buf[64];
    memset(&m, 0, sizeof(m));
    m.mode = (uint8_t)mode;
    m.torque = (float)torque_nm;
    m.speed = (float)speed_rpm;
    m.k_speed = (float)k_speed_nms;
    hil_bench_load_cmd_pack(buf, &m, sizeof(buf));
    return sil_bench_frame(b, HIL_BENCH_LOAD_CMD_FRAME_ID, 1, buf, HIL_BENCH_LOAD_CMD_LENGTH,
                           NULL, 0);
}

/* ------------------------------------------------------------------------ one period */

static void trace(sil_bench_t *b, hiltrace_t *t, const struct canfd_frame *f)
{
    if (t != NULL && hiltrace_write(t, f) != 0) {
        b->st.trace_errors++;
    }
}

/* Rejections that refuse a frame (an incomplete period is counted but refuses nothing). */
static uint64_t refusals(const fwh_t *fw)
{
    return fwh_rejected_total(fw) - fw->cnt.rejects[FWH_REJ_INCOMPLETE];
}

/* One ADC frame through fw_host's handler (bus_io.c: feed, the ISRs of lost periods, the
 * ISR, VIO_PWM out): 1 when *pwm holds the VIO_PWM it sent, 0 when more frames are needed,
 * -1 when the data was refused. */
static int firmware_adc(sil_bench_t *b, const struct canfd_frame *adc, struct canfd_frame *pwm)
{
    const uint64_t refused = refusals(&b->fw);
    b->pwm_sent = 0;
    fwh_bus_vio_frame(&b->fw, adc, 1, 0);
    if (refusals(&b->fw) != refused) {
        return -1;
    }
    *pwm = b->pwm_out;
    return b->pwm_sent;
}

/* VIO_SYNC after the period's frames, as plant_rt sends it after a faulted exchange: the
 * firmware's handler marks the barrier (the plant may skip periods from now on). */
static void firmware_sync(sil_bench_t *b, uint32_t period)
{
    struct hil_vio_vio_sync_t m;
    struct canfd_frame f;
    memset(&m, 0, sizeof(m));
    memset(&f, 0, sizeof(f));
    m.period = period;
    m.seq = b->sync_seq++;
    f.can_id = HIL_VIO_VIO_SYNC_FRAME_ID;
    f.len = HIL_VIO_VIO_SYNC_LENGTH;
    hil_vio_vio_sync_pack(f.data, &m, sizeof(f.data));
    fwh_bus_vio_frame(&b->fw, &f, 1, 0);
}

int sil_bench_step(sil_bench_t *b)
{
    plant_samples_t s;
    struct canfd_frame adc[PLANT_VIO_ADC_FRAMES_MAX], truth[2], pwm;
    const int max_out = (int)(sizeof(b->out) / sizeof(b->out[0]));
    int n, n_out, k, barrier, rc;
    /* the command with the faults in force now (plant_link.h; a FAULT_CMD given between
     * periods acts from the next one, as on the bus) */
    rc = plant_link_commit(&b->link, &b->pwm, &b->pwm);
    if (rc != PLANT_REJ_NONE) {
        b->plant_rejects[rc]++;
        b->st.plant_rejected++;
    }
    b->pwm.period = plant_next_period(b->plant);
    if (b->timing) {
        const double t0 = now_ns();
        plant_step(b->plant, &b->pwm, &s, &b->truth);
        b->st.plant_ns_total += now_ns() - t0;
    } else {
        plant_step(b->plant, &b->pwm, &s, &b->truth);
    }
    b->st.periods++;
    b->st.adc_clipped += s.clipped;
    n = plant_pack_adc(&s, adc);
    plant_pack_truth(&b->truth, truth);
    /* the frames as they leave the plant under the frame faults (plant_link.h, as plant_rt) */
    n_out = plant_link_adc_out(&b->link, s.period, adc, n, b->out, max_out);
    barrier = plant_link_barrier(&b->link);
    if (b->trace_vio) {
        for (k = 0; k < n_out; k++) {
            trace(b, b->plant_trace, &b->out[k]);
        }
    }
    trace(b, b->plant_trace, &truth[0]);
    trace(b, b->plant_trace, &truth[1]);
    if (b->outbox.truth_every > 0 && b->truth.period % b->outbox.truth_every == 0u) {
        outbox_put(b, &truth[0]); /* before the period's telemetry, as plant_rt sends it */
    }
    for (k = 0; k < n_out; k++) {
        int rej;
        const int r = firmware_adc(b, &b->out[k], &pwm);
        if (r < 0 && !barrier) {
            return -1; /* refused without a fault on the wires: on the bus the lockstep stalls */
        }
        if (r != 1) {
            continue;
        }
        if (b->trace_vio) {
            trace(b, b->plant_trace, &pwm);
        }
        rej = plant_link_pwm(&b->link, &pwm, 1);
        if (rej != PLANT_REJ_NONE) {
            b->plant_rejects[rej]++;
            b->st.plant_rejected++;
            if (!barrier && !plant_link_decided(&b->link)) {
                return -1; /* the plant would wait for a PWM it accepts */
            }
        }
    }
    if (barrier) {
        /* the barrier (VIO_SYNC after the period's frames, as on the bus): everything the
         * firmware made of these frames is in */
        firmware_sync(b, s.period);
        plant_link_resolve(&b->link);
    }
    if (!plant_link_decided(&b->link)) {
        return -1; /* no PWM(k+1): on the bus the lockstep would stall */
    }
    return 0;
}

long sil_bench_run_until(sil_bench_t *b, uint32_t run_until)
{
    long n = 0;
    while ((int32_t)(plant_next_period(b->plant) - run_until) < 0) {
        if (sil_bench_step(b) != 0) {
            return -1;
        }
        n++;
    }
    return n;
}

uint32_t sil_bench_next_period(const sil_bench_t *b)
{
    return plant_next_period(b->plant);
}

/* The plant's side and the timings as counted here, the firmware's from fw_host's counters
 * (isr there counts the ISRs without data too). */
void sil_bench_get_stats(const sil_bench_t *b, sil_bench_stats_t *stats)
{
    const fwh_counters_t *c = &b->fw.cnt;
    *stats = b->st;
    stats->isr = c->isr - c->isr_no_data;
    stats->isr_no_data = c->isr_no_data;
    stats->pwm_invalid = c->pwm_invalid;
    stats->fw_rejected = fwh_rejected_total(&b->fw);
    stats->drive_cmds = c->drive_cmds;
    stats->cmds_refused = c->cmds_refused;
    stats->limits = c->limits;
    stats->limits_refused = c->rejects[FWH_REJ_REFUSED]; /* DRIVE_LIMITS only */
    stats->trace_records = c->trace_records;
    stats->trace_errors = b->st.trace_errors + c->trace_errors;
}

void sil_bench_time_isr(sil_bench_t *b, int on)
{
    b->timing = on;
}

double sil_bench_last_isr_ns(const sil_bench_t *b)
{
    return b->last_isr_ns;
}

int sil_bench_journal_open(sil_bench_t *b, const char *path, const uint32_t *win_start,
                           const uint32_t *win_len, int n_win, char *err, size_t errlen)
{
    if (b->journal != NULL) {
        fail(err, errlen, "journal: already open");
        return -1;
    }
    b->journal = core_journal_open(path, &b->fw.core, win_start, win_len, n_win, err, errlen);
    return b->journal != NULL ? 0 : -1;
}

void sil_bench_outbox(sil_bench_t *b, uint32_t tlm_div, uint32_t truth_every)
{
    b->fw.opt.tlm_div = tlm_div;
    b->outbox.truth_every = truth_every;
    b->outbox.on = tlm_div > 0 || truth_every > 0;
}

int sil_bench_take_frame(sil_bench_t *b, uint32_t *can_id, uint8_t *data, uint8_t *len)
{
    const struct canfd_frame *f;
    if (b->outbox.count == 0) {
        return 0;
    }
    f = &b->outbox.f[b->outbox.head];
    *can_id = f->can_id;
    *len = f->len;
    memcpy(data, f->data, f->len);
    b->outbox.head = (b->outbox.head + 1) % SIL_BENCH_OUTBOX_FRAMES;
    b->outbox.count--;
    return 1;
}

uint64_t sil_bench_outbox_dropped(const sil_bench_t *b)
{
    return b->outbox.dropped;
}

void sil_bench_set_adc_hook(sil_bench_t *b, sil_bench_adc_hook_t hook, void *ctx)
{
    b->hook = hook;
    b->hook_ctx = ctx;
}

void sil_bench_last_io(const sil_bench_t *b, fw_adc_t *adc, fw_pwm_t *pwm)
{
    if (adc != NULL) {
        *adc = b->last_adc;
    }
    if (pwm != NULL) {
        *pwm = b->last_pwm;
    }
}

struct plant *sil_bench_plant(sil_bench_t *b)
{
    return b->plant;
}

struct fw_core *sil_bench_core(sil_bench_t *b)
{
    return &b->fw.core;
}

const struct plant_truth *sil_bench_truth(const sil_bench_t *b)
{
    return &b->truth;
}

size_t sil_bench_sizeof_stats(void)
{
    return sizeof(sil_bench_stats_t);
}

int sil_bench_fw_trace_record(const fw_status_t *status, uint8_t *data)
{
    struct canfd_frame f;
    fwh_vio_trace_pack(status, &f);
    memcpy(data, f.data, f.len);
    return f.len;
}

size_t sil_bench_sizeof_fw_status(void)
{
    return sizeof(fw_status_t);
}

/* ------------------------------------------------------------------------ counters */

#define APPEND(...)                                                                         \
    do {                                                                                    \
        const int w_ = snprintf(buf + (used < len ? used : len), used < len ? len - used : 0, \
                                __VA_ARGS__);                                               \
        used += w_ > 0 ? (size_t)w_ : 0;                                                    \
    } while (0)

int sil_bench_counters_json(const sil_bench_t *b, char *buf, size_t len)
{
    size_t used = 0;
    plant_stats_t ps;
    sil_bench_stats_t st;
    fw_status_t s;
    int k;
    plant_get_stats(b->plant, &ps);
    sil_bench_get_stats(b, &st);
    fw_core_status(&b->fw.core, &s);
    APPEND("{\"plant\": {\"program\": \"sil_bench\", \"mode\": \"inproc\", \"periods\": %llu, "
           "\"next_period\": %u, \"rejected\": %llu, \"rejects\": {",
           (unsigned long long)st.periods, (unsigned)plant_next_period(b->plant),
           (unsigned long long)st.plant_rejected);
    for (k = 1; k < PLANT_REJ_COUNT; k++) {
        APPEND("%s\"%s\": %llu", k > 1 ? ", " : "", plant_reject_name(k),
               (unsigned long long)b->plant_rejects[k]);
    }
    APPEND("}, \"adc_clipped\": %llu, \"load_cmds\": %llu, \"conduction_events\": %llu, "
           "\"newton_failures\": %llu, \"mode_loops_cut\": %llu, \"late_cmds\": %llu, ",
           (unsigned long long)st.adc_clipped, (unsigned long long)st.load_cmds,
           (unsigned long long)ps.conduction_events, (unsigned long long)ps.newton_failures,
           (unsigned long long)ps.mode_loops_cut, (unsigned long long)b->link.st.held);
    {
        char link[512];
        plant_link_stats_json(&b->link, link, sizeof(link));
        APPEND("%s}, ", link);
    }
    APPEND("\"firmware\": {\"program\": \"sil_bench\", \"mode\": \"inproc\", \"isr\": %llu, "
           "\"isr_no_data\": %llu, \"pwm_invalid\": %llu, \"rx_rejected\": %llu, \"rejects\": {",
           (unsigned long long)st.isr, (unsigned long long)st.isr_no_data,
           (unsigned long long)st.pwm_invalid, (unsigned long long)st.fw_rejected);
    for (k = 0; k < FWH_REJ_COUNT; k++) {
        APPEND("%s\"%s\": %llu", k ? ", " : "", fwh_reject_name(k),
               (unsigned long long)b->fw.cnt.rejects[k]);
    }
    APPEND("}, \"drive_cmds\": %llu, \"cmds_refused\": %llu, \"limits\": %llu, "
           "\"trace_records\": %llu, \"trace_errors\": %llu, \"fault_code\": %u, "
           "\"core_overruns\": %u}}",
           (unsigned long long)st.drive_cmds, (unsigned long long)st.cmds_refused,
           (unsigned long long)st.limits, (unsigned long long)st.trace_records,
           (unsigned long long)st.trace_errors, s.fault_code, s.isr_overruns);
    return (int)used;
}
