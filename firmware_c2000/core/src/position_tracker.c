/* position_tracker.c - the rotor-position tracker: a mechanical observer on the raw estimate
 * (theta known modulo pi, branch nearest the prediction), with the torque model as input.
 *
 * States: electrical angle theta and speed omega at a reference instant (the time stamp of the
 * last measurement) and a disturbance acceleration a_d (load, friction, torque-model error).
 * Between measurements the rotor is predicted with the known acceleration a_ff (the core's
 * torque model * pole pairs / J) plus a_d, so a commanded torque change moves the estimate
 * at once instead of showing up as a tracking error. Each measurement error eps corrects
 *
 *     theta += L1 Ts eps,  omega += L2 Ts eps,  a_d += L3 Ts eps,
 *
 * the discrete form of an observer whose error polynomial is (s^2 + 2 zeta wn s + wn^2)(s + p)
 * with the disturbance pole p (below): L1 = 2 zeta wn + p, L2 = wn^2 + 2 zeta wn p,
 * L3 = wn^2 p. A constant speed and a constant load are tracked without steady-state error.
 *
 * The bandwidth wn is what trades noise against agility. The raw per-period estimate is
 * noise-limited (sigma ~1.7 deg on the paper profile at standstill): its share in theta_hat
 * scales with sqrt(wn Ts), in omega_hat with wn^1.5 (simulated with that noise: 1 ms means of
 * the speed estimate scatter by 0.0062 r/min rms at 0.5 Hz, 0.134 at 4 Hz, 6.9 at 60 Hz).
 * Three terms, the largest wins:
 *   - low_bw_hz: the floor, where the rotor barely moves (1 r/min: 0.012 deg per period). It
 *     is meant for a raw estimate whose noise is at most noise_ref; a noisier one lowers it
 *     by the cube root of the ratio (down to FW_TRK_FLOOR_MIN of it), as the steady-state
 *     gain of a Kalman filter on position, speed and load would (its bandwidth goes as
 *     (process noise / measurement noise)^(1/6) in variance). The noise is measured from
 *     successive innovations, var(eps_k - eps_k-1) / 2, which a slow tracking error (a load
 *     the loop is still taking up) hardly enters, so a disturbance does not narrow the loop.
 *     On harsh at 2 N*m the raw angle scatters by ~19 deg (paper: 1.6 deg at 1 N*m, 2.9
 *     at 2 N*m), and there a 2 Hz loop handed the speed loop +-2 r/min of estimate noise;
 *   - speed_ratio * |omega|: at speed the raw estimate carries errors that repeat with the
 *     electrical angle and the flux estimator takes over; tracking a fraction of the electrical
 *     frequency keeps those out (and ramps are tracked through a_ff, not the bandwidth);
 *   - convergence: after a reset or a detected disturbance the loop starts at bw_hz and comes
 *     down as bw_hz / (1 + t wn_hi / 4): the shape of a least-squares (Kalman) gain, which may
 *     only shrink as fast as the data it has averaged allow. A disturbance the present loop is
 *     too slow for (a load step: 2 N*m is 8000 rad/s^2 electrical) shows as a mean of eps beyond
 *     boost_sigma times its RMS and restarts the convergence; nothing switches abruptly.
 *
 * age_ticks is the time from the reference instant to the start of the period being
 * processed, so a prediction at any tick of the period is theta + omega dt + a dt^2 / 2 with
 * dt = (age + tick) * 10 ns.
 */
#include "fw_internal.h"

#define FW_TRK_EMEAN_TAU_S 0.005f  /* innovation mean for the disturbance detector */
#define FW_TRK_EVAR_TAU_S 0.5f     /* innovation mean square */
#define FW_TRK_NOISE_FLOOR 0.0035f /* rad (0.2 deg): a smaller mean never counts */
/* disturbance pole: wn / 2 (the bandwidth may then come down as fast as wn = 10 / t, see
 * above; with wn / 4 the error of a 2 rad/s start decayed only as 1 / t), but at most wn_hi / 4:
 * the flux estimator's angle carries a filter lag, and wn_hi / 2 made the loop ring at 40 Hz,
 * +-8 deg, at 2000 r/min */
