/* Unit tests of the host HAL's pure parts: the ADC frame assembly rules (adc_assembly.h),
 * the parameter file (param_file.h), and the fault codes the core reports against the wire's
 * table (DRIVE_STATUS.fault_code in protocols/drive.dbc). Usage: fw_host_test_units
 * SCRATCH_DIR */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "adc_assembly.h"
#include "fw_core.h"
#include "fw_host.h"
#include "hil_drive.h"
#include "param_file.h"

static int failures;

#define CHECK(cond, ...)                                                                    \
    do {                                                                                    \
        if (!(cond)) {                                                                      \
            failures++;                                                                     \
            printf("FAIL %s:%d: ", __FILE__, __LINE__);                                     \
            printf(__VA_ARGS__);                                                            \
            printf("\n");                                                                   \
        }                                                                                   \
    } while (0)

static const int32_t codes[7] = {1, 2, 3, 4, 5, 6, 7};
static fwh_adc_asm_t A;

static fwh_adc_result_t feed(int index, uint32_t period, int16_t n_soc)
{
    fwh_adc_result_t r;
    fwh_adc_feed(&A, index, period, n_soc, 100 + index, codes, codes, &r);
    return r;
}

static void test_assembly(void)
{
    fwh_adc_result_t r;
    fwh_adc_init(&A);
    CHECK(fwh_adc_frames_for(0) == 1 && fwh_adc_frames_for(7) == 1 &&
              fwh_adc_frames_for(8) == 2 && fwh_adc_frames_for(14) == 2 &&
              fwh_adc_frames_for(15) == 3 && fwh_adc_frames_for(16) == 3,
          "frames per n_soc");
    /* the first period may be any index; one frame is enough for n_soc <= 7 */
    r = feed(0, 500, 2);
    CHECK(r.verdict == FWH_ADC_OK && r.complete && !r.repeat && r.n_lost == 0,
          "first period complete");
    CHECK(r.adc->period == 500 && r.adc->n_soc == 2 && r.adc->vdc == 100 && r.adc->ia[1] == 2,
          "first period content");
    /* 16 SOCs in three frames, any order; samples land at their SOC index */
    r = feed(2, 501, 16);
    CHECK(r.verdict == FWH_ADC_OK && !r.complete, "frame 2 alone");
    r = feed(1, 501, 16);
    CHECK(!r.complete, "frames 2 and 1");
    r = feed(0, 501, 16);
    CHECK(r.complete && r.adc->ia[0] == 1 && r.adc->ia[7] == 1 && r.adc->ia[13] == 7 &&
              r.adc->ia[14] == 1 && r.adc->ia[15] == 2 && r.adc->vdc == 100,
          "three frames assembled");
    /* a lockstep re-send of the same period is a repeat */
    r = feed(0, 501, 16);
    CHECK(!r.complete && r.verdict == FWH_ADC_OK, "repeat first frame");
    feed(1, 501, 16);
    r = feed(2, 501, 16);
    CHECK(r.complete && r.repeat, "repeat complete");
    /* stale, future, malformed */
    CHECK(feed(0, 400, 2).verdict == FWH_ADC_STALE, "stale");
    CHECK(feed(0, 501 + FWH_ADC_MAX_GAP + 1, 2).verdict == FWH_ADC_FUTURE, "future");
    CHECK(feed(1, 502, 3).verdict == FWH_ADC_MALFORMED, "frame 1 with n_soc 3");
    CHECK(feed(0, 502, 17).verdict == FWH_ADC_MALFORMED, "n_soc 17");
    r = feed(0, 502, 10);
    CHECK(r.verdict == FWH_ADC_OK && !r.complete, "502 begins");
    CHECK(feed(1, 502, 9).verdict == FWH_ADC_MALFORMED, "n_soc disagrees");
    /* 502 never completes; 505 arrives: 502 incomplete, 502..504 lost */
    r = feed(0, 505, 1);
    CHECK(r.incomplete == 1 && r.lost_first == 502 && r.n_lost == 3 && r.complete,
          "incomplete and lost (%d %lu %lu)", r.incomplete, (unsigned long)r.lost_first,
          (unsigned long)r.n_lost);
    /* a period inside the gap window that is older than the one being collected */
    r = feed(0, 507, 8);
    CHECK(!r.complete && r.n_lost == 1, "507 begins after lost 506");
    CHECK(feed(0, 506, 1).verdict == FWH_ADC_STALE, "506 behind 507");
    /* a restarted sequence: after FWH_ADC_RESYNC consecutive stale periods it is followed */
    {
        uint32_t k;
        int resynced = 0;
        fwh_adc_init(&A);
        feed(0, 9000, 1);
        for (k = 0; k < FWH_ADC_RESYNC; k++) {
            r = feed(0, k, 1);
            if (k + 1 < FWH_ADC_RESYNC) {
                CHECK(r.verdict == FWH_ADC_STALE && !r.resynced, "stale %lu", (unsigned long)k);
                feed(0, k, 1); /* a re-sent copy does not count twice */
            } else {
                resynced = r.resynced && r.complete && r.verdict == FWH_ADC_OK;
            }
        }
        CHECK(resynced, "resync after %d periods", FWH_ADC_RESYNC);
        r = feed(0, FWH_ADC_RESYNC, 1);
        CHECK(r.complete && r.n_lost == 0 && !r.repeat, "follows the new sequence");
    }
    /* Issue 16.1: stray frames never take the sequence over. Only a plant that restarted
     * (its start-up period 0, then 1, 2, ...) is followed. Twenty consecutive far periods
     * (injected), and delayed duplicates of older periods in order, are rejected. */
    {
        uint32_t k;
        int taken = 0;
        fwh_adc_init(&A);
        for (k = 0; k < 40; k++) {
            feed(0, 5000 + k, 1);
        }
        for (k = 0; k < 2 * FWH_ADC_RESYNC; k++) {
            r = feed(0, 3000000000u + k, 1);
            taken |= r.resynced || r.complete;
        }
        CHECK(!taken, "a far sequence was followed");
        for (k = 0; k < 2 * FWH_ADC_RESYNC; k++) {
            r = feed(0, 5010 + k, 1); /* duplicates of 5010..5029, delayed */
            taken |= r.resynced || r.complete;
        }
        CHECK(!taken, "delayed duplicates were followed");
        r = feed(0, 5040, 1);
        CHECK(r.complete && r.n_lost == 0 && !r.resynced, "the paired plant goes on at 5040");
    }
    /* Paired from the start (lockstep: the plant's first ADC is its start-up period 0, and
     * the rig says so with --first-period 0): stray frames before it never become the
     * first period; the plant's period 0 does. */
    {
        uint32_t k;
        int taken = 0;
        fwh_adc_init(&A);
        fwh_adc_expect_first(&A, 0u);
        for (k = 0; k < 20; k++) {
            r = feed(0, 3000000000u + k, 1);
            taken |= r.complete || r.resynced;
            CHECK(r.verdict != FWH_ADC_OK, "stray first frame %lu accepted", (unsigned long)k);
        }
        CHECK(!taken, "a stray frame became the first period");
        r = feed(0, 0u, 1);
        CHECK(r.complete && r.verdict == FWH_ADC_OK && r.adc->period == 0u, "period 0 first");
        r = feed(0, 1u, 1);
        CHECK(r.complete && r.n_lost == 0, "then 1");
    }
    /* Issue 23.5: in lockstep the plant skips no period before its first barrier: data that
     * skips periods then is another node's (future, rejected), and never runs the ISR; after
     * a barrier (frame faults: the plant goes on without PWM) it is followed as before */
    {
        fwh_adc_init(&A);
        fwh_adc_lockstep(&A);
        fwh_adc_expect_first(&A, 0u);
        CHECK(feed(0, 0u, 1).complete, "period 0");
        CHECK(feed(0, 1u, 1).complete, "period 1");
        r = feed(0, 1u + 60u, 1); /* the stray frame */
        CHECK(r.verdict == FWH_ADC_FUTURE && !r.complete && r.n_lost == 0,
              "a skip before any barrier is future (verdict %d)", (int)r.verdict);
        r = feed(0, 2u, 1); /* the plant's next period */
        CHECK(r.complete && r.n_lost == 0 && r.adc->period == 2u, "the plant goes on at 2");
        fwh_adc_barrier(&A);
        r = feed(0, 5u, 1); /* 3 and 4 lost behind barriers */
        CHECK(r.verdict == FWH_ADC_OK && r.complete && r.lost_first == 3u && r.n_lost == 2,
              "after a barrier a skip is followed (%d %lu %lu)", r.complete,
              (unsigned long)r.lost_first, (unsigned long)r.n_lost);
    }
    /* period counter wrap-around */
    fwh_adc_init(&A);
    feed(0, 0xFFFFFFFFu, 1);
    r = feed(0, 0u, 1);
    CHECK(r.complete && r.n_lost == 0 && r.verdict == FWH_ADC_OK, "wrap");
}

