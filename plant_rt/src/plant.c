/* One PWM period: events and integration.
 *
 * The period is split at every gate edge of every leg (dead-time delayed, inverter.c).
 * Between edges the gate states are fixed and the state is integrated with classical RK4
 * in substeps of at most solver.max_step_s. Inside an interval the conduction modes can
 * still change (a phase current reaching zero, an open phase's diode becoming forward
 * biased, the diode bridge starting to conduct): the event functions of machine.c are
 * checked after every substep and a sign change is located by a safeguarded secant
 * (Illinois) search to 1e-13 s, re-integrating the substep from its start. ADC
 * start-of-conversion instants do not split the integration: the current between the
 * ends of a substep is the cubic Hermite interpolant of the end values and slopes (error
 * < 1e-10 A at these substep lengths), and the sensor filter is integrated exactly for it.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "plant_internal.h"

struct plant {
    plant_config_t cfg;
    plant_mag_t mag;
    plant_machine_t mach;
    plant_state_t x;
    plant_deriv_t d;          /* right-hand side at the current instant */
    plant_sensors_t sen;
    plant_gate_memory_t gmem;
    int32_t dead_ticks;
    int adc_bits, vdc_bits;
    double max_step;
    uint32_t next_period;
    plant_stats_t stats;
    plant_faults_t flt;  /* physical faults in force (faults.c) */
    double vdc_from;     /* DC link at the start of its ramp to flt.vdc_target */
    uint32_t vdc_step;   /* periods of that ramp done */
};

/* ------------------------------------------------------------------ creation */

static void machine_setup(plant_t *p)
{
    const plant_config_t *c = &p->cfg;
    plant_machine_t *m = &p->mach;
    memset(m, 0, sizeof(*m));
    m->cfg = c;
    m->mag = &p->mag;
    m->rs = c->machine.rs_ohm;
    m->pp = c->machine.pole_pairs;
    m->lambda_m = c->machine.lambda_m_wb;
    m->vdc = c->inverter.vdc_v;
    m->vdrop = c->inverter.device_drop_v;
    m->j_total = c->shaft.j_kgm2 + c->shaft.j_load_kgm2;
    m->b_total = c->shaft.b_nms + c->shaft.b_load_nms;
    m->stats = &p->stats;
    plant_mag_point_at(&p->mag, 0.0, 0.0, &m->mp);
    m->psi_zero[0] = m->mp.psi[0];
    m->psi_zero[1] = m->mp.psi[1];
}

plant_t *plant_new(const plant_config_t *cfg, char *err, size_t errlen)
{
    plant_t *p;
    int k;
    if (plant_config_check(cfg, err, errlen) != 0) {
        return NULL;
    }
    p = (plant_t *)calloc(1, sizeof(*p));
    if (!p) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    p->cfg = *cfg;
    if (plant_mag_init(&p->mag, &p->cfg, err, errlen) != 0) {
        free(p);
        return NULL;
    }
    machine_setup(p);
    p->dead_ticks = (int32_t)floor(cfg->inverter.dead_time_s * PLANT_TBCLK_HZ + 0.5);
    p->adc_bits = (int)cfg->adc.bits;
    p->vdc_bits = (int)cfg->adc.vdc_bits;
    p->max_step = cfg->solver.max_step_s;
    p->sen.tau = cfg->sensors.bandwidth_hz > 0.0 ? 1.0 / (PLANT_TWO_PI * cfg->sensors.bandwidth_hz)
                                                 : 0.0;
    plant_rng_seed(&p->sen.rng, (uint64_t)cfg->sensors.seed);
    plant_faults_init(&p->flt, cfg->inverter.vdc_v);
    p->vdc_from = cfg->inverter.vdc_v;
    for (k = 0; k < 3; ++k) {
        p->mach.gate[k] = GATE_NONE;
    }
    plant_set_load(p, (int)cfg->load.mode, cfg->load.torque_nm, cfg->load.speed_rpm,
                   cfg->load.k_speed_nms);
    plant_set_state(p, cfg->initial.theta_e_deg * PLANT_PI / 180.0,
                    p->mach.load_mode == HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE
                        ? p->mach.load_speed_rad
                        : cfg->initial.speed_rpm * PLANT_TWO_PI / 60.0,
                    0.0, 0.0);
    return p;
}

