/* Current sensors, ringing, noise and the ADC transfer.
 *
 * Signal chain of a current channel (a or b):
 *   true phase current -> first-order sensor bandwidth (tau = 1/(2 pi f_bw))
 *   -> gain and offset -> + ringing + Gaussian noise  = analog ADC input
 *   -> offset-binary quantisation and clamping (docs/interfaces.md).
 *
 * Bandwidth: the filter is integrated exactly for a cubic (Hermite) interpolation of the
 * current over each integration substep, built from the current and its slope at both
 * ends. The interpolation error is below 1e-10 A for the substeps used, and the filter
 * stays exact however short its time constant is against the substep.
 *
 * Ringing: the profile's figure is what the ADC input shows (as one would measure it at
 * the ADC pin): after every jump of a leg's terminal voltage by more than Vdc/2 (a hard
 * switching edge), the leg's phase carries
 *     r(t) = sign * A * exp(-t/tau_r) * sin(2 pi f_r t),   t since the edge,
 * sign +1 for a rising edge (displacement current flows out of the leg). A share
 * ring_return_fraction of it returns through the two other phases, half each (with 1, the
 * default, the ringing is purely differential and KCL holds at the star point), so an edge
 * of the unsensed phase c shows on a and b with -A/2. The sine start keeps the sensed
 * current continuous at the edge.
 */
#include <math.h>

#include "plant_internal.h"

/* ------------------------------------------------------------ PRNG: xoshiro256** */

