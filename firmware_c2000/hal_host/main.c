/* fw_host: the portable control core as a Linux process on the bus (DESIGN.md section 6).
 *
 * The firmware does not pace: in both modes it reacts to the plant's ADC frames (bus_io.c).
 * One thread polls the bus, the SCI console's pseudo-terminal (console.c, pty.c) and a 10 ms
 * timer (DRIVE_STATUS and HEARTBEAT every 100 ms, console connection). Exit 0 on SIGTERM or
 * SIGINT (or after --max-periods) with the trace flushed and one JSON line of counters on
 * stderr; exit 2 on bad arguments or a bad parameter file; 1 when the bus, the trace or the
 * console cannot be opened.
 */
#define _GNU_SOURCE /* getopt_long, timerfd, mlockall, sched_setscheduler */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#include "fw_host.h"
#include "hil_ready.h"
#include "param_file.h"

#define LOG_LINES_PER_S 10
#define DRAIN_MAX 256 /* frames handled before the timer and the console get a turn */
#define CONSOLE_PROBE_NS (10LL * 1000000LL)

static fwh_t app; /* the core object is large: static storage, as on the DSP */
static fwh_param_list_t start_list;

static void on_signal(int sig)
{
    (void)sig;
    app.stop = 1;
}

/* ------------------------------------------------------------------------ options */

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fw_host [options]\n"
            "Runs the sensorless IPMSM control core on the bus: VIO_ADC in, VIO_PWM out (the\n"
            "ISR runs when a period's ADC data is complete), the drive protocol (DRIVE_CMD,\n"
            "DRIVE_LIMITS, PARAM_REQ/RESP, DRIVE_STATUS, HEARTBEAT, TLM_*) and the SCI console\n"
            "on a pseudo-terminal (protocols/console.md).\n"
            "\n"
            "  --bus socketcan|unixcan|auto   transport (default $HIL_BUS, else unixcan)\n"
            "  --channel NAME                 channel (default $HIL_CHANNEL, else vcan0)\n"
            "  --lockstep | --realtime        pacing of the plant (default lockstep); the firmware\n"
            "                                 reacts to ADC frames in both; real time counts an\n"
            "                                 overrun when ADC-in to PWM-out exceeds a PWM\n"
            "                                 period\n"
            "  --trace FILE                   FW_TRACE record for every ISR (HILTRACE file)\n"
            "  --send-trace                   also send FW_TRACE on the bus\n"
            "  --tlm-div N                    TLM_* every N speed-loop periods (default 1: at the\n"
            "                                 speed-loop rate, 1 kHz; 0 off)\n"
            "  --params FILE, --config FILE   parameter file ('name = value' lines, # comments),\n"
            "                                 loaded at start; PARAM_REQ SAVE/LOAD and the\n"
            "                                 console's save/load use it\n"
            "  --set name=value               set a parameter after the file (repeatable)\n"
            "  --pty-link PATH                symbolic link to the console's pseudo-terminal\n"
            "  --no-console                   no console pseudo-terminal\n"
            "  --console-timeout-ms N         a console-owned drive command stays refreshed while\n"
            "                                 a line came within N ms (default 5000; 0: until the\n"
            "                                 client hangs up)\n"
            "  --ready-file FILE              written (atomically) once on the bus and ready\n"
            "  --max-periods N                exit after N ISRs (0: until SIGTERM/SIGINT)\n"
            "  --spin-us N                    busy-poll the bus N us before sleeping (default 0)\n"
            "  --node N                       HEARTBEAT node number (default 1)\n"
            "  --rt-priority N                real time: SCHED_FIFO priority (default 80; 0 off)\n"
            "  --first-period N               the paired plant's first ADC period (lockstep: 0);\n"
            "                                 ADC data of other periods before it is rejected\n"
            "  --help                         this text\n"
            "\n"
            "Exit: 0 on SIGTERM/SIGINT or after --max-periods (counters as one JSON line on\n"
            "stderr), 2 on bad arguments or a bad parameter file, 1 on other errors.\n");
}

