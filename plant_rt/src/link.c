/* plant_link: see plant_link.h. */
#include "plant_link.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "hil_bench.h"
#include "hil_vio.h"
#include "plant_vio.h"

static int frame_kind(int kind)
{
    return kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_LOSS_CHOICE ||
           kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_DELAY_CHOICE ||
           kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_CORRUPT_CHOICE;
}

static int adc_id(uint32_t id)
{
    return id == HIL_VIO_VIO_ADC_0_FRAME_ID || id == HIL_VIO_VIO_ADC_1_FRAME_ID ||
           id == HIL_VIO_VIO_ADC_2_FRAME_ID;
}

int plant_decode_fault_cmd(int fd, const uint8_t *data, size_t len, plant_fault_cmd_t *out)
{
    struct hil_bench_fault_cmd_t m;
    if (!fd) {
        return PLANT_REJ_MALFORMED; /* FAULT_CMD is a CAN FD frame */
    }
    if (len != HIL_BENCH_FAULT_CMD_LENGTH) {
        return PLANT_REJ_BAD_LENGTH;
    }
    hil_bench_fault_cmd_unpack(&m, data, len);
    if (!hil_bench_fault_cmd_slot_is_in_range(m.slot) ||
        !hil_bench_fault_cmd_kind_is_in_range(m.kind) ||
        !hil_bench_fault_cmd_channel_is_in_range(m.channel) ||
        !hil_bench_fault_cmd_phase_is_in_range(m.phase) ||
        !hil_bench_fault_cmd_gate_is_in_range(m.gate) ||
        !hil_bench_fault_cmd_message_is_in_range(m.message) ||
        !hil_bench_fault_cmd_value_is_in_range(m.value) || !isfinite(m.value) ||
        !hil_bench_fault_cmd_periods_is_in_range(m.periods) ||
        !hil_bench_fault_cmd_delay_is_in_range(m.delay) ||
        !hil_bench_fault_cmd_byte_is_in_range(m.byte) || m.slot >= PLANT_FAULT_SLOTS) {
        return PLANT_REJ_OUT_OF_RANGE;
    }
    if (frame_kind(m.kind) &&
        ((m.message != HIL_VIO_VIO_PWM_FRAME_ID && !adc_id(m.message)) ||
         (m.kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_DELAY_CHOICE && m.delay == 0) ||
         (m.kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_CORRUPT_CHOICE && m.xor == 0))) {
        return PLANT_REJ_OUT_OF_RANGE;
    }
    out->slot = m.slot;
    out->kind = m.kind;
    out->channel = m.channel;
    out->phase = m.phase;
    out->gate = m.gate;
    out->message = m.message;
    out->value = m.value;
    out->periods = m.periods;
    out->delay = m.delay;
    out->byte = m.byte;
    out->xor_mask = m.xor;
    return PLANT_REJ_NONE;
}

void plant_link_init(plant_link_t *l)
{
    memset(l, 0, sizeof(*l));
    /* period 0 runs on the start-up command (docs/interfaces.md) */
    plant_startup_command(&l->cmd);
    l->have_cmd = 1;
    l->decided = 1;
}

static int pwm_delay_active(const plant_link_t *l)
{
    int s;
    for (s = 0; s < PLANT_FAULT_SLOTS; ++s) {
        if (l->slot[s].kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_DELAY_CHOICE &&
            l->slot[s].id == HIL_VIO_VIO_PWM_FRAME_ID) {
            return 1;
        }
    }
    return 0;
}