static void test_numbers(void)
{
    double v;
    char buf[32];
    const char *good[] = {"0", "-1", "+2.5", ".5", "5.", "1e3", "1.5E-3", "007"};
    const char *bad[] = {"", "-", ".", "e3", "1e", "1e+", "0x10", "nan", "inf", "1,5", " 1",
                         "1 ", "--1", "1e400"};
    size_t i;
    for (i = 0; i < sizeof(good) / sizeof(good[0]); i++) {
        CHECK(fwh_parse_number(good[i], &v) == 0, "good number '%s'", good[i]);
    }
    for (i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        CHECK(fwh_parse_number(bad[i], &v) != 0, "bad number '%s'", bad[i]);
    }
    fwh_fmt_real(buf, sizeof(buf), 0.015f);
    CHECK(strcmp(buf, "0.015") == 0, "0.015 -> %s", buf);
    fwh_fmt_real(buf, sizeof(buf), 1.0f / 3.0f);
    CHECK((float)strtod(buf, NULL) == 1.0f / 3.0f, "1/3 round trip: %s", buf);
    fwh_fmt_real(buf, sizeof(buf), 4294967295.0f);
    CHECK((float)strtod(buf, NULL) == 4294967295.0f, "big round trip: %s", buf);
}

static fw_core_t core;
static fwh_param_list_t list;

