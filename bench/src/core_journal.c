/* core_journal.c - see core_journal.h. */
#include "core_journal.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct core_journal {
    FILE *f;
    int failed;
    uint32_t n_isr; /* fw_core_isr calls so far */
    int n_win;
    uint32_t start[CORE_JOURNAL_WINDOWS_MAX], len[CORE_JOURNAL_WINDOWS_MAX];
    int snapshotted[CORE_JOURNAL_WINDOWS_MAX];
};

static void put(core_journal_t *j, const void *data, size_t len)
{
    static const uint8_t zero[4] = {0, 0, 0, 0};
    if (fwrite(data, 1, len, j->f) != len) {
        j->failed = 1;
    }
    if (len % 4u != 0u && fwrite(zero, 1, 4u - len % 4u, j->f) != 4u - len % 4u) {
        j->failed = 1;
    }
}

static void put_u32(core_journal_t *j, uint32_t v) { put(j, &v, sizeof(v)); }

static void tag(core_journal_t *j, char t)
{
    put_u32(j, (uint32_t)(uint8_t)t);
    put_u32(j, j->n_isr);
}

static int in_window(const core_journal_t *j)
{
    int w;
    if (j->n_win == 0) {
        return 1;
    }
    for (w = 0; w < j->n_win; w++) {
        if (j->n_isr >= j->start[w] && j->n_isr - j->start[w] < j->len[w]) {
            return 1;
        }
    }
    return 0;
}

uint32_t core_journal_crc32(const void *data, size_t len)
{
    static uint32_t table[256];
    static int ready = 0;
    const uint8_t *p = (const uint8_t *)data;
    uint32_t c = 0xFFFFFFFFu;
    size_t i;
    if (!ready) {
        uint32_t n, k;
        for (n = 0; n < 256u; n++) {
            uint32_t v = n;
            for (k = 0; k < 8u; k++) {
                v = (v & 1u) ? 0xEDB88320u ^ (v >> 1) : v >> 1;
            }
            table[n] = v;
        }
        ready = 1;
    }
    for (i = 0; i < len; i++) {
        c = table[(c ^ p[i]) & 0xFFu] ^ (c >> 8);
    }
    return c ^ 0xFFFFFFFFu;
}

core_journal_t *core_journal_open(const char *path, const fw_core_t *core,
                                  const uint32_t *win_start, const uint32_t *win_len, int n_win,
                                  char *err, size_t errlen)
{
    core_journal_t *j;
    const uint32_t sizes[5] = {(uint32_t)sizeof(fw_core_t), (uint32_t)sizeof(fw_adc_t),
                               (uint32_t)sizeof(fw_pwm_t), (uint32_t)sizeof(fw_cmd_t),
                               (uint32_t)sizeof(fw_status_t)};
    uint16_t i;
    int w;
    if (n_win < 0 || n_win > CORE_JOURNAL_WINDOWS_MAX) {
        snprintf(err, errlen, "journal: %d windows (0..%d)", n_win, CORE_JOURNAL_WINDOWS_MAX);
        return NULL;
    }
    j = (core_journal_t *)calloc(1, sizeof(*j));
    if (j == NULL) {
        snprintf(err, errlen, "journal: out of memory");
        return NULL;
    }
    for (w = 0; w < n_win; w++) {
        j->start[w] = win_start[w];
        j->len[w] = win_len[w];
    }
    j->n_win = n_win;
    j->f = fopen(path, "wb");
    if (j->f == NULL) {
        snprintf(err, errlen, "journal: cannot create %s: %s", path, strerror(errno));
        free(j);
        return NULL;
    }
    put(j, "FWJ1", 4);
    put_u32(j, CORE_JOURNAL_VERSION);
    put(j, sizes, sizeof(sizes));
    for (i = 0; i < fw_param_count(); i++) {
        const fw_param_info_t *info = fw_param_info_at(i);
        real_t v;
        if (fw_param_get(core, info->id, &v) == FW_STATUS_OK && v != info->def) {
            tag(j, 'P');
            put_u32(j, info->id);
            put(j, &v, sizeof(v));
        }
    }
    return j;
}

int core_journal_close(core_journal_t *j)
{
    int rc;
    if (j == NULL) {
        return 0;
    }
    rc = (fclose(j->f) != 0 || j->failed) ? -1 : 0;
    free(j);
    return rc;
}

void core_journal_before(core_journal_t *j, const fw_core_t *core)
{
    int w;
    if (j == NULL) {
        return;
    }
    if (j->n_win == 0 && !j->snapshotted[0]) {
        j->snapshotted[0] = 1;
        tag(j, 'S');
        put(j, core, sizeof(*core));
        return;
    }
    for (w = 0; w < j->n_win; w++) {
        if (!j->snapshotted[w] && j->n_isr >= j->start[w] && j->n_isr - j->start[w] < j->len[w]) {
            j->snapshotted[w] = 1;
            tag(j, 'S');
            put(j, core, sizeof(*core));
        }
    }
}

void core_journal_isr(core_journal_t *j, const fw_core_t *core, const fw_adc_t *adc,
                      const fw_pwm_t *pwm)
{
    fw_adc_t none;
    fw_status_t s;
    if (j == NULL) {
        return;
    }
    if (in_window(j)) {
        memset(&none, 0, sizeof(none));
        fw_core_status(core, &s);
        tag(j, 'I');
        put_u32(j, adc != NULL);
        put(j, adc != NULL ? adc : &none, sizeof(none));
        put(j, pwm, sizeof(*pwm));
        put_u32(j, core_journal_crc32(core, sizeof(*core)));
        put_u32(j, (uint32_t)(int32_t)s.state);
    }
    j->n_isr++;
}

void core_journal_command(core_journal_t *j, const fw_cmd_t *cmd, int16_t status)
{
    if (j != NULL && in_window(j)) {
        tag(j, 'C');
        put(j, cmd, sizeof(*cmd));
        put_u32(j, (uint32_t)(int32_t)status);
    }
}

void core_journal_limits(core_journal_t *j, real_t i_max, real_t speed_max_rpm,
                         real_t accel_rpm_s, int16_t status)
{
    if (j != NULL && in_window(j)) {
        const real_t v[3] = {i_max, speed_max_rpm, accel_rpm_s};
        tag(j, 'L');
        put(j, v, sizeof(v));
        put_u32(j, (uint32_t)(int32_t)status);
    }
}
