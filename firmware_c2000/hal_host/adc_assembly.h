/* adc_assembly.h - collects the VIO_ADC_0..2 frames of one PWM period into an fw_adc_t.
 *
 * Pure bookkeeping (no I/O, no clock) so that it can be unit-tested. Per period the plant
 * sends VIO_ADC_0 (SOCs 0-6), VIO_ADC_1 (7-13, only when n_soc > 7) and VIO_ADC_2 (14-15,
 * only when n_soc > 14), each carrying the period index and n_soc. The rules:
 *
 *  - a period is complete when every frame its n_soc calls for has arrived (in any order;
 *    a duplicate frame of the period being collected replaces the earlier copy);
 *  - data of the period the ISR ran last (a lockstep re-send) is collected again and handed
 *    back as a repeat: the HAL calls the core with it, which returns the same PWM(k+1);
 *  - data of a newer period ends the period being collected: if it never completed it is
 *    rejected as incomplete, and every period between the last one the ISR ran and the new
 *    one is reported lost (the HAL runs the ISR without data for each, oldest first);
 *  - older data is stale, data more than FWH_ADC_MAX_GAP periods ahead is future: both are
 *    rejected. A restarted plant (FWH_ADC_RESYNC consecutive periods 0, 1, 2, ... of such
 *    data: its start-up period first) is taken as the new sequence; the core then counts
 *    one ADC loss and follows it. No other run of rejected periods is ever followed (stray
 *    frames of another node, delayed duplicates): only the plant itself starts at 0;
 *  - frames whose n_soc does not agree with the period's first frame, or that n_soc does not
 *    call for (VIO_ADC_1 with n_soc <= 7), are malformed and rejected;
 *  - in lockstep (fwh_adc_lockstep) the plant does not run a period before PWM of it came,
 *    so it skips none, until a frame fault makes it end every exchange with a barrier
 *    (VIO_SYNC: fwh_adc_barrier) and go on without PWM where none came. Before the first
 *    barrier, data that skips periods is not the plant's: future, rejected. (One stray frame
 *    a little ahead of the plant once took the sequence over; the plant's own frames were
 *    then stale and the lockstep stalled.)
 */
#ifndef ADC_ASSEMBLY_H
#define ADC_ASSEMBLY_H

#include <stdint.h>

#include "fw_core.h"

#define FWH_ADC_MAX_GAP 100u /* periods (10 ms): more than this ahead is "future" */
#define FWH_ADC_RESYNC 10    /* consecutive stale/future periods that start a new sequence */

typedef enum {
    FWH_ADC_OK = 0,
    FWH_ADC_STALE,
    FWH_ADC_FUTURE,
    FWH_ADC_MALFORMED
} fwh_adc_verdict_t;

typedef struct {
    int have_last;     /* the ISR ran for at least one period */
    uint32_t last;     /* period of the last ISR run (with or without data) */
    int building;      /* a period is being collected */
    int repeat;        /* ... and it is the last one again (re-send) */
    uint32_t period;
    int16_t n_soc;
    unsigned got;      /* bit i: VIO_ADC_i arrived */
    fw_adc_t adc;
    uint32_t resync_next; /* resynchronisation on a consistent stream of rejected periods */
    int resync_count;
    int first_fixed;      /* the first period is known (fwh_adc_expect_first) */
    uint32_t first;
    int lockstep;         /* fwh_adc_lockstep */
    int barriers;         /* the plant has sent a barrier (fwh_adc_barrier) */
} fwh_adc_asm_t;

/* What one frame led to. The HAL acts in this order: count `incomplete` rejections, run
 * the ISR without data for periods lost_first .. lost_first + n_lost - 1, count `verdict`,
 * then run the ISR with `adc` if `complete` (a repeat when `repeat`). */
typedef struct {
    fwh_adc_verdict_t verdict; /* of this frame */
    int incomplete;            /* 0 or 1: a period's data ended incomplete */
    uint32_t lost_first;
    uint32_t n_lost;
    int complete;
    int repeat;
    int resynced;              /* this frame started a new sequence */
    const fw_adc_t *adc;       /* valid until the next call when complete */
} fwh_adc_result_t;

void fwh_adc_init(fwh_adc_asm_t *a);

/* The first period the paired plant sends (lockstep: its start-up period 0, fw_host
 * --first-period): data of any other period before it is rejected (stale or future), so
 * stray frames on the bus cannot become the first period. Without it the newest period
 * seen is the first (real time: the plant runs before the firmware joins). */
void fwh_adc_expect_first(fwh_adc_asm_t *a, uint32_t period);

/* Lockstep pacing: periods are skipped only once the plant has sent a barrier (above). */
void fwh_adc_lockstep(fwh_adc_asm_t *a);
/* The plant's barrier (VIO_SYNC) arrived: from now on its periods may skip. */
void fwh_adc_barrier(fwh_adc_asm_t *a);

/* One received frame: index 0..2 (VIO_ADC_0..2), its period, n_soc (0..16, range-checked by
 * the caller), vdc code and the up to 7 current code pairs it carries. */
void fwh_adc_feed(fwh_adc_asm_t *a, int index, uint32_t period, int16_t n_soc, int32_t vdc,
                  const int32_t *ia, const int32_t *ib, fwh_adc_result_t *out);

/* Number of VIO_ADC frames a period with n_soc samples is sent in (1 for n_soc = 0). */
int fwh_adc_frames_for(int16_t n_soc);

#endif
