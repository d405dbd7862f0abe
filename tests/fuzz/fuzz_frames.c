/* libFuzzer harness: the frame decoders of both programs. The input is a sequence of
 * struct canfd_frame records (72 bytes); each one that hilbus would deliver (a length a CAN
 * or CAN FD controller sends; FD when flags has CANFD_FDF) goes to
 *  - plant_rt's VIO_PWM decoder (plant_decode_pwm), its side of the wires under faults
 *    (plant_link.h: FAULT_CMD, the PWM exchange, the ADC frames out) on one plant per input,
 *    and the generated unpack + range checks of every DBC message, and
 *  - fw_host's receive path (extended/remote/error frames aside: ADC assembly, the drive
 *    protocol, the parameter requests), on one application object per input. */
#define _POSIX_C_SOURCE 200809L /* setenv, getpid */
#include <stddef.h>
#include <stdint.h>

#include "fuzz_host.h"
#include "hil_bench.h"
#include "hil_drive.h"
#include "hil_vio.h"
#include "plant_core.h"
#include "plant_link.h"
#include "plant_vio.h"

static void unpack_all(const struct canfd_frame *f)
{
    union {
        struct hil_vio_vio_pwm_t pwm;
        struct hil_vio_vio_adc_0_t adc0;
        struct hil_vio_vio_adc_1_t adc1;
        struct hil_vio_vio_adc_2_t adc2;
        struct hil_bench_bench_step_t step;
        struct hil_bench_load_cmd_t load;
        struct hil_bench_fault_cmd_t fault;
        struct hil_vio_vio_sync_t sync;
        struct hil_drive_drive_cmd_t cmd;
        struct hil_drive_drive_limits_t lim;
        struct hil_drive_param_req_t req;
    } m;
    (void)hil_vio_vio_pwm_unpack(&m.pwm, f->data, f->len);
    (void)hil_vio_vio_adc_0_unpack(&m.adc0, f->data, f->len);
    (void)hil_vio_vio_adc_1_unpack(&m.adc1, f->data, f->len);
    (void)hil_vio_vio_adc_2_unpack(&m.adc2, f->data, f->len);
    (void)hil_bench_bench_step_unpack(&m.step, f->data, f->len);
    (void)hil_bench_load_cmd_unpack(&m.load, f->data, f->len);
    (void)hil_bench_fault_cmd_unpack(&m.fault, f->data, f->len);
    (void)hil_vio_vio_sync_unpack(&m.sync, f->data, f->len);
    (void)hil_drive_drive_cmd_unpack(&m.cmd, f->data, f->len);
    (void)hil_drive_drive_limits_unpack(&m.lim, f->data, f->len);
    (void)hil_drive_param_req_unpack(&m.req, f->data, f->len);
}

static int deliverable(const struct canfd_frame *f, int fd)
{
    return fd ? f->len <= CANFD_MAX_DLEN && hilbus_fd_len(f->len) == f->len
              : f->len <= CAN_MAX_DLEN;
}

static plant_link_t wires; /* large: not on the stack */

/* The plant's side of the wires: a FAULT_CMD, or a frame offered as the PWM of the exchange;
 * then the period's (empty) ADC frames out, as plant_rt and the bench do. */
static void plant_side(plant_t *plant, const struct canfd_frame *f, int fd, uint32_t *k)
{
    static struct canfd_frame out[PLANT_VIO_ADC_FRAMES_MAX + PLANT_LINK_HELD_MAX];
    plant_pwm_cmd_t cur;
    char err[128];
    if ((f->can_id & CAN_SFF_MASK) == HIL_BENCH_FAULT_CMD_FRAME_ID) {
        (void)plant_link_fault(&wires, plant, fd, f->data, f->len, err, sizeof err);
        return;
    }
    plant_startup_command(&cur);
    (void)plant_link_pwm(&wires, f, fd);
    plant_link_resolve(&wires);
    (void)plant_link_commit(&wires, &cur, &cur);
    (void)plant_link_adc_out(&wires, (*k)++, f, 1, out,
                             (int)(sizeof(out) / sizeof(out[0])));
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t off;
    uint32_t expected = 0, k = 0;
    char err[128];
    plant_t *plant = plant_open(NULL, NULL, 0, err, sizeof err);
    fuzz_host_reset();
    plant_link_init(&wires);
    for (off = 0; off + sizeof(struct canfd_frame) <= size; off += sizeof(struct canfd_frame)) {
        struct canfd_frame f;
        plant_pwm_cmd_t cmd;
        int fd;
        memcpy(&f, data + off, sizeof f);
        fd = (f.flags & CANFD_FDF) != 0;
        if (!deliverable(&f, fd)) {
            continue;
        }
        if (plant_decode_pwm(f.can_id & CAN_SFF_MASK, fd, f.data, f.len, expected, &cmd) == 0) {
            expected = cmd.period + 1u;
        }
        unpack_all(&f);
        if (plant != NULL) {
            plant_side(plant, &f, fd, &k);
        }
        if (f.can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) {
            continue;
        }
        if (hil_vio_id_in_range(f.can_id & CAN_SFF_MASK)) {
            fwh_bus_vio_frame(&fuzz_app, &f, fd, hil_now_ns());
        } else if (hil_drive_id_in_range(f.can_id & CAN_SFF_MASK)) {
            fwh_drive_frame(&fuzz_app, &f, fd);
        }
    }
    plant_free(plant);
    return 0;
}
