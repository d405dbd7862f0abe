/* codec_util.h - saturating encoding for the frames fw_host sends. */
#ifndef CODEC_UTIL_H
#define CODEC_UTIL_H

#include <math.h>

/* Raw value of `value` for the signal whose generated functions start with `prefix`: the
 * value saturated into what the raw type [TMIN, TMAX] represents, rounded to nearest by the
 * generated encoder (cantools --use-round), then saturated into the DBC range (bisection
 * towards raw 0, which every signal used with it accepts). A non-finite value encodes as 0.
 * The DBC stays the only place scale and range are written. */
#define FWH_SAT_ENCODE(out, prefix, value, TMIN, TMAX)                                       \
    do {                                                                                    \
        double v_ = (double)(value);                                                        \
        const double lo_ = prefix##_decode(TMIN), hi_ = prefix##_decode(TMAX);              \
        long long r_;                                                                       \
        if (!isfinite(v_)) {                                                                \
            v_ = 0.0;                                                                       \
        }                                                                                   \
        v_ = v_ < lo_ ? lo_ : v_ > hi_ ? hi_ : v_;                                          \
        r_ = (long long)prefix##_encode(v_);                                                \
        if (!prefix##_is_in_range(r_)) {                                                    \
            long long ok_ = 0, bad_ = r_;                                                   \
            while (bad_ - ok_ > 1 || ok_ - bad_ > 1) {                                      \
                const long long m_ = ok_ + (bad_ - ok_) / 2;                                \
                if (prefix##_is_in_range(m_)) {                                             \
                    ok_ = m_;                                                               \
                } else {                                                                    \
                    bad_ = m_;                                                              \
                }                                                                           \
            }                                                                               \
            r_ = ok_;                                                                       \
        }                                                                                   \
        (out) = r_;                                                                         \
    } while (0)

#endif
