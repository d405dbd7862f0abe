/* Unit tests of hilbus on one transport (argv[1]); several nodes in one process. */
#define _GNU_SOURCE
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <signal.h>
#include <sys/wait.h>

#include "../check.h"
#include "hilbus.h"
#include "../../../hilbus/src/hilbus_internal.h"

/* A ceiling, not a wait, for a frame already sent: it ends as soon as the frame is there and
 * only a broken bus reaches it (a loaded or emulated machine must not change the verdict). */
#define EVENT_US 60000000LL


static const char *transport;
static char channel[64];

static hilbus_t *node_flags(unsigned flags)
{
    char err[256];
    hilbus_t *b = hilbus_open_flags(transport, channel, flags, err, sizeof err);
    if (b == NULL) {
        fprintf(stderr, "open: %s\n", err);
        exit(2);
    }
    return b;
}

static hilbus_t *node(void)
{
    char err[256];
    hilbus_t *b = hilbus_open(transport, channel, err, sizeof err);
    if (b == NULL) {
        fprintf(stderr, "open: %s\n", err);
        exit(2);
    }
    return b;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static struct canfd_frame frame(canid_t id, uint8_t len, uint8_t seed)
{
    struct canfd_frame f;
    memset(&f, 0, sizeof f);
    f.can_id = id;
    f.len = len;
    for (int i = 0; i < len; i++) f.data[i] = (uint8_t)(seed + 7 * i);
    return f;
}

static void drain(hilbus_t *b)
{
    struct canfd_frame f;
    int fd;
    while (hilbus_recv(b, &f, &fd, 0) == 1) {}
}

static void test_classic_and_fd(void)
{
    hilbus_t *a = node(), *b = node();
    struct canfd_frame c = frame(0x123, 8, 1), f = frame(0x456, 64, 9), got;
    int fd = -1;
    CHECK(hilbus_send(a, &c, 0) == 0);
    CHECK(hilbus_recv(b, &got, &fd, EVENT_US) == 1);
    CHECK(fd == 0 && got.can_id == 0x123 && got.len == 8 && memcmp(got.data, c.data, 8) == 0);
    CHECK(hilbus_send(a, &f, 1) == 0);
    CHECK(hilbus_recv(b, &got, &fd, EVENT_US) == 1);
    CHECK(fd == 1 && got.can_id == 0x456 && got.len == 64 && memcmp(got.data, f.data, 64) == 0);
    /* the sender does not receive its own frames (SocketCAN default without RECV_OWN_MSGS) */
    CHECK(hilbus_recv(a, &got, &fd, 0) == 0);
    hilbus_close(a);
    hilbus_close(b);
}

static void test_order(void)
{
    hilbus_t *a = node(), *b = node();
    for (int round = 0; round < 50; round++) {
        for (int i = 0; i < 5; i++) {
            struct canfd_frame f = frame(0x100, 8, (uint8_t)(5 * round + i));
            CHECK(hilbus_send(a, &f, 0) == 0);
        }
        for (int i = 0; i < 5; i++) {
            struct canfd_frame got;
            int fd;
            CHECK(hilbus_recv(b, &got, &fd, EVENT_US) == 1);
            CHECK(got.data[0] == (uint8_t)(5 * round + i));
        }
    }
    hilbus_close(a);
    hilbus_close(b);
}

static void test_filters_and_timeout(void)
{
    hilbus_t *a = node(), *b = node();
    struct can_filter only = {.can_id = 0x200, .can_mask = 0x7F0};
    CHECK(hilbus_set_filters(b, &only, 1) == 0);
    struct canfd_frame other = frame(0x310, 4, 3), wanted = frame(0x20A, 4, 4), got;
    int fd;
    CHECK(hilbus_send(a, &other, 0) == 0);
    CHECK(hilbus_send(a, &wanted, 0) == 0);
    CHECK(hilbus_recv(b, &got, &fd, EVENT_US) == 1);
    CHECK(got.can_id == 0x20A);
    double t0 = now_s();
    CHECK(hilbus_recv(b, &got, &fd, 50000) == 0); /* 0x310 was filtered: time-out */
    double waited = now_s() - t0;
    CHECK(waited >= 0.049 && waited < EVENT_US * 1e-6); /* waited; the ceiling: no hang */
    CHECK(hilbus_set_filters(b, NULL, 0) == 0);
    CHECK(hilbus_send(a, &other, 0) == 0);
    CHECK(hilbus_recv(b, &got, &fd, EVENT_US) == 1 && got.can_id == 0x310);
    hilbus_close(a);
    hilbus_close(b);
}

static void test_invalid_frames(void)
{
    hilbus_t *a = node();
    struct canfd_frame bad_fd = frame(0x1, 13, 0), bad_classic = frame(0x1, 9, 0);
    errno = 0;
    CHECK(hilbus_send(a, &bad_fd, 1) == -1 && errno == EINVAL);
    CHECK(hilbus_send(a, &bad_classic, 0) == -1 && errno == EINVAL);
    hilbus_stats_t s;
    hilbus_get_stats(a, &s);
    CHECK(s.tx_errors == 2 && s.tx_frames == 0);
    CHECK(hilbus_fd_len(0) == 0 && hilbus_fd_len(8) == 8 && hilbus_fd_len(9) == 12);
    CHECK(hilbus_fd_len(33) == 48 && hilbus_fd_len(64) == 64);
    hilbus_close(a);
}

static void test_full_receiver_counts_drops(void)
{
    hilbus_t *a = node(), *b = node();
    const int n = 3000;
    for (int i = 0; i < n; i++) {
        struct canfd_frame f = frame(0x300, 64, (uint8_t)i);
        CHECK(hilbus_send(a, &f, 1) == 0);
    }
    int received = 0;
    struct canfd_frame got;
    int fd;
    while (hilbus_recv(b, &got, &fd, 0) == 1) received++;
    hilbus_stats_t sa, sb;
    hilbus_get_stats(a, &sa);
    hilbus_get_stats(b, &sb);
    /* b never read while a sent: the queue filled; every frame is either delivered or counted */
    CHECK(received < n);
    CHECK((uint64_t)received + sa.tx_drops + sb.rx_overflows == (uint64_t)n);
    hilbus_close(a);
    hilbus_close(b);
}

static void test_dead_peer_removed(void)
{
    if (strcmp(transport, "unixcan") != 0) return;
    hilbus_t *a = node(), *dead = node(), *alive = node();
    drain(alive);
    /* A killed node leaves its socket file behind with nobody reading it. */
    close(dead->sock);
    dead->sock = -1;
    struct canfd_frame f = frame(0x55, 2, 5), got;
    int fd;
    CHECK(hilbus_send(a, &f, 0) == 0);
    CHECK(hilbus_recv(alive, &got, &fd, EVENT_US) == 1 && got.can_id == 0x55);
    hilbus_stats_t s;
    hilbus_get_stats(a, &s);
    CHECK(s.peers_removed == 1 && s.tx_errors == 0);
    CHECK(access(dead->self.sun_path, F_OK) != 0);
    dead->kind = HILBUS_UNIXCAN;
    hilbus_close(dead);
    hilbus_close(a);
    hilbus_close(alive);
}

static const char *base_name(const char *path)
{
    const char *slash = strrchr(path, '/');
    return slash != NULL ? slash + 1 : path;
}

static struct canfd_frame numbered(canid_t id, int i)
{
    struct canfd_frame f = frame(id, 64, 0);
    memcpy(f.data, &i, sizeof i);
    return f;
}

/* n frames from b, numbered 0..n-1 in order (1), or 0 */
static int receive_numbered(hilbus_t *b, canid_t id, int n)
{
    for (int i = 0; i < n; i++) {
        struct canfd_frame got;
        int fd, k;
        if (hilbus_recv(b, &got, &fd, EVENT_US) != 1 || got.can_id != id) return 0;
        memcpy(&k, got.data, sizeof k);
        if (k != i) return 0;
    }
    return 1;
}

static void wait_byte(int fd)
{
    char c;
    while (read(fd, &c, 1) < 0 && errno == EINTR) {}
}

/* A lossless node that is slow to read loses nothing: the sender waits (back-pressure). */
static void test_lossless_receiver_loses_nothing(void)
{
    if (strcmp(transport, "unixcan") != 0) return;
    const int n = 3000;
    int ready[2];
    CHECK(pipe(ready) == 0);
    pid_t child = fork();
    if (child == 0) {
        hilbus_t *r = node_flags(HILBUS_LOSSLESS);
        CHECK(write(ready[1], "r", 1) == 1);
        struct timespec nap = {0, 100000000}; /* the sender meets a full queue meanwhile */
        nanosleep(&nap, NULL);
        const int ok = receive_numbered(r, 0x301, n);
        hilbus_close(r);
        _exit(ok ? 0 : 1);
    }
    wait_byte(ready[0]);
    hilbus_t *a = node();
    int sent = 0;
    for (int i = 0; i < n; i++) {
        struct canfd_frame f = numbered(0x301, i);
        sent += hilbus_send(a, &f, 1) == 0;
    }
    int status = 0;
    CHECK(waitpid(child, &status, 0) == child);
    CHECK(WIFEXITED(status) && WEXITSTATUS(status) == 0);
    hilbus_stats_t s;
    hilbus_get_stats(a, &s);
    CHECK(sent == n && s.tx_drops == 0 && s.tx_stall_failures == 0);
    CHECK(s.tx_stalls > 0 && s.tx_stall_ns_max > 0 && s.tx_stall_ns_total >= s.tx_stall_ns_max);
    hilbus_close(a);
    close(ready[0]);
    close(ready[1]);
}

/* Two lossless nodes that each send more than the other's queue holds before reading: each
 * takes its own deliveries while it waits, so both finish (no deadlock, nothing lost). */
static void test_lossless_nodes_waiting_on_each_other(void)
{
    if (strcmp(transport, "unixcan") != 0) return;
    const int n = 2000;
    int up[2], go[2];
    CHECK(pipe(up) == 0 && pipe(go) == 0);
    pid_t child = fork();
    if (child == 0) {
        hilbus_t *c = node_flags(HILBUS_LOSSLESS);
        CHECK(write(up[1], "c", 1) == 1);
        wait_byte(go[0]);
        int ok = 1;
        for (int i = 0; i < n && ok; i++) { /* (a failed wait ends it: 5 s each) */
            struct canfd_frame f = numbered(0x402, i);
            ok &= hilbus_send(c, &f, 1) == 0;
        }
        ok = ok && receive_numbered(c, 0x401, n);
        hilbus_close(c);
        _exit(ok ? 0 : 1);
    }
    wait_byte(up[0]);
    hilbus_t *p = node_flags(HILBUS_LOSSLESS);
    CHECK(write(go[1], "g", 1) == 1);
    int sent = 0;
    for (int i = 0; i < n && sent == i; i++) { /* (a failed wait ends it: 5 s each) */
        struct canfd_frame f = numbered(0x401, i);
        sent += hilbus_send(p, &f, 1) == 0;
    }
    CHECK(sent == n);
    CHECK(sent == n && receive_numbered(p, 0x402, n));
    int status = 0;
    CHECK(waitpid(child, &status, 0) == child);
    CHECK(WIFEXITED(status) && WEXITSTATUS(status) == 0);
    hilbus_stats_t s;
    hilbus_get_stats(p, &s);
    CHECK(s.tx_drops == 0 && s.tx_stall_failures == 0);
    CHECK(hilbus_pending(p) == 0);
    hilbus_close(p);
    close(up[0]);
    close(up[1]);
    close(go[0]);
    close(go[1]);
}

/* A lossless node that never reads: the stop flag ends the wait at once (EINTR); otherwise the
 * send fails after the stall limit (ETIMEDOUT) with an error naming the node. */
static void test_lossless_stall_is_bounded_and_named(void)
{
    if (strcmp(transport, "unixcan") != 0) return;
    hilbus_t *stuck = node_flags(HILBUS_LOSSLESS), *a = node(), *listener = node();
    volatile sig_atomic_t stop = 1;
    hilbus_set_stop(a, &stop);
    int rc = 0, i = 0;
    double t0 = now_s();
    for (; i < 100 && rc == 0; i++) {
        struct canfd_frame f = numbered(0x500, i);
        rc = hilbus_send(a, &f, 1);
    }
    CHECK(rc == -1 && errno == EINTR && now_s() - t0 < 2.0);
    stop = 0;
    t0 = now_s();
    struct canfd_frame f = numbered(0x500, i);
    rc = hilbus_send(a, &f, 1);
    const int err = errno;
    const double waited = now_s() - t0;
    CHECK(rc == -1 && err == ETIMEDOUT);
    CHECK(waited >= HIL_UNIXCAN_LOSSLESS_STALL_NS * 1e-9 * 0.99 &&
          waited < HIL_UNIXCAN_LOSSLESS_STALL_NS * 1e-9 + 5.0);
    char pid[32];
    snprintf(pid, sizeof pid, "(pid %ld)", (long)getpid());
    CHECK(strstr(hilbus_last_error(a), base_name(stuck->self.sun_path)) != NULL);
    CHECK(strstr(hilbus_last_error(a), pid) != NULL);
    CHECK(strstr(hilbus_last_error(a), "loses no frame") != NULL);
    hilbus_stats_t s;
    hilbus_get_stats(a, &s);
    CHECK(s.tx_stall_failures == 1);
    /* the other node (a listener that did not read either) still got frames: the wait for one
     * node does not keep them from the others */
    struct canfd_frame got;
    int fd, k = 0;
    while (hilbus_recv(listener, &got, &fd, 0) == 1) k++;
    CHECK(k > 0);
    hilbus_close(stuck);
    hilbus_close(a);
    hilbus_close(listener);
}

/* A listener that falls behind misses frames, counted for it by its socket's name. */
static void test_listener_drops_are_named(void)
{
    if (strcmp(transport, "unixcan") != 0) return;
    hilbus_t *listener = node(), *a = node_flags(HILBUS_LOSSLESS);
    for (int i = 0; i < 200; i++) {
        struct canfd_frame f = numbered(0x600, i);
        CHECK(hilbus_send(a, &f, 1) == 0);
    }
    hilbus_stats_t s;
    hilbus_get_stats(a, &s);
    const char *name = NULL;
    uint64_t drops = 0;
    CHECK(s.tx_drops > 0 && s.tx_stalls == 0);
    CHECK(hilbus_listener_drops(a, 0, &name, &drops) == 1);
    CHECK(name != NULL && strcmp(name, base_name(listener->self.sun_path)) == 0);
    CHECK(drops == s.tx_drops);
    CHECK(hilbus_listener_drops(a, 1, &name, &drops) == 0);
    /* and its name does not say lossless; the lossless node's does */
    CHECK(strstr(listener->self.sun_path, HIL_UNIXCAN_LOSSLESS_MARK) == NULL);
    CHECK(strstr(a->self.sun_path, HIL_UNIXCAN_LOSSLESS_MARK HIL_UNIXCAN_SOCKET_SUFFIX) != NULL);
    hilbus_close(listener);
    hilbus_close(a);
}

int main(int argc, char **argv)
{
    transport = argc > 1 ? argv[1] : "unixcan";
    snprintf(channel, sizeof channel, "%s", argc > 2 ? argv[2] : "test_hilbus");
    test_classic_and_fd();
    test_order();
    test_filters_and_timeout();
    test_invalid_frames();
    test_full_receiver_counts_drops();
    test_dead_peer_removed();
    test_listener_drops_are_named();
    test_lossless_receiver_loses_nothing();
    test_lossless_nodes_waiting_on_each_other();
    test_lossless_stall_is_bounded_and_named();
    char name[96];
    snprintf(name, sizeof name, "test_hilbus (%s)", transport);
    return check_report(name);
}