static int parse_u64(const char *s, uint64_t max, uint64_t *v)
{
    char *end;
    unsigned long long x;
    if (s[0] == '-' || s[0] == '\0') {
        return -1;
    }
    errno = 0;
    x = strtoull(s, &end, 10);
    if (errno || *end || x > max) {
        return -1;
    }
    *v = x;
    return 0;
}

static int parse_options(int argc, char **argv, fwh_param_list_t *sets)
{
    enum {
        O_BUS = 256, O_CHANNEL, O_LOCKSTEP, O_REALTIME, O_TRACE, O_SEND_TRACE, O_TLM_DIV,
        O_PARAMS, O_SET, O_PTY_LINK, O_NO_CONSOLE, O_CONSOLE_TIMEOUT, O_READY, O_MAX_PERIODS,
        O_SPIN, O_NODE, O_RT_PRIO, O_FIRST_PERIOD, O_HELP
    };
    static const struct option longopts[] = {
        {"bus", required_argument, 0, O_BUS},
        {"channel", required_argument, 0, O_CHANNEL},
        {"lockstep", no_argument, 0, O_LOCKSTEP},
        {"realtime", no_argument, 0, O_REALTIME},
        {"trace", required_argument, 0, O_TRACE},
        {"send-trace", no_argument, 0, O_SEND_TRACE},
        {"tlm-div", required_argument, 0, O_TLM_DIV},
        {"params", required_argument, 0, O_PARAMS},
        {"config", required_argument, 0, O_PARAMS},
        {"set", required_argument, 0, O_SET},
        {"pty-link", required_argument, 0, O_PTY_LINK},
        {"no-console", no_argument, 0, O_NO_CONSOLE},
        {"console-timeout-ms", required_argument, 0, O_CONSOLE_TIMEOUT},
        {"ready-file", required_argument, 0, O_READY},
        {"max-periods", required_argument, 0, O_MAX_PERIODS},
        {"spin-us", required_argument, 0, O_SPIN},
        {"node", required_argument, 0, O_NODE},
        {"rt-priority", required_argument, 0, O_RT_PRIO},
        {"first-period", required_argument, 0, O_FIRST_PERIOD},
        {"help", no_argument, 0, O_HELP},
        {0, 0, 0, 0},
    };
    fwh_options_t *o = &app.opt;
    int c;
    char err[512];
    o->bus = getenv("HIL_BUS") ? getenv("HIL_BUS") : "unixcan";
    o->channel = getenv("HIL_CHANNEL") ? getenv("HIL_CHANNEL") : "vcan0";
    o->tlm_div = 1;
    o->console_timeout_ns = 5000LL * 1000000LL;
    o->node = 1;
    o->rt_priority = 80;
    o->first_period = -1; /* any */
    sets->n = 0;
    opterr = 0;
    while ((c = getopt_long(argc, argv, "h", longopts, NULL)) != -1) {
        uint64_t v;
        switch (c) {
        case O_BUS: o->bus = optarg; break;
        case O_CHANNEL: o->channel = optarg; break;
        case O_LOCKSTEP: o->realtime = 0; break;
        case O_REALTIME: o->realtime = 1; break;
        case O_TRACE: o->trace = optarg; break;
        case O_SEND_TRACE: o->send_trace = 1; break;
        case O_PARAMS: o->params = optarg; break;
        case O_PTY_LINK: o->pty_link = optarg; break;
        case O_NO_CONSOLE: o->no_console = 1; break;
        case O_READY: o->ready_file = optarg; break;
        case O_SET:
            if (sets->n >= FWH_PARAM_ITEMS_MAX) {
                fprintf(stderr, "fw_host: too many --set\n");
                return 2;
            }
            if (fwh_params_parse_assignment(optarg, &sets->items[sets->n], err, sizeof(err)) != 0) {
                fprintf(stderr, "fw_host: bad parameter: %s\n", err);
                return 2;
            }
            sets->items[sets->n].line = sets->n + 1;
            sets->n++;
            break;
        case O_TLM_DIV:
        case O_CONSOLE_TIMEOUT:
        case O_MAX_PERIODS:
        case O_SPIN:
        case O_NODE:
        case O_FIRST_PERIOD:
        case O_RT_PRIO: {
            const uint64_t max = c == O_NODE ? 255u : c == O_RT_PRIO ? 99u
                               : c == O_FIRST_PERIOD ? UINT32_MAX
                               : c == O_MAX_PERIODS ? UINT64_MAX : c == O_SPIN ? 1000000u
                               : c == O_CONSOLE_TIMEOUT ? 86400000u : 1000000u;
            if (parse_u64(optarg, max, &v) != 0) {
                fprintf(stderr, "fw_host: %s %s: not an integer in 0..%llu\n", argv[optind - 2],
                        optarg, (unsigned long long)max);
                return 2;
            }
            if (c == O_TLM_DIV) {
                o->tlm_div = (uint32_t)v;
            } else if (c == O_CONSOLE_TIMEOUT) {
                o->console_timeout_ns = (int64_t)v * 1000000LL;
            } else if (c == O_MAX_PERIODS) {
                o->max_periods = v;
            } else if (c == O_SPIN) {
                o->spin_us = (int32_t)v;
            } else if (c == O_NODE) {
                o->node = (uint8_t)v;
            } else if (c == O_FIRST_PERIOD) {
                o->first_period = (int64_t)v;
            } else {
                o->rt_priority = (int)v;
            }
            break;
        }
        case O_HELP:
        case 'h':
            usage(stdout);
            return 1;
        case ':':
            fprintf(stderr, "fw_host: %s needs a value (see --help)\n", argv[optind - 1]);
            return 2;
        default:
            fprintf(stderr, "fw_host: unknown option %s (see --help)\n", argv[optind - 1]);
            return 2;
        }
    }
    if (optind < argc) {
        fprintf(stderr, "fw_host: unexpected argument '%s' (see --help)\n", argv[optind]);
        return 2;
    }
    return 0;
}

