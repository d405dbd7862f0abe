/* pty.h - the SCI console's serial line, emulated by a pseudo-terminal.
 *
 * The master side belongs to fw_host; a client (pyserial, screen, minicom) opens the slave,
 * found through an optional symbolic link. The line is set to raw mode, 115200 8N1 with
 * termios exactly as the DSP's SCI is configured (the rate means nothing on a pty). Output
 * is queued (FWH_PTY_OUT_MAX bytes) and written as the client reads; what does not fit is
 * dropped and counted (the console queues one reply at a time, far less: main.c takes the
 * next line only when the last reply is out). A client hanging up is reported so the console can end its session.
 */
#ifndef PTY_H
#define PTY_H

#include <stddef.h>
#include <stdint.h>

#define FWH_PTY_OUT_MAX 32768
#define FWH_PTY_PATH_MAX 4096

typedef struct {
    int master;               /* -1 when closed */
    char slave_path[64];
    char link[FWH_PTY_PATH_MAX]; /* "" when no link was asked for */
    char out[FWH_PTY_OUT_MAX];
    size_t out_len;
    uint64_t out_dropped;     /* bytes */
} fwh_pty_t;

/* Opens the master, configures the line and creates the link (atomically replacing an
 * existing link or file). 0, or -1 with err set. */
int fwh_pty_open(fwh_pty_t *p, const char *link, char *err, size_t errlen);
/* Removes the link (if it still points to this pty) and closes the master. */
void fwh_pty_close(fwh_pty_t *p);
/* Reads what is there (non-blocking): > 0 bytes, 0 nothing, -1 hung up (no client). */
int fwh_pty_read(fwh_pty_t *p, char *buf, size_t len);
/* Queues bytes and writes as much as the line takes now. */
void fwh_pty_write(fwh_pty_t *p, const char *data, size_t len);
/* Writes queued output; call when poll() reports POLLOUT. */
void fwh_pty_flush(fwh_pty_t *p);
/* Drops queued output (the client went away). */
void fwh_pty_discard(fwh_pty_t *p);

#endif
