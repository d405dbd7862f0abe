/* fw_host.h - the host HAL: the control core as a Linux process on the bus.
 *
 * One thread, one poll() over the bus, the console's pseudo-terminal and a 10 ms timer.
 * The ISR runs when the ADC data of a PWM period is complete (bus_io.c); the drive protocol
 * (drive_protocol.c) and the SCI console (console.c) act on the core between ISRs, as the
 * background loop of the DSP does.
 *
 * The frame handlers (bus_io.c, drive_protocol.c) know no bus: they send through the sink
 * in their state, so fw_host (main.c: the bus), the in-process bench (bench/: its plant) and
 * the fuzz harnesses (nowhere) run the same handlers.
 */
#ifndef FW_HOST_H
#define FW_HOST_H

#include <stdint.h>

#include "adc_assembly.h"
#include "fw_core.h"
#include "hil_wire.h"
#include "hilnode.h" /* the bus, trace, log limit, node options */
#include "pty.h"
#include "rx_reject.h"

#define FWH_VERSION "1.0"
#define FWH_STATUS_PERIOD_NS (100LL * 1000000LL) /* DRIVE_STATUS, HEARTBEAT */
#define FWH_TICK_NS (10LL * 1000000LL)           /* housekeeping timer */
#define FWH_OVERRUN_NS HIL_PERIOD_NS             /* ADC received -> PWM sent, real time */

enum { FWH_OWNER_NONE, FWH_OWNER_CAN, FWH_OWNER_CONSOLE };

typedef struct {
    hil_node_opts_t node; /* --bus, --channel, pacing, --trace, --ready-file, ... (hilnode.h) */
    int send_trace;
    const char *params;
    const char *pty_link;
    int no_console;
    int64_t console_timeout_ns; /* 0: a console session lasts until the client hangs up */
    uint32_t tlm_div;           /* telemetry every 10*tlm_div periods; 0 = off */
    int32_t spin_us;
    uint8_t node_number;  /* --node: the HEARTBEAT node */
    int64_t first_period; /* --first-period, or -1: the first ADC period may be any */
} fwh_options_t;

/* Where the handlers' frames and lines go. send: 0 sent, -1 lost (FW_TRACE counts its
 * losses; the owner of the sink counts the rest). log: a rejection ("rejected (REASON):
 * why") or log line, each one; NULL: stderr, at most 10 lines a second (log_limit). */
typedef struct {
    int (*send)(void *ctx, const struct canfd_frame *f, int fd);
    void (*log)(void *ctx, const char *line);
    void *ctx;
} fwh_sink_t;

/* The control core's entries the handlers call, for an owner that watches them (the
 * in-process bench journals and times them, and edits the ADC data under test). A NULL
 * member: the core's own function. */
typedef struct {
    void (*isr)(void *ctx, fw_core_t *core, const fw_adc_t *adc, fw_pwm_t *pwm);
    int16_t (*command)(void *ctx, fw_core_t *core, const fw_cmd_t *cmd);
    int16_t (*limits)(void *ctx, fw_core_t *core, real_t i_max, real_t speed_max_rpm,
                      real_t accel_rpm_s);
    void *ctx;
} fwh_core_calls_t;

typedef struct {
    uint64_t rejects[FWH_REJ_COUNT];
    uint64_t isr, isr_no_data, repeats, pwm_sent, pwm_invalid, overruns, resyncs, syncs;
    uint64_t non_data_frames; /* extended, remote or error frames: not this protocol's */
    int64_t max_latency_ns;
    uint64_t drive_cmds, cmds_refused, limits, param_reqs, status_frames, heartbeats;
    uint64_t tlm_frames, trace_records, trace_sent, trace_errors;
    uint64_t console_lines, console_errors, console_sessions, console_keepalive_lapses;
    uint64_t fw_trace_tx_errors;
} fwh_counters_t;

/* what DRIVE_STATUS last carried (sent again on any change) */
typedef struct {
    int valid;
    int16_t state, ctrl_mode, fw_mode, cmd_status, polarity_ok, est_valid;
    uint16_t fault_code;
} fwh_status_key_t;

