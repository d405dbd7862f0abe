/* fw_core_state.h - complete definition of the core object (so a HAL can allocate it
 * statically) and of the module states it is made of. Only the core's own sources look
 * inside; the HAL treats fw_core_t as opaque storage.
 */
#ifndef FW_CORE_STATE_H
#define FW_CORE_STATE_H

#include "fw_types.h"
#include "fw_math.h"

#define FW_PARAM_MAX 128 /* capacity of the value array; gen_params.py enforces it */
#define FW_MAX_SEG 8     /* switching states per period (7 at most) + sentinel */
#define FW_LQ_BINS 16    /* incremental-Lq curve bins over 0..i_max */

/* measured windows of a period */
#define FW_WIN_ZERO 0 /* V7 across the period centre */
#define FW_WIN_ODD 1  /* the sector's one-phase-on vector (V1, V3, V5) */
#define FW_WIN_EVEN 2 /* the sector's two-phase-on vector (V2, V4, V6) */

#define FW_LAYOUT_OFF 0
#define FW_LAYOUT_DIRECT 1  /* Vo | V7 | Ve, long vectors split around the centre */
#define FW_LAYOUT_STRETCH 2 /* compensation (opposite vectors) | V7 | stretched Ve, Vo */

typedef struct {
    int16_t measured;   /* 1 when this state is measured in the period */
    int16_t vec;        /* vector number 1..6 (active) or 7 (zero) */
    uint16_t start;     /* state interval [start, end) in period ticks */
    uint16_t end;
    int16_t soc_first;  /* index of its first SOC in soc[] */
    int16_t soc_count;
} fw_window_t;

/* One period's switching pattern and sampling plan. */
typedef struct {
    int16_t layout;                 /* FW_LAYOUT_* */
    int16_t sector;                 /* 1..6, 0 when the gates are off */
    int16_t vec_odd, vec_even;      /* vector numbers of the sector */
    int32_t t_odd, t_even;          /* net on-time of each active vector, ticks */
    int32_t c_odd, c_even;          /* compensation time (opposite vectors), ticks */
    uint16_t on[3], off[3];         /* phase a, b, c upper gate on during [on, off) */
    uint16_t cmp_up[3], cmp_dn[3];
    int16_t n_seg;                  /* switching states in time order */
    uint16_t seg_t[FW_MAX_SEG + 1]; /* segment i: [seg_t[i], seg_t[i+1]) */
    int16_t seg_state[FW_MAX_SEG];  /* bit0 = a, bit1 = b, bit2 = c */
    fw_window_t win[3];
    int16_t n_soc;
    uint16_t soc[16];
    fw_cplx_t v_applied;            /* average alpha-beta voltage of the pattern (ideal inverter), V */
    real_t vdc;                     /* DC-link voltage the pattern was computed for */
    int16_t clipped;                /* the reference was outside the measurable hexagon */
    int16_t n_soc_windows;          /* SOCs of the measured windows (the rest: current only) */
    int16_t mirror;                 /* 1: the B layout of an A/B pair (svpwm.c) */
    /* volt-second dipole about the period centre, sum of v_seg * len * (H - t_mid) / P, V*s:
     * the period-mean current exceeds the mean of its start and end currents by Gamma * it */
    fw_cplx_t dipole;
} fw_plan_t;

/* Modulator state carried from one period to the next. */
typedef struct {
    fw_cplx_t carry; /* volt-ticks the patterns still owe the reference */
    int16_t sector;  /* sector of the last pattern, 0: none (gates were off) */
} fw_mod_t;

typedef struct {
    uint16_t tmin;      /* ticks */
    uint16_t soc_on;    /* ticks */
    uint16_t soc_off;   /* ticks */
    int16_t n_per_state;
    int16_t stretch;
    uint16_t sector_hyst; /* ticks: an A period keeps the last sector while its request lies
                             at most this far outside it (the carry makes up the rest) */
    int16_t pairs;        /* 1: A/B pairs of mirrored layouts whose dipoles cancel */
    /* 1: whole voltage range (no Tmin reserve): references beyond the hexagon are projected
     * onto it (minimum distance), windows are measured only where they fit, and current
     * samples are added in the other switching states (FULL modulation, svpwm.c) */
    int16_t full_range;
    /* 1: a reference beyond the hexagon leaves its deficit in the carry (a measurement period
     * inside FULL modulation, made up by the next periods); 0: a clipped reference is dropped */
    int16_t carry_clipped;
} fw_pwm_cfg_t;