plant_t *plant_open(const char *profile_path, const char *const *sets, int n_sets, char *err,
                    size_t errlen)
{
    plant_config_t cfg;
    int k;
    plant_config_defaults(&cfg);
    if (profile_path && plant_config_load(&cfg, profile_path, err, errlen) != 0) {
        return NULL;
    }
    for (k = 0; k < n_sets; ++k) {
        if (plant_config_set(&cfg, sets[k], err, errlen) != 0) {
            return NULL;
        }
    }
    return plant_new(&cfg, err, errlen);
}

void plant_free(plant_t *plant)
{
    free(plant);
}

const plant_config_t *plant_config(const plant_t *plant)
{
    return &plant->cfg;
}

uint32_t plant_next_period(const plant_t *plant)
{
    return plant->next_period;
}

void plant_get_stats(const plant_t *plant, plant_stats_t *stats)
{
    *stats = plant->stats;
}

void plant_set_state(plant_t *p, double theta_e, double omega_m, double id, double iq)
{
    plant_mag_point_at(&p->mag, id, iq, &p->mach.mp);
    p->x.psi_d = p->mach.mp.psi[0];
    p->x.psi_q = p->mach.mp.psi[1];
    p->x.theta = theta_e;
    p->x.omega_m = omega_m;
    plant_machine_modes_from_currents(&p->mach, &p->x);
    plant_machine_rhs(&p->mach, &p->x, &p->d);
}

void plant_set_load(plant_t *p, int mode, double torque_nm, double speed_rpm, double k_speed_nms)
{
    p->mach.load_mode = mode;
    p->mach.load_torque = torque_nm;
    p->mach.load_speed_rad = speed_rpm * PLANT_TWO_PI / 60.0;
    p->mach.load_k = k_speed_nms;
    if (mode == HIL_BENCH_LOAD_CMD_MODE_SPEED_HOLD_CHOICE) {
        p->x.omega_m = p->mach.load_speed_rad; /* the dynamometer imposes the speed */
    }
    plant_machine_rhs(&p->mach, &p->x, &p->d);
}

int plant_set_fault(plant_t *p, int slot, int kind, int channel, int phase, int gate,
                    double value, uint32_t periods, char *err, size_t errlen)
{
    const double target = p->flt.vdc_target;
    if (plant_faults_set(&p->flt, p->cfg.inverter.vdc_v, slot, kind, channel, phase, gate,
                         value, periods, err, errlen) != 0) {
        return -1;
    }
    if (p->flt.vdc_target != target) {
        p->vdc_from = p->mach.vdc; /* a new ramp starts where the link is */
        p->vdc_step = 0;
    }
    return 0;
}

/* DC link of the next period under a DC_LINK fault (a step, or a linear ramp). */
static void dc_link_step(plant_t *p)
{
    const plant_faults_t *f = &p->flt;
    if (f->vdc_ramp == 0 || p->vdc_step >= f->vdc_ramp) {
        p->mach.vdc = f->vdc_target;
        return;
    }
    p->vdc_step++;
    p->mach.vdc = p->vdc_from + (f->vdc_target - p->vdc_from) * ((double)p->vdc_step /
                                                                 (double)f->vdc_ramp);
}

void plant_flux_map(const plant_t *plant, double id, double iq, double psi[2], double linc[3])
{
    plant_mag_flux(&plant->mag, id, iq, psi, linc);
}

int plant_current_from_flux(const plant_t *plant, double psi_d, double psi_q, double i[2])
{
    /* Cold start from the nominal linear model, as a caller without history would. */
    i[0] = (psi_d - plant->mag.lambda_m) / plant->mag.ld_nominal;
    i[1] = psi_q / plant->mag.lq_nominal;
    return plant_mag_invert(&plant->mag, psi_d, psi_q, i, NULL);
}

/* ------------------------------------------------------------------ truth */

static void fill_truth(plant_t *p, double t_in_period, plant_truth_t *t)
{
    const plant_deriv_t *d = &p->d;
    double l[3];
    double th = fmod(p->x.theta, PLANT_TWO_PI);
    if (th < 0.0) {
        th += PLANT_TWO_PI;
    }
    plant_mag_flux(&p->mag, d->id, d->iq, NULL, l);
    t->period = p->next_period;
    t->t_s = (double)p->next_period * PLANT_TS_S + t_in_period;
    t->theta_e = th;
    t->omega_m = p->x.omega_m;
    t->id = d->id;
    t->iq = d->iq;
    t->te = d->te;
    t->tl = d->tl;
    /* Torque sensor between motor and load machine: what the motor rotor passes on. */
    t->t_shaft = d->te - p->cfg.shaft.b_nms * p->x.omega_m - p->cfg.shaft.j_kgm2 * d->domega;
    t->ia = d->i_ph[0];
    t->ib = d->i_ph[1];
    t->ic = d->i_ph[2];
    t->vdc = p->mach.vdc;
    t->psi_d = p->x.psi_d;
    t->psi_q = p->x.psi_q;
    t->ua = d->u_ph[0];
    t->ub = d->u_ph[1];
    t->uc = d->u_ph[2];
    t->ld_inc = l[0];
    t->lq_inc = l[1];
    t->ldq_inc = l[2];
    /* Apparent inductances; at (near) zero current their limits, the incremental values. */
    t->ld_app = fabs(d->id) > 1e-6 ? (p->x.psi_d - p->mag.lambda_m) / d->id : l[0];
    t->lq_app = fabs(d->iq) > 1e-6 ? p->x.psi_q / d->iq : l[1];
    t->lambda_m = p->mag.lambda_m;
    t->rs = p->cfg.machine.rs_ohm;
}

