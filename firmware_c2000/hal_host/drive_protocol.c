/* drive_protocol.c - the DSP's classic-CAN drive protocol (protocols/drive.dbc).
 *
 * In: DRIVE_CMD -> fw_core_command (result in DRIVE_STATUS.cmd_status), DRIVE_LIMITS ->
 * fw_core_set_limits, PARAM_REQ (read, write, save, load) -> PARAM_RESP with the value read
 * back after the operation. Out: DRIVE_STATUS every 100 ms and on every change, HEARTBEAT
 * every 100 ms, TLM_* at the speed-loop rate (bus_io.c decides when).
 *
 * A frame with an unknown id in the drive range, a wrong length or frame type, or a signal
 * outside its DBC range is rejected (counted, logged, nothing changed). A PARAM_REQ that is
 * rejected for its op or value is still answered (BAD_OP / OUT_OF_RANGE) so the requester
 * does not wait for a time-out.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "codec_util.h"
#include "fw_host.h"
#include "drive_codec.h"
#include "hil_drive.h"
#include "param_file.h"

#define PARAM_VALUE_LIMIT 1.0e9f /* PARAM_RESP.value range */

static void send_classic(fwh_t *app, uint32_t id, const uint8_t *data, uint8_t len)
{
    struct canfd_frame f;
    memset(&f, 0, sizeof(f));
    f.can_id = id;
    f.len = len;
    memcpy(f.data, data, len);
    (void)fwh_send(app, &f, 0); /* failures are counted by the sink's owner */
}

/* ------------------------------------------------------------------------ commands */

int16_t fwh_command(fwh_t *app, const fw_cmd_t *cmd, int owner)
{
    int16_t st = fwh_core_command(app, cmd);
    if (st == FW_STATUS_OK) {
        app->cmd = *cmd;
        app->owner = owner;
    }
    return st;
}

void fwh_command_refresh(fwh_t *app, int64_t now_ns)
{
    int live;
    if (app->owner != FWH_OWNER_CONSOLE) {
        app->console_refreshing = 0;
        return;
    }
    live = app->console_connected &&
           (app->opt.console_timeout_ns == 0 ||
            now_ns - app->console_last_ns < app->opt.console_timeout_ns);
    if (live) {
        fw_cmd_t c = app->cmd;
        c.fault_reset = 0;
        (void)fwh_core_command(app, &c);
        app->console_refreshing = 1;
    } else if (app->console_refreshing) {
        app->console_refreshing = 0;
        app->cnt.console_keepalive_lapses++;
        fwh_log(app, "console session %s: its command is no longer refreshed (the command "
                     "time-out protects the drive)",
                app->console_connected ? "silent too long" : "closed");
    }
}

static void on_drive_cmd(fwh_t *app, const uint8_t *data, uint8_t len)
{
    fw_cmd_t cmd;
    char why[200];
    int16_t st;
    if (fwh_drive_cmd_decode(data, len, &cmd, why, sizeof(why)) != 0) {
        fwh_reject(app, FWH_REJ_OUT_OF_RANGE, "%s", why);
        return;
    }
    app->cnt.drive_cmds++;
    st = fwh_command(app, &cmd, FWH_OWNER_CAN);
    if (st != FW_STATUS_OK) {
        app->cnt.cmds_refused++;
        fwh_log(app, "DRIVE_CMD refused by the control core (status %d): speed_ref %.3f r/min, "
                     "iq_ref %.3f A",
                st, (double)cmd.speed_ref_rpm, (double)cmd.iq_ref);
    }
    fwh_drive_status_if_changed(app);
}

static void on_drive_limits(fwh_t *app, const uint8_t *data, uint8_t len)
{
    fwh_limits_t lim;
    char why[200];
    if (fwh_drive_limits_decode(data, len, &lim, why, sizeof(why)) != 0) {
        fwh_reject(app, FWH_REJ_OUT_OF_RANGE, "%s", why);
        return;
    }
    app->cnt.limits++;
    if (fwh_core_limits(app, (real_t)lim.i_max_a, (real_t)lim.speed_max_rpm,
                        (real_t)lim.accel_rpm_s) != FW_STATUS_OK) {
        fwh_reject(app, FWH_REJ_REFUSED,
                   "DRIVE_LIMITS refused by the control core: i_max %.3f A (must stay below "
                   "oc_trip_a), speed_max %.0f r/min, accel %.1f r/min/s",
                   lim.i_max_a, lim.speed_max_rpm, lim.accel_rpm_s);
    }
}

/* ------------------------------------------------------------------------ parameters */

