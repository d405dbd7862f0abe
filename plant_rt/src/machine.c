/* Machine right-hand side and the conduction modes of the three legs.
 *
 * Electrical state: flux linkages in the rotor (dq) frame, amplitude-invariant Park:
 *     d psi_d/dt = v_d - rs*i_d + w_e*psi_q
 *     d psi_q/dt = v_q - rs*i_q - w_e*psi_d
 * with (i_d, i_q) from the inverse flux map. Phase x (axis angle 0, 2pi/3, 4pi/3) has
 * i_x = c_x . i_dq with c_x = (cos(theta - ax), -sin(theta - ax)), and the dq voltage of the
 * leg voltages u_x (to DC-) is v_dq = 2/3 * sum_x u_x c_x: the common mode of the legs
 * (and so the star-point voltage) drops out, as it does for an isolated neutral. This is
 * the paper's abc model (eqs. 1-7) with its zero sequence removed: Ll acts only there.
 *
 * Conduction modes: a leg whose current is non-zero has the terminal voltage of that
 * current's sign (inverter.c). A leg at zero current is "open" (mode ZERO) while the
 * voltage that keeps its current at zero stays inside the leg's band; that voltage is
 * solved from d i_x/dt = 0, which is linear in u_x with a positive coefficient
 * (2/3 c_x' Gamma c_x, Gamma = incremental inductance inverse). With two legs at zero the
 * third is at zero too (KCL at the star point): then the fluxes stay at their zero-current
 * value, the phase voltages equal the back-EMF, and the legs stay open while one common
 * star-point potential keeps every terminal inside its band (the diode bridge blocks).
 */
#include <math.h>

#include "plant_internal.h"

#define TWO_THIRDS (2.0 / 3.0)

/* Beyond this distance from the last libm angle, sin/cos come from libm again. Within it the
 * angle-addition series below is exact to double rounding: the first omitted terms are
 * d^11/11! < 1.2e-22 and d^12/12! < 5e-25 (relative to 1). At 3000 r/min the rotor turns
 * 0.063 rad (electrical) per period, so libm runs about once per period instead of at every
 * right-hand side. */
#define SINCOS_SERIES_MAX 0.05

static void sincos_near(plant_machine_t *m, double theta, double *s, double *c)
{
    const double d = theta - m->sc_base;
    if (m->sc_base_valid && fabs(d) <= SINCOS_SERIES_MAX) {
        const double d2 = d * d;
        /* sin d and cos d by their Taylor series (Horner) */
        const double sd =
            d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0) *
                 (1.0 - d2 * (1.0 / 72.0) * (1.0 - d2 * (1.0 / 110.0))))));
        const double cm1 =
            -d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0) *
                         (1.0 - d2 * (1.0 / 56.0) * (1.0 - d2 * (1.0 / 90.0)))));
        *s = m->sc_base_sin + (m->sc_base_sin * cm1 + m->sc_base_cos * sd);
        *c = m->sc_base_cos + (m->sc_base_cos * cm1 - m->sc_base_sin * sd);
        return;
    }
    *s = sin(theta);
    *c = cos(theta);
    m->sc_base = theta;
    m->sc_base_sin = *s;
    m->sc_base_cos = *c;
    m->sc_base_valid = 1;
}

static void rotor_sincos(plant_machine_t *m, double theta, double *s, double *c);

static void phase_axes(plant_machine_t *m, double theta, double cph[3][2], double *s_out,
                       double *c_out)
{
    double s, c;
    rotor_sincos(m, theta, &s, &c);
    const double h = 0.5, r = 0.5 * PLANT_SQRT3;
    /* cos/sin of theta - 2pi/3 and theta + 2pi/3 */
    const double cb = -h * c + r * s, sb = -h * s - r * c;
    const double cc = -h * c - r * s, sc = -h * s + r * c;
    cph[0][0] = c;
    cph[0][1] = -s;
    cph[1][0] = cb;
    cph[1][1] = -sb;
    cph[2][0] = cc;
    cph[2][1] = -sc;
    *s_out = s;
    *c_out = c;
}

/* Load-machine torque and shaft acceleration for motor torque te at speed w. */
static void mechanics(const plant_machine_t *m, double te, double w, double *tl, double *dw)
{
    switch (m->load_mode) {
    case HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE:
        /* The dynamometer holds the speed: it supplies whatever torque that takes. */
        *dw = 0.0;
        *tl = te - m->b_total * w;
        return;
    case HIL_BENCH_LOAD_CMD_MODE_TORQUE_CHOICE:
        *tl = m->load_torque + m->load_k * w;
        break;
    default:
        *tl = 0.0;
        break;
    }
    *dw = (te - *tl - m->b_total * w) / m->j_total;
}

