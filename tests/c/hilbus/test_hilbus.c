/* Unit tests of hilbus on one transport (argv[1]); several nodes in one process. */
#define _GNU_SOURCE
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "../check.h"
#include "hilbus.h"
#include "../../../hilbus/src/hilbus_internal.h"


static const char *transport;
static char channel[64];

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
    CHECK(hilbus_recv(b, &got, &fd, 1000000) == 1);
    CHECK(fd == 0 && got.can_id == 0x123 && got.len == 8 && memcmp(got.data, c.data, 8) == 0);
    CHECK(hilbus_send(a, &f, 1) == 0);
    CHECK(hilbus_recv(b, &got, &fd, 1000000) == 1);
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
            CHECK(hilbus_recv(b, &got, &fd, 1000000) == 1);
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
    CHECK(hilbus_recv(b, &got, &fd, 1000000) == 1);
    CHECK(got.can_id == 0x20A);
    double t0 = now_s();
    CHECK(hilbus_recv(b, &got, &fd, 50000) == 0); /* 0x310 was filtered: time-out */
    double waited = now_s() - t0;
    CHECK(waited >= 0.049 && waited < 1.0);
    CHECK(hilbus_set_filters(b, NULL, 0) == 0);
    CHECK(hilbus_send(a, &other, 0) == 0);
    CHECK(hilbus_recv(b, &got, &fd, 1000000) == 1 && got.can_id == 0x310);
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
    CHECK(hilbus_recv(alive, &got, &fd, 1000000) == 1 && got.can_id == 0x55);
    hilbus_stats_t s;
    hilbus_get_stats(a, &s);
    CHECK(s.peers_removed == 1 && s.tx_errors == 0);
    CHECK(access(dead->self.sun_path, F_OK) != 0);
    dead->kind = HILBUS_UNIXCAN;
    hilbus_close(dead);
    hilbus_close(a);
    hilbus_close(alive);
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
    char name[96];
    snprintf(name, sizeof name, "test_hilbus (%s)", transport);
    return check_report(name);
}
