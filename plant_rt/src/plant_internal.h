/* Internal structures of plant_core, shared by its source files. */
#ifndef PLANT_INTERNAL_H
#define PLANT_INTERNAL_H

#include <stdint.h>

#include "plant_core.h"

#define PLANT_PI 3.14159265358979323846
#define PLANT_TWO_PI (2.0 * PLANT_PI)
#define PLANT_SQRT3 1.73205080756887729353

/* ------------------------------------------------------------------ magnetics.c */

/* Co-energy W'(id, iq) = Wd(id) + Wq(iq) + Wc(id, iq); psi = grad W', Linc = Hessian.
 *  Wd: incremental Ld(id) = ld_sat + ld_delta * sigma((knee - id)/width)  (logistic)
 *  Wq: psi_q = Lq0*iq/(1 + a*iq^2) for |iq| <= x1, then a C2 exponential extension to lq_inf
 *  Wc: -K * U(id) * V(iq), U = S*tanh(id/S), V = S^2*(1 - exp(-iq^2/(2 S^2)))  */
typedef struct plant_mag {
    double lambda_m;
    double ld_sat, ld_delta, ld_knee, ld_width, ld_sp0; /* sp0 = softplus(-knee/width) */
    double ld_inv_width;
    double lq0, lq_a, lq_x1, lq_inf;
    double lq_psi1, lq_l1, lq_s; /* extension: value, slope and decay rate at x1 */
    double cross_k, cross_s;
    /* Bounds used to start the inversion and in the config check. */
    double ld_nominal, lq_nominal;
    int linear; /* no saturation, no cross term: psi = (lambda_m + ld_sat id, lq0 iq) */
    double w4_bound; /* bound of W''''s components over all currents (plant_mag_init) */
} plant_mag_t;

/* Fills mag from the config. Returns 0 or -1 with a message (non-invertible map). */
int plant_mag_init(plant_mag_t *mag, const plant_config_t *cfg, char *err, size_t errlen);
/* psi = (psi_d, psi_q); linc = (Ldd, Lqq, Ldq); either output may be NULL. */
void plant_mag_flux(const plant_mag_t *mag, double id, double iq, double psi[2], double linc[3]);
/* Solves psi(i) = target. i holds the start on entry and the solution on exit; linc (may be
 * NULL) receives the incremental inductances at the last linearisation point. Returns the
 * iterations used, negated when the tolerance was not reached. */
int plant_mag_invert(const plant_mag_t *mag, double psi_d, double psi_q, double i[2],
                     double linc[3]);
/* A solution of the flux map: current, flux, incremental inductances (dd, qq, dq), their
 * inverse and the third derivatives of W' there (as plant_mag_flux3): where the next
 * inversion starts. */
typedef struct plant_mag_point {
    double i[2], psi[2], l[3], g[3], t[4];
} plant_mag_point_t;
/* The point at current (id, iq) (one forward evaluation). */
void plant_mag_point_at(const plant_mag_t *mag, double id, double iq, plant_mag_point_t *p);
/* Moves p to the solution at flux (psi_d, psi_q) (a second-order warm start from p, one
 * Newton step when that suffices, else the damped iteration). may_skip 1: an integration
 * stage, which takes the warm start unevaluated when its error is provably below 1e-12 A;
 * 2: a right-hand side with outputs, which does so only when the inductances' first-order
 * update is also within 1e-12 of them; 0: never.
 * Returns the Newton iterations (0: the closed form of linear magnetics, or a warm start
 * taken as it is), negated when the tolerance was not reached. */
int plant_mag_invert_from(const plant_mag_t *mag, double psi_d, double psi_q,
                          plant_mag_point_t *p, int may_skip);
/* The third derivatives of W' beside psi and linc: w3 = (dLdd/did, dLdd/diq = dLdq/did,
 * dLqq/did = dLdq/diq, dLqq/diq). */
void plant_mag_flux3(const plant_mag_t *mag, double id, double iq, double psi[2], double linc[3],
                     double w3[4]);

/* ------------------------------------------------------------------ inverter.c */

/* GATE_OPEN: the phase is disconnected from its leg (fault injection, OPEN_PHASE): whatever
 * the leg does, the phase carries no current and its terminal may take any voltage. */
enum plant_gate_state { GATE_NONE = 0, GATE_UPPER = 1, GATE_LOWER = 2, GATE_OPEN = 3 };
#define PLANT_OPEN_BAND_V 1e30
/* Conduction mode of a leg: current out of the leg (POS), into it (NEG), or zero (open or
 * clamped at zero inside the leg's voltage band). */
enum plant_leg_mode { LEG_POS = 0, LEG_NEG = 1, LEG_ZERO = 2 };

#define PLANT_MAX_LEG_EDGES 8

