/* param_file.h - the host's parameter store: a text file of "name = value" lines.
 *
 * Grammar (one assignment per line, at most FWH_PARAM_LINE_MAX characters, no NUL byte; at
 * most FWH_PARAM_FILE_MAX bytes in all):
 *   line       = [ws] [assignment] [ws] ["#" comment]
 *   assignment = NAME [ws] "=" [ws] NUMBER
 * NAME is a parameter name of protocols/parameters.csv (writable ones only); NUMBER is a
 * decimal number: ["+"|"-"] (DIGITS ["." [DIGITS]] | "." DIGITS) [("e"|"E") ["+"|"-"] DIGITS].
 * A name may appear once per file. Values are range-checked against the parameter table
 * while parsing and applied all-or-nothing by fwh_params_apply().
 */
#ifndef PARAM_FILE_H
#define PARAM_FILE_H

#include <stddef.h>
#include <stdint.h>

#include "fw_core.h"

#define FWH_PARAM_LINE_MAX 255
#define FWH_PARAM_FILE_MAX (1L << 20) /* bytes: a file of every parameter is a few kB */
#define FWH_PARAM_ITEMS_MAX 256
#define FWH_PARAM_NAME_MAX 48

typedef struct {
    uint16_t id;
    real_t value;
    int line; /* 1-based line in the file, or the position of a --set (1-based) */
    char name[FWH_PARAM_NAME_MAX];
} fwh_param_item_t;

typedef struct {
    fwh_param_item_t items[FWH_PARAM_ITEMS_MAX];
    int n;
} fwh_param_list_t;

/* Strict decimal number (grammar above); 0 and *out finite, or -1. */
/* The parameter named `name` in the generated table, or NULL. */
const fw_param_info_t *fwh_param_by_name(const char *name);

int fwh_parse_number(const char *text, double *out);
/* Shortest decimal text that reads back as the same real_t (at most 16 characters). */
void fwh_fmt_real(char *buf, size_t len, real_t value);

/* Parses a parameter file. 0, or -1 with err = "FILE:LINE: field 'NAME': reason" (or
 * "FILE: reason" when the file cannot be read). */
int fwh_params_parse_file(const char *path, fwh_param_list_t *out, char *err, size_t errlen);
/* Parses one "name=value" (--set); same checks as a file line. 0, or -1 with a message. */
int fwh_params_parse_assignment(const char *text, fwh_param_item_t *item, char *err,
                                size_t errlen);

/* Applies every item, all or nothing, in whatever order the cross-parameter rules need
 * (e.g. raising both ld_h and lq_h). Items equal to the present value are skipped, so a
 * file of unchanged configuration loads while the drive is enabled; of two items for the same
 * parameter the later one is the one applied. Returns FW_STATUS_OK,
 * or the core's status for the first item that cannot be applied (*failed = its index);
 * *changed = number of parameters changed. */
int16_t fwh_params_apply(fw_core_t *core, const fwh_param_list_t *list, int *failed,
                         int *changed);

/* Writes every writable parameter to path atomically (temporary file, fsync, rename).
 * Returns the number written, or -1 with err set. */
int fwh_params_save(const fw_core_t *core, const char *path, char *err, size_t errlen);

#endif
