/* hil_log_limit: at most N lines per one-second window, the rest counted and reported in one
 * "(k more messages not logged)" line when the window ends. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../check.h"
#include "hil_log_limit.h"

int main(void)
{
    const long long s = 1000000000LL;
    hil_log_limit_t l;
    char path[] = "/tmp/hil_log_limit_XXXXXX";
    char text[256] = {0};
    int fd = mkstemp(path);
    FILE *f;
    int k, allowed = 0;
    CHECK(fd >= 0);
    CHECK(freopen(path, "w", stderr) != NULL);

    hil_log_limit_init(&l, "node", 3, 5 * s);
    for (k = 0; k < 10; k++) {
        allowed += hil_log_limit_allow(&l, 5 * s + k * 1000);
    }
    CHECK(allowed == 3);
    CHECK(l.suppressed == 7);
    CHECK(!hil_log_limit_allow(&l, 6 * s - 1)); /* still the first window */
    /* the next window: the report line, then 3 more lines allowed */
    CHECK(hil_log_limit_allow(&l, 6 * s));
    CHECK(l.suppressed == 0 && l.lines == 1);
    /* a quiet window writes no report line */
    CHECK(hil_log_limit_allow(&l, 8 * s));
    fflush(stderr);

    f = fopen(path, "r");
    CHECK(f != NULL);
    if (f != NULL) {
        size_t n = fread(text, 1, sizeof text - 1, f);
        text[n] = '\0';
        fclose(f);
    }
    unlink(path);
    CHECK(strcmp(text, "node: (8 more messages not logged)\n") == 0);
    if (g_failures) {
        fprintf(stdout, "stderr was: \"%s\"\n", text);
    }
    return check_report("test_log_limit");
}
