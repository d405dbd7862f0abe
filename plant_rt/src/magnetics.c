/* Flux map of the IPMSM from an algebraic co-energy W'(id, iq).
 *
 * psi_d = dW'/did, psi_q = dW'/diq, so the incremental matrix [[Ldd, Ldq], [Ldq, Lqq]] is
 * the Hessian of W' and is symmetric by construction (reciprocal cross-saturation). Every
 * term has bounded second derivatives and the self terms are bounded below, which keeps the
 * Hessian positive definite for all currents (checked in plant_mag_init): the map
 * current -> flux is then a bijection and the damped Newton inversion converges from any
 * start.
 *
 * d axis:  incremental Ld(id) = ld_sat + ld_delta / (1 + exp((id - knee)/width)).
 *          Positive id adds to the magnet flux and saturates the d-axis iron: Ld falls
 *          towards ld_sat; negative id leaves it near ld_sat + ld_delta (mild asymmetry
 *          used by the firmware's polarity detection).
 *          psi_d = lambda_m + ld_sat*id + ld_delta*(id - width*(softplus((id-knee)/width)
 *                                                   - softplus(-knee/width)))
 * q axis:  psi_q = Lq0*iq / (1 + a*iq^2) for |iq| <= x1 (apparent Lq falls with |iq|);
 *          beyond x1 the incremental Lq continues as lq_inf + (L1 - lq_inf)*exp(-s(|iq|-x1))
 *          with L1 and s matching value and slope at x1 (C2 flux, monotone, odd).
 * cross:   W'c = -K * U(id) * V(iq), U = S*tanh(id/S), V = S^2*(1 - exp(-iq^2/(2S^2))).
 *          Ldq = -K*U'(id)*V'(iq): negative for iq > 0 at id = 0 (q current lowers psi_d),
 *          bounded for all currents.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "plant_internal.h"

static double softplus(double u)
{
    return u > 0.0 ? u + log1p(exp(-u)) : log1p(exp(u));
}

/* Slope of the incremental Lq of the rational law at x: d/dx [Lq0 (1 - a x^2)/(1 + a x^2)^2]. */
static double lq_rational_slope(double lq0, double a, double x)
{
    double den = 1.0 + a * x * x;
    return -2.0 * a * lq0 * x * (3.0 - a * x * x) / (den * den * den);
}

