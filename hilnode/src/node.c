/* hilnode: see hilnode.h. */
#define _GNU_SOURCE /* mlockall, sched_setscheduler */
#include "hilnode.h"

#include <errno.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

int64_t hil_now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * HIL_NS_PER_S + ts.tv_nsec;
}

static volatile sig_atomic_t *g_stop;

static void on_signal(int sig)
{
    (void)sig;
    if (g_stop != NULL) {
        *g_stop = 1;
    }
}

void hil_node_signals(volatile sig_atomic_t *stop, int ignore_hup)
{
    struct sigaction sa;
    g_stop = stop;
    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    if (ignore_hup) {
        signal(SIGHUP, SIG_IGN);
    }
}

/* ------------------------------------------------------------------------ options */

void hil_node_opts_init(hil_node_opts_t *o, const char *prog)
{
    memset(o, 0, sizeof(*o));
    o->prog = prog;
    o->bus = getenv("HIL_BUS") ? getenv("HIL_BUS") : "unixcan";
    o->channel = getenv("HIL_CHANNEL") ? getenv("HIL_CHANNEL") : "vcan0";
    o->rt_priority = 80;
}

int hil_parse_u64(const char *s, uint64_t max, uint64_t *v)
{
    char *end;
    unsigned long long x;
    if (s[0] < '0' || s[0] > '9') {
        return -1; /* no sign, no blank: strtoull would take " -1" for 2^64 - 1 */
    }
    errno = 0;
    x = strtoull(s, &end, 10);
    if (errno || *end || end == s || x > max) {
        return -1;
    }
    *v = x;
    return 0;
}

int hil_node_u64_arg(const hil_node_opts_t *o, const char *flag, const char *arg, uint64_t max,
                     uint64_t *v)
{
    if (hil_parse_u64(arg, max, v) != 0) {
        fprintf(stderr, "%s: %s %s: not an integer in 0..%llu\n", o->prog, flag, arg,
                (unsigned long long)max);
        return -1;
    }
    return 0;
}

int hil_node_option(hil_node_opts_t *o, int c, const char *arg)
{
    uint64_t v;
    switch (c) {
    case HIL_OPT_BUS: o->bus = arg; return 1;
    case HIL_OPT_CHANNEL: o->channel = arg; return 1;
    case HIL_OPT_LOCKSTEP: o->realtime = 0; return 1;
    case HIL_OPT_REALTIME: o->realtime = 1; return 1;
    case HIL_OPT_TRACE: o->trace = arg; return 1;
    case HIL_OPT_READY_FILE: o->ready_file = arg; return 1;
    case HIL_OPT_MAX_PERIODS:
        if (hil_node_u64_arg(o, "--max-periods", arg, UINT64_MAX, &v) != 0) {
            return -1;
        }
        o->max_periods = v;
        return 1;
    case HIL_OPT_RT_PRIORITY:
        if (hil_node_u64_arg(o, "--rt-priority", arg, 99u, &v) != 0) {
            return -1;
        }
        o->rt_priority = (int)v;
        return 1;
    default:
        return 0;
    }
}

void hil_node_usage(FILE *out)
{
    fputs("  --bus socketcan|unixcan|auto   transport (default $HIL_BUS, else unixcan)\n"
          "  --channel NAME                 channel (default $HIL_CHANNEL, else vcan0)\n"
          "  --ready-file FILE              written (atomically) once on the bus and ready\n"
          "  --max-periods N                exit after N periods (0: until SIGTERM/SIGINT)\n"
          "  --rt-priority N                real time: SCHED_FIFO priority, 0..99 (default 80;\n"
          "                                 0 off)\n",
          out);
}

/* ------------------------------------------------------------------------ start-up */

const char *hil_node_realtime(const hil_node_opts_t *o)
{
    struct sched_param sp;
    const int ok_lock = mlockall(MCL_CURRENT | MCL_FUTURE) == 0;
    int ok_sched = 0;
    if (o->rt_priority > 0) {
        memset(&sp, 0, sizeof(sp));
        sp.sched_priority = o->rt_priority;
        ok_sched = sched_setscheduler(0, SCHED_FIFO, &sp) == 0;
    }
    if (ok_sched) {
        return ok_lock ? "SCHED_FIFO+mlockall" : "SCHED_FIFO; mlockall not permitted";
    }
    if (ok_lock) {
        return o->rt_priority > 0 ? "SCHED_OTHER (SCHED_FIFO not permitted)+mlockall"
                                  : "SCHED_OTHER (--rt-priority 0)+mlockall";
    }
    return "SCHED_OTHER; SCHED_FIFO and mlockall not permitted";
}

