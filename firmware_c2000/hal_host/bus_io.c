/* bus_io.c - the virtual I/O of the DSP (protocols/vio.dbc, docs/interfaces.md).
 *
 * VIO_ADC_0..2 of period k are collected (adc_assembly.c); when complete the ISR runs and
 * VIO_PWM(k+1) goes out at once. A repeated ADC(k) is handed to the core again, which answers
 * with the same PWM(k+1). Periods whose data never came run the ISR without data (the core
 * counts the ADC loss and faults after adc_loss_max); their PWM is not sent (the plant is
 * past them). Every ISR writes one FW_TRACE record; every 10*tlm_div-th period (the 1 kHz
 * speed-loop rate, in ISR time) sends the TLM_* frames.
 */
#include <stdio.h>
#include <string.h>

#include "codec_util.h"
#include "fw_host.h"
#include "hil_vio.h"
#include "param_file.h"

#define VIO_RANGE_LO 0x10u
#define VIO_RANGE_HI 0x2Fu

int fwh_bus_is_vio(uint32_t id)
{
    return id >= VIO_RANGE_LO && id <= VIO_RANGE_HI;
}

/* ------------------------------------------------------------------------ PWM out */

static int pwm_valid(const fw_pwm_t *p, uint32_t want_period)
{
    int x;
    if (p->period != want_period || p->n_soc < 0 || p->n_soc > FW_MAX_SOC ||
        (p->gate_enable != 0 && p->gate_enable != 1)) {
        return 0;
    }
    for (x = 0; x < 3; x++) {
        if (!hil_vio_vio_pwm_cmp_a_up_is_in_range(p->cmp_up[x]) ||
            !hil_vio_vio_pwm_cmp_a_dn_is_in_range(p->cmp_dn[x])) {
            return 0;
        }
    }
    for (x = 0; x < p->n_soc; x++) {
        if (!hil_vio_vio_pwm_soc_0_is_in_range(p->soc[x])) {
            return 0;
        }
    }
    return 1;
}

static void send_pwm(fwh_t *app, const fw_pwm_t *in, uint32_t want_period)
{
    struct hil_vio_vio_pwm_t m;
    struct canfd_frame f;
    uint16_t soc[FW_MAX_SOC];
    fw_pwm_t p = *in;
    int k;
    if (!pwm_valid(&p, want_period)) {
        /* never put a value outside the DBC on the wire: gates off for that period */
        app->cnt.pwm_invalid++;
        fwh_log(app, "control core produced an invalid PWM for period %lu (period %lu, n_soc "
                     "%d, gate_enable %d): sent with the gates off",
                (unsigned long)want_period, (unsigned long)p.period, p.n_soc, p.gate_enable);
        memset(&p, 0, sizeof(p));
        p.period = want_period;
        for (k = 0; k < 3; k++) {
            p.cmp_up[k] = p.cmp_dn[k] = (uint16_t)FW_TBPRD;
        }
        p.n_soc = 0;
    }
    for (k = 0; k < FW_MAX_SOC; k++) {
        soc[k] = k < p.n_soc ? p.soc[k] : 0u;
    }
    memset(&m, 0, sizeof(m));
    m.period = p.period;
    m.cmp_a_up = p.cmp_up[0];
    m.cmp_a_dn = p.cmp_dn[0];
    m.cmp_b_up = p.cmp_up[1];
    m.cmp_b_dn = p.cmp_dn[1];
    m.cmp_c_up = p.cmp_up[2];
    m.cmp_c_dn = p.cmp_dn[2];
    m.n_soc = (uint8_t)p.n_soc;
    m.gate_enable = (uint8_t)p.gate_enable;
    m.soc_0 = soc[0], m.soc_1 = soc[1], m.soc_2 = soc[2], m.soc_3 = soc[3];
    m.soc_4 = soc[4], m.soc_5 = soc[5], m.soc_6 = soc[6], m.soc_7 = soc[7];
    m.soc_8 = soc[8], m.soc_9 = soc[9], m.soc_10 = soc[10], m.soc_11 = soc[11];
    m.soc_12 = soc[12], m.soc_13 = soc[13], m.soc_14 = soc[14], m.soc_15 = soc[15];
    memset(&f, 0, sizeof(f));
    f.can_id = HIL_VIO_VIO_PWM_FRAME_ID;
    f.len = HIL_VIO_VIO_PWM_LENGTH;
    hil_vio_vio_pwm_pack(f.data, &m, sizeof(f.data));
    (void)hilbus_send(app->bus, &f, 1); /* failures and drops are counted by hilbus */
    app->cnt.pwm_sent++;
}