/* ------------------------------------------------------------------------ parameters */

static int apply_list(const fwh_param_list_t *list, const char *source)
{
    int failed, changed;
    int16_t st = fwh_params_apply(&app.core, list, &failed, &changed);
    if (st != FW_STATUS_OK) {
        const fwh_param_item_t *it = &list->items[failed];
        char num[32];
        fwh_fmt_real(num, sizeof(num), it->value);
        if (source != NULL) {
            fprintf(stderr, "fw_host: bad parameter file: %s:%d: field '%s': value %s ", source,
                    it->line, it->name, num);
        } else {
            fprintf(stderr, "fw_host: bad parameter: --set %s=%s: field '%s': ", it->name, num,
                    it->name);
        }
        fprintf(stderr, "rejected by the control core (status %d: not a whole number, or "
                        "inconsistent with other parameters: ld_h < lq_h, tmin_us >= soc_on_us + "
                        "soc_off_us + 1, uv_trip_v < ov_trip_v, currents below oc_trip_a)\n",
                st);
        return 2;
    }
    return 0;
}

static int load_parameters(const fwh_param_list_t *sets)
{
    char err[600];
    if (app.opt.params != NULL) {
        if (fwh_params_parse_file(app.opt.params, &start_list, err, sizeof(err)) != 0) {
            fprintf(stderr, "fw_host: bad parameter file: %s\n", err);
            return 2;
        }
        if (apply_list(&start_list, app.opt.params) != 0) {
            return 2;
        }
    }
    return sets->n > 0 ? apply_list(sets, NULL) : 0;
}

/* ------------------------------------------------------------------------ start-up */

static void setup_realtime(void)
{
    struct sched_param sp;
    int ok_lock = mlockall(MCL_CURRENT | MCL_FUTURE) == 0;
    int ok_sched = 0;
    if (app.opt.rt_priority > 0) {
        memset(&sp, 0, sizeof(sp));
        sp.sched_priority = app.opt.rt_priority;
        ok_sched = sched_setscheduler(0, SCHED_FIFO, &sp) == 0;
    }
    app.rt_note = ok_sched && ok_lock ? "SCHED_FIFO+mlockall"
                  : ok_sched          ? "SCHED_FIFO; mlockall not permitted"
                  : ok_lock           ? (app.opt.rt_priority > 0
                                             ? "SCHED_OTHER (SCHED_FIFO not permitted)+mlockall"
                                             : "SCHED_OTHER (--rt-priority 0)+mlockall")
                                      : "SCHED_OTHER; SCHED_FIFO and mlockall not permitted";
}