#define FW_OM_N 16 /* overmodulation table: reference magnitudes and their fundamentals */

/* Least-squares position estimate of one period (docs/estimator.md §3). */
typedef struct {
    int16_t n_active;   /* active vectors used: 0, 1 or 2 */
    int16_t ok;         /* plausible (residual, saliency) */
    real_t theta_raw;   /* 2*theta/2 in (-pi/2, pi/2], theta modulo pi */
    real_t gamma0;      /* 1/H */
    real_t gamma1;      /* |g|, 1/H */
    fw_cplx_t g;        /* Gamma1 * exp(j*2*theta) at t_ref */
    real_t residual;    /* 1/H, signed 4th equation */
    real_t t_ref;       /* s, time the estimate is valid at (same origin as the inputs) */
} fw_est_out_t;

/* Position tracker: mechanical observer on theta with branch selection (position_tracker.c). */
typedef struct {
    int16_t init;
    real_t theta;       /* rad at the reference instant */
    real_t omega;       /* electrical rad/s */
    real_t a_ff;        /* electrical rad/s^2 from the torque model (input) */
    real_t a_d;         /* electrical rad/s^2, estimated disturbance (load, friction, model) */
    real_t a_d_lo;      /* compensation term of the a_d sum */
    real_t theta_unwrapped;
    int32_t age_ticks;  /* ticks from the reference instant to the start of the current period */
    real_t l1, l2, l3;  /* gains per update at the present natural frequency wn */
    real_t wn, wn_hi, wn_lo, zeta; /* rad/s: present, highest, floor */
    real_t speed_ratio; /* wn per electrical rad/s of speed (between wn_lo and wn_hi) */
    real_t boost_sigma; /* innovation-mean threshold in RMS of the innovation (0: never) */
    int32_t conv_ticks; /* periods since the last reset or detected disturbance */
    uint32_t boosts;    /* detected disturbances (diagnostics) */
    real_t e_mean, e_var; /* innovation mean and mean square */
    real_t noise_ref2;  /* rad^2: raw-estimate noise variance the floor wn_lo is meant for (0: fixed) */
    real_t n_var;       /* rad^2: the raw estimate's noise variance, from successive innovations */
    real_t floor_scale; /* wn_lo's share at the present noise: cbrt(sqrt(noise_ref2 / n_var)), <= 1 */
    real_t last_err;    /* rad */
    uint16_t stamp;     /* tick of the reference instant within the period of the last update */
} fw_tracker_t;

typedef struct {
    real_t kp, ki, x;   /* gains and integrator (output units) */
} fw_pi_t;

typedef struct {
    real_t gamma0_f, gamma1_f; /* filtered inverse inductances, 1/H */
    real_t gamma0_fast;        /* fast-filtered Gamma0 for the single-vector fallback, 1/H */
    real_t iq_fast;            /* q current at the gamma0_fast updates, A */
    real_t ld_inc, lq_inc;     /* H */
    real_t lq_bin[FW_LQ_BINS]; /* 1/Lq_inc vs |iq|, 1/H */
    real_t lq_bin_x[FW_LQ_BINS]; /* mean |iq| of the samples in the bin, A */
    int16_t lq_bin_seen[FW_LQ_BINS]; /* updates in the bin, saturating at 30000 */
    real_t bin_width;          /* A */
    real_t lq_app, ld_app;     /* H, apparent values at the present operating point */
    int32_t n_updates;
    /* cross-saturation identification: the turn of the saliency axes against the flux
     * angle, mean over ~0.2 s at the present current (param_estimator.c) */
    fw_cplx_t xs_g;              /* mean of |g| exp(j2 (flux angle - slope angle)): the turn is
                                    half its argument (xsat_turn_deg, params.c) */
    real_t xs_iq;                /* A, the q current the mean belongs to */
    int32_t xs_n;
} fw_param_est_t;

