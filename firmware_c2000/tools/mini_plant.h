/* mini_plant.h - a deliberately small IPMSM + inverter + ADC model for the core's own
 * benchmark and core-level simulation tests (host only; the real plant is plant_rt/).
 *
 * State: stator flux linkage psi (alpha-beta), rotor angle and speed. Current from flux in the
 * rotor frame: id = x/Ld + k*x^3 for x = psi_d - lambda > 0 (magnet-side saturation, k = 0:
 * linear); iq from psi_q = Lq iq / (1 + a iq^2) (q self-saturation as in DESIGN.md section 5,
 * a = 0: linear), so incremental and apparent inductances are consistent.
 * dpsi/dt = v - rs*i, integrated with midpoint steps of 0.1 us; the phase voltages follow the
 * compare values of docs/interfaces.md exactly (no dead time). Samples at the SOC ticks are
 * converted to offset-binary codes with optional Gaussian noise.
 */
#ifndef MINI_PLANT_H
#define MINI_PLANT_H

#include <math.h>
#include <stdint.h>

#include "fw_core.h"

typedef struct {
    double rs, ld, lq, lambda, pp, j, b, vdc;
    double sat_k;        /* A/Wb^3, magnet-side d-axis saturation (0: linear) */
    double qsat_a;       /* 1/A^2, q-axis self-saturation psi_q = Lq iq / (1 + a iq^2) */
    double load_nm;      /* load torque */
    int hold_speed;      /* 1: speed fixed at omega_m (dynamometer) */
    double noise_a;      /* rms current noise per sample */
    int bits;            /* current ADC bits */
    double range_a;
    int vdc_bits;
    double vdc_range;
    /* state */
    double psi_a, psi_b; /* stator flux, V*s */
    double theta;        /* electrical angle, rad (unwrapped) */
    double omega_m;      /* mechanical speed, rad/s */
    uint64_t rng;
    double ia, ib;       /* last current alpha-beta */
    double ia_mean, ib_mean; /* period-mean current alpha-beta of the last period */
} mini_plant_t;

static inline void mp_default(mini_plant_t *m)
{
    m->rs = 1.93;
    m->ld = 0.015;
    m->lq = 0.032;
    m->lambda = 0.216;
    m->pp = 2.0;
    m->j = 0.0005;
    m->b = 0.003;
    m->vdc = 200.0;
    m->sat_k = 0.0;
    m->qsat_a = 0.0;
    m->load_nm = 0.0;
    m->hold_speed = 0;
    m->noise_a = 0.0;
    m->bits = 16;
    m->range_a = 10.0;
    m->vdc_bits = 16;
    m->vdc_range = 400.0;
    m->theta = 0.0;
    m->omega_m = 0.0;
    m->rng = 0x9E3779B97F4A7C15ull;
    /* zero current: psi = lambda along d */
    m->psi_a = m->lambda * cos(m->theta);
    m->psi_b = m->lambda * sin(m->theta);
    m->ia = m->ib = 0.0;
}

static inline void mp_set_angle(mini_plant_t *m, double theta)
{
    m->theta = theta;
    m->psi_a = m->lambda * cos(theta);
    m->psi_b = m->lambda * sin(theta);
}