/* The currents at flux x->psi: the last solution when the flux is the same (right-hand
 * sides at a gate edge, after a mode change, at the period start), else the inversion
 * from it. */
static void currents_from_flux(plant_machine_t *m, const plant_state_t *x, plant_deriv_t *d,
                               int stage)
{
    plant_mag_point_t *p = &m->mp;
    if (!(x->psi_d == p->psi[0] && x->psi_q == p->psi[1])) {
        int it = plant_mag_invert_from(m->mag, x->psi_d, x->psi_q, p, stage);
        if (it < 0) {
            m->stats->newton_failures++;
            it = -it;
        }
        m->stats->newton_iterations += (uint64_t)it;
    }
    d->id = p->i[0];
    d->iq = p->i[1];
    d->ldd = p->l[0];
    d->lqq = p->l[1];
    d->ldq = p->l[2];
    d->gdd = p->g[0];
    d->gqq = p->g[1];
    d->gdq = p->g[2];
}

/* The leg voltages of the conduction modes and gates in force (no leg at zero current), and
 * their alpha-beta components v_ab = 2/3 sum_x u_x (cos a_x, sin a_x): the dq voltage is
 * v_ab turned by -theta. They change only with a gate, a mode or the DC link, so they are
 * kept until one of those changes (an interval between gate edges has one set). */
static inline const double *legs_conducting(plant_machine_t *m)
{
    if (!(m->legs_valid && m->legs_gate[0] == m->gate[0] && m->legs_gate[1] == m->gate[1] &&
          m->legs_gate[2] == m->gate[2] && m->legs_mode[0] == m->mode[0] &&
          m->legs_mode[1] == m->mode[1] && m->legs_mode[2] == m->mode[2] &&
          m->legs_vdc == m->vdc && m->legs_vdrop == m->vdrop)) {
        int k;
        for (k = 0; k < 3; ++k) {
            m->legs_u[k] = plant_leg_voltage(m->gate[k], m->mode[k], m->vdc, m->vdrop);
            m->legs_gate[k] = m->gate[k];
            m->legs_mode[k] = m->mode[k];
        }
        m->legs_vdc = m->vdc;
        m->legs_vdrop = m->vdrop;
        m->legs_u[3] = TWO_THIRDS * (m->legs_u[0] - 0.5 * (m->legs_u[1] + m->legs_u[2]));
        m->legs_u[4] = (m->legs_u[1] - m->legs_u[2]) * (1.0 / PLANT_SQRT3);
        m->legs_valid = 1;
    }
    return m->legs_u;
}

/* sin and cos of theta (the angle of the last call again, or sincos_near). */
static void rotor_sincos(plant_machine_t *m, double theta, double *s, double *c)
{
    if (m->sc_valid && theta == m->sc_theta) {
        *s = m->sc_sin;
        *c = m->sc_cos;
        return;
    }
    sincos_near(m, theta, s, c);
    m->sc_theta = theta;
    m->sc_sin = *s;
    m->sc_cos = *c;
    m->sc_valid = 1;
}

/* An integration stage with every leg conducting (the common case): the state derivatives
 * only, without the phase axes. */
static void stage_conducting(plant_machine_t *m, const plant_state_t *x, plant_deriv_t *d)
{
    const double we = m->pp * x->omega_m;
    const double *u = legs_conducting(m);
    double sn, cs;
    m->stats->rhs_evals++;
    rotor_sincos(m, x->theta, &sn, &cs);
    currents_from_flux(m, x, d, 1);
    d->dpsi_d = -m->rs * d->id + we * x->psi_q + (cs * u[3] + sn * u[4]);
    d->dpsi_q = -m->rs * d->iq - we * x->psi_d + (cs * u[4] - sn * u[3]);
    d->te = 1.5 * m->pp * (x->psi_d * d->iq - x->psi_q * d->id);
    d->dtheta = we;
    mechanics(m, d->te, x->omega_m, &d->tl, &d->domega);
}

/* full = 0: only what an integration stage needs (dpsi_d, dpsi_q, dtheta, domega, te, tl;
 * id, iq and the inductances): the phase currents, their slopes, the phase voltages and the
 * event functions are left unset. The state derivatives are the same either way. */
