/* hilbus_tool: send, receive, echo and ping CAN frames over hilbus.
 * Used by the cross-language bus tests and by `rig bench bus`. Output is JSON lines. */
#define _GNU_SOURCE
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "hilbus.h"

#define PING_ID 0x7A0u
#define PONG_ID 0x7A1u
#define MAX_SAMPLES 1000000

static volatile sig_atomic_t stop_requested;
static void on_signal(int sig) { (void)sig; stop_requested = 1; }

static void usage(FILE *out)
{
    fprintf(out,
            "usage: hilbus_tool MODE [options]\n"
            "modes:\n"
            "  send   send frames:       --id ID [--fd] [--data HEX] [--count N] [--interval-us U] [--brs]\n"
            "  recv   print frames:      [--filter ID:MASK]... [--count N] [--timeout-ms T]\n"
            "  echo   answer pings:      frames with id 0x7A0 are sent back as 0x7A1\n"
            "  ping   round-trip timing: [--count N] [--fd] [--window W] [--timeout-ms T]\n"
            "  dir    open the bus and print its unixcan folder: {\"dir\": PATH, \"max_peers\": N}\n"
            "  wire   print the unixcan wire facts hilbus was built with, the FD length of 0..64\n"
            "         bytes, and its verdict on each channel name read from stdin (hex, one a line)\n"
            "common:  --bus socketcan|unixcan|auto (default auto)  --channel NAME (default vcan0)\n"
            "         --ready-file PATH (written once the bus is open)\n"
            "         --lossless (unixcan: a node every sender waits for, as a lockstep run's)\n"
            "Output: one JSON object per line on stdout; errors on stderr, exit 1.\n");
}

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static int parse_hex(const char *hex, unsigned char *out, size_t max)
{
    size_t len = strlen(hex);
    if (len % 2 != 0 || len / 2 > max) return -1;
    for (size_t i = 0; i < len / 2; i++) {
        unsigned int v;
        if (sscanf(hex + 2 * i, "%2x", &v) != 1) return -1;
        out[i] = (unsigned char)v;
    }
    return (int)(len / 2);
}

static void print_frame(const struct canfd_frame *f, int fd)
{
    printf("{\"id\": %u, \"fd\": %s, \"len\": %u, \"data\": \"", f->can_id & CAN_EFF_MASK, fd ? "true" : "false",
           f->len);
    for (int i = 0; i < f->len; i++) printf("%02x", f->data[i]);
    printf("\"}\n");
    fflush(stdout);
}

static void print_stats(const hilbus_t *bus)
{
    hilbus_stats_t s;
    hilbus_get_stats(bus, &s);
    printf("{\"stats\": {\"transport\": \"%s\", \"tx_frames\": %llu, \"tx_drops\": %llu, \"tx_errors\": %llu, "
           "\"rx_frames\": %llu, \"rx_overflows\": %llu, \"rx_filtered\": %llu, \"peers_removed\": %llu, "
           "\"rx_malformed\": %llu, \"foreign_entries\": %llu, \"peers_beyond_limit\": %llu, "
           "\"tx_stalls\": %llu, \"tx_stall_ms_max\": %.3f, \"tx_stall_ms_total\": %.3f, "
           "\"tx_stall_failures\": %llu, \"rx_pending_max\": %llu, \"listener_drops\": {",
           hilbus_transport(bus), (unsigned long long)s.tx_frames, (unsigned long long)s.tx_drops,
           (unsigned long long)s.tx_errors, (unsigned long long)s.rx_frames, (unsigned long long)s.rx_overflows,
           (unsigned long long)s.rx_filtered, (unsigned long long)s.peers_removed,
           (unsigned long long)s.rx_malformed, (unsigned long long)s.foreign_entries,
           (unsigned long long)s.peers_beyond_limit, (unsigned long long)s.tx_stalls,
           (double)s.tx_stall_ns_max * 1e-6, (double)s.tx_stall_ns_total * 1e-6,
           (unsigned long long)s.tx_stall_failures, (unsigned long long)s.rx_pending_max);
    const char *name;
    uint64_t drops;
    for (int i = 0; hilbus_listener_drops(bus, i, &name, &drops); i++)
        printf("%s\"%s\": %llu", i ? ", " : "", name, (unsigned long long)drops);
    printf("}}}\n");
    fflush(stdout);
}

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