typedef struct fwh {
    fwh_options_t opt;
    fw_core_t core;
    fwh_sink_t sink;
    fwh_core_calls_t calls;
    hiltrace_t *trace;
    fwh_adc_asm_t adc;
    fwh_pty_t pty;
    int pty_open;
    int console_connected;     /* a session: bytes came since the last hang-up */
    int console_hup;           /* the line reported a hang-up: probed every 10 ms */
    int64_t console_retry_ns;
    int64_t console_last_ns;   /* last line received (keep-alive) */
    int console_refreshing;    /* the session's command is being refreshed every ISR */
    char console_in[512];      /* input read but not taken yet (a reply was still queued) */
    size_t console_in_off, console_in_len;
    /* the command both sources write (last writer wins) */
    fw_cmd_t cmd;
    int owner;
    /* timing */
    int64_t t0_ns, next_status_ns, next_heartbeat_ns;
    uint8_t alive;
    fwh_status_key_t sent;
    hil_log_limit_t log_limit; /* rejection and protocol lines on stderr */
    fwh_counters_t cnt;
    const char *rt_note;
    volatile sig_atomic_t stop;
} fwh_t;

const char *fwh_state_name(int16_t state);
const char *fwh_fault_name(uint16_t code);
uint64_t fwh_rejected_total(const fwh_t *app);
/* Counts a rejection and logs it (at most 10 lines a second, then a summary). */
void fwh_reject(fwh_t *app, int reason, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
void fwh_log(fwh_t *app, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* A frame out through the sink: 0 sent, -1 lost. */
int fwh_send(fwh_t *app, const struct canfd_frame *f, int fd);
/* The core's entries through app->calls (the core's own functions when NULL). */
void fwh_core_isr(fwh_t *app, const fw_adc_t *adc, fw_pwm_t *pwm);
int16_t fwh_core_command(fwh_t *app, const fw_cmd_t *cmd);
int16_t fwh_core_limits(fwh_t *app, real_t i_max, real_t speed_max_rpm, real_t accel_rpm_s);

/* bus_io.c: virtual I/O (ADC in, PWM out, FW_TRACE, telemetry); a frame whose id is in
 * vio.dbc's range (hil_vio_id_in_range, hil_wire.h) */
void fwh_bus_vio_frame(fwh_t *app, const struct canfd_frame *f, int fd, int64_t t_rx_ns);

/* drive_protocol.c: frames whose id is in drive.dbc's range (hil_drive_id_in_range) */
void fwh_drive_frame(fwh_t *app, const struct canfd_frame *f, int fd);
void fwh_drive_send_status(fwh_t *app);
void fwh_drive_send_heartbeat(fwh_t *app);
void fwh_drive_status_if_changed(fwh_t *app);
void fwh_drive_telemetry(fwh_t *app, const fw_status_t *s);
/* SAVE / LOAD of the parameter file (shared by PARAM_REQ and the console). msg gets a
 * human-readable reason on failure. Returns FW_STATUS_* (FW_STATUS_STORE_ERROR: the file). */
int fwh_params_save_store(fwh_t *app, int *count, char *msg, size_t msglen);
int fwh_params_load_store(fwh_t *app, int *count, char *msg, size_t msglen);
/* Sends a drive command to the core on behalf of a source; updates owner on success. */
int16_t fwh_command(fwh_t *app, const fw_cmd_t *cmd, int owner);
/* Called before every ISR: keeps a live console session's command fresh. */
void fwh_command_refresh(fwh_t *app, int64_t now_ns);

/* console.c */
/* Takes console input line by line; stops after a line whose reply is still queued (the
 * client has not read it yet) and returns the bytes taken: the caller keeps the rest and
 * reads nothing more from the line until the reply is out (backpressure). */
size_t fwh_console_input(fwh_t *app, const char *data, size_t len, int64_t now_ns);
void fwh_console_hangup(fwh_t *app);

#endif