hilbus_t *hil_node_open_bus(const hil_node_opts_t *o)
{
    char err[256];
    /* in lockstep the run's nodes lose no frame: every sender waits for them (unixcan) */
    hilbus_t *bus = hilbus_open_flags(o->bus, o->channel, o->realtime ? 0u : HILBUS_LOSSLESS, err,
                                      sizeof(err));
    if (bus == NULL) {
        fprintf(stderr, "%s: cannot open bus %s/%s: %s\n", o->prog, o->bus, o->channel, err);
    } else if (g_stop != NULL) {
        hilbus_set_stop(bus, g_stop); /* a stop signal ends a wait for a full peer at once */
    }
    return bus;
}

hiltrace_t *hil_node_open_trace(const hil_node_opts_t *o, int *failed)
{
    hiltrace_t *t;
    *failed = 0;
    if (o->trace == NULL) {
        return NULL;
    }
    t = hiltrace_open(o->trace);
    if (t == NULL) {
        fprintf(stderr, "%s: cannot create trace %s: %s\n", o->prog, o->trace, strerror(errno));
        *failed = 1;
    }
    return t;
}

int hil_node_close_trace(const hil_node_opts_t *o, hiltrace_t *trace)
{
    if (trace != NULL && hiltrace_close(trace) != 0) {
        fprintf(stderr, "%s: trace %s: write error\n", o->prog, o->trace);
        return -1;
    }
    return 0;
}

int hil_node_ready(const hil_node_opts_t *o)
{
    if (o->ready_file != NULL && hil_write_ready_file(o->ready_file) != 0) {
        fprintf(stderr, "%s: cannot write ready file %s: %s\n", o->prog, o->ready_file,
                strerror(errno));
        return -1;
    }
    return 0;
}

/* ------------------------------------------------------------------------ counters */

void hil_node_json_begin(hil_json_t *j, const hil_node_opts_t *o, const hilbus_t *bus)
{
    hil_json_str(j, "program", o->prog);
    hil_json_str(j, "mode", o->realtime ? "realtime" : "lockstep");
    hil_json_str(j, "transport", bus != NULL ? hilbus_transport(bus) : "none");
}

/* "key": {"<id>": frames, ...} for the ids with frames (decimal, ascending), at most
 * HIL_NODE_JSON_IDS of them; the frames of any further ids as "other" (a flood of ids must
 * not truncate the line the rig reads). */
#define HIL_NODE_JSON_IDS 48
static void id_counts(hil_json_t *j, const char *key, const hilbus_t *bus,
                      uint64_t (*count)(const hilbus_t *, uint32_t))
{
    char name[16];
    uint64_t other = 0;
    int shown = 0;
    uint32_t id;
    hil_json_open(j, key);
    for (id = 0; id < HILBUS_IDS; id++) {
        const uint64_t n = count(bus, id);
        if (n == 0) continue;
        if (shown < HIL_NODE_JSON_IDS) {
            snprintf(name, sizeof(name), "%u", (unsigned)id);
            hil_json_u64(j, name, n);
            shown++;
        } else {
            other += n;
        }
    }
    if (other > 0) hil_json_u64(j, "other", other);
    hil_json_close(j);
}

void hil_node_json_bus(hil_json_t *j, const hilbus_t *bus, uint64_t non_data_frames)
{
    hilbus_stats_t bs;
    memset(&bs, 0, sizeof(bs));
    if (bus != NULL) {
        hilbus_get_stats(bus, &bs);
    }
    hil_json_u64(j, "tx_frames", bs.tx_frames);
    hil_json_u64(j, "tx_drops", bs.tx_drops);
    hil_json_u64(j, "tx_errors", bs.tx_errors);
    hil_json_u64(j, "rx_frames", bs.rx_frames);
    hil_json_u64(j, "rx_overflows", bs.rx_overflows);
    hil_json_u64(j, "rx_malformed", bs.rx_malformed);
    hil_json_u64(j, "rx_filtered", bs.rx_filtered);
    hil_json_u64(j, "non_data_frames", non_data_frames);
    hil_json_u64(j, "foreign_entries", bs.foreign_entries);
    hil_json_u64(j, "peers_beyond_limit", bs.peers_beyond_limit);
    hil_json_u64(j, "tx_stalls", bs.tx_stalls);
    hil_json_fmt(j, "tx_stall_ms_total", "%.3f", (double)bs.tx_stall_ns_total * 1e-6);
    hil_json_fmt(j, "tx_stall_ms_max", "%.3f", (double)bs.tx_stall_ns_max * 1e-6);
    hil_json_u64(j, "tx_stall_failures", bs.tx_stall_failures);
    hil_json_u64(j, "rx_pending_max", bs.rx_pending_max);
    if (bus != NULL) {
        const char *name;
        uint64_t drops;
        int i;
        /* socket names: the pid and a serial, the C tag and marks (no quote, no backslash) */
        hil_json_open(j, "listener_drops");
        for (i = 0; hilbus_listener_drops(bus, i, &name, &drops); i++) {
            hil_json_u64(j, name, drops);
        }
        hil_json_close(j);
        id_counts(j, "tx_ids", bus, hilbus_id_sent);
        id_counts(j, "rx_ids", bus, hilbus_id_received);
    }
}
