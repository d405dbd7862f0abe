/* protection.c - sample-level over-current and DC-link checks. */
#include "fw_internal.h"

/* the integer path of fw_protection_samples: converters of up to 20 bits (below) */
#define FW_PROT_INT_HALF_MAX ((int32_t)1 << 19)

static int16_t n_samples(const fw_adc_t *adc)
{
    return (adc->n_soc < FW_MAX_SOC) ? adc->n_soc : (int16_t)FW_MAX_SOC;
}

int16_t fw_protection_codes_in_range(const fw_adc_t *adc, int32_t adc_half)
{
    /* offset binary of N bits: 0 .. 2^N - 1 = 2*adc_half - 1 (docs/interfaces.md) */
    const int32_t top = adc_half - 1 + adc_half;
    const int16_t n = n_samples(adc);
    int16_t k;
    if (adc_half > 0 && (adc_half & (adc_half - 1)) == 0) {
        /* 2^N - 1 is a mask: a code is in range when no bit above it is set (a negative
         * code has the sign bit); one OR per code instead of two comparisons */
        uint32_t bits = 0u;
        for (k = 0; k < n; k++) {
            bits |= (uint32_t)adc->ia[k] | (uint32_t)adc->ib[k];
        }
        return (int16_t)((bits & ~(uint32_t)top) == 0u);
    }
    for (k = 0; k < n; k++) {
        if (adc->ia[k] < 0 || adc->ia[k] > top || adc->ib[k] < 0 || adc->ib[k] > top) {
            return 0;
        }
    }
    return 1;
}

/* A converter that returns one code in every sample of a switching period is stuck: the
 * phase currents slew by hundreds of codes inside each measured active window (the slopes the
 * estimator fits), and noise alone moves them by a few. Bit 0: ia, bit 1: ib. */
int16_t fw_protection_codes_frozen(const fw_adc_t *adc)
{
    const int16_t n = n_samples(adc);
    int32_t moved_a = 0, moved_b = 0;
    int16_t k;
    if (n < 2) {
        return 0;
    }
    for (k = 1; k < n; k++) {
        moved_a |= adc->ia[k] ^ adc->ia[0];
        moved_b |= adc->ib[k] ^ adc->ib[0];
    }
    return (int16_t)((moved_a == 0 ? 1 : 0) | (moved_b == 0 ? 2 : 0));
}

/* the largest phase-current magnitude of the samples in real_t, sample by sample */
static real_t peak_of_samples(const fw_adc_t *adc, int32_t adc_half, real_t lsb)
{
    const int16_t n = n_samples(adc);
    int16_t k;
    real_t peak = FW_REAL(0.0);
    for (k = 0; k < n; k++) {
        real_t ia = fw_protection_adc_offset(adc->ia[k], adc_half) * lsb;
        real_t ib = fw_protection_adc_offset(adc->ib[k], adc_half) * lsb;
        real_t ic = -ia - ib;
        peak = fw_max(peak, fw_max(fw_fabs(ia), fw_max(fw_fabs(ib), fw_fabs(ic))));
    }
    return peak;
}

/* 1 when x * lsb is exact in real_t for every integer |x| <= 2 adc_half, i.e. lsb has at most
 * 24 - log2(4 adc_half) significant bits (the default 10 A over 16 bits: 5 * 2^-14, 3 bits):
 * Veltkamp's split of lsb at that width leaves no remainder. */
static int16_t lsb_products_exact(int32_t adc_half, real_t lsb)
{
    const real_t split = (real_t)(4 * adc_half) + FW_REAL(1.0);
    real_t c, hi;
    if (!(adc_half > 0 && adc_half <= FW_PROT_INT_HALF_MAX && lsb > FW_REAL(0.0) &&
          lsb < FW_REAL(1.0e30))) {
        return 0;
    }
    c = split * lsb;
    hi = c - (c - lsb);
    return (int16_t)(hi == lsb);
}

/* With exact products every phase current is its code offset times lsb, and so is the
 * largest: the extremes of the integer codes (ia, ib and ia + ib, whose mid-scale is 2
 * adc_half) give the same value as the sample-by-sample path in about half the
 * instructions, and the range check for free. All zero (the sign of the zero), wider
 * converters, codes out of range and other lsb take the sample-by-sample path. */
uint16_t fw_protection_samples(const fw_adc_t *adc, int32_t adc_half, real_t lsb, real_t oc_trip,
                               real_t *i_peak)
{
    const int16_t n = n_samples(adc);
    real_t peak;
    if (n > 0 && lsb_products_exact(adc_half, lsb)) {
        int32_t lo = adc->ia[0], hi = lo;
        uint32_t lo_s = (uint32_t)adc->ia[0] + (uint32_t)adc->ib[0], hi_s = lo_s;
        int16_t k;
        for (k = 0; k < n; k++) {
            int32_t a = adc->ia[k], b = adc->ib[k];
            uint32_t s = (uint32_t)a + (uint32_t)b; /* meaningful only in range (below) */
            lo = (a < lo) ? a : lo;
            hi = (a > hi) ? a : hi;
            lo = (b < lo) ? b : lo;
            hi = (b > hi) ? b : hi;
            lo_s = (s < lo_s) ? s : lo_s;
            hi_s = (s > hi_s) ? s : hi_s;
        }
        if (lo >= 0 && hi <= adc_half - 1 + adc_half) {
            int32_t m = (hi - adc_half > adc_half - lo) ? hi - adc_half : adc_half - lo;
            int32_t two = 2 * adc_half;
            int32_t ms = ((int32_t)hi_s - two > two - (int32_t)lo_s) ? (int32_t)hi_s - two
                                                                    : two - (int32_t)lo_s;
            m = (ms > m) ? ms : m;
            if (m > 0) {
                *i_peak = (real_t)m * lsb;
                return (uint16_t)((*i_peak > oc_trip) ? FW_FAULT_OVERCURRENT : FW_FAULT_NONE);
            }
        }
    }
    peak = peak_of_samples(adc, adc_half, lsb);
    *i_peak = peak;
    return (uint16_t)((peak > oc_trip) ? FW_FAULT_OVERCURRENT : FW_FAULT_NONE);
}

uint16_t fw_protection_vdc(real_t vdc, real_t ov, real_t uv, int16_t check_uv)
{
    if (!(vdc <= ov)) { /* also catches NaN */
        return FW_FAULT_DC_OVERVOLTAGE;
    }
    if (check_uv && vdc < uv) {
        return FW_FAULT_DC_UNDERVOLTAGE;
    }
    return FW_FAULT_NONE;
}