static int run_ping(hilbus_t *bus, long count, int fd, int window, int64_t timeout_us)
{
    if (count < 1 || count > MAX_SAMPLES || window < 1 || window > 64) {
        fprintf(stderr, "hilbus_tool: ping needs 1 <= count <= %d and 1 <= window <= 64\n", MAX_SAMPLES);
        return 1;
    }
    int64_t *rtt = calloc((size_t)count, sizeof *rtt);
    int64_t *sent_at = calloc((size_t)count, sizeof *sent_at);
    if (rtt == NULL || sent_at == NULL) return 1;
    struct can_filter pong = {.can_id = PONG_ID, .can_mask = CAN_SFF_MASK};
    hilbus_set_filters(bus, &pong, 1);
    long next = 0, done = 0, lost = 0;
    int64_t t_start = now_ns();
    while (done + lost < count && !stop_requested) {
        while (next < count && next - done - lost < window) {
            struct canfd_frame f;
            memset(&f, 0, sizeof f);
            f.can_id = PING_ID;
            f.len = fd ? 64 : 8;
            memcpy(f.data, &next, sizeof next);
            sent_at[next] = now_ns();
            if (hilbus_send(bus, &f, fd) != 0) {
                fprintf(stderr, "hilbus_tool: send: %s\n", strerror(errno));
                return 1;
            }
            next++;
        }
        struct canfd_frame r;
        int rfd;
        int got = hilbus_recv(bus, &r, &rfd, timeout_us);
        if (got < 0) return 1;
        if (got == 0) { /* the oldest outstanding ping is lost */
            lost++;
            continue;
        }
        long seq;
        memcpy(&seq, r.data, sizeof seq);
        if (seq < 0 || seq >= next || rtt[seq] != 0) continue;
        rtt[seq] = now_ns() - sent_at[seq];
        done++;
    }
    double elapsed = (double)(now_ns() - t_start) * 1e-9;
    long n = 0;
    for (long i = 0; i < count; i++)
        if (rtt[i] > 0) rtt[n++] = rtt[i];
    qsort(rtt, (size_t)n, sizeof *rtt, cmp_i64);
    hilbus_stats_t s;
    hilbus_get_stats(bus, &s);
    if (n == 0) {
        printf("{\"transport\": \"%s\", \"fd\": %s, \"count\": %ld, \"received\": 0, \"lost\": %ld}\n",
               hilbus_transport(bus), fd ? "true" : "false", count, lost);
    } else {
        printf("{\"transport\": \"%s\", \"fd\": %s, \"window\": %d, \"count\": %ld, \"received\": %ld, \"lost\": %ld, "
               "\"rtt_us\": {\"min\": %.2f, \"median\": %.2f, \"p99\": %.2f, \"max\": %.2f}, "
               "\"frames_per_s\": %.0f, \"tx_drops\": %llu}\n",
               hilbus_transport(bus), fd ? "true" : "false", window, count, n, lost, rtt[0] * 1e-3,
               rtt[n / 2] * 1e-3, rtt[(n * 99) / 100 < n ? (n * 99) / 100 : n - 1] * 1e-3, rtt[n - 1] * 1e-3,
               2.0 * (double)n / elapsed, (unsigned long long)s.tx_drops);
    }
    free(rtt);
    free(sent_at);
    return lost == 0 ? 0 : 3;
}

/* `wire`: what hilbus holds of protocols/unixcan.toml, for tests/python/bus/test_unixcan_wire.py
 * to hold against the description and the Python side. No bus is opened. */
