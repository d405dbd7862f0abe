/* position_tracker.c - type-2 PLL on the raw estimate (theta known modulo pi), branch
 * selection nearest the prediction (estimator-math.md section 7).
 *
 * The PLL state is the angle at a reference instant (the time stamp of the last measurement)
 * and the electrical speed; age_ticks is the time from that instant to the start of the period
 * being processed, so a prediction at any tick of the period is theta + omega * (age + tick).
 */
#include "fw_internal.h"

void fw_pll_config(fw_pll_t *pll, real_t bw_hz, real_t zeta)
{
    /* Discrete alpha-beta form of a type-2 loop with natural frequency wn and damping zeta:
     * theta += k1 * eps, omega += k2 * eps / Ts, k1 = 2 zeta wn Ts, k2 = (wn Ts)^2. */
    real_t wn_ts = FW_2PI_R * bw_hz * FW_TS;
    pll->k1 = fw_min(FW_REAL(2.0) * zeta * wn_ts, FW_REAL(1.0));
    pll->k2 = wn_ts * wn_ts;
}

void fw_pll_reset(fw_pll_t *pll, real_t theta, real_t omega, uint16_t stamp)
{
    pll->init = 1;
    pll->theta = fw_wrap_2pi(theta);
    pll->theta_unwrapped = theta;
    pll->omega = omega;
    pll->age_ticks = -(int32_t)stamp;
    pll->stamp = stamp;
    pll->last_err = FW_REAL(0.0);
}

void fw_pll_advance(fw_pll_t *pll, int32_t ticks)
{
    pll->age_ticks += ticks;
    /* re-anchor long predictions so the float angle does not lose resolution */
    if (pll->age_ticks > 4 * FW_P_TICKS) {
        real_t dt = (real_t)(pll->age_ticks - FW_P_TICKS) * FW_TICK_S;
        pll->theta = fw_wrap_2pi(pll->theta + pll->omega * dt);
        pll->theta_unwrapped += pll->omega * dt;
        pll->age_ticks = FW_P_TICKS;
    }
}

real_t fw_pll_predict(const fw_pll_t *pll, int32_t tick)
{
    real_t dt = (real_t)(pll->age_ticks + tick) * FW_TICK_S;
    return fw_wrap_2pi(pll->theta + pll->omega * dt);
}

real_t fw_pll_update(fw_pll_t *pll, real_t theta_raw, uint16_t stamp, real_t *theta_meas)
{
    real_t dt = (real_t)(pll->age_ticks + (int32_t)stamp) * FW_TICK_S;
    real_t pred = pll->theta + pll->omega * dt;
    /* eps = 1/2 wrap(2 (theta_raw - theta_pred)): the branch of theta_raw (mod pi) nearest
     * the prediction */
    real_t eps = FW_REAL(0.5) * fw_wrap_pi(FW_REAL(2.0) * (theta_raw - pred));
    *theta_meas = fw_wrap_2pi(pred + eps);
    pll->theta_unwrapped += pll->omega * dt + pll->k1 * eps;
    pll->theta = fw_wrap_2pi(pred + pll->k1 * eps);
    pll->omega += pll->k2 * eps / FW_TS;
    pll->age_ticks = -(int32_t)stamp;
    pll->stamp = stamp;
    pll->last_err = eps;
    return eps;
}

void fw_pll_flip(fw_pll_t *pll)
{
    pll->theta = fw_wrap_2pi(pll->theta + FW_PI_R);
    pll->theta_unwrapped += FW_PI_R;
}
