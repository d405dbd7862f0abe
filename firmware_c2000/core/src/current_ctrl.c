/* current_ctrl.c - dq current PI at 10 kHz with decoupling, voltage-vector limit and
 * anti-windup by holding each integral where it alone reaches the limit. */
#include "fw_internal.h"

void fw_current_ctrl(fw_pi_t *pid, fw_pi_t *piq, real_t id_ref, real_t iq_ref, real_t id,
                     real_t iq, real_t omega, real_t ld, real_t lq, real_t lambda, real_t rs,
                     real_t v_lim, real_t ts, real_t *vd, real_t *vq, real_t *u_mag)
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
    /* the demand before the limit: flux weakening's voltage feedback must see how far the
     * loop wants beyond the limit, which the limited output never shows */
    *u_mag = fw_sqrt(ud * ud + uq * uq);
    yd = fw_clamp(ud, -v_lim, v_lim);
    q_room = fw_sqrt(fw_max(v_lim * v_lim - yd * yd, FW_REAL(0.0)));
    yq = fw_clamp(uq, -q_room, q_room);
    /* integrate, the integral held where it alone (with the feed-forward) would reach the
     * limit: pulling it back by the whole excess of the output (back-calculation) also took
     * out the proportional part, and each 1 kHz reference step at the voltage limit left
     * the q integrator tens of volts low for ~10 ms (measured at 2400 r/min in FULL
     * modulation: iq 1 A short of its reference with the output below its limit) */
    pid->x = fw_clamp(pid->x + pid->ki * ts * ed, -v_lim - ffd, v_lim - ffd);
    piq->x = fw_clamp(piq->x + piq->ki * ts * eq, -q_room - ffq, q_room - ffq);
    *vd = yd;
    *vq = yq;
}
