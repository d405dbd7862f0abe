/* Rate limit for the diagnostic lines the rig's programs write to stderr (rejected frames,
 * protocol errors): a node fed garbage at 10 kHz must not spend its period writing a log.
 * At most `lines_per_s` lines per one-second window; when a window ends, one line says how
 * many were left out, so nothing disappears without a trace. */
#ifndef HIL_LOG_LIMIT_H
#define HIL_LOG_LIMIT_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    const char *prog;         /* prefix of the "(N more messages not logged)" line */
    int lines_per_s;
    int64_t window_start_ns;  /* monotonic clock */
    int lines;                /* written in this window */
    uint64_t suppressed;      /* left out in this window */
} hil_log_limit_t;

void hil_log_limit_init(hil_log_limit_t *l, const char *prog, int lines_per_s, int64_t now_ns);

/* 1 when one more line may be written now (and counts it), 0 when it must be left out. */
int hil_log_limit_allow(hil_log_limit_t *l, int64_t now_ns);

#ifdef __cplusplus
}
#endif
#endif
