/* Fidelity-profile configuration: defaults, a flat-TOML subset loader and overrides.
 *
 * Accepted syntax (a subset of TOML that tomllib reads identically): blank lines,
 * comments from '#' to the end of a line, "[section]" headers and "key = number" lines,
 * numbers as TOML integers or floats (optional sign, '_' between digits, exponent).
 * Every key must be known, appear at most once per file and lie in its range; errors name
 * the file, the line and the field.
 */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "plant_internal.h"

enum { F_INT = 1, F_POSITIVE = 2 };

typedef struct field {
    const char *section;
    const char *key;
    size_t offset;
    double min, max;
    int flags;
} field_t;

#define FIELD(sec, key, min, max, flags) \
    { #sec, #key, offsetof(plant_config_t, sec.key), (min), (max), (flags) }

static const field_t FIELDS[] = {
    FIELD(machine, rs_ohm, 0.0, 100.0, 0),
    FIELD(machine, lambda_m_wb, 0.0, 10.0, 0),
    FIELD(machine, pole_pairs, 1.0, 64.0, F_INT),
    FIELD(magnetics, ld_h, 0.0, 10.0, F_POSITIVE),
    FIELD(magnetics, ld_sat_h, 0.0, 10.0, F_POSITIVE),
    FIELD(magnetics, ld_knee_a, -1000.0, 1000.0, 0),
    FIELD(magnetics, ld_width_a, 0.0, 1000.0, F_POSITIVE),
    FIELD(magnetics, lq_h, 0.0, 10.0, F_POSITIVE),
    FIELD(magnetics, lq_sat_per_a2, 0.0, 100.0, 0),
    FIELD(magnetics, lq_ext_from_a, 0.0, 1e6, F_POSITIVE),
    FIELD(magnetics, lq_inf_h, 0.0, 10.0, F_POSITIVE),
    FIELD(magnetics, ldq_ref_h, -1.0, 1.0, 0),
    FIELD(magnetics, cross_ref_a, 0.0, 1000.0, F_POSITIVE),
    FIELD(magnetics, cross_scale_a, 0.0, 10000.0, F_POSITIVE),
    FIELD(inverter, vdc_v, 0.0, 10000.0, F_POSITIVE),
    FIELD(inverter, dead_time_s, 0.0, 40e-6, 0),
    FIELD(inverter, device_drop_v, 0.0, 100.0, 0),
    FIELD(sensors, bandwidth_hz, 0.0, 1e9, 0),
    FIELD(sensors, gain_a, -10.0, 10.0, 0),
    FIELD(sensors, gain_b, -10.0, 10.0, 0),
    FIELD(sensors, offset_a_a, -100.0, 100.0, 0),
    FIELD(sensors, offset_b_a, -100.0, 100.0, 0),
    FIELD(sensors, noise_rms_a, 0.0, 100.0, 0),
    FIELD(sensors, ring_amp_a, 0.0, 100.0, 0),
    FIELD(sensors, ring_freq_hz, 0.0, 1e9, 0),
    FIELD(sensors, ring_tau_s, 0.0, 1e-3, F_POSITIVE),
    FIELD(sensors, ring_return_fraction, 0.0, 1.0, 0),
    FIELD(sensors, vdc_noise_rms_v, 0.0, 1000.0, 0),
    FIELD(sensors, seed, 0.0, 9007199254740991.0, F_INT),
    FIELD(adc, bits, 2.0, 24.0, F_INT),
    FIELD(adc, range_a, 0.0, 10000.0, F_POSITIVE),
    FIELD(adc, vdc_bits, 2.0, 23.0, F_INT),
    FIELD(adc, vdc_range_v, 0.0, 100000.0, F_POSITIVE),
    FIELD(shaft, j_kgm2, 0.0, 1000.0, F_POSITIVE),
    FIELD(shaft, b_nms, 0.0, 1000.0, 0),
    FIELD(shaft, j_load_kgm2, 0.0, 1000.0, 0),
    FIELD(shaft, b_load_nms, 0.0, 1000.0, 0),
    FIELD(load, mode, 0.0, 2.0, F_INT),
    FIELD(load, torque_nm, -1000.0, 1000.0, 0),
    FIELD(load, speed_rpm, -100000.0, 100000.0, 0),
    FIELD(load, k_speed_nms, 0.0, 1000.0, 0),
    FIELD(initial, theta_e_deg, -1e6, 1e6, 0),
    FIELD(initial, speed_rpm, -100000.0, 100000.0, 0),
    FIELD(solver, max_step_s, 1e-7, 1e-4, 0),
};
#define N_FIELDS ((int)(sizeof(FIELDS) / sizeof(FIELDS[0])))

void plant_config_defaults(plant_config_t *c)
{
    memset(c, 0, sizeof(*c));
    c->machine.rs_ohm = 1.93;
    c->machine.lambda_m_wb = 0.216;
    c->machine.pole_pairs = 2;
    c->magnetics.ld_h = 0.015;
    c->magnetics.ld_sat_h = 0.015; /* linear d axis */
    c->magnetics.ld_knee_a = 7.0;
    c->magnetics.ld_width_a = 2.0;
    c->magnetics.lq_h = 0.032;
    c->magnetics.lq_sat_per_a2 = 0.0; /* linear q axis */
    c->magnetics.lq_ext_from_a = 5.0;
    c->magnetics.lq_inf_h = 0.004;
    c->magnetics.ldq_ref_h = 0.0;
    c->magnetics.cross_ref_a = 3.0;
    c->magnetics.cross_scale_a = 10.0;
    c->inverter.vdc_v = 200.0;
    c->sensors.gain_a = 1.0;
    c->sensors.gain_b = 1.0;
    c->sensors.ring_freq_hz = 1e6;
    c->sensors.ring_tau_s = 1e-6;
    c->sensors.ring_return_fraction = 1.0;
    c->sensors.seed = 1;
    c->adc.bits = 24;
    c->adc.range_a = 10.0;
    c->adc.vdc_bits = 23;
    c->adc.vdc_range_v = 400.0;
    c->shaft.j_kgm2 = 0.0005;
    c->shaft.b_nms = 0.003;
    c->load.mode = HIL_BENCH_LOAD_CMD_MODE_OFF_CHOICE;
    c->solver.max_step_s = 10e-6;
}

size_t plant_config_size(void)
{
    return sizeof(plant_config_t);
}

int plant_config_key_count(void)
{
    return N_FIELDS;
}

const char *plant_config_key_name(int index)
{
    /* "section.key" strings built once into a static table of constant text */
    static const char *const NAMES[] = {
#define NAME(sec, key) #sec "." #key
        NAME(machine, rs_ohm), NAME(machine, lambda_m_wb), NAME(machine, pole_pairs),
        NAME(magnetics, ld_h), NAME(magnetics, ld_sat_h), NAME(magnetics, ld_knee_a),
        NAME(magnetics, ld_width_a), NAME(magnetics, lq_h), NAME(magnetics, lq_sat_per_a2),
        NAME(magnetics, lq_ext_from_a), NAME(magnetics, lq_inf_h), NAME(magnetics, ldq_ref_h),
        NAME(magnetics, cross_ref_a), NAME(magnetics, cross_scale_a), NAME(inverter, vdc_v),
        NAME(inverter, dead_time_s), NAME(inverter, device_drop_v), NAME(sensors, bandwidth_hz),
        NAME(sensors, gain_a), NAME(sensors, gain_b), NAME(sensors, offset_a_a),
        NAME(sensors, offset_b_a), NAME(sensors, noise_rms_a), NAME(sensors, ring_amp_a),
        NAME(sensors, ring_freq_hz), NAME(sensors, ring_tau_s),
        NAME(sensors, ring_return_fraction), NAME(sensors, vdc_noise_rms_v),
        NAME(sensors, seed), NAME(adc, bits), NAME(adc, range_a), NAME(adc, vdc_bits),
        NAME(adc, vdc_range_v), NAME(shaft, j_kgm2), NAME(shaft, b_nms),
        NAME(shaft, j_load_kgm2), NAME(shaft, b_load_nms), NAME(load, mode),
        NAME(load, torque_nm), NAME(load, speed_rpm), NAME(load, k_speed_nms),
        NAME(initial, theta_e_deg), NAME(initial, speed_rpm), NAME(solver, max_step_s),
#undef NAME
    };
    if (index < 0 || index >= N_FIELDS ||
        (int)(sizeof(NAMES) / sizeof(NAMES[0])) != N_FIELDS) {
        return NULL;
    }
    return NAMES[index];
}

static const field_t *find_field(const char *section, size_t section_len, const char *key,
                                 size_t key_len)
{
    int k;
    for (k = 0; k < N_FIELDS; ++k) {
        if (strlen(FIELDS[k].section) == section_len &&
            strncmp(FIELDS[k].section, section, section_len) == 0 &&
            strlen(FIELDS[k].key) == key_len && strncmp(FIELDS[k].key, key, key_len) == 0) {
            return &FIELDS[k];
        }
    }
    return NULL;
}

static int section_known(const char *section, size_t len)
{
    int k;
    for (k = 0; k < N_FIELDS; ++k) {
        if (strlen(FIELDS[k].section) == len && strncmp(FIELDS[k].section, section, len) == 0) {
            return 1;
        }
    }
    return 0;
}

/* Parses a TOML number (int or float, '_' between digits). Returns 0 or -1. */
static int parse_number(const char *s, size_t len, double *out)
{
    char buf[128];
    size_t n = 0, k;
    char *end;
    double v;
    if (len == 0 || len >= sizeof(buf)) {
        return -1;
    }
    for (k = 0; k < len; ++k) {
        const char c = s[k];
        if (c == '_') {
            /* TOML: an underscore must sit between two digits */
            if (k == 0 || k + 1 >= len || !isdigit((unsigned char)s[k - 1]) ||
                !isdigit((unsigned char)s[k + 1])) {
                return -1;
            }
            continue;
        }
        if (!(isdigit((unsigned char)c) || c == '+' || c == '-' || c == '.' || c == 'e' ||
              c == 'E')) {
            return -1; /* rejects inf, nan, hex and anything strtod would accept beyond TOML */
        }
        buf[n++] = c;
    }
    buf[n] = '\0';
    if (buf[0] == '.' || ((buf[0] == '+' || buf[0] == '-') && buf[1] == '.')) {
        return -1; /* TOML needs a digit before the point */
    }
    errno = 0;
    v = strtod(buf, &end);
    if (end == buf || *end != '\0' || errno == ERANGE || !isfinite(v)) {
        return -1;
    }
    if (end[-1] == '.') {
        return -1; /* nor a bare trailing point */
    }
    *out = v;
    return 0;
}

static int assign(plant_config_t *cfg, const field_t *f, double v, char *why, size_t whylen)
{
    if (f->flags & F_INT) {
        if (v != floor(v)) {
            snprintf(why, whylen, "must be an integer");
            return -1;
        }
    }
    if (v < f->min || v > f->max || ((f->flags & F_POSITIVE) && !(v > 0.0))) {
        snprintf(why, whylen, "%.17g outside %s%.6g .. %.6g", v,
                 (f->flags & F_POSITIVE) ? "(" : "[", f->min, f->max);
        return -1;
    }
    *(double *)((char *)cfg + f->offset) = v;
    return 0;
}

/* s[0..n) as an error message shows it, written to out: at most SHOWN_MAX characters, the
 * last three "..." when cut (a 400-digit number echoed whole filled the message and cut off
 * the reason after it) */
#define SHOWN_MAX 40
static const char *shown(char out[SHOWN_MAX + 1], const char *s, size_t n)
{
    if (n > SHOWN_MAX) {
        memcpy(out, s, SHOWN_MAX - 3);
        memcpy(out + SHOWN_MAX - 3, "...", 4);
    } else {
        memcpy(out, s, n);
        out[n] = '\0';
    }
    return out;
}

static const char *skip_ws(const char *s, const char *end)
{
    while (s < end && (*s == ' ' || *s == '\t')) {
        ++s;
    }
    return s;
}

static const char *trim_end(const char *s, const char *end)
{
    while (end > s && (end[-1] == ' ' || end[-1] == '\t' || end[-1] == '\r')) {
        --end;
    }
    return end;
}

static int is_bare_key(const char *s, const char *end)
{
    if (s == end) {
        return 0;
    }
    for (; s < end; ++s) {
        if (!(isalnum((unsigned char)*s) || *s == '_' || *s == '-')) {
            return 0;
        }
    }
    return 1;
}

int plant_config_load(plant_config_t *cfg, const char *path, char *err, size_t errlen)
{
    FILE *fp = fopen(path, "r");
    char line[1024];
    char section[64] = "";
    unsigned char seen[sizeof(FIELDS) / sizeof(FIELDS[0])];
    int lineno = 0;

    memset(seen, 0, sizeof(seen));
    if (!fp) {
        snprintf(err, errlen, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    while (fgets(line, sizeof(line), fp)) {
        const char *s, *end, *hash;
        ++lineno;
        if (!strchr(line, '\n') && !feof(fp)) {
            snprintf(err, errlen, "%s:%d: line too long", path, lineno);
            fclose(fp);
            return -1;
        }
        end = line + strlen(line);
        if (end > line && end[-1] == '\n') {
            --end;
        }
        hash = memchr(line, '#', (size_t)(end - line));
        if (hash) {
            end = hash;
        }
        s = skip_ws(line, end);
        end = trim_end(s, end);
        if (s == end) {
            continue;
        }
        if (*s == '[') {
            const char *name = skip_ws(s + 1, end), *close = end - 1, *name_end;
            if (*close != ']') {
                snprintf(err, errlen, "%s:%d: malformed section header", path, lineno);
                fclose(fp);
                return -1;
            }
            name_end = trim_end(name, close);
            if (!is_bare_key(name, name_end) || (size_t)(name_end - name) >= sizeof(section)) {
                snprintf(err, errlen, "%s:%d: malformed section header", path, lineno);
                fclose(fp);
                return -1;
            }
            if (!section_known(name, (size_t)(name_end - name))) {
                snprintf(err, errlen, "%s:%d: [%.*s]: unknown section", path, lineno,
                         (int)(name_end - name), name);
                fclose(fp);
                return -1;
            }
            memcpy(section, name, (size_t)(name_end - name));
            section[name_end - name] = '\0';
            continue;
        }
        {
            const char *eq = memchr(s, '=', (size_t)(end - s));
            const char *key_end, *val;
            const field_t *f;
            double v;
            char why[160];
            if (!eq) {
                snprintf(err, errlen, "%s:%d: expected 'key = number'", path, lineno);
                fclose(fp);
                return -1;
            }
            key_end = trim_end(s, eq);
            if (!is_bare_key(s, key_end)) {
                snprintf(err, errlen, "%s:%d: malformed key", path, lineno);
                fclose(fp);
                return -1;
            }
            if (section[0] == '\0') {
                snprintf(err, errlen, "%s:%d: %.*s: key outside any [section]", path, lineno,
                         (int)(key_end - s), s);
                fclose(fp);
                return -1;
            }
            f = find_field(section, strlen(section), s, (size_t)(key_end - s));
            if (!f) {
                snprintf(err, errlen, "%s:%d: %s.%.*s: unknown field", path, lineno, section,
                         (int)(key_end - s), s);
                fclose(fp);
                return -1;
            }
            if (seen[f - FIELDS]) {
                snprintf(err, errlen, "%s:%d: %s.%s: defined twice", path, lineno, f->section,
                         f->key);
                fclose(fp);
                return -1;
            }
            seen[f - FIELDS] = 1;
            val = skip_ws(eq + 1, end);
            if (parse_number(val, (size_t)(end - val), &v) != 0) {
                char vs[SHOWN_MAX + 1];
                snprintf(err, errlen, "%s:%d: %s.%s: '%s' is not a number", path, lineno,
                         f->section, f->key, shown(vs, val, (size_t)(end - val)));
                fclose(fp);
                return -1;
            }
            if (assign(cfg, f, v, why, sizeof(why)) != 0) {
                snprintf(err, errlen, "%s:%d: %s.%s: %s", path, lineno, f->section, f->key, why);
                fclose(fp);
                return -1;
            }
        }
    }
    if (ferror(fp)) {
        snprintf(err, errlen, "%s: read error", path);
        fclose(fp);
        return -1;
    }
    fclose(fp);
    {
        char why[400];
        if (plant_config_check(cfg, why, sizeof(why)) != 0) {
            snprintf(err, errlen, "%s: %s", path, why);
            return -1;
        }
    }
    return 0;
}

int plant_config_set(plant_config_t *cfg, const char *assignment, char *err, size_t errlen)
{
    const char *eq = strchr(assignment, '=');
    const char *end = assignment + strlen(assignment);
    const char *s = skip_ws(assignment, end), *dot, *key_end, *val;
    const field_t *f;
    double v;
    char why[160];
    char as[SHOWN_MAX + 1], part[SHOWN_MAX + 1]; /* the assignment and a part of it, shown */
    shown(as, assignment, (size_t)(end - assignment));
    if (!eq) {
        snprintf(err, errlen, "--set %s: expected section.key=value", as);
        return -1;
    }
    key_end = trim_end(s, eq);
    dot = memchr(s, '.', (size_t)(key_end - s));
    if (!dot) {
        snprintf(err, errlen, "--set %s: expected section.key=value", as);
        return -1;
    }
    f = find_field(s, (size_t)(dot - s), dot + 1, (size_t)(key_end - dot - 1));
    if (!f) {
        snprintf(err, errlen, "--set %s: %s: unknown field", as,
                 shown(part, s, (size_t)(key_end - s)));
        return -1;
    }
    val = skip_ws(eq + 1, end);
    end = trim_end(val, end);
    if (parse_number(val, (size_t)(end - val), &v) != 0) {
        snprintf(err, errlen, "--set %s: %s.%s: '%s' is not a number", as, f->section, f->key,
                 shown(part, val, (size_t)(end - val)));
        return -1;
    }
    if (assign(cfg, f, v, why, sizeof(why)) != 0) {
        snprintf(err, errlen, "--set %s: %s.%s: %s", as, f->section, f->key, why);
        return -1;
    }
    return 0;
}

int plant_config_check(const plant_config_t *cfg, char *err, size_t errlen)
{
    const double ticks = cfg->inverter.dead_time_s * PLANT_TBCLK_HZ;
    plant_mag_t mag;
    if (fabs(ticks - floor(ticks + 0.5)) > 1e-6) {
        snprintf(err, errlen,
                 "inverter.dead_time_s: %.9g s is not a whole number of 10 ns TBCLK ticks",
                 cfg->inverter.dead_time_s);
        return -1;
    }
    if (cfg->sensors.ring_amp_a > 0.0 && !(cfg->sensors.ring_freq_hz > 0.0)) {
        snprintf(err, errlen, "sensors.ring_freq_hz: must be > 0 when sensors.ring_amp_a > 0");
        return -1;
    }
    if (cfg->magnetics.ld_sat_h > cfg->magnetics.ld_h) {
        snprintf(err, errlen, "magnetics.ld_sat_h: must not exceed magnetics.ld_h");
        return -1;
    }
    return plant_mag_init(&mag, cfg, err, errlen);
}
