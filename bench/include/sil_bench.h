/* sil_bench: the firmware's control core and the plant in one process (software in the loop).
 *
 * The same wires as on the bus, without the bus: each period the plant's VIO_ADC frames go
 * through the firmware's frame checks and ADC assembly into fw_core_isr(), and its PWM
 * through the VIO_PWM codec and the plant's PWM check into the next period (plant_vio.h,
 * hal_host/vio_codec.h, adc_assembly.h: the code plant_rt and fw_host run). Drive commands,
 * limits and load commands are frames too (sil_bench_frame), checked and decoded by the bus
 * programs' code; parameters are "name=value" assignments as fw_host's --set, the plant's
 * configuration "section.key=value" as plant_rt's --set. The trace files are those of
 * plant_rt and fw_host (hiltrace.h), so the rig's capture reads them unchanged.
 *
 * Lockstep order, as on the bus: frames given between periods act before the next period
 * (a LOAD_CMD before the plant simulates it, a DRIVE_CMD before the ISR of its ADC data).
 * Not thread-safe per bench; benches are independent except for fw_host's parameter-file
 * scratch state (param_file.c): open benches in one thread.
 */
#ifndef SIL_BENCH_H
#define SIL_BENCH_H

#include <stddef.h>
#include <stdint.h>

#include "fw_core.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct sil_bench sil_bench_t;

typedef struct sil_bench_config {
    const char *profile_path;        /* plant profile file; NULL: the built-in defaults */
    const char *const *plant_sets;   /* "section.key=value", applied in order */
    int n_plant_sets;
    const char *const *fw_sets;      /* firmware parameters "name=value", applied in order */
    int n_fw_sets;
    const char *plant_trace;         /* BENCH_TRUTH, BENCH_TRUTH_MAG per period (or NULL) */
    const char *fw_trace;            /* FW_TRACE per ISR (or NULL) */
    int trace_vio;                   /* also VIO_PWM and VIO_ADC into the plant trace */
    int fw_from_plant;               /* set the firmware's hardware parameters (ADC scaling,
                                        dead time, device drop) from the plant's configuration
                                        before fw_sets, as the rig does from the profile */
} sil_bench_config_t;

/* Exit-counter style statistics (the names of plant_rt's and fw_host's exit JSON). */
typedef struct sil_bench_stats {
    uint64_t periods;            /* plant periods simulated */
    uint64_t isr;                /* ISRs run with data */
    uint64_t isr_no_data;        /* ISRs of periods whose data never completed (never expected) */
    uint64_t pwm_invalid;        /* core PWMs replaced by gates off */
    uint64_t plant_rejected;     /* PWM or LOAD_CMD frames the plant refused */
    uint64_t fw_rejected;        /* frames the firmware side refused */
    uint64_t adc_clipped;
    uint64_t load_cmds, drive_cmds, cmds_refused, limits, limits_refused, param_sets;
    uint64_t trace_records, trace_errors;
    double isr_ns_total;         /* wall time inside fw_core_isr (sil_bench_time_isr) */
    double plant_ns_total;       /* wall time inside plant_step (sil_bench_time_isr) */
} sil_bench_stats_t;

/* NULL with a message ("plant: FIELD: reason", "firmware: name=value: reason", "trace: ...")
 * on a bad configuration or an unwritable trace. */
sil_bench_t *sil_bench_open(const sil_bench_config_t *cfg, char *err, size_t errlen);
/* Flushes and closes the traces; 0, or -1 when a trace write failed. */
int sil_bench_close(sil_bench_t *b);

/* A frame to the bench (drive protocol: DRIVE_CMD, DRIVE_LIMITS; bench: LOAD_CMD, FAULT_CMD
 * (fault injection, plant_link.h: the exchange of each period then follows it), as the
 * bus would carry it (can_id without flags, fd = CAN FD frame). Returns 0 when taken, 1 when
 * ignored (not for a bench node, as on the bus; or a PARAM_REQ: parameters are set at open,
 * reason in err), -1 when rejected (counted, reason in err when err is not NULL). */
int sil_bench_frame(sil_bench_t *b, uint32_t can_id, int fd, const uint8_t *data, uint8_t len,
                    char *err, size_t errlen);

/* Convenience for C callers: the frames above packed from values. Same return values. */
int sil_bench_drive_cmd(sil_bench_t *b, int enable, int fault_reset, int ctrl_mode,
                        int fw_mode, double speed_ref_rpm, double iq_ref_a);
int sil_bench_drive_limits(sil_bench_t *b, double i_max_a, double speed_max_rpm,
                           double accel_rpm_s);
int sil_bench_load_cmd(sil_bench_t *b, int mode, double torque_nm, double speed_rpm,
                       double k_speed_nms);

