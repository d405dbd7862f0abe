/* param_file.c - parse, apply and save parameter files (see param_file.h). */
#define _POSIX_C_SOURCE 200809L /* fileno, fsync, getpid */
#include "param_file.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static fw_core_t scratch; /* candidate state of an all-or-nothing apply */

int fwh_parse_number(const char *s, double *out)
{
    const char *p = s;
    int digits = 0;
    char *end;
    double v;
    if (*p == '+' || *p == '-') {
        p++;
    }
    while (isdigit((unsigned char)*p)) {
        p++, digits++;
    }
    if (*p == '.') {
        p++;
        while (isdigit((unsigned char)*p)) {
            p++, digits++;
        }
    }
    if (digits == 0) {
        return -1;
    }
    if (*p == 'e' || *p == 'E') {
        int exp_digits = 0;
        p++;
        if (*p == '+' || *p == '-') {
            p++;
        }
        while (isdigit((unsigned char)*p)) {
            p++, exp_digits++;
        }
        if (exp_digits == 0) {
            return -1;
        }
    }
    if (*p != '\0') {
        return -1;
    }
    errno = 0;
    v = strtod(s, &end);
    if (end != p || !isfinite(v)) {
        return -1;
    }
    *out = v;
    return 0;
}

void fwh_fmt_real(char *buf, size_t len, real_t value)
{
    int prec;
    for (prec = 6; prec <= 9; prec++) {
        snprintf(buf, len, "%.*g", prec, (double)value);
        if ((real_t)strtod(buf, NULL) == value) {
            return;
        }
    }
}

static int valid_name(const char *s)
{
    if (!islower((unsigned char)*s)) {
        return 0;
    }
    for (; *s; s++) {
        if (!islower((unsigned char)*s) && !isdigit((unsigned char)*s) && *s != '_') {
            return 0;
        }
    }
    return 1;
}

const fw_param_info_t *fwh_param_by_name(const char *name)
{
    uint16_t i;
    const fw_param_info_t *p;
    for (i = 0; (p = fw_param_info_at(i)) != NULL; i++) {
        if (strcmp(p->name, name) == 0) {
            return p;
        }
    }
    return NULL;
}

/* "name = value" without comment, trimmed. 0 or -1 with a reason (and *field set when the
 * name was read). */
static int parse_assignment(char *text, fwh_param_item_t *item, char *why, size_t whylen,
                            const char **field)
{
    char *eq = strchr(text, '=');
    char *name = text, *value, *e;
    const fw_param_info_t *info;
    double v;
    char lo[32], hi[32];
    *field = NULL;
    if (eq == NULL) {
        snprintf(why, whylen, "expected 'name = value'");
        return -1;
    }
    *eq = '\0';
    value = eq + 1;
    for (e = eq; e > name && isspace((unsigned char)e[-1]); e--) {
        e[-1] = '\0';
    }
    while (isspace((unsigned char)*value)) {
        value++;
    }
    if (*name == '\0' || !valid_name(name) || strlen(name) >= FWH_PARAM_NAME_MAX) {
        snprintf(why, whylen, "expected 'name = value' (name: lower-case letters, digits, _)");
        return -1;
    }
    *field = name;
    info = fwh_param_by_name(name);
    if (info == NULL) {
        snprintf(why, whylen, "unknown parameter");
        return -1;
    }
    if (info->read_only) {
        snprintf(why, whylen, "read-only parameter");
        return -1;
    }
    if (*value == '\0' || fwh_parse_number(value, &v) != 0) {
        snprintf(why, whylen, "value '%.40s' is not a decimal number", value);
        return -1;
    }
    if (!((real_t)v >= info->min && (real_t)v <= info->max)) {
        fwh_fmt_real(lo, sizeof(lo), info->min);
        fwh_fmt_real(hi, sizeof(hi), info->max);
        snprintf(why, whylen, "value %.40s outside [%s, %s] %s", value, lo, hi, info->unit);
        return -1;
    }
    item->id = info->id;
    item->value = (real_t)v;
    snprintf(item->name, sizeof(item->name), "%s", info->name);
    return 0;
}