static int open_bus(void)
{
    char err[256];
    /* 11-bit data frames of the drive (0x100-0x1FF) and virtual-I/O (0x00-0x3F) ranges */
    const struct can_filter filters[2] = {
        {.can_id = 0x100u, .can_mask = 0x700u | CAN_EFF_FLAG | CAN_RTR_FLAG},
        {.can_id = 0x000u, .can_mask = 0x7C0u | CAN_EFF_FLAG | CAN_RTR_FLAG},
    };
    app.bus = hilbus_open(app.opt.bus, app.opt.channel, err, sizeof(err));
    if (app.bus == NULL) {
        fprintf(stderr, "fw_host: cannot open bus %s/%s: %s\n", app.opt.bus, app.opt.channel, err);
        return -1;
    }
    if (hilbus_set_filters(app.bus, filters, 2) != 0) {
        fprintf(stderr, "fw_host: bus filters: %s\n", strerror(errno));
        return -1;
    }
    if (app.opt.spin_us > 0) {
        hilbus_set_spin(app.bus, app.opt.spin_us);
    }
    return 0;
}

/* ------------------------------------------------------------------------ main loop */

static void handle_frame(const struct canfd_frame *f, int fd)
{
    const int64_t t_rx = fwh_now_ns();
    const uint32_t id = f->can_id & CAN_SFF_MASK;
    if (f->can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) {
        app.cnt.non_data_frames++; /* outside this protocol's 11-bit data frames */
        return;
    }
    if (fwh_bus_is_vio(id)) {
        fwh_bus_vio_frame(&app, f, fd, t_rx);
    } else if (fwh_drive_is_drive(id)) {
        fwh_drive_frame(&app, f, fd);
    }
}

static int periods_done(void)
{
    return app.opt.max_periods > 0 && app.cnt.isr >= app.opt.max_periods;
}

/* Receives what is waiting (and, with --spin-us, what comes within the spin). */
static int drain_bus(void)
{
    struct canfd_frame f;
    int fd, r, n = 0;
    int64_t timeout = 0;
    while (n < DRAIN_MAX && !app.stop && !periods_done()) {
        r = hilbus_recv(app.bus, &f, &fd, timeout);
        if (r < 0) {
            if (errno == EINTR || errno == EAGAIN) {
                return 0;
            }
            fprintf(stderr, "fw_host: bus receive error: %s\n", strerror(errno));
            return -1;
        }
        if (r == 0) {
            break;
        }
        handle_frame(&f, fd);
        n++;
        timeout = app.opt.spin_us; /* hilbus spins this long before giving up */
    }
    return 0;
}

/* Reads what the client sent; a session starts with the first bytes after a hang-up. */
static int console_input_pending(void)
{
    return app.console_in_off < app.console_in_len;
}

/* Lines are taken while their replies leave: input waits (first in console_in, then in the
 * pty, then in the client's write) while a reply is still queued, so none is dropped. */
static void console_read(int64_t now)
{
    int n;
    for (;;) {
        if (console_input_pending()) {
            app.console_in_off += fwh_console_input(&app, app.console_in + app.console_in_off,
                                                    app.console_in_len - app.console_in_off,
                                                    now);
            if (console_input_pending()) {
                return; /* a reply waits for the client: POLLOUT resumes */
            }
        }
        if (app.pty.out_len > 0) {
            return;
        }
        n = fwh_pty_read(&app.pty, app.console_in, sizeof(app.console_in));
        if (n <= 0) {
            return;
        }
        app.console_in_off = 0;
        app.console_in_len = (size_t)n;
        if (!app.console_connected) {
            app.console_connected = 1;
            app.console_last_ns = now;
            app.cnt.console_sessions++;
        }
    }
}

