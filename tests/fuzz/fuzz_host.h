/* fuzz_host.h - an fw_host application object for the fuzz harnesses, set up the way
 * firmware_c2000/hal_host/main.c sets up its own (core, ADC assembly, no console client,
 * a unixcan bus of its own that nobody else is on: PWM and status frames go nowhere). */
#ifndef FUZZ_HOST_H
#define FUZZ_HOST_H

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fw_host.h"

static fwh_t fuzz_app;
static hilbus_t *fuzz_bus;

static void fuzz_host_reset(void)
{
    if (fuzz_bus == NULL) {
        char dir[64], err[256];
        snprintf(dir, sizeof dir, "/tmp/hil-fuzz-%ld", (long)getpid());
        setenv("UNIXCAN_DIR", dir, 1);
        fuzz_bus = hilbus_open("unixcan", "fuzz", err, sizeof err);
        if (fuzz_bus == NULL) {
            fprintf(stderr, "fuzz: %s\n", err);
            abort();
        }
    }
    memset(&fuzz_app, 0, sizeof fuzz_app);
    fw_core_init(&fuzz_app.core);
    fwh_adc_init(&fuzz_app.adc);
    fuzz_app.pty.master = -1;
    fuzz_app.bus = fuzz_bus;
    fuzz_app.opt.tlm_div = 1;
    fuzz_app.t0_ns = hil_now_ns();
    /* no line on stderr: 0 lines a second */
    hil_log_limit_init(&fuzz_app.log_limit, "fw_host", 0, fuzz_app.t0_ns);
}

#endif
