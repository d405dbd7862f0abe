/* Fault injection in the plant (plant_set_fault, faults.c) and on its side of the wires
 * (plant_link.h), against expectations worked out by hand: ADC codes from the transfer of
 * docs/interfaces.md, currents an open phase or a dead gate cannot carry, the DC link's ramp,
 * the FAULT_CMD checks, frames dropped, XORed and held back, PWM commands held and delayed.
 * The built-in defaults are used: no noise, no dead time, no device drop, a 24-bit ADC. */
#include <stdlib.h>
#include <string.h>

#include "hil_bench.h"
#include "hil_vio.h"
#include "../check.h"
#include "plant_cmd.h"
#include "plant_internal.h"
#include "plant_link.h"
#include "plant_vio.h"

#define KIND(x) HIL_BENCH_FAULT_CMD_KIND_##x##_CHOICE

static plant_t *plant_default(void)
{
    plant_config_t cfg;
    char err[256];
    plant_t *p;
    plant_config_defaults(&cfg);
    p = plant_new(&cfg, err, sizeof(err));
    if (p == NULL) {
        fprintf(stderr, "plant_new: %s\n", err);
    }
    return p;
}

/* every fault test samples the currents once, at the period's middle */
static void cmd_set_sampled(plant_pwm_cmd_t *c, int up0, int dn0, int up1, int dn1, int up2,
                            int dn2)
{
    cmd_set(c, up0, dn0, up1, dn1, up2, dn2);
    c->n_soc = 1;
    c->soc[0] = 5000;
}

static int32_t code_of(double amps)
{
    /* docs/interfaces.md: floor((i + R)/(2R) * 2^N + 0.5), N = 24, R = 10 A */
    return (int32_t)floor((amps + 10.0) / 20.0 * 16777216.0 + 0.5);
}

static void fault(plant_t *p, int slot, int kind, int channel, int phase, int gate, double value,
                  uint32_t periods)
{
    char err[256];
    CHECK(plant_set_fault(p, slot, kind, channel, phase, gate, value, periods, err,
                          sizeof(err)) == 0);
}

static void test_adc_channel_faults(void)
{
    plant_t *p = plant_default();
    plant_pwm_cmd_t c;
    plant_samples_t s;
    if (p == NULL) {
        ++g_failures;
        return;
    }
    cmd_set_sampled(&c, 5000, 5000, 5000, 5000, 5000, 5000);
    c.gate_enable = 0; /* standstill, gates off: every current is exactly zero */
    plant_step(p, &c, &s, NULL);
    CHECK(s.ia_code[0] == code_of(0.0) && s.ib_code[0] == code_of(0.0));
    fault(p, 0, KIND(ADC_OFFSET), 0, 0, 0, 1.5, 0);
    fault(p, 1, KIND(ADC_OFFSET), 0, 0, 0, 0.25, 0); /* offsets add */
    fault(p, 2, KIND(ADC_STUCK), 1, 0, 0, 1234.0, 0);
    fault(p, 3, KIND(ADC_OFFSET), 2, 0, 0, -50.0, 0); /* the DC-link channel, in volts */
    plant_step(p, &c, &s, NULL);
    CHECK(s.ia_code[0] == code_of(1.75));
    CHECK(s.ib_code[0] == 1234);
    /* 150 V on a 23-bit channel of 0 .. 400 V */
    CHECK(s.vdc_code[0] == (int32_t)floor(150.0 / 400.0 * 8388608.0 + 0.5));
    fault(p, 0, KIND(ADC_GAIN), 0, 0, 0, 3.0, 0); /* gain 3 on an input of 0.25 A offset */
    fault(p, 2, KIND(ADC_SATURATION), 1, 0, 0, 2.0, 0);
    fault(p, 4, KIND(ADC_OFFSET), 1, 0, 0, -5.0, 0); /* ib: -5 A clipped to -2 A */
    plant_step(p, &c, &s, NULL);
    CHECK(s.ia_code[0] == code_of(0.25)); /* gain first (0 A x 3), then the offsets */
    CHECK(s.ib_code[0] == code_of(-2.0));
    /* a freed slot takes its fault away; a stuck code beyond the converter is clamped */
    fault(p, 1, KIND(NONE), 0, 0, 0, 0.0, 0);
    fault(p, 2, KIND(ADC_STUCK), 1, 0, 0, 1e9, 0);
    plant_step(p, &c, &s, NULL);
    CHECK(s.ia_code[0] == code_of(0.0));
    CHECK(s.ib_code[0] == 16777215);
    /* a value that makes no sense is refused, the slot unchanged */
    {
        char err[256];
        CHECK(plant_set_fault(p, 0, KIND(ADC_GAIN), 0, 0, 0, -1.0, 0, err, sizeof(err)) != 0);
        CHECK(plant_set_fault(p, 0, KIND(SENSOR_LOSS), 2, 0, 0, 0.0, 0, err, sizeof(err)) != 0);
        CHECK(plant_set_fault(p, PLANT_FAULT_SLOTS, KIND(ADC_GAIN), 0, 0, 0, 1.0, 0, err,
                              sizeof(err)) != 0);
        CHECK(plant_set_fault(p, 0, KIND(DC_LINK), 0, 0, 0, 0.0, 0, err, sizeof(err)) != 0);
    }
    plant_free(p);
}

