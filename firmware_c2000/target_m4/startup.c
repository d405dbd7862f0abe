/* startup.c - reset of the Cortex-M images: the vector table, .data/.bss, the FPU (M4F).
 *
 * A product's reset handler would go on to configure the clocks, the PWM timer and its
 * interrupt and enter the background loop; here the image is only run under emulation, which
 * calls the entry points of target_entry.c one at a time (rig/target_m4), so the reset handler
 * returns to its caller after the C run-time is set up.
 */
#include <stdint.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;

void m4_reset_handler(void);

/* Cortex-M vector table: initial stack pointer and reset; the PWM interrupt (fw_core_isr via
 * m4_isr) would be entered from its peripheral vector on a real part. */
__attribute__((section(".vectors"), used)) static const uintptr_t vectors[2] = {
    (uintptr_t)&_estack,
    (uintptr_t)&m4_reset_handler,
};

#define SCB_CPACR (*(volatile uint32_t *)0xE000ED88u)

void m4_reset_handler(void)
{
    const uint32_t *src = &_sidata;
    uint32_t *dst;
    for (dst = &_sdata; dst < &_edata; dst++) {
        *dst = *src++;
    }
    for (dst = &_sbss; dst < &_ebss; dst++) {
        *dst = 0u;
    }
#ifdef __ARM_FP
    SCB_CPACR |= (0xFu << 20); /* CP10, CP11 full access: the single-precision FPU */
    __asm volatile("dsb\n\tisb" ::: "memory");
#endif
}
