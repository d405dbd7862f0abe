/* host_log.c - fw_host's names (states, faults; rejections are in rx_reject.c), its
 * rejection and log lines (rate-limited on stderr, or each to the sink's log), and the ways
 * out of the frame handlers: the sink and the core's entries. Apart from main.c so that
 * everything running the handlers (the unit tests, the fuzz harnesses, the in-process
 * bench) has them. */
#include <stdarg.h>
#include <stdio.h>

#include "fw_host.h"
#include "hil_wire.h"

/* The names are drive.dbc's value tables (DRIVE_STATUS.state, .fault_code). */
const char *fwh_state_name(int16_t state)
{
    const char *n = hil_drive_drive_status_state_name(state);
    return n != NULL ? n : "?";
}

const char *fwh_fault_name(uint16_t code)
{
    const char *n = hil_drive_drive_status_fault_code_name(code);
    return n != NULL ? n : "UNKNOWN";
}

uint64_t fwh_rejected_total(const fwh_t *a)
{
    uint64_t n = 0;
    int k;
    for (k = 0; k < FWH_REJ_COUNT; k++) {
        n += a->cnt.rejects[k];
    }
    return n;
}

static int log_allowed(fwh_t *a)
{
    return hil_log_limit_allow(&a->log_limit, hil_now_ns());
}

/* One line, prefix then the formatted text: to the sink's log, else to stderr when the rate
 * limit allows. */
static void line(fwh_t *a, const char *prefix, const char *fmt, va_list ap)
{
    if (a->sink.log != NULL) {
        char text[512];
        const int n = snprintf(text, sizeof(text), "%s", prefix);
        vsnprintf(text + n, sizeof(text) - (size_t)n, fmt, ap);
        a->sink.log(a->sink.ctx, text);
        return;
    }
    if (!log_allowed(a)) {
        return;
    }
    fprintf(stderr, "fw_host: %s", prefix);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
}

void fwh_reject(fwh_t *a, int reason, const char *fmt, ...)
{
    char prefix[64];
    va_list ap;
    a->cnt.rejects[reason]++;
    snprintf(prefix, sizeof(prefix), "rejected (%s): ", fwh_reject_name(reason));
    va_start(ap, fmt);
    line(a, prefix, fmt, ap);
    va_end(ap);
}

void fwh_log(fwh_t *a, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    line(a, "", fmt, ap);
    va_end(ap);
}

int fwh_send(fwh_t *a, const struct canfd_frame *f, int fd)
{
    return a->sink.send != NULL ? a->sink.send(a->sink.ctx, f, fd) : -1;
}

void fwh_core_isr(fwh_t *a, const fw_adc_t *adc, fw_pwm_t *pwm)
{
    if (a->calls.isr != NULL) {
        a->calls.isr(a->calls.ctx, &a->core, adc, pwm);
    } else {
        fw_core_isr(&a->core, adc, pwm);
    }
}

int16_t fwh_core_command(fwh_t *a, const fw_cmd_t *cmd)
{
    return a->calls.command != NULL ? a->calls.command(a->calls.ctx, &a->core, cmd)
                                    : fw_core_command(&a->core, cmd);
}

int16_t fwh_core_limits(fwh_t *a, real_t i_max, real_t speed_max_rpm, real_t accel_rpm_s)
{
    return a->calls.limits != NULL
               ? a->calls.limits(a->calls.ctx, &a->core, i_max, speed_max_rpm, accel_rpm_s)
               : fw_core_set_limits(&a->core, i_max, speed_max_rpm, accel_rpm_s);
}