void plant_truth_now(plant_t *plant, plant_truth_t *truth)
{
    plant_machine_rhs(&plant->mach, &plant->x, &plant->d);
    fill_truth(plant, 0.0, truth);
}

/* ------------------------------------------------------------------ integration */

static void state_axpy(const plant_state_t *x, double h, const plant_deriv_t *k, plant_state_t *out)
{
    out->psi_d = x->psi_d + h * k->dpsi_d;
    out->psi_q = x->psi_q + h * k->dpsi_q;
    out->theta = x->theta + h * k->dtheta;
    out->omega_m = x->omega_m + h * k->domega;
}

/* One classical RK4 step of length h from x with k1 = f(x); returns f at the result in d1.
 * The stages need only the state derivatives (plant_machine_stage). */
static void rk4_step(plant_t *p, const plant_state_t *x, const plant_deriv_t *k1, double h,
                     plant_state_t *x1, plant_deriv_t *d1)
{
    plant_deriv_t k2, k3, k4;
    plant_state_t tmp;
    const double h6 = h / 6.0;
    state_axpy(x, 0.5 * h, k1, &tmp);
    plant_machine_stage(&p->mach, &tmp, &k2);
    state_axpy(x, 0.5 * h, &k2, &tmp);
    plant_machine_stage(&p->mach, &tmp, &k3);
    state_axpy(x, h, &k3, &tmp);
    plant_machine_stage(&p->mach, &tmp, &k4);
    x1->psi_d = x->psi_d + h6 * (k1->dpsi_d + 2.0 * (k2.dpsi_d + k3.dpsi_d) + k4.dpsi_d);
    x1->psi_q = x->psi_q + h6 * (k1->dpsi_q + 2.0 * (k2.dpsi_q + k3.dpsi_q) + k4.dpsi_q);
    x1->theta = x->theta + h6 * (k1->dtheta + 2.0 * (k2.dtheta + k3.dtheta) + k4.dtheta);
    x1->omega_m = x->omega_m + h6 * (k1->domega + 2.0 * (k2.domega + k3.domega) + k4.domega);
    p->stats.rk_steps++;
    if (plant_machine_zero_count(&p->mach) > 0) {
        plant_machine_project(&p->mach, x1);
    }
    plant_machine_rhs(&p->mach, x1, d1);
}

static double min_monitor(const plant_deriv_t *d)
{
    double g = d->monitor[0];
    int k;
    for (k = 1; k < d->n_monitor; ++k) {
        if (d->monitor[k] < g) {
            g = d->monitor[k];
        }
    }
    return g;
}

/* Earliest h* in (0, h] where the smallest event function changes sign (it is >= 0 at 0,
 * < 0 at h). Returns the state and derivative just past the root (function < 0 there). */
typedef struct warm_start {
    plant_mag_point_t mp;
    double sc[3], sc_base[3]; /* sin/cos cache and series base (machine.c, phase_axes) */
    int sc_valid, sc_base_valid;
} warm_start_t;

static void warm_save(const plant_machine_t *m, warm_start_t *w)
{
    w->mp = m->mp;
    w->sc[0] = m->sc_theta, w->sc[1] = m->sc_sin, w->sc[2] = m->sc_cos;
    w->sc_base[0] = m->sc_base, w->sc_base[1] = m->sc_base_sin, w->sc_base[2] = m->sc_base_cos;
    w->sc_valid = m->sc_valid;
    w->sc_base_valid = m->sc_base_valid;
}

