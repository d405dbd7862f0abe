/* hil_log_limit: at most N lines per one-second window, the rest counted and reported in one
 * "(k more messages not logged)" line when the window ends. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "hil_log_limit.h"

static int failures;

#define EXPECT(cond)                                                        \
    do {                                                                    \
        if (!(cond)) {                                                      \
            fprintf(stdout, "%s:%d: EXPECT(%s) failed\n", __FILE__, __LINE__, #cond); \
            failures++;                                                     \
        }                                                                   \
    } while (0)

int main(void)
{
    const long long s = 1000000000LL;
    hil_log_limit_t l;
    char path[] = "/tmp/hil_log_limit_XXXXXX";
    char text[256] = {0};
    int fd = mkstemp(path);
    FILE *f;
    int k, allowed = 0;
    EXPECT(fd >= 0);
    EXPECT(freopen(path, "w", stderr) != NULL);

    hil_log_limit_init(&l, "node", 3, 5 * s);
    for (k = 0; k < 10; k++) {
        allowed += hil_log_limit_allow(&l, 5 * s + k * 1000);
    }
    EXPECT(allowed == 3);
    EXPECT(l.suppressed == 7);
    EXPECT(!hil_log_limit_allow(&l, 6 * s - 1)); /* still the first window */
    /* the next window: the report line, then 3 more lines allowed */
    EXPECT(hil_log_limit_allow(&l, 6 * s));
    EXPECT(l.suppressed == 0 && l.lines == 1);
    /* a quiet window writes no report line */
    EXPECT(hil_log_limit_allow(&l, 8 * s));
    fflush(stderr);

    f = fopen(path, "r");
    EXPECT(f != NULL);
    if (f != NULL) {
        size_t n = fread(text, 1, sizeof text - 1, f);
        text[n] = '\0';
        fclose(f);
    }
    unlink(path);
    EXPECT(strcmp(text, "node: (8 more messages not logged)\n") == 0);
    if (failures) {
        fprintf(stdout, "stderr was: \"%s\"\n", text);
    }
    printf("%d failures\n", failures);
    return failures ? 1 : 0;
}
