/* fw_core.h - public API of the portable sensorless IPMSM control core.
 *
 * The core is pure computation: the HAL hands it the raw ADC codes of PWM period k and gets
 * back the compare values, ADC start-of-conversion instants and gate enable for period k+1
 * (docs/interfaces.md: PWM(k+1) is computed from ADC(k)). It never touches a register, a frame
 * or a socket, allocates nothing and calls no library except the math in fw_math.h.
 *
 * Threading: fw_core_isr() is the 10 kHz interrupt. fw_core_command(), fw_core_set_limits()
 * and fw_param_set() are meant for the background loop; on a single-core target the HAL calls
 * them with the ISR masked (or from the ISR itself) - the core has no locks.
 */
#ifndef FW_CORE_H
#define FW_CORE_H

#include "fw_types.h" /* real_t, fixed-width ints, no uint8_t */
/* What the wire defines, generated from the DBC files in protocols/ at configure time (never
 * committed): the PWM time base FW_TBPRD, FW_PERIOD_TICKS, FW_TBCLK_HZ, FW_TS (100 us),
 * FW_SPEED_DIVIDER (speed loop, MTPA/FW every 10th ISR: 1 kHz), FW_MAX_SOC, and the value
 * tables FW_STATE_* (DRIVE_STATUS.state, FW_TRACE.state), FW_CTRL_*, FW_FWMODE_* (DRIVE_CMD),
 * FW_FAULT_* (DRIVE_STATUS.fault_code: the first fault since the last reset), FW_STATUS_*
 * (PARAM_RESP.status). */
#include "fw_wire_gen.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Raw ADC codes of period k, in the order of the SOCs the core asked for (pwm.soc[]). */
typedef struct {
    uint32_t period;
    int16_t n_soc;
    int32_t ia[FW_MAX_SOC];
    int32_t ib[FW_MAX_SOC];
    int32_t vdc;
} fw_adc_t;

/* Command for period k+1: upper gate of phase x on for period ticks
 * [cmp_up[x], 2*TBPRD - cmp_dn[x]); soc[] are period ticks 0..9999 (any order). */
typedef struct {
    uint32_t period;
    uint16_t cmp_up[3];
    uint16_t cmp_dn[3];
    int16_t n_soc;
    uint16_t soc[FW_MAX_SOC];
    int16_t gate_enable;
} fw_pwm_t;

/* Drive command (DRIVE_CMD). ctrl_mode: FW_CTRL_*; fw_mode: FW_FWMODE_*. */
typedef struct {
    int16_t enable;
    int16_t fault_reset;
    int16_t ctrl_mode;
    int16_t fw_mode;
    real_t speed_ref_rpm;
    real_t iq_ref;
} fw_cmd_t;

/* ---- Status codes of the API: PARAM_RESP.status's table (fw_wire_gen.h), and one more ---- */
#define FW_STATUS_BAD_ARG (FW_STATUS_WIRE_MAX + 1) /* NULL pointer (a caller's programming
                                                      error; never on the wire) */
/* What each mode and fault means: the comments of DRIVE_CMD.fw_mode and
 * DRIVE_STATUS.fault_code in protocols/drive.dbc. */

/* Everything FW_TRACE and the TLM_* / DRIVE_STATUS frames carry: fw_status_t, one
 * X(type, name) per field. The list is the one declaration: the struct below, the host HAL's
 * FW_TRACE packer (generated from protocols/vio.dbc: each FW_TRACE signal is the field of its
 * name) and the test API's field table (names, offsets, types for Python) are made from it. */