int plant_mag_init(plant_mag_t *mag, const plant_config_t *cfg, char *err, size_t errlen)
{
    const double ld = cfg->magnetics.ld_h, ld_sat = cfg->magnetics.ld_sat_h;
    const double knee = cfg->magnetics.ld_knee_a, width = cfg->magnetics.ld_width_a;
    double sig0;

    mag->lambda_m = cfg->machine.lambda_m_wb;
    mag->ld_sat = ld_sat;
    mag->ld_knee = knee;
    mag->ld_width = width;
    mag->ld_inv_width = 1.0 / width;
    mag->ld_sp0 = softplus(-knee / width);
    sig0 = 1.0 / (1.0 + exp(-knee / width)); /* logistic factor at id = 0 */
    mag->ld_delta = (ld - ld_sat) / sig0;
    if (ld_sat > ld) {
        snprintf(err, errlen, "magnetics.ld_sat_h: must not exceed magnetics.ld_h");
        return -1;
    }

    mag->lq0 = cfg->magnetics.lq_h;
    mag->lq_a = cfg->magnetics.lq_sat_per_a2;
    mag->lq_x1 = cfg->magnetics.lq_ext_from_a;
    mag->lq_inf = cfg->magnetics.lq_inf_h;
    {
        const double a = mag->lq_a, x1 = mag->lq_x1, den = 1.0 + a * x1 * x1;
        double slope;
        mag->lq_psi1 = mag->lq0 * x1 / den;
        mag->lq_l1 = mag->lq0 * (1.0 - a * x1 * x1) / (den * den);
        slope = lq_rational_slope(mag->lq0, a, x1);
        if (a > 0.0) {
            if (!(mag->lq_l1 > mag->lq_inf)) {
                snprintf(err, errlen,
                         "magnetics.lq_ext_from_a: the incremental Lq there (%.4g H) must exceed "
                         "magnetics.lq_inf_h (%.4g H)",
                         mag->lq_l1, mag->lq_inf);
                return -1;
            }
            mag->lq_s = -slope / (mag->lq_l1 - mag->lq_inf);
        } else {
            mag->lq_s = 0.0; /* linear q axis: the extension continues with Lq0 */
        }
    }

    mag->cross_s = cfg->magnetics.cross_scale_a;
    {
        const double iref = cfg->magnetics.cross_ref_a, s = mag->cross_s;
        /* Ldq(0, iref) = -K * 1 * iref * exp(-iref^2/(2 S^2)) = ldq_ref */
        mag->cross_k = -cfg->magnetics.ldq_ref_h / (iref * exp(-iref * iref / (2.0 * s * s)));
    }

    /* Positive definiteness for every current: bounds of each Hessian contribution. */
    {
        const double k = fabs(mag->cross_k), s = mag->cross_s;
        const double ldd_min = ld_sat - k * s * (4.0 / (3.0 * PLANT_SQRT3)) * 1.0000001;
        const double lq_min = (mag->lq_a > 0.0 ? mag->lq_inf : mag->lq0);
        const double lqq_min = lq_min - k * s;
        const double ldq_max = k * s * exp(-0.5);
        if (!(ldd_min > 0.0 && lqq_min > 0.0 && ldd_min * lqq_min > ldq_max * ldq_max)) {
            snprintf(err, errlen,
                     "magnetics.ldq_ref_h: cross-saturation too strong for the self "
                     "inductances (flux map would not be invertible)");
            return -1;
        }
    }
    mag->ld_nominal = ld;
    mag->lq_nominal = mag->lq0;
    mag->linear = mag->ld_delta == 0.0 && mag->lq_a == 0.0 && mag->cross_k == 0.0;

    /* A bound of the fourth derivatives of W' for every current (plant_mag_invert_from's
     * skip): the sum of the bounds of each term's, each component with its multiplicity.
     *  d axis: d2Ld/did2 = ld_delta s''(v)/width^2, |s''| <= 1/(6 sqrt 3) (s the logistic);
     *  q axis: d2Lq/diq2 of the rational law = -6 a Lq0 (1 - 6y + y^2)/(1 + y)^4, y = a iq^2,
     *          at most 6 a Lq0 (at iq = 0); of the extension s^2 (L1 - Linf) e^(-s dx): the
     *          larger of the two (they hold on either side of lq_ext_from_a);
     *  cross:  -K U^(a) V^(4-a) = -K/S tanh^(a)(x) f^(4-a)(y) (x = id/S, y = iq/S,
     *          f = 1 - exp(-y^2/2)) with max |tanh^(a)| = 1, 1, 0.770, 2, 4.08 and
     *          max |f^(b)| = 1, 0.607, 1, 1.38, 3: sum over a with C(4, a) < 22.1 |K|/S. */
    {
        const double q_rational = 6.0 * mag->lq_a * mag->lq0;
        const double q_ext =
            mag->lq_a > 0.0 ? mag->lq_s * mag->lq_s * (mag->lq_l1 - mag->lq_inf) : 0.0;
        mag->w4_bound = fabs(mag->ld_delta) * mag->ld_inv_width * mag->ld_inv_width *
                            (1.0 / (6.0 * PLANT_SQRT3)) +
                        (q_rational > q_ext ? q_rational : q_ext) +
                        (mag->cross_k != 0.0 ? 22.1 * fabs(mag->cross_k) / mag->cross_s : 0.0);
    }
    return 0;
}