static void rhs(plant_machine_t *m, const plant_state_t *x, plant_deriv_t *d, int full)
{
    const int nz = plant_machine_zero_count(m);
    const double we = m->pp * x->omega_m;
    double sn, cs, vd = 0.0, vq = 0.0;
    int k;

    if (nz == 0 && !full) {
        stage_conducting(m, x, d);
        return;
    }
    m->stats->rhs_evals++;
    phase_axes(m, x->theta, d->cph, &sn, &cs);
    d->n_monitor = 3;

    if (nz == 3) {
        /* All phases open: i = 0, psi stays at its zero-current value, phase voltages are
         * the back-EMF; the leg potentials float with one common star-point potential. */
        double lo[3], hi[3], m_lo = -1e300, m_hi = 1e300, un;
        double l[3];
        plant_mag_flux(m->mag, 0.0, 0.0, NULL, l);
        d->id = d->iq = 0.0;
        d->ldd = l[0];
        d->lqq = l[1];
        d->ldq = l[2];
        {
            const double det = l[0] * l[1] - l[2] * l[2];
            d->gdd = l[1] / det;
            d->gqq = l[0] / det;
            d->gdq = -l[2] / det;
        }
        vd = -we * x->psi_q;
        vq = we * x->psi_d;
        for (k = 0; k < 3; ++k) {
            d->u_ph[k] = d->cph[k][0] * vd + d->cph[k][1] * vq;
            d->i_ph[k] = 0.0;
            d->di_ph[k] = 0.0;
            plant_leg_band(m->gate[k], m->vdc, m->vdrop, &lo[k], &hi[k]);
            if (lo[k] - d->u_ph[k] > m_lo) {
                m_lo = lo[k] - d->u_ph[k];
            }
            if (hi[k] - d->u_ph[k] < m_hi) {
                m_hi = hi[k] - d->u_ph[k];
            }
        }
        un = 0.5 * (m_lo + m_hi);
        for (k = 0; k < 3; ++k) {
            d->u_leg[k] = d->u_ph[k] + un;
            d->monitor[k] = 1.0;
        }
        d->monitor[0] = m_hi - m_lo; /* >= 0 while one star potential fits every band */
        d->dpsi_d = 0.0;
        d->dpsi_q = 0.0;
    } else {
        double bd, bq, dpd, dpq, didd, didq, mean;
        int z = -1;

        currents_from_flux(m, x, d, full ? 2 : 1);
        bd = -m->rs * d->id + we * x->psi_q;
        bq = -m->rs * d->iq - we * x->psi_d;
        if (nz == 0) {
            /* as stage_conducting: the leg voltages' alpha-beta vector turned by -theta */
            const double *u = legs_conducting(m);
            d->u_leg[0] = u[0];
            d->u_leg[1] = u[1];
            d->u_leg[2] = u[2];
            vd = cs * u[3] + sn * u[4];
            vq = cs * u[4] - sn * u[3];
        } else {
            for (k = 0; k < 3; ++k) {
                if (m->mode[k] == LEG_ZERO) {
                    z = k;
                    continue;
                }
                d->u_leg[k] = plant_leg_voltage(m->gate[k], m->mode[k], m->vdc, m->vdrop);
                vd += TWO_THIRDS * d->u_leg[k] * d->cph[k][0];
                vq += TWO_THIRDS * d->u_leg[k] * d->cph[k][1];
            }
        }
        if (z >= 0) {
            /* Open leg z: d i_z/dt = A + B u_z = 0. */
            const double *c = d->cph[z];
            const double rd = bd + vd, rq = bq + vq;
            const double gcd = d->gdd * c[0] + d->gdq * c[1]; /* (Gamma c)_d */
            const double gcq = d->gdq * c[0] + d->gqq * c[1];
            const double a = we * (c[1] * d->id - c[0] * d->iq) + gcd * rd + gcq * rq;
            const double b = TWO_THIRDS * (c[0] * gcd + c[1] * gcq);
            d->u_leg[z] = -a / b;
            vd += TWO_THIRDS * d->u_leg[z] * c[0];
            vq += TWO_THIRDS * d->u_leg[z] * c[1];
        }
        dpd = bd + vd;
        dpq = bq + vq;
        d->dpsi_d = dpd;
        d->dpsi_q = dpq;
        if (full) { /* the per-phase outputs and event functions */
            didd = d->gdd * dpd + d->gdq * dpq;
            didq = d->gdq * dpd + d->gqq * dpq;
            mean = (d->u_leg[0] + d->u_leg[1] + d->u_leg[2]) / 3.0;
            for (k = 0; k < 3; ++k) {
                const double *c = d->cph[k];
                double lo, hi;
                d->i_ph[k] = c[0] * d->id + c[1] * d->iq;
                /* d c_x/d theta = (c_x[1], -c_x[0]) */
                d->di_ph[k] = we * (c[1] * d->id - c[0] * d->iq) + c[0] * didd + c[1] * didq;
                d->u_ph[k] = d->u_leg[k] - mean;
                plant_leg_band(m->gate[k], m->vdc, m->vdrop, &lo, &hi);
                if (k == z) {
                    const double a = d->u_leg[k] - lo, b = hi - d->u_leg[k];
                    d->monitor[k] = a < b ? a : b;
                } else if (hi > lo) {
                    d->monitor[k] = m->mode[k] == LEG_POS ? d->i_ph[k] : -d->i_ph[k];
                } else {
                    d->monitor[k] = 1.0; /* the sign of the current changes nothing */
                }
            }
        }
    }

    d->te = 1.5 * m->pp * (x->psi_d * d->iq - x->psi_q * d->id);
    d->dtheta = we;
    mechanics(m, d->te, x->omega_m, &d->tl, &d->domega);
}