static inline double mp_gauss(mini_plant_t *m)
{
    double u1;
    double u2;
    m->rng ^= m->rng << 13;
    m->rng ^= m->rng >> 7;
    m->rng ^= m->rng << 17;
    u1 = ((double)(m->rng >> 11) + 0.5) / 9007199254740992.0;
    m->rng ^= m->rng << 13;
    m->rng ^= m->rng >> 7;
    m->rng ^= m->rng << 17;
    u2 = ((double)(m->rng >> 11) + 0.5) / 9007199254740992.0;
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

/* current from flux at angle theta */
static inline void mp_current(const mini_plant_t *m, double psi_a, double psi_b, double theta,
                              double *ia, double *ib)
{
    double c = cos(theta);
    double s = sin(theta);
    double psd = c * psi_a + s * psi_b;
    double psq = -s * psi_a + c * psi_b;
    double x = psd - m->lambda;
    double id = x / m->ld + ((x > 0.0) ? m->sat_k * x * x * x : 0.0);
    /* inverse of psi_q = Lq iq / (1 + a iq^2), the branch through the origin */
    double disc = m->lq * m->lq - 4.0 * m->qsat_a * psq * psq;
    double iq = 2.0 * psq / (m->lq + sqrt(disc > 0.0 ? disc : 0.0));
    *ia = c * id - s * iq;
    *ib = s * id + c * iq;
}

static inline void mp_phase_voltage(const mini_plant_t *m, const fw_pwm_t *pwm, int32_t tick,
                                    double *va, double *vb)
{
    int x;
    double s[3];
    for (x = 0; x < 3; x++) {
        int32_t on = pwm->cmp_up[x];
        int32_t off = 2 * (int32_t)FW_TBPRD - pwm->cmp_dn[x];
        s[x] = (pwm->gate_enable && tick >= on && tick < off) ? 1.0 : 0.0;
    }
    *va = m->vdc * (2.0 / 3.0) * (s[0] - 0.5 * (s[1] + s[2]));
    *vb = m->vdc / sqrt(3.0) * (s[1] - s[2]);
}

static inline int32_t mp_code(const mini_plant_t *m, double i)
{
    double full = (double)((int64_t)1 << m->bits);
    double code = floor((i + m->range_a) / (2.0 * m->range_a) * full + 0.5);
    if (code < 0.0) {
        code = 0.0;
    }
    if (code > full - 1.0) {
        code = full - 1.0;
    }
    return (int32_t)code;
}

/* Simulate one period with pwm (gate off: all phases open, treated as zero current when the
 * EMF stays below Vdc). Fills adc for the SOCs of pwm. */
static inline void mp_period(mini_plant_t *m, const fw_pwm_t *pwm, fw_adc_t *adc)
{
    const int32_t sub = 10; /* ticks per step: 0.1 us */
    int32_t t;
    int16_t k;
    double samp_a[FW_MAX_SOC];
    double samp_b[FW_MAX_SOC];
    double dt = (double)sub / 1e8;
    double sum_a = 0.0;
    double sum_b = 0.0;
    int32_t n_steps = 0;
    adc->period = pwm->period;
    adc->n_soc = pwm->n_soc;
    for (t = 0; t < 2 * (int32_t)FW_TBPRD; t += sub) {
        double va;
        double vb;
        double ia;
        double ib;
        double te;
        /* samples that fall in [t, t+sub) are taken at t (0.1 us resolution) */
        for (k = 0; k < pwm->n_soc; k++) {
            if (pwm->soc[k] >= t && pwm->soc[k] < t + sub) {
                mp_current(m, m->psi_a, m->psi_b, m->theta, &samp_a[k], &samp_b[k]);
            }
        }
        mp_phase_voltage(m, pwm, t, &va, &vb);
        mp_current(m, m->psi_a, m->psi_b, m->theta, &ia, &ib);
        if (!pwm->gate_enable) {
            /* open inverter: current decays to zero (no conduction at these speeds) */
            double th = m->theta + m->omega_m * m->pp * dt;
            m->theta = th;
            m->psi_a = m->lambda * cos(th);
            m->psi_b = m->lambda * sin(th);
            ia = ib = 0.0;
        } else {
            /* midpoint step */
            double th_mid = m->theta + 0.5 * m->omega_m * m->pp * dt;
            double pa = m->psi_a + 0.5 * dt * (va - m->rs * ia);
            double pb = m->psi_b + 0.5 * dt * (vb - m->rs * ib);
            double ia_m;
            double ib_m;
            mp_current(m, pa, pb, th_mid, &ia_m, &ib_m);
            m->psi_a += dt * (va - m->rs * ia_m);
            m->psi_b += dt * (vb - m->rs * ib_m);
            m->theta += m->omega_m * m->pp * dt;
            ia = ia_m;
            ib = ib_m;
        }
        te = 1.5 * m->pp * (m->psi_a * ib - m->psi_b * ia);
        if (!m->hold_speed) {
            m->omega_m += dt * (te - m->load_nm - m->b * m->omega_m) / m->j;
        }
        m->ia = ia;
        m->ib = ib;
        sum_a += ia;
        sum_b += ib;
        n_steps++;
    }
    m->ia_mean = sum_a / (double)n_steps;
    m->ib_mean = sum_b / (double)n_steps;
    for (k = 0; k < pwm->n_soc; k++) {
        /* phase currents a, b from alpha-beta (amplitude-invariant Clarke) */
        double i_a = samp_a[k];
        double i_b = -0.5 * samp_a[k] + 0.5 * sqrt(3.0) * samp_b[k];
        if (m->noise_a > 0.0) {
            i_a += m->noise_a * mp_gauss(m);
            i_b += m->noise_a * mp_gauss(m);
        }
        adc->ia[k] = mp_code(m, i_a);
        adc->ib[k] = mp_code(m, i_b);
    }
    adc->vdc = (int32_t)floor(m->vdc / m->vdc_range * (double)((int64_t)1 << m->vdc_bits) + 0.5);
}

#endif /* MINI_PLANT_H */