int fwh_params_save_store(fwh_t *app, int *count, char *msg, size_t msglen)
{
    char err[512];
    int n;
    *count = 0;
    if (app->opt.params == NULL) {
        snprintf(msg, msglen, "no parameter file (start fw_host with --params FILE)");
        return FW_STATUS_STORE_ERROR;
    }
    n = fwh_params_save(&app->core, app->opt.params, err, sizeof(err));
    if (n < 0) {
        snprintf(msg, msglen, "%s", err);
        fwh_log(app, "SAVE failed: %s", err);
        return FW_STATUS_STORE_ERROR;
    }
    *count = n;
    return FW_STATUS_OK;
}

static fwh_param_list_t load_list; /* (large: not on the stack) */

int fwh_params_load_store(fwh_t *app, int *count, char *msg, size_t msglen)
{
    char err[512];
    int failed, changed;
    int16_t st;
    *count = 0;
    if (app->opt.params == NULL) {
        snprintf(msg, msglen, "no parameter file (start fw_host with --params FILE)");
        return FW_STATUS_STORE_ERROR;
    }
    if (fwh_params_parse_file(app->opt.params, &load_list, err, sizeof(err)) != 0) {
        snprintf(msg, msglen, "%s", err);
        fwh_log(app, "LOAD failed: %s", err);
        return FW_STATUS_STORE_ERROR;
    }
    st = fwh_params_apply(&app->core, &load_list, &failed, &changed);
    if (st != FW_STATUS_OK) {
        const fwh_param_item_t *it = &load_list.items[failed];
        snprintf(msg, msglen, "%s:%d: field '%s': %s, nothing loaded", app->opt.params,
                 it->line, it->name,
                 st == FW_STATUS_BUSY ? "configuration parameter cannot change while enabled"
                                      : "rejected by the control core (inconsistent with "
                                        "other parameters or not a whole number)");
        fwh_log(app, "LOAD failed: %s", msg);
        return st;
    }
    *count = changed;
    return FW_STATUS_OK;
}

static float read_back(const fwh_t *app, uint16_t id)
{
    real_t v = 0.0f;
    if (fw_param_get(&app->core, id, &v) != FW_STATUS_OK || !isfinite(v)) {
        return 0.0f;
    }
    return v > PARAM_VALUE_LIMIT ? PARAM_VALUE_LIMIT : v < -PARAM_VALUE_LIMIT ? -PARAM_VALUE_LIMIT
                                                                                : (float)v;
}

static void send_param_resp(fwh_t *app, const struct hil_drive_param_req_t *req, int status)
{
    struct hil_drive_param_resp_t r;
    uint8_t buf[8];
    memset(&r, 0, sizeof(r));
    r.op = (uint8_t)(req->op & 0x0Fu);
    r.status = (uint8_t)status;
    r.seq = req->seq;
    r.param_id = req->param_id;
    r.value = read_back(app, req->param_id);
    hil_drive_param_resp_pack(buf, &r, sizeof(buf));
    send_classic(app, HIL_DRIVE_PARAM_RESP_FRAME_ID, buf, HIL_DRIVE_PARAM_RESP_LENGTH);
}

static void on_param_req(fwh_t *app, const uint8_t *data, uint8_t len)
{
    struct hil_drive_param_req_t m;
    char msg[600];
    int status = FW_STATUS_OK, count;
    real_t v;
    hil_drive_param_req_unpack(&m, data, len);
    app->cnt.param_reqs++;
    if (!hil_drive_param_req_op_is_in_range(m.op)) {
        fwh_reject(app, FWH_REJ_OUT_OF_RANGE, "PARAM_REQ: op %u outside [0, 3] (seq %u)", m.op,
                   m.seq);
        send_param_resp(app, &m, FW_STATUS_BAD_OP);
        return;
    }
    if (!hil_drive_param_req_value_is_in_range(m.value) ||
        !hil_drive_param_req_seq_is_in_range(m.seq) ||
        !hil_drive_param_req_param_id_is_in_range(m.param_id)) {
        fwh_reject(app, FWH_REJ_OUT_OF_RANGE,
                   "PARAM_REQ: value %g outside its DBC range (param %u, seq %u)",
                   (double)m.value, m.param_id, m.seq);
        send_param_resp(app, &m, FW_STATUS_OUT_OF_RANGE);
        return;
    }
    switch (m.op) {
    case HIL_DRIVE_PARAM_REQ_OP_READ_CHOICE:
        status = fw_param_get(&app->core, m.param_id, &v);
        break;
    case HIL_DRIVE_PARAM_REQ_OP_WRITE_CHOICE:
        status = fw_param_set(&app->core, m.param_id, (real_t)m.value);
        break;
    case HIL_DRIVE_PARAM_REQ_OP_SAVE_CHOICE:
        status = fwh_params_save_store(app, &count, msg, sizeof(msg));
        break;
    default: /* LOAD */
        status = fwh_params_load_store(app, &count, msg, sizeof(msg));
        break;
    }
    send_param_resp(app, &m, status);
    fwh_drive_status_if_changed(app);
}

