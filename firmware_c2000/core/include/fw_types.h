/* fw_types.h - the only scalar types the portable control core uses.
 *
 * Target: TI C28x (16-bit char and int, no 8-bit type, no FPU on the F2808), host: any C99.
 * Every integer has an explicit width; all engineering quantities are real_t so that a
 * fixed-point (IQmath-style) build only has to replace this typedef and fw_math.h.
 */
#ifndef FW_TYPES_H
#define FW_TYPES_H

#include <stdint.h>

/* The one floating/fixed type of the core (SI units throughout: A, V, H, Wb, rad, s). */
typedef float real_t;

#define FW_REAL(x) ((real_t)(x))

#endif /* FW_TYPES_H */