/* One period: plant period -> ADC -> fw_core_isr -> PWM of the next period. 0, or -1 when
 * the loop broke (the plant refused the core's PWM, or the ADC data did not complete). */
int sil_bench_step(sil_bench_t *b);
/* Periods until the plant's next period is run_until (lockstep grant). Returns the periods
 * run, or -1 as sil_bench_step. */
long sil_bench_run_until(sil_bench_t *b, uint32_t run_until);

uint32_t sil_bench_next_period(const sil_bench_t *b);
void sil_bench_get_stats(const sil_bench_t *b, sil_bench_stats_t *stats);
/* Time plant_step and fw_core_isr separately (two clock reads per call each). */
void sil_bench_time_isr(sil_bench_t *b, int on);
/* Wall time of the last fw_core_isr call (ns; with sil_bench_time_isr on). */
double sil_bench_last_isr_ns(const sil_bench_t *b);

/* Counters as one JSON object (plant_rt/fw_host exit-counter names where they mean the same).
 * Returns the length written (snprintf semantics). */
int sil_bench_counters_json(const sil_bench_t *b, char *buf, size_t len);

/* Journal every call into the control core from now on (core_journal.h: the inputs of each
 * fw_core_isr, fw_core_command and fw_core_set_limits with the core's outputs, the parameters
 * that differ from their defaults, and the state at the start of each window of ISR indices
 * [win_start, win_start + win_len); n_win 0: everything). Before the first period, so that
 * the ISR indices count from the first call. Closed with the bench (sil_bench_close fails
 * when a journal write failed). 0, or -1 with a reason in err. */
int sil_bench_journal_open(sil_bench_t *b, const char *path, const uint32_t *win_start,
                           const uint32_t *win_len, int n_win, char *err, size_t errlen);

/* The frames the bus programs would send to the rig, kept in order until taken: what a live
 * view of an in-process run reads (the same frames it reads on the bus). fw_host's TLM_*
 * every tlm_div speed-loop periods (as its --tlm-div; its DRIVE_STATUS on a change comes
 * along) and plant_rt's BENCH_TRUTH every truth_every periods (as its --truth-every); 0, 0
 * turns it off, the default. The control loop computes the same with it on or off. Holds
 * SIL_BENCH_OUTBOX_FRAMES: take them after each grant (a frame beyond is dropped, counted). */
#define SIL_BENCH_OUTBOX_FRAMES 4096
void sil_bench_outbox(sil_bench_t *b, uint32_t tlm_div, uint32_t truth_every);
/* The oldest frame of the outbox (data: 64 bytes): 1, or 0 when it is empty. */
int sil_bench_take_frame(sil_bench_t *b, uint32_t *can_id, uint8_t *data, uint8_t *len);
uint64_t sil_bench_outbox_dropped(const sil_bench_t *b);

/* Fault injection: hook(ctx, adc) sees (and may change) every period's assembled ADC data
 * just before fw_core_isr(). NULL removes it. */
typedef void (*sil_bench_adc_hook_t)(void *ctx, fw_adc_t *adc);
void sil_bench_set_adc_hook(sil_bench_t *b, sil_bench_adc_hook_t hook, void *ctx);
/* The ADC data of the last ISR (after the hook) and the PWM the core returned (before the
 * VIO_PWM codec: an invalid one is what the core made). Either may be NULL. */
void sil_bench_last_io(const sil_bench_t *b, fw_adc_t *adc, fw_pwm_t *pwm);

/* The parts, for tests and tools that look inside (act through frames where you can). */
struct plant;
struct fw_core;
struct plant *sil_bench_plant(sil_bench_t *b);
struct fw_core *sil_bench_core(sil_bench_t *b);
/* The truth at the start of the last simulated period, and the core's status after its ISR. */
struct plant_truth;
const struct plant_truth *sil_bench_truth(const sil_bench_t *b);

size_t sil_bench_sizeof_stats(void);

/* The FW_TRACE record fw_host and the bench write for a core status (vio_codec.c, packed by
 * the code generated from protocols/vio.dbc): 64 data bytes into data; returns the length.
 * For the test that every FW_TRACE signal is carried from its fw_status_t field. */
int sil_bench_fw_trace_record(const fw_status_t *status, uint8_t *data);
size_t sil_bench_sizeof_fw_status(void);

/* The hardware parameters of fw_from_plant: firmware parameter i, the plant profile key it
 * comes from and the factor from the profile's SI unit (the rig's FIRMWARE_FROM_PROFILE,
 * which a test holds this table to). NULL past the end. */
const char *sil_bench_hardware_param(int i, const char **profile_key, double *factor);

#ifdef __cplusplus
}
#endif
#endif