typedef struct {
    fw_cplx_t psi_f;     /* low-passed stator flux, V*s */
    fw_cplx_t psi;       /* compensated stator flux at the end of the period, V*s */
    real_t lambda_f;     /* filtered PM flux estimate, Wb */
    real_t lambda_inst;
    real_t lq_app_flux;  /* psi_q / iq when measurable, H */
    int16_t active;
    int16_t neg_count;   /* consecutive updates with lambda_d < -lambda_nom / 2 (polarity lost) */
    real_t settle_tc;    /* filter time constants since the estimator became active */
    int32_t n_valid;     /* plausible lambda updates since the reset */
} fw_flux_t;

/* The back-EMF test's window (polarity_detect.c): the angle the back-EMF says the rotor
 * turned against the raw slope angle. The start-up test runs one; the polarity watch in RUN
 * two, staggered. */
typedef struct {
    int16_t on;                 /* 1 once the window has started */
    fw_cplx_t psi_i;            /* the current's own flux L(theta_hat) i at the last period end, V*s */
    real_t phi;                 /* sum of e_q Ts / lambda_m: +-(theta - theta0), rad */
    real_t phi_min, phi_max;
    real_t phi_tol;             /* the most an rs error could have added to phi (the watch), rad */
    real_t raw;                 /* raw slope angle continued across periods (modulo pi), rad */
    real_t raw0;
    real_t raw_prev;            /* the last raw slope angle on the tracker's branch (the watch) */
    int32_t m;                  /* periods with a raw estimate: sums of phi, phi^2, raw, phi raw, raw^2 */
    real_t sp, spp, sr, spr, srr;
    real_t slope, slope_se;     /* raw against phi: +1 north pole, -1 south pole */
    /* the q back-EMF of each period in the tracked frame, +-lambda_m omega: its straight line
     * over the window's periods n = 1, 2, ... (sums of 1, n, n^2, e, n e) */
    real_t s0, s1, s2, sy, sny;
} fw_emf_window_t;

/* The polarity watch in RUN (polarity_detect.c): the back-EMF test over two windows of
 * pol_watch_window_ms, started half a window apart, while the speed is below
 * pol_loss_min_rpm. */
typedef struct {
    fw_emf_window_t win[2];
    int32_t age[2];             /* periods since each window started */
    int16_t started;            /* 0 until both windows run (the second starts half a window later) */
    int16_t q_on;               /* 1 once psi_i holds the last period's */
    fw_cplx_t psi_i;            /* the current's own flux L(theta_hat) i at the last period end, V*s */
    /* the q back-EMF's exponentially weighted straight line against time (this period 0, the
     * one before -1, ...): sums of w, w t, w t^2, w e, w t e */
    real_t ew_s0, ew_s1, ew_s2, ew_sy, ew_sty;
    uint16_t flips_seen;        /* the core's polarity_flips when the windows last started */
    uint16_t decided_north;     /* windows that found the north pole since the start (tests) */
} fw_polarity_watch_t;