static void trim(char *s)
{
    size_t n = strlen(s), i = 0;
    while (n > 0 && isspace((unsigned char)s[n - 1])) {
        s[--n] = '\0';
    }
    while (isspace((unsigned char)s[i])) {
        i++;
    }
    memmove(s, s + i, n - i + 1);
}

int fwh_params_parse_assignment(const char *text, fwh_param_item_t *item, char *err,
                                size_t errlen)
{
    char buf[FWH_PARAM_LINE_MAX + 1], why[160];
    const char *field;
    if (strlen(text) > FWH_PARAM_LINE_MAX) {
        snprintf(err, errlen, "--set %.40s...: longer than %d characters", text,
                 FWH_PARAM_LINE_MAX);
        return -1;
    }
    snprintf(buf, sizeof(buf), "%s", text);
    trim(buf);
    if (parse_assignment(buf, item, why, sizeof(why), &field) != 0) {
        if (field) {
            snprintf(err, errlen, "--set %s: field '%s': %s", text, field, why);
        } else {
            snprintf(err, errlen, "--set %s: %s", text, why);
        }
        return -1;
    }
    return 0;
}

typedef enum { LINE_OK, LINE_END, LINE_TOO_LONG, LINE_NUL, LINE_FILE_TOO_LONG } line_read_t;

/* One line of the file into buf (NUL-terminated, without its newline), byte by byte: a NUL
 * byte is named as such (with fgets it looked like an overlong line), and the whole file is
 * bounded (FWH_PARAM_FILE_MAX bytes: --params /dev/zero looped for ever). */
static line_read_t read_line(FILE *f, char *buf, size_t size, long *bytes)
{
    size_t n = 0;
    int c;
    while ((c = getc(f)) != EOF) {
        if (++*bytes > FWH_PARAM_FILE_MAX) {
            return LINE_FILE_TOO_LONG;
        }
        if (c == '\n') {
            break;
        }
        if (c == '\0') {
            return LINE_NUL;
        }
        if (n + 1 >= size) {
            return LINE_TOO_LONG;
        }
        buf[n++] = (char)c;
    }
    if (c == EOF && n == 0) {
        return LINE_END;
    }
    buf[n] = '\0';
    return LINE_OK;
}

int fwh_params_parse_file(const char *path, fwh_param_list_t *out, char *err, size_t errlen)
{
    FILE *f = fopen(path, "r");
    char buf[FWH_PARAM_LINE_MAX + 1], why[160];
    int line = 0, rc = 0, i;
    long bytes = 0;
    line_read_t got;
    out->n = 0;
    if (f == NULL) {
        snprintf(err, errlen, "%s: cannot read: %s", path, strerror(errno));
        return -1;
    }
    while ((got = read_line(f, buf, sizeof(buf), &bytes)) != LINE_END) {
        char *hash;
        const char *field;
        fwh_param_item_t item;
        line++;
        if (got == LINE_TOO_LONG) {
            snprintf(err, errlen, "%s:%d: line longer than %d characters", path, line,
                     FWH_PARAM_LINE_MAX);
            rc = -1;
            break;
        }
        if (got == LINE_NUL) {
            snprintf(err, errlen, "%s:%d: a NUL byte (not a text file)", path, line);
            rc = -1;
            break;
        }
        if (got == LINE_FILE_TOO_LONG) {
            snprintf(err, errlen, "%s: longer than %ld bytes (not a parameter file)", path,
                     (long)FWH_PARAM_FILE_MAX);
            rc = -1;
            break;
        }
        hash = strchr(buf, '#');
        if (hash) {
            *hash = '\0';
        }
        trim(buf);
        if (buf[0] == '\0') {
            continue;
        }
        memset(&item, 0, sizeof(item));
        if (parse_assignment(buf, &item, why, sizeof(why), &field) != 0) {
            if (field) {
                snprintf(err, errlen, "%s:%d: field '%s': %s", path, line, field, why);
            } else {
                snprintf(err, errlen, "%s:%d: %s", path, line, why);
            }
            rc = -1;
            break;
        }
        item.line = line;
        for (i = 0; i < out->n; i++) {
            if (out->items[i].id == item.id) {
                snprintf(err, errlen, "%s:%d: field '%s': set twice (first on line %d)", path,
                         line, item.name, out->items[i].line);
                rc = -1;
                break;
            }
        }
        if (rc != 0) {
            break;
        }
        if (out->n >= FWH_PARAM_ITEMS_MAX) {
            snprintf(err, errlen, "%s:%d: too many assignments", path, line);
            rc = -1;
            break;
        }
        out->items[out->n++] = item;
    }
    if (rc == 0 && ferror(f)) {
        snprintf(err, errlen, "%s: read error", path);
        rc = -1;
    }
    fclose(f);
    return rc;
}