static void test_param_file(const char *dir)
{
    char path[512], err[512];
    FILE *f;
    int failed, changed, n;
    real_t v;
    snprintf(path, sizeof(path), "%s/fw_host_units_params.txt", dir);
    fw_core_init(&core);
    fw_param_set(&core, 100, 77.0f); /* pll_bw_hz */
    n = fwh_params_save(&core, path, err, sizeof(err));
    CHECK(n > 50, "saved %d (%s)", n, n < 0 ? err : "");
    fw_core_init(&core);
    CHECK(fwh_params_parse_file(path, &list, err, sizeof(err)) == 0, "parse saved: %s", err);
    CHECK(fwh_params_apply(&core, &list, &failed, &changed) == FW_STATUS_OK && changed == 1,
          "apply saved (changed %d)", changed);
    CHECK(fw_param_get(&core, 100, &v) == FW_STATUS_OK && v == 77.0f, "pll_bw_hz back");
    /* order-independent application, all or nothing */
    f = fopen(path, "w");
    fputs("ld_h = 0.04   # raised before lq_h\nlq_h = 0.05\n", f);
    fclose(f);
    fw_core_init(&core);
    CHECK(fwh_params_parse_file(path, &list, err, sizeof(err)) == 0, "parse: %s", err);
    CHECK(fwh_params_apply(&core, &list, &failed, &changed) == FW_STATUS_OK && changed == 2,
          "ld before lq");
    /* the later of two assignments wins, also when it restores the present value (the
     * bench's hardware values are followed by a scenario's own: deadtime_us=2 then 0) */
    fw_core_init(&core);
    list.n = 0;
    CHECK(fwh_params_parse_assignment("deadtime_us=2", &list.items[list.n++], err,
                                      sizeof(err)) == 0 &&
              fwh_params_parse_assignment("deadtime_us=0", &list.items[list.n++], err,
                                          sizeof(err)) == 0,
          "parse assignments: %s", err);
    CHECK(fwh_params_apply(&core, &list, &failed, &changed) == FW_STATUS_OK && changed == 0,
          "later assignment of the default (changed %d)", changed);
    CHECK(fw_param_get(&core, 24, &v) == FW_STATUS_OK && v == 0.0f, "deadtime_us %g, not 0",
          (double)v);
    list.n = 0;
    CHECK(fwh_params_parse_assignment("deadtime_us=0", &list.items[list.n++], err,
                                      sizeof(err)) == 0 &&
              fwh_params_parse_assignment("deadtime_us=3", &list.items[list.n++], err,
                                          sizeof(err)) == 0,
          "parse assignments: %s", err);
    CHECK(fwh_params_apply(&core, &list, &failed, &changed) == FW_STATUS_OK && changed == 1 &&
              fw_param_get(&core, 24, &v) == FW_STATUS_OK && v == 3.0f,
          "later assignment wins (%g)", (double)v);
    f = fopen(path, "w");
    fputs("rs_ohm = 3\nld_h = 0.06\n", f);
    fclose(f);
    CHECK(fwh_params_parse_file(path, &list, err, sizeof(err)) == 0, "parse: %s", err);
    CHECK(fwh_params_apply(&core, &list, &failed, &changed) == FW_STATUS_OUT_OF_RANGE &&
              failed == 1,
          "inconsistent item found");
    CHECK(fw_param_get(&core, 1, &v) == FW_STATUS_OK && fabsf(v - 1.93f) < 1e-6f,
          "nothing applied");
    f = fopen(path, "w");
    fputs("rs_ohm = 3\n  # comment\n\nrs_ohm = 4\n", f);
    fclose(f);
    CHECK(fwh_params_parse_file(path, &list, err, sizeof(err)) != 0 &&
              strstr(err, ":4: field 'rs_ohm': set twice (first on line 1)") != NULL,
          "duplicate: %s", err);
    remove(path);
}

