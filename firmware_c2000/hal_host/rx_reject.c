/* rx_reject.c - see rx_reject.h (moved out of main.c for the in-process bench). */
#include "rx_reject.h"

static const char *const reject_names[FWH_REJ_COUNT] = {
    "unknown_id", "bad_length", "wrong_frame_type", "out_of_range", "malformed",
    "stale_period", "future_period", "incomplete", "refused"};

const char *fwh_reject_name(int reason)
{
    return reason >= 0 && reason < FWH_REJ_COUNT ? reject_names[reason] : "?";
}
