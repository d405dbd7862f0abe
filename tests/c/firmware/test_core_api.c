/* Core API on bad input: rejected with a status code and nothing changed; loss of ADC data
 * and of commands turns the outputs off and reports the fault; repeated ADC frames are
 * idempotent; protection trips. Closed loops on the in-process bench (sim.h); faults are
 * injected into the ADC data through its hook. */
#include <stdlib.h>

#include "fw_test.h"
#include "sim.h"

static sim_t S;
static fw_core_t snap;
static fw_core_t alone; /* the core without a bench: API checks from its defaults */

/* the whole object must be byte-identical except the reported command status */
static int unchanged_except_cmd_status(const fw_core_t *c)
{
    fw_core_t tmp = *c;
    tmp.cmd_status = snap.cmd_status;
    return memcmp(&tmp, &snap, sizeof tmp) == 0;
}

static void bad_commands(void)
{
    fw_core_t *c;
    fw_cmd_t good = {0, 0, FW_CTRL_SPEED, FW_FWMODE_REALTIME, 100.0f, 0.5f};
    fw_cmd_t bad;
    real_t nan = (real_t)NAN;
    int k;
    fw_core_init(&alone);
    c = &alone;
    CHECK(fw_core_command(c, &good) == FW_STATUS_OK, "good command rejected");
    for (k = 0; k < 9; k++) {
        int16_t st;
        bad = good;
        switch (k) {
        case 0: bad.enable = 2; break;
        case 1: bad.fault_reset = -1; break;
        case 2: bad.ctrl_mode = 2; break;
        case 3: bad.fw_mode = 3; break;
        case 4: bad.speed_ref_rpm = c->p[FW_IDX_SPEED_MAX_RPM] + 1.0f; break;
        case 5: bad.speed_ref_rpm = nan; break;
        case 6: bad.iq_ref = c->p[FW_IDX_I_MAX_A] * 1.01f; break;
        case 7: bad.iq_ref = (real_t)INFINITY; break;
        default: bad.fw_mode = -1; break;
        }
        snap = *c;
        st = fw_core_command(c, &bad);
        CHECK(st == FW_STATUS_OUT_OF_RANGE, "bad command %d accepted (%d)", k, st);
        CHECK(c->cmd_status == FW_STATUS_OUT_OF_RANGE, "cmd_status not reported");
        CHECK(unchanged_except_cmd_status(c), "bad command %d changed the core", k);
    }
    CHECK(fw_core_command(NULL, &good) == FW_STATUS_BAD_ARG, "NULL core");
    CHECK(fw_core_command(c, NULL) == FW_STATUS_BAD_ARG, "NULL command");
}