static void warm_restore(plant_machine_t *m, const warm_start_t *w)
{
    m->mp = w->mp;
    m->sc_theta = w->sc[0], m->sc_sin = w->sc[1], m->sc_cos = w->sc[2];
    m->sc_base = w->sc_base[0], m->sc_base_sin = w->sc_base[1], m->sc_base_cos = w->sc_base[2];
    m->sc_valid = w->sc_valid;
    m->sc_base_valid = w->sc_base_valid;
}

/* Half width of the bracket tried around the predicted root (s): the search stops at a
 * bracket of 1e-13 s, so a prediction within 4e-14 s ends it after these two trials. */
#define HINT_HALF_WIDTH 4e-14

/* Root in (0, h) of the earliest phase-current event function that is >= 0 at the start of
 * the step and < 0 at its end, from the cubic Hermite interpolant of that current (values
 * and slopes at both ends); -1 when the event is not a current's (an open leg's voltage
 * margin) or no such root is found. */
static double current_root_guess(const plant_machine_t *m, const plant_deriv_t *d0,
                                 const plant_deriv_t *d1, double h)
{
    double best = -1.0;
    int k;
    if (d0->n_monitor != 3 || d1->n_monitor != 3 || plant_machine_zero_count(m) == 3) {
        return -1.0;
    }
    for (k = 0; k < 3; ++k) {
        double lo, hi, sgn, m0, m1, s0, s1, c2, c3, a = 0.0, b = h, t;
        int it;
        if (!(d1->monitor[k] < 0.0)) {
            continue;
        }
        plant_leg_band(m->gate[k], m->vdc, m->vdrop, &lo, &hi);
        if (m->mode[k] == LEG_ZERO || !(hi > lo)) {
            return -1.0; /* a voltage-margin event: no slope to go by */
        }
        sgn = m->mode[k] == LEG_POS ? 1.0 : -1.0;
        m0 = sgn * d0->i_ph[k];
        m1 = sgn * d1->i_ph[k];
        if (!(m0 >= 0.0 && m1 < 0.0) || d0->monitor[k] != m0 || d1->monitor[k] != m1) {
            return -1.0;
        }
        s0 = sgn * d0->di_ph[k] * h;
        s1 = sgn * d1->di_ph[k] * h;
        /* p(u) = m0 + s0 u + c2 u^2 + c3 u^3 on u in [0, 1] */
        c2 = 3.0 * (m1 - m0) - 2.0 * s0 - s1;
        c3 = 2.0 * (m0 - m1) + s0 + s1;
        a = 0.0;
        b = 1.0;
        t = m0 / (m0 - m1);
        for (it = 0; it < 60; ++it) {
            const double v = m0 + t * (s0 + t * (c2 + t * c3));
            const double dv = s0 + t * (2.0 * c2 + t * 3.0 * c3);
            double tn;
            if (v >= 0.0) {
                a = t;
            } else {
                b = t;
            }
            tn = dv < 0.0 ? t - v / dv : 0.5 * (a + b);
            if (!(tn > a && tn < b)) {
                tn = 0.5 * (a + b); /* Newton left the bracket: bisect */
            }
            if (fabs(tn - t) * h < 1e-16 || b - a < 1e-16) {
                t = tn;
                break;
            }
            t = tn;
        }
        t *= h;
        if (best < 0.0 || t < best) {
            best = t;
        }
    }
    return best;
}