/* ------------------------------------------------------------------------ receive */

void fwh_drive_frame(fwh_t *app, const struct canfd_frame *f, int fd)
{
    char why[160];
    int reason = 0;
    switch (fwh_drive_classify(f, fd, &reason, why, sizeof(why))) {
    case FWH_DRIVE_REJECTED:
        fwh_reject(app, reason, "%s", why);
        break;
    case FWH_DRIVE_CMD:
        on_drive_cmd(app, f->data, f->len);
        break;
    case FWH_DRIVE_LIMITS:
        on_drive_limits(app, f->data, f->len);
        break;
    case FWH_DRIVE_PARAM_REQ:
        on_param_req(app, f->data, f->len);
        break;
    default:
        break; /* what a drive sends: not for us */
    }
}

/* ------------------------------------------------------------------------ send */

void fwh_drive_send_status(fwh_t *app)
{
    struct hil_drive_drive_status_t m;
    fw_status_t s;
    uint8_t buf[8];
    uint64_t rej = fwh_rejected_total(app);
    fw_core_status(&app->core, &s);
    memset(&m, 0, sizeof(m));
    m.state = (uint8_t)s.state;
    m.ctrl_mode = (uint8_t)s.ctrl_mode;
    m.fw_mode = (uint8_t)s.fw_mode;
    m.fault_code = s.fault_code;
    m.cmd_status = (uint8_t)s.cmd_status;
    m.rx_rejected = (uint16_t)(rej > 65535u ? 65535u : rej);
    m.polarity_ok = (uint8_t)(s.polarity_ok != 0);
    m.est_valid = (uint8_t)(s.est_valid != 0);
    hil_drive_drive_status_pack(buf, &m, sizeof(buf));
    send_classic(app, HIL_DRIVE_DRIVE_STATUS_FRAME_ID, buf, HIL_DRIVE_DRIVE_STATUS_LENGTH);
    app->cnt.status_frames++;
    app->sent.valid = 1;
    app->sent.state = s.state;
    app->sent.ctrl_mode = s.ctrl_mode;
    app->sent.fw_mode = s.fw_mode;
    app->sent.cmd_status = s.cmd_status;
    app->sent.polarity_ok = s.polarity_ok;
    app->sent.est_valid = s.est_valid;
    app->sent.fault_code = s.fault_code;
}

void fwh_drive_status_if_changed(fwh_t *app)
{
    fw_status_t s;
    const fwh_status_key_t *k = &app->sent;
    fw_core_status(&app->core, &s);
    if (!k->valid || k->state != s.state || k->ctrl_mode != s.ctrl_mode ||
        k->fw_mode != s.fw_mode || k->cmd_status != s.cmd_status ||
        k->polarity_ok != s.polarity_ok || k->est_valid != s.est_valid ||
        k->fault_code != s.fault_code) {
        fwh_drive_send_status(app);
    }
}

void fwh_drive_send_heartbeat(fwh_t *app)
{
    struct hil_drive_heartbeat_t m;
    fw_status_t s;
    uint8_t buf[8];
    long long uptime;
    fw_core_status(&app->core, &s);
    memset(&m, 0, sizeof(m));
    m.alive = app->alive++;
    FWH_SAT_ENCODE(uptime, hil_drive_heartbeat_uptime,
                   (double)(hil_now_ns() - app->t0_ns) * 1e-9, 0u, 4294967295u);
    m.uptime = (uint32_t)uptime;
    m.isr_overruns = s.isr_overruns;
    m.node = app->opt.node_number;
    hil_drive_heartbeat_pack(buf, &m, sizeof(buf));
    send_classic(app, HIL_DRIVE_HEARTBEAT_FRAME_ID, buf, HIL_DRIVE_HEARTBEAT_LENGTH);
    app->cnt.heartbeats++;
}

#define RAD_TO_DEG 57.295779513082320876
#define I16_MIN (-32768)
#define I16_MAX 32767