/* The last Newton correction accepted: the error left is about |dL/di|/(2 L) * step^2. */
#define NEWTON_ACCEPT_A 1e-7
/* An integration stage takes the second-order warm start without evaluating the map when
 * its error is provably below this (a current error of 1e-12 A changes a stage's flux
 * derivative by rs * 1e-12 V: far below the RK4 step's own error). */
#define SKIP_ERROR_A 1e-12
/* A right-hand side with outputs (the phase-current slopes: the interpolation between
 * steps and the event location use them) skips only when the inductances' first-order
 * update is also this close, relative to them: |Gamma| W4 |e|^2. */
#define SKIP_L_RELATIVE 1e-12

#if defined(__GNUC__)
#define MAG_INLINE static inline __attribute__((always_inline))
#define MAG_NOINLINE static __attribute__((noinline))
#else
#define MAG_INLINE static inline
#define MAG_NOINLINE static
#endif

/* psi, Linc and (w3 != NULL) the third derivatives of W'. */
MAG_INLINE void flux_eval_inline(const plant_mag_t *mag, double id, double iq, double psi[2],
                                 double linc[3], double w3[4])
{
    double psid, psiq, ldd, lqq, ldq = 0.0;
    double wddd = 0.0, wddq = 0.0, wdqq = 0.0, wqqq = 0.0;

    /* d axis: one exponential serves the logistic and the softplus, e = exp(-|u|) <= 1:
     *   u <= 0: sigma = 1/(1 + e), softplus(u) = log1p(e)
     *   u > 0:  sigma = e/(1 + e), softplus(u) = u + log1p(e)
     * and d sigma/d id = -sigma (1 - sigma)/width = -e/(1 + e)^2/width.              */
    if (mag->ld_delta != 0.0) {
        const double u = (id - mag->ld_knee) * mag->ld_inv_width;
        const double e = exp(-fabs(u)), r = 1.0 / (1.0 + e);
        const double sig = (u > 0.0 ? e : 1.0) * r; /* logistic of (knee - id)/width */
        const double sp = (u > 0.0 ? u : 0.0) + log1p(e);
        psid = mag->lambda_m + mag->ld_sat * id +
               mag->ld_delta * (id - mag->ld_width * (sp - mag->ld_sp0));
        ldd = mag->ld_sat + mag->ld_delta * sig;
        if (w3) {
            wddd = -mag->ld_delta * mag->ld_inv_width * e * r * r;
        }
    } else {
        psid = mag->lambda_m + mag->ld_sat * id;
        ldd = mag->ld_sat;
    }

    /* q axis (odd in iq) */
    {
        const double x = fabs(iq), sgn = iq < 0.0 ? -1.0 : 1.0;
        if (x <= mag->lq_x1 || mag->lq_a == 0.0) {
            const double a = mag->lq_a, inv_den = 1.0 / (1.0 + a * iq * iq);
            psiq = mag->lq0 * iq * inv_den;
            lqq = mag->lq0 * (1.0 - a * iq * iq) * (inv_den * inv_den);
            if (w3) { /* lq_rational_slope */
                wqqq = -2.0 * a * mag->lq0 * iq * (3.0 - a * iq * iq) *
                       (inv_den * inv_den * inv_den);
            }
        } else {
            const double dx = x - mag->lq_x1, e = exp(-mag->lq_s * dx);
            /* integral of (L1 - Linf) e^{-s t} over [0, dx] = (L1 - Linf) (1 - e^{-s dx}) / s */
            const double tail = mag->lq_s > 0.0 ? -expm1(-mag->lq_s * dx) / mag->lq_s : dx;
            psiq = sgn * (mag->lq_psi1 + mag->lq_inf * dx + (mag->lq_l1 - mag->lq_inf) * tail);
            lqq = mag->lq_inf + (mag->lq_l1 - mag->lq_inf) * e;
            if (w3) {
                wqqq = -sgn * mag->lq_s * (mag->lq_l1 - mag->lq_inf) * e;
            }
        }
    }

    /* cross-saturation */
    if (mag->cross_k != 0.0) {
        const double s = mag->cross_s, k = mag->cross_k;
        const double th = tanh(id / s), sech2 = 1.0 - th * th;
        const double u = s * th, du = sech2, ddu = -2.0 / s * th * sech2;
        const double g = exp(-iq * iq / (2.0 * s * s));
        const double v = s * s * (1.0 - g), dv = iq * g, ddv = (1.0 - iq * iq / (s * s)) * g;
        psid -= k * du * v;
        psiq -= k * u * dv;
        ldd -= k * ddu * v;
        lqq -= k * u * ddv;
        ldq = -k * du * dv;
        if (w3) {
            /* U''' = -2/S^2 sech^2 (1 - 3 tanh^2), V''' = -(iq/S^2) (3 - iq^2/S^2) g */
            const double dddu = -2.0 / (s * s) * sech2 * (1.0 - 3.0 * th * th);
            const double dddv = -iq / (s * s) * (3.0 - iq * iq / (s * s)) * g;
            wddd -= k * dddu * v;
            wddq = -k * ddu * dv;
            wdqq = -k * du * ddv;
            wqqq -= k * u * dddv;
        }
    }

    if (psi) {
        psi[0] = psid;
        psi[1] = psiq;
    }
    if (linc) {
        linc[0] = ldd;
        linc[1] = lqq;
        linc[2] = ldq;
    }
    if (w3) {
        w3[0] = wddd;
        w3[1] = wddq;
        w3[2] = wdqq;
        w3[3] = wqqq;
    }
}

