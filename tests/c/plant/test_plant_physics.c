/* Analytic checks of the plant: gate timing with dead time, ADC transfer, locked-rotor RL
 * step response, torque (paper eq. 10), back-EMF of an open machine, the diode bridge,
 * determinism of the noise. */
#include <string.h>

#include "../check.h"
#include "plant_cmd.h"
#include "plant_internal.h"

#define PI 3.14159265358979323846

static void test_schedule(void)
{
    plant_gate_memory_t mem;
    plant_leg_schedule_t legs[3];
    plant_pwm_cmd_t c;
    memset(&mem, 0, sizeof(mem));

    /* first period after start-up: every turn-on is delayed by 200 ticks */
    cmd_set(&c, 1000, 1500, 5000, 5000, 0, 0);
    plant_inverter_schedule(&c, 200, &mem, legs);
    CHECK(legs[0].state0 == GATE_NONE);
    CHECK(legs[0].n_edges == 5);
    CHECK(legs[0].tick[0] == 200 && legs[0].state[0] == GATE_LOWER);
    CHECK(legs[0].tick[1] == 1000 && legs[0].state[1] == GATE_NONE);
    CHECK(legs[0].tick[2] == 1200 && legs[0].state[2] == GATE_UPPER);
    CHECK(legs[0].tick[3] == 8500 && legs[0].state[3] == GATE_NONE);
    CHECK(legs[0].tick[4] == 8700 && legs[0].state[4] == GATE_LOWER);
    CHECK(legs[1].state0 == GATE_NONE && legs[1].n_edges == 1 && legs[1].tick[0] == 200 &&
          legs[1].state[0] == GATE_LOWER);
    CHECK(legs[2].state0 == GATE_NONE && legs[2].n_edges == 1 && legs[2].state[0] == GATE_UPPER);

    /* same command again: gates that stay commanded across the boundary are not delayed */
    plant_inverter_schedule(&c, 200, &mem, legs);
    CHECK(legs[0].state0 == GATE_LOWER && legs[0].n_edges == 4);
    CHECK(legs[0].tick[0] == 1000 && legs[0].tick[1] == 1200);
    CHECK(legs[1].state0 == GATE_LOWER && legs[1].n_edges == 0);
    CHECK(legs[2].state0 == GATE_UPPER && legs[2].n_edges == 0);

    /* a command pulse shorter than the dead time is swallowed; leg c switches off at 0 */
    cmd_set(&c, 1000, 1500, 4950, 4950, 5000, 5000);
    plant_inverter_schedule(&c, 200, &mem, legs);
    CHECK(legs[1].state0 == GATE_LOWER && legs[1].n_edges == 2);
    CHECK(legs[1].tick[0] == 4950 && legs[1].state[0] == GATE_NONE);
    CHECK(legs[1].tick[1] == 5250 && legs[1].state[1] == GATE_LOWER);
    CHECK(legs[2].state0 == GATE_NONE && legs[2].n_edges == 1 && legs[2].tick[0] == 200);

    /* a turn-on delayed past the period end happens in the next period */
    cmd_set(&c, 2000, 50, 5000, 5000, 5000, 5000);
    plant_inverter_schedule(&c, 200, &mem, legs);
    CHECK(legs[0].n_edges == 3 && legs[0].tick[2] == 9950 && legs[0].state[2] == GATE_NONE);
    cmd_set(&c, 2000, 2000, 5000, 5000, 5000, 5000);
    plant_inverter_schedule(&c, 200, &mem, legs);
    CHECK(legs[0].state0 == GATE_NONE && legs[0].tick[0] == 150 && legs[0].state[0] == GATE_LOWER);

    /* gate_enable = 0: all off, and the next enabled period starts with a dead time */
    c.gate_enable = 0;
    plant_inverter_schedule(&c, 200, &mem, legs);
    CHECK(legs[0].n_edges == 0 && legs[0].state0 == GATE_NONE);
    c.gate_enable = 1;
    plant_inverter_schedule(&c, 200, &mem, legs);
    CHECK(legs[1].state0 == GATE_NONE && legs[1].tick[0] == 200);

    /* no dead time: complementary gates switch at the compare instants */
    memset(&mem, 0, sizeof(mem));
    cmd_set(&c, 1000, 1500, 0, 0, 5000, 5000);
    plant_inverter_schedule(&c, 0, &mem, legs);
    CHECK(legs[0].state0 == GATE_LOWER && legs[0].n_edges == 2 && legs[0].tick[0] == 1000 &&
          legs[0].tick[1] == 8500);
}