int plant_link_fault(plant_link_t *l, plant_t *plant, int fd, const uint8_t *data, size_t len,
                     char *err, size_t errlen)
{
    plant_fault_cmd_t c;
    plant_link_slot_t sl;
    int r = plant_decode_fault_cmd(fd, data, len, &c);
    if (r != PLANT_REJ_NONE) {
        return r;
    }
    memset(&sl, 0, sizeof(sl));
    if (frame_kind(c.kind)) {
        sl.kind = c.kind;
        sl.id = c.message;
        sl.delay = c.delay;
        sl.byte = c.byte;
        sl.xor_mask = c.xor_mask;
        /* the slot no longer holds a physical fault */
        (void)plant_set_fault(plant, c.slot, HIL_BENCH_FAULT_CMD_KIND_NONE_CHOICE, 0, 0, 0, 0.0,
                              0, err, errlen);
    } else if (plant_set_fault(plant, c.slot, c.kind, c.channel, c.phase, c.gate, c.value,
                               c.periods, err, errlen) != 0) {
        return PLANT_REJ_OUT_OF_RANGE;
    }
    l->slot[c.slot] = sl;
    if (sl.kind != 0 && adc_id(sl.id)) {
        l->barrier = 1;
    }
    if (!pwm_delay_active(l)) {
        l->n_pwmq = 0; /* a PWM delay that ended: the held-back commands are stale */
    }
    l->st.fault_cmds++;
    return PLANT_REJ_NONE;
}

static void xor_word(struct canfd_frame *f, uint32_t byte, uint32_t mask)
{
    int k;
    for (k = 0; k < 4; ++k) {
        if (byte + (uint32_t)k < f->len) {
            f->data[byte + (uint32_t)k] ^= (uint8_t)(mask >> (8 * k));
        }
    }
}

int plant_link_adc_out(plant_link_t *l, uint32_t k, const struct canfd_frame *in, int n,
                       struct canfd_frame *out, int max_out)
{
    int i, s, n_out = 0, kept = 0;
    l->expect = k + 1u;
    l->decided = l->have_frame = l->have_cmd = 0;
    for (i = 0; i < n; ++i) {
        struct canfd_frame w = in[i];
        const uint32_t id = w.can_id & CAN_SFF_MASK;
        uint32_t delay = 0;
        int lost = 0;
        for (s = 0; s < PLANT_FAULT_SLOTS && !lost; ++s) {
            const plant_link_slot_t *sl = &l->slot[s];
            if (sl->kind == 0 || sl->id != id) {
                continue;
            }
            if (sl->kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_LOSS_CHOICE) {
                lost = 1;
            } else if (sl->kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_CORRUPT_CHOICE) {
                xor_word(&w, sl->byte, sl->xor_mask);
                l->st.corrupted++;
            } else {
                delay = sl->delay;
            }
        }
        if (lost) {
            l->st.dropped++;
        } else if (delay > 0) {
            if (l->n_held < PLANT_LINK_HELD_MAX) {
                l->held[l->n_held].f = w;
                l->held[l->n_held].due = k + delay;
                l->n_held++;
                l->st.delayed++;
            } else {
                l->st.overflow++;
            }
        } else if (n_out < max_out) {
            out[n_out++] = w;
        }
    }
    /* frames held back from earlier periods that are due now, in the order they were held */
    for (i = 0; i < l->n_held; ++i) {
        if ((int32_t)(l->held[i].due - k) <= 0 && n_out < max_out) {
            out[n_out++] = l->held[i].f;
        } else {
            l->held[kept++] = l->held[i];
        }
    }
    l->n_held = kept;
    return n_out;
}

int plant_link_barrier(const plant_link_t *l)
{
    return l->barrier;
}

int plant_link_decided(const plant_link_t *l)
{
    return l->decided;
}

static uint32_t raw_period(const struct canfd_frame *f)
{
    return f->len >= 4 ? (uint32_t)f->data[0] | ((uint32_t)f->data[1] << 8) |
                             ((uint32_t)f->data[2] << 16) | ((uint32_t)f->data[3] << 24)
                       : 0u;
}

static int pwm_fault_active(const plant_link_t *l)
{
    int s;
    for (s = 0; s < PLANT_FAULT_SLOTS; ++s) {
        if (l->slot[s].kind != 0 && l->slot[s].id == HIL_VIO_VIO_PWM_FRAME_ID) {
            return 1;
        }
    }
    return 0;
}