/* The client closed the line (POLLHUP): end the session and leave the line out of the main
 * poll (it would report the hang-up continuously) until the 10 ms probe sees it clear. */
static void console_hangup(int64_t now)
{
    console_read(now); /* what it wrote before closing */
    app.console_in_off = app.console_in_len = 0;
    if (app.console_connected) {
        app.console_connected = 0;
        fwh_console_hangup(&app);
    }
    app.console_hup = 1;
    app.console_retry_ns = now + CONSOLE_PROBE_NS;
}

static void console_probe(int64_t now)
{
    struct pollfd p;
    if (!app.pty_open || !app.console_hup || now < app.console_retry_ns) {
        return;
    }
    p.fd = app.pty.master;
    p.events = POLLIN;
    p.revents = 0;
    if (poll(&p, 1, 0) < 0) {
        return;
    }
    if (p.revents & POLLHUP) {
        console_hangup(now);
    } else {
        app.console_hup = 0; /* a client opened the line: back into the main poll */
        console_read(now);
    }
}

static void housekeeping(int64_t now)
{
    if (now >= app.next_status_ns) {
        fwh_drive_send_status(&app);
        app.next_status_ns += FWH_STATUS_PERIOD_NS;
        if (app.next_status_ns <= now) {
            app.next_status_ns = now + FWH_STATUS_PERIOD_NS;
        }
    }
    if (now >= app.next_heartbeat_ns) {
        fwh_drive_send_heartbeat(&app);
        app.next_heartbeat_ns += FWH_STATUS_PERIOD_NS;
        if (app.next_heartbeat_ns <= now) {
            app.next_heartbeat_ns = now + FWH_STATUS_PERIOD_NS;
        }
    }
    console_probe(now); /* (the log window rolls over on the next message) */
}

static int run(int tfd)
{
    while (!app.stop && !periods_done()) {
        struct pollfd p[3];
        int n = 0, i_bus, i_tim, i_pty = -1;
        int64_t now;
        p[n].fd = hilbus_fileno(app.bus), p[n].events = POLLIN, p[n].revents = 0, i_bus = n++;
        p[n].fd = tfd, p[n].events = POLLIN, p[n].revents = 0, i_tim = n++;
        if (app.pty_open && !app.console_hup) {
            p[n].fd = app.pty.master;
            /* no reading while a reply waits for the client (backpressure) */
            p[n].events = (short)(app.pty.out_len > 0 ? POLLOUT
                                  : console_input_pending() ? 0 : POLLIN);
            p[n].revents = 0;
            i_pty = n++;
        }
        if (poll(p, (nfds_t)n, -1) < 0) {
            if (errno == EINTR) {
                continue;
            }
            fprintf(stderr, "fw_host: poll: %s\n", strerror(errno));
            return 1;
        }
        if (p[i_bus].revents & (POLLIN | POLLERR)) {
            if (drain_bus() != 0) {
                return 1;
            }
        }
        now = fwh_now_ns();
        if (i_pty >= 0 && p[i_pty].revents) {
            if (p[i_pty].revents & (POLLHUP | POLLERR)) {
                console_hangup(now);
            } else {
                if (p[i_pty].revents & POLLIN) {
                    console_read(now);
                }
                if (p[i_pty].revents & POLLOUT) {
                    fwh_pty_flush(&app.pty);
                    if (app.pty.out_len == 0) {
                        console_read(now); /* the lines that waited for that reply */
                    }
                }
            }
        }
        if (p[i_tim].revents & POLLIN) {
            uint64_t expirations;
            if (read(tfd, &expirations, sizeof(expirations)) < 0 && errno != EAGAIN) {
                fprintf(stderr, "fw_host: timer: %s\n", strerror(errno));
                return 1;
            }
            housekeeping(now);
        }
    }
    return 0;
}

