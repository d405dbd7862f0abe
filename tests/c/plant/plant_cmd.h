/* A PWM command for the plant tests: the three legs' up- and down-count compares, the gates
 * enabled, nothing else (no ADC trigger). */
#ifndef PLANT_CMD_H
#define PLANT_CMD_H

#include <stdint.h>
#include <string.h>

#include "plant_internal.h"

static inline void cmd_set(plant_pwm_cmd_t *c, int up0, int dn0, int up1, int dn1, int up2,
                           int dn2)
{
    memset(c, 0, sizeof(*c));
    c->cmp_up[0] = (uint16_t)up0;
    c->cmp_dn[0] = (uint16_t)dn0;
    c->cmp_up[1] = (uint16_t)up1;
    c->cmp_dn[1] = (uint16_t)dn1;
    c->cmp_up[2] = (uint16_t)up2;
    c->cmp_dn[2] = (uint16_t)dn2;
    c->gate_enable = 1;
}

#endif