/* Drives a current into phase a (a high, b and c low), returns the truth after n periods. */
static void drive_phase_a(plant_t *p, int n, plant_truth_t *t, plant_samples_t *s)
{
    plant_pwm_cmd_t c;
    int k;
    cmd_set_sampled(&c, 4000, 4000, 5000, 5000, 5000, 5000); /* a high for 2000 of 10000 ticks */
    for (k = 0; k < n; ++k) {
        plant_step(p, &c, s, t);
    }
    plant_truth_now(p, t);
}

static void test_sensor_loss_and_open_phase(void)
{
    plant_t *p = plant_default();
    plant_truth_t t;
    plant_samples_t s;
    if (p == NULL) {
        ++g_failures;
        return;
    }
    plant_set_load(p, HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE, 0.0, 0.0, 0.0); /* locked rotor */
    drive_phase_a(p, 20, &t, &s);
    CHECK(t.ia > 1.0); /* the current flows... */
    fault(p, 0, KIND(SENSOR_LOSS), 0, 0, 0, 0.0, 0);
    drive_phase_a(p, 1, &t, &s);
    CHECK(t.ia > 1.0 && s.ia_code[0] == code_of(0.0)); /* ...but the lost sensor reads 0 A */
    CHECK(s.ib_code[0] != code_of(0.0));
    /* phase a opens: its current is cut at the period start and stays zero; the star point
     * is isolated, so b and c carry opposite currents */
    fault(p, 1, KIND(OPEN_PHASE), 0, 0, 0, 0.0, 0);
    drive_phase_a(p, 1, &t, &s);
    CHECK_NEAR(t.ia, 0.0, 1e-9);
    drive_phase_a(p, 10, &t, &s);
    CHECK_NEAR(t.ia, 0.0, 1e-9);
    CHECK_NEAR(t.ib + t.ic, 0.0, 1e-9);
    /* reconnected, the current builds up again */
    fault(p, 1, KIND(NONE), 0, 0, 0, 0.0, 0);
    drive_phase_a(p, 20, &t, &s);
    CHECK(t.ia > 1.0);
    plant_free(p);
}

