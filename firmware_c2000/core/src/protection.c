/* protection.c - sample-level over-current and DC-link checks. */
#include "fw_internal.h"

uint16_t fw_protect_samples(const fw_adc_t *adc, int32_t adc_half, real_t lsb, real_t oc_trip,
                            real_t *i_peak)
{
    int16_t k;
    real_t peak = FW_REAL(0.0);
    for (k = 0; k < adc->n_soc && k < FW_MAX_SOC; k++) {
        real_t ia = (real_t)(adc->ia[k] - adc_half) * lsb;
        real_t ib = (real_t)(adc->ib[k] - adc_half) * lsb;
        real_t ic = -ia - ib;
        peak = fw_max(peak, fw_max(fw_fabs(ia), fw_max(fw_fabs(ib), fw_fabs(ic))));
    }
    *i_peak = peak;
    return (uint16_t)((peak > oc_trip) ? FW_FAULT_OVERCURRENT : FW_FAULT_NONE);
}

uint16_t fw_protect_vdc(real_t vdc, real_t ov, real_t uv, int16_t check_uv)
{
    if (!(vdc <= ov)) { /* also catches NaN */
        return FW_FAULT_DC_OVERVOLTAGE;
    }
    if (check_uv && vdc < uv) {
        return FW_FAULT_DC_UNDERVOLTAGE;
    }
    return FW_FAULT_NONE;
}