static double locate_event(plant_t *p, const plant_state_t *x0, const plant_deriv_t *d0,
                           double h, double g_end, plant_state_t *x1, plant_deriv_t *d1)
{
    warm_start_t saved; /* the result must not depend on the search's trial points */
    double a = 0.0, b = h, ga = min_monitor(d0), gb = g_end, width_check = h;
    int side = 0, it, stalled = 0;
    plant_state_t xt;
    plant_deriv_t dt;

    int b_is_last_trial = 0; /* xt/dt (and the warm start) are the trial at b */
    warm_save(&p->mach, &saved);
    if (ga < 0.0) {
        ga = 0.0;
    }
    {
        /* A phase current's zero crossing: the cubic through its values and slopes at both
         * ends of the step places the root far inside the final tolerance (its error is
         * about h^4/384 |d4i/dt4| / |di/dt|, < 1e-14 s for these machines), so two trials a hair
         * either side of it usually close the bracket at once. When they do not, the search
         * goes on from the bracket they leave. */
        const double guess = current_root_guess(&p->mach, d0, d1, h);
        if (guess > a + 2.0 * HINT_HALF_WIDTH && guess < b - 2.0 * HINT_HALF_WIDTH) {
            const double lo = guess - HINT_HALF_WIDTH, hi = guess + HINT_HALF_WIDTH;
            warm_restore(&p->mach, &saved);
            rk4_step(p, x0, d0, lo, &xt, &dt);
            if (min_monitor(&dt) >= 0.0) {
                a = lo;
                ga = min_monitor(&dt);
                warm_restore(&p->mach, &saved);
                rk4_step(p, x0, d0, hi, &xt, &dt);
                if (min_monitor(&dt) < 0.0) {
                    b = hi;
                    gb = min_monitor(&dt);
                    b_is_last_trial = 1;
                } else {
                    a = hi;
                    ga = min_monitor(&dt);
                }
            } else {
                b = lo;
                gb = min_monitor(&dt);
                b_is_last_trial = 1;
            }
            width_check = b - a;
        }
    }
    for (it = 0; it < 200 && b - a > 1e-13; ++it) {
        const double tol = 2e-14; /* trial points stay this far inside the bracket */
        double t;
        double g;
        if (it > 0 && (it % 3) == 0) {
            /* safeguard: the bracket must halve at least every three trials */
            if (b - a > 0.5 * width_check) {
                stalled = 1;
            }
            width_check = b - a;
        }
        if (stalled || !(ga - gb > 0.0)) {
            t = 0.5 * (a + b);
            stalled = 0;
        } else {
            t = a + (b - a) * ga / (ga - gb); /* regula falsi, Illinois-weighted */
        }
        if (!(t >= a + tol)) {
            t = a + tol;
        }
        if (!(t <= b - tol)) {
            t = b - tol;
        }
        warm_restore(&p->mach, &saved);
        rk4_step(p, x0, d0, t, &xt, &dt);
        g = min_monitor(&dt);
        b_is_last_trial = g < 0.0;
        if (g < 0.0) {
            b = t;
            gb = g;
            if (side == -1) {
                ga *= 0.5; /* Illinois: the retained end's value is halved */
            }
            side = -1;
        } else {
            a = t;
            ga = g;
            if (side == 1) {
                gb *= 0.5;
            }
            side = 1;
        }
    }
    if (b_is_last_trial) {
        /* the same step from the same warm start: its result, not a second evaluation */
        *x1 = xt;
        *d1 = dt;
    } else {
        warm_restore(&p->mach, &saved);
        rk4_step(p, x0, d0, b, x1, d1);
    }
    if (min_monitor(d1) >= 0.0) {
        /* The search's end state rounds to the near side: step to h itself instead. */
        warm_restore(&p->mach, &saved);
        rk4_step(p, x0, d0, h, x1, d1);
        return h;
    }
    return b;
}

typedef struct soc_queue {
    int n, next;
    int index[PLANT_MAX_SOC];
    double t[PLANT_MAX_SOC];
} soc_queue_t;

static double hermite(double i0, double di0, double i1, double di1, double h, double s)
{
    const double u = s / h, delta = i1 - i0;
    const double c2 = 3.0 * delta - h * (2.0 * di0 + di1);
    const double c3 = -2.0 * delta + h * (di0 + di1);
    return i0 + u * (h * di0 + u * (c2 + u * c3));
}