static uint64_t splitmix64(uint64_t *x)
{
    uint64_t z = (*x += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static uint64_t rotl(uint64_t x, int k)
{
    return (x << k) | (x >> (64 - k));
}

static uint64_t rng_next(plant_rng_t *r)
{
    const uint64_t result = rotl(r->s[1] * 5u, 7) * 9u;
    const uint64_t t = r->s[1] << 17;
    r->s[2] ^= r->s[0];
    r->s[3] ^= r->s[1];
    r->s[1] ^= r->s[2];
    r->s[0] ^= r->s[3];
    r->s[2] ^= t;
    r->s[3] = rotl(r->s[3], 45);
    return result;
}

void plant_rng_seed(plant_rng_t *rng, uint64_t seed)
{
    uint64_t x = seed;
    int k;
    for (k = 0; k < 4; ++k) {
        rng->s[k] = splitmix64(&x);
    }
    rng->has_spare = 0;
    rng->spare = 0.0;
}

/* Uniform in (-1, 1) with 53 random bits. */
static double rng_sym_uniform(plant_rng_t *r)
{
    return ((double)(rng_next(r) >> 11) + 0.5) * (2.0 / 9007199254740992.0) - 1.0;
}

/* Standard normal deviate, Marsaglia's polar method (deterministic sequence). */
double plant_rng_gauss(plant_rng_t *rng)
{
    double u, v, s;
    if (rng->has_spare) {
        rng->has_spare = 0;
        return rng->spare;
    }
    do {
        u = rng_sym_uniform(rng);
        v = rng_sym_uniform(rng);
        s = u * u + v * v;
    } while (s >= 1.0 || s == 0.0);
    s = sqrt(-2.0 * log(s) / s);
    rng->spare = v * s;
    rng->has_spare = 1;
    return u * s;
}

/* ------------------------------------------------------------ sensor bandwidth */

void plant_filter_eval(const plant_sensors_t *sen, const double i0[2], const double di0[2],
                       const double i1[2], const double di1[2], double h, double s,
                       double out[2])
{
    const double tau = sen->tau;
    const double decay = tau > 0.0 ? exp(-s / tau) : 0.0;
    int ch;
    for (ch = 0; ch < 2; ++ch) {
        const double delta = i1[ch] - i0[ch];
        double p, yp, yp0;
        if (h < 1e-8) {
            /* Very short substep: a linear input is exact enough (curvature error < 1e-10 A)
             * and avoids the cancellation of the cubic coefficients. */
            const double m = h > 0.0 ? delta / h : 0.5 * (di0[ch] + di1[ch]);
            p = i0[ch] + m * s;
            yp = p - tau * m;
            yp0 = i0[ch] - tau * m;
        } else {
            const double c2 = (3.0 * delta / h - 2.0 * di0[ch] - di1[ch]) / h;
            const double c3 = (-2.0 * delta / h + di0[ch] + di1[ch]) / (h * h);
            const double dp = di0[ch] + s * (2.0 * c2 + 3.0 * c3 * s);
            const double ddp = 2.0 * c2 + 6.0 * c3 * s;
            const double dddp = 6.0 * c3;
            p = i0[ch] + s * (di0[ch] + s * (c2 + c3 * s));
            /* particular solution of tau*y' + y = p for a cubic p */
            yp = p - tau * dp + tau * tau * ddp - tau * tau * tau * dddp;
            yp0 = i0[ch] - tau * di0[ch] + tau * tau * 2.0 * c2 - tau * tau * tau * dddp;
        }
        out[ch] = tau > 0.0 ? yp + decay * (sen->y[ch] - yp0) : p;
    }
}

/* ------------------------------------------------------------ ringing */

/* A ringing source older than this many decay times is gone: exp(-40) ~ 4e-18. */
#define RING_HORIZON_TAUS 40.0

void plant_ring_add(plant_sensors_t *sen, double t, int leg, double sign)
{
    if (sen->n_ring == PLANT_MAX_RINGS) {
        int k; /* drop the oldest: it has decayed the most */
        for (k = 1; k < sen->n_ring; ++k) {
            sen->ring[k - 1] = sen->ring[k];
        }
        sen->n_ring--;
    }
    sen->ring[sen->n_ring].t = t;
    sen->ring[sen->n_ring].leg = leg;
    sen->ring[sen->n_ring].sign = sign;
    sen->n_ring++;
}

void plant_ring_eval(const plant_sensors_t *sen, const plant_config_t *cfg, double t,
                     double out[2])
{
    const double amp = cfg->sensors.ring_amp_a, tau = cfg->sensors.ring_tau_s;
    const double w = PLANT_TWO_PI * cfg->sensors.ring_freq_hz;
    const double ret = -0.5 * cfg->sensors.ring_return_fraction;
    const double horizon = RING_HORIZON_TAUS * tau; /* as plant_ring_next_period */
    int k;
    out[0] = 0.0;
    out[1] = 0.0;
    for (k = 0; k < sen->n_ring; ++k) {
        const double dt = t - sen->ring[k].t;
        double r;
        if (dt <= 0.0 || dt >= horizon) {
            continue; /* not started, or decayed below 1e-18 of its amplitude */
        }
        r = sen->ring[k].sign * amp * exp(-dt / tau) * sin(w * dt);
        switch (sen->ring[k].leg) {
        case 0:
            out[0] += r;
            out[1] += ret * r;
            break;
        case 1:
            out[0] += ret * r;
            out[1] += r;
            break;
        default:
            out[0] += ret * r;
            out[1] += ret * r;
            break;
        }
    }
}

void plant_ring_next_period(plant_sensors_t *sen, const plant_config_t *cfg, double ts)
{
    const double horizon = RING_HORIZON_TAUS * cfg->sensors.ring_tau_s;
    int k, n = 0;
    for (k = 0; k < sen->n_ring; ++k) {
        if (ts - sen->ring[k].t < horizon) {
            sen->ring[n] = sen->ring[k];
            sen->ring[n].t -= ts;
            ++n;
        }
    }
    sen->n_ring = n;
}

/* ------------------------------------------------------------ ADC */

/* 2^bits: exact either way; the shift avoids a libm call per sample and channel. */
static double pow2(int bits)
{
    return bits >= 0 && bits < 63 ? (double)((uint64_t)1 << bits) : ldexp(1.0, bits);
}

int32_t plant_adc_current_code(double i_a, int bits, double range_a, int *clipped)
{
    const double full = pow2(bits);
    const double raw = floor((i_a + range_a) / (2.0 * range_a) * full + 0.5);
    *clipped = 0;
    if (!(raw >= 0.0)) { /* also catches NaN */
        *clipped = 1;
        return 0;
    }
    if (raw > full - 1.0) {
        *clipped = 1;
        return (int32_t)(full - 1.0);
    }
    return (int32_t)raw;
}

int32_t plant_adc_vdc_code(double vdc_v, int bits, double range_v, int *clipped)
{
    const double full = pow2(bits);
    const double raw = floor(vdc_v / range_v * full + 0.5);
    *clipped = 0;
    if (!(raw >= 0.0)) {
        *clipped = 1;
        return 0;
    }
    if (raw > full - 1.0) {
        *clipped = 1;
        return (int32_t)(full - 1.0);
    }
    return (int32_t)raw;
}