static void print_counters(void)
{
    hilbus_stats_t bs;
    fw_status_t s;
    const fwh_counters_t *c = &app.cnt;
    int k;
    char last[24];
    memset(&bs, 0, sizeof(bs));
    if (app.bus != NULL) {
        hilbus_get_stats(app.bus, &bs);
    }
    fw_core_status(&app.core, &s);
    if (app.adc.have_last) {
        snprintf(last, sizeof(last), "%lu", (unsigned long)app.adc.last);
    } else {
        snprintf(last, sizeof(last), "null");
    }
    fprintf(stderr,
            "{\"program\": \"fw_host\", \"mode\": \"%s\", \"transport\": \"%s\", "
            "\"isr\": %llu, \"isr_no_data\": %llu, \"repeats\": %llu, \"last_period\": %s, "
            "\"pwm_sent\": %llu, \"pwm_invalid\": %llu, \"overruns\": %llu, "
            "\"max_latency_us\": %.1f, \"rx_rejected\": %llu, \"rejects\": {",
            app.opt.realtime ? "realtime" : "lockstep",
            app.bus != NULL ? hilbus_transport(app.bus) : "none", (unsigned long long)c->isr,
            (unsigned long long)c->isr_no_data, (unsigned long long)c->repeats, last,
            (unsigned long long)c->pwm_sent, (unsigned long long)c->pwm_invalid,
            (unsigned long long)c->overruns, (double)c->max_latency_ns * 1e-3,
            (unsigned long long)fwh_rejected_total(&app));
    for (k = 0; k < FWH_REJ_COUNT; k++) {
        fprintf(stderr, "%s\"%s\": %llu", k ? ", " : "", fwh_reject_name(k),
                (unsigned long long)c->rejects[k]);
    }
    fprintf(stderr,
            "}, \"resyncs\": %llu, \"syncs\": %llu, \"drive_cmds\": %llu, "
            "\"cmds_refused\": %llu, "
            "\"limits\": %llu, \"param_reqs\": %llu, \"status_frames\": %llu, "
            "\"heartbeats\": %llu, \"tlm_frames\": %llu, \"trace_records\": %llu, "
            "\"trace_sent\": %llu, \"trace_errors\": %llu, \"console_sessions\": %llu, "
            "\"console_lines\": %llu, \"console_errors\": %llu, "
            "\"console_keepalive_lapses\": %llu, \"console_out_dropped\": %llu, "
            "\"state\": \"%s\", \"fault_code\": %u, \"fault_name\": \"%s\", "
            "\"core_overruns\": %u, \"tx_frames\": %llu, \"tx_drops\": %llu, "
            "\"tx_errors\": %llu, \"rx_frames\": %llu, \"rx_overflows\": %llu, "
            "\"rx_malformed\": %llu, \"rx_filtered\": %llu, \"non_data_frames\": %llu, "
            "\"foreign_entries\": %llu, \"peers_beyond_limit\": %llu, \"rt\": \"%s\"}\n",
            (unsigned long long)c->resyncs, (unsigned long long)c->syncs,
            (unsigned long long)c->drive_cmds,
            (unsigned long long)c->cmds_refused, (unsigned long long)c->limits,
            (unsigned long long)c->param_reqs, (unsigned long long)c->status_frames,
            (unsigned long long)c->heartbeats, (unsigned long long)c->tlm_frames,
            (unsigned long long)c->trace_records, (unsigned long long)c->trace_sent,
            (unsigned long long)(c->trace_errors + c->fw_trace_tx_errors),
            (unsigned long long)c->console_sessions, (unsigned long long)c->console_lines,
            (unsigned long long)c->console_errors,
            (unsigned long long)c->console_keepalive_lapses,
            (unsigned long long)app.pty.out_dropped, fwh_state_name(s.state), s.fault_code,
            fwh_fault_name(s.fault_code), s.isr_overruns, (unsigned long long)bs.tx_frames,
            (unsigned long long)bs.tx_drops, (unsigned long long)bs.tx_errors,
            (unsigned long long)bs.rx_frames, (unsigned long long)bs.rx_overflows,
            (unsigned long long)bs.rx_malformed, (unsigned long long)bs.rx_filtered,
            (unsigned long long)c->non_data_frames, (unsigned long long)bs.foreign_entries,
            (unsigned long long)bs.peers_beyond_limit,
            app.rt_note != NULL ? app.rt_note : "not requested (lockstep)");
    fflush(stderr);
}

