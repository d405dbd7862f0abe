/* rx_reject.h - why the host HAL rejects a received frame (or a period's data). Shared by
 * fw_host and the in-process bench (bench/), which count them under these names. */
#ifndef RX_REJECT_H
#define RX_REJECT_H

enum {
    FWH_REJ_UNKNOWN_ID,       /* no such message in the drive / virtual-I/O id range */
    FWH_REJ_BAD_LENGTH,       /* length differs from the DBC */
    FWH_REJ_WRONG_FRAME_TYPE, /* CAN FD where classic is defined or the reverse */
    FWH_REJ_OUT_OF_RANGE,     /* a signal outside its DBC range */
    FWH_REJ_MALFORMED,        /* inconsistent n_soc, a frame n_soc does not call for */
    FWH_REJ_STALE_PERIOD,     /* ADC data of a period older than the last ISR */
    FWH_REJ_FUTURE_PERIOD,    /* ADC data too far ahead */
    FWH_REJ_INCOMPLETE,       /* a period's ADC data that never completed */
    FWH_REJ_REFUSED,          /* DRIVE_LIMITS the control core refused */
    FWH_REJ_COUNT
};

/* "unknown_id", ... (the names of the exit counters) */
const char *fwh_reject_name(int reason);

#endif
