/* plant_link: the plant's side of the virtual-I/O wires under fault injection (FAULT_CMD,
 * protocols/bench.dbc), and the exchange ADC(k) -> PWM(k+1) that paces a lockstep period.
 *
 * Shared by plant_rt (bus) and the in-process bench (bench/): both hand the link the same
 * frames in the same order, so a fault acts on the same period with the same result.
 *
 * - FAULT_CMD: frame faults are kept here, physical ones go to the plant (plant_set_fault).
 * - ADC out (plant_link_adc_out): the period's VIO_ADC frames under the frame faults on them
 *   (dropped, XOR-corrupted, or held back and delivered after the frames of a later period).
 * - PWM in (plant_link_pwm): the frame that carries PWM(k+1) is kept as it came; the frame
 *   faults on VIO_PWM act on it when period k+1 is about to run (plant_link_commit), with
 *   the faults in force then (a FAULT_CMD always arrives before the period it starts, but
 *   the frame may come before or after it): dropped (the previous command stays: the compare
 *   registers keep their values), corrupted (then checked; refused: the previous command
 *   stays), or applied d periods late (PWM(k+1) runs in period k+1+d; until the first is
 *   due, the previous command).
 * - Pacing: without faults on VIO_ADC the plant waits for PWM(k+1), as always (a frame that
 *   fails the checks while no fault acts on VIO_PWM is refused and the plant goes on
 *   waiting). Once a frame fault on VIO_ADC was commanded, whether the firmware answers a
 *   period is no longer known in advance (it may refuse a corrupted frame, a period may be
 *   missing), so from then on every exchange ends with a barrier (plant_link_barrier:
 *   plant_rt sends VIO_SYNC and waits for VIO_SYNC_ACK; in process the firmware has run when
 *   the frames are fed), plant_link_resolve; without PWM(k+1) the previous command stays.
 *
 * No I/O, no allocation.
 */
#ifndef PLANT_LINK_H
#define PLANT_LINK_H

#include <linux/can.h>
#include <stddef.h>
#include <stdint.h>

#include "plant_vio.h" /* plant_core.h, the reasons a frame is refused */