int main(int argc, char **argv)
{
    static fwh_param_list_t sets;
    struct sigaction sa;
    struct itimerspec its;
    int rc, tfd;
    char err[512];

    rc = parse_options(argc, argv, &sets);
    if (rc != 0) {
        return rc == 1 ? 0 : rc; /* 1: --help */
    }
    fw_core_init(&app.core);
    app.cmd.enable = 0;
    app.cmd.fault_reset = 0;
    app.cmd.ctrl_mode = FW_CTRL_SPEED;
    app.cmd.fw_mode = FW_FWMODE_REALTIME;
    app.cmd.speed_ref_rpm = 0.0f;
    app.cmd.iq_ref = 0.0f;
    app.owner = FWH_OWNER_NONE;
    app.pty.master = -1;
    fwh_adc_init(&app.adc);
    if (app.opt.first_period >= 0) {
        fwh_adc_expect_first(&app.adc, (uint32_t)app.opt.first_period);
    }
    if (load_parameters(&sets) != 0) {
        return 2;
    }

    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    signal(SIGHUP, SIG_IGN);

    if (open_bus() != 0) {
        if (app.bus != NULL) {
            hilbus_close(app.bus);
        }
        return 1;
    }
    if (app.opt.trace != NULL) {
        app.trace = hiltrace_open(app.opt.trace);
        if (app.trace == NULL) {
            fprintf(stderr, "fw_host: cannot create trace %s: %s\n", app.opt.trace,
                    strerror(errno));
            hilbus_close(app.bus);
            return 1;
        }
    }
    if (!app.opt.no_console) {
        if (fwh_pty_open(&app.pty, app.opt.pty_link, err, sizeof(err)) != 0) {
            fprintf(stderr, "fw_host: console: %s\n", err);
            if (app.trace != NULL) {
                hiltrace_close(app.trace);
            }
            hilbus_close(app.bus);
            return 1;
        }
        app.pty_open = 1;
    }
    tfd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
    memset(&its, 0, sizeof(its));
    its.it_value.tv_nsec = (long)FWH_TICK_NS;
    its.it_interval.tv_nsec = (long)FWH_TICK_NS;
    if (tfd < 0 || timerfd_settime(tfd, 0, &its, NULL) != 0) {
        fprintf(stderr, "fw_host: timerfd: %s\n", strerror(errno));
        return 1;
    }
    if (app.opt.realtime) {
        setup_realtime();
    }
    app.t0_ns = fwh_now_ns();
    app.next_status_ns = app.t0_ns;
    app.next_heartbeat_ns = app.t0_ns;
    hil_log_limit_init(&app.log_limit, "fw_host", LOG_LINES_PER_S, app.t0_ns);
    housekeeping(app.t0_ns);
    fprintf(stderr, "fw_host: %s on %s/%s, console %s%s%s\n",
            app.opt.realtime ? "real time" : "lockstep", hilbus_transport(app.bus),
            app.opt.channel, app.pty_open ? app.pty.slave_path : "off",
            app.pty.link[0] ? " linked from " : "", app.pty.link);
    rc = 0;
    if (app.opt.ready_file != NULL && hil_write_ready_file(app.opt.ready_file) != 0) {
        fprintf(stderr, "fw_host: cannot write ready file %s: %s\n", app.opt.ready_file,
                strerror(errno));
        rc = 1;
    }
    if (rc == 0) {
        rc = run(tfd);
    }
    fwh_drive_send_status(&app);
    if (app.trace != NULL && hiltrace_close(app.trace) != 0) {
        fprintf(stderr, "fw_host: trace %s: write error\n", app.opt.trace);
        rc = 1;
    }
    if (app.pty_open) {
        fwh_pty_flush(&app.pty);
    }
    print_counters();
    if (app.pty_open) {
        fwh_pty_close(&app.pty);
    }
    close(tfd);
    hilbus_close(app.bus);
    return rc;
}