static int wire_mode(void)
{
    static const unsigned char fd_lengths[] = HIL_UNIXCAN_FD_LENGTHS;
    printf("{\"classic_size\": %d, \"fd_size\": %d, \"id_offset\": %d, \"len_offset\": %d, "
           "\"flags_offset\": %d, \"data_offset\": %d, \"classic_max_len\": %d, \"fd_max_len\": %d, ",
           HIL_UNIXCAN_CLASSIC_SIZE, HIL_UNIXCAN_FD_SIZE, HIL_UNIXCAN_ID_OFFSET, HIL_UNIXCAN_LEN_OFFSET,
           HIL_UNIXCAN_FLAGS_OFFSET, HIL_UNIXCAN_DATA_OFFSET, HIL_UNIXCAN_CLASSIC_MAX_LEN,
           HIL_UNIXCAN_FD_MAX_LEN);
    printf("\"fd_lengths\": [");
    for (size_t i = 0; i < sizeof fd_lengths; i++) printf("%s%u", i ? ", " : "", fd_lengths[i]);
    printf("], \"fd_len\": [");
    for (size_t n = 0; n <= HIL_UNIXCAN_FD_MAX_LEN; n++) printf("%s%u", n ? ", " : "", hilbus_fd_len(n));
    printf("], \"eff_flag\": %lu, \"rtr_flag\": %lu, \"err_flag\": %lu, \"sff_mask\": %lu, "
           "\"eff_mask\": %lu, \"brs\": %u, \"esi\": %u, \"fdf\": %u, ",
           (unsigned long)HIL_UNIXCAN_EFF_FLAG, (unsigned long)HIL_UNIXCAN_RTR_FLAG,
           (unsigned long)HIL_UNIXCAN_ERR_FLAG, (unsigned long)HIL_UNIXCAN_SFF_MASK,
           (unsigned long)HIL_UNIXCAN_EFF_MASK, HIL_UNIXCAN_BRS, HIL_UNIXCAN_ESI, HIL_UNIXCAN_FDF);
    printf("\"lossless_mark\": \"%s\", \"lossless_stall_ns\": %lld, ", HIL_UNIXCAN_LOSSLESS_MARK,
           HIL_UNIXCAN_LOSSLESS_STALL_NS);
    printf("\"channel_rule\": \"%s\", \"socket_suffix\": \"%s\", \"c_tag\": \"%s\", "
           "\"folder_mode\": %d, \"group_folder_mode\": %d, \"socket_mode\": %d, "
           "\"group_socket_mode\": %d, \"rescan_interval_ns\": %lld, \"full_peer_grace_ns\": %lld, ",
           HIL_UNIXCAN_CHANNEL_RULE, HIL_UNIXCAN_SOCKET_SUFFIX, HIL_UNIXCAN_C_TAG, HIL_UNIXCAN_FOLDER_MODE,
           HIL_UNIXCAN_GROUP_FOLDER_MODE, HIL_UNIXCAN_SOCKET_MODE, HIL_UNIXCAN_GROUP_SOCKET_MODE,
           HIL_UNIXCAN_RESCAN_INTERVAL_NS, HIL_UNIXCAN_FULL_PEER_GRACE_NS);
    printf("\"names_ok\": [");
    char line[1024];
    int first = 1;
    while (fgets(line, sizeof line, stdin) != NULL) {
        char name[sizeof line / 2 + 1];
        line[strcspn(line, "\r\n")] = '\0';
        int n = parse_hex(line, (unsigned char *)name, sizeof name - 1);
        if (n < 0) {
            fprintf(stderr, "hilbus_tool: wire: a name is hex, at most %zu bytes\n", sizeof name - 1);
            return 2;
        }
        name[n] = '\0';
        printf("%s%d", first ? "" : ", ", hilbus_channel_name_ok(name));
        first = 0;
    }
    printf("]}\n");
    return 0;
}

