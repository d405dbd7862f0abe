/* plant_vio: the plant's side of the wires as CAN frames (protocols/vio.dbc, bench.dbc).
 *
 * What plant_rt puts on the bus and into its trace, and how it checks a LOAD_CMD, shared by
 * plant_rt (bus) and the in-process bench (bench/), so both hand the firmware and the
 * capture exactly the same bytes. No I/O here.
 */
#ifndef PLANT_VIO_H
#define PLANT_VIO_H

#include <linux/can.h>

#include "plant_core.h"

#ifdef __cplusplus
extern "C" {
#endif

#define PLANT_VIO_ADC_FRAMES_MAX 3

/* Why a frame was refused (the exit counters' "rejects", BENCH_REJECTS). */
enum plant_reject {
    PLANT_REJ_NONE = 0,
    PLANT_REJ_UNKNOWN_ID,
    PLANT_REJ_BAD_LENGTH,
    PLANT_REJ_OUT_OF_RANGE,
    PLANT_REJ_STALE_PERIOD,
    PLANT_REJ_FUTURE_PERIOD,
    PLANT_REJ_TOO_MANY_SOC,
    PLANT_REJ_SOC_OUTSIDE,
    PLANT_REJ_MALFORMED,
    PLANT_REJ_COUNT
};
const char *plant_reject_name(int reason);

/* Checks a decoded PWM command against the limits and the expected period. */
int plant_pwm_validate(const plant_pwm_cmd_t *cmd, uint32_t expected_period);

/* Decodes and validates a VIO_PWM frame: can_id (without flags), fd (CAN FD frame?), data,
 * len. Returns PLANT_REJ_NONE with *out filled, or the reason. */
int plant_decode_pwm(uint32_t can_id, int fd, const uint8_t *data, size_t len,
                     uint32_t expected_period, plant_pwm_cmd_t *out);

/* The command of period 0 (docs/interfaces.md, start-up): gates disabled, one SOC at tick 0,
 * so ADC(0) reaches the firmware, which answers with PWM(1). */
void plant_startup_command(plant_pwm_cmd_t *cmd);

/* VIO_ADC_0..2 of one period (as many as n_soc calls for; none when n_soc is 0).
 * Returns the number of frames written to out. */
int plant_pack_adc(const plant_samples_t *s, struct canfd_frame out[PLANT_VIO_ADC_FRAMES_MAX]);

/* BENCH_TRUTH (out[0]) and BENCH_TRUTH_MAG (out[1]) of the truth at a period's start. */
void plant_pack_truth(const plant_truth_t *t, struct canfd_frame out[2]);

/* A decoded, range-checked LOAD_CMD. */
typedef struct plant_load_cmd {
    int mode;
    double torque_nm, speed_rpm, k_speed_nms;
} plant_load_cmd_t;

/* Checks a LOAD_CMD frame (CAN FD, DBC length, signal ranges). Returns PLANT_REJ_NONE with
 * *out filled, or PLANT_REJ_MALFORMED (classic frame), _BAD_LENGTH or _OUT_OF_RANGE. */
int plant_decode_load_cmd(int fd, const uint8_t *data, size_t len, plant_load_cmd_t *out);

#ifdef __cplusplus
}
#endif
#endif
