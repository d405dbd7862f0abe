/* plant_core: switching-level emulator of the IPMSM bench (machine, inverter, sensors and
 * ADC, shaft, load machine, torque sensor), one PWM period at a time.
 *
 * Model summary (details in the source files and plant_rt/README.md):
 *  - Machine: flux linkages (psi_d, psi_q) in the rotor frame are the electrical state; the
 *    currents follow from a magnetically consistent flux map (gradient of a co-energy),
 *    inverted by a globally convergent damped Newton iteration. Isolated neutral: the
 *    zero sequence carries no current, so the dq form equals the abc model of the paper.
 *  - Inverter: three legs with dead time (every off->on gate transition delayed), a single
 *    forward drop for transistor and diode (v = Vdc*s - Vdrop*sign(i)), freewheeling
 *    diodes and open phases (a leg with zero current stays open until a diode is forward
 *    biased), stiff DC link.
 *  - Every period is split at every gate edge; the ODE is integrated with RK4 substeps
 *    between edges, with root finding for phase-current zero crossings and diode
 *    turn-on instants. ADC samples are taken at the exact SOC instants.
 *
 * No global mutable state: all state lives in plant_t. Not thread-safe per instance.
 */
#ifndef PLANT_CORE_H
#define PLANT_CORE_H

#include <stddef.h>
#include <stdint.h>

#include "hil_bench.h" /* LOAD_CMD.mode: HIL_BENCH_LOAD_CMD_MODE_*_CHOICE (protocols/bench.dbc) */
#include "hil_wire.h"  /* the time base of protocols/vio.dbc (generated) */

