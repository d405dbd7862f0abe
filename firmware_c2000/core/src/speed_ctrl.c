/* speed_ctrl.c - speed reference ramp and speed PI at 1 kHz (output: q-current demand). */
#include "fw_internal.h"

real_t fw_speed_ctrl_ramp(real_t y, real_t target, real_t step)
{
    real_t d = target - y;
    if (d > step) {
        return y + step;
    }
    if (d < -step) {
        return y - step;
    }
    return target;
}

real_t fw_speed_ctrl(fw_pi_t *pi, real_t ref_rpm, real_t speed_rpm, real_t iq_lim, real_t ts)
{
    real_t e = ref_rpm - speed_rpm;
    real_t u = pi->kp * e + pi->x;
    real_t y = fw_clamp(u, -iq_lim, iq_lim);
    pi->x += pi->ki * ts * e + (y - u); /* back-calculation anti-windup */
    return y;
}
