/* Inverter: gate timing with dead time, and the terminal voltage of a leg.
 *
 * Gate commands (docs/interfaces.md): the upper gate of a phase is commanded on for period
 * ticks [cmp_up, 2*TBPRD - cmp_dn), the lower gate for the rest of the period (both off
 * with gate_enable = 0). The dead-band module delays every off->on transition of a gate by
 * the dead time: a gate is on only when its command has been on continuously for the dead
 * time (a shorter command pulse is swallowed, as on the ePWM dead-band). Commands that
 * are still on at the end of a period keep their start instant, so a delayed turn-on can
 * fall into the next period.
 *
 * Terminal voltage of a leg (to DC-), with one forward drop Vdrop for transistor and diode
 * and i > 0 out of the leg into the machine:
 *   upper gate on:   i > 0: Vdc - Vdrop (transistor)   i < 0: Vdc + Vdrop (upper diode)
 *   lower gate on:   i > 0: -Vdrop      (lower diode)  i < 0: +Vdrop      (transistor)
 *   both gates off:  i > 0: -Vdrop      (lower diode)  i < 0: Vdc + Vdrop (upper diode)
 * i.e. v = Vdc*s - Vdrop*sign(i). At zero current the leg blocks anywhere between those two
 * values (its "band"); the machine model keeps such a phase at zero current until its
 * terminal would leave the band.
 */
#include "plant_internal.h"

typedef struct {
    int n;
    int32_t start[2], end[2];
} interval_set_t;

/* Actual (dead-time delayed) on-intervals of one gate in this period, updating memory. */
static void gate_actual(const interval_set_t *cmd, int32_t dead, int g, plant_gate_memory_t *mem,
                        interval_set_t *out)
{
    int k;
    int next_on = 0;
    int64_t next_since = 0;

    out->n = 0;
    for (k = 0; k < cmd->n; ++k) {
        int64_t since = cmd->start[k];
        int64_t on_from;
        if (cmd->start[k] == 0 && mem->cmd_on[g]) {
            since = mem->cmd_since[g]; /* the command has been on since the last period */
        }
        on_from = since + dead;
        if (on_from < 0) {
            on_from = 0;
        }
        if (on_from < cmd->end[k]) {
            out->start[out->n] = (int32_t)on_from;
            out->end[out->n] = cmd->end[k];
            out->n++;
        }
        if (cmd->end[k] == PLANT_PERIOD_TICKS) {
            next_on = 1;
            next_since = since - PLANT_PERIOD_TICKS;
        }
    }
    mem->cmd_on[g] = next_on;
    mem->cmd_since[g] = next_since;
}

static int in_set(const interval_set_t *s, int32_t t)
{
    int k;
    for (k = 0; k < s->n; ++k) {
        if (t >= s->start[k] && t < s->end[k]) {
            return 1;
        }
    }
    return 0;
}

void plant_inverter_schedule(const plant_pwm_cmd_t *cmd, int32_t dead_ticks,
                             plant_gate_memory_t *memory, plant_leg_schedule_t legs[3])
{
    int x;
    for (x = 0; x < 3; ++x) {
        interval_set_t up_cmd = {0, {0, 0}, {0, 0}}, lo_cmd = {0, {0, 0}, {0, 0}};
        interval_set_t up, lo;
        int32_t cand[8];
        int n_cand = 0, k, j;
        plant_leg_schedule_t *leg = &legs[x];

        if (cmd->gate_enable) {
            const int32_t w0 = cmd->cmp_up[x];
            const int32_t w1 = PLANT_PERIOD_TICKS - (int32_t)cmd->cmp_dn[x];
            if (w0 < w1) {
                up_cmd.start[0] = w0;
                up_cmd.end[0] = w1;
                up_cmd.n = 1;
                if (w0 > 0) {
                    lo_cmd.start[lo_cmd.n] = 0;
                    lo_cmd.end[lo_cmd.n] = w0;
                    lo_cmd.n++;
                }
                if (w1 < PLANT_PERIOD_TICKS) {
                    lo_cmd.start[lo_cmd.n] = w1;
                    lo_cmd.end[lo_cmd.n] = PLANT_PERIOD_TICKS;
                    lo_cmd.n++;
                }
            } else {
                lo_cmd.start[0] = 0;
                lo_cmd.end[0] = PLANT_PERIOD_TICKS;
                lo_cmd.n = 1;
            }
        }
        gate_actual(&up_cmd, dead_ticks, 2 * x, memory, &up);
        gate_actual(&lo_cmd, dead_ticks, 2 * x + 1, memory, &lo);

        for (k = 0; k < up.n; ++k) {
            cand[n_cand++] = up.start[k];
            cand[n_cand++] = up.end[k];
        }
        for (k = 0; k < lo.n; ++k) {
            cand[n_cand++] = lo.start[k];
            cand[n_cand++] = lo.end[k];
        }
        /* insertion sort of the candidate edge ticks */
        for (k = 1; k < n_cand; ++k) {
            int32_t v = cand[k];
            j = k - 1;
            while (j >= 0 && cand[j] > v) {
                cand[j + 1] = cand[j];
                --j;
            }
            cand[j + 1] = v;
        }
        leg->state0 = in_set(&up, 0) ? GATE_UPPER : (in_set(&lo, 0) ? GATE_LOWER : GATE_NONE);
        leg->n_edges = 0;
        {
            int prev = leg->state0;
            for (k = 0; k < n_cand; ++k) {
                const int32_t t = cand[k];
                int st;
                if (t <= 0 || t >= PLANT_PERIOD_TICKS || (k > 0 && cand[k - 1] == t)) {
                    continue;
                }
                st = in_set(&up, t) ? GATE_UPPER : (in_set(&lo, t) ? GATE_LOWER : GATE_NONE);
                if (st != prev) {
                    leg->tick[leg->n_edges] = t;
                    leg->state[leg->n_edges] = st;
                    leg->n_edges++;
                    prev = st;
                }
            }
        }
    }
}

/* plant_leg_band and plant_leg_voltage are static inline in plant_internal.h (hot path). */
