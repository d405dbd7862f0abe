/* current_ctrl.c - dq current PI at 10 kHz with decoupling, voltage-vector limit and
 * back-calculation anti-windup. */
#include "fw_internal.h"

void fw_current_ctrl(fw_pi_t *pid, fw_pi_t *piq, real_t id_ref, real_t iq_ref, real_t id,
                     real_t iq, real_t omega, real_t ld, real_t lq, real_t lambda, real_t rs,
                     real_t v_lim, real_t ts, real_t *vd, real_t *vq)
{
    real_t ed = id_ref - id;
    real_t eq = iq_ref - iq;
    /* steady-state model (eq. 52) as feed-forward on the references: the PI only corrects */
    real_t ffd = rs * id_ref - omega * lq * iq_ref;
    real_t ffq = rs * iq_ref + omega * (ld * id_ref + lambda);
    real_t ud = pid->kp * ed + pid->x + ffd;
    real_t uq = piq->kp * eq + piq->x + ffq;
    real_t yd, yq, q_room;

    /* d first (flux weakening keeps its voltage), q gets what is left of the circle */
    yd = fw_clamp(ud, -v_lim, v_lim);
    q_room = fw_sqrt(fw_max(v_lim * v_lim - yd * yd, FW_REAL(0.0)));
    yq = fw_clamp(uq, -q_room, q_room);
    /* integrate, then pull the integrator back by the amount the output was limited */
    pid->x += pid->ki * ts * ed + (yd - ud);
    piq->x += piq->ki * ts * eq + (yq - uq);
    *vd = yd;
    *vq = yq;
}