#define FW_TRK_P_FACTOR 0.5f
#define FW_TRK_P_MAX_FACTOR 0.25f
#define FW_TRK_CONV_CYCLES 10.0f   /* convergence: wn = wn_hi / (1 + t wn_hi / this) */
#define FW_TRK_CONV_MAX 100000000L /* periods: the counter saturates (2.8 h) */
#define FW_TRK_FLOOR_MIN 0.4f      /* the noise may lower the floor to this share (2 Hz: 0.8 Hz) */

static void set_gains(fw_tracker_t *pll, real_t wn)
{
    real_t z = pll->zeta;
    real_t p = fw_min(FW_TRK_P_FACTOR * wn, FW_TRK_P_MAX_FACTOR * pll->wn_hi);
    pll->wn = wn;
    pll->l1 = fw_min((FW_REAL(2.0) * z * wn + p) * FW_TS, FW_REAL(1.0));
    pll->l2 = (wn * wn + FW_REAL(2.0) * z * wn * p) * FW_TS;
    pll->l3 = wn * wn * p * FW_TS;
}

void fw_tracker_config(fw_tracker_t *pll, real_t bw_hz, real_t zeta)
{
    pll->zeta = zeta;
    pll->wn_hi = FW_M_2PI * bw_hz;
    pll->wn_lo = pll->wn_hi;
    pll->speed_ratio = FW_REAL(0.0);
    pll->boost_sigma = FW_REAL(0.0);
    pll->noise_ref2 = FW_REAL(0.0);
    pll->n_var = FW_REAL(0.0);
    pll->floor_scale = FW_REAL(1.0);
    set_gains(pll, pll->wn_hi);
}

void fw_tracker_config_schedule(fw_tracker_t *pll, real_t low_bw_hz, real_t speed_ratio,
                            real_t boost_sigma, real_t noise_ref_deg)
{
    real_t ref = noise_ref_deg * (FW_M_PI / FW_REAL(180.0));
    pll->wn_lo = fw_min(FW_M_2PI * low_bw_hz, pll->wn_hi);
    pll->speed_ratio = speed_ratio;
    pll->boost_sigma = boost_sigma;
    pll->noise_ref2 = ref * ref;
}

real_t fw_tracker_schedule(fw_tracker_t *pll)
{
    real_t w_speed = fw_clamp(pll->speed_ratio * fw_fabs(pll->omega),
                              pll->wn_lo * pll->floor_scale, pll->wn_hi);
    real_t w_conv = pll->wn_hi / (FW_REAL(1.0) + (real_t)pll->conv_ticks * FW_TS * pll->wn_hi /
                                                     FW_TRK_CONV_CYCLES);
    if (pll->conv_ticks < FW_TRK_CONV_MAX) {
        pll->conv_ticks++;
    }
    set_gains(pll, fw_max(w_speed, w_conv));
    return pll->wn;
}

void fw_tracker_reset(fw_tracker_t *pll, real_t theta, real_t omega, uint16_t stamp)
{
    pll->init = 1;
    pll->theta = fw_wrap_2pi(theta);
    pll->theta_unwrapped = theta;
    pll->omega = omega;
    pll->a_ff = FW_REAL(0.0);
    pll->a_d = FW_REAL(0.0);
    pll->a_d_lo = FW_REAL(0.0);
    pll->age_ticks = -(int32_t)stamp;
    pll->stamp = stamp;
    pll->last_err = FW_REAL(0.0);
    pll->e_mean = FW_REAL(0.0);
    pll->e_var = FW_REAL(0.0);
    pll->n_var = FW_REAL(0.0);
    pll->floor_scale = FW_REAL(1.0);
    /* start agile: the first estimates converge at bw_hz whatever the speed */
    pll->conv_ticks = 0;
    set_gains(pll, pll->wn_hi);
}

void fw_tracker_set_accel(fw_tracker_t *pll, real_t a_ff) { pll->a_ff = a_ff; }

/* the angle and speed advance from the reference instant by dt (s) */
static void advance_by(const fw_tracker_t *pll, real_t dt, real_t *theta, real_t *omega)
{
    real_t a = pll->a_ff + pll->a_d;
    *theta = pll->theta + (pll->omega + FW_REAL(0.5) * a * dt) * dt;
    *omega = pll->omega + a * dt;
}

void fw_tracker_advance(fw_tracker_t *pll, int32_t ticks)
{
    pll->age_ticks += ticks;
    /* re-anchor long predictions so the float angle does not lose resolution */
    if (pll->age_ticks > 4 * FW_P_TICKS) {
        real_t dt = (real_t)(pll->age_ticks - FW_P_TICKS) * FW_TICK_S;
        real_t th, om;
        advance_by(pll, dt, &th, &om);
        pll->theta_unwrapped += th - pll->theta;
        pll->theta = fw_wrap_2pi(th);
        pll->omega = om;
        pll->age_ticks = FW_P_TICKS;
    }
}