#define FW_STATUS_FIELDS(X)                                                                  \
    X(int16_t, state)             /* FW_STATE_* */                                          \
    X(uint16_t, fault_code)       /* FW_FAULT_* */                                          \
    X(int16_t, ctrl_mode)                                                                   \
    X(int16_t, fw_mode)                                                                     \
    X(int16_t, cmd_status)        /* FW_STATUS_* of the last fw_core_command() */           \
    X(uint32_t, period)           /* period the estimates below belong to (ADC period k) */ \
    X(int16_t, stamp)             /* ticks from the start of 'period': theta_hat valid */   \
    X(real_t, theta_hat)          /* electrical rad, [0, 2pi) */                            \
    X(real_t, omega_hat)          /* electrical rad/s */                                    \
    X(real_t, speed_hat_rpm)      /* mechanical r/min */                                    \
    X(real_t, id)                 /* A, measured, in the estimated frame */                 \
    X(real_t, iq)                                                                           \
    X(real_t, id_ref)             /* A */                                                   \
    X(real_t, iq_ref)                                                                       \
    X(real_t, vd)                 /* V, voltage references for the next period */           \
    X(real_t, vq)                                                                           \
    X(real_t, vd_mean)            /* V, vd, vq over the last complete block of */           \
    X(real_t, vq_mean)            /* FW_SPEED_DIVIDER periods (the 1 kHz TLM_VOLT) */       \
    X(real_t, ld_hat)             /* H, online estimates (incremental) */                   \
    X(real_t, lq_hat)                                                                       \
    X(real_t, lambda_hat)         /* Wb, online PM flux estimate */                         \
    X(real_t, te_hat)             /* N*m, estimated torque */                               \
    X(real_t, theta_raw)          /* rad, raw estimate of the period after branch choice */ \
    X(real_t, residual)           /* 1/H, least-squares consistency residual */             \
    X(int16_t, sector)            /* SVPWM sector 1..6 of the period (0 when off) */        \
    X(int16_t, slopes_ok)         /* active vectors measured this period: 0, 1 or 2 */      \
    X(int16_t, fw_active)         /* flux weakening active (voltage limit reached) */       \
    X(real_t, speed_ref_ramped_rpm)                                                         \
    X(int16_t, polarity_ok)                                                                 \
    X(int16_t, est_valid)                                                                   \
    X(uint16_t, isr_overruns)

#define FW_STATUS_DECLARE(type, name) type name;
typedef struct {
    FW_STATUS_FIELDS(FW_STATUS_DECLARE)
} fw_status_t;

/* Full definition of the core object: the HAL allocates it statically. */
#include "fw_core_state.h"
typedef struct fw_core fw_core_t;

void fw_core_init(fw_core_t *c); /* defaults from the parameter table */
int16_t fw_core_command(fw_core_t *c, const fw_cmd_t *cmd); /* validates; FW_STATUS_* */
int16_t fw_core_set_limits(fw_core_t *c, real_t i_max, real_t speed_max_rpm, real_t accel_rpm_s);
/* 10 kHz ISR, runs the 1 kHz tasks every 10th call. adc_k == NULL means "no ADC data for this
 * period" (counted as ADC loss). pwm_next->period = adc_k->period + 1. A repeated adc_k (same
 * period as the previous call) returns the same pwm_next without running the control again. */
void fw_core_isr(fw_core_t *c, const fw_adc_t *adc_k, fw_pwm_t *pwm_next);
int16_t fw_param_get(const fw_core_t *c, uint16_t id, real_t *value);
int16_t fw_param_set(fw_core_t *c, uint16_t id, real_t value);
void fw_core_status(const fw_core_t *c, fw_status_t *s);

/* ---- Additions for the HAL (console, parameter listing, timing) -------------------------- */
/* Parameter metadata from protocols/parameters.csv (generated table). */
typedef struct {
    uint16_t id;
    const char *name; /* string for the console only: the core never does arithmetic on char */
    const char *unit;
    real_t min, max, def;
    int16_t read_only;
} fw_param_info_t;
uint16_t fw_param_count(void);
const fw_param_info_t *fw_param_info_at(uint16_t index); /* NULL past the end */
const fw_param_info_t *fw_param_info(uint16_t id);       /* NULL for an unknown id */
/* The HAL counts a missed ISR deadline (real-time mode) so it appears in the status. */
void fw_core_note_overrun(fw_core_t *c);

#ifdef __cplusplus
}
#endif

#endif /* FW_CORE_H */