void fwh_drive_telemetry(fwh_t *app, const fw_status_t *s)
{
    uint8_t buf[8];
    long long r;
    const uint16_t period = (uint16_t)(s->period & 0xFFFFu);
    {
        struct hil_drive_tlm_pos_t m;
        double deg = (double)s->theta_hat * RAD_TO_DEG;
        memset(&m, 0, sizeof(m));
        m.period = period;
        if (!isfinite(deg)) {
            deg = 0.0;
        }
        deg = fmod(deg, 360.0);
        if (deg < 0.0) {
            deg += 360.0;
        }
        /* 360 = 0: raw 65536 wraps in the generated encoder's uint16_t (it converts through
         * uint64_t) */
        m.theta_hat = hil_drive_tlm_pos_theta_hat_encode(deg);
        FWH_SAT_ENCODE(r, hil_drive_tlm_pos_speed_hat, s->speed_hat_rpm, INT32_MIN, INT32_MAX);
        m.speed_hat = (int32_t)r;
        hil_drive_tlm_pos_pack(buf, &m, sizeof(buf));
        send_classic(app, HIL_DRIVE_TLM_POS_FRAME_ID, buf, HIL_DRIVE_TLM_POS_LENGTH);
    }
    {
        struct hil_drive_tlm_cur_t m;
        memset(&m, 0, sizeof(m));
        m.period = period;
        FWH_SAT_ENCODE(r, hil_drive_tlm_cur_id, s->id, I16_MIN, I16_MAX);
        m.id = (int16_t)r;
        FWH_SAT_ENCODE(r, hil_drive_tlm_cur_iq, s->iq, I16_MIN, I16_MAX);
        m.iq = (int16_t)r;
        FWH_SAT_ENCODE(r, hil_drive_tlm_cur_te_hat, s->te_hat, I16_MIN, I16_MAX);
        m.te_hat = (int16_t)r;
        hil_drive_tlm_cur_pack(buf, &m, sizeof(buf));
        send_classic(app, HIL_DRIVE_TLM_CUR_FRAME_ID, buf, HIL_DRIVE_TLM_CUR_LENGTH);
    }
    {
        struct hil_drive_tlm_ref_t m;
        memset(&m, 0, sizeof(m));
        m.period = period;
        FWH_SAT_ENCODE(r, hil_drive_tlm_ref_id_ref, s->id_ref, I16_MIN, I16_MAX);
        m.id_ref = (int16_t)r;
        FWH_SAT_ENCODE(r, hil_drive_tlm_ref_iq_ref, s->iq_ref, I16_MIN, I16_MAX);
        m.iq_ref = (int16_t)r;
        FWH_SAT_ENCODE(r, hil_drive_tlm_ref_speed_ref, s->speed_ref_ramped_rpm, I16_MIN,
                       I16_MAX);
        m.speed_ref = (int16_t)r;
        hil_drive_tlm_ref_pack(buf, &m, sizeof(buf));
        send_classic(app, HIL_DRIVE_TLM_REF_FRAME_ID, buf, HIL_DRIVE_TLM_REF_LENGTH);
    }
    {
        struct hil_drive_tlm_param_t m;
        memset(&m, 0, sizeof(m));
        m.period = period;
        FWH_SAT_ENCODE(r, hil_drive_tlm_param_ld_hat, s->ld_hat, 0u, 65535u);
        m.ld_hat = (uint16_t)r;
        FWH_SAT_ENCODE(r, hil_drive_tlm_param_lq_hat, s->lq_hat, 0u, 65535u);
        m.lq_hat = (uint16_t)r;
        FWH_SAT_ENCODE(r, hil_drive_tlm_param_lambda_hat, s->lambda_hat, 0u, 65535u);
        m.lambda_hat = (uint16_t)r;
        hil_drive_tlm_param_pack(buf, &m, sizeof(buf));
        send_classic(app, HIL_DRIVE_TLM_PARAM_FRAME_ID, buf, HIL_DRIVE_TLM_PARAM_LENGTH);
    }
    {
        struct hil_drive_tlm_volt_t m;
        memset(&m, 0, sizeof(m));
        m.period = period;
        FWH_SAT_ENCODE(r, hil_drive_tlm_volt_vd, s->vd_mean, I16_MIN, I16_MAX);
        m.vd = (int16_t)r;
        FWH_SAT_ENCODE(r, hil_drive_tlm_volt_vq, s->vq_mean, I16_MIN, I16_MAX);
        m.vq = (int16_t)r;
        m.sector = (uint8_t)(s->sector >= 0 && s->sector <= 6 ? s->sector : 0);
        m.slopes_ok = (uint8_t)(s->slopes_ok >= 0 && s->slopes_ok <= 3 ? s->slopes_ok : 0);
        m.fw_active = (uint8_t)(s->fw_active != 0);
        hil_drive_tlm_volt_pack(buf, &m, sizeof(buf));
        send_classic(app, HIL_DRIVE_TLM_VOLT_FRAME_ID, buf, HIL_DRIVE_TLM_VOLT_LENGTH);
    }
    app->cnt.tlm_frames += 5;
}