/* ------------------------------------------------------------------------ data log */

static void write_trace(fwh_t *app, const fw_status_t *s)
{
    struct hil_vio_fw_trace_t m;
    struct canfd_frame f;
    if (app->trace == NULL && !app->opt.send_trace) {
        return;
    }
    memset(&m, 0, sizeof(m));
    m.period = s->period;
    m.stamp = s->stamp;
    m.state = (uint8_t)(s->state >= 0 && s->state <= 4 ? s->state : 4);
    m.slopes_ok = (uint8_t)(s->slopes_ok >= 0 && s->slopes_ok <= 3 ? s->slopes_ok : 0);
    m.sector = (uint8_t)(s->sector >= 0 && s->sector <= 6 ? s->sector : 0);
    m.fw_active = (uint8_t)(s->fw_active != 0);
    m.theta_hat = s->theta_hat;
    m.omega_hat = s->omega_hat;
    m.id = s->id;
    m.iq = s->iq;
    m.id_ref = s->id_ref;
    m.iq_ref = s->iq_ref;
    m.vd = s->vd;
    m.vq = s->vq;
    m.ld_hat = s->ld_hat;
    m.lq_hat = s->lq_hat;
    m.lambda_hat = s->lambda_hat;
    m.te_hat = s->te_hat;
    m.theta_raw = s->theta_raw;
    m.residual = s->residual;
    memset(&f, 0, sizeof(f));
    f.can_id = HIL_VIO_FW_TRACE_FRAME_ID;
    f.len = HIL_VIO_FW_TRACE_LENGTH;
    hil_vio_fw_trace_pack(f.data, &m, sizeof(f.data));
    if (app->trace != NULL) {
        if (hiltrace_write(app->trace, &f) == 0) {
            app->cnt.trace_records++;
        } else {
            app->cnt.trace_errors++;
        }
    }
    if (app->opt.send_trace) {
        if (hilbus_send(app->bus, &f, 1) == 0) {
            app->cnt.trace_sent++;
        } else {
            app->cnt.fw_trace_tx_errors++;
        }
    }
}

/* ------------------------------------------------------------------------ ISR */

static void after_isr(fwh_t *app)
{
    fw_status_t s;
    fw_core_status(&app->core, &s);
    write_trace(app, &s);
    if (app->opt.tlm_div > 0 && s.period % (10u * app->opt.tlm_div) == 0u) {
        fwh_drive_telemetry(app, &s);
    }
    fwh_drive_status_if_changed(app);
}

/* ISR of a period whose ADC data never came (no PWM goes out: the plant is past it) */
static void run_isr_without_data(fwh_t *app)
{
    fw_pwm_t pwm;
    fwh_command_refresh(app, fwh_now_ns());
    fw_core_isr(&app->core, NULL, &pwm);
    app->cnt.isr++;
    app->cnt.isr_no_data++;
    after_isr(app);
}

static void run_isr(fwh_t *app, const fw_adc_t *adc, int repeat, int64_t t_rx_ns)
{
    fw_pwm_t pwm;
    int64_t latency;
    if (!repeat) {
        fwh_command_refresh(app, t_rx_ns);
    }
    fw_core_isr(&app->core, adc, &pwm);
    send_pwm(app, &pwm, adc->period + 1u);
    latency = fwh_now_ns() - t_rx_ns;
    if (latency > app->cnt.max_latency_ns) {
        app->cnt.max_latency_ns = latency;
    }
    if (app->opt.realtime && latency > FWH_OVERRUN_NS) {
        /* PWM(k+1) left after the plant's next period had (nearly) begun */
        fw_core_note_overrun(&app->core);
        app->cnt.overruns++;
    }
    if (repeat) {
        app->cnt.repeats++;
        return;
    }
    app->cnt.isr++;
    after_isr(app);
}