#ifdef __cplusplus
extern "C" {
#endif

/* Time base of the virtual ePWM (docs/interfaces.md; defined in protocols/vio.dbc). */
#define PLANT_TBCLK_HZ HIL_TBCLK_HZ
#define PLANT_TBPRD HIL_TBPRD
#define PLANT_PERIOD_TICKS (2 * PLANT_TBPRD)
#define PLANT_TS_S (PLANT_PERIOD_TICKS / PLANT_TBCLK_HZ)
#define PLANT_MAX_SOC HIL_MAX_SOC

/* ---------------------------------------------------------------- configuration */

/* All fields in SI units. Every field is a key `section.key` of the profile TOML files;
 * the files in plant_rt/profiles document each one. */
typedef struct plant_config {
    struct {
        double rs_ohm;      /* phase resistance */
        double lambda_m_wb; /* PM flux linkage (amplitude, per phase) */
        double pole_pairs;  /* integer */
    } machine;
    struct {
        double ld_h;          /* incremental Ld at id = 0 */
        double ld_sat_h;      /* incremental Ld deep in magnet-side saturation (id -> +inf) */
        double ld_knee_a;     /* id where the d-axis saturation is half-way */
        double ld_width_a;    /* width of that transition */
        double lq_h;          /* Lq0: Lq at iq = 0 */
        double lq_sat_per_a2; /* a in psi_q = Lq0*iq/(1 + a*iq^2) */
        double lq_ext_from_a; /* |iq| beyond which the smooth extension takes over */
        double lq_inf_h;      /* incremental Lq approached for |iq| -> inf */
        double ldq_ref_h;     /* cross-saturation: d psi_d / d iq at (id = 0, iq = cross_ref_a) */
        double cross_ref_a;
        double cross_scale_a; /* current scale of the bounded cross-saturation term */
    } magnetics;
    struct {
        double vdc_v;
        double dead_time_s;   /* rounded to whole TBCLK ticks (the dead-band counts ticks) */
        double device_drop_v; /* forward drop of transistor and diode */
    } inverter;
    struct {
        double bandwidth_hz; /* first-order current-sensor bandwidth; 0 = infinite */
        double gain_a, gain_b;
        double offset_a_a, offset_b_a;
        double noise_rms_a;  /* Gaussian, per sample and channel */
        double ring_amp_a;   /* envelope amplitude of the ringing after a leg-voltage edge */
        double ring_freq_hz;
        double ring_tau_s;
        double ring_return_fraction; /* share of the ringing current returning via the other two phases */
        double vdc_noise_rms_v;
        double seed; /* PRNG seed (integer) */
    } sensors;
    struct {
        double bits;    /* current channels, offset binary */
        double range_a; /* +-range */
        double vdc_bits;
        double vdc_range_v; /* 0 .. range */
    } adc;
    struct {
        double j_kgm2; /* motor rotor inertia */
        double b_nms;  /* motor viscous friction, N*m*s/rad */
        double j_load_kgm2; /* load-machine inertia (beyond the torque sensor) */
        double b_load_nms;  /* load-machine friction (beyond the torque sensor) */
    } shaft;
    struct {
        double mode; /* LOAD_CMD.mode: HIL_BENCH_LOAD_CMD_MODE_*_CHOICE */
        double torque_nm;
        double speed_rpm;
        double k_speed_nms; /* N*m*s/rad */
    } load;
    struct {
        double theta_e_deg;
        double speed_rpm;
    } initial;
    struct {
        double max_step_s; /* RK4 substep ceiling */
    } solver;
} plant_config_t;

/* Built-in defaults: the nominal machine, ideal inverter and sensors. */
void plant_config_defaults(plant_config_t *cfg);
/* Loads a profile file over cfg. Returns 0, or -1 with "FILE:LINE: field: reason" in err. */
int plant_config_load(plant_config_t *cfg, const char *path, char *err, size_t errlen);
/* Applies one "section.key=value". Returns 0, or -1 with a message naming the field. */
int plant_config_set(plant_config_t *cfg, const char *assignment, char *err, size_t errlen);
/* Cross-field checks (magnetics invertible, dead time below half a period, ...).
 * Returns 0 or -1 with a message. plant_new calls it too. */
int plant_config_check(const plant_config_t *cfg, char *err, size_t errlen);
/* Number of configuration keys and the i-th "section.key" (for --help and tests). */
/* sizeof(plant_config_t), for callers through a foreign-function interface (the rig checks a
 * scenario's overrides with this very loader: one schema for C and Python). */
size_t plant_config_size(void);
int plant_config_key_count(void);
const char *plant_config_key_name(int index);

/* ---------------------------------------------------------------- commands and results */

/* One period's PWM command, as carried by VIO_PWM (docs/interfaces.md). */
typedef struct plant_pwm_cmd {
    uint32_t period;
    uint16_t cmp_up[3];
    uint16_t cmp_dn[3];
    uint16_t soc[PLANT_MAX_SOC];
    uint8_t n_soc;
    uint8_t gate_enable;
} plant_pwm_cmd_t;

/* What the ADC returns for one period, plus the analog truth behind each conversion. */
typedef struct plant_samples {
    uint32_t period;
    uint32_t n_soc;
    int32_t ia_code[PLANT_MAX_SOC];
    int32_t ib_code[PLANT_MAX_SOC];
    int32_t vdc_code[PLANT_MAX_SOC];
    double ia_true[PLANT_MAX_SOC];   /* exact phase currents at the SOC instant */
    double ib_true[PLANT_MAX_SOC];
    double ia_sensor[PLANT_MAX_SOC]; /* sensor output (gain, offset, bandwidth), no ringing/noise */
    double ib_sensor[PLANT_MAX_SOC];
    double ia_adc_in[PLANT_MAX_SOC]; /* analog ADC input: sensor + ringing + noise */
    double ib_adc_in[PLANT_MAX_SOC];
    uint32_t clipped; /* conversions clipped at the ADC range in this period */
} plant_samples_t;

/* Truth at one instant (the start of a period). Phase voltages are to the star point. */
typedef struct plant_truth {
    uint32_t period;
    double t_s;
    double theta_e; /* [0, 2*pi) */
    double omega_m; /* rad/s */
    double id, iq, te, tl, t_shaft;
    double ia, ib, ic, vdc;
    double psi_d, psi_q;
    double ua, ub, uc;
    double ld_inc, lq_inc, ldq_inc; /* d psi / d i */
    double ld_app, lq_app;          /* (psi_d - lambda_m)/id, psi_q/iq */
    double lambda_m, rs;
} plant_truth_t;

typedef struct plant_stats {
    uint64_t periods;
    uint64_t adc_clipped;
    uint64_t rk_steps;
    uint64_t rhs_evals;
    uint64_t conduction_events; /* zero crossings and diode turn-ons located inside intervals */
    uint64_t newton_iterations;
    uint64_t newton_failures;   /* never expected; counted, the best iterate is used */
    uint64_t mode_loops_cut;    /* inconsistent conduction-mode resolutions cut short */
} plant_stats_t;

typedef struct plant plant_t;

/* Creates a plant from a checked configuration. NULL with a message on a bad config. */
plant_t *plant_new(const plant_config_t *cfg, char *err, size_t errlen);
/* Convenience for ctypes: profile file (may be NULL for the defaults) plus n_sets
 * "section.key=value" overrides. */
plant_t *plant_open(const char *profile_path, const char *const *sets, int n_sets, char *err,
                    size_t errlen);
void plant_free(plant_t *plant);
const plant_config_t *plant_config(const plant_t *plant);

/* Simulates period plant->next_period with cmd (its period field is not checked here: use
 * plant_pwm_validate). Fills samples (may be NULL) and the truth at the period's start
 * (may be NULL). Returns 0. */
int plant_step(plant_t *plant, const plant_pwm_cmd_t *cmd, plant_samples_t *samples,
               plant_truth_t *truth_at_start);
/* Truth at the current instant (start of the next period), with the gates of the last
 * period's end. */
void plant_truth_now(plant_t *plant, plant_truth_t *truth);
uint32_t plant_next_period(const plant_t *plant);
void plant_get_stats(const plant_t *plant, plant_stats_t *stats);

/* Sets the mechanical and electrical state (currents give the fluxes via the flux map). */
void plant_set_state(plant_t *plant, double theta_e, double omega_m, double id, double iq);
/* Load machine command (LOAD_CMD semantics). */
void plant_set_load(plant_t *plant, int mode, double torque_nm, double speed_rpm,
                    double k_speed_nms);

/* ---------------------------------------------------------------- fault injection */

/* Fault slots (FAULT_CMD.slot in protocols/bench.dbc; a C test holds the DBC's range to it). */
#define PLANT_FAULT_SLOTS 16

/* A physical fault in slot 'slot' from the next simulated period on (scenario [[faults]],
 * FAULT_CMD). kind, channel, phase and gate are FAULT_CMD's enums (generated from
 * protocols/bench.dbc: HIL_BENCH_FAULT_CMD_KIND_*_CHOICE, ...): ADC_OFFSET (value A, or V on
 * the VDC channel, added to the ADC input), ADC_GAIN (the input times value), ADC_STUCK (the
 * converter returns code value), ADC_SATURATION (the input clipped to +-value), SENSOR_LOSS
 * (the current sensor of channel IA or IB outputs 0 A), OPEN_PHASE (phase disconnected: its
 * current is cut at once, the flux linkage of the other two phases' loop kept), GATE_OFF (that gate of phase never turns on), DC_LINK (the DC link
 * moves to value V, linearly over 'periods' periods). NONE, or a frame kind (those act on the
 * wires, plant_link.h), frees the slot. Slots add up in slot order (offsets add, gains
 * multiply, the lowest saturation level and the last stuck code or DC link win). Returns 0,
 * or -1 with a message for a slot, kind, target or value out of range. */
int plant_set_fault(plant_t *plant, int slot, int kind, int channel, int phase, int gate,
                    double value, uint32_t periods, char *err, size_t errlen);

/* The flux map of the configured machine: psi[2] = (psi_d, psi_q), linc[3] = (Ldd, Lqq, Ldq). */
void plant_flux_map(const plant_t *plant, double id, double iq, double psi[2], double linc[3]);
/* Inverse flux map. Returns the Newton iterations used (negative if not converged). */
int plant_current_from_flux(const plant_t *plant, double psi_d, double psi_q, double i[2]);

/* ADC transfer (docs/interfaces.md); *clipped set to 1 when clamped. */
int32_t plant_adc_current_code(double i_a, int bits, double range_a, int *clipped);
int32_t plant_adc_vdc_code(double vdc_v, int bits, double range_v, int *clipped);

/* Size checks for ctypes mirrors. */
size_t plant_sizeof_pwm_cmd(void);
size_t plant_sizeof_samples(void);
size_t plant_sizeof_truth(void);
size_t plant_sizeof_stats(void);

#ifdef __cplusplus
}
#endif
#endif
