/* adc_assembly.c - see adc_assembly.h for the rules. */
#include "adc_assembly.h"

#include <string.h>

#include "hil_arrays.h"

/* The SOCs VIO_ADC_0..2 carry (ia_<k>, ib_<k> of vio.dbc) */
static const int first_soc[3] = {HIL_VIO_VIO_ADC_0_IA_FIRST, HIL_VIO_VIO_ADC_1_IA_FIRST,
                                 HIL_VIO_VIO_ADC_2_IA_FIRST};
static const int socs_in[3] = {HIL_VIO_VIO_ADC_0_IA_COUNT, HIL_VIO_VIO_ADC_1_IA_COUNT,
                               HIL_VIO_VIO_ADC_2_IA_COUNT};

int fwh_adc_frames_for(int16_t n_soc)
{
    return n_soc > first_soc[2] ? 3 : n_soc > first_soc[1] ? 2 : 1;
}

void fwh_adc_init(fwh_adc_asm_t *a)
{
    memset(a, 0, sizeof(*a));
}

void fwh_adc_expect_first(fwh_adc_asm_t *a, uint32_t period)
{
    a->first_fixed = 1;
    a->first = period;
}

void fwh_adc_lockstep(fwh_adc_asm_t *a)
{
    a->lockstep = 1;
}

void fwh_adc_barrier(fwh_adc_asm_t *a)
{
    a->barriers = 1;
}

static void start(fwh_adc_asm_t *a, uint32_t period, int16_t n_soc, int repeat)
{
    a->building = 1;
    a->repeat = repeat;
    a->period = period;
    a->n_soc = n_soc;
    a->got = 0;
    memset(&a->adc, 0, sizeof(a->adc));
    a->adc.period = period;
    a->adc.n_soc = n_soc;
}

/* a rejected (stale/future) frame: a restarted plant starts again at its start-up period 0
 * (docs/interfaces.md), so only a sequence 0, 1, 2, ... of FWH_ADC_RESYNC periods is
 * followed. Any other run of rejected periods (frames of another node, delayed duplicates
 * of older periods) never takes the sequence over: the plant the firmware is paired with
 * goes on and those frames stay rejected. */
static int resync_candidate(fwh_adc_asm_t *a, int index, uint32_t period)
{
    if (index != 0) {
        return 0;
    }
    if (a->resync_count > 0 && period == a->resync_next) {
        a->resync_count++;
    } else if (a->resync_count > 0 && period == a->resync_next - 1u) {
        /* a re-sent copy of the same period does not count twice */
    } else {
        a->resync_count = period == 0u ? 1 : 0;
    }
    a->resync_next = period + 1u;
    return a->resync_count >= FWH_ADC_RESYNC;
}

void fwh_adc_feed(fwh_adc_asm_t *a, int index, uint32_t period, int16_t n_soc, int32_t vdc,
                  const int32_t *ia, const int32_t *ib, fwh_adc_result_t *out)
{
    int k, need;
    memset(out, 0, sizeof(*out));
    if (index < 0 || index > 2 || n_soc < 0 || n_soc > FW_MAX_SOC ||
        index >= fwh_adc_frames_for(n_soc)) {
        out->verdict = FWH_ADC_MALFORMED;
        return;
    }
    if (!a->have_last && a->first_fixed && period != a->first) {
        out->verdict = (int32_t)(period - a->first) < 0 ? FWH_ADC_STALE : FWH_ADC_FUTURE;
        return; /* not the paired plant's first period */
    }
    if (!a->have_last) {
        /* nothing ran yet: the newest period seen is the one to collect */
        if (a->building && period != a->period) {
            if ((int32_t)(period - a->period) < 0) {
                out->verdict = FWH_ADC_STALE;
                return;
            }
            out->incomplete = 1;
            a->building = 0;
        }
        if (!a->building) {
            start(a, period, n_soc, 0);
        }
    } else {
        int32_t d = (int32_t)(period - a->last);
        int32_t ahead = a->building ? (int32_t)(period - a->period) : 0;
        /* the furthest a period may lie ahead of the last ISR: one, in lockstep before the
         * plant's first barrier (it skips none then) */
        const uint32_t max_gap = a->lockstep && !a->barriers ? 1u : FWH_ADC_MAX_GAP;
        if (d < 0 || (d == 0 && a->building && !a->repeat) || (a->building && ahead < 0) ||
            (uint32_t)d > max_gap) {
            out->verdict = (d < 0 || (a->building && ahead < 0) || d == 0) ? FWH_ADC_STALE
                                                                          : FWH_ADC_FUTURE;
            if (!resync_candidate(a, index, period)) {
                return;
            }
            /* a consistent new sequence: follow it (the core counts the jump as ADC loss) */
            out->verdict = FWH_ADC_OK;
            out->resynced = 1;
            out->incomplete = a->building && !a->repeat;
            a->resync_count = 0;
            a->have_last = 0;
            a->first = period; /* (with a fixed first period: this sequence's, from now) */
            start(a, period, n_soc, 0);
        } else {
            if (a->building && ahead > 0) {
                out->incomplete = 1; /* the period being collected never completed */
                a->building = 0;
            }
            if (!a->building) {
                if (d == 0) {
                    start(a, period, n_soc, 1);
                } else {
                    out->lost_first = a->last + 1u;
                    out->n_lost = (uint32_t)d - 1u;
                    a->last = period - 1u; /* the HAL runs the lost periods now */
                    start(a, period, n_soc, 0);
                }
            }
            a->resync_count = 0;
        }
    }
    if (n_soc != a->n_soc) {
        out->verdict = FWH_ADC_MALFORMED;
        return;
    }
    for (k = 0; k < socs_in[index]; k++) {
        a->adc.ia[first_soc[index] + k] = ia[k];
        a->adc.ib[first_soc[index] + k] = ib[k];
    }
    if (index == 0) {
        a->adc.vdc = vdc;
    }
    a->got |= 1u << index;
    need = (1 << fwh_adc_frames_for(n_soc)) - 1;
    if ((a->got & (unsigned)need) == (unsigned)need) {
        out->complete = 1;
        out->repeat = a->repeat;
        out->adc = &a->adc;
        a->building = 0;
        a->have_last = 1;
        a->last = period;
    }
}
