/* protection.c - sample-level over-current and DC-link checks. */
#include "fw_internal.h"

/* A code minus the mid-scale code, for any int32 input: the subtraction is done in real_t
 * (an int32 difference overflows for codes near INT32_MIN). Exact for every code of a
 * converter of up to 24 bits (the float mantissa). */
real_t fw_protection_adc_offset(int32_t code, int32_t adc_half)
{
    return (real_t)code - (real_t)adc_half;
}

int16_t fw_protection_codes_in_range(const fw_adc_t *adc, int32_t adc_half)
{
    /* offset binary of N bits: 0 .. 2^N - 1 = 2*adc_half - 1 (docs/interfaces.md) */
    const int32_t top = adc_half - 1 + adc_half;
    int16_t k;
    for (k = 0; k < adc->n_soc && k < FW_MAX_SOC; k++) {
        if (adc->ia[k] < 0 || adc->ia[k] > top || adc->ib[k] < 0 || adc->ib[k] > top) {
            return 0;
        }
    }
    return 1;
}

uint16_t fw_protection_samples(const fw_adc_t *adc, int32_t adc_half, real_t lsb, real_t oc_trip,
                            real_t *i_peak)
{
    int16_t k;
    real_t peak = FW_REAL(0.0);
    for (k = 0; k < adc->n_soc && k < FW_MAX_SOC; k++) {
        real_t ia = fw_protection_adc_offset(adc->ia[k], adc_half) * lsb;
        real_t ib = fw_protection_adc_offset(adc->ib[k], adc_half) * lsb;
        real_t ic = -ia - ib;
        peak = fw_max(peak, fw_max(fw_fabs(ia), fw_max(fw_fabs(ib), fw_fabs(ic))));
    }
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
