/* console.c - the SCI console: a line protocol on the pseudo-terminal.
 *
 * protocols/console.md is the grammar; the command table is generated from
 * protocols/console.json (tools/gen_console.py). Each non-blank line gets exactly one reply that
 * ends with a line starting "OK" or "ERR <code> "; list commands send data lines starting
 * "- " before it. No echo, no unsolicited output. A bad line changes nothing.
 *
 * Console and CAN commands both write the one drive command of the HAL (last writer wins).
 * While the console owns the command it is refreshed before every ISR for as long as the
 * console session is live (client connected and a line within --console-timeout-ms); after
 * that the control core's command time-out (cmd_timeout_ms, ISR ticks) protects the drive.
 */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "console_gen.h"
#include "fw_host.h"
#include "param_file.h"

#define MAX_TOKENS 4

static struct {
    char buf[CON_MAX_LINE + 1];
    int len;
    int overflow;
    int bad_char;
} line;

static void out_line(fwh_t *app, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void out_line(fwh_t *app, const char *fmt, ...)
{
    char buf[1024];
    va_list ap;
    int n;
    va_start(ap, fmt);
    n = vsnprintf(buf, sizeof(buf) - 2, fmt, ap);
    va_end(ap);
    if (n < 0) {
        return;
    }
    if ((size_t)n > sizeof(buf) - 3) {
        n = (int)(sizeof(buf) - 3);
    }
    buf[n++] = '\r';
    buf[n++] = '\n';
    fwh_pty_write(&app->pty, buf, (size_t)n);
}

static void err_line(fwh_t *app, int code, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

static void err_line(fwh_t *app, int code, const char *fmt, ...)
{
    char msg[600];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);
    out_line(app, "ERR %d %s", code, msg);
    app->cnt.console_errors++;
}

static const char *ctrl_name(int16_t m)
{
    return m == FW_CTRL_CURRENT ? "current" : "speed";
}

static const char *fwmode_name(int16_t m)
{
    return m == FW_FWMODE_CONVENTIONAL ? "conventional" : m == FW_FWMODE_ID_ZERO ? "id_zero"
                                                                                : "realtime";
}

static const char *owner_name(int o)
{
    return o == FWH_OWNER_CAN ? "can" : o == FWH_OWNER_CONSOLE ? "console" : "none";
}

/* ------------------------------------------------------------------------ commands */

static void map_status_error(fwh_t *app, int16_t st, const char *what)
{
    switch (st) {
    case FW_STATUS_UNKNOWN_ID:
        err_line(app, CON_ERR_UNKNOWN_PARAM, "%s: unknown parameter", what);
        break;
    case FW_STATUS_READ_ONLY:
        err_line(app, CON_ERR_READ_ONLY, "%s: read-only parameter", what);
        break;
    case FW_STATUS_BUSY:
        err_line(app, CON_ERR_BUSY, "%s: configuration parameter, disable the drive first", what);
        break;
    default:
        err_line(app, CON_ERR_OUT_OF_RANGE,
                 "%s: refused by the control core (outside the range, not a whole number, or "
                 "inconsistent with other parameters or limits)",
                 what);
        break;
    }
}

static void cmd_status(fwh_t *app)
{
    fw_status_t s;
    fw_core_status(&app->core, &s);
    out_line(app,
             "OK state=%s fault=%u fault_name=%s enable=%d ctrl=%s fw=%s owner=%s period=%lu "
             "speed_ref=%.6g speed_ramp=%.6g speed=%.6g iq_ref_cmd=%.6g id=%.6g iq=%.6g "
             "id_ref=%.6g iq_ref=%.6g theta=%.6g est_valid=%d polarity_ok=%d cmd_status=%d "
             "overruns=%u rx_rejected=%llu",
             fwh_state_name(s.state), s.fault_code, fwh_fault_name(s.fault_code),
             app->cmd.enable, ctrl_name(s.ctrl_mode), fwmode_name(s.fw_mode),
             owner_name(app->owner), (unsigned long)s.period, (double)app->cmd.speed_ref_rpm,
             (double)s.speed_ref_ramped_rpm, (double)s.speed_hat_rpm, (double)app->cmd.iq_ref,
             (double)s.id, (double)s.iq, (double)s.id_ref, (double)s.iq_ref,
             (double)s.theta_hat * 57.295779513082320876, s.est_valid, s.polarity_ok,
             s.cmd_status, s.isr_overruns, (unsigned long long)fwh_rejected_total(app));
}

static void cmd_counters(fwh_t *app)
{
    const fwh_counters_t *c = &app->cnt;
    out_line(app,
             "OK isr=%llu isr_no_data=%llu repeats=%llu pwm_sent=%llu overruns=%llu "
             "max_latency_us=%.1f rx_rejected=%llu resyncs=%llu drive_cmds=%llu "
             "cmds_refused=%llu param_reqs=%llu console_lines=%llu console_errors=%llu",
             (unsigned long long)c->isr, (unsigned long long)c->isr_no_data,
             (unsigned long long)c->repeats, (unsigned long long)c->pwm_sent,
             (unsigned long long)c->overruns, (double)c->max_latency_ns * 1e-3,
             (unsigned long long)fwh_rejected_total(app), (unsigned long long)c->resyncs,
             (unsigned long long)c->drive_cmds, (unsigned long long)c->cmds_refused,
             (unsigned long long)c->param_reqs, (unsigned long long)c->console_lines,
             (unsigned long long)c->console_errors);
}

static void cmd_params(fwh_t *app)
{
    uint16_t i;
    const fw_param_info_t *p;
    char v[32], lo[32], hi[32];
    for (i = 0; (p = fw_param_info_at(i)) != NULL; i++) {
        real_t value = 0.0f;
        (void)fw_param_get(&app->core, p->id, &value);
        fwh_fmt_real(v, sizeof(v), value);
        fwh_fmt_real(lo, sizeof(lo), p->min);
        fwh_fmt_real(hi, sizeof(hi), p->max);
        out_line(app, "- id=%u name=%s value=%s unit=%s min=%s max=%s access=%s", p->id,
                 p->name, v, p->unit, lo, hi, p->read_only ? "ro" : "rw");
    }
    out_line(app, "OK %u", (unsigned)fw_param_count());
}

/* sends a drive command built from the present one; replies ERR when the core refuses */
static int drive_command(fwh_t *app, const fw_cmd_t *c, const char *what)
{
    int16_t st = fwh_command(app, c, FWH_OWNER_CONSOLE);
    if (st != FW_STATUS_OK) {
        err_line(app, CON_ERR_OUT_OF_RANGE,
                 "%s refused by the control core (status %d: outside speed_max_rpm / i_max_a "
                 "or invalid)",
                 what, st);
        return -1;
    }
    fwh_drive_status_if_changed(app);
    return 0;
}

static fw_cmd_t base_command(const fwh_t *app)
{
    fw_cmd_t c = app->cmd;
    c.fault_reset = 0;
    return c;
}

static void execute(fwh_t *app, char **tok, int ntok, const con_cmd_info_t *cmd)
{
    char num[32];
    double v = 0.0;
    int choice = -1, a;
    const fw_param_info_t *param = NULL;
    fw_cmd_t c;
    fw_status_t s;
    int16_t st;
    real_t value;

    /* arguments, left to right */
    if (ntok - 1 != cmd->n_args) {
        err_line(app, CON_ERR_BAD_ARG_COUNT, "usage: %s", cmd->usage);
        return;
    }
    for (a = 0; a < cmd->n_args; a++) {
        const con_arg_info_t *ai = &cmd->args[a];
        const char *t = tok[a + 1];
        if (ai->type == CON_ARG_PARAM) {
            param = fwh_param_by_name(t);
            if (param == NULL) {
                err_line(app, CON_ERR_UNKNOWN_PARAM, "unknown parameter '%s'", t);
                return;
            }
        } else if (ai->type == CON_ARG_NUMBER) {
            if (fwh_parse_number(t, &v) != 0) {
                err_line(app, CON_ERR_BAD_VALUE, "'%s' is not a decimal number", t);
                return;
            }
        } else {
            int k;
            for (k = 0; k < ai->n_choices; k++) {
                if (strcmp(t, ai->choices[k]) == 0) {
                    choice = k;
                }
            }
            if (choice < 0) {
                err_line(app, CON_ERR_BAD_VALUE, "'%s' is not one of: %s", t, cmd->usage);
                return;
            }
        }
    }
    fw_core_status(&app->core, &s);
    c = base_command(app);
    switch (cmd->id) {
    case CON_CMD_HELP: {
        int k;
        for (k = 0; k < CON_CMD_COUNT; k++) {
            out_line(app, "- %s : %s", con_commands[k].usage, con_commands[k].summary);
        }
        out_line(app, "OK %d", (int)CON_CMD_COUNT);
        break;
    }
    case CON_CMD_VERSION: {
        real_t core_version = 0.0f;
        const fw_param_info_t *vp = fwh_param_by_name("fw_version");
        if (vp != NULL) {
            (void)fw_param_get(&app->core, vp->id, &core_version);
        }
        out_line(app, "OK fw_host=%s core=%.0f console=%d", FWH_VERSION, (double)core_version,
                 CON_VERSION);
        break;
    }
    case CON_CMD_STATUS:
        cmd_status(app);
        break;
    case CON_CMD_COUNTERS:
        cmd_counters(app);
        break;
    case CON_CMD_PARAMS:
        cmd_params(app);
        break;
    case CON_CMD_GET:
        (void)fw_param_get(&app->core, param->id, &value);
        fwh_fmt_real(num, sizeof(num), value);
        out_line(app, "OK %s", num);
        break;
    case CON_CMD_SET:
        if (param->read_only) {
            err_line(app, CON_ERR_READ_ONLY, "'%s' is read-only", param->name);
            break;
        }
        st = fw_param_set(&app->core, param->id, (real_t)v);
        if (st != FW_STATUS_OK) {
            char lo[32], hi[32], what[160];
            fwh_fmt_real(lo, sizeof(lo), param->min);
            fwh_fmt_real(hi, sizeof(hi), param->max);
            snprintf(what, sizeof(what), "%s = %s [%s, %s] %s", param->name, tok[2], lo, hi,
                     param->unit);
            map_status_error(app, st, what);
            break;
        }
        (void)fw_param_get(&app->core, param->id, &value);
        fwh_fmt_real(num, sizeof(num), value);
        out_line(app, "OK %s", num);
        fwh_drive_status_if_changed(app);
        break;
    case CON_CMD_ENABLE:
        if (s.state == FW_STATE_FAULT) {
            err_line(app, CON_ERR_FAULTED, "drive in FAULT %s (%u): send reset first",
                     fwh_fault_name(s.fault_code), s.fault_code);
            break;
        }
        if (s.state != FW_STATE_POLARITY && s.state != FW_STATE_RUN && app->cmd.enable) {
            /* the core starts on a rising edge of enable: make one */
            fw_cmd_t off = c;
            off.enable = 0;
            if (drive_command(app, &off, "enable") != 0) {
                break;
            }
        }
        c.enable = 1;
        if (drive_command(app, &c, "enable") == 0) {
            out_line(app, "OK");
        }
        break;
    case CON_CMD_DISABLE:
        c.enable = 0;
        if (drive_command(app, &c, "disable") == 0) {
            out_line(app, "OK");
        }
        break;
    case CON_CMD_RESET:
        c.enable = 0;
        c.fault_reset = 1;
        if (drive_command(app, &c, "reset") == 0) {
            c.fault_reset = 0; /* the core acts on the rising edge; do not keep it asserted */
            (void)drive_command(app, &c, "reset");
            out_line(app, "OK");
        }
        break;
    case CON_CMD_SPEED:
        c.speed_ref_rpm = (real_t)v;
        if (drive_command(app, &c, "speed") == 0) {
            fwh_fmt_real(num, sizeof(num), c.speed_ref_rpm);
            out_line(app, "OK %s", num);
        }
        break;
    case CON_CMD_IQ:
        c.iq_ref = (real_t)v;
        if (drive_command(app, &c, "iq") == 0) {
            fwh_fmt_real(num, sizeof(num), c.iq_ref);
            out_line(app, "OK %s", num);
        }
        break;
    case CON_CMD_MODE:
        c.ctrl_mode = (int16_t)(choice == 1 ? FW_CTRL_CURRENT : FW_CTRL_SPEED);
        if (drive_command(app, &c, "mode") == 0) {
            out_line(app, "OK %s", ctrl_name(c.ctrl_mode));
        }
        break;
    case CON_CMD_FWMODE:
        c.fw_mode = (int16_t)(choice == 1 ? FW_FWMODE_CONVENTIONAL
                              : choice == 2 ? FW_FWMODE_ID_ZERO
                                            : FW_FWMODE_REALTIME);
        if (drive_command(app, &c, "fwmode") == 0) {
            out_line(app, "OK %s", fwmode_name(c.fw_mode));
        }
        break;
    case CON_CMD_SAVE:
    case CON_CMD_LOAD: {
        char msg[700];
        int n = 0;
        int rc = cmd->id == CON_CMD_SAVE ? fwh_params_save_store(app, &n, msg, sizeof(msg))
                                         : fwh_params_load_store(app, &n, msg, sizeof(msg));
        if (rc == FW_STATUS_OK) {
            out_line(app, "OK %d", n);
            fwh_drive_status_if_changed(app);
        } else if (rc == FW_STATUS_BUSY) {
            err_line(app, CON_ERR_BUSY, "%s", msg);
        } else if (rc == FW_STATUS_STORE_ERROR) {
            err_line(app, CON_ERR_STORE_ERROR, "%s", msg);
        } else {
            err_line(app, CON_ERR_OUT_OF_RANGE, "%s", msg);
        }
        break;
    }
    case CON_CMD_PING:
        out_line(app, "OK");
        break;
    case CON_CMD_COUNT:
        break;
    }
}

static void process_line(fwh_t *app, char *text)
{
    char *tok[MAX_TOKENS + 1];
    int ntok = 0, k;
    char *p = text;
    while (*p != '\0') {
        while (*p == ' ' || *p == '\t') {
            *p++ = '\0';
        }
        if (*p == '\0') {
            break;
        }
        if (ntok <= MAX_TOKENS) {
            tok[ntok] = p;
        }
        ntok++;
        while (*p != '\0' && *p != ' ' && *p != '\t') {
            p++;
        }
    }
    if (ntok == 0) {
        return; /* blank line: no reply */
    }
    app->cnt.console_lines++;
    for (k = 0; k < CON_CMD_COUNT; k++) {
        if (strcmp(tok[0], con_commands[k].name) == 0) {
            if (ntok > MAX_TOKENS) {
                err_line(app, CON_ERR_BAD_ARG_COUNT, "usage: %s", con_commands[k].usage);
                return;
            }
            execute(app, tok, ntok, &con_commands[k]);
            return;
        }
    }
    err_line(app, CON_ERR_UNKNOWN_COMMAND, "unknown command '%.32s' (try help)", tok[0]);
}

size_t fwh_console_input(fwh_t *app, const char *data, size_t len, int64_t now_ns)
{
    size_t i;
    for (i = 0; i < len; i++) {
        if (app->pty.out_len > 0 && i > 0 && (data[i - 1] == '\r' || data[i - 1] == '\n')) {
            /* a reply is still queued: the next line waits until the client has read it
             * (backpressure; a reply is never dropped, protocols/console.md) */
            return i;
        }
        const unsigned char ch = (unsigned char)data[i];
        if (ch == '\r' || ch == '\n') {
            int had = line.len > 0 || line.overflow || line.bad_char;
            line.buf[line.len] = '\0';
            if (had) {
                app->console_last_ns = now_ns;
            }
            if (line.overflow) {
                app->cnt.console_lines++;
                err_line(app, CON_ERR_LINE_TOO_LONG, "line longer than %d characters, discarded",
                         CON_MAX_LINE);
            } else if (line.bad_char) {
                app->cnt.console_lines++;
                err_line(app, CON_ERR_BAD_CHAR,
                         "line holds a byte outside printable ASCII, discarded");
            } else if (line.len > 0) {
                process_line(app, line.buf);
            }
            line.len = 0;
            line.overflow = 0;
            line.bad_char = 0;
            continue;
        }
        if (line.overflow) {
            continue;
        }
        if (line.len >= CON_MAX_LINE) {
            line.overflow = 1;
            continue;
        }
        if (!(ch == '\t' || (ch >= 0x20u && ch <= 0x7Eu))) {
            line.bad_char = 1;
        }
        line.buf[line.len++] = (char)ch;
    }
    return len;
}

void fwh_console_hangup(fwh_t *app)
{
    line.len = 0;
    line.overflow = 0;
    line.bad_char = 0;
    fwh_pty_discard(&app->pty);
}
