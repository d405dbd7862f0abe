/* Bad input: the validation of PWM commands and the decoding of VIO_PWM frames. */
#include <string.h>

#include "hil_vio.h"
#include "../check.h"
#include "plant_vio.h"

static void good_cmd(plant_pwm_cmd_t *c, uint32_t period)
{
    memset(c, 0, sizeof(*c));
    c->period = period;
    c->cmp_up[0] = 1000;
    c->cmp_dn[0] = 1200;
    c->cmp_up[1] = 2500;
    c->cmp_dn[1] = 2500;
    c->cmp_up[2] = 5000;
    c->cmp_dn[2] = 0;
    c->n_soc = 3;
    c->soc[0] = 0;
    c->soc[1] = 5000;
    c->soc[2] = 9999;
    c->gate_enable = 1;
}

static void pack(const plant_pwm_cmd_t *c, uint8_t out[64])
{
    struct hil_vio_vio_pwm_t m;
    memset(&m, 0, sizeof(m));
    m.period = c->period;
    m.cmp_a_up = c->cmp_up[0];
    m.cmp_a_dn = c->cmp_dn[0];
    m.cmp_b_up = c->cmp_up[1];
    m.cmp_b_dn = c->cmp_dn[1];
    m.cmp_c_up = c->cmp_up[2];
    m.cmp_c_dn = c->cmp_dn[2];
    m.n_soc = c->n_soc;
    m.gate_enable = c->gate_enable;
    m.soc_0 = c->soc[0];
    m.soc_1 = c->soc[1];
    m.soc_2 = c->soc[2];
    m.soc_15 = c->soc[15];
    CHECK(hil_vio_vio_pwm_pack(out, &m, 64) == 64);
}

int main(void)
{
    plant_pwm_cmd_t c, d;
    uint8_t buf[64];

    /* limits of a command */
    good_cmd(&c, 7);
    CHECK(plant_pwm_validate(&c, 7) == PLANT_REJ_NONE);
    c.cmp_up[1] = 5001;
    CHECK(plant_pwm_validate(&c, 7) == PLANT_REJ_OUT_OF_RANGE);
    good_cmd(&c, 7);
    c.cmp_dn[2] = 65535;
    CHECK(plant_pwm_validate(&c, 7) == PLANT_REJ_OUT_OF_RANGE);
    good_cmd(&c, 7);
    c.n_soc = 17;
    CHECK(plant_pwm_validate(&c, 7) == PLANT_REJ_TOO_MANY_SOC);
    good_cmd(&c, 7);
    c.n_soc = 16;
    c.soc[15] = 10000;
    CHECK(plant_pwm_validate(&c, 7) == PLANT_REJ_SOC_OUTSIDE);
    c.n_soc = 15; /* an unused slot may hold anything */
    CHECK(plant_pwm_validate(&c, 7) == PLANT_REJ_NONE);
    good_cmd(&c, 7);
    CHECK(plant_pwm_validate(&c, 8) == PLANT_REJ_STALE_PERIOD);
    CHECK(plant_pwm_validate(&c, 6) == PLANT_REJ_FUTURE_PERIOD);
    /* ordering survives the 32-bit wrap of the period counter */
    good_cmd(&c, 0xFFFFFFFFu);
    CHECK(plant_pwm_validate(&c, 1) == PLANT_REJ_STALE_PERIOD);
    good_cmd(&c, 2);
    CHECK(plant_pwm_validate(&c, 0xFFFFFFFEu) == PLANT_REJ_FUTURE_PERIOD);
    /* a broken frame is reported as broken even when it is also stale */
    good_cmd(&c, 3);
    c.cmp_up[0] = 6000;
    CHECK(plant_pwm_validate(&c, 9) == PLANT_REJ_OUT_OF_RANGE);

    /* frames */
    good_cmd(&c, 42);
    pack(&c, buf);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 64, 42, &d) == PLANT_REJ_NONE);
    CHECK(d.period == 42 && d.cmp_up[0] == 1000 && d.cmp_dn[0] == 1200 && d.cmp_up[2] == 5000);
    CHECK(d.n_soc == 3 && d.soc[1] == 5000 && d.soc[2] == 9999 && d.gate_enable == 1);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 48, 42, &d) == PLANT_REJ_BAD_LENGTH);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 8, 42, &d) == PLANT_REJ_BAD_LENGTH);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 0, buf, 8, 42, &d) == PLANT_REJ_MALFORMED);
    CHECK(plant_decode_pwm(0x15, 1, buf, 64, 42, &d) == PLANT_REJ_UNKNOWN_ID);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 64, 43, &d) == PLANT_REJ_STALE_PERIOD);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 64, 41, &d) == PLANT_REJ_FUTURE_PERIOD);
    buf[17] |= 0x80u; /* a bit beyond gate_enable: not this layout */
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 64, 42, &d) == PLANT_REJ_MALFORMED);
    good_cmd(&c, 42);
    c.n_soc = 200;
    pack(&c, buf);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 64, 42, &d) == PLANT_REJ_TOO_MANY_SOC);
    good_cmd(&c, 42);
    c.cmp_dn[1] = 5001;
    pack(&c, buf);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 64, 42, &d) == PLANT_REJ_OUT_OF_RANGE);
    good_cmd(&c, 42);
    c.soc[2] = 12000;
    pack(&c, buf);
    CHECK(plant_decode_pwm(HIL_VIO_VIO_PWM_FRAME_ID, 1, buf, 64, 42, &d) == PLANT_REJ_SOC_OUTSIDE);

    CHECK(strcmp(plant_reject_name(PLANT_REJ_STALE_PERIOD), "stale_period") == 0);
    CHECK(strcmp(plant_reject_name(PLANT_REJ_COUNT), "invalid") == 0);

    /* the plant keeps running on the previous command after a rejection: the core itself
     * simulates whatever it is given, so a rejected frame never reaches it (main.c); a
     * valid command after rejections runs normally */
    {
        char err[256];
        plant_t *p = plant_open(PROFILES_DIR "/paper.toml", NULL, 0, err, sizeof(err));
        plant_samples_t s;
        CHECK(p != NULL);
        if (p) {
            good_cmd(&c, plant_next_period(p));
            CHECK(plant_pwm_validate(&c, plant_next_period(p)) == PLANT_REJ_NONE);
            plant_step(p, &c, &s, NULL);
            CHECK(s.n_soc == 3 && plant_next_period(p) == 1);
            plant_free(p);
        }
    }
    return check_report("test_plant_validate");
}