static void test_adc(void)
{
    int clip;
    CHECK(plant_adc_current_code(0.0, 16, 10.0, &clip) == 32768 && !clip);
    CHECK(plant_adc_current_code(-10.0, 16, 10.0, &clip) == 0 && !clip);
    CHECK(plant_adc_current_code(10.0, 16, 10.0, &clip) == 65535 && clip);
    CHECK(plant_adc_current_code(-10.1, 16, 10.0, &clip) == 0 && clip);
    /* one LSB is 2R/2^N; the code steps half an LSB either side of a level */
    CHECK(plant_adc_current_code(20.0 / 65536.0 * 0.49, 16, 10.0, &clip) == 32768);
    CHECK(plant_adc_current_code(20.0 / 65536.0 * 0.51, 16, 10.0, &clip) == 32769);
    CHECK(plant_adc_current_code(1.0, 12, 10.0, &clip) == 2048 + 205);
    CHECK(plant_adc_vdc_code(200.0, 16, 400.0, &clip) == 32768 && !clip);
    CHECK(plant_adc_vdc_code(400.0, 16, 400.0, &clip) == 65535 && clip);
    CHECK(plant_adc_vdc_code(200.0, 23, 400.0, &clip) == 4194304);
}

static plant_t *open_with(const char *profile, const char **sets, int n)
{
    char path[512], err[512];
    plant_t *p;
    snprintf(path, sizeof(path), "%s/%s.toml", PROFILES_DIR, profile);
    p = plant_open(path, sets, n, err, sizeof(err));
    if (!p) {
        fprintf(stderr, "plant_open: %s\n", err);
    }
    CHECK(p != NULL);
    return p;
}

/* Locked rotor, one constant voltage vector along phase a: with the rotor at theta the
 * vector has d and q components v*cos(theta) and -v*sin(theta), and each axis current is
 * an exact RL step with its own inductance (no speed, linear magnetics). */
static void test_rl_step(double theta)
{
    const char *sets[] = {"load.mode=1", "load.speed_rpm=0"};
    plant_t *p = open_with("ideal", sets, 2);
    plant_pwm_cmd_t c;
    plant_truth_t t;
    const double v = 2.0 / 3.0 * 200.0, rs = 1.93, ld = 0.015, lq = 0.032;
    int k;
    double worst = 0.0;
    if (!p) {
        return;
    }
    plant_set_state(p, theta, 0.0, 0.0, 0.0);
    cmd_set(&c, 0, 0, 5000, 5000, 5000, 5000); /* a upper on, b and c lower on */
    for (k = 0; k < 8; ++k) {
        const double time = (k + 1) * PLANT_TS_S;
        const double id = v * cos(theta) / rs * (1.0 - exp(-time * rs / ld));
        const double iq = -v * sin(theta) / rs * (1.0 - exp(-time * rs / lq));
        c.period = plant_next_period(p);
        plant_step(p, &c, NULL, NULL);
        plant_truth_now(p, &t);
        worst = fmax(worst, fmax(fabs(t.id - id), fabs(t.iq - iq)));
    }
    printf("RL step at theta %.2f rad: max error %.3g A\n", theta, worst);
    CHECK(worst < 1e-9);
    plant_free(p);
}

static void test_torque(void)
{
    plant_t *p = open_with("ideal", NULL, 0);
    plant_truth_t t;
    const double cases[3][2] = {{-1.0, 2.0}, {0.5, -3.0}, {-4.0, 4.5}};
    int k;
    if (!p) {
        return;
    }
    for (k = 0; k < 3; ++k) {
        const double id = cases[k][0], iq = cases[k][1];
        plant_set_state(p, 0.7, 0.0, id, iq);
        plant_truth_now(p, &t);
        /* paper eq. 10 with P = 4: Te = 3P/4 [(Ld - Lq) id iq + lambda_m iq] */
        CHECK_NEAR(t.te, 3.0 * 4.0 / 4.0 * ((0.015 - 0.032) * id * iq + 0.216 * iq), 1e-12);
        CHECK_NEAR(t.id, id, 1e-12);
        CHECK_NEAR(t.iq, iq, 1e-12);
        CHECK_NEAR(t.ia + t.ib + t.ic, 0.0, 1e-12);
    }
    plant_free(p);
}

/* Open machine (gates disabled) below the rectifying speed: the phase voltages are the
 * back-EMF, amplitude lambda_m * w_e; the currents stay exactly zero. */
