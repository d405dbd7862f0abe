/* libFuzzer harness: the host's parameter file (param_file.c): the parser on a file with the
 * input as content, applying what it accepts to a fresh core, and one "name=value" --set. */
#define _POSIX_C_SOURCE 200809L /* setenv, getpid */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "param_file.h"

static fwh_param_list_t list;
static fw_core_t core;

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static char path[64];
    char err[512], text[FWH_PARAM_LINE_MAX + 2];
    fwh_param_item_t item;
    FILE *f;
    int failed = 0, changed = 0;
    if (path[0] == '\0') {
        snprintf(path, sizeof path, "/tmp/hil-fuzz-params-%ld.txt", (long)getpid());
    }
    f = fopen(path, "wb");
    if (f == NULL || fwrite(data, 1, size, f) != size || fclose(f) != 0) {
        abort();
    }
    memset(&list, 0, sizeof list);
    if (fwh_params_parse_file(path, &list, err, sizeof err) == 0) {
        fw_core_init(&core);
        (void)fwh_params_apply(&core, &list, &failed, &changed);
    }
    size = size < sizeof text - 1 ? size : sizeof text - 1;
    memcpy(text, data, size);
    text[size] = '\0';
    (void)fwh_params_parse_assignment(text, &item, err, sizeof err);
    return 0;
}