/* Gate bookkeeping that crosses period boundaries: when each gate's command went on. */
typedef struct plant_gate_memory {
    int cmd_on[6];          /* gate (2*leg + 0 upper, + 1 lower) commanded on at period end */
    int64_t cmd_since[6];   /* tick (relative to the next period's start) it went on */
} plant_gate_memory_t;

typedef struct plant_leg_schedule {
    int state0;                       /* leg state at tick 0 after tick-0 edges */
    int n_edges;                      /* edges at ticks in (0, PERIOD) */
    int32_t tick[PLANT_MAX_LEG_EDGES];
    int state[PLANT_MAX_LEG_EDGES];   /* state from that tick on */
} plant_leg_schedule_t;

/* Builds this period's leg schedules from cmd and updates memory for the next period. */
void plant_inverter_schedule(const plant_pwm_cmd_t *cmd, int32_t dead_ticks,
                             plant_gate_memory_t *memory, plant_leg_schedule_t legs[3]);
/* Voltage band of a leg at zero current: lo = voltage with positive current, hi = with
 * negative current (hi >= lo); legs clamp at zero current anywhere in [lo, hi]. */
static inline void plant_leg_band(int gate, double vdc, double vdrop, double *lo, double *hi)
{
    switch (gate) {
    case GATE_UPPER:
        *lo = vdc - vdrop;
        *hi = vdc + vdrop;
        break;
    case GATE_LOWER:
        *lo = -vdrop;
        *hi = vdrop;
        break;
    case GATE_OPEN:
        *lo = -PLANT_OPEN_BAND_V;
        *hi = PLANT_OPEN_BAND_V;
        break;
    default:
        *lo = -vdrop;
        *hi = vdc + vdrop;
        break;
    }
}

/* Terminal voltage of a leg in conduction mode POS (lo of the band) or NEG (hi). */
static inline double plant_leg_voltage(int gate, int mode, double vdc, double vdrop)
{
    double lo, hi;
    plant_leg_band(gate, vdc, vdrop, &lo, &hi);
    return mode == LEG_NEG ? hi : lo;
}

/* ------------------------------------------------------------------ faults.c */

/* One fault slot of FAULT_CMD (protocols/bench.dbc): kind and targets as its enums. */
typedef struct plant_fault_slot {
    int kind; /* HIL_BENCH_FAULT_CMD_KIND_*_CHOICE; NONE: the slot is free */
    int channel, phase, gate;
    double value;
    uint32_t periods;
} plant_fault_slot_t;

/* The physical faults in force, from the slots (plant_faults_set). Channels 0 ia, 1 ib,
 * 2 vdc; phases 0..2; gate bit 2x the upper and 2x+1 the lower gate of phase x. */
typedef struct plant_faults {
    plant_fault_slot_t slot[PLANT_FAULT_SLOTS];
    int adc_active;           /* some ADC channel or sensor fault is in force */
    double adc_gain[3], adc_offset[3], adc_clip[3];
    int stuck[3];
    int32_t stuck_code[3];
    int sensor_lost[2];
    unsigned open_mask;       /* bit x: phase x disconnected */
    unsigned gate_off_mask;   /* bit 2x / 2x+1: that gate never turns on */
    int dc_active;            /* a DC_LINK slot is in force */
    double vdc_target;        /* V: the DC link the slots ask for (the profile's without one) */
    uint32_t vdc_ramp;        /* periods to get there (0: at once) */
} plant_faults_t;

void plant_faults_init(plant_faults_t *f, double vdc_nominal);
/* Sets a slot (see plant_set_fault) and recomputes what is in force. */
int plant_faults_set(plant_faults_t *f, double vdc_nominal, int slot, int kind, int channel,
                     int phase, int gate, double value, uint32_t periods, char *err,
                     size_t errlen);
/* The analog input of ADC channel ch under the channel faults (gain, offset, saturation). */
double plant_faults_adc_in(const plant_faults_t *f, int ch, double x);
/* Rewrites the legs' gate schedules: disconnected phases (GATE_OPEN for the whole period),
 * gates that stay off. */
void plant_faults_legs(const plant_faults_t *f, plant_leg_schedule_t legs[3]);

/* ------------------------------------------------------------------ sensors.c */

typedef struct plant_rng {
    uint64_t s[4];
    int has_spare;
    double spare;
} plant_rng_t;

void plant_rng_seed(plant_rng_t *rng, uint64_t seed);
double plant_rng_gauss(plant_rng_t *rng);

#define PLANT_MAX_RINGS 48
typedef struct plant_ring {
    double t;    /* edge instant, seconds relative to the current period start */
    int leg;
    double sign; /* +1 rising leg voltage, -1 falling */
} plant_ring_t;