static void take_sample(plant_t *p, int idx, double t, const double i_true[2],
                        const double y[2], plant_samples_t *out)
{
    const plant_config_t *c = &p->cfg;
    double ring[2], in_a, in_b, vdc;
    int clip_a, clip_b, clip_v;
    /* Draw the noise whether or not it is used, so the sequence does not depend on it. */
    const double na = plant_rng_gauss(&p->sen.rng), nb = plant_rng_gauss(&p->sen.rng);
    const double nv = plant_rng_gauss(&p->sen.rng);
    double sa = c->sensors.gain_a * y[0] + c->sensors.offset_a_a;
    double sb = c->sensors.gain_b * y[1] + c->sensors.offset_b_a;
    const plant_faults_t *f = &p->flt;
    if (f->adc_active) {
        sa = f->sensor_lost[0] ? 0.0 : sa;
        sb = f->sensor_lost[1] ? 0.0 : sb;
    }
    plant_ring_eval(&p->sen, c, t, ring);
    in_a = sa + ring[0] + c->sensors.noise_rms_a * na;
    in_b = sb + ring[1] + c->sensors.noise_rms_a * nb;
    vdc = p->mach.vdc + c->sensors.vdc_noise_rms_v * nv;
    if (!out) {
        return;
    }
    if (f->adc_active) {
        in_a = plant_faults_adc_in(f, 0, in_a);
        in_b = plant_faults_adc_in(f, 1, in_b);
        vdc = plant_faults_adc_in(f, 2, vdc);
    }
    out->ia_true[idx] = i_true[0];
    out->ib_true[idx] = i_true[1];
    out->ia_sensor[idx] = sa;
    out->ib_sensor[idx] = sb;
    out->ia_adc_in[idx] = in_a;
    out->ib_adc_in[idx] = in_b;
    out->ia_code[idx] = plant_adc_current_code(in_a, p->adc_bits, c->adc.range_a, &clip_a);
    out->ib_code[idx] = plant_adc_current_code(in_b, p->adc_bits, c->adc.range_a, &clip_b);
    out->vdc_code[idx] = plant_adc_vdc_code(vdc, p->vdc_bits, c->adc.vdc_range_v, &clip_v);
    if (f->adc_active) {
        /* a stuck converter: its code whatever the input (clamped to what it can output) */
        const int32_t top[3] = {(int32_t)(ldexp(1.0, p->adc_bits) - 1.0),
                                (int32_t)(ldexp(1.0, p->adc_bits) - 1.0),
                                (int32_t)(ldexp(1.0, p->vdc_bits) - 1.0)};
        int32_t *code[3];
        int *clip[3];
        int ch;
        code[0] = &out->ia_code[idx], code[1] = &out->ib_code[idx], code[2] = &out->vdc_code[idx];
        clip[0] = &clip_a, clip[1] = &clip_b, clip[2] = &clip_v;
        for (ch = 0; ch < 3; ++ch) {
            if (f->stuck[ch]) {
                *code[ch] = f->stuck_code[ch] < top[ch] ? f->stuck_code[ch] : top[ch];
                *clip[ch] = 0;
            }
        }
    }
    out->clipped += (uint32_t)(clip_a + clip_b + clip_v);
}

/* Leg-voltage jumps larger than Vdc/2 are hard switching edges: they start ringing. */
static void ring_on_jumps(plant_t *p, const double u_before[3], double t)
{
    int k;
    if (p->cfg.sensors.ring_amp_a == 0.0) {
        return;
    }
    for (k = 0; k < 3; ++k) {
        const double du = p->d.u_leg[k] - u_before[k];
        if (p->mach.gate[k] == GATE_OPEN) {
            continue; /* a disconnected phase: no current, no ringing in its sensor */
        }
        if (fabs(du) > 0.5 * p->mach.vdc) {
            plant_ring_add(&p->sen, t, k, du > 0.0 ? 1.0 : -1.0);
        }
    }
}

/* Integrates from t to t_end (seconds in the period) with fixed gates, taking the samples
 * that fall into (t, t_end]. */
static void integrate_interval(plant_t *p, double t, double t_end, soc_queue_t *q,
                               plant_samples_t *out)
{
    int stalled_events = 0;
    while (t_end - t > 1e-15) {
        const double remaining = t_end - t;
        const double n = ceil(remaining / p->max_step - 1e-9);
        double h = n <= 1.0 ? remaining : remaining / n;
        plant_state_t x1;
        plant_deriv_t d1;
        double i0[2], di0[2], i1[2], di1[2], g;
        int event = 0;

        rk4_step(p, &p->x, &p->d, h, &x1, &d1);
        g = min_monitor(&d1);
        if (g < 0.0 && stalled_events <= 16) {
            h = locate_event(p, &p->x, &p->d, h, g, &x1, &d1);
            event = 1;
            p->stats.conduction_events++;
            if (remaining - h < 1e-15) {
                h = remaining;
            }
        } else if (g < 0.0) {
            /* Mode changes that cycle without progress cannot be resolved at this instant
             * (not seen in practice): count it and take the step with the modes as they are. */
            p->stats.mode_loops_cut++;
            stalled_events = 0;
        }

        /* sensors over [t, t + h] */
        i0[0] = p->d.i_ph[0];
        i0[1] = p->d.i_ph[1];
        di0[0] = p->d.di_ph[0];
        di0[1] = p->d.di_ph[1];
        i1[0] = d1.i_ph[0];
        i1[1] = d1.i_ph[1];
        di1[0] = d1.di_ph[0];
        di1[1] = d1.di_ph[1];
        while (q->next < q->n && q->t[q->next] <= t + h + 1e-15) {
            const double s = q->t[q->next] - t;
            double it[2], y[2];
            it[0] = hermite(i0[0], di0[0], i1[0], di1[0], h, s);
            it[1] = hermite(i0[1], di0[1], i1[1], di1[1], h, s);
            plant_filter_eval(&p->sen, i0, di0, i1, di1, h, s, y);
            take_sample(p, q->index[q->next], q->t[q->next], it, y, out);
            q->next++;
        }
        {
            double y[2];
            plant_filter_eval(&p->sen, i0, di0, i1, di1, h, h, y);
            p->sen.y[0] = y[0];
            p->sen.y[1] = y[1];
        }
        p->x = x1;
        p->d = d1;
        t += h;

        if (event) {
            double u_before[3];
            int k;
            memcpy(u_before, p->d.u_leg, sizeof(u_before));
            /* The leg(s) whose current reached zero become candidates for the open state;
             * resolve() decides from the voltage that keeps them at zero. */
            for (k = 0; k < 3; ++k) {
                if (p->d.monitor[k] < 0.0 && p->mach.mode[k] != LEG_ZERO) {
                    p->mach.mode[k] = LEG_ZERO;
                }
            }
            plant_machine_resolve(&p->mach, &p->x);
            plant_machine_rhs(&p->mach, &p->x, &p->d);
            ring_on_jumps(p, u_before, t);
            stalled_events = h < 1e-12 ? stalled_events + 1 : 0;
        }
    }
}