int16_t fwh_params_apply(fw_core_t *core, const fwh_param_list_t *list, int *failed,
                         int *changed)
{
    unsigned char pending[FWH_PARAM_ITEMS_MAX];
    int order[FWH_PARAM_ITEMS_MAX];
    int i, left = 0, progress = 1, n_order = 0;
    *failed = -1;
    *changed = 0;
    /* dry run on a copy of the core (opaque storage: a byte copy) */
    memcpy(&scratch, core, sizeof(scratch));
    for (i = 0; i < list->n; i++) {
        real_t now;
        int j, superseded = 0;
        /* a later assignment of the same parameter wins (the bench's hardware values come
         * first, a scenario's own settings after them): an earlier one is not applied, or a
         * later "deadtime_us=0" equal to the default was skipped and the earlier 2 stayed */
        for (j = i + 1; j < list->n; j++) {
            superseded |= (list->items[j].id == list->items[i].id);
        }
        pending[i] = (unsigned char)(!superseded &&
                                     (fw_param_get(&scratch, list->items[i].id, &now) !=
                                          FW_STATUS_OK ||
                                      now != list->items[i].value));
        left += pending[i];
    }
    /* cross-parameter rules can make the order matter: retry until nothing moves */
    while (left > 0 && progress) {
        progress = 0;
        for (i = 0; i < list->n; i++) {
            if (pending[i] &&
                fw_param_set(&scratch, list->items[i].id, list->items[i].value) ==
                    FW_STATUS_OK) {
                pending[i] = 0;
                left--;
                order[n_order++] = i;
                progress = 1;
            }
        }
    }
    if (left > 0) {
        for (i = 0; i < list->n; i++) {
            if (pending[i]) {
                *failed = i;
                return fw_param_set(&scratch, list->items[i].id, list->items[i].value);
            }
        }
    }
    /* the same writes, in the order that worked, on the real core */
    for (i = 0; i < n_order; i++) {
        const fwh_param_item_t *it = &list->items[order[i]];
        int16_t st = fw_param_set(core, it->id, it->value);
        if (st != FW_STATUS_OK) { /* cannot happen: same state, same writes */
            *failed = order[i];
            *changed = i;
            return st;
        }
    }
    *changed = n_order;
    return FW_STATUS_OK;
}

int fwh_params_save(const fw_core_t *core, const char *path, char *err, size_t errlen)
{
    char tmp[4096], num[32];
    FILE *f;
    uint16_t i;
    int n = 0, ok;
    const fw_param_info_t *p;
    if ((size_t)snprintf(tmp, sizeof(tmp), "%s.tmp.%ld", path, (long)getpid()) >= sizeof(tmp)) {
        snprintf(err, errlen, "%s: path too long", path);
        return -1;
    }
    f = fopen(tmp, "w");
    if (f == NULL) {
        snprintf(err, errlen, "%s: cannot create: %s", tmp, strerror(errno));
        return -1;
    }
    fprintf(f, "# fw_host parameter file: name = value (protocols/parameters.csv names)\n"
               "# written by SAVE; read at start with --params and by LOAD\n");
    for (i = 0; (p = fw_param_info_at(i)) != NULL; i++) {
        real_t v;
        if (p->read_only || fw_param_get(core, p->id, &v) != FW_STATUS_OK) {
            continue;
        }
        fwh_fmt_real(num, sizeof(num), v);
        fprintf(f, "%s = %s  # %s\n", p->name, num, p->unit);
        n++;
    }
    ok = fflush(f) == 0 && !ferror(f) && fsync(fileno(f)) == 0;
    ok = (fclose(f) == 0) && ok;
    if (!ok || rename(tmp, path) != 0) {
        snprintf(err, errlen, "%s: cannot write: %s", path, strerror(errno));
        unlink(tmp);
        return -1;
    }
    return n;
}
