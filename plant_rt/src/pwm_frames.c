/* VIO_PWM as the plant takes it: decoding and the checks of a PWM command (docs/interfaces.md,
 * "Bad input"), and the names of the reasons a frame is refused. */
#include <string.h>

#include "hil_arrays.h"
#include "hil_vio.h"
#include "plant_vio.h"

const char *plant_reject_name(int reason)
{
    static const char *const NAMES[PLANT_REJ_COUNT] = {
        "none",         "unknown_id",    "bad_length",   "out_of_range", "stale_period",
        "future_period", "too_many_soc", "soc_outside", "malformed",
    };
    if (reason < 0 || reason >= PLANT_REJ_COUNT) {
        return "invalid";
    }
    return NAMES[reason];
}

int plant_pwm_validate(const plant_pwm_cmd_t *cmd, uint32_t expected_period)
{
    int k;
    for (k = 0; k < 3; ++k) {
        if (cmd->cmp_up[k] > PLANT_TBPRD || cmd->cmp_dn[k] > PLANT_TBPRD) {
            return PLANT_REJ_OUT_OF_RANGE;
        }
    }
    if (cmd->gate_enable > 1) {
        return PLANT_REJ_OUT_OF_RANGE;
    }
    if (cmd->n_soc > PLANT_MAX_SOC) {
        return PLANT_REJ_TOO_MANY_SOC;
    }
    for (k = 0; k < cmd->n_soc; ++k) {
        if (cmd->soc[k] >= PLANT_PERIOD_TICKS) {
            return PLANT_REJ_SOC_OUTSIDE;
        }
    }
    /* Period checks last: a frame that is broken and also stale counts as broken. The
     * difference is taken modulo 2^32 so that a wrapped counter stays ordered. */
    if (cmd->period != expected_period) {
        const int32_t ahead = (int32_t)(cmd->period - expected_period);
        return ahead < 0 ? PLANT_REJ_STALE_PERIOD : PLANT_REJ_FUTURE_PERIOD;
    }
    return PLANT_REJ_NONE;
}

int plant_decode_pwm(uint32_t can_id, int fd, const uint8_t *data, size_t len,
                     uint32_t expected_period, plant_pwm_cmd_t *out)
{
    struct hil_vio_vio_pwm_t m;
    int k;
    if (can_id != HIL_VIO_VIO_PWM_FRAME_ID) {
        return PLANT_REJ_UNKNOWN_ID;
    }
    if (!fd) {
        return PLANT_REJ_MALFORMED; /* VIO_PWM is a CAN FD frame; a classic one is not it */
    }
    if (len != HIL_VIO_VIO_PWM_LENGTH) {
        return PLANT_REJ_BAD_LENGTH;
    }
    if (hil_vio_vio_pwm_unpack(&m, data, len) != 0) {
        return PLANT_REJ_MALFORMED;
    }
    /* Bits 137..143 (after gate_enable) are unused: set ones mean a foreign layout. */
    if (data[17] & 0xFEu) {
        return PLANT_REJ_MALFORMED;
    }
    memset(out, 0, sizeof(*out));
    out->period = m.period;
    out->cmp_up[0] = m.cmp_a_up;
    out->cmp_dn[0] = m.cmp_a_dn;
    out->cmp_up[1] = m.cmp_b_up;
    out->cmp_dn[1] = m.cmp_b_dn;
    out->cmp_up[2] = m.cmp_c_up;
    out->cmp_dn[2] = m.cmp_c_dn;
    out->n_soc = m.n_soc;
    out->gate_enable = m.gate_enable;
    for (k = 0; k < HIL_VIO_VIO_PWM_SOC_COUNT; k++) {
        out->soc[k] = hil_vio_vio_pwm_soc_get(&m, k);
    }
    return plant_pwm_validate(out, expected_period);
}
