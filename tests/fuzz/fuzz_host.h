/* fuzz_host.h - an fw_host application object for the fuzz harnesses, set up the way
 * firmware_c2000/hal_host/main.c sets up its own (core, ADC assembly, no console client),
 * with a sink that takes every frame and sends it nowhere (PWM and status frames). */
#ifndef FUZZ_HOST_H
#define FUZZ_HOST_H

#include <string.h>

#include "fw_host.h"

static fwh_t fuzz_app;

static int fuzz_sink_send(void *ctx, const struct canfd_frame *f, int fd)
{
    (void)ctx, (void)f, (void)fd;
    return 0;
}

static void fuzz_host_reset(void)
{
    memset(&fuzz_app, 0, sizeof fuzz_app);
    fw_core_init(&fuzz_app.core);
    fwh_adc_init(&fuzz_app.adc);
    fuzz_app.pty.master = -1;
    fuzz_app.sink.send = fuzz_sink_send;
    fuzz_app.opt.tlm_div = 1;
    fuzz_app.t0_ns = hil_now_ns();
    /* no line on stderr: 0 lines a second */
    hil_log_limit_init(&fuzz_app.log_limit, "fw_host", 0, fuzz_app.t0_ns);
}

#endif