/* the same as a call (the Newton loop's line search and the other callers) */
MAG_NOINLINE void flux_eval(const plant_mag_t *mag, double id, double iq, double psi[2],
                            double linc[3], double w3[4])
{
    flux_eval_inline(mag, id, iq, psi, linc, w3);
}

void plant_mag_flux(const plant_mag_t *mag, double id, double iq, double psi[2], double linc[3])
{
    flux_eval(mag, id, iq, psi, linc, NULL);
}

void plant_mag_flux3(const plant_mag_t *mag, double id, double iq, double psi[2], double linc[3],
                     double w3[4])
{
    flux_eval(mag, id, iq, psi, linc, w3);
}

/* Damped Newton on F(i) = psi(i) - target. The Jacobian (incremental inductance matrix) is
 * symmetric positive definite everywhere, so the Newton direction always reduces |F|; a
 * halving line search on |F| makes the iteration converge from any start, and the
 * iteration count is bounded. With w3: the third derivatives of W' at the last
 * linearisation point come out too, and the inductances follow the last step to first
 * order in it. */
MAG_NOINLINE int invert(const plant_mag_t *mag, double psi_d, double psi_q, double i[2],
                         double linc[3], double w3[4])
{
    enum { MAX_ITER = 60, MAX_HALVINGS = 40 };
    double psi[2], l[3], t[4] = {0.0, 0.0, 0.0, 0.0}, f0, f1, res2;
    int it;

    flux_eval(mag, i[0], i[1], psi, l, w3 ? t : NULL);
    f0 = psi[0] - psi_d;
    f1 = psi[1] - psi_q;
    res2 = f0 * f0 + f1 * f1;
    for (it = 1; it <= MAX_ITER; ++it) {
        const double inv_det = 1.0 / (l[0] * l[1] - l[2] * l[2]);
        const double d0 = (l[1] * f0 - l[2] * f1) * inv_det;
        const double d1 = (l[0] * f1 - l[2] * f0) * inv_det;
        const double step = fabs(d0) + fabs(d1);
        double alpha = 1.0, n0, n1, g0, g1, res2_new;
        double psi_new[2], l_new[3], t_new[4];
        int h;

        if (step <= NEWTON_ACCEPT_A) {
            /* Quadratic convergence: after a correction of at most 1e-7 A the error is about
             * |dL/di|/(2 L) * step^2 < 1e-14 A for these maps (|dL/di| < 10 mH/A, L > 2 mH). */
            i[0] -= d0;
            i[1] -= d1;
            if (w3) {
                l[0] -= t[0] * d0 + t[1] * d1;
                l[1] -= t[2] * d0 + t[3] * d1;
                l[2] -= t[1] * d0 + t[2] * d1;
            }
            break;
        }
        for (h = 0; h <= MAX_HALVINGS; ++h) {
            n0 = i[0] - alpha * d0;
            n1 = i[1] - alpha * d1;
            flux_eval(mag, n0, n1, psi_new, l_new, w3 ? t_new : NULL);
            g0 = psi_new[0] - psi_d;
            g1 = psi_new[1] - psi_q;
            res2_new = g0 * g0 + g1 * g1;
            if (res2_new < res2 || alpha * step < 1e-14) {
                break;
            }
            alpha *= 0.5;
        }
        i[0] = n0;
        i[1] = n1;
        l[0] = l_new[0];
        l[1] = l_new[1];
        l[2] = l_new[2];
        if (w3) {
            t[0] = t_new[0];
            t[1] = t_new[1];
            t[2] = t_new[2];
            t[3] = t_new[3];
        }
        f0 = g0;
        f1 = g1;
        res2 = res2_new;
        if (res2 == 0.0) {
            break;
        }
    }
    if (linc) {
        linc[0] = l[0];
        linc[1] = l[1];
        linc[2] = l[2];
    }
    if (w3) {
        w3[0] = t[0];
        w3[1] = t[1];
        w3[2] = t[2];
        w3[3] = t[3];
    }
    return it <= MAX_ITER ? it : -MAX_ITER;
}