/* A phase that opens loses its current at once while the loop through the other two keeps
 * its flux linkage (plant_machine_cut), so their currents change and may change sign. The
 * other legs' conduction labels are set again from the currents that are left; with the
 * labels of before, a leg whose current had just changed sign "reached zero" one step later
 * and every current was set to zero. apply_gates then resolves the modes for the open leg's
 * new gate state. */
static void cut_open_phases(plant_t *p)
{
    int k;
    plant_machine_cut(&p->mach, &p->x);
    plant_machine_rhs(&p->mach, &p->x, &p->d);
    for (k = 0; k < 3; ++k) {
        if (p->mach.mode[k] != LEG_ZERO) {
            const double i = p->d.i_ph[k];
            p->mach.mode[k] = i > 0.0 ? LEG_POS : (i < 0.0 ? LEG_NEG : LEG_ZERO);
        }
    }
}

/* New gate states at time t: ringing on hard edges and consistent conduction modes. */
static void apply_gates(plant_t *p, const int gate[3], double t)
{
    double u_before[3];
    int k, changed = 0;
    for (k = 0; k < 3; ++k) {
        changed |= gate[k] != p->mach.gate[k];
    }
    if (!changed) {
        return;
    }
    memcpy(u_before, p->d.u_leg, sizeof(u_before));
    for (k = 0; k < 3; ++k) {
        double lo, hi;
        plant_leg_band(p->mach.gate[k], p->mach.vdc, p->mach.vdrop, &lo, &hi);
        if (p->mach.mode[k] != LEG_ZERO && !(hi > lo)) {
            /* Under a degenerate band the mode label was not tracked: refresh it. */
            const double i = p->d.i_ph[k];
            p->mach.mode[k] = i > 0.0 ? LEG_POS : (i < 0.0 ? LEG_NEG : LEG_ZERO);
        }
        p->mach.gate[k] = gate[k];
    }
    plant_machine_resolve(&p->mach, &p->x);
    plant_machine_rhs(&p->mach, &p->x, &p->d);
    ring_on_jumps(p, u_before, t);
}

