/* fw_trig.c - sine, cosine and atan2 of the core in single precision, its own.
 *
 * The core's outputs must not depend on the C library it is linked with: glibc's sinf and
 * newlib's (the Cortex-M4F build) differ in the last bit for some arguments, and a last-bit
 * difference in an angle moves a PWM compare by a tick now and then and the states apart
 * after that. These use only float additions, multiplications and one division, each
 * rounded as IEEE 754 prescribes on every target (built without contraction into fused
 * multiply-adds), so the host and the target compute the same bits. Accuracy: within about
 * one unit in the last place for |x| < 6400 rad (the reduction below is exact there); the
 * core's angles are wrapped or products of a speed and a period, far inside that.
 *
 * On a C28x with TMU the three map to its sin/cos/atan instructions (per-unit angles), on a
 * fixed-point part to IQmath's _IQsin/_IQcos/_IQatan2 (fw_math.h).
 */
#include "fw_math.h"

/* pi/2 = PIO2_1 + PIO2_2 + PIO2_3: the first two have 12 significant bits, so k * PIO2_1
 * and k * PIO2_2 are exact for |k| < 2^12 (Cody and Waite's reduction) */
#define PIO2_1 FW_REAL(1.57080078125)
#define PIO2_2 FW_REAL(-4.453584551811218e-06)
#define PIO2_3 FW_REAL(-8.705515752716053e-10)
#define TWO_OVER_PI FW_REAL(0.63661977236758134308)
#define QUARTER_TURNS_MAX FW_REAL(1.0e6) /* beyond: no angle the core holds */

void fw_sincos(real_t x, real_t *s, real_t *c)
{
    const real_t q = x * TWO_OVER_PI;
    real_t r, r2, sr, cr;
    int32_t k;
    if (!(q > -QUARTER_TURNS_MAX && q < QUARTER_TURNS_MAX)) {
        const real_t z = x - x; /* NaN for NaN and infinities, as the C library's */
        *s = z;
        *c = FW_REAL(1.0) + z;
        return;
    }
    k = (int32_t)(q >= FW_REAL(0.0) ? q + FW_REAL(0.5) : q - FW_REAL(0.5));
    r = x - (real_t)k * PIO2_1;
    r = r - (real_t)k * PIO2_2;
    r = r - (real_t)k * PIO2_3; /* |r| <= pi/4 */
    r2 = r * r;
    /* Taylor series: the first omitted terms are below 2e-9 on |r| <= pi/4 */
    sr = r + r * r2 *
                 (FW_REAL(-1.0 / 6.0) +
                  r2 * (FW_REAL(1.0 / 120.0) +
                        r2 * (FW_REAL(-1.0 / 5040.0) + r2 * FW_REAL(1.0 / 362880.0))));
    cr = FW_REAL(1.0) - FW_REAL(0.5) * r2 +
         r2 * r2 *
             (FW_REAL(1.0 / 24.0) +
              r2 * (FW_REAL(-1.0 / 720.0) +
                    r2 * (FW_REAL(1.0 / 40320.0) + r2 * FW_REAL(-1.0 / 3628800.0))));
    switch (k & 3) {
    case 0: *s = sr; *c = cr; break;
    case 1: *s = cr; *c = -sr; break;
    case 2: *s = -sr; *c = -cr; break;
    default: *s = -cr; *c = sr; break;
    }
}

real_t fw_sin(real_t x)
{
    real_t s, c;
    fw_sincos(x, &s, &c);
    return s;
}

real_t fw_cos(real_t x)
{
    real_t s, c;
    fw_sincos(x, &s, &c);
    return c;
}

#define TAN_PI_8 FW_REAL(0.41421356237309504880)

/* atan(t) for 0 <= t <= 1 */
static real_t atan_unit(real_t t)
{
    real_t u = t, base = FW_REAL(0.0), u2;
    if (t > TAN_PI_8) { /* atan(t) = pi/4 + atan((t - 1) / (t + 1)), |u| <= tan(pi/8) */
        u = (t - FW_REAL(1.0)) / (t + FW_REAL(1.0));
        base = FW_M_PI / FW_REAL(4.0);
    }
    u2 = u * u;
    /* Taylor series to u^19: the first omitted term is below 2.5e-9 for |u| <= tan(pi/8) */
    return base +
           (u + u * u2 *
                    (FW_REAL(-1.0 / 3.0) +
                     u2 * (FW_REAL(1.0 / 5.0) +
                           u2 * (FW_REAL(-1.0 / 7.0) +
                                 u2 * (FW_REAL(1.0 / 9.0) +
                                       u2 * (FW_REAL(-1.0 / 11.0) +
                                             u2 * (FW_REAL(1.0 / 13.0) +
                                                   u2 * (FW_REAL(-1.0 / 15.0) +
                                                         u2 * (FW_REAL(1.0 / 17.0) +
                                                               u2 * FW_REAL(-1.0 / 19.0))))))))));
}

real_t fw_atan2(real_t y, real_t x)
{
    const real_t ax = fw_fabs(x), ay = fw_fabs(y);
    real_t a;
    if (!(ax == ax && ay == ay)) {
        return x + y; /* NaN */
    }
    if (ay <= ax) {
        a = (ax > FW_REAL(0.0)) ? atan_unit(ay / ax) : FW_REAL(0.0);
    } else {
        a = FW_M_PI / FW_REAL(2.0) - atan_unit(ax / ay);
    }
    if (x < FW_REAL(0.0)) {
        a = FW_M_PI - a;
    }
    return (y < FW_REAL(0.0)) ? -a : a;
}
