/* drive_codec.c - see drive_codec.h. Moved out of drive_protocol.c (the frame checks and the
 * range checks and decoding of DRIVE_CMD and DRIVE_LIMITS) so the in-process bench shares
 * them. */
#include "drive_codec.h"

#include <stdio.h>

#include "hil_drive.h"

int fwh_drive_classify(const struct canfd_frame *f, int fd, int *reason, char *why,
                       size_t whylen)
{
    const uint32_t id = f->can_id & CAN_SFF_MASK;
    int kind;
    switch (id) {
    case HIL_DRIVE_DRIVE_CMD_FRAME_ID:
        kind = FWH_DRIVE_CMD;
        break;
    case HIL_DRIVE_DRIVE_LIMITS_FRAME_ID:
        kind = FWH_DRIVE_LIMITS;
        break;
    case HIL_DRIVE_PARAM_REQ_FRAME_ID:
        kind = FWH_DRIVE_PARAM_REQ;
        break;
    case HIL_DRIVE_PARAM_RESP_FRAME_ID:
    case HIL_DRIVE_DRIVE_STATUS_FRAME_ID:
    case HIL_DRIVE_HEARTBEAT_FRAME_ID:
    case HIL_DRIVE_TLM_POS_FRAME_ID:
    case HIL_DRIVE_TLM_CUR_FRAME_ID:
    case HIL_DRIVE_TLM_REF_FRAME_ID:
    case HIL_DRIVE_TLM_PARAM_FRAME_ID:
    case HIL_DRIVE_TLM_VOLT_FRAME_ID:
        return FWH_DRIVE_NOT_OURS; /* what a drive sends: not for us */
    default:
        *reason = FWH_REJ_UNKNOWN_ID;
        snprintf(why, whylen, "id 0x%03X: no such drive-protocol message", (unsigned)id);
        return FWH_DRIVE_REJECTED;
    }
    if (fd) {
        *reason = FWH_REJ_WRONG_FRAME_TYPE;
        snprintf(why, whylen, "id 0x%03X: CAN FD frame, the drive protocol is classic CAN",
                 (unsigned)id);
        return FWH_DRIVE_REJECTED;
    }
    if (f->len != 8u) { /* all three are 8 bytes long in drive.dbc */
        *reason = FWH_REJ_BAD_LENGTH;
        snprintf(why, whylen, "id 0x%03X: length %u, expected 8", (unsigned)id, f->len);
        return FWH_DRIVE_REJECTED;
    }
    return kind;
}

int fwh_drive_cmd_decode(const uint8_t *data, uint8_t len, fw_cmd_t *cmd, char *why,
                         size_t whylen)
{
    struct hil_drive_drive_cmd_t m;
    hil_drive_drive_cmd_unpack(&m, data, len);
    if (!hil_drive_drive_cmd_enable_is_in_range(m.enable) ||
        !hil_drive_drive_cmd_fault_reset_is_in_range(m.fault_reset) ||
        !hil_drive_drive_cmd_ctrl_mode_is_in_range(m.ctrl_mode) ||
        !hil_drive_drive_cmd_fw_mode_is_in_range(m.fw_mode) ||
        !hil_drive_drive_cmd_alive_is_in_range(m.alive) ||
        !hil_drive_drive_cmd_speed_ref_is_in_range(m.speed_ref) ||
        !hil_drive_drive_cmd_iq_ref_is_in_range(m.iq_ref)) {
        snprintf(why, whylen,
                 "DRIVE_CMD: signal outside its DBC range (enable %u, fault_reset %u, "
                 "ctrl_mode %u, fw_mode %u, speed_ref raw %ld, iq_ref raw %d)",
                 m.enable, m.fault_reset, m.ctrl_mode, m.fw_mode, (long)m.speed_ref, m.iq_ref);
        return -1;
    }
    cmd->enable = (int16_t)m.enable;
    cmd->fault_reset = (int16_t)m.fault_reset;
    cmd->ctrl_mode = (int16_t)m.ctrl_mode;
    cmd->fw_mode = (int16_t)m.fw_mode;
    cmd->speed_ref_rpm = (real_t)hil_drive_drive_cmd_speed_ref_decode(m.speed_ref);
    cmd->iq_ref = (real_t)hil_drive_drive_cmd_iq_ref_decode(m.iq_ref);
    return 0;
}

int fwh_drive_limits_decode(const uint8_t *data, uint8_t len, fwh_limits_t *lim, char *why,
                            size_t whylen)
{
    struct hil_drive_drive_limits_t m;
    hil_drive_drive_limits_unpack(&m, data, len);
    if (!hil_drive_drive_limits_i_max_is_in_range(m.i_max) ||
        !hil_drive_drive_limits_speed_max_is_in_range(m.speed_max) ||
        !hil_drive_drive_limits_accel_max_is_in_range(m.accel_max)) {
        snprintf(why, whylen,
                 "DRIVE_LIMITS: signal outside its DBC range (raw i_max %u, speed_max %u, "
                 "accel_max %lu)",
                 m.i_max, m.speed_max, (unsigned long)m.accel_max);
        return -1;
    }
    lim->i_max_a = hil_drive_drive_limits_i_max_decode(m.i_max);
    lim->speed_max_rpm = hil_drive_drive_limits_speed_max_decode(m.speed_max);
    lim->accel_rpm_s = hil_drive_drive_limits_accel_max_decode(m.accel_max);
    return 0;
}