/* ------------------------------------------------------------------------ receive */

/* Every current code of a frame within the converter's range, 0 .. 2^N - 1 with N the
 * adc_bits parameter (docs/interfaces.md, ADC codes); unused slots are 0. */
static int codes_in_range(fwh_t *app, const int32_t *ia, const int32_t *ib)
{
    static const fw_param_info_t *adc_bits; /* looked up by name once */
    real_t bits = FW_REAL(0.0);
    int32_t top;
    int k;
    if (adc_bits == NULL) {
        adc_bits = fwh_param_by_name("adc_bits");
    }
    if (adc_bits == NULL || fw_param_get(&app->core, adc_bits->id, &bits) != FW_STATUS_OK ||
        !(bits >= 1.0f) ||
        !(bits <= 30.0f)) {
        return 1; /* the core checks the codes again in any case */
    }
    top = (int32_t)(((int64_t)1 << (int)bits) - 1);
    for (k = 0; k < 7; k++) {
        if (ia[k] < 0 || ia[k] > top || ib[k] < 0 || ib[k] > top) {
            return 0;
        }
    }
    return 1;
}

static void feed(fwh_t *app, int index, uint32_t period, uint8_t n_soc, int32_t vdc,
                 const int32_t *ia, const int32_t *ib, int64_t t_rx_ns)
{
    fwh_adc_result_t r;
    uint32_t k;
    if (!hil_vio_vio_adc_0_n_soc_is_in_range(n_soc)) {
        fwh_reject(app, FWH_REJ_OUT_OF_RANGE, "VIO_ADC_%d period %lu: n_soc %u outside [0, 16]",
                   index, (unsigned long)period, n_soc);
        return;
    }
    if (!codes_in_range(app, ia, ib)) {
        fwh_reject(app, FWH_REJ_OUT_OF_RANGE,
                   "VIO_ADC_%d period %lu: a current code outside the converter's 0 .. 2^N-1",
                   index, (unsigned long)period);
        return;
    }
    fwh_adc_feed(&app->adc, index, period, (int16_t)n_soc, vdc, ia, ib, &r);
    if (r.incomplete) {
        fwh_reject(app, FWH_REJ_INCOMPLETE,
                   "ADC data of a period ended incomplete (VIO_ADC_%d of period %lu arrived)",
                   index, (unsigned long)period);
    }
    if (r.resynced) {
        app->cnt.resyncs++;
        fwh_log(app, "ADC periods restarted at %lu: following the new sequence",
                (unsigned long)period);
    }
    for (k = 0; k < r.n_lost; k++) {
        run_isr_without_data(app);
    }
    switch (r.verdict) {
    case FWH_ADC_OK:
        break;
    case FWH_ADC_STALE:
        fwh_reject(app, FWH_REJ_STALE_PERIOD, "VIO_ADC_%d: stale period %lu (last ISR: %lu)",
                   index, (unsigned long)period, (unsigned long)app->adc.last);
        return;
    case FWH_ADC_FUTURE:
        fwh_reject(app, FWH_REJ_FUTURE_PERIOD,
                   "VIO_ADC_%d: period %lu is more than %u periods after the last ISR (%lu)",
                   index, (unsigned long)period, FWH_ADC_MAX_GAP, (unsigned long)app->adc.last);
        return;
    default:
        fwh_reject(app, FWH_REJ_MALFORMED,
                   "VIO_ADC_%d period %lu: n_soc %u disagrees with the period's other frames "
                   "or does not call for this frame",
                   index, (unsigned long)period, n_soc);
        return;
    }
    if (r.complete) {
        run_isr(app, r.adc, r.repeat, t_rx_ns);
    }
}

