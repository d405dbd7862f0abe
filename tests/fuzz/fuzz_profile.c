/* libFuzzer harness: plant_rt's profile loader (config.c, the flat-TOML subset the
 * profiles in plant_rt/profiles use): a file with the input as content, then the cross-field check
 * and the flux-map set-up it leads to, and the input as one --set section.key=value. */
#define _POSIX_C_SOURCE 200809L /* setenv, getpid */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "plant_core.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static char path[64];
    static plant_config_t cfg;
    char err[512], text[256];
    FILE *f;
    if (path[0] == '\0') {
        snprintf(path, sizeof path, "/tmp/hil-fuzz-profile-%ld.toml", (long)getpid());
    }
    f = fopen(path, "wb");
    if (f == NULL || fwrite(data, 1, size, f) != size || fclose(f) != 0) {
        abort();
    }
    plant_config_defaults(&cfg);
    if (plant_config_load(&cfg, path, err, sizeof err) == 0) {
        (void)plant_config_check(&cfg, err, sizeof err);
    }
    size = size < sizeof text - 1 ? size : sizeof text - 1;
    memcpy(text, data, size);
    text[size] = '\0';
    plant_config_defaults(&cfg);
    (void)plant_config_set(&cfg, text, err, sizeof err);
    return 0;
}