void plant_machine_rhs(plant_machine_t *m, const plant_state_t *x, plant_deriv_t *d)
{
    rhs(m, x, d, 1);
}

void plant_machine_stage(plant_machine_t *m, const plant_state_t *x, plant_deriv_t *d)
{
    rhs(m, x, d, 0);
}

/* Moves the state so that phase z carries exactly zero current (removes integration
 * drift of an open phase; the change is of the order of the integration error). Not the
 * cut of a phase that opens with current in it: plant_machine_cut. */
static void project_zero(plant_machine_t *m, plant_state_t *x, int z)
{
    double i[2], cph[3][2], sn, cs, iz;
    phase_axes(m, x->theta, cph, &sn, &cs);
    if (plant_mag_invert_from(m->mag, x->psi_d, x->psi_q, &m->mp, 0) < 0) {
        m->stats->newton_failures++;
    }
    i[0] = m->mp.i[0];
    i[1] = m->mp.i[1];
    iz = cph[z][0] * i[0] + cph[z][1] * i[1];
    i[0] -= iz * cph[z][0];
    i[1] -= iz * cph[z][1];
    plant_mag_point_at(m->mag, i[0], i[1], &m->mp);
    x->psi_d = m->mp.psi[0];
    x->psi_q = m->mp.psi[1];
}

/* The cut of phase z when it is disconnected (OPEN_PHASE) at flux psi: the current that
 * has i_z = 0 and the same flux linkage of the loop through the two remaining phases x, y.
 * That loop sees only finite voltages (its legs, its resistance; the arc voltage of the
 * opening contact appears in phase z), so psi_x - psi_y cannot jump; psi_z takes whatever
 * the arc's voltage impulse gives it. With the phase axes c_x + c_y + c_z = 0 and
 * |c_x| = |c_y|, c_x - c_y is perpendicular to c_z: with f perpendicular to c_z,
 *     i' = s f   (i'_z = c_z . i' = 0)   and   f . psi(s f) = f . psi   (the loop's flux),
 * g(s) = f . psi(s f) - f . psi has g'(s) = f' L(s f) f > 0 (the incremental inductance is
 * positive definite everywhere), so the root is unique: Newton from the component the cut
 * keeps, s0 = f . i (the root when Ld = Lq), inside the bracket the iterates build. The
 * magnetic energy W(psi) is convex with gradient i; along the line of fluxes with the loop's
 * flux fixed (direction c_z) it is least where i . c_z = 0: the cut never adds energy, the
 * arc takes the difference. */
static void cut_keeping_loop_flux(plant_machine_t *m, plant_state_t *x, int z)
{
    enum { MAX_ITER = 60 };
    double l[3], psi[2], cph[3][2], sn, cs, loop, s, lo = -HUGE_VAL, hi = HUGE_VAL;
    double f0, f1;
    int it;
    phase_axes(m, x->theta, cph, &sn, &cs);
    f0 = -cph[z][1];
    f1 = cph[z][0];
    loop = f0 * x->psi_d + f1 * x->psi_q;
    if (plant_mag_invert_from(m->mag, x->psi_d, x->psi_q, &m->mp, 0) < 0) {
        m->stats->newton_failures++;
    }
    s = (f0 * m->mp.i[0] + f1 * m->mp.i[1]) / (f0 * f0 + f1 * f1);
    for (it = 0; it < MAX_ITER; ++it) {
        double g, dg, ds, next;
        plant_mag_flux(m->mag, s * f0, s * f1, psi, l);
        g = f0 * psi[0] + f1 * psi[1] - loop;
        if (g == 0.0) {
            break;
        }
        if (g > 0.0) {
            hi = s < hi ? s : hi;
        } else {
            lo = s > lo ? s : lo;
        }
        dg = f0 * f0 * l[0] + 2.0 * f0 * f1 * l[2] + f1 * f1 * l[1];
        ds = g / dg;
        if (fabs(ds) <= 1e-12) {
            /* Newton converges quadratically near the root: the error left after a step of
             * 1e-12 A is far below rounding (about |dL/di|/(2 L) * ds^2) */
            s -= ds;
            break;
        }
        /* A Newton step moves towards the root, so it can only leave the bracket on a side
         * that is already finite: then bisect. */
        next = s - ds;
        s = next > lo && next < hi ? next : 0.5 * (lo + hi);
    }
    if (it == MAX_ITER) {
        m->stats->newton_failures++;
    }
    plant_mag_point_at(m->mag, s * f0, s * f1, &m->mp);
    x->psi_d = m->mp.psi[0];
    x->psi_q = m->mp.psi[1];
}

