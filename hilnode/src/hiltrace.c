/* hiltrace: buffered writer of the binary trace format (docs/interfaces.md). */
#define _GNU_SOURCE
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hiltrace.h"

struct hiltrace {
    FILE *file;
    int failed;
};

hiltrace_t *hiltrace_open(const char *path)
{
    FILE *f = fopen(path, "wb");
    if (f == NULL) return NULL;
    struct hiltrace *t = calloc(1, sizeof *t);
    if (t == NULL) {
        fclose(f);
        return NULL;
    }
    t->file = f;
    setvbuf(f, NULL, _IOFBF, 1 << 20);
    unsigned char header[16];
    uint32_t version = 1, record = (uint32_t)sizeof(struct canfd_frame);
    memcpy(header, "HILTRACE", 8);
    memcpy(header + 8, &version, 4); /* little-endian hosts only, as the reader assumes */
    memcpy(header + 12, &record, 4);
    if (fwrite(header, sizeof header, 1, f) != 1) t->failed = 1;
    return t;
}

int hiltrace_write(hiltrace_t *t, const struct canfd_frame *frame)
{
    if (fwrite(frame, sizeof *frame, 1, t->file) != 1) t->failed = 1;
    return t->failed ? -1 : 0;
}

int hiltrace_flush(hiltrace_t *t)
{
    if (fflush(t->file) != 0) t->failed = 1;
    return t->failed ? -1 : 0;
}

int hiltrace_close(hiltrace_t *t)
{
    if (t == NULL) return 0;
    if (fclose(t->file) != 0) t->failed = 1;
    int rc = t->failed ? -1 : 0;
    free(t);
    return rc;
}