static void test_gate_off(void)
{
    plant_t *p = plant_default();
    plant_t *healthy = plant_default();
    plant_truth_t t;
    plant_samples_t s;
    if (p == NULL || healthy == NULL) {
        ++g_failures;
        plant_free(p);
        plant_free(healthy);
        return;
    }
    plant_set_load(healthy, HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE, 0.0, 0.0, 0.0);
    drive_phase_a(healthy, 30, &t, &s);
    CHECK(t.ia > 1.0 && fabs(t.ib - t.ic) < 1e-6 * t.ia); /* b and c share the return */
    plant_free(healthy);
    plant_set_load(p, HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE, 0.0, 0.0, 0.0);
    /* the upper switch of phase a never conducts: nothing drives current into phase a (its
     * upper diode only carries current out of the machine) */
    fault(p, 0, KIND(GATE_OFF), 0, 0, 0, 0.0, 0);
    drive_phase_a(p, 30, &t, &s);
    CHECK(t.ia <= 1e-9);
    /* the lower gate of phase b dead instead, the upper of a back: healthy, the current of
     * phase a returns through b and c alike; now b has no switch to DC- and the current
     * returns through c (b only through its lower diode, while its terminal is driven below
     * DC-: a few mA in the freewheeling intervals) */
    fault(p, 0, KIND(GATE_OFF), 0, 1, 1, 0.0, 0);
    drive_phase_a(p, 30, &t, &s);
    CHECK(t.ia > 1.0 && t.ic < -0.98 * t.ia && fabs(t.ib) < 0.02 * t.ia);
    plant_free(p);
}

static void test_dc_link(void)
{
    plant_t *p = plant_default();
    plant_pwm_cmd_t c;
    plant_samples_t s;
    plant_truth_t t;
    int k;
    if (p == NULL) {
        ++g_failures;
        return;
    }
    cmd_set_sampled(&c, 5000, 5000, 5000, 5000, 5000, 5000);
    c.gate_enable = 0;
    plant_step(p, &c, &s, &t);
    CHECK(t.vdc == 200.0);
    fault(p, 3, KIND(DC_LINK), 0, 0, 0, 280.0, 0); /* a step */
    plant_step(p, &c, &s, &t);
    CHECK(t.vdc == 280.0);
    CHECK(s.vdc_code[0] == (int32_t)floor(280.0 / 400.0 * 8388608.0 + 0.5));
    fault(p, 3, KIND(DC_LINK), 0, 0, 0, 180.0, 4); /* 280 -> 180 V over 4 periods */
    for (k = 1; k <= 6; ++k) {
        plant_step(p, &c, &s, &t);
        CHECK_NEAR(t.vdc, k < 4 ? 280.0 - 25.0 * k : 180.0, 1e-12);
    }
    fault(p, 3, KIND(NONE), 0, 0, 0, 0.0, 0); /* freed: back to the profile's link */
    plant_step(p, &c, &s, &t);
    CHECK(t.vdc == 200.0);
    plant_free(p);
}

static void pack_fault(uint8_t buf[64], int slot, int kind, uint32_t message, uint32_t delay,
                       uint32_t byte, uint32_t xor_mask)
{
    struct hil_bench_fault_cmd_t m;
    memset(&m, 0, sizeof(m));
    m.slot = (uint8_t)slot;
    m.kind = (uint8_t)kind;
    m.message = (uint16_t)message;
    m.delay = (uint8_t)delay;
    m.byte = (uint8_t)byte;
    m.xor = xor_mask;
    hil_bench_fault_cmd_pack(buf, &m, 64);
}