/* The core's fault codes are the DBC's (its value table is what the rig reads). */
static void test_fault_codes(void)
{
    static const struct {
        unsigned core, dbc;
        const char *name;
    } codes[] = {
        {FW_FAULT_NONE, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_NONE_CHOICE, "NONE"},
        {FW_FAULT_OVERCURRENT, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_OVERCURRENT_CHOICE,
         "OVERCURRENT"},
        {FW_FAULT_DC_OVERVOLTAGE, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_DC_OVERVOLTAGE_CHOICE,
         "DC_OVERVOLTAGE"},
        {FW_FAULT_DC_UNDERVOLTAGE, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_DC_UNDERVOLTAGE_CHOICE,
         "DC_UNDERVOLTAGE"},
        {FW_FAULT_ESTIMATOR, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_ESTIMATOR_CHOICE, "ESTIMATOR"},
        {FW_FAULT_CMD_TIMEOUT, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_CMD_TIMEOUT_CHOICE,
         "CMD_TIMEOUT"},
        {FW_FAULT_ADC_LOSS, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_ADC_LOSS_CHOICE, "ADC_LOSS"},
        {FW_FAULT_POLARITY, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_POLARITY_CHOICE, "POLARITY"},
        {FW_FAULT_POLARITY_LOST, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_POLARITY_LOST_CHOICE,
         "POLARITY_LOST"},
        {FW_FAULT_OVERSPEED, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_OVERSPEED_CHOICE, "OVERSPEED"},
        {FW_FAULT_CURRENT_IMPLAUSIBLE, HIL_DRIVE_DRIVE_STATUS_FAULT_CODE_CURRENT_IMPLAUSIBLE_CHOICE,
         "CURRENT_IMPLAUSIBLE"},
    };
    size_t k;
    for (k = 0; k < sizeof(codes) / sizeof(codes[0]); k++) {
        CHECK(codes[k].core == codes[k].dbc, "%s: core %u, drive.dbc %u", codes[k].name,
              codes[k].core, codes[k].dbc);
        CHECK(strcmp(fwh_fault_name((uint16_t)codes[k].core), codes[k].name) == 0,
              "%s: fw_host calls it %s", codes[k].name, fwh_fault_name((uint16_t)codes[k].core));
    }
}

int main(int argc, char **argv)
{
    test_fault_codes();
    test_assembly();
    test_numbers();
    test_param_file(argc > 1 ? argv[1] : ".");
    if (failures) {
        printf("%d failure(s)\n", failures);
        return 1;
    }
    printf("fw_host units: all passed\n");
    return 0;
}
