/* fw_math.h - the few math functions the core needs, behind one interface.
 *
 * Float build: sqrtf and floorf of the C library (exact on every IEEE 754 target); sine,
 * cosine and atan2 are the core's own (fw_trig.c: the C libraries differ in their last
 * bits). A fixed-point build maps these to IQmath (_IQsin, _IQatan2, _IQsqrt ...) together
 * with the real_t typedef in fw_types.h. Nothing else in the core includes math.h.
 */
#ifndef FW_MATH_H
#define FW_MATH_H

#include <float.h>
#include <math.h>
#include "fw_types.h"

#define FW_M_PI ((real_t)3.14159265358979323846)
#define FW_M_2PI ((real_t)6.28318530717958647692)
#define FW_M_SQRT3 ((real_t)1.73205080756887729353)
#define FW_M_INV_SQRT3 ((real_t)0.57735026918962576451)
#define FW_REAL_MAX FLT_MAX

/* alpha-beta (or d-q) vector; also used as a complex number re + j*im */
typedef struct {
    real_t re;
    real_t im;
} fw_cplx_t;

static inline real_t fw_sqrt(real_t x) { return (x > FW_REAL(0.0)) ? sqrtf(x) : FW_REAL(0.0); }
static inline real_t fw_fabs(real_t x) { return (x < FW_REAL(0.0)) ? -x : x; }
/* sine, cosine (both of one angle: one reduction) and atan2 are the core's own (fw_sincos
 * here, inline: a dozen per period; the rest in fw_trig.c): the same bits on every target
 * whatever its C library. They use only float additions and multiplications, each rounded as
 * IEEE 754 prescribes on every target (built without contraction into fused multiply-adds).
 * Accuracy: within about one unit in the last place for |x| < 6400 rad (the reduction is
 * exact there); the core's angles are wrapped or products of a speed and a period.
 * pi/2 = PIO2_1 + PIO2_2 + PIO2_3: the first two have 12 significant bits, so k * PIO2_1 and
 * k * PIO2_2 are exact for |k| < 2^12 (Cody and Waite's reduction). */
#define FW_TRIG_PIO2_1 FW_REAL(1.57080078125)
#define FW_TRIG_PIO2_2 FW_REAL(-4.453584551811218e-06)
#define FW_TRIG_PIO2_3 FW_REAL(-8.705515752716053e-10)
#define FW_TRIG_TWO_OVER_PI FW_REAL(0.63661977236758134308)
#define FW_TRIG_QUARTER_TURNS_MAX FW_REAL(1.0e6) /* beyond: no angle the core holds */
static inline void fw_sincos(real_t x, real_t *s, real_t *c)
{
    const real_t q = x * FW_TRIG_TWO_OVER_PI;
    real_t r, r2, sr, cr;
    int32_t k;
    if (!(q > -FW_TRIG_QUARTER_TURNS_MAX && q < FW_TRIG_QUARTER_TURNS_MAX)) {
        const real_t z = x - x; /* NaN for NaN and infinities, as the C library's */
        *s = z;
        *c = FW_REAL(1.0) + z;
        return;
    }
    k = (int32_t)(q >= FW_REAL(0.0) ? q + FW_REAL(0.5) : q - FW_REAL(0.5));
    r = x - (real_t)k * FW_TRIG_PIO2_1;
    r = r - (real_t)k * FW_TRIG_PIO2_2;
    r = r - (real_t)k * FW_TRIG_PIO2_3; /* |r| <= pi/4 */
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
real_t fw_sin(real_t x);
real_t fw_cos(real_t x);
real_t fw_atan2(real_t y, real_t x);
/* floor, exact as floorf for every float (signed zeros, infinities and NaN included), without
 * the library call: the Cortex-M4F has no rounding instruction and newlib's floorf takes
 * ~20 instructions of bit handling; a conversion toward zero is one (VCVT) */
static inline real_t fw_floor(real_t x)
{
    real_t t;
    if (!(fw_fabs(x) < FW_REAL(8388608.0)) || x == FW_REAL(0.0)) {
        return x; /* |x| >= 2^23 is integral already; NaN, infinities and zeros as they are */
    }
    t = (real_t)(int32_t)x;
    return (t > x) ? t - FW_REAL(1.0) : t;
}
static inline real_t fw_min(real_t a, real_t b) { return (a < b) ? a : b; }
static inline real_t fw_max(real_t a, real_t b) { return (a > b) ? a : b; }
static inline real_t fw_clamp(real_t x, real_t lo, real_t hi)
{
    return (x < lo) ? lo : ((x > hi) ? hi : x);
}
/* finite check without isfinite(): NaN fails the equality, +-inf fails the bounds */
static inline int16_t fw_is_finite(real_t x)
{
    return (int16_t)((x == x) && (x <= FW_REAL_MAX) && (x >= -FW_REAL_MAX));
}
/* angle to (-pi, pi] */
static inline real_t fw_wrap_pi(real_t x)
{
    return x + FW_M_2PI * fw_floor((FW_M_PI - x) / FW_M_2PI);
}
/* angle to [0, 2pi) */
static inline real_t fw_wrap_2pi(real_t x)
{
    real_t y = x - FW_M_2PI * fw_floor(x / FW_M_2PI);
    return (y >= FW_M_2PI) ? FW_REAL(0.0) : y;
}

static inline fw_cplx_t fw_c(real_t re, real_t im)
{
    fw_cplx_t z;
    z.re = re;
    z.im = im;
    return z;
}
static inline fw_cplx_t fw_cadd(fw_cplx_t a, fw_cplx_t b) { return fw_c(a.re + b.re, a.im + b.im); }
static inline fw_cplx_t fw_csub(fw_cplx_t a, fw_cplx_t b) { return fw_c(a.re - b.re, a.im - b.im); }
static inline fw_cplx_t fw_cscale(fw_cplx_t a, real_t k) { return fw_c(a.re * k, a.im * k); }
static inline fw_cplx_t fw_cmul(fw_cplx_t a, fw_cplx_t b)
{
    return fw_c(a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re);
}
static inline fw_cplx_t fw_cconj(fw_cplx_t a) { return fw_c(a.re, -a.im); }
static inline real_t fw_cabs2(fw_cplx_t a) { return a.re * a.re + a.im * a.im; }
static inline real_t fw_cabs(fw_cplx_t a) { return fw_sqrt(fw_cabs2(a)); }
static inline fw_cplx_t fw_cexpj(real_t angle)
{
    fw_cplx_t z;
    fw_sincos(angle, &z.im, &z.re);
    return z;
}

#endif /* FW_MATH_H */
