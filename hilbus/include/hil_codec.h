/* Encoding physical values into DBC raw values from C.
 *
 * cantools' generated `<msg>_<signal>_encode(double)` truncates toward zero, while its
 * Python encoder rounds to nearest: 3.57 A at 1 mA/LSB gives raw 3569 in C and 3570 in
 * Python. C programs therefore encode integer signals with HIL_ENCODE, which rounds to the
 * nearest raw value as Python does; the scale and offset are taken from the generated
 * decode function, so the DBC stays the only place they are written. Float signals carry
 * no scaling: assign them directly. */
#ifndef HIL_CODEC_H
#define HIL_CODEC_H

#include <math.h>

/* Raw value nearest to `value` for the signal whose generated functions start with
 * `prefix` (e.g. hil_drive_tlm_cur_id). Assign the result to the struct field. */
#define HIL_ENCODE(prefix, value)                                                          \
    lround(((double)(value) - prefix##_decode(0)) / (prefix##_decode(1) - prefix##_decode(0)))

#endif
