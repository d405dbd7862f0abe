/* The core's own math (fw_math.h, fw_trig.c) against the C library in double precision:
 * fw_floor equals floorf bit for bit (every 61st float and the special values), fw_sincos
 * and fw_atan2 are within 3 units in the last place of the exact value (|x| < 6400 rad),
 * fw_cexpj(-x) is the conjugate of fw_cexpj(x) bit for bit (x not zero). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "fw_math.h"

static int failures = 0;

static void check(int ok, const char *what, double a, double b)
{
    if (!ok && failures++ < 10) {
        printf("FAIL %s: %.9g %.9g\n", what, a, b);
    }
}

static int same_bits(float a, float b) { return memcmp(&a, &b, sizeof(a)) == 0; }

/* error in units of the last place of the float nearest the exact value */
static double ulps(float got, double exact)
{
    float e = (float)exact;
    double ulp = (double)nextafterf(fabsf(e), INFINITY) - (double)fabsf(e);
    return fabs((double)got - exact) / ulp;
}

int main(void)
{
    uint32_t u = 0;
    uint64_t n = 0;
    double worst_sin = 0.0, worst_cos = 0.0, worst_atan2 = 0.0;
    const float special[] = {0.0f, -0.0f, 0.5f, -0.5f, 1.0f, -1.0f, 8388607.5f, -8388607.5f,
                             8388608.0f, 1e30f, -1e30f, INFINITY, -INFINITY};
    size_t k;
    for (k = 0; k < sizeof(special) / sizeof(special[0]); k++) {
        check(same_bits(fw_floor(special[k]), floorf(special[k])), "floor", special[k], 0);
    }
    check(fw_floor(NAN) != fw_floor(NAN), "floor(NaN)", 0, 0);
    do {
        float x;
        memcpy(&x, &u, sizeof(x));
        if (x == x) {
            check(same_bits(fw_floor(x), floorf(x)), "floor", x, floorf(x));
        }
        u += 61u;
        n++;
    } while (u >= 61u);
    for (k = 0; k < 400000; k++) {
        /* a deterministic spread over +-6400 rad, denser near zero */
        const double t = (double)k / 400000.0;
        const float x = (float)((k % 2 ? -1.0 : 1.0) * 6400.0 * t * t * t);
        const float y = (float)(5.0 * sin(7.1 * (double)k)), xa = (float)(5.0 * cos(3.3 * (double)k));
        float s, c;
        fw_cplx_t z1 = fw_cexpj(x), z2 = fw_cexpj(-x);
        fw_sincos(x, &s, &c);
        if (fabs(sin((double)x)) > 1e-30) {
            worst_sin = fmax(worst_sin, ulps(s, sin((double)x)));
        }
        worst_cos = fmax(worst_cos, ulps(c, cos((double)x)));
        worst_atan2 = fmax(worst_atan2, ulps(fw_atan2(y, xa), atan2((double)y, (double)xa)));
        check(x == 0.0f || (same_bits(z1.re, z2.re) && same_bits(z1.im, -z2.im)), "cexpj(-x)", x, 0);
    }
    check(worst_sin <= 3.0, "sin ulps", worst_sin, 3.0);
    check(worst_cos <= 3.0, "cos ulps", worst_cos, 3.0);
    check(worst_atan2 <= 3.0, "atan2 ulps", worst_atan2, 3.0);
    check(fw_atan2(0.0f, -1.0f) == FW_M_PI && fw_atan2(1.0f, 0.0f) == FW_M_PI / 2.0f &&
              fw_atan2(0.0f, 0.0f) == 0.0f && fw_atan2(-1.0f, -1.0f) == -0.75f * FW_M_PI,
          "atan2 axes", 0, 0);
    printf("fw_math: floor on %llu floats, sin %.2f cos %.2f atan2 %.2f ulps at worst: %s\n",
           (unsigned long long)n, worst_sin, worst_cos, worst_atan2, failures ? "FAIL" : "ok");
    return failures ? 1 : 0;
}
