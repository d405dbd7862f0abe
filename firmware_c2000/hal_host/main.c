/* fw_host: the portable control core as a Linux process on the bus (docs/design.md section 6).
 *
 * The firmware does not pace: in both modes it reacts to the plant's ADC frames (bus_io.c).
 * One thread polls the bus, the SCI console's pseudo-terminal (console.c, pty.c) and a 10 ms
 * timer (DRIVE_STATUS and HEARTBEAT every 100 ms, console connection). Exit 0 on SIGTERM or
 * SIGINT (or after --max-periods) with the trace flushed and one JSON line of counters on
 * stderr; exit 2 on bad arguments or a bad parameter file; 1 when the bus, the trace or the
 * console cannot be opened.
 */
#define _GNU_SOURCE /* getopt_long, timerfd */
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>
#include <sys/timerfd.h>
#include <unistd.h>

#include "fw_host.h" /* hilnode.h: options, real time, bus, trace, ready file, counters */
#include "param_file.h"

#define LOG_LINES_PER_S 10
#define DRAIN_MAX 256 /* frames handled before the timer and the console get a turn */
#define CONSOLE_PROBE_NS (10LL * 1000000LL)

static fwh_t app; /* the core object is large: static storage, as on the DSP */
static hilbus_t *bus;

static int bus_failed; /* a node that loses no frame stayed full past the bus's stall limit */

/* The frame handlers' sink: the bus (failures and drops are counted by hilbus). A node of the
 * run (lossless) that took no frame within the stall limit ends the program: the lockstep
 * cannot go on. */
static int send_on_bus(void *ctx, const struct canfd_frame *f, int fd)
{
    (void)ctx;
    const int rc = hilbus_send(bus, f, fd);
    if (rc != 0 && errno == ETIMEDOUT && !bus_failed) {
        fprintf(stderr, "fw_host: %s\n", hilbus_last_error(bus));
        bus_failed = 1;
        app.stop = 1;
    }
    return rc;
}
static fwh_param_list_t start_list;

/* ------------------------------------------------------------------------ options */

static void usage(FILE *out)
{
    fputs("usage: fw_host [options]\n"
            "Runs the sensorless IPMSM control core on the bus: VIO_ADC in, VIO_PWM out (the\n"
            "ISR runs when a period's ADC data is complete), the drive protocol (DRIVE_CMD,\n"
            "DRIVE_LIMITS, PARAM_REQ/RESP, DRIVE_STATUS, HEARTBEAT, TLM_*) and the SCI console\n"
            "on a pseudo-terminal (protocols/console.md).\n"
            "\n",
            out);
    hil_node_usage(out);
    fputs("  --lockstep | --realtime        pacing of the plant (default lockstep); the firmware\n"
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
            "  --spin-us N                    busy-poll the bus N us before sleeping (default 0)\n"
            "  --node N                       HEARTBEAT node number (default 1)\n"
            "  --first-period N               the paired plant's first ADC period (lockstep: 0);\n"
            "                                 ADC data of other periods before it is rejected\n"
            "  --help                         this text\n"
            "\n"
            "Exit: 0 on SIGTERM/SIGINT or after --max-periods (counters as one JSON line on\n"
            "stderr), 2 on bad arguments or a bad parameter file, 1 on other errors.\n",
          out);
}