static void bad_params(void)
{
    fw_core_t *c = &alone;
    real_t v = 0.0f;
    struct {
        uint16_t id;
        real_t value;
        int16_t status;
    } cases[] = {
        {9999u, 1.0f, FW_STATUS_UNKNOWN_ID},
        {0u, 1.0f, FW_STATUS_UNKNOWN_ID},
        {FW_PID_FW_VERSION, 2.0f, FW_STATUS_READ_ONLY},
        {FW_PID_LD_HAT_H, 0.01f, FW_STATUS_READ_ONLY},
        {FW_PID_RS_OHM, -1.0f, FW_STATUS_OUT_OF_RANGE},
        {FW_PID_RS_OHM, 1000.0f, FW_STATUS_OUT_OF_RANGE},
        {FW_PID_RS_OHM, (real_t)NAN, FW_STATUS_OUT_OF_RANGE},
        {FW_PID_RS_OHM, (real_t)INFINITY, FW_STATUS_OUT_OF_RANGE},
        {FW_PID_POLE_PAIRS, 2.5f, FW_STATUS_OUT_OF_RANGE},        /* integral */
        {FW_PID_ADC_BITS, 25.0f, FW_STATUS_OUT_OF_RANGE},
        {FW_PID_LD_H, 0.040f, FW_STATUS_OUT_OF_RANGE},            /* Ld >= Lq */
        {FW_PID_TMIN_US, 14.0f, FW_STATUS_OUT_OF_RANGE},          /* < on + off + 1 us */
        {FW_PID_UV_TRIP_V, 300.0f, FW_STATUS_OUT_OF_RANGE},       /* above OV */
        {FW_PID_I_MAX_A, 9.9f, FW_STATUS_OUT_OF_RANGE},           /* above the OC trip */
        {FW_PID_CMD_TIMEOUT_MS, 0.0f, FW_STATUS_OUT_OF_RANGE},
    };
    size_t k;
    CHECK(fw_param_get(c, FW_PID_RS_OHM, &v) == FW_STATUS_OK && fabs(v - 1.93) < 1e-6,
          "rs default %.4f", (double)v);
    CHECK(fw_param_get(c, FW_PID_ADC_BITS, &v) == FW_STATUS_OK && v == 16.0f, "adc bits");
    CHECK(fw_param_get(c, 9999u, &v) == FW_STATUS_UNKNOWN_ID, "get unknown id");
    CHECK(fw_param_get(c, FW_PID_RS_OHM, NULL) == FW_STATUS_BAD_ARG, "get NULL");
    for (k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        int16_t st;
        snap = *c;
        st = fw_param_set(c, cases[k].id, cases[k].value);
        CHECK(st == cases[k].status, "param %u = %g: status %d, expected %d", cases[k].id,
              (double)cases[k].value, st, cases[k].status);
        CHECK(memcmp(c, &snap, sizeof snap) == 0, "rejected param %u changed the core",
              cases[k].id);
    }
    /* valid sets take effect and read back */
    CHECK(fw_param_set(c, FW_PID_PLL_BW_HZ, 80.0f) == FW_STATUS_OK, "pll bw");
    CHECK(fw_param_get(c, FW_PID_PLL_BW_HZ, &v) == FW_STATUS_OK && v == 80.0f, "pll bw read");
    CHECK(fw_param_set(c, FW_PID_LQ_H, 0.050f) == FW_STATUS_OK, "lq up");
    CHECK(fw_param_set(c, FW_PID_LD_H, 0.040f) == FW_STATUS_OK, "ld below the new lq");
    CHECK(fw_param_set(c, FW_PID_CMD_TIMEOUT_MS, 50.0f) == FW_STATUS_OK &&
              c->cmd_timeout_ticks == 500u,
          "timeout ticks %u", (unsigned)c->cmd_timeout_ticks);
    /* limits */
    snap = *c;
    CHECK(fw_core_set_limits(c, 11.0f, 1000.0f, 100.0f) == FW_STATUS_OUT_OF_RANGE, "i_max 11");
    CHECK(fw_core_set_limits(c, 5.0f, -1.0f, 100.0f) == FW_STATUS_OUT_OF_RANGE, "speed -1");
    CHECK(fw_core_set_limits(c, 5.0f, 1000.0f, (real_t)NAN) == FW_STATUS_OUT_OF_RANGE, "NaN");
    CHECK(memcmp(c, &snap, sizeof snap) == 0, "rejected limits changed the core");
    CHECK(fw_core_set_limits(c, 5.0f, 2500.0f, 500.0f) == FW_STATUS_OK, "valid limits");
    CHECK(fw_param_get(c, FW_PID_SPEED_MAX_RPM, &v) == FW_STATUS_OK && v == 2500.0f,
          "limits are the parameters");
    /* every table entry: default within range and readable */
    for (k = 0; k < fw_param_count(); k++) {
        const fw_param_info_t *pi = fw_param_info_at((uint16_t)k);
        CHECK(pi != NULL && pi->min <= pi->def && pi->def <= pi->max, "entry %u", (unsigned)k);
        CHECK(fw_param_info(pi->id) == pi, "lookup of id %u", pi->id);
    }
    CHECK(fw_param_info_at(fw_param_count()) == NULL, "past the end");
}

static void reach_run(sim_t *s)
{
    long k;
    sim_open(s, "ideal", 1.0, NULL);
    s->cmd.enable = 1;
    for (k = 0; k < 20000 && s->core->state != FW_STATE_RUN; k++) {
        sim_step(s);
    }
    CHECK(s->core->state == FW_STATE_RUN, "did not reach RUN (state %d, fault %u)",
          s->core->state, s->core->fault_code);
}

static void busy_while_running(void)
{
    sim_t *s = &S;
    reach_run(s);
    snap = *s->core;
    CHECK(fw_param_set(s->core, FW_PID_POLE_PAIRS, 3.0f) == FW_STATUS_BUSY, "config not busy");
    CHECK(memcmp(s->core, &snap, sizeof snap) == 0, "busy set changed the core");
    CHECK(fw_param_set(s->core, FW_PID_SPD_KP, 0.02f) == FW_STATUS_OK, "tuning while running");
}

/* the telemetry voltages are block means of FW_SPEED_DIVIDER periods: they change once per
 * block, then equal the mean of the block's per-period references (an alias-free 1 kHz value) */
