/* hil_json: the one-line JSON objects the rig's C programs report their counters in (at exit
 * on stderr, or into a caller's buffer), written member by member into a fixed buffer:
 *   {"program": "plant_rt", "periods": 3, "rejects": {"bad_length": 0}, "rt": "..."}
 * No allocation; a full buffer truncates (hil_json_end returns the length it would have).
 */
#ifndef HIL_JSON_H
#define HIL_JSON_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HIL_JSON_DEPTH 8

typedef struct {
    char *buf;
    size_t cap;
    size_t len;                    /* what was written, or would have been */
    int depth;                     /* open objects */
    int members[HIL_JSON_DEPTH];   /* members written in each open object */
} hil_json_t;

/* Starts the outer object in buf (cap bytes, cap > 0). */
void hil_json_init(hil_json_t *j, char *buf, size_t cap);
/* "key": value members of the innermost open object */
void hil_json_u64(hil_json_t *j, const char *key, uint64_t v);
void hil_json_str(hil_json_t *j, const char *key, const char *v);  /* v holds no '"' or '\' */
void hil_json_fmt(hil_json_t *j, const char *key, const char *fmt, double v); /* e.g. "%.1f" */
void hil_json_raw(hil_json_t *j, const char *key, const char *text); /* text as it is (null) */
/* A whole member already written as JSON text (`"faults": {...}`). */
void hil_json_member(hil_json_t *j, const char *member);
/* "key": {  ...  } */
void hil_json_open(hil_json_t *j, const char *key);
void hil_json_close(hil_json_t *j);
/* The counters counts[first..n-1] named name(k), as "key": {"name": count, ...}. */
void hil_json_counts(hil_json_t *j, const char *key, const char *(*name)(int), const uint64_t *counts,
                     int first, int n);
/* Closes every open object; returns the length (as snprintf: >= cap means truncated). */
size_t hil_json_end(hil_json_t *j);

#ifdef __cplusplus
}
#endif
#endif