typedef struct {
    int16_t phase;       /* polarity sub-state */
    int32_t count;       /* periods in the sub-state */
    int32_t periods;     /* periods since the start */
    real_t id_pos, id_neg;      /* mean d current measured at the +d and -d bias, A */
    real_t l_pos, l_neg;        /* incremental Ld measured at the +d and -d bias, H */
    real_t ratio;               /* (l_neg - l_pos) / mean: > 0 when +d_hat is the magnet side */
    real_t ratio_sigma;         /* standard error of ratio from the per-period scatter */
    real_t g_ref;               /* 1/H, reference the per-period 1/Ld_inc are summed from */
    real_t s1[2], s2[2];        /* [+d, -d]: sums of (1/Ld_inc - g_ref) and of its square */
    real_t si[2];               /* [+d, -d]: sums of the measured d current, A */
    int32_t n[2];               /* [+d, -d]: periods summed */
    int16_t pairs;              /* +d/-d pairs of holds done */
    /* back-EMF test (polarity_detect.c) */
    int16_t emf_wait;           /* periods tracked before the window starts */
    fw_emf_window_t emf;
    /* the catch (polarity_detect.c): a shaft turning fast at the enable */
    int16_t catch_on;           /* 1 while the catch measures */
    int16_t catch_n;            /* back-EMF vectors measured */
    int16_t catch_k;            /* periods since the enable */
    int16_t catch_rn;           /* raw angles among them */
    real_t catch_rlast;         /* the last, continued modulo pi, rad */
    real_t catch_rj, catch_rjj, catch_rt, catch_rjt, catch_rtt; /* sums of k, k^2, r, k r, r^2 */
    real_t catch_wax;           /* the axes' turn per period last used, rad */
    fw_cplx_t catch_i;          /* current at the end of the last period, A */
    /* the vectors with the saliency axes turning forwards [0] and backwards [1] */
    struct {
        fw_cplx_t e;            /* the last one (alpha-beta, mean over its period), V */
        fw_cplx_t e2;           /* the one before it */
        real_t d2;              /* sum of |e_k - e_k-2|^2, V^2 */
        real_t ang;             /* its angle continued across periods, rad */
        real_t s1, s2, sp, skp, spp; /* sums of k, k^2, a, k a, a^2 */
        real_t mag;             /* sum of |e_k|, V */
    } catch_h[2];
    real_t catch_w;             /* electrical rad/s, the vector's turn so far */
    real_t catch_omega;         /* electrical rad/s (decided) */
    real_t catch_theta;         /* rad, the magnet's angle at the end of the deciding period */
    real_t theta_start;  /* unwrapped angle at the start of the motion check */
    real_t moved;        /* rad */
    int16_t method_used; /* 1 saturation, 2 motion, 3 back-EMF */
    int16_t flipped;
    int16_t result;      /* 0 running, 1 done, -1 failed */
} fw_polarity_t;

struct fw_core {
    /* parameters (values; metadata in the generated table) */
    real_t p[FW_PARAM_MAX];
    /* derived from parameters */
    fw_pwm_cfg_t pwm_cfg;
    real_t om_ref[FW_OM_N], om_fund[FW_OM_N]; /* overmodulation: |v_ref| -> fundamental, in
                                                 units of Vdc/sqrt3 (fw_svpwm_om_init) */
    real_t adc_i_lsb, adc_v_lsb; /* A and V per code */
    int32_t adc_half;            /* 2^(N-1) */
    uint32_t cmd_timeout_ticks;
    real_t speed_alpha;          /* first-order speed filter coefficient per ISR */

    /* state machine */
    int16_t state;
    uint16_t fault_code;
    fw_cmd_t cmd;
    int16_t cmd_status;
    int16_t start_request;       /* enable rising edge seen */
    int16_t reset_request;       /* fault_reset rising edge seen */
    uint32_t ticks_since_cmd;
    int16_t have_cmd;

    /* period bookkeeping */
    int16_t have_period;
    uint32_t period;             /* ADC period processed last */
    uint32_t isr_count;
    int16_t adc_loss_run;
    uint32_t adc_loss_count;
    uint16_t isr_overruns;
    fw_plan_t plan_cur;          /* pattern applied in the period of the ADC data being processed */
    fw_plan_t plan_next;         /* pattern computed for the next period */
    uint16_t prev_on[3], prev_off[3]; /* edges of the period before plan_cur (dead-time count) */
    int16_t pwm_valid;
    fw_pwm_t pwm_last;
    fw_mod_t mod;                /* modulator state (carry, last sector) */