void plant_machine_cut(plant_machine_t *m, plant_state_t *x)
{
    int k;
    if (plant_machine_zero_count(m) == 1) {
        for (k = 0; k < 3; ++k) {
            if (m->mode[k] == LEG_ZERO) {
                cut_keeping_loop_flux(m, x, k);
            }
        }
        return;
    }
    /* no loop is left (a second phase open or at zero current): every current is zero */
    plant_machine_project(m, x);
}

void plant_machine_project(plant_machine_t *m, plant_state_t *x)
{
    const int nz = plant_machine_zero_count(m);
    int k;
    if (nz == 1) {
        for (k = 0; k < 3; ++k) {
            if (m->mode[k] == LEG_ZERO) {
                project_zero(m, x, k);
            }
        }
    } else if (nz >= 2) {
        plant_mag_point_at(m->mag, 0.0, 0.0, &m->mp);
        x->psi_d = m->mp.psi[0]; /* = psi_zero */
        x->psi_q = m->mp.psi[1];
    }
}

int plant_machine_resolve(plant_machine_t *m, plant_state_t *x)
{
    int changes = 0, iter, k;
    plant_deriv_t d;

    for (iter = 0; iter < 8; ++iter) {
        int nz = plant_machine_zero_count(m);
        if (nz == 0) {
            return changes;
        }
        if (nz == 2) {
            /* KCL: the third phase is at zero current as well. */
            for (k = 0; k < 3; ++k) {
                m->mode[k] = LEG_ZERO;
            }
            ++changes;
            nz = 3;
        }
        plant_machine_project(m, x);
        plant_machine_rhs(m, x, &d);
        if (nz == 3) {
            /* Does one star potential keep every open terminal inside its band? If not, the
             * leg that most needs a lower terminal voltage starts to source current through
             * its lower path (POS) and the one that most needs a higher one sinks (NEG). */
            double lo, hi, best_lo = -1e300, best_hi = 1e300;
            int p = 0, n = 1;
            for (k = 0; k < 3; ++k) {
                plant_leg_band(m->gate[k], m->vdc, m->vdrop, &lo, &hi);
                if (lo - d.u_ph[k] > best_lo) {
                    best_lo = lo - d.u_ph[k];
                    p = k;
                }
                if (hi - d.u_ph[k] < best_hi) {
                    best_hi = hi - d.u_ph[k];
                    n = k;
                }
            }
            if (best_lo <= best_hi || p == n) {
                return changes;
            }
            m->mode[p] = LEG_POS;
            m->mode[n] = LEG_NEG;
            ++changes;
            continue;
        }
        /* nz == 1 */
        for (k = 0; k < 3; ++k) {
            if (m->mode[k] == LEG_ZERO) {
                double lo, hi;
                const double u = d.u_leg[k];
                plant_leg_band(m->gate[k], m->vdc, m->vdrop, &lo, &hi);
                if (hi > lo && u >= lo && u <= hi) {
                    return changes;
                }
                /* Above the band: the current goes negative through the upper path. */
                m->mode[k] = u > 0.5 * (lo + hi) ? LEG_NEG : LEG_POS;
                ++changes;
                return changes;
            }
        }
    }
    m->stats->mode_loops_cut++;
    return changes;
}

void plant_machine_modes_from_currents(plant_machine_t *m, plant_state_t *x)
{
    plant_deriv_t d;
    int k;
    for (k = 0; k < 3; ++k) {
        m->mode[k] = LEG_POS;
    }
    plant_machine_rhs(m, x, &d);
    for (k = 0; k < 3; ++k) {
        m->mode[k] = d.i_ph[k] > 0.0 ? LEG_POS : (d.i_ph[k] < 0.0 ? LEG_NEG : LEG_ZERO);
    }
    plant_machine_resolve(m, x);
}