void fwh_bus_vio_frame(fwh_t *app, const struct canfd_frame *f, int fd, int64_t t_rx_ns)
{
    const uint32_t id = f->can_id & CAN_SFF_MASK;
    int32_t ia[7], ib[7];
    int index;
    switch (id) {
    case HIL_VIO_VIO_ADC_0_FRAME_ID:
        index = 0;
        break;
    case HIL_VIO_VIO_ADC_1_FRAME_ID:
        index = 1;
        break;
    case HIL_VIO_VIO_ADC_2_FRAME_ID:
        index = 2;
        break;
    case HIL_VIO_VIO_PWM_FRAME_ID:
    case HIL_VIO_FW_TRACE_FRAME_ID:
        return; /* what a firmware sends: not for us */
    default:
        fwh_reject(app, FWH_REJ_UNKNOWN_ID, "id 0x%03X: no such virtual-I/O message",
                   (unsigned)id);
        return;
    }
    if (!fd) {
        fwh_reject(app, FWH_REJ_WRONG_FRAME_TYPE,
                   "VIO_ADC_%d: classic CAN frame, virtual I/O is CAN FD", index);
        return;
    }
    if (f->len != 64u) {
        fwh_reject(app, FWH_REJ_BAD_LENGTH, "VIO_ADC_%d: length %u, expected 64", index,
                   f->len);
        return;
    }
    memset(ia, 0, sizeof(ia));
    memset(ib, 0, sizeof(ib));
    if (index == 0) {
        struct hil_vio_vio_adc_0_t m;
        hil_vio_vio_adc_0_unpack(&m, f->data, f->len);
        if (!hil_vio_vio_adc_0_vdc_code_is_in_range(m.vdc_code)) {
            fwh_reject(app, FWH_REJ_OUT_OF_RANGE, "VIO_ADC_0: vdc_code outside its range");
            return;
        }
        ia[0] = m.ia_0, ib[0] = m.ib_0, ia[1] = m.ia_1, ib[1] = m.ib_1;
        ia[2] = m.ia_2, ib[2] = m.ib_2, ia[3] = m.ia_3, ib[3] = m.ib_3;
        ia[4] = m.ia_4, ib[4] = m.ib_4, ia[5] = m.ia_5, ib[5] = m.ib_5;
        ia[6] = m.ia_6, ib[6] = m.ib_6;
        feed(app, 0, m.period, m.n_soc, m.vdc_code, ia, ib, t_rx_ns);
    } else if (index == 1) {
        struct hil_vio_vio_adc_1_t m;
        hil_vio_vio_adc_1_unpack(&m, f->data, f->len);
        if (!hil_vio_vio_adc_1_vdc_code_is_in_range(m.vdc_code)) {
            fwh_reject(app, FWH_REJ_OUT_OF_RANGE, "VIO_ADC_1: vdc_code outside its range");
            return;
        }
        ia[0] = m.ia_7, ib[0] = m.ib_7, ia[1] = m.ia_8, ib[1] = m.ib_8;
        ia[2] = m.ia_9, ib[2] = m.ib_9, ia[3] = m.ia_10, ib[3] = m.ib_10;
        ia[4] = m.ia_11, ib[4] = m.ib_11, ia[5] = m.ia_12, ib[5] = m.ib_12;
        ia[6] = m.ia_13, ib[6] = m.ib_13;
        feed(app, 1, m.period, m.n_soc, m.vdc_code, ia, ib, t_rx_ns);
    } else {
        struct hil_vio_vio_adc_2_t m;
        hil_vio_vio_adc_2_unpack(&m, f->data, f->len);
        if (!hil_vio_vio_adc_2_vdc_code_is_in_range(m.vdc_code)) {
            fwh_reject(app, FWH_REJ_OUT_OF_RANGE, "VIO_ADC_2: vdc_code outside its range");
            return;
        }
        ia[0] = m.ia_14, ib[0] = m.ib_14, ia[1] = m.ia_15, ib[1] = m.ib_15;
        feed(app, 2, m.period, m.n_soc, m.vdc_code, ia, ib, t_rx_ns);
    }
}
