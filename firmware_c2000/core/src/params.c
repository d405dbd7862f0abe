/* params.c - parameter access on top of the table generated from protocols/parameters.csv.
 *
 * Rules: every set is range-checked against the table; integral parameters must be whole
 * numbers; configuration parameters (id below FW_PARAM_CONFIG_ID_LIMIT) are BUSY while the
 * drive is enabled; cross-parameter constraints (Ld < Lq, Tmin >= sampling offsets + 1 us,
 * UV < OV, i_max and pulse currents below the over-current trip) are checked on the candidate
 * value. A rejected set changes nothing.
 */
#include "fw_internal.h"

#define FW_CORE_VERSION 1

/* parameters that count things or select modes */
static int16_t is_integral(int16_t idx)
{
    switch (idx) {
    case FW_IDX_POLE_PAIRS:
    case FW_IDX_ADC_BITS:
    case FW_IDX_ADC_VDC_BITS:
    case FW_IDX_SOC_PER_STATE:
    case FW_IDX_STRETCH_ENABLE:
    case FW_IDX_POL_METHOD:
    case FW_IDX_POL_SETTLE_PERIODS:
    case FW_IDX_POL_PULSE_PERIODS:
    case FW_IDX_POL_BIAS_PERIODS:
    case FW_IDX_LAMBDA_MODE:
    case FW_IDX_ADC_LOSS_MAX:
    case FW_IDX_EST_FAIL_MAX:
    case FW_IDX_POL_LOSS_FLIPS_MAX:
        return 1;
    default:
        return 0;
    }
}

int16_t fw_param_index(uint16_t id)
{
    int16_t lo = 0;
    int16_t hi = (int16_t)(FW_PARAM_COUNT - 1);
    while (lo <= hi) { /* bisection: at most 7 steps for 128 entries */
        int16_t mid = (int16_t)((lo + hi) / 2);
        uint16_t mid_id = fw_param_table[mid].id;
        if (mid_id == id) {
            return mid;
        }
        if (mid_id < id) {
            lo = (int16_t)(mid + 1);
        } else {
            hi = (int16_t)(mid - 1);
        }
    }
    return -1;
}

uint16_t fw_param_count(void) { return (uint16_t)FW_PARAM_COUNT; }

const fw_param_info_t *fw_param_info_at(uint16_t index)
{
    return (index < (uint16_t)FW_PARAM_COUNT) ? &fw_param_table[index] : 0;
}

const fw_param_info_t *fw_param_info(uint16_t id)
{
    int16_t idx = fw_param_index(id);
    return (idx < 0) ? 0 : &fw_param_table[idx];
}

void fw_params_defaults(fw_core_t *c)
{
    int16_t i;
    for (i = 0; i < FW_PARAM_COUNT; i++) {
        c->p[i] = fw_param_table[i].def;
    }
}

static uint16_t us_to_ticks(real_t us) { return (uint16_t)(us * FW_REAL(100.0) + FW_REAL(0.5)); }

void fw_params_apply(fw_core_t *c)
{
    const real_t *p = c->p;
    int16_t bits = (int16_t)p[FW_IDX_ADC_BITS];
    real_t full = (real_t)((int32_t)1 << bits);
    c->adc_half = (int32_t)1 << (bits - 1);
    c->adc_i_lsb = FW_REAL(2.0) * p[FW_IDX_ADC_RANGE_A] / full;
    c->adc_v_lsb = p[FW_IDX_ADC_VDC_RANGE_V] / (real_t)((int32_t)1 << (int16_t)p[FW_IDX_ADC_VDC_BITS]);
    c->pwm_cfg.tmin = us_to_ticks(p[FW_IDX_TMIN_US]);
    c->pwm_cfg.soc_on = us_to_ticks(p[FW_IDX_SOC_ON_US]);
    c->pwm_cfg.soc_off = us_to_ticks(p[FW_IDX_SOC_OFF_US]);
    c->pwm_cfg.n_per_state = (int16_t)p[FW_IDX_SOC_PER_STATE];
    c->pwm_cfg.stretch = (int16_t)p[FW_IDX_STRETCH_ENABLE];
    c->pwm_cfg.sector_hyst = us_to_ticks(p[FW_IDX_SECTOR_HYST_US]);
    c->pwm_cfg.pairs = (int16_t)p[FW_IDX_PATTERN_PAIRS];
    c->cmd_timeout_ticks = (uint32_t)(p[FW_IDX_CMD_TIMEOUT_MS] * FW_REAL(10.0) + FW_REAL(0.5));
    fw_tracker_config(&c->trk, p[FW_IDX_PLL_BW_HZ], p[FW_IDX_PLL_ZETA]);
    fw_tracker_config_schedule(&c->trk, p[FW_IDX_PLL_LOW_BW_HZ], p[FW_IDX_PLL_SPEED_RATIO],
                               p[FW_IDX_PLL_BOOST_SIGMA], p[FW_IDX_PLL_NOISE_REF_DEG]);
    c->speed_alpha = fw_min(FW_M_2PI * p[FW_IDX_SPD_FILTER_HZ] * FW_TS, FW_REAL(1.0));
    c->pi_d.kp = p[FW_IDX_CUR_KP_D];
    c->pi_d.ki = p[FW_IDX_CUR_KI_D];
    c->pi_q.kp = p[FW_IDX_CUR_KP_Q];
    c->pi_q.ki = p[FW_IDX_CUR_KI_Q];
    c->pi_spd.kp = p[FW_IDX_SPD_KP];
    c->pi_spd.ki = p[FW_IDX_SPD_KI];
}

