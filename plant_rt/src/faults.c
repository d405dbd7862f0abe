/* Physical fault injection (plant_set_fault, FAULT_CMD in protocols/bench.dbc): what the
 * slots in force do to the sensors and the ADC, the inverter's gates and phases, and the DC
 * link. The plant's physics is unchanged while no slot holds a physical fault: every hook
 * is skipped then (plant.c), so a run without faults computes exactly what it did before.
 *
 * - ADC channel faults act on the analog input of the converter (after the sensor, its
 *   ringing and noise): x -> gain*x + offset, clipped to +-level (saturation); a stuck
 *   converter returns its code whatever the input.
 * - A lost current sensor outputs 0 A (its ringing pick-up and the ADC noise stay).
 * - A disconnected phase carries no current from the period it opens (its current is cut at
 *   once, the loop through the other two phases keeping its flux linkage: the energy the
 *   cut releases goes into an arc the model does not follow); its terminal floats.
 * - A gate that stays off: its transistor never conducts; the leg's diodes still do.
 * - The DC link moves to a new voltage (sag, overvoltage), linearly over a number of periods.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "hil_bench.h"
#include "plant_internal.h"

void plant_faults_init(plant_faults_t *f, double vdc_nominal)
{
    int k;
    memset(f, 0, sizeof(*f));
    for (k = 0; k < 3; ++k) {
        f->adc_gain[k] = 1.0;
        f->adc_offset[k] = 0.0;
        f->adc_clip[k] = HUGE_VAL;
    }
    f->vdc_target = vdc_nominal;
}

static int physical(int kind)
{
    switch (kind) {
    case HIL_BENCH_FAULT_CMD_KIND_ADC_OFFSET_CHOICE:
    case HIL_BENCH_FAULT_CMD_KIND_ADC_GAIN_CHOICE:
    case HIL_BENCH_FAULT_CMD_KIND_ADC_STUCK_CHOICE:
    case HIL_BENCH_FAULT_CMD_KIND_ADC_SATURATION_CHOICE:
    case HIL_BENCH_FAULT_CMD_KIND_SENSOR_LOSS_CHOICE:
    case HIL_BENCH_FAULT_CMD_KIND_OPEN_PHASE_CHOICE:
    case HIL_BENCH_FAULT_CMD_KIND_GATE_OFF_CHOICE:
    case HIL_BENCH_FAULT_CMD_KIND_DC_LINK_CHOICE:
        return 1;
    default:
        return 0;
    }
}

static void recompute(plant_faults_t *f, double vdc_nominal)
{
    int s, k;
    for (k = 0; k < 3; ++k) {
        f->adc_gain[k] = 1.0;
        f->adc_offset[k] = 0.0;
        f->adc_clip[k] = HUGE_VAL;
        f->stuck[k] = 0;
        f->stuck_code[k] = 0;
    }
    f->sensor_lost[0] = f->sensor_lost[1] = 0;
    f->open_mask = f->gate_off_mask = 0;
    f->adc_active = 0;
    f->dc_active = 0;
    f->vdc_target = vdc_nominal;
    f->vdc_ramp = 0;
    for (s = 0; s < PLANT_FAULT_SLOTS; ++s) {
        const plant_fault_slot_t *sl = &f->slot[s];
        switch (sl->kind) {
        case HIL_BENCH_FAULT_CMD_KIND_ADC_OFFSET_CHOICE:
            f->adc_offset[sl->channel] += sl->value;
            f->adc_active = 1;
            break;
        case HIL_BENCH_FAULT_CMD_KIND_ADC_GAIN_CHOICE:
            f->adc_gain[sl->channel] *= sl->value;
            f->adc_active = 1;
            break;
        case HIL_BENCH_FAULT_CMD_KIND_ADC_STUCK_CHOICE:
            f->stuck[sl->channel] = 1;
            f->stuck_code[sl->channel] = (int32_t)sl->value;
            f->adc_active = 1;
            break;
        case HIL_BENCH_FAULT_CMD_KIND_ADC_SATURATION_CHOICE:
            if (sl->value < f->adc_clip[sl->channel]) {
                f->adc_clip[sl->channel] = sl->value;
            }
            f->adc_active = 1;
            break;
        case HIL_BENCH_FAULT_CMD_KIND_SENSOR_LOSS_CHOICE:
            f->sensor_lost[sl->channel] = 1;
            f->adc_active = 1;
            break;
        case HIL_BENCH_FAULT_CMD_KIND_OPEN_PHASE_CHOICE:
            f->open_mask |= 1u << sl->phase;
            break;
        case HIL_BENCH_FAULT_CMD_KIND_GATE_OFF_CHOICE:
            f->gate_off_mask |= 1u << (2 * sl->phase + sl->gate);
            break;
        case HIL_BENCH_FAULT_CMD_KIND_DC_LINK_CHOICE:
            f->dc_active = 1;
            f->vdc_target = sl->value;
            f->vdc_ramp = sl->periods;
            break;
        default:
            break;
        }
    }
}

int plant_faults_set(plant_faults_t *f, double vdc_nominal, int slot, int kind, int channel,
                     int phase, int gate, double value, uint32_t periods, char *err,
                     size_t errlen)
{
    plant_fault_slot_t sl;
    if (slot < 0 || slot >= PLANT_FAULT_SLOTS) {
        snprintf(err, errlen, "fault slot %d outside 0 .. %d", slot, PLANT_FAULT_SLOTS - 1);
        return -1;
    }
    memset(&sl, 0, sizeof(sl));
    if (physical(kind)) {
        const int adc = kind == HIL_BENCH_FAULT_CMD_KIND_ADC_OFFSET_CHOICE ||
                        kind == HIL_BENCH_FAULT_CMD_KIND_ADC_GAIN_CHOICE ||
                        kind == HIL_BENCH_FAULT_CMD_KIND_ADC_STUCK_CHOICE ||
                        kind == HIL_BENCH_FAULT_CMD_KIND_ADC_SATURATION_CHOICE;
        const int max_channel = kind == HIL_BENCH_FAULT_CMD_KIND_SENSOR_LOSS_CHOICE ? 1 : 2;
        if ((adc || kind == HIL_BENCH_FAULT_CMD_KIND_SENSOR_LOSS_CHOICE) &&
            (channel < 0 || channel > max_channel)) {
            snprintf(err, errlen, "fault kind %d: channel %d outside 0 .. %d", kind, channel,
                     max_channel);
            return -1;
        }
        if (phase < 0 || phase > 2 || gate < 0 || gate > 1) {
            snprintf(err, errlen, "fault kind %d: phase %d or gate %d out of range", kind,
                     phase, gate);
            return -1;
        }
        if (!isfinite(value) ||
            (kind == HIL_BENCH_FAULT_CMD_KIND_ADC_GAIN_CHOICE && value < 0.0) ||
            (kind == HIL_BENCH_FAULT_CMD_KIND_ADC_SATURATION_CHOICE && !(value > 0.0)) ||
            (kind == HIL_BENCH_FAULT_CMD_KIND_DC_LINK_CHOICE && !(value > 0.0)) ||
            (kind == HIL_BENCH_FAULT_CMD_KIND_ADC_STUCK_CHOICE &&
             (value < 0.0 || value > 2147483647.0 || value != floor(value)))) {
            snprintf(err, errlen, "fault kind %d: value %g out of range", kind, value);
            return -1;
        }
        sl.kind = kind;
        sl.channel = channel;
        sl.phase = phase;
        sl.gate = gate;
        sl.value = value;
        sl.periods = periods;
    }
    f->slot[slot] = sl; /* anything else frees the slot */
    recompute(f, vdc_nominal);
    return 0;
}