static void telemetry_voltage_means(void)
{
    sim_t *s = &S;
    double vd[FW_SPEED_DIVIDER * 40], vq[FW_SPEED_DIVIDER * 40];
    const int n = FW_SPEED_DIVIDER * 40;
    int k, changes = 0, last_change = -1;
    double ripple = 0.0;
    fw_status_t st, prev;
    reach_run(s);
    s->cmd.ctrl_mode = FW_CTRL_CURRENT;
    s->cmd.iq_ref = 1.0f;
    fw_core_status(s->core, &prev);
    for (k = 0; k < n; k++) {
        sim_step(s);
        fw_core_status(s->core, &st);
        vd[k] = st.vd;
        vq[k] = st.vq;
        if (k > 0) {
            ripple = fmax(ripple, fabs(vq[k] - vq[k - 1]));
        }
        if (st.vd_mean != prev.vd_mean || st.vq_mean != prev.vq_mean) {
            double md = 0.0, mq = 0.0;
            int j;
            CHECK(last_change < 0 || k - last_change == FW_SPEED_DIVIDER,
                  "mean changed %d periods after the last change", k - last_change);
            /* RUN may start anywhere in a block: the first block is compared once it lies
             * wholly in the recording */
            if (k >= FW_SPEED_DIVIDER - 1) {
                for (j = k - FW_SPEED_DIVIDER + 1; j <= k; j++) {
                    md += vd[j] / FW_SPEED_DIVIDER;
                    mq += vq[j] / FW_SPEED_DIVIDER;
                }
                CHECK(fabs(st.vd_mean - md) < 1e-4 && fabs(st.vq_mean - mq) < 1e-4,
                      "block mean (%g, %g) V, expected (%g, %g) V", st.vd_mean, st.vq_mean, md,
                      mq);
            }
            changes++;
            last_change = k;
        }
        prev = st;
    }
    CHECK(changes >= n / FW_SPEED_DIVIDER - 1, "only %d block means in %d periods", changes, n);
    /* the test means something only when the per-period references do move */
    CHECK(ripple > 1e-3, "references constant (%g V): nothing to average", ripple);
}

static void drop_one_conversion(void *ctx, fw_adc_t *adc)
{
    (void)ctx;
    adc->n_soc = (int16_t)(adc->n_soc - 1);
}

static void adc_loss(void)
{
    sim_t *s = &S;
    int k;
    int loss_max;
    fw_pwm_t pwm;
    reach_run(s);
    loss_max = (int)s->core->p[FW_IDX_ADC_LOSS_MAX];
    for (k = 0; k < loss_max; k++) {
        fw_core_isr(s->core, NULL, &pwm);
        if (k < loss_max - 1) {
            CHECK(s->core->state == FW_STATE_RUN, "faulted after %d lost periods", k + 1);
        }
    }
    CHECK(s->core->state == FW_STATE_FAULT && s->core->fault_code == FW_FAULT_ADC_LOSS,
          "ADC loss: state %d fault %u", s->core->state, s->core->fault_code);
    CHECK(pwm.gate_enable == 0, "gates still enabled after ADC loss");

    /* a frame with the wrong number of conversions is a loss too */
    reach_run(s);
    sil_bench_set_adc_hook(s->b, drop_one_conversion, NULL);
    for (k = 0; k < loss_max; k++) {
        sim_step(s);
    }
    sil_bench_set_adc_hook(s->b, NULL, NULL);
    CHECK(s->core->fault_code == FW_FAULT_ADC_LOSS && s->pwm.gate_enable == 0, "short frame");

    /* fault reset: back to idle, outputs stay off until a new enable edge */
    s->cmd.fault_reset = 1;
    s->cmd.enable = 0;
    for (k = 0; k < 30; k++) {
        sim_step(s);
    }
    CHECK(s->core->state == FW_STATE_IDLE && s->core->fault_code == FW_FAULT_NONE &&
              s->pwm.gate_enable == 0,
          "reset: state %d", s->core->state);
}

static void command_timeout(void)
{
    sim_t *s = &S;
    long k;
    uint32_t limit;
    reach_run(s);
    limit = s->core->cmd_timeout_ticks;
    s->send_cmd = 0;
    /* the last command was at most 9 periods ago */
    for (k = 0; k < (long)limit + 20 && s->core->state == FW_STATE_RUN; k++) {
        sim_step(s);
    }
    CHECK(s->core->state == FW_STATE_FAULT && s->core->fault_code == FW_FAULT_CMD_TIMEOUT,
          "timeout: state %d fault %u", s->core->state, s->core->fault_code);
    CHECK(s->core->ticks_since_cmd == limit + 1u, "tripped after %u ticks, limit %u",
          (unsigned)s->core->ticks_since_cmd, (unsigned)limit);
    CHECK(s->pwm.gate_enable == 0, "gates on after the time-out");
}