int plant_mag_invert(const plant_mag_t *mag, double psi_d, double psi_q, double i[2],
                     double linc[3])
{
    return invert(mag, psi_d, psi_q, i, linc, NULL);
}

/* The inverse of the incremental inductance matrix. */
static void point_inverse(plant_mag_point_t *p)
{
    const double inv_det = 1.0 / (p->l[0] * p->l[1] - p->l[2] * p->l[2]);
    p->g[0] = p->l[1] * inv_det;
    p->g[1] = p->l[0] * inv_det;
    p->g[2] = -p->l[2] * inv_det;
}

void plant_mag_point_at(const plant_mag_t *mag, double id, double iq, plant_mag_point_t *p)
{
    p->i[0] = id;
    p->i[1] = iq;
    flux_eval(mag, id, iq, p->psi, p->l, p->t);
    point_inverse(p);
}

int plant_mag_invert_from(const plant_mag_t *mag, double psi_d, double psi_q,
                          plant_mag_point_t *p, int may_skip)
{
    /* p's values in locals: the stores into p below cannot then make the compiler load them
     * again */
    const double g0 = p->g[0], g1 = p->g[1], g2 = p->g[2];
    const double t0 = p->t[0], t1 = p->t[1], t2 = p->t[2], t3 = p->t[3];
    const double dpd = psi_d - p->psi[0], dpq = psi_q - p->psi[1];
    double i0, i1, e0, e1;
    int it;
    if (mag->linear) {
        /* psi = (lambda_m + Ld id, Lq iq): the closed form; L, Gamma and T stay */
        p->i[0] = (psi_d - mag->lambda_m) / mag->ld_sat;
        p->i[1] = psi_q / mag->lq0;
        p->psi[0] = psi_d;
        p->psi[1] = psi_q;
        return 0;
    }
    {
        /* Warm start: the second-order step of the map from p, psi(i + e) = psi + L e +
         * T[e, e]/2: e = Gamma (dpsi - T[e1, e1]/2) with e1 = Gamma dpsi. Between RK stages
         * the first order alone is off by 1e-5 .. 1e-4 A on the saturating maps (a second
         * flux-map evaluation followed), the second order by about 1e-7 A. */
        double e00, e01, e11, q0, q1;
        e0 = g0 * dpd + g2 * dpq;
        e1 = g2 * dpd + g1 * dpq;
        e00 = 0.5 * e0 * e0;
        e01 = e0 * e1;
        e11 = 0.5 * e1 * e1;
        q0 = t0 * e00 + t1 * e01 + t2 * e11;
        q1 = t1 * e00 + t2 * e01 + t3 * e11;
        i0 = p->i[0] + e0 - (g0 * q0 + g2 * q1);
        i1 = p->i[1] + e1 - (g2 * q0 + g1 * q1);
    }
    if (may_skip) {
        /* Close enough that the warm start itself is the solution to SKIP_ERROR_A: with e*
         * the exact step, e1 - e* = O(|Gamma T| |e|^2), and the warm start is off by at most
         * (|Gamma T|^2/2 + |Gamma| W4/6) |e|^3 to leading order (W4 the fourth derivatives'
         * bound: the remainder of the quadratic model). Norms: sums of absolute values (they
         * bound the operator norms used); T along the step within its value here plus
         * W4 |e|. The factor 2 on the first term is margin. */
        const double en = fabs(e0) + fabs(e1);
        const double gn = fabs(g0) + fabs(g1) + 2.0 * fabs(g2);
        const double tn = fabs(t0) + 2.0 * (fabs(t1) + fabs(t2)) + fabs(t3) + mag->w4_bound * en;
        const double kappa = gn * tn, w4g = gn * mag->w4_bound;
        if ((kappa * kappa + w4g * (1.0 / 6.0)) * (en * en * en) <= SKIP_ERROR_A &&
            (may_skip == 1 || w4g * (en * en) <= SKIP_L_RELATIVE)) {
            /* the inductances to first order: their error W4 |e|^2 is below 1e-9 of them in
             * a stage (which uses them only to start the next inversion), and below
             * SKIP_L_RELATIVE where the phase-current slopes come from them */
            p->i[0] = i0;
            p->i[1] = i1;
            p->psi[0] = psi_d;
            p->psi[1] = psi_q;
            p->l[0] += t0 * e0 + t1 * e1;
            p->l[1] += t2 * e0 + t3 * e1;
            p->l[2] += t1 * e0 + t2 * e1;
            point_inverse(p);
            return 0;
        }
    }
    {
        /* one Newton step from there; accepted as plant_mag_invert accepts its last */
        double psi[2], l[3], w3[4];
        flux_eval_inline(mag, i0, i1, psi, l, w3);
        {
            const double f0 = psi[0] - psi_d, f1 = psi[1] - psi_q;
            const double inv_det = 1.0 / (l[0] * l[1] - l[2] * l[2]);
            const double d0 = (l[1] * f0 - l[2] * f1) * inv_det;
            const double d1 = (l[0] * f1 - l[2] * f0) * inv_det;
            if (fabs(d0) + fabs(d1) <= NEWTON_ACCEPT_A) {
                p->i[0] = i0 - d0;
                p->i[1] = i1 - d1;
                p->psi[0] = psi_d;
                p->psi[1] = psi_q;
                p->l[0] = l[0] - (w3[0] * d0 + w3[1] * d1);
                p->l[1] = l[1] - (w3[2] * d0 + w3[3] * d1);
                p->l[2] = l[2] - (w3[1] * d0 + w3[2] * d1);
                p->t[0] = w3[0];
                p->t[1] = w3[1];
                p->t[2] = w3[2];
                p->t[3] = w3[3];
                point_inverse(p);
                return 1;
            }
        }
    }
    /* farther: the damped Newton iteration from the warm start */
    p->i[0] = i0;
    p->i[1] = i1;
    it = invert(mag, psi_d, psi_q, p->i, p->l, p->t);
    p->psi[0] = psi_d;
    p->psi[1] = psi_q;
    point_inverse(p);
    return it;
}