int main(int argc, char **argv)
{
    if (argc < 2 || strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
        usage(argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    const char *mode = argv[1];
    if (strcmp(mode, "wire") == 0) return wire_mode();
    const char *transport = "auto", *channel = "vcan0", *data_hex = "", *ready_file = NULL;
    long count = 1, interval_us = 0, timeout_ms = 1000;
    unsigned long id = 0;
    int fd = 0, brs = 0, window = 1, n_filters = 0;
    unsigned flags = 0;
    struct can_filter filters[16];
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--fd") == 0) { fd = 1; continue; }
        if (strcmp(a, "--brs") == 0) { brs = 1; continue; }
        if (strcmp(a, "--lossless") == 0) { flags |= HILBUS_LOSSLESS; continue; }
        if (strcmp(a, "--help") == 0) { usage(stdout); return 0; }
        if (v == NULL) { fprintf(stderr, "hilbus_tool: %s needs a value\n", a); return 2; }
        i++;
        char *end = NULL;
        if (strcmp(a, "--bus") == 0) transport = v;
        else if (strcmp(a, "--channel") == 0) channel = v;
        else if (strcmp(a, "--data") == 0) data_hex = v;
        else if (strcmp(a, "--ready-file") == 0) ready_file = v;
        else if (strcmp(a, "--id") == 0) id = strtoul(v, &end, 0);
        else if (strcmp(a, "--count") == 0) count = strtol(v, &end, 0);
        else if (strcmp(a, "--interval-us") == 0) interval_us = strtol(v, &end, 0);
        else if (strcmp(a, "--timeout-ms") == 0) timeout_ms = strtol(v, &end, 0);
        else if (strcmp(a, "--window") == 0) window = (int)strtol(v, &end, 0);
        else if (strcmp(a, "--filter") == 0) {
            unsigned int fid, fmask;
            if (n_filters >= 16 || sscanf(v, "%x:%x", &fid, &fmask) != 2) {
                fprintf(stderr, "hilbus_tool: --filter takes HEXID:HEXMASK (at most 16)\n");
                return 2;
            }
            filters[n_filters].can_id = fid;
            filters[n_filters].can_mask = fmask;
            n_filters++;
        } else {
            fprintf(stderr, "hilbus_tool: unknown option %s\n", a);
            return 2;
        }
        if (end != NULL && *end != '\0') { fprintf(stderr, "hilbus_tool: bad number for %s: %s\n", a, v); return 2; }
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);

    char err[256];
    hilbus_t *bus = hilbus_open_flags(transport, channel, flags, err, sizeof err);
    if (bus == NULL) {
        fprintf(stderr, "hilbus_tool: %s\n", err);
        return 1;
    }
    hilbus_set_stop(bus, &stop_requested);
    if (n_filters > 0 && hilbus_set_filters(bus, filters, n_filters) != 0) {
        fprintf(stderr, "hilbus_tool: filters: %s\n", strerror(errno));
        return 1;
    }
    if (ready_file != NULL) {
        FILE *rf = fopen(ready_file, "w");
        if (rf != NULL) {
            fprintf(rf, "%s\n", hilbus_transport(bus));
            fclose(rf);
        }
    }
    int rc = 0;
    if (strcmp(mode, "dir") == 0) {
        char base[108];
        if (strcmp(hilbus_transport(bus), "unixcan") != 0 || hilbus_unixcan_base(base, sizeof base) != 0) {
            fprintf(stderr, "hilbus_tool: dir: not a unixcan bus\n");
            rc = 1;
        } else {
            printf("{\"dir\": \"%s/%s\", \"max_peers\": %d}\n", base, channel, HILBUS_MAX_PEERS);
        }
    } else if (strcmp(mode, "send") == 0) {
        struct canfd_frame f;
        memset(&f, 0, sizeof f);
        int len = parse_hex(data_hex, f.data, fd ? 64 : 8);
        if (len < 0) {
            fprintf(stderr, "hilbus_tool: --data must be hex, at most %d bytes\n", fd ? 64 : 8);
            hilbus_close(bus);
            return 2;
        }
        f.can_id = (canid_t)id | (id > CAN_SFF_MASK ? CAN_EFF_FLAG : 0);
        f.len = fd ? hilbus_fd_len((size_t)len) : (uint8_t)len;
        if (brs) f.flags |= CANFD_BRS;
        for (long i = 0; i < count && !stop_requested; i++) {
            if (hilbus_send(bus, &f, fd) != 0) {
                fprintf(stderr, "hilbus_tool: send: %s\n",
                        hilbus_last_error(bus)[0] ? hilbus_last_error(bus) : strerror(errno));
                rc = 1;
                break;
            }
            if (interval_us > 0) {
                struct timespec ts = {.tv_sec = interval_us / 1000000, .tv_nsec = (interval_us % 1000000) * 1000};
                nanosleep(&ts, NULL);
            }
        }
        print_stats(bus);
    } else if (strcmp(mode, "recv") == 0) {
        long got = 0;
        while ((count <= 0 || got < count) && !stop_requested) {
            struct canfd_frame f;
            int ffd;
            int r = hilbus_recv(bus, &f, &ffd, timeout_ms * 1000);
            if (r < 0) { rc = 1; break; }
            if (r == 0) { if (!stop_requested) rc = 3; break; } /* time-out */
            print_frame(&f, ffd);
            got++;
        }
        print_stats(bus);
    } else if (strcmp(mode, "echo") == 0) {
        struct can_filter ping = {.can_id = PING_ID, .can_mask = CAN_SFF_MASK};
        hilbus_set_filters(bus, &ping, 1);
        while (!stop_requested) {
            struct canfd_frame f;
            int ffd;
            int r = hilbus_recv(bus, &f, &ffd, 200000);
            if (r < 0) { rc = 1; break; }
            if (r == 0) continue;
            f.can_id = PONG_ID;
            hilbus_send(bus, &f, ffd);
        }
        print_stats(bus);
    } else if (strcmp(mode, "ping") == 0) {
        rc = run_ping(bus, count, fd, window, timeout_ms * 1000);
    } else {
        fprintf(stderr, "hilbus_tool: unknown mode '%s'\n", mode);
        usage(stderr);
        rc = 2;
    }
    hilbus_close(bus);
    return rc;
}