real_t fw_tracker_predict(const fw_tracker_t *pll, int32_t tick)
{
    real_t dt = (real_t)(pll->age_ticks + tick) * FW_TICK_S;
    real_t th, om;
    advance_by(pll, dt, &th, &om);
    return fw_wrap_2pi(th);
}

/* The floor's share at the raw estimate's present noise (see the top): de is this innovation
 * less the last one. The cube root follows its target by one Newton step per period (the
 * noise estimate moves by a 5000th per period; the step is exact where the target is 1, so
 * a raw estimate within noise_ref leaves the tracker as it was without this rule). */
static void floor_for_noise(fw_tracker_t *pll, real_t de)
{
    real_t target = FW_REAL(1.0), y = pll->floor_scale;
    pll->n_var += (FW_TS / FW_TRK_EVAR_TAU_S) * (FW_REAL(0.5) * de * de - pll->n_var);
    if (!(pll->noise_ref2 > FW_REAL(0.0))) {
        return;
    }
    if (pll->n_var > pll->noise_ref2) {
        target = fw_sqrt(pll->noise_ref2 / pll->n_var);
    } else if (y == FW_REAL(1.0)) {
        return; /* at its target: the Newton step would leave 1 exactly */
    }
    y -= (y * y * y - target) / (FW_REAL(3.0) * y * y);
    pll->floor_scale = fw_clamp(y, FW_TRK_FLOOR_MIN, FW_REAL(1.0));
}

real_t fw_tracker_update(fw_tracker_t *pll, real_t theta_raw, uint16_t stamp, real_t *theta_meas)
{
    real_t dt = (real_t)(pll->age_ticks + (int32_t)stamp) * FW_TICK_S;
    real_t pred, om, eps, step, y, t;
    advance_by(pll, dt, &pred, &om);
    /* eps = 1/2 wrap(2 (theta_raw - theta_pred)): the branch of theta_raw (mod pi) nearest
     * the prediction */
    eps = FW_REAL(0.5) * fw_wrap_pi(FW_REAL(2.0) * (theta_raw - pred));
    *theta_meas = fw_wrap_2pi(pred + eps);
    pll->theta_unwrapped += (pred - pll->theta) + pll->l1 * eps;
    pll->theta = fw_wrap_2pi(pred + pll->l1 * eps);
    pll->omega = om + pll->l2 * eps;
    /* a_d takes tiny steps against a large value at low gains: compensated summation keeps
     * the float sum unbiased */
    step = pll->l3 * eps - pll->a_d_lo;
    y = pll->a_d + step;
    pll->a_d_lo = (y - pll->a_d) - step;
    pll->a_d = y;
    pll->age_ticks = -(int32_t)stamp;
    pll->stamp = stamp;
    floor_for_noise(pll, eps - pll->last_err);
    pll->last_err = eps;
    /* disturbance detector: the 20 ms mean of eps against the RMS of eps. White noise leaves
     * the mean at ~0.07 RMS; an error of the raw estimate that repeats with the angle has a
     * mean below its RMS unless it is the larger part; a disturbance the slow loop cannot
     * follow (a load ramp) grows the mean within ms. */
    pll->e_mean += (FW_TS / FW_TRK_EMEAN_TAU_S) * (eps - pll->e_mean);
    pll->e_var += (FW_TS / FW_TRK_EVAR_TAU_S) * (eps * eps - pll->e_var);
    if (pll->boost_sigma > FW_REAL(0.0) && pll->wn < pll->wn_hi) {
        t = pll->boost_sigma * fw_sqrt(pll->e_var);
        if (fw_fabs(pll->e_mean) > fw_max(t, FW_TRK_NOISE_FLOOR)) {
            if (pll->conv_ticks > 0) {
                pll->boosts++;
            }
            pll->conv_ticks = 0;
        }
    }
    return eps;
}

void fw_tracker_flip(fw_tracker_t *pll)
{
    pll->theta = fw_wrap_2pi(pll->theta + FW_M_PI);
    pll->theta_unwrapped += FW_M_PI;
    pll->e_mean = FW_REAL(0.0);
}