int plant_link_pwm(plant_link_t *l, const struct canfd_frame *f, int fd)
{
    const uint32_t id = f->can_id & CAN_SFF_MASK;
    plant_pwm_cmd_t cmd;
    const int r = plant_decode_pwm(id, fd, f->data, f->len, l->expect, &cmd);
    if (l->decided) {
        /* the exchange is over: a second PWM for its period is as late as any other */
        return r == PLANT_REJ_NONE ? PLANT_REJ_STALE_PERIOD : r;
    }
    if (id != HIL_VIO_VIO_PWM_FRAME_ID || raw_period(f) != l->expect ||
        (r != PLANT_REJ_NONE && !pwm_fault_active(l))) {
        return r; /* not PWM(k+1), or refused while no fault acts on it: wait on */
    }
    l->frame = *f;
    l->frame_fd = fd;
    l->have_frame = 1;
    l->decided = 1;
    return PLANT_REJ_NONE; /* (under a fault, its checks come at plant_link_commit) */
}

void plant_link_resolve(plant_link_t *l)
{
    l->st.syncs++;
    l->decided = 1;
}

/* The command of period 'expect' from the PWM delay queue, else the current one. */
static void from_queue(plant_link_t *l, const plant_pwm_cmd_t *current, plant_pwm_cmd_t *out)
{
    int i, kept = 0, found = -1;
    for (i = 0; i < l->n_pwmq; ++i) {
        if (l->pwmq[i].due == l->expect) {
            found = i;
        }
    }
    if (found >= 0) {
        *out = l->pwmq[found].cmd;
    } else {
        *out = *current;
        l->st.held++;
    }
    for (i = 0; i < l->n_pwmq; ++i) {
        if ((int32_t)(l->pwmq[i].due - l->expect) > 0) {
            l->pwmq[kept++] = l->pwmq[i];
        }
    }
    l->n_pwmq = kept;
}

int plant_link_commit(plant_link_t *l, const plant_pwm_cmd_t *current, plant_pwm_cmd_t *out)
{
    struct canfd_frame w = l->frame;
    plant_pwm_cmd_t cmd;
    uint32_t delay = 0;
    int s, r = PLANT_REJ_NONE, lost = 0, usable = 0;
    if (l->have_cmd) {
        *out = l->cmd; /* the start-up command */
    } else {
        if (l->have_frame) {
            const uint32_t id = w.can_id & CAN_SFF_MASK;
            for (s = 0; s < PLANT_FAULT_SLOTS && !lost; ++s) {
                const plant_link_slot_t *sl = &l->slot[s];
                if (sl->kind == 0 || sl->id != id) {
                    continue;
                }
                if (sl->kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_LOSS_CHOICE) {
                    lost = 1;
                    l->st.dropped++;
                } else if (sl->kind == HIL_BENCH_FAULT_CMD_KIND_FRAME_CORRUPT_CHOICE) {
                    xor_word(&w, sl->byte, sl->xor_mask);
                    l->st.corrupted++;
                } else {
                    delay = sl->delay;
                }
            }
            if (!lost) {
                r = plant_decode_pwm(id, l->frame_fd, w.data, w.len, l->expect, &cmd);
                usable = r == PLANT_REJ_NONE;
            }
        }
        if (usable && delay > 0) {
            if (l->n_pwmq < PLANT_LINK_PWM_QUEUE) {
                l->pwmq[l->n_pwmq].cmd = cmd;
                l->pwmq[l->n_pwmq].due = l->expect + delay;
                l->n_pwmq++;
                l->st.delayed++;
            } else {
                l->st.overflow++;
            }
            usable = 0;
        }
        if (usable) {
            *out = cmd;
        } else if (pwm_delay_active(l)) {
            from_queue(l, current, out);
        } else {
            *out = *current; /* no usable update: the compare registers keep their values */
            l->st.held++;
        }
    }
    out->period = l->expect;
    l->have_cmd = l->have_frame = 0;
    return r;
}

int plant_link_stats_json(const plant_link_t *l, char *buf, size_t len)
{
    return snprintf(buf, len,
                    "\"faults\": {\"commands\": %llu, \"frames_dropped\": %llu, "
                    "\"frames_delayed\": %llu, \"frames_corrupted\": %llu, "
                    "\"held_periods\": %llu, \"overflow\": %llu, \"barriers\": %llu}",
                    (unsigned long long)l->st.fault_cmds, (unsigned long long)l->st.dropped,
                    (unsigned long long)l->st.delayed, (unsigned long long)l->st.corrupted,
                    (unsigned long long)l->st.held, (unsigned long long)l->st.overflow,
                    (unsigned long long)l->st.syncs);
}
