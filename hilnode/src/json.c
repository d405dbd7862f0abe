/* hil_json: see hil_json.h. */
#include "hil_json.h"

#include <stdarg.h>
#include <stdio.h>

static void put(hil_json_t *j, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void put(hil_json_t *j, const char *fmt, ...)
{
    va_list ap;
    int w;
    va_start(ap, fmt);
    w = vsnprintf(j->buf + (j->len < j->cap ? j->len : j->cap),
                  j->len < j->cap ? j->cap - j->len : 0, fmt, ap);
    va_end(ap);
    j->len += w > 0 ? (size_t)w : 0;
}

/* the separator before a member, and its key */
static void key(hil_json_t *j, const char *k)
{
    put(j, "%s\"%s\": ", j->members[j->depth]++ ? ", " : "", k);
}

void hil_json_init(hil_json_t *j, char *buf, size_t cap)
{
    j->buf = buf;
    j->cap = cap;
    j->len = 0;
    j->depth = 0;
    j->members[0] = 0;
    buf[0] = '\0';
    put(j, "{");
}

void hil_json_u64(hil_json_t *j, const char *k, uint64_t v)
{
    key(j, k);
    put(j, "%llu", (unsigned long long)v);
}

void hil_json_str(hil_json_t *j, const char *k, const char *v)
{
    key(j, k);
    put(j, "\"%s\"", v);
}

void hil_json_fmt(hil_json_t *j, const char *k, const char *fmt, double v)
{
    key(j, k);
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wformat-nonliteral"
    put(j, fmt, v);
#pragma GCC diagnostic pop
}

void hil_json_raw(hil_json_t *j, const char *k, const char *text)
{
    key(j, k);
    put(j, "%s", text);
}

void hil_json_member(hil_json_t *j, const char *member)
{
    put(j, "%s%s", j->members[j->depth]++ ? ", " : "", member);
}

void hil_json_open(hil_json_t *j, const char *k)
{
    key(j, k);
    put(j, "{");
    if (j->depth + 1 < HIL_JSON_DEPTH) {
        j->members[++j->depth] = 0;
    }
}

void hil_json_close(hil_json_t *j)
{
    put(j, "}");
    if (j->depth > 0) {
        j->depth--;
    }
}

void hil_json_counts(hil_json_t *j, const char *k, const char *(*name)(int), const uint64_t *counts,
                     int first, int n)
{
    int i;
    hil_json_open(j, k);
    for (i = first; i < n; i++) {
        hil_json_u64(j, name(i), counts[i]);
    }
    hil_json_close(j);
}

size_t hil_json_end(hil_json_t *j)
{
    while (j->depth > 0) {
        hil_json_close(j);
    }
    put(j, "}");
    return j->len;
}
