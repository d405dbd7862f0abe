/* fw_test.h - minimal check macros for the firmware C tests (no framework dependency). */
#ifndef FW_TEST_H
#define FW_TEST_H

#include <math.h>
#include <stdio.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

static int fw_test_failures = 0;
static int fw_test_checks = 0;

#define CHECK(cond, ...)                                                    \
    do {                                                                    \
        fw_test_checks++;                                                   \
        if (!(cond)) {                                                      \
            fw_test_failures++;                                             \
            if (fw_test_failures <= 25) {                                   \
                fprintf(stderr, "%s:%d: CHECK(%s) failed: ", __FILE__, __LINE__, #cond); \
                fprintf(stderr, __VA_ARGS__);                               \
                fprintf(stderr, "\n");                                      \
            }                                                               \
        }                                                                   \
    } while (0)

#define TEST_DONE()                                                                    \
    do {                                                                               \
        printf("%d checks, %d failures\n", fw_test_checks, fw_test_failures);         \
        return fw_test_failures == 0 ? 0 : 1;                                          \
    } while (0)

#endif
