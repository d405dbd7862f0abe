/* vio_codec.h - the firmware's side of the virtual I/O as frames (protocols/vio.dbc):
 * VIO_ADC_0..2 in (checked and unpacked), VIO_PWM out (an invalid PWM never reaches the
 * wire), FW_TRACE records. No I/O: shared by fw_host (bus_io.c) and the in-process bench
 * (bench/), so both hand the core and the plant exactly the same values. */
#ifndef VIO_CODEC_H
#define VIO_CODEC_H

#include <linux/can.h>
#include <stddef.h>
#include <stdint.h>

#include "fw_core.h"
#include "hil_arrays.h"
#include "rx_reject.h"

/* One VIO_ADC_x frame: index x, its period and n_soc, the DC-link code and the up to 7
 * current code pairs it carries. */
/* samples one VIO_ADC frame carries at most: VIO_ADC_0's (vio.dbc, hil_arrays.h) */
#define FWH_VIO_ADC_MAX_SAMPLES HIL_VIO_VIO_ADC_0_IA_COUNT

typedef struct {
    int index;
    uint32_t period;
    uint8_t n_soc;
    int32_t vdc;
    int32_t ia[FWH_VIO_ADC_MAX_SAMPLES], ib[FWH_VIO_ADC_MAX_SAMPLES];
} fwh_vio_adc_t;

/* A virtual-I/O frame (id in vio.dbc's range, flags already checked by the caller):
 *   1  a VIO_ADC frame, *out filled;
 *   0  not ADC data (VIO_PWM, FW_TRACE, VIO_SYNC_ACK: what a firmware sends; VIO_SYNC:
 *      the plant's lockstep barrier, answered by the HAL);
 *  -1  rejected: *reason (FWH_REJ_*) and a message in why. */
int fwh_vio_adc_decode(const struct canfd_frame *f, int fd, fwh_vio_adc_t *out, int *reason,
                       char *why, size_t whylen);

/* Current codes of a decoded VIO_ADC frame inside the converter's 0 .. 2^adc_bits - 1 (the
 * core's adc_bits): 1, else 0 with *reason FWH_REJ_OUT_OF_RANGE and a message in why. */
int fwh_vio_adc_codes_ok(const fw_core_t *core, const fwh_vio_adc_t *m, int *reason, char *why,
                         size_t whylen);

/* VIO_PWM for want_period from the core's PWM. A PWM that is not for want_period or has a
 * value outside the DBC goes out with the gates off instead (returns 0; 1 when valid). */
int fwh_vio_pwm_pack(const fw_pwm_t *pwm, uint32_t want_period, struct canfd_frame *f);

/* FW_TRACE of one ISR: every signal from the fw_status_t field of its name (generated from
 * protocols/vio.dbc, fw_trace_gen.c); integers saturated into their DBC ranges. */
void fwh_vio_trace_pack(const fw_status_t *s, struct canfd_frame *f);

#endif