static int parse_options(int argc, char **argv, fwh_param_list_t *sets)
{
    enum {
        O_SEND_TRACE = HIL_OPT_NODE_END, O_TLM_DIV, O_PARAMS, O_SET, O_PTY_LINK, O_NO_CONSOLE,
        O_CONSOLE_TIMEOUT, O_SPIN, O_NODE, O_FIRST_PERIOD, O_HELP
    };
    static const struct option longopts[] = {
        HIL_NODE_LONGOPTS,
        {"send-trace", no_argument, 0, O_SEND_TRACE},
        {"tlm-div", required_argument, 0, O_TLM_DIV},
        {"params", required_argument, 0, O_PARAMS},
        {"config", required_argument, 0, O_PARAMS},
        {"set", required_argument, 0, O_SET},
        {"pty-link", required_argument, 0, O_PTY_LINK},
        {"no-console", no_argument, 0, O_NO_CONSOLE},
        {"console-timeout-ms", required_argument, 0, O_CONSOLE_TIMEOUT},
        {"spin-us", required_argument, 0, O_SPIN},
        {"node", required_argument, 0, O_NODE},
        {"first-period", required_argument, 0, O_FIRST_PERIOD},
        {"help", no_argument, 0, O_HELP},
        {0, 0, 0, 0},
    };
    fwh_options_t *o = &app.opt;
    int c;
    char err[512];
    hil_node_opts_init(&o->node, "fw_host");
    o->tlm_div = 1;
    o->console_timeout_ns = 5000LL * 1000000LL;
    o->node_number = 1;
    o->first_period = -1; /* any */
    sets->n = 0;
    opterr = 0;
    while ((c = getopt_long(argc, argv, "h", longopts, NULL)) != -1) {
        const int node = hil_node_option(&o->node, c, optarg);
        uint64_t v;
        if (node != 0) {
            if (node < 0) {
                return 2;
            }
            continue;
        }
        switch (c) {
        case O_SEND_TRACE: o->send_trace = 1; break;
        case O_PARAMS: o->params = optarg; break;
        case O_PTY_LINK: o->pty_link = optarg; break;
        case O_NO_CONSOLE: o->no_console = 1; break;
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
        case O_SPIN:
        case O_NODE:
        case O_FIRST_PERIOD: {
            const uint64_t max = c == O_NODE ? 255u : c == O_FIRST_PERIOD ? UINT32_MAX
                               : c == O_CONSOLE_TIMEOUT ? 86400000u : 1000000u;
            if (hil_node_u64_arg(&o->node, argv[optind - 2], optarg, max, &v) != 0) {
                return 2;
            }
            if (c == O_TLM_DIV) {
                o->tlm_div = (uint32_t)v;
            } else if (c == O_CONSOLE_TIMEOUT) {
                o->console_timeout_ns = (int64_t)v * 1000000LL;
            } else if (c == O_SPIN) {
                o->spin_us = (int32_t)v;
            } else if (c == O_NODE) {
                o->node_number = (uint8_t)v;
            } else {
                o->first_period = (int64_t)v;
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

static int open_bus(void)
{
    /* 11-bit data frames of the drive and virtual-I/O ranges (drive.dbc, vio.dbc: hil_wire.h) */
    struct can_filter filters[HIL_DRIVE_ID_BLOCKS + HIL_VIO_ID_BLOCKS];
    int n = 0, k;
    for (k = 0; k < HIL_DRIVE_ID_BLOCKS; k++, n++) {
        filters[n].can_id = hil_drive_id_blocks[k].id;
        filters[n].can_mask = hil_drive_id_blocks[k].mask | CAN_EFF_FLAG | CAN_RTR_FLAG;
    }
    for (k = 0; k < HIL_VIO_ID_BLOCKS; k++, n++) {
        filters[n].can_id = hil_vio_id_blocks[k].id;
        filters[n].can_mask = hil_vio_id_blocks[k].mask | CAN_EFF_FLAG | CAN_RTR_FLAG;
    }
    bus = hil_node_open_bus(&app.opt.node);
    if (bus == NULL) {
        return -1;
    }
    app.sink.send = send_on_bus;
    if (hilbus_set_filters(bus, filters, n) != 0) {
        fprintf(stderr, "fw_host: bus filters: %s\n", strerror(errno));
        return -1;
    }
    if (app.opt.spin_us > 0) {
        hilbus_set_spin(bus, app.opt.spin_us);
    }
    return 0;
}

/* ------------------------------------------------------------------------ main loop */

static void handle_frame(const struct canfd_frame *f, int fd)
{
    const int64_t t_rx = hil_now_ns();
    const uint32_t id = f->can_id & CAN_SFF_MASK;
    if (f->can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) {
        app.cnt.non_data_frames++; /* outside this protocol's 11-bit data frames */
        return;
    }
    if (hil_vio_id_in_range(id)) {
        fwh_bus_vio_frame(&app, f, fd, t_rx);
    } else if (hil_drive_id_in_range(id)) {
        fwh_drive_frame(&app, f, fd);
    }
}

static int periods_done(void)
{
    return app.opt.node.max_periods > 0 && app.cnt.isr >= app.opt.node.max_periods;
}

/* Receives what is waiting (and, with --spin-us, what comes within the spin). */
static int drain_bus(void)
{
    struct canfd_frame f;
    int fd, r, n = 0;
    int64_t timeout = 0;
    while (n < DRAIN_MAX && !app.stop && !periods_done()) {
        r = hilbus_recv(bus, &f, &fd, timeout);
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
        p[n].fd = hilbus_fileno(bus), p[n].events = POLLIN, p[n].revents = 0, i_bus = n++;
        p[n].fd = tfd, p[n].events = POLLIN, p[n].revents = 0, i_tim = n++;
        if (app.pty_open && !app.console_hup) {
            p[n].fd = app.pty.master;
            /* no reading while a reply waits for the client (backpressure) */
            p[n].events = (short)(app.pty.out_len > 0 ? POLLOUT
                                  : console_input_pending() ? 0 : POLLIN);
            p[n].revents = 0;
            i_pty = n++;
        }
        /* frames a send's wait took off the socket are there already: no sleeping then */
        if (poll(p, (nfds_t)n, hilbus_pending(bus) > 0 ? 0 : -1) < 0) {
            if (errno == EINTR) {
                continue;
            }
            fprintf(stderr, "fw_host: poll: %s\n", strerror(errno));
            return 1;
        }
        if ((p[i_bus].revents & (POLLIN | POLLERR)) || hilbus_pending(bus) > 0) {
            if (drain_bus() != 0) {
                return 1;
            }
        }
        now = hil_now_ns();
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
    static char buf[8192];
    hil_json_t j;
    fw_status_t s;
    const fwh_counters_t *c = &app.cnt;
    fw_core_status(&app.core, &s);
    hil_json_init(&j, buf, sizeof(buf));
    hil_node_json_begin(&j, &app.opt.node, bus);
    hil_json_u64(&j, "isr", c->isr);
    hil_json_u64(&j, "isr_no_data", c->isr_no_data);
    hil_json_u64(&j, "repeats", c->repeats);
    if (app.adc.have_last) {
        hil_json_u64(&j, "last_period", app.adc.last);
    } else {
        hil_json_raw(&j, "last_period", "null");
    }
    hil_json_u64(&j, "pwm_sent", c->pwm_sent);
    hil_json_u64(&j, "pwm_invalid", c->pwm_invalid);
    hil_json_u64(&j, "overruns", c->overruns);
    hil_json_fmt(&j, "max_latency_us", "%.1f", (double)c->max_latency_ns * 1e-3);
    hil_json_u64(&j, "rx_rejected", fwh_rejected_total(&app));
    hil_json_counts(&j, "rejects", fwh_reject_name, c->rejects, 0, FWH_REJ_COUNT);
    hil_json_u64(&j, "resyncs", c->resyncs);
    hil_json_u64(&j, "syncs", c->syncs);
    hil_json_u64(&j, "drive_cmds", c->drive_cmds);
    hil_json_u64(&j, "cmds_refused", c->cmds_refused);
    hil_json_u64(&j, "limits", c->limits);
    hil_json_u64(&j, "param_reqs", c->param_reqs);
    hil_json_u64(&j, "status_frames", c->status_frames);
    hil_json_u64(&j, "heartbeats", c->heartbeats);
    hil_json_u64(&j, "tlm_frames", c->tlm_frames);
    hil_json_u64(&j, "trace_records", c->trace_records);
    hil_json_u64(&j, "trace_sent", c->trace_sent);
    hil_json_u64(&j, "trace_errors", c->trace_errors + c->fw_trace_tx_errors);
    hil_json_u64(&j, "console_sessions", c->console_sessions);
    hil_json_u64(&j, "console_lines", c->console_lines);
    hil_json_u64(&j, "console_errors", c->console_errors);
    hil_json_u64(&j, "console_keepalive_lapses", c->console_keepalive_lapses);
    hil_json_u64(&j, "console_out_dropped", app.pty.out_dropped);
    hil_json_str(&j, "state", fwh_state_name(s.state));
    hil_json_u64(&j, "fault_code", s.fault_code);
    hil_json_str(&j, "fault_name", fwh_fault_name(s.fault_code));
    hil_json_u64(&j, "core_overruns", s.isr_overruns);
    hil_node_json_bus(&j, bus, c->non_data_frames);
    hil_json_str(&j, "rt", app.rt_note != NULL ? app.rt_note : HIL_NODE_RT_NONE);
    hil_json_end(&j);
    fprintf(stderr, "%s\n", buf);
    fflush(stderr);
}

int main(int argc, char **argv)
{
    static fwh_param_list_t sets;
    struct itimerspec its;
    int rc, tfd, trace_failed;
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
    if (!app.opt.node.realtime) {
        fwh_adc_lockstep(&app.adc); /* the plant skips a period only behind a barrier */
    }
    if (app.opt.first_period >= 0) {
        fwh_adc_expect_first(&app.adc, (uint32_t)app.opt.first_period);
    }
    if (load_parameters(&sets) != 0) {
        return 2;
    }

    hil_node_signals(&app.stop, 1); /* SIGHUP too: the console's terminal may hang up */

    if (open_bus() != 0) {
        if (bus != NULL) {
            hilbus_close(bus);
        }
        return 1;
    }
    app.trace = hil_node_open_trace(&app.opt.node, &trace_failed);
    if (trace_failed) {
        hilbus_close(bus);
        return 1;
    }
    if (!app.opt.no_console) {
        if (fwh_pty_open(&app.pty, app.opt.pty_link, err, sizeof(err)) != 0) {
            fprintf(stderr, "fw_host: console: %s\n", err);
            if (app.trace != NULL) {
                hiltrace_close(app.trace);
            }
            hilbus_close(bus);
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
    if (app.opt.node.realtime) {
        app.rt_note = hil_node_realtime(&app.opt.node);
    }
    app.t0_ns = hil_now_ns();
    app.next_status_ns = app.t0_ns;
    app.next_heartbeat_ns = app.t0_ns;
    hil_log_limit_init(&app.log_limit, "fw_host", LOG_LINES_PER_S, app.t0_ns);
    housekeeping(app.t0_ns);
    fprintf(stderr, "fw_host: %s on %s/%s, console %s%s%s\n",
            app.opt.node.realtime ? "real time" : "lockstep", hilbus_transport(bus),
            app.opt.node.channel, app.pty_open ? app.pty.slave_path : "off",
            app.pty.link[0] ? " linked from " : "", app.pty.link);
    rc = hil_node_ready(&app.opt.node) != 0 ? 1 : 0;
    if (rc == 0) {
        rc = run(tfd);
    }
    fwh_drive_send_status(&app);
    if (hil_node_close_trace(&app.opt.node, app.trace) != 0 || bus_failed) {
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
    hilbus_close(bus);
    return rc;
}
