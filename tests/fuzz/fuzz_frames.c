/* libFuzzer harness: the frame decoders of both programs. The input is a sequence of
 * struct canfd_frame records (72 bytes); each one that hilbus would deliver (a length a CAN
 * or CAN FD controller sends; FD when flags has CANFD_FDF) goes to
 *  - plant_rt's VIO_PWM decoder (plant_decode_pwm) and the generated unpack + range checks
 *    of every DBC message, and
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

static void unpack_all(const struct canfd_frame *f)
{
    union {
        struct hil_vio_vio_pwm_t pwm;
        struct hil_vio_vio_adc_0_t adc0;
        struct hil_vio_vio_adc_1_t adc1;
        struct hil_vio_vio_adc_2_t adc2;
        struct hil_bench_bench_step_t step;
        struct hil_bench_load_cmd_t load;
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
    (void)hil_drive_drive_cmd_unpack(&m.cmd, f->data, f->len);
    (void)hil_drive_drive_limits_unpack(&m.lim, f->data, f->len);
    (void)hil_drive_param_req_unpack(&m.req, f->data, f->len);
}

static int deliverable(const struct canfd_frame *f, int fd)
{
    return fd ? f->len <= CANFD_MAX_DLEN && hilbus_fd_len(f->len) == f->len
              : f->len <= CAN_MAX_DLEN;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t off;
    uint32_t expected = 0;
    fuzz_host_reset();
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
        if (f.can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) {
            continue;
        }
        if (fwh_bus_is_vio(f.can_id & CAN_SFF_MASK)) {
            fwh_bus_vio_frame(&fuzz_app, &f, fd, fwh_now_ns());
        } else if (fwh_drive_is_drive(f.can_id & CAN_SFF_MASK)) {
            fwh_drive_frame(&fuzz_app, &f, fd);
        }
    }
    return 0;
}
