/* bus_io.c - the virtual I/O of the DSP (protocols/vio.dbc, docs/interfaces.md).
 *
 * VIO_ADC_0..2 of period k are collected (adc_assembly.c); when complete the ISR runs and
 * VIO_PWM(k+1) goes out at once. A repeated ADC(k) is handed to the core again, which answers
 * with the same PWM(k+1). Periods whose data never came run the ISR without data (the core
 * counts the ADC loss and faults after adc_loss_max); their PWM is not sent (the plant is
 * past them). Every ISR writes one FW_TRACE record; every FW_SPEED_DIVIDER*tlm_div-th period
 * (the 1 kHz speed-loop rate, in ISR time) sends the TLM_* frames. A VIO_SYNC (the plant's lockstep
 * barrier after a faulted exchange, protocols/vio.dbc) is answered with VIO_SYNC_ACK once
 * everything received before it is handled: frames are handled in order, so its PWM (if any)
 * went out first.
 */
#include <stdio.h>
#include <string.h>

#include "codec_util.h"
#include "fw_host.h"
#include "hil_vio.h"
#include "vio_codec.h"

/* ------------------------------------------------------------------------ PWM out */

static void send_pwm(fwh_t *app, const fw_pwm_t *p, uint32_t want_period)
{
    struct canfd_frame f;
    if (!fwh_vio_pwm_pack(p, want_period, &f)) {
        app->cnt.pwm_invalid++;
        fwh_log(app, "control core produced an invalid PWM for period %lu (period %lu, n_soc "
                     "%d, gate_enable %d): sent with the gates off",
                (unsigned long)want_period, (unsigned long)p->period, p->n_soc, p->gate_enable);
    }
    (void)fwh_send(app, &f, 1); /* failures and drops are counted by the sink's owner */
    app->cnt.pwm_sent++;
}

/* ------------------------------------------------------------------------ data log */

static void write_trace(fwh_t *app, const fw_status_t *s)
{
    struct canfd_frame f;
    if (app->trace == NULL && !app->opt.send_trace) {
        return;
    }
    fwh_vio_trace_pack(s, &f);
    if (app->trace != NULL) {
        if (hiltrace_write(app->trace, &f) == 0) {
            app->cnt.trace_records++;
        } else {
            app->cnt.trace_errors++;
        }
    }
    if (app->opt.send_trace) {
        if (fwh_send(app, &f, 1) == 0) {
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
    if (app->opt.tlm_div > 0 && s.period % ((uint32_t)FW_SPEED_DIVIDER * app->opt.tlm_div) == 0u) {
        fwh_drive_telemetry(app, &s);
    }
    fwh_drive_status_if_changed(app);
}

/* ISR of a period whose ADC data never came (no PWM goes out: the plant is past it) */
static void run_isr_without_data(fwh_t *app)
{
    fw_pwm_t pwm;
    fwh_command_refresh(app, hil_now_ns());
    fwh_core_isr(app, NULL, &pwm);
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
    fwh_core_isr(app, adc, &pwm);
    send_pwm(app, &pwm, adc->period + 1u);
    latency = hil_now_ns() - t_rx_ns;
    if (latency > app->cnt.max_latency_ns) {
        app->cnt.max_latency_ns = latency;
    }
    if (app->opt.node.realtime && latency > FWH_OVERRUN_NS) {
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


static void feed(fwh_t *app, int index, uint32_t period, uint8_t n_soc, int32_t vdc,
                 const int32_t *ia, const int32_t *ib, int64_t t_rx_ns)
{
    fwh_adc_result_t r;
    uint32_t k;
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

static void answer_sync(fwh_t *app, const struct canfd_frame *f, int fd)
{
    struct hil_vio_vio_sync_t m;
    struct hil_vio_vio_sync_ack_t ack;
    struct canfd_frame out;
    if (!fd || f->len != HIL_VIO_VIO_SYNC_LENGTH) {
        fwh_reject(app, fd ? FWH_REJ_BAD_LENGTH : FWH_REJ_WRONG_FRAME_TYPE,
                   "VIO_SYNC: %s frame of length %u, expected CAN FD of %u",
                   fd ? "CAN FD" : "classic", f->len, (unsigned)HIL_VIO_VIO_SYNC_LENGTH);
        return;
    }
    hil_vio_vio_sync_unpack(&m, f->data, f->len);
    fwh_adc_barrier(&app->adc); /* the plant may skip periods from now on (adc_assembly.h) */
    memset(&ack, 0, sizeof(ack));
    ack.period = m.period;
    ack.seq = m.seq;
    memset(&out, 0, sizeof(out));
    out.can_id = HIL_VIO_VIO_SYNC_ACK_FRAME_ID;
    out.len = HIL_VIO_VIO_SYNC_ACK_LENGTH;
    hil_vio_vio_sync_ack_pack(out.data, &ack, sizeof(out.data));
    (void)fwh_send(app, &out, 1); /* failures and drops are counted by the sink's owner */
    app->cnt.syncs++;
}

void fwh_bus_vio_frame(fwh_t *app, const struct canfd_frame *f, int fd, int64_t t_rx_ns)
{
    fwh_vio_adc_t m;
    char why[160];
    int reason = 0;
    int r;
    if ((f->can_id & CAN_SFF_MASK) == HIL_VIO_VIO_SYNC_FRAME_ID) {
        answer_sync(app, f, fd);
        return;
    }
    r = fwh_vio_adc_decode(f, fd, &m, &reason, why, sizeof(why));
    if (r > 0 && !fwh_vio_adc_codes_ok(&app->core, &m, &reason, why, sizeof(why))) {
        r = -1;
    }
    if (r < 0) {
        fwh_reject(app, reason, "%s", why);
    } else if (r > 0) {
        feed(app, m.index, m.period, m.n_soc, m.vdc, m.ia, m.ib, t_rx_ns);
    }
}