int plant_step(plant_t *p, const plant_pwm_cmd_t *cmd, plant_samples_t *samples,
               plant_truth_t *truth_at_start)
{
    plant_leg_schedule_t legs[3];
    int32_t ticks[3 * PLANT_MAX_LEG_EDGES + 1];
    int n_ticks = 0, k, j, pos[3] = {0, 0, 0};
    int gate[3];
    soc_queue_t q;
    const double dt_tick = 1.0 / PLANT_TBCLK_HZ;
    const int n_soc = cmd->n_soc > PLANT_MAX_SOC ? PLANT_MAX_SOC : cmd->n_soc;
    double t = 0.0;

    if (samples) {
        memset(samples, 0, sizeof(*samples));
        samples->period = p->next_period;
        samples->n_soc = (uint32_t)n_soc;
    }
    if (p->flt.dc_active || p->mach.vdc != p->flt.vdc_target) {
        dc_link_step(p);
    }
    plant_inverter_schedule(cmd, p->dead_ticks, &p->gmem, legs);
    if (p->flt.open_mask | p->flt.gate_off_mask) {
        int cut = 0;
        plant_faults_legs(&p->flt, legs);
        for (k = 0; k < 3; ++k) {
            if (((p->flt.open_mask >> k) & 1u) && p->mach.mode[k] != LEG_ZERO) {
                p->mach.mode[k] = LEG_ZERO; /* its current is cut */
                cut = 1;
            }
        }
        if (cut) {
            cut_open_phases(p);
        }
    }

    /* period start: gate states after the edges at tick 0 */
    for (k = 0; k < 3; ++k) {
        gate[k] = legs[k].state0;
    }
    plant_machine_rhs(&p->mach, &p->x, &p->d);
    apply_gates(p, gate, 0.0);
    if (truth_at_start) {
        fill_truth(p, 0.0, truth_at_start);
    }

    /* SOC instants in time order (stable for equal instants) */
    q.n = n_soc;
    q.next = 0;
    for (k = 0; k < n_soc; ++k) {
        const uint16_t tick = cmd->soc[k] < PLANT_PERIOD_TICKS ? cmd->soc[k] : PLANT_PERIOD_TICKS - 1;
        j = k - 1;
        while (j >= 0 && q.t[j] > tick * dt_tick) {
            q.t[j + 1] = q.t[j];
            q.index[j + 1] = q.index[j];
            --j;
        }
        q.t[j + 1] = tick * dt_tick;
        q.index[j + 1] = k;
    }
    while (q.next < q.n && q.t[q.next] <= 0.0) {
        double it[2], y[2];
        it[0] = p->d.i_ph[0];
        it[1] = p->d.i_ph[1];
        if (p->sen.tau > 0.0) {
            y[0] = p->sen.y[0];
            y[1] = p->sen.y[1];
        } else {
            y[0] = it[0];
            y[1] = it[1];
        }
        take_sample(p, q.index[q.next], 0.0, it, y, samples);
        q.next++;
    }

    /* all edge ticks of the period, sorted, each once */
    for (k = 0; k < 3; ++k) {
        for (j = 0; j < legs[k].n_edges; ++j) {
            ticks[n_ticks++] = legs[k].tick[j];
        }
    }
    for (k = 1; k < n_ticks; ++k) {
        const int32_t v = ticks[k];
        j = k - 1;
        while (j >= 0 && ticks[j] > v) {
            ticks[j + 1] = ticks[j];
            --j;
        }
        ticks[j + 1] = v;
    }
    for (k = 0, j = 0; k < n_ticks; ++k) {
        if (j == 0 || ticks[k] != ticks[j - 1]) {
            ticks[j++] = ticks[k];
        }
    }
    n_ticks = j;
    ticks[n_ticks++] = PLANT_PERIOD_TICKS;

    for (k = 0; k < n_ticks; ++k) {
        const double t_next = ticks[k] * dt_tick;
        integrate_interval(p, t, t_next, &q, samples);
        t = t_next;
        if (ticks[k] < PLANT_PERIOD_TICKS) {
            for (j = 0; j < 3; ++j) {
                while (pos[j] < legs[j].n_edges && legs[j].tick[pos[j]] <= ticks[k]) {
                    gate[j] = legs[j].state[pos[j]];
                    pos[j]++;
                }
            }
            apply_gates(p, gate, t);
        }
    }
    /* SOCs rounding onto the period end */
    while (q.next < q.n) {
        double it[2], y[2];
        it[0] = p->d.i_ph[0];
        it[1] = p->d.i_ph[1];
        y[0] = p->sen.tau > 0.0 ? p->sen.y[0] : it[0];
        y[1] = p->sen.tau > 0.0 ? p->sen.y[1] : it[1];
        take_sample(p, q.index[q.next], q.t[q.next], it, y, samples);
        q.next++;
    }

    /* next period */
    if (p->sen.tau == 0.0) {
        p->sen.y[0] = p->d.i_ph[0];
        p->sen.y[1] = p->d.i_ph[1];
    }
    plant_ring_next_period(&p->sen, &p->cfg, PLANT_TS_S);
    {
        const double turns = floor(p->x.theta / PLANT_TWO_PI);
        if (turns != 0.0) {
            p->x.theta -= turns * PLANT_TWO_PI;
            plant_machine_rhs(&p->mach, &p->x, &p->d);
        }
    }
    if (samples) {
        p->stats.adc_clipped += samples->clipped;
    }
    p->stats.periods++;
    p->next_period++;
    return 0;
}

size_t plant_sizeof_pwm_cmd(void)
{
    return sizeof(plant_pwm_cmd_t);
}
size_t plant_sizeof_samples(void)
{
    return sizeof(plant_samples_t);
}
size_t plant_sizeof_truth(void)
{
    return sizeof(plant_truth_t);
}
size_t plant_sizeof_stats(void)
{
    return sizeof(plant_stats_t);
}