static void repeated_frame(void)
{
    sim_t *s = &S;
    fw_pwm_t first;
    fw_pwm_t again;
    reach_run(s);
    sim_step(s); /* the bench's ISR of ADC(k): first */
    first = s->pwm;
    snap = *s->core;
    fw_core_isr(s->core, &s->adc, &again);
    CHECK(memcmp(&first, &again, sizeof first) == 0, "repeated ADC(k) gives another PWM");
    CHECK(memcmp(s->core, &snap, sizeof snap) == 0, "repeated ADC(k) changed the core");
    CHECK(first.period == s->adc.period + 1u, "pwm period %u for adc %u", (unsigned)first.period,
          (unsigned)s->adc.period);
}

/* what the ADC hook forces: one phase-a current sample, or the DC-link code */
typedef struct {
    int32_t ia0, vdc;
    int force_ia0, force_vdc;
} forced_adc_t;

static void force_adc(void *ctx, fw_adc_t *adc)
{
    const forced_adc_t *f = (const forced_adc_t *)ctx;
    if (f->force_ia0) {
        adc->ia[0] = f->ia0;
    }
    if (f->force_vdc) {
        adc->vdc = f->vdc;
    }
}

static void trips(void)
{
    sim_t *s = &S;
    forced_adc_t f;
    /* over-current on one sample */
    reach_run(s);
    memset(&f, 0, sizeof f);
    f.force_ia0 = 1;
    f.ia0 = sim_current_code(s, 9.8);
    sil_bench_set_adc_hook(s->b, force_adc, &f);
    sim_step(s);
    CHECK(s->core->fault_code == FW_FAULT_OVERCURRENT && s->pwm.gate_enable == 0, "OC: %u",
          s->core->fault_code);
    /* DC-link over-voltage */
    reach_run(s);
    memset(&f, 0, sizeof f);
    f.force_vdc = 1;
    f.vdc = sim_vdc_code(s, 270.0);
    sil_bench_set_adc_hook(s->b, force_adc, &f);
    sim_step(s);
    CHECK(s->core->fault_code == FW_FAULT_DC_OVERVOLTAGE && s->pwm.gate_enable == 0, "OV: %u",
          s->core->fault_code);
    /* under-voltage while running */
    reach_run(s);
    f.vdc = sim_vdc_code(s, 100.0);
    sil_bench_set_adc_hook(s->b, force_adc, &f);
    sim_step(s);
    CHECK(s->core->fault_code == FW_FAULT_DC_UNDERVOLTAGE && s->pwm.gate_enable == 0, "UV: %u",
          s->core->fault_code);
}

/* Codes outside the converter's range (the adversarial campaign sent INT32_MIN): no
 * arithmetic overflow (the sanitized build aborts on one), no false over-current; the
 * period counts as lost data, as a frame with the wrong n_soc does. The hook puts the codes
 * into what the core gets (the host HAL rejects them before: vio_codec.c). */
typedef struct {
    int32_t ia;
    int32_t ib0;
    int16_t index;
    int16_t set_ib0;
} bad_codes_t;

static void bad_codes(void *ctx, fw_adc_t *adc)
{
    const bad_codes_t *b = (const bad_codes_t *)ctx;
    if (adc->n_soc > 0) {
        adc->ia[b->index % adc->n_soc] = b->ia;
        if (b->set_ib0) {
            adc->ib[0] = b->ib0;
        }
    }
}

