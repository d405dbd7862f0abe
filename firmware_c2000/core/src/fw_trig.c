/* fw_trig.c - sine, cosine and atan2 of the core in single precision, its own.
 *
 * The core's outputs must not depend on the C library it is linked with: glibc's sinf and
 * newlib's (the Cortex-M4F build) differ in the last bit for some arguments, and a last-bit
 * difference in an angle moves a PWM compare by a tick now and then and the states apart
 * after that. These use only float additions, multiplications and one division, each
 * rounded as IEEE 754 prescribes on every target (built without contraction into fused
 * multiply-adds), so the host and the target compute the same bits. Accuracy: within about
 * one unit in the last place for |x| < 6400 rad (the reduction below is exact there); the
 * core's angles are wrapped or products of a speed and a period, far inside that. The sine
 * and cosine (fw_sincos) are inline in fw_math.h: a dozen per period, and the call with its
 * results through memory cost a fifth of each on a Cortex-M4F.
 *
 * On a C28x with TMU the three map to its sin/cos/atan instructions (per-unit angles), on a
 * fixed-point part to IQmath's _IQsin/_IQcos/_IQatan2 (fw_math.h).
 */
#include "fw_math.h"

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