double plant_faults_adc_in(const plant_faults_t *f, int ch, double x)
{
    double y = f->adc_gain[ch] * x + f->adc_offset[ch];
    if (y > f->adc_clip[ch]) {
        y = f->adc_clip[ch];
    } else if (y < -f->adc_clip[ch]) {
        y = -f->adc_clip[ch];
    }
    return y;
}

void plant_faults_legs(const plant_faults_t *f, plant_leg_schedule_t legs[3])
{
    int x, k;
    for (x = 0; x < 3; ++x) {
        plant_leg_schedule_t *leg = &legs[x];
        const int up_off = (f->gate_off_mask >> (2 * x)) & 1u;
        const int lo_off = (f->gate_off_mask >> (2 * x + 1)) & 1u;
        int n = 0, prev;
        if ((f->open_mask >> x) & 1u) {
            leg->state0 = GATE_OPEN;
            leg->n_edges = 0;
            continue;
        }
        if (!up_off && !lo_off) {
            continue;
        }
        /* a gate that never conducts: its on-intervals become both-off intervals */
        if ((up_off && leg->state0 == GATE_UPPER) || (lo_off && leg->state0 == GATE_LOWER)) {
            leg->state0 = GATE_NONE;
        }
        prev = leg->state0;
        for (k = 0; k < leg->n_edges; ++k) {
            int st = leg->state[k];
            if ((up_off && st == GATE_UPPER) || (lo_off && st == GATE_LOWER)) {
                st = GATE_NONE;
            }
            if (st != prev) {
                leg->tick[n] = leg->tick[k];
                leg->state[n] = st;
                n++;
                prev = st;
            }
        }
        leg->n_edges = n;
    }
}
