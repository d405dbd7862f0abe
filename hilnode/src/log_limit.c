#include "hil_log_limit.h"

#include <stdio.h>

#define NS_PER_S 1000000000LL

void hil_log_limit_init(hil_log_limit_t *l, const char *prog, int lines_per_s, int64_t now_ns)
{
    l->prog = prog;
    l->lines_per_s = lines_per_s;
    l->window_start_ns = now_ns;
    l->lines = 0;
    l->suppressed = 0;
}

int hil_log_limit_allow(hil_log_limit_t *l, int64_t now_ns)
{
    if (now_ns - l->window_start_ns >= NS_PER_S) {
        if (l->suppressed) {
            fprintf(stderr, "%s: (%llu more messages not logged)\n", l->prog,
                    (unsigned long long)l->suppressed);
        }
        l->window_start_ns = now_ns;
        l->lines = 0;
        l->suppressed = 0;
    }
    if (l->lines >= l->lines_per_s) {
        l->suppressed++;
        return 0;
    }
    l->lines++;
    return 1;
}
