/* The plant's frames (see plant_vio.h): moved out of plant_rt's main.c so that the
 * in-process bench packs and checks exactly what the bus program does. */
#include <string.h>

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

int plant_pack_adc(const plant_samples_t *s, struct canfd_frame out[PLANT_VIO_ADC_FRAMES_MAX])
{
    uint8_t buf[64];
    const uint32_t n = s->n_soc;
    int count = 0;
    if (n > 0) {
        struct hil_vio_vio_adc_0_t m;
        memset(&m, 0, sizeof(m));
        m.period = s->period;
        m.n_soc = (uint8_t)n;
        m.vdc_code = s->vdc_code[0];
        m.ia_0 = s->ia_code[0], m.ib_0 = s->ib_code[0];
        m.ia_1 = s->ia_code[1], m.ib_1 = s->ib_code[1];
        m.ia_2 = s->ia_code[2], m.ib_2 = s->ib_code[2];
        m.ia_3 = s->ia_code[3], m.ib_3 = s->ib_code[3];
        m.ia_4 = s->ia_code[4], m.ib_4 = s->ib_code[4];
        m.ia_5 = s->ia_code[5], m.ib_5 = s->ib_code[5];
        m.ia_6 = s->ia_code[6], m.ib_6 = s->ib_code[6];
        hil_vio_vio_adc_0_pack(buf, &m, sizeof(buf));
        frame(&out[count++], HIL_VIO_VIO_ADC_0_FRAME_ID, buf, 64);
    }
    if (n > 7) {
        struct hil_vio_vio_adc_1_t m;
        memset(&m, 0, sizeof(m));
        m.period = s->period;
        m.n_soc = (uint8_t)n;
        m.vdc_code = s->vdc_code[7];
        m.ia_7 = s->ia_code[7], m.ib_7 = s->ib_code[7];
        m.ia_8 = s->ia_code[8], m.ib_8 = s->ib_code[8];
        m.ia_9 = s->ia_code[9], m.ib_9 = s->ib_code[9];
        m.ia_10 = s->ia_code[10], m.ib_10 = s->ib_code[10];
        m.ia_11 = s->ia_code[11], m.ib_11 = s->ib_code[11];
        m.ia_12 = s->ia_code[12], m.ib_12 = s->ib_code[12];
        m.ia_13 = s->ia_code[13], m.ib_13 = s->ib_code[13];
        hil_vio_vio_adc_1_pack(buf, &m, sizeof(buf));
        frame(&out[count++], HIL_VIO_VIO_ADC_1_FRAME_ID, buf, 64);
    }
    if (n > 14) {
        struct hil_vio_vio_adc_2_t m;
        memset(&m, 0, sizeof(m));
        m.period = s->period;
        m.n_soc = (uint8_t)n;
        m.vdc_code = s->vdc_code[14];
        m.ia_14 = s->ia_code[14], m.ib_14 = s->ib_code[14];
        m.ia_15 = s->ia_code[15], m.ib_15 = s->ib_code[15];
        hil_vio_vio_adc_2_pack(buf, &m, sizeof(buf));
        frame(&out[count++], HIL_VIO_VIO_ADC_2_FRAME_ID, buf, 64);
    }
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
