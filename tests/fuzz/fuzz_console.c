/* libFuzzer harness: the SCI console's line parser and commands (console.c, the grammar of
 * protocols/console.md) on an fw_host application object; replies go to a closed line. */
#define _POSIX_C_SOURCE 200809L /* setenv, getpid */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "fuzz_host.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t off = 0;
    int64_t now;
    fuzz_host_reset();
    fwh_console_hangup(&fuzz_app); /* a fresh session: no partial line from the last input */
    now = hil_now_ns();
    while (off < size) {
        size_t took = fwh_console_input(&fuzz_app, (const char *)data + off, size - off, now);
        if (took == 0) {
            fwh_pty_discard(&fuzz_app.pty); /* the client "read" the reply */
            took = fwh_console_input(&fuzz_app, (const char *)data + off, size - off, now);
            if (took == 0) {
                abort(); /* no progress with an empty queue: the console would hang */
            }
        }
        off += took;
    }
    return 0;
}
