/* libFuzzer harness: hilbus' unixcan receive path (where a datagram enters every C program).
 * The input is a list of datagrams (a length byte, then that many bytes, up to 100: sizes
 * other than a frame's included), sent to a node's own socket; whatever hilbus_recv hands
 * on must be a frame a controller could send (a classic length <= 8, or a CAN FD length),
 * and every datagram is either handed on or counted as malformed. */
#define _POSIX_C_SOURCE 200809L /* setenv, getpid */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "hilbus.h"

static hilbus_t *node;
static int tx = -1;
static struct sockaddr_un to;

static void setup(void)
{
    char base[64], err[256];
    snprintf(base, sizeof base, "/tmp/hil-fuzz-dg-%ld", (long)getpid());
    setenv("UNIXCAN_DIR", base, 1);
    node = hilbus_open("unixcan", "dg", err, sizeof err);
    if (node == NULL) {
        fprintf(stderr, "fuzz: %s\n", err);
        abort();
    }
    memset(&to, 0, sizeof to);
    to.sun_family = AF_UNIX;
    /* the node's own socket: <base>/dg/<pid>-0.sock (the first node of this process) */
    snprintf(to.sun_path, sizeof to.sun_path, "%s/dg/%ld-0.sock", base, (long)getpid());
    tx = socket(AF_UNIX, SOCK_DGRAM, 0);
    if (tx < 0) {
        abort();
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t off = 0;
    hilbus_stats_t before, after;
    uint64_t sent = 0, delivered = 0;
    struct canfd_frame f;
    int fd;
    if (node == NULL) {
        setup();
    }
    hilbus_get_stats(node, &before);
    while (off < size) {
        size_t n = data[off++] % 101u;
        if (n > size - off) {
            n = size - off;
        }
        /* one at a time: the receiving queue holds only a few datagrams */
        if (sendto(tx, data + off, n, 0, (const struct sockaddr *)&to, sizeof to) != (ssize_t)n) {
            abort();
        }
        sent++;
        off += n;
        while (hilbus_recv(node, &f, &fd, 0) == 1) {
            delivered++;
            if (fd ? (f.len > CANFD_MAX_DLEN || hilbus_fd_len(f.len) != f.len)
                   : f.len > CAN_MAX_DLEN) {
                abort(); /* a frame no controller sends reached the program */
            }
        }
    }
    hilbus_get_stats(node, &after);
    if (delivered + (after.rx_malformed - before.rx_malformed) != sent) {
        abort(); /* a datagram neither delivered nor counted */
    }
    return 0;
}
