/* target_entry.c - the control core's entry points on the Cortex-M4F image.
 *
 * The host HAL calls fw_core_isr() with a pointer to the ADC data and the core object; a
 * target HAL fills the same fw_adc_t from its ADC result registers and writes fw_pwm_t into
 * the compare and SOC registers. Under emulation (rig/target_m4) the "registers" are these
 * mailboxes: the harness writes the inputs into RAM, calls one entry point (no arguments, so
 * the harness needs no calling convention beyond a return to its caller) and reads the result.
 * m4_core is the whole state: the harness can also load a state the host build saved, since
 * fw_core_t holds only fixed-width integers and real_t (same layout on both ABIs).
 */
#include <stddef.h>

#include "fw_core.h"

fw_core_t m4_core;
fw_adc_t m4_adc;
fw_pwm_t m4_pwm;
fw_cmd_t m4_cmd;
real_t m4_arg[3];
uint16_t m4_param_id;
int16_t m4_ret;
/* sizes the harness checks against the host build's before it moves any of them */
const uint32_t m4_sizes[5] = {(uint32_t)sizeof(fw_core_t), (uint32_t)sizeof(fw_adc_t),
                              (uint32_t)sizeof(fw_pwm_t), (uint32_t)sizeof(fw_cmd_t),
                              (uint32_t)sizeof(fw_status_t)};
fw_status_t m4_status;
/* the core's ISR count after the last call (its 1 kHz tasks run when it is a multiple of
 * FW_SPEED_DIVIDER): the benchmark tells the paths apart by it */
uint32_t m4_isr_count;
/* where the state code sits in fw_core_t (a window replayed from a saved state starts in it) */
const uint32_t m4_state_offset = (uint32_t)offsetof(fw_core_t, state);

void m4_init(void) { fw_core_init(&m4_core); }
/* the PWM period interrupt: ADC(k) in, PWM(k+1) out */
void m4_isr(void)
{
    fw_core_isr(&m4_core, &m4_adc, &m4_pwm);
    m4_isr_count = m4_core.isr_count;
}
/* a period whose ADC data never came */
void m4_isr_no_data(void)
{
    fw_core_isr(&m4_core, 0, &m4_pwm);
    m4_isr_count = m4_core.isr_count;
}
void m4_command(void) { m4_ret = fw_core_command(&m4_core, &m4_cmd); }
void m4_limits(void) { m4_ret = fw_core_set_limits(&m4_core, m4_arg[0], m4_arg[1], m4_arg[2]); }
void m4_param_set(void) { m4_ret = fw_param_set(&m4_core, m4_param_id, m4_arg[0]); }
void m4_get_status(void) { fw_core_status(&m4_core, &m4_status); }