static void test_fault_cmd_checks(void)
{
    plant_fault_cmd_t c;
    uint8_t buf[64];
    pack_fault(buf, 2, KIND(FRAME_LOSS), HIL_VIO_VIO_ADC_1_FRAME_ID, 0, 0, 0);
    CHECK(plant_decode_fault_cmd(1, buf, HIL_BENCH_FAULT_CMD_LENGTH, &c) == PLANT_REJ_NONE);
    CHECK(c.slot == 2 && c.message == HIL_VIO_VIO_ADC_1_FRAME_ID);
    CHECK(plant_decode_fault_cmd(0, buf, HIL_BENCH_FAULT_CMD_LENGTH, &c) == PLANT_REJ_MALFORMED);
    CHECK(plant_decode_fault_cmd(1, buf, 16, &c) == PLANT_REJ_BAD_LENGTH);
    /* frame faults only on the plant's wires; a delay of at least a period; a non-zero mask */
    pack_fault(buf, 2, KIND(FRAME_LOSS), HIL_VIO_FW_TRACE_FRAME_ID, 0, 0, 0);
    CHECK(plant_decode_fault_cmd(1, buf, HIL_BENCH_FAULT_CMD_LENGTH, &c) ==
          PLANT_REJ_OUT_OF_RANGE);
    pack_fault(buf, 2, KIND(FRAME_DELAY), HIL_VIO_VIO_PWM_FRAME_ID, 0, 0, 0);
    CHECK(plant_decode_fault_cmd(1, buf, HIL_BENCH_FAULT_CMD_LENGTH, &c) ==
          PLANT_REJ_OUT_OF_RANGE);
    pack_fault(buf, 2, KIND(FRAME_CORRUPT), HIL_VIO_VIO_PWM_FRAME_ID, 0, 4, 0);
    CHECK(plant_decode_fault_cmd(1, buf, HIL_BENCH_FAULT_CMD_LENGTH, &c) ==
          PLANT_REJ_OUT_OF_RANGE);
    pack_fault(buf, 2, 12, 0, 0, 0, 0); /* beyond the kind table */
    CHECK(plant_decode_fault_cmd(1, buf, HIL_BENCH_FAULT_CMD_LENGTH, &c) ==
          PLANT_REJ_OUT_OF_RANGE);
    /* the room for held-back frames and commands covers every delay the DBC allows, and the
     * slots are the DBC's */
    CHECK(!hil_bench_fault_cmd_delay_is_in_range(PLANT_LINK_PWM_QUEUE));
    CHECK(!hil_bench_fault_cmd_delay_is_in_range(PLANT_LINK_HELD_MAX / PLANT_VIO_ADC_FRAMES_MAX -
                                                 1));
    CHECK(hil_bench_fault_cmd_slot_is_in_range(PLANT_FAULT_SLOTS - 1));
    CHECK(!hil_bench_fault_cmd_slot_is_in_range(PLANT_FAULT_SLOTS));
}

static void adc_frames(uint32_t k, struct canfd_frame f[2])
{
    int i;
    for (i = 0; i < 2; ++i) {
        memset(&f[i], 0, sizeof(f[i]));
        f[i].can_id = i == 0 ? HIL_VIO_VIO_ADC_0_FRAME_ID : HIL_VIO_VIO_ADC_1_FRAME_ID;
        f[i].len = 64;
        memcpy(f[i].data, &k, 4); /* little-endian period, as the DBC lays it out */
    }
}