typedef struct plant_sensors {
    double tau;        /* filter time constant, 0 = none */
    double y[2];       /* filter states, channels a and b */
    plant_ring_t ring[PLANT_MAX_RINGS];
    int n_ring;
    plant_rng_t rng;
} plant_sensors_t;

/* Advances the filter states over [0, h] given current values and slopes at both ends;
 * with s in (0, h] evaluates the filter output at s without advancing (out[2]). */
void plant_filter_eval(const plant_sensors_t *sen, const double i0[2], const double di0[2],
                       const double i1[2], const double di1[2], double h, double s,
                       double out[2]);
void plant_ring_add(plant_sensors_t *sen, double t, int leg, double sign);
/* Ringing current on channels a and b at time t (relative to the period start). */
void plant_ring_eval(const plant_sensors_t *sen, const plant_config_t *cfg, double t,
                     double out[2]);
/* Drops sources that have decayed and shifts times by -ts for the next period. */
void plant_ring_next_period(plant_sensors_t *sen, const plant_config_t *cfg, double ts);

/* ------------------------------------------------------------------ machine.c */

typedef struct plant_state {
    double psi_d, psi_q;
    double theta;   /* electrical angle, not wrapped within a period */
    double omega_m; /* mechanical speed */
} plant_state_t;

/* Everything one evaluation of the right-hand side yields. */
typedef struct plant_deriv {
    double id, iq;
    double ldd, lqq, ldq;    /* incremental inductances */
    double gdd, gqq, gdq;    /* their inverse */
    double cph[3][2];        /* unit vectors of the phase axes in dq: i_x = cph[x] . i_dq */
    double i_ph[3], di_ph[3];
    double u_leg[3];         /* leg voltages (to DC-) incl. the solved one of an open leg */
    double u_ph[3];          /* phase voltages to the star point */
    double dpsi_d, dpsi_q, dtheta, domega;
    double te, tl;           /* motor torque, load-machine torque */
    double monitor[3];       /* event functions, >= 0 while the conduction modes hold */
    int n_monitor;
} plant_deriv_t;

/* What the machine right-hand side needs beyond the state. */
typedef struct plant_machine {
    const plant_config_t *cfg;
    const plant_mag_t *mag;
    double rs, pp, lambda_m, vdc, vdrop;
    double j_total, b_total;
    int gate[3];      /* leg gate states of the current interval */
    int mode[3];      /* leg conduction modes */
    int load_mode;
    double load_torque, load_speed_rad, load_k;
    plant_mag_point_t mp; /* the last solution of the flux map: the next one starts there */
    double psi_zero[2];  /* flux at zero current */
    /* sin and cos of the last angle evaluated (RK4 stages often repeat an angle exactly) */
    double sc_theta, sc_sin, sc_cos;
    int sc_valid;
    double sc_base, sc_base_sin, sc_base_cos; /* last angle given to libm (phase_axes) */
    int sc_base_valid;
    /* leg voltages of the gates and modes in force with every leg conducting, and their
     * alpha-beta vector (u[3], u[4]), for those gates, modes and DC link (machine.c) */
    double legs_u[5];
    int legs_gate[3], legs_mode[3], legs_valid;
    double legs_vdc, legs_vdrop;
    plant_stats_t *stats;
} plant_machine_t;

static inline int plant_machine_zero_count(const plant_machine_t *m)
{
    return (m->mode[0] == LEG_ZERO) + (m->mode[1] == LEG_ZERO) + (m->mode[2] == LEG_ZERO);
}
void plant_machine_rhs(plant_machine_t *m, const plant_state_t *x, plant_deriv_t *d);
/* The state derivatives alone (an integration stage): dpsi_d, dpsi_q, dtheta, domega, with
 * the currents, inductances and torques; not the per-phase outputs and event functions. */
void plant_machine_stage(plant_machine_t *m, const plant_state_t *x, plant_deriv_t *d);
/* Removes integration drift of open phases (their currents exactly zero). */
void plant_machine_project(plant_machine_t *m, plant_state_t *x);
/* The cut of a phase that is disconnected (its mode just set to LEG_ZERO) while it carries
 * current: its current becomes zero and the flux linkage of the loop through the two
 * remaining phases stays; with no loop left every current becomes zero. */
void plant_machine_cut(plant_machine_t *m, plant_state_t *x);
/* Makes the conduction modes consistent at the present state (may adjust x to put an
 * open phase's current exactly at zero). Returns the number of mode changes made. */
int plant_machine_resolve(plant_machine_t *m, plant_state_t *x);
/* Sets the modes from the phase currents of state x (used after plant_set_state). */
void plant_machine_modes_from_currents(plant_machine_t *m, plant_state_t *x);

#endif
