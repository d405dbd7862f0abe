/* hiltrace: the per-process binary trace of the lossless capture (docs/interfaces.md).
 * A 16-byte header ("HILTRACE", u32 version 1, u32 record size 72) followed by records
 * that are exactly struct canfd_frame, each holding one DBC message. Buffered; flushed on
 * close. */
#ifndef HILTRACE_H
#define HILTRACE_H

#include <linux/can.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hiltrace hiltrace_t;

/* Creates (truncates) path. NULL with errno set on failure. */
hiltrace_t *hiltrace_open(const char *path);
/* Appends one record. Returns 0, or -1 on a write error (sticky; see hiltrace_close). */
int hiltrace_write(hiltrace_t *trace, const struct canfd_frame *frame);
/* Flushes to the kernel (not fsync). */
int hiltrace_flush(hiltrace_t *trace);
/* Flushes and closes. Returns 0 if every write succeeded, -1 otherwise. */
int hiltrace_close(hiltrace_t *trace);

#ifdef __cplusplus
}
#endif
#endif