static void test_link_adc(void)
{
    plant_t *p = plant_default();
    plant_link_t *l = (plant_link_t *)calloc(1, sizeof(plant_link_t));
    struct canfd_frame in[2], out[8];
    uint8_t buf[64];
    char err[128];
    uint32_t k;
    int n;
    if (p == NULL || l == NULL) {
        ++g_failures;
        free(l);
        plant_free(p);
        return;
    }
    plant_link_init(l);
    adc_frames(7, in);
    CHECK(plant_link_adc_out(l, 7, in, 2, out, 8) == 2 && !plant_link_barrier(l));
    /* VIO_ADC_1 lost, VIO_ADC_0 XORed at byte 8 (ia_0): the barrier from now on */
    pack_fault(buf, 0, KIND(FRAME_LOSS), HIL_VIO_VIO_ADC_1_FRAME_ID, 0, 0, 0);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) ==
          PLANT_REJ_NONE);
    pack_fault(buf, 1, KIND(FRAME_CORRUPT), HIL_VIO_VIO_ADC_0_FRAME_ID, 0, 8, 0x00010203u);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) ==
          PLANT_REJ_NONE);
    adc_frames(8, in);
    n = plant_link_adc_out(l, 8, in, 2, out, 8);
    CHECK(n == 1 && out[0].can_id == HIL_VIO_VIO_ADC_0_FRAME_ID && plant_link_barrier(l));
    CHECK(out[0].data[8] == 0x03 && out[0].data[9] == 0x02 && out[0].data[10] == 0x01 &&
          out[0].data[11] == 0x00 && out[0].data[0] == 8);
    /* VIO_ADC_0 two periods late instead; the slots freed; the barrier stays */
    pack_fault(buf, 0, KIND(NONE), 0, 0, 0, 0);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) == 0);
    pack_fault(buf, 1, KIND(FRAME_DELAY), HIL_VIO_VIO_ADC_0_FRAME_ID, 2, 0, 0);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) == 0);
    for (k = 9; k <= 11; ++k) {
        adc_frames(k, in);
        n = plant_link_adc_out(l, k, in, 2, out, 8);
        if (k < 11) {
            CHECK(n == 1 && out[0].can_id == HIL_VIO_VIO_ADC_1_FRAME_ID);
        } else {
            /* period 11's own VIO_ADC_1, then VIO_ADC_0 of period 9, due now */
            CHECK(n == 2 && out[0].can_id == HIL_VIO_VIO_ADC_1_FRAME_ID && out[0].data[0] == 11 &&
                  out[1].can_id == HIL_VIO_VIO_ADC_0_FRAME_ID && out[1].data[0] == 9);
        }
    }
    pack_fault(buf, 1, KIND(NONE), 0, 0, 0, 0);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) == 0);
    adc_frames(12, in);
    n = plant_link_adc_out(l, 12, in, 2, out, 8);
    /* frames held back before the fault ended still come at their time: 10's VIO_ADC_0 */
    CHECK(n == 3 && out[2].data[0] == 10 && plant_link_barrier(l));
    CHECK(l->st.dropped == 1 && l->st.corrupted == 1 && l->st.delayed == 3);
    free(l);
    plant_free(p);
}

static void pwm_frame(uint32_t period, int cmp, struct canfd_frame *f)
{
    struct hil_vio_vio_pwm_t m;
    memset(&m, 0, sizeof(m));
    m.period = period;
    m.cmp_a_up = m.cmp_a_dn = m.cmp_b_up = m.cmp_b_dn = m.cmp_c_up = m.cmp_c_dn = (uint16_t)cmp;
    m.gate_enable = 1;
    memset(f, 0, sizeof(*f));
    f->can_id = HIL_VIO_VIO_PWM_FRAME_ID;
    f->len = HIL_VIO_VIO_PWM_LENGTH;
    hil_vio_vio_pwm_pack(f->data, &m, sizeof(f->data));
}

/* One exchange: ADC(k) out, PWM(k+1) with compare value cmp in; the command of k+1. */
static int exchange(plant_link_t *l, uint32_t k, int cmp, plant_pwm_cmd_t *cur)
{
    struct canfd_frame in[2], out[8], f;
    adc_frames(k, in);
    (void)plant_link_adc_out(l, k, in, 1, out, 8);
    pwm_frame(k + 1, cmp, &f);
    CHECK(plant_link_pwm(l, &f, 1) == PLANT_REJ_NONE && plant_link_decided(l));
    (void)plant_link_commit(l, cur, cur);
    CHECK(cur->period == k + 1);
    return cur->cmp_up[0];
}

