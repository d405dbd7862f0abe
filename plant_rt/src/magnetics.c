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
    return 0;
}

void plant_mag_flux(const plant_mag_t *mag, double id, double iq, double psi[2], double linc[3])
{
    double psid, psiq, ldd, lqq, ldq = 0.0;

    /* d axis: one exponential serves the logistic and the softplus, e = exp(-|u|) <= 1:
     *   u <= 0: sigma = 1/(1 + e), softplus(u) = log1p(e)
     *   u > 0:  sigma = e/(1 + e), softplus(u) = u + log1p(e)                          */
    if (mag->ld_delta != 0.0) {
        const double u = (id - mag->ld_knee) * mag->ld_inv_width;
        const double e = exp(-fabs(u));
        const double sig = (u > 0.0 ? e : 1.0) / (1.0 + e); /* logistic of (knee - id)/width */
        const double sp = (u > 0.0 ? u : 0.0) + log1p(e);
        psid = mag->lambda_m + mag->ld_sat * id +
               mag->ld_delta * (id - mag->ld_width * (sp - mag->ld_sp0));
        ldd = mag->ld_sat + mag->ld_delta * sig;
    } else {
        psid = mag->lambda_m + mag->ld_sat * id;
        ldd = mag->ld_sat;
    }

    /* q axis (odd in iq) */
    {
        const double x = fabs(iq), sgn = iq < 0.0 ? -1.0 : 1.0;
        if (x <= mag->lq_x1 || mag->lq_a == 0.0) {
            const double den = 1.0 + mag->lq_a * iq * iq;
            psiq = mag->lq0 * iq / den;
            lqq = mag->lq0 * (1.0 - mag->lq_a * iq * iq) / (den * den);
        } else {
            const double dx = x - mag->lq_x1, e = exp(-mag->lq_s * dx);
            /* integral of (L1 - Linf) e^{-s t} over [0, dx] = (L1 - Linf) (1 - e^{-s dx}) / s */
            const double tail = mag->lq_s > 0.0 ? -expm1(-mag->lq_s * dx) / mag->lq_s : dx;
            psiq = sgn * (mag->lq_psi1 + mag->lq_inf * dx + (mag->lq_l1 - mag->lq_inf) * tail);
            lqq = mag->lq_inf + (mag->lq_l1 - mag->lq_inf) * e;
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
}

/* Damped Newton on F(i) = psi(i) - target. The Jacobian (incremental inductance matrix) is
 * symmetric positive definite everywhere, so the Newton direction always reduces |F|; a
 * halving line search on |F| makes the iteration converge from any start, and the
 * iteration count is bounded. */
int plant_mag_invert(const plant_mag_t *mag, double psi_d, double psi_q, double i[2],
                     double linc[3])
{
    enum { MAX_ITER = 60, MAX_HALVINGS = 40 };
    double psi[2], l[3], f0, f1, res2;
    int it;

    plant_mag_flux(mag, i[0], i[1], psi, l);
    f0 = psi[0] - psi_d;
    f1 = psi[1] - psi_q;
    res2 = f0 * f0 + f1 * f1;
    for (it = 1; it <= MAX_ITER; ++it) {
        const double inv_det = 1.0 / (l[0] * l[1] - l[2] * l[2]);
        const double d0 = (l[1] * f0 - l[2] * f1) * inv_det;
        const double d1 = (l[0] * f1 - l[2] * f0) * inv_det;
        const double step = fabs(d0) + fabs(d1);
        double alpha = 1.0, n0, n1, g0, g1, res2_new;
        double psi_new[2], l_new[3];
        int h;

        if (step <= 1e-7) {
            /* Quadratic convergence: after a correction of at most 1e-7 A the error is about
             * |dL/di|/(2 L) * step^2 < 1e-14 A for these maps (|dL/di| < 10 mH/A, L > 2 mH). */
            i[0] -= d0;
            i[1] -= d1;
            if (linc) {
                linc[0] = l[0];
                linc[1] = l[1];
                linc[2] = l[2];
            }
            return it;
        }
        for (h = 0; h <= MAX_HALVINGS; ++h) {
            n0 = i[0] - alpha * d0;
            n1 = i[1] - alpha * d1;
            plant_mag_flux(mag, n0, n1, psi_new, l_new);
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
        f0 = g0;
        f1 = g1;
        res2 = res2_new;
        if (res2 == 0.0) {
            if (linc) {
                linc[0] = l[0];
                linc[1] = l[1];
                linc[2] = l[2];
            }
            return it;
        }
    }
    if (linc) {
        linc[0] = l[0];
        linc[1] = l[1];
        linc[2] = l[2];
    }
    return -MAX_ITER;
}
