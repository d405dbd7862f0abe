/* vio_codec.c - see vio_codec.h. Moved out of bus_io.c (frame checks and unpacking of
 * VIO_ADC, packing of VIO_PWM and FW_TRACE) so that the in-process bench shares it. */
#include "vio_codec.h"

#include <stdio.h>
#include <string.h>

#include "fw_trace_gen.h"
#include "hil_arrays.h"
#include "hil_vio.h"
#include "param_file.h"

int fwh_vio_adc_decode(const struct canfd_frame *f, int fd, fwh_vio_adc_t *out, int *reason,
                       char *why, size_t whylen)
{
    const uint32_t id = f->can_id & CAN_SFF_MASK;
    int index, j;
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
    case HIL_VIO_VIO_SYNC_ACK_FRAME_ID:
        return 0; /* what a firmware sends: not for us */
    case HIL_VIO_VIO_SYNC_FRAME_ID:
        return 0; /* the lockstep barrier: no ADC data (fw_host answers it, bus_io.c) */
    default:
        *reason = FWH_REJ_UNKNOWN_ID;
        snprintf(why, whylen, "id 0x%03X: no such virtual-I/O message", (unsigned)id);
        return -1;
    }
    if (!fd) {
        *reason = FWH_REJ_WRONG_FRAME_TYPE;
        snprintf(why, whylen, "VIO_ADC_%d: classic CAN frame, virtual I/O is CAN FD", index);
        return -1;
    }
    if (f->len != 64u) {
        *reason = FWH_REJ_BAD_LENGTH;
        snprintf(why, whylen, "VIO_ADC_%d: length %u, expected 64", index, f->len);
        return -1;
    }
    memset(out, 0, sizeof(*out));
    out->index = index;
    if (index == 0) {
        struct hil_vio_vio_adc_0_t m;
        hil_vio_vio_adc_0_unpack(&m, f->data, f->len);
        if (!hil_vio_vio_adc_0_vdc_code_is_in_range(m.vdc_code)) {
            *reason = FWH_REJ_OUT_OF_RANGE;
            snprintf(why, whylen, "VIO_ADC_0: vdc_code outside its range");
            return -1;
        }
        for (j = 0; j < HIL_VIO_VIO_ADC_0_IA_COUNT; j++) {
            out->ia[j] = hil_vio_vio_adc_0_ia_get(&m, j);
            out->ib[j] = hil_vio_vio_adc_0_ib_get(&m, j);
        }
        out->period = m.period, out->n_soc = m.n_soc, out->vdc = m.vdc_code;
    } else if (index == 1) {
        struct hil_vio_vio_adc_1_t m;
        hil_vio_vio_adc_1_unpack(&m, f->data, f->len);
        if (!hil_vio_vio_adc_1_vdc_code_is_in_range(m.vdc_code)) {
            *reason = FWH_REJ_OUT_OF_RANGE;
            snprintf(why, whylen, "VIO_ADC_1: vdc_code outside its range");
            return -1;
        }
        for (j = 0; j < HIL_VIO_VIO_ADC_1_IA_COUNT; j++) {
            out->ia[j] = hil_vio_vio_adc_1_ia_get(&m, j);
            out->ib[j] = hil_vio_vio_adc_1_ib_get(&m, j);
        }
        out->period = m.period, out->n_soc = m.n_soc, out->vdc = m.vdc_code;
    } else {
        struct hil_vio_vio_adc_2_t m;
        hil_vio_vio_adc_2_unpack(&m, f->data, f->len);
        if (!hil_vio_vio_adc_2_vdc_code_is_in_range(m.vdc_code)) {
            *reason = FWH_REJ_OUT_OF_RANGE;
            snprintf(why, whylen, "VIO_ADC_2: vdc_code outside its range");
            return -1;
        }
        for (j = 0; j < HIL_VIO_VIO_ADC_2_IA_COUNT; j++) {
            out->ia[j] = hil_vio_vio_adc_2_ia_get(&m, j);
            out->ib[j] = hil_vio_vio_adc_2_ib_get(&m, j);
        }
        out->period = m.period, out->n_soc = m.n_soc, out->vdc = m.vdc_code;
    }
    if (!hil_vio_vio_adc_0_n_soc_is_in_range(out->n_soc)) {
        *reason = FWH_REJ_OUT_OF_RANGE;
        snprintf(why, whylen, "VIO_ADC_%d period %lu: n_soc %u outside [0, 16]", index,
                 (unsigned long)out->period, out->n_soc);
        return -1;
    }
    return 1;
}

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

int fwh_vio_pwm_pack(const fw_pwm_t *in, uint32_t want_period, struct canfd_frame *f)
{
    struct hil_vio_vio_pwm_t m;
    uint16_t soc[FW_MAX_SOC];
    fw_pwm_t p = *in;
    const int valid = pwm_valid(&p, want_period);
    int k;
    if (!valid) {
        /* never put a value outside the DBC on the wire: gates off for that period */
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
    for (k = 0; k < HIL_VIO_VIO_PWM_SOC_COUNT; k++) {
        hil_vio_vio_pwm_soc_set(&m, k, soc[k]);
    }
    memset(f, 0, sizeof(*f));
    f->can_id = HIL_VIO_VIO_PWM_FRAME_ID;
    f->len = HIL_VIO_VIO_PWM_LENGTH;
    hil_vio_vio_pwm_pack(f->data, &m, sizeof(f->data));
    return valid;
}

void fwh_vio_trace_pack(const fw_status_t *s, struct canfd_frame *f)
{
    struct hil_vio_fw_trace_t m;
    memset(&m, 0, sizeof(m));
    fwh_trace_from_status(s, &m); /* generated from FW_TRACE in protocols/vio.dbc */
    memset(f, 0, sizeof(*f));
    f->can_id = HIL_VIO_FW_TRACE_FRAME_ID;
    f->len = HIL_VIO_FW_TRACE_LENGTH;
    hil_vio_fw_trace_pack(f->data, &m, sizeof(f->data));
}

int fwh_vio_adc_codes_ok(const fw_core_t *core, const fwh_vio_adc_t *m, int *reason, char *why,
                         size_t whylen)
{
    static const fw_param_info_t *adc_bits; /* looked up by name once */
    real_t bits = FW_REAL(0.0);
    int32_t top;
    int k;
    if (adc_bits == NULL) {
        adc_bits = fwh_param_by_name("adc_bits");
    }
    if (adc_bits == NULL || fw_param_get(core, adc_bits->id, &bits) != FW_STATUS_OK ||
        !(bits >= 1.0f) || !(bits <= 30.0f)) {
        return 1; /* the core checks the codes again in any case */
    }
    top = (int32_t)(((int64_t)1 << (int)bits) - 1);
    for (k = 0; k < FWH_VIO_ADC_MAX_SAMPLES; k++) {
        if (m->ia[k] < 0 || m->ia[k] > top || m->ib[k] < 0 || m->ib[k] > top) {
            *reason = FWH_REJ_OUT_OF_RANGE;
            snprintf(why, whylen,
                     "VIO_ADC_%d period %lu: a current code outside the converter's 0 .. 2^N-1",
                     m->index, (unsigned long)m->period);
            return 0;
        }
    }
    return 1;
}