static void test_link_pwm(void)
{
    plant_t *p = plant_default();
    plant_link_t *l = (plant_link_t *)calloc(1, sizeof(plant_link_t));
    plant_pwm_cmd_t cur;
    uint8_t buf[64];
    char err[128];
    struct canfd_frame f, in[2], out[8];
    if (p == NULL || l == NULL) {
        ++g_failures;
        free(l);
        plant_free(p);
        return;
    }
    plant_link_init(l);
    memset(&cur, 0xA5, sizeof(cur));
    CHECK(plant_link_commit(l, &cur, &cur) == PLANT_REJ_NONE); /* period 0: the start-up */
    CHECK(cur.period == 0 && cur.gate_enable == 0 && cur.n_soc == 1 && cur.soc[0] == 0);
    CHECK(exchange(l, 0, 100, &cur) == 100 && cur.period == 1);
    /* a second PWM of a decided period is as late as any other */
    pwm_frame(1, 300, &f);
    CHECK(plant_link_pwm(l, &f, 1) == PLANT_REJ_STALE_PERIOD);
    /* without a fault on VIO_PWM a refused PWM(k+1) leaves the exchange open (the plant
     * waits for a good one); the barrier ends it, and the values stay */
    adc_frames(1, in);
    (void)plant_link_adc_out(l, 1, in, 1, out, 8);
    pwm_frame(2, 200, &f);
    f.data[5] ^= 0x20; /* cmp_a_up 200 -> 8392: outside the DBC */
    CHECK(plant_link_pwm(l, &f, 1) == PLANT_REJ_OUT_OF_RANGE && !plant_link_decided(l));
    plant_link_resolve(l);
    CHECK(plant_link_decided(l) && plant_link_commit(l, &cur, &cur) == PLANT_REJ_NONE);
    CHECK(cur.cmp_up[0] == 100 && cur.period == 2);
    /* PWM(k+1) may come before the FAULT_CMD of period k+1: the fault still acts on it */
    adc_frames(2, in);
    (void)plant_link_adc_out(l, 2, in, 1, out, 8);
    pwm_frame(3, 250, &f);
    CHECK(plant_link_pwm(l, &f, 1) == PLANT_REJ_NONE);
    /* VIO_PWM lost: the compare values stay */
    pack_fault(buf, 5, KIND(FRAME_LOSS), HIL_VIO_VIO_PWM_FRAME_ID, 0, 0, 0);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) == 0);
    CHECK(plant_link_commit(l, &cur, &cur) == PLANT_REJ_NONE);
    CHECK(cur.cmp_up[0] == 100 && cur.period == 3);
    /* VIO_PWM 2 periods late: PWM(k+1) runs in period k+3 */
    pack_fault(buf, 5, KIND(FRAME_DELAY), HIL_VIO_VIO_PWM_FRAME_ID, 2, 0, 0);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) == 0);
    CHECK(exchange(l, 3, 301, &cur) == 100); /* period 4: nothing due yet */
    CHECK(exchange(l, 4, 302, &cur) == 100); /* period 5 */
    CHECK(exchange(l, 5, 303, &cur) == 301); /* period 6: PWM(4) */
    CHECK(exchange(l, 6, 304, &cur) == 302 && cur.period == 7);
    /* corrupted beyond the DBC (cmp_a_up 0x2000 + 303 > 5000): refused, the values stay */
    pack_fault(buf, 5, KIND(FRAME_CORRUPT), HIL_VIO_VIO_PWM_FRAME_ID, 0, 4, 0x2000);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) == 0);
    {
        struct canfd_frame fr;
        adc_frames(7, in);
        (void)plant_link_adc_out(l, 7, in, 1, out, 8);
        pwm_frame(8, 400, &fr);
        CHECK(plant_link_pwm(l, &fr, 1) == PLANT_REJ_NONE); /* taken; checked when it runs */
        CHECK(plant_link_commit(l, &cur, &cur) == PLANT_REJ_OUT_OF_RANGE);
        CHECK(cur.cmp_up[0] == 302 && cur.period == 8);
    }
    /* freed: PWM(k+1) again */
    pack_fault(buf, 5, KIND(NONE), 0, 0, 0, 0);
    CHECK(plant_link_fault(l, p, 1, buf, HIL_BENCH_FAULT_CMD_LENGTH, err, sizeof(err)) == 0);
    CHECK(exchange(l, 8, 500, &cur) == 500);
    /* held: the refused update, the lost one, two periods before the first delayed one is
     * due, the refused corrupted one */
    CHECK(l->st.held == 5 && l->st.dropped == 1 && l->st.corrupted == 1);
    CHECK(l->st.delayed == 4 && l->st.syncs == 1);
    free(l);
    plant_free(p);
}

int main(void)
{
    test_adc_channel_faults();
    test_sensor_loss_and_open_phase();
    test_gate_off();
    test_dc_link();
    test_fault_cmd_checks();
    test_link_adc();
    test_link_pwm();
    return check_report("test_plant_faults");
}
