/* drive_codec.h - checks and decodes the drive-protocol commands (protocols/drive.dbc)
 * into the core's types. No I/O: shared by fw_host (drive_protocol.c) and the in-process
 * bench (bench/), so a command means the same on both. */
#ifndef DRIVE_CODEC_H
#define DRIVE_CODEC_H

#include <linux/can.h>
#include <stddef.h>
#include <stdint.h>

#include "fw_core.h"
#include "rx_reject.h"

enum {
    FWH_DRIVE_REJECTED = -1, /* *reason and why say why */
    FWH_DRIVE_NOT_OURS = 0,  /* what a drive sends (status, telemetry, ...) */
    FWH_DRIVE_CMD,
    FWH_DRIVE_LIMITS,
    FWH_DRIVE_PARAM_REQ
};

/* What a frame of the drive range (hil_drive_id_in_range, flags checked by the caller) is:
 * one of the FWH_DRIVE_* kinds; unknown ids, CAN FD frames and wrong lengths are FWH_DRIVE_REJECTED. */
int fwh_drive_classify(const struct canfd_frame *f, int fd, int *reason, char *why,
                       size_t whylen);

/* DRIVE_CMD data -> command. 0, or -1 (a signal outside its DBC range: FWH_REJ_OUT_OF_RANGE)
 * with a message in why. */
int fwh_drive_cmd_decode(const uint8_t *data, uint8_t len, fw_cmd_t *cmd, char *why,
                         size_t whylen);

typedef struct {
    double i_max_a, speed_max_rpm, accel_rpm_s;
} fwh_limits_t;

/* DRIVE_LIMITS data -> limits. 0, or -1 (FWH_REJ_OUT_OF_RANGE) with a message in why. */
int fwh_drive_limits_decode(const uint8_t *data, uint8_t len, fwh_limits_t *lim, char *why,
                            size_t whylen);

#endif