    /* measurement of the last period */
    real_t vdc;
    real_t vdc_f;
    fw_cplx_t i_avg, i_end;      /* alpha-beta currents: period mean and at the period end */
    fw_cplx_t v_meas;            /* period-mean voltage: pattern plus inverter error, V */
    real_t i_peak;               /* largest phase-current magnitude of the period */
    fw_cplx_t slope[3];          /* A/s per window */
    real_t slope_t[3];           /* s, mean sample time per window from the period start */
    fw_cplx_t i_win[3];          /* A, current at slope_t */
    int16_t slope_ok[3];

    /* estimation */
    fw_est_out_t est;
    fw_tracker_t trk;
    fw_param_est_t pe;
    fw_flux_t flux;
    int16_t est_valid;
    int16_t est_fail_run;
    int16_t sensor_bad;          /* leaky count of implausible periods (current sensors) */
    int16_t codes_frozen;        /* fw_protection_codes_frozen of the period (RUN only) */
    real_t vec_proj[2];          /* 1/H, each measured active vector's slope difference
                                    projected on its own voltage (v . di / |v|^2) */
    uint32_t est_reject_count;
    int16_t flux_pos_load;       /* 1: load high enough for the flux hand-over (hysteresis) */
    int16_t start_recover;       /* 1: ramp back to start_speed_rpm; 2: then to the command, no faster */
    int32_t start_gov;           /* periods left in which |iq| follows the measured saliency */
    int16_t start_fw_hold;       /* periods left in which flux weakening's feedback holds */
    real_t g1_fast;              /* 1/H, Gamma1 along d_hat of the two-vector estimates, ~1 ms filter */
    real_t iq_gov;               /* A, q-current limit of the saliency governor */
    real_t start_speed_rpm;      /* the shaft's speed at the enable (the start-up measured it) */
    int16_t flux_pos_active;     /* the flux estimator carried the PLL in the last period */
    int16_t est_param_ok;        /* the period's two-vector estimate is fit for Ld/Lq */
    real_t theta_raw_axes;       /* rad, the estimate's saliency-axis angle (before the
                                    cross-saturation correction) */
    int16_t full_mod;            /* FULL modulation (whole voltage range) is active */
    real_t theta_raw_branch;
    int16_t slopes_ok;
    int16_t stamp;
    real_t theta_hat;            /* at stamp */
    real_t speed_f_rpm;          /* filtered mechanical speed */
    uint16_t polarity_flips;
    int32_t flip_window_ticks;
    int16_t flips_in_window;
    int16_t polarity_ok;
    fw_polarity_t pol;
    fw_polarity_watch_t watch;

    /* control */
    real_t id, iq;               /* measured, estimated frame */
    real_t id_ref, iq_ref;
    real_t vd, vq;               /* references for the next period */
    /* mean of (vd, vq) over blocks of FW_SPEED_DIVIDER periods for the 1 kHz telemetry:
     * sampling the 10 kHz references every 10th period would alias their period-to-period
     * ripple into a bias (a 10-period mean has zeros at every multiple of 1 kHz) */
    fw_cplx_t vdq_sum;
    int16_t vdq_sum_n;
    fw_cplx_t vdq_mean;
    real_t v_lim;                /* V, voltage available to the current controller */
    real_t u_mag;                /* V, the current loop's demand before its voltage limit */
    real_t v_mag_f;              /* filtered demand |u| for the flux-weakening feedback */
    fw_pi_t pi_d, pi_q, pi_spd;
    real_t speed_ref_ramped;
    real_t iq_demand;
    real_t iq_sal_lim;           /* A, q-current limit from current, voltage and saliency */
    real_t id_ref_base;          /* A, d reference of MTPA/FW before the reluctance extension */
    real_t fluxweak_did;         /* A, voltage-feedback d-current */
    int16_t fluxweak_active;     /* flux weakening active (voltage limit reached) */
    real_t te_hat;
    real_t te_model;             /* N*m, torque of the references through the current loop */
    real_t te_ripple;            /* N*m, reluctance torque of the next pattern's current ripple */
    real_t ld_use, lq_use, lambda_use; /* parameter set of the selected mode */
};

#endif /* FW_CORE_STATE_H */