static void test_back_emf(const char *profile)
{
    const char *sets[] = {"load.mode=1", "load.speed_rpm=1000", "initial.theta_e_deg=20"};
    plant_t *p = open_with(profile, sets, 3);
    plant_pwm_cmd_t c;
    plant_truth_t t;
    const double we = 1000.0 / 60.0 * 2.0 * PI * 2.0, lam = plant_config(p)->machine.lambda_m_wb;
    double peak = 0.0;
    int k;
    memset(&c, 0, sizeof(c));
    for (k = 0; k < 400; ++k) {
        c.period = plant_next_period(p);
        plant_step(p, &c, NULL, &t);
        CHECK_NEAR(t.ua, -lam * we * sin(t.theta_e), 1e-9);
        CHECK_NEAR(t.ub, -lam * we * sin(t.theta_e - 2.0 * PI / 3.0), 1e-9);
        CHECK_NEAR(t.ia, 0.0, 0.0);
        CHECK_NEAR(t.ib, 0.0, 0.0);
        peak = fmax(peak, fabs(t.ua - t.ub) / sqrt(3.0));
    }
    printf("%s: back-EMF amplitude %.6f V (lambda_m*w_e = %.6f V)\n", profile, peak, lam * we);
    CHECK(fabs(peak - lam * we) < 2e-3 * lam * we); /* sampled every 100 us: peak within 0.2 % */
    plant_free(p);
}

/* Above the rectifying speed the diode bridge conducts and brakes the machine. */
static void test_rectifier(void)
{
    const char *fast[] = {"load.mode=1", "load.speed_rpm=3000"};
    const char *slow[] = {"load.mode=1", "load.speed_rpm=2000"};
    plant_t *p = open_with("paper", fast, 2);
    plant_pwm_cmd_t c;
    plant_truth_t t;
    double te_sum = 0.0, imax = 0.0;
    int k;
    memset(&c, 0, sizeof(c));
    for (k = 0; k < 600; ++k) {
        c.period = plant_next_period(p);
        plant_step(p, &c, NULL, &t);
        if (k >= 300) {
            te_sum += t.te;
            imax = fmax(imax, fabs(t.ia));
        }
    }
    printf("rectifying at 3000 r/min: peak current %.3f A, mean torque %.4f N*m\n", imax,
           te_sum / 300.0);
    CHECK(imax > 0.1);
    CHECK(te_sum < 0.0);
    plant_free(p);
    p = open_with("paper", slow, 2);
    for (k = 0; k < 300; ++k) {
        c.period = plant_next_period(p);
        plant_step(p, &c, NULL, &t);
        CHECK(t.ia == 0.0 && t.ib == 0.0 && t.ic == 0.0);
    }
    plant_free(p);
}

static void test_determinism(void)
{
    const char *s1[] = {"sensors.seed=5"};
    const char *s2[] = {"sensors.seed=6"};
    plant_t *a = open_with("harsh", s1, 1), *b = open_with("harsh", s1, 1);
    plant_t *d = open_with("harsh", s2, 1);
    plant_pwm_cmd_t c;
    plant_samples_t sa, sb, sd;
    int k, same = 1, differ = 0;
    cmd_set(&c, 2000, 2000, 2600, 2600, 3000, 3000);
    c.n_soc = 4;
    c.soc[0] = 100;
    c.soc[1] = 2100;
    c.soc[2] = 4000;
    c.soc[3] = 9000;
    for (k = 0; k < 50; ++k) {
        c.period = (uint32_t)k;
        plant_step(a, &c, &sa, NULL);
        plant_step(b, &c, &sb, NULL);
        plant_step(d, &c, &sd, NULL);
        same &= memcmp(sa.ia_code, sb.ia_code, sizeof(sa.ia_code)) == 0;
        differ |= memcmp(sa.ia_code, sd.ia_code, sizeof(sa.ia_code)) != 0;
    }
    CHECK(same);
    CHECK(differ);
    plant_free(a);
    plant_free(b);
    plant_free(d);
}

int main(void)
{
    test_schedule();
    test_adc();
    test_rl_step(0.0);
    test_rl_step(0.4);
    test_rl_step(PI / 2.0);
    test_rl_step(2.0);
    test_torque();
    test_back_emf("ideal");
    test_back_emf("paper");
    test_rectifier();
    test_determinism();
    return check_report("test_plant_physics");
}
