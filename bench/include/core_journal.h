/* core_journal: every call into the control core of a bench, with its inputs and the host
 * build's outputs, in a file another build of the core can be replayed on (rig/target_m4
 * replays it on the Cortex-M4F image under emulation and compares period by period).
 *
 * File (little-endian, every field 4-byte aligned; fw_*_t are the core's own structs, which
 * hold only fixed-width integers and real_t and so have the same layout on every 32/64-bit
 * ABI the core is built for):
 *   header  "FWJ1", u32 version, u32 sizeof fw_core_t, fw_adc_t, fw_pwm_t, fw_cmd_t, fw_status_t
 *   records u32 tag, u32 isr index (the number of fw_core_isr calls before it), then
 *     'P' u32 id, f32 value      a parameter that differs from its default at the start (the
 *                                 table's order; a replay retries what a cross-check refuses)
 *     'S' fw_core_t               the core's state before the record that follows (at the
 *                                 start of each window)
 *     'C' fw_cmd_t, i32 status    fw_core_command
 *     'L' f32 i_max, speed_max_rpm, accel_rpm_s, i32 status   fw_core_set_limits
 *     'I' u32 has_adc, fw_adc_t, fw_pwm_t, u32 crc32 of fw_core_t after, i32 state after
 *                                 fw_core_isr (adc NULL when has_adc is 0: zero bytes)
 * Windows restrict the records to ISR index ranges [start, start + length) (commands given
 * just before a window's first ISR included): each window starts with an 'S', so it can be
 * replayed from the host's state without the periods before it. No windows: everything.
 */
#ifndef CORE_JOURNAL_H
#define CORE_JOURNAL_H

#include <stddef.h>
#include <stdint.h>

#include "fw_core.h"

#define CORE_JOURNAL_VERSION 1u
#define CORE_JOURNAL_WINDOWS_MAX 16

typedef struct core_journal core_journal_t;

/* NULL with a reason in err when the file cannot be created or the windows are bad. */
core_journal_t *core_journal_open(const char *path, const fw_core_t *core,
                                  const uint32_t *win_start, const uint32_t *win_len, int n_win,
                                  char *err, size_t errlen);
/* 0, or -1 when a write failed. */
int core_journal_close(core_journal_t *j);

/* Each after the call it records (the state before it is what a window's 'S' needs: the
 * caller passes the core as it was before the call through core_journal_before). */
void core_journal_before(core_journal_t *j, const fw_core_t *core);
void core_journal_isr(core_journal_t *j, const fw_core_t *core, const fw_adc_t *adc,
                      const fw_pwm_t *pwm);
void core_journal_command(core_journal_t *j, const fw_cmd_t *cmd, int16_t status);
void core_journal_limits(core_journal_t *j, real_t i_max, real_t speed_max_rpm,
                         real_t accel_rpm_s, int16_t status);

/* crc32 (IEEE 802.3, as zlib's) of the core's state bytes */
uint32_t core_journal_crc32(const void *data, size_t len);

#endif
