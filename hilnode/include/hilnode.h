/* hilnode: the skeleton the rig's C programs on the bus share (plant_rt, fw_host,
 * pwm_responder), so each main.c holds only what the program itself does: the clock, the stop
 * signals, the options every node takes, the real-time set-up, opening the bus, the trace and
 * the ready file, and the counters JSON line at exit (hil_json.h). The bus itself is hilbus;
 * trace files are hiltrace.h, the ready file hil_ready.h, the log rate limit hil_log_limit.h.
 */
#ifndef HILNODE_H
#define HILNODE_H

#include <getopt.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>

#include "hil_json.h"
#include "hil_log_limit.h"
#include "hil_ready.h"
#include "hilbus.h"
#include "hiltrace.h"

#ifdef __cplusplus
extern "C" {
#endif

#define HIL_NS_PER_S 1000000000LL

/* CLOCK_MONOTONIC in ns. */
int64_t hil_now_ns(void);

/* SIGTERM and SIGINT set *stop to 1; SIGPIPE is ignored, SIGHUP too when ignore_hup. */
void hil_node_signals(volatile sig_atomic_t *stop, int ignore_hup);

/* The options every node takes. */
typedef struct {
    const char *prog;       /* program name: the prefix of its messages */
    const char *bus;        /* --bus socketcan|unixcan|auto: $HIL_BUS, else unixcan */
    const char *channel;    /* --channel NAME: $HIL_CHANNEL, else vcan0 */
    int realtime;           /* --lockstep (0, the default) | --realtime (1) */
    const char *trace;      /* --trace FILE, or NULL */
    const char *ready_file; /* --ready-file FILE, or NULL */
    uint64_t max_periods;   /* --max-periods N: exit after N periods (0: until a signal) */
    int rt_priority;        /* --rt-priority N: SCHED_FIFO priority in real time, 0..99 (80) */
} hil_node_opts_t;

enum {
    HIL_OPT_BUS = 0x4000, HIL_OPT_CHANNEL, HIL_OPT_LOCKSTEP, HIL_OPT_REALTIME, HIL_OPT_TRACE,
    HIL_OPT_READY_FILE, HIL_OPT_MAX_PERIODS, HIL_OPT_RT_PRIORITY,
    HIL_OPT_NODE_END /* a program's own option codes start here */
};

/* The struct option entries of the node options, for a program's getopt_long table. */
#define HIL_NODE_LONGOPTS                                                                   \
    {"bus", required_argument, 0, HIL_OPT_BUS},                                             \
    {"channel", required_argument, 0, HIL_OPT_CHANNEL},                                     \
    {"lockstep", no_argument, 0, HIL_OPT_LOCKSTEP},                                         \
    {"realtime", no_argument, 0, HIL_OPT_REALTIME},                                         \
    {"trace", required_argument, 0, HIL_OPT_TRACE},                                         \
    {"ready-file", required_argument, 0, HIL_OPT_READY_FILE},                               \
    {"max-periods", required_argument, 0, HIL_OPT_MAX_PERIODS},                             \
    {"rt-priority", required_argument, 0, HIL_OPT_RT_PRIORITY}

/* Defaults (from the environment where the README says so). */
void hil_node_opts_init(hil_node_opts_t *o, const char *prog);

/* One getopt_long result c with its argument: 1 when it was a node option (taken), 0 when it
 * is not one, -1 for a bad value (said on stderr: the program exits 2). */
int hil_node_option(hil_node_opts_t *o, int c, const char *arg);

/* The help lines of the node options but --lockstep/--realtime and --trace, whose meaning
 * each program says itself. */
void hil_node_usage(FILE *out);

/* A decimal integer in 0..max, digits only: 0, or -1 (a sign, a blank, junk, too large). */
int hil_parse_u64(const char *s, uint64_t max, uint64_t *v);

/* The same for the value of option `flag`: 0, or -1 after "PROG: FLAG ARG: not an integer in
 * 0..MAX" on stderr. */
int hil_node_u64_arg(const hil_node_opts_t *o, const char *flag, const char *arg, uint64_t max,
                     uint64_t *v);

/* Real time: mlockall and SCHED_FIFO at o->rt_priority (0: none). Returns what was granted,
 * the "rt" of the exit counters. */
const char *hil_node_realtime(const hil_node_opts_t *o);
#define HIL_NODE_RT_NONE "not requested (lockstep)"

/* The bus of --bus/--channel; NULL after "PROG: cannot open bus B/C: why" on stderr. */
hilbus_t *hil_node_open_bus(const hil_node_opts_t *o);

/* The trace of --trace (NULL when none was asked for); *failed set after "PROG: cannot
 * create trace F: why" on stderr. */
hiltrace_t *hil_node_open_trace(const hil_node_opts_t *o, int *failed);

/* Closes the trace (NULL: nothing). 0, or -1 after "PROG: trace F: write error". */
int hil_node_close_trace(const hil_node_opts_t *o, hiltrace_t *trace);

/* Writes --ready-file (none: nothing). 0, or -1 after "PROG: cannot write ready file F: why". */
int hil_node_ready(const hil_node_opts_t *o);

/* The counters JSON line at exit starts with the program, its pacing and the transport. */
void hil_node_json_begin(hil_json_t *j, const hil_node_opts_t *o, const hilbus_t *bus);

/* The bus counters every node reports (hilbus_stats_t, and the frames outside the protocol's
 * 11-bit data frames that the node counted itself). */
void hil_node_json_bus(hil_json_t *j, const hilbus_t *bus, uint64_t non_data_frames);

#ifdef __cplusplus
}
#endif
#endif