static void out_of_range_codes(void)
{
    sim_t *s = &S;
    const int32_t bad[] = {INT32_MIN, INT32_MIN + 1, -1, 65536, INT32_MAX};
    size_t i;
    bad_codes_t h;
    reach_run(s);
    for (i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        uint32_t lost = s->core->adc_loss_count;
        h.index = (int16_t)i;
        h.ia = bad[i] == 65536 ? (int32_t)1 << 24 : bad[i]; /* the ideal profile: 24 bits */
        h.set_ib0 = (int16_t)(bad[i] == INT32_MAX);
        h.ib0 = INT32_MIN;
        sil_bench_set_adc_hook(s->b, bad_codes, &h);
        sim_step(s);
        sil_bench_set_adc_hook(s->b, NULL, NULL);
        CHECK(s->core->fault_code != FW_FAULT_OVERCURRENT, "code %ld: false over-current",
              (long)bad[i]);
        CHECK(s->core->adc_loss_count == lost + 1u, "code %ld: not counted as lost data",
              (long)bad[i]);
        sim_step(s); /* a good period between (consecutive losses fault: adc_loss_max) */
    }
    CHECK(s->core->state == FW_STATE_RUN, "a few bad periods stopped the drive (state %d)",
          s->core->state);
    /* fw_protection_samples on its own: any code, no overflow */
    {
        fw_adc_t a;
        real_t peak = 0.0f;
        memset(&a, 0, sizeof a);
        a.n_soc = 2;
        a.ia[0] = INT32_MIN;
        a.ib[0] = INT32_MAX;
        a.ia[1] = INT32_MAX;
        a.ib[1] = INT32_MIN;
        (void)fw_protection_samples(&a, (int32_t)1 << 23, 1e-6f, 10.0f, &peak);
        CHECK(peak > 0.0f, "peak %g", (double)peak);
    }
    /* the phase no sensor measures: with an isolated neutral ic = -ia - ib, so 5 A out of
     * phases a and b is 10 A back through c, over a 9.5 A trip that neither measured phase
     * reaches; 5 A out of a and back through b leaves c at zero */
    {
        fw_adc_t a;
        real_t peak = 0.0f;
        const int32_t half = (int32_t)1 << 15;
        const real_t lsb = 10.0f / (real_t)half; /* a 16-bit converter over +-10 A */
        memset(&a, 0, sizeof a);
        a.n_soc = 1;
        a.ia[0] = half + (int32_t)(5.0f / lsb);
        a.ib[0] = half + (int32_t)(5.0f / lsb);
        CHECK(fw_protection_samples(&a, half, lsb, 9.5f, &peak) == FW_FAULT_OVERCURRENT &&
                  fabsf(peak - 10.0f) < 0.01f, "ia = ib = 5 A: peak %g A, phase c not watched",
              (double)peak);
        a.ib[0] = half - (int32_t)(5.0f / lsb);
        CHECK(fw_protection_samples(&a, half, lsb, 9.5f, &peak) == FW_FAULT_NONE &&
                  fabsf(peak - 5.0f) < 0.01f, "ia = -ib = 5 A: peak %g A", (double)peak);
    }
    /* the same on a converter whose lsb has more bits than its products keep exact (+-10.3 A:
     * the sample-by-sample path, not the integer codes') */
    {
        fw_adc_t a;
        real_t peak = 0.0f;
        const int32_t half = (int32_t)1 << 15;
        const real_t lsb = 10.3f / (real_t)half;
        memset(&a, 0, sizeof a);
        a.n_soc = 1;
        a.ia[0] = half + (int32_t)(5.0f / lsb);
        a.ib[0] = half + (int32_t)(5.0f / lsb);
        CHECK(fw_protection_samples(&a, half, lsb, 9.5f, &peak) == FW_FAULT_OVERCURRENT &&
                  fabsf(peak - 10.0f) < 0.01f,
              "ia = ib = 5 A, sample path: peak %g A, phase c not watched", (double)peak);
        a.ib[0] = half - (int32_t)(5.0f / lsb);
        CHECK(fw_protection_samples(&a, half, lsb, 9.5f, &peak) == FW_FAULT_NONE &&
                  fabsf(peak - 5.0f) < 0.01f, "ia = -ib = 5 A, sample path: peak %g A",
              (double)peak);
    }
}

static void idle_outputs_off(void)
{
    sim_t *s = &S;
    int k;
    sim_open(s, "ideal", 0.3, NULL);
    for (k = 0; k < 50; k++) {
        sim_step(s);
        CHECK(s->pwm.gate_enable == 0, "gates on in idle");
    }
    CHECK(s->core->state == FW_STATE_IDLE, "state %d", s->core->state);
    fw_core_isr(NULL, &s->adc, &s->pwm); /* no crash */
    fw_core_status(NULL, NULL);
}

int main(void)
{
    bad_commands();
    bad_params();
    busy_while_running();
    telemetry_voltage_means();
    adc_loss();
    command_timeout();
    repeated_frame();
    trips();
    out_of_range_codes();
    idle_outputs_off();
    sim_close(&S);
    TEST_DONE();
}