/* cross-parameter constraints on a candidate value array */
static int16_t consistent(const real_t *p)
{
    if (!(p[FW_IDX_LD_H] < p[FW_IDX_LQ_H])) {
        return 0;
    }
    if (p[FW_IDX_TMIN_US] < p[FW_IDX_SOC_ON_US] + p[FW_IDX_SOC_OFF_US] + FW_REAL(1.0)) {
        return 0;
    }
    if (!(p[FW_IDX_UV_TRIP_V] < p[FW_IDX_OV_TRIP_V])) {
        return 0;
    }
    if (!(p[FW_IDX_I_MAX_A] < p[FW_IDX_OC_TRIP_A]) || !(p[FW_IDX_POL_PULSE_A] < p[FW_IDX_OC_TRIP_A]) ||
        !(p[FW_IDX_POL_MOTION_IQ_A] < p[FW_IDX_OC_TRIP_A])) {
        return 0;
    }
    return 1;
}

static real_t live_value(const fw_core_t *c, uint16_t id, real_t stored)
{
    switch (id) {
    case FW_PID_FW_VERSION:
        return (real_t)FW_CORE_VERSION;
    case FW_PID_LD_HAT_H:
        return c->pe.ld_inc;
    case FW_PID_LQ_HAT_H:
        return c->pe.lq_inc;
    case FW_PID_LAMBDA_HAT_WB:
        return c->flux.lambda_f;
    case FW_PID_LQ_APP_H:
        return c->pe.lq_app;
    case FW_PID_LD_APP_H:
        return c->pe.ld_app;
    case FW_PID_POLARITY_FLIPS:
        return (real_t)c->polarity_flips;
    case FW_PID_ADC_LOSS_COUNT:
        return (real_t)c->adc_loss_count;
    case FW_PID_EST_REJECT_COUNT:
        return (real_t)c->est_reject_count;
    case FW_PID_XSAT_TURN_DEG:
        /* (the turn is derived here, where it is read, not in every ISR that learns it) */
        return FW_REAL(0.5) * fw_atan2(c->pe.xs_g.im, c->pe.xs_g.re) *
               (FW_REAL(180.0) / FW_M_PI);
    default:
        return stored;
    }
}

int16_t fw_param_get(const fw_core_t *c, uint16_t id, real_t *value)
{
    int16_t idx;
    if (c == 0 || value == 0) {
        return FW_STATUS_BAD_ARG;
    }
    idx = fw_param_index(id);
    if (idx < 0) {
        return FW_STATUS_UNKNOWN_ID;
    }
    *value = fw_param_table[idx].read_only ? live_value(c, id, c->p[idx]) : c->p[idx];
    return FW_STATUS_OK;
}

int16_t fw_param_set(fw_core_t *c, uint16_t id, real_t value)
{
    int16_t idx;
    const fw_param_info_t *info;
    real_t saved;
    if (c == 0) {
        return FW_STATUS_BAD_ARG;
    }
    idx = fw_param_index(id);
    if (idx < 0) {
        return FW_STATUS_UNKNOWN_ID;
    }
    info = &fw_param_table[idx];
    if (info->read_only) {
        return FW_STATUS_READ_ONLY;
    }
    if (!fw_is_finite(value) || value < info->min || value > info->max) {
        return FW_STATUS_OUT_OF_RANGE;
    }
    if (is_integral(idx) && value != fw_floor(value)) {
        return FW_STATUS_OUT_OF_RANGE;
    }
    if (id < (uint16_t)FW_PARAM_CONFIG_ID_LIMIT &&
        (c->state == FW_STATE_POLARITY || c->state == FW_STATE_RUN)) {
        return FW_STATUS_BUSY;
    }
    saved = c->p[idx];
    c->p[idx] = value;
    if (!consistent(c->p)) {
        c->p[idx] = saved;
        return FW_STATUS_OUT_OF_RANGE;
    }
    fw_params_apply(c);
    return FW_STATUS_OK;
}