#ifdef __cplusplus
extern "C" {
#endif

/* Room for frames and commands held back by FRAME_DELAY (a C test holds the DBC's largest
 * FAULT_CMD.delay to it: 3 VIO_ADC frames per period, one PWM command per period). */
#define PLANT_LINK_HELD_MAX 512
#define PLANT_LINK_PWM_QUEUE 128

typedef struct plant_link_slot {
    int kind;         /* FAULT_CMD kind (a frame kind), NONE when free */
    uint32_t id;      /* CAN id of the message it acts on */
    uint32_t delay;   /* FRAME_DELAY: periods */
    uint32_t byte;    /* FRAME_CORRUPT: first data byte of the 32-bit little-endian word */
    uint32_t xor_mask;
} plant_link_slot_t;

typedef struct plant_link_stats {
    uint64_t fault_cmds;   /* FAULT_CMD frames taken */
    uint64_t dropped;      /* frames dropped by FRAME_LOSS */
    uint64_t delayed;      /* frames (ADC) or commands (PWM) held back by FRAME_DELAY */
    uint64_t corrupted;    /* frames XORed by FRAME_CORRUPT */
    uint64_t held;         /* periods run on the previous command: no usable PWM update */
    uint64_t overflow;     /* held-back frames or commands dropped for want of room */
    uint64_t syncs;        /* exchanges that ended with the barrier (plant_link_resolve) */
} plant_link_stats_t;

typedef struct plant_link {
    plant_link_slot_t slot[PLANT_FAULT_SLOTS];
    int barrier; /* sticky: a frame fault on VIO_ADC was commanded */
    struct {
        struct canfd_frame f;
        uint32_t due; /* sent after the frames of this period */
    } held[PLANT_LINK_HELD_MAX];
    int n_held;
    struct {
        plant_pwm_cmd_t cmd;
        uint32_t due; /* the period it runs in */
    } pwmq[PLANT_LINK_PWM_QUEUE];
    int n_pwmq;
    /* the exchange in progress: the command of period 'expect' */
    uint32_t expect;
    int decided;           /* the frame came (or the barrier ended the exchange) */
    int have_frame;        /* ... and 'frame' is PWM(expect) as it came (CAN FD: frame_fd) */
    int frame_fd;
    int have_cmd;          /* 'cmd' is the command already (the start-up command) */
    struct canfd_frame frame;
    plant_pwm_cmd_t cmd;
    plant_link_stats_t st;
} plant_link_t;

/* A decoded, range-checked FAULT_CMD. */
typedef struct plant_fault_cmd {
    int slot, kind, channel, phase, gate;
    uint32_t message; /* CAN id (frame kinds) */
    double value;
    uint32_t periods, delay, byte, xor_mask;
} plant_fault_cmd_t;

/* Checks a FAULT_CMD frame (CAN FD, DBC length and ranges; a frame kind must name VIO_PWM or
 * a VIO_ADC message, FRAME_DELAY a delay of at least one period, FRAME_CORRUPT a non-zero
 * mask). PLANT_REJ_NONE with *out filled, or PLANT_REJ_MALFORMED, _BAD_LENGTH, _OUT_OF_RANGE. */
int plant_decode_fault_cmd(int fd, const uint8_t *data, size_t len, plant_fault_cmd_t *out);

/* The start: no faults, period 0 runs on the start-up command (plant_startup_command). */
void plant_link_init(plant_link_t *l);

/* A FAULT_CMD frame: PLANT_REJ_NONE when taken, else the reason (nothing changes; err gets
 * the plant's message when it refused a physical fault's value). */
int plant_link_fault(plant_link_t *l, plant_t *plant, int fd, const uint8_t *data, size_t len,
                     char *err, size_t errlen);

/* The n VIO_ADC frames of period k (plant_pack_adc) as they leave the plant: out gets up to
 * max_out frames (the period's own, then held-back frames now due); returns how many. Starts
 * the exchange of the command of period k + 1. */
int plant_link_adc_out(plant_link_t *l, uint32_t k, const struct canfd_frame *in, int n,
                       struct canfd_frame *out, int max_out);

/* 1 when this exchange ends with the barrier (VIO_SYNC) instead of the wait for PWM(k+1). */
int plant_link_barrier(const plant_link_t *l);

/* A VIO_PWM frame (can_id without flags; CAN FD) while the exchange waits: returns
 * PLANT_REJ_NONE when it is PWM(k+1) (kept for plant_link_commit; the exchange is decided),
 * else the reason it was refused (count it; the plant goes on waiting). */
int plant_link_pwm(plant_link_t *l, const struct canfd_frame *f, int fd);

/* 1 when the exchange is decided: PWM(k+1) came, or the barrier ended it. */
int plant_link_decided(const plant_link_t *l);

/* The end of a barrier exchange (everything the firmware sent for it is in). */
void plant_link_resolve(plant_link_t *l);

/* The command of period k+1, just before it runs (or in real time, whenever a decided
 * exchange's period starts), with the VIO_PWM faults in force now; 'current' is the command
 * the last period ran on (it stays when no usable update came). Returns PLANT_REJ_NONE, or
 * the reason the (corrupted) update was refused (count it: the previous command stays). */
int plant_link_commit(plant_link_t *l, const plant_pwm_cmd_t *current, plant_pwm_cmd_t *out);

/* The statistics as one JSON member, "faults": {...} (the exit counters of plant_rt and of
 * the in-process bench). Returns the length (snprintf semantics). */
int plant_link_stats_json(const plant_link_t *l, char *buf, size_t len);

#ifdef __cplusplus
}
#endif
#endif
