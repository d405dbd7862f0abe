/* The plant's frames (see plant_vio.h): moved out of plant_rt's main.c so that the
 * in-process bench packs and checks exactly what the bus program does. */
#include <string.h>

#include "hil_arrays.h"
#include "hil_bench.h"
#include "hil_vio.h"
#include "plant_vio.h"

void plant_startup_command(plant_pwm_cmd_t *c)
{
    memset(c, 0, sizeof(*c));
    c->gate_enable = 0;
    c->n_soc = 1;
    c->soc[0] = 0;
}

static void frame(struct canfd_frame *f, uint32_t id, const uint8_t *buf, uint8_t len)
{
    memset(f, 0, sizeof(*f));
    f->can_id = id;
    f->len = len;
    memcpy(f->data, buf, len);
}

/* VIO_ADC_<X> when the period has a sample for it: SOCs FIRST .. FIRST + COUNT - 1 (ia_<k>,
 * ib_<k> by index through hil_arrays.h), the DC-link code of its first SOC. */
#define PACK_ADC(X)                                                                  \
    if (n > HIL_VIO_VIO_ADC_##X##_IA_FIRST) {                                        \
        struct hil_vio_vio_adc_##X##_t m;                                            \
        const int32_t *ia = s->ia_code + HIL_VIO_VIO_ADC_##X##_IA_FIRST;             \
        const int32_t *ib = s->ib_code + HIL_VIO_VIO_ADC_##X##_IB_FIRST;             \
        int j;                                                                       \
        memset(&m, 0, sizeof(m));                                                    \
        m.period = s->period;                                                        \
        m.n_soc = (uint8_t)n;                                                        \
        m.vdc_code = s->vdc_code[HIL_VIO_VIO_ADC_##X##_IA_FIRST];                    \
        for (j = 0; j < HIL_VIO_VIO_ADC_##X##_IA_COUNT; j++) {                       \
            hil_vio_vio_adc_##X##_ia_set(&m, j, ia[j]);                              \
            hil_vio_vio_adc_##X##_ib_set(&m, j, ib[j]);                              \
        }                                                                            \
        hil_vio_vio_adc_##X##_pack(buf, &m, sizeof(buf));                            \
        frame(&out[count++], HIL_VIO_VIO_ADC_##X##_FRAME_ID, buf, 64);               \
    }

int plant_pack_adc(const plant_samples_t *s, struct canfd_frame out[PLANT_VIO_ADC_FRAMES_MAX])
{
    uint8_t buf[64];
    const uint32_t n = s->n_soc;
    int count = 0;
    PACK_ADC(0)
    PACK_ADC(1)
    PACK_ADC(2)
    return count;
}

void plant_pack_truth(const plant_truth_t *t, struct canfd_frame out[2])
{
    uint8_t buf[64];
    {
        struct hil_bench_bench_truth_t m;
        m.period = t->period;
        m.theta_e = (float)t->theta_e;
        m.omega_m = (float)t->omega_m;
        m.id = (float)t->id;
        m.iq = (float)t->iq;
        m.te = (float)t->te;
        m.tl = (float)t->tl;
        m.t_shaft = (float)t->t_shaft;
        m.ia = (float)t->ia;
        m.ib = (float)t->ib;
        m.vdc = (float)t->vdc;
        m.psi_d = (float)t->psi_d;
        m.psi_q = (float)t->psi_q;
        m.ua = (float)t->ua;
        m.ub = (float)t->ub;
        m.uc = (float)t->uc;
        hil_bench_bench_truth_pack(buf, &m, sizeof(buf));
        frame(&out[0], HIL_BENCH_BENCH_TRUTH_FRAME_ID, buf, 64);
    }
    {
        struct hil_bench_bench_truth_mag_t m;
        memset(&m, 0, sizeof(m));
        m.period = t->period;
        m.ld_inc = (float)t->ld_inc;
        m.lq_inc = (float)t->lq_inc;
        m.ldq_inc = (float)t->ldq_inc;
        m.ld_app = (float)t->ld_app;
        m.lq_app = (float)t->lq_app;
        m.lambda_m = (float)t->lambda_m;
        m.rs = (float)t->rs;
        hil_bench_bench_truth_mag_pack(buf, &m, sizeof(buf));
        frame(&out[1], HIL_BENCH_BENCH_TRUTH_MAG_FRAME_ID, buf, 64);
    }
}

int plant_decode_load_cmd(int fd, const uint8_t *data, size_t len, plant_load_cmd_t *out)
{
    struct hil_bench_load_cmd_t m;
    if (!fd) {
        return PLANT_REJ_MALFORMED; /* LOAD_CMD is a CAN FD frame */
    }
    if (len != HIL_BENCH_LOAD_CMD_LENGTH) {
        return PLANT_REJ_BAD_LENGTH;
    }
    hil_bench_load_cmd_unpack(&m, data, len);
    /* the DBC ranges (a NaN is in none) */
    if (!hil_bench_load_cmd_mode_is_in_range(m.mode) ||
        !hil_bench_load_cmd_torque_is_in_range(m.torque) ||
        !hil_bench_load_cmd_speed_is_in_range(m.speed) ||
        !hil_bench_load_cmd_k_speed_is_in_range(m.k_speed)) {
        return PLANT_REJ_OUT_OF_RANGE;
    }
    out->mode = m.mode;
    out->torque_nm = m.torque;
    out->speed_rpm = m.speed;
    out->k_speed_nms = m.k_speed;
    return PLANT_REJ_NONE;
}
