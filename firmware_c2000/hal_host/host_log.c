/* host_log.c - fw_host's names (states, faults; rejections are in rx_reject.c) and its rate-limited
 * rejection and log lines on stderr. Apart from main.c so that everything linking the host
 * HAL (the unit tests, the fuzz harnesses) has them. */
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

void fwh_reject(fwh_t *a, int reason, const char *fmt, ...)
{
    va_list ap;
    a->cnt.rejects[reason]++;
    if (!log_allowed(a)) {
        return;
    }
    fprintf(stderr, "fw_host: rejected (%s): ", fwh_reject_name(reason));
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
}

void fwh_log(fwh_t *a, const char *fmt, ...)
{
    va_list ap;
    if (!log_allowed(a)) {
        return;
    }
    fputs("fw_host: ", stderr);
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
}
