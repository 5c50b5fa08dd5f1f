/* Boot for the Cortex-M4F image: vector table, .data and .bss, the FPU on, the free RAM painted
 * (for the stack high-water mark), then main; a fault ends the run with failure. Only integer
 * code runs before the FPU is enabled. */
#include <stdint.h>

#include "semihost.h"
#include "stack.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _stack_top;

int main(void);

/* Coprocessor access control: CP10 and CP11 (the FPU) full access. */
#define SCB_CPACR (*(volatile uint32_t *)0xE000ED88u)
#define STACK_PAINT 0xDEADBEEFu
/* Left unpainted below the live stack pointer while painting (this frame). */
#define PAINT_GUARD 64u

void reset_handler(void) {
    const uint32_t *from = &_sidata;
    for (uint32_t *to = &_sdata; to < &_edata;) {
        *to++ = *from++;
    }
    for (uint32_t *p = &_sbss; p < &_ebss;) {
        *p++ = 0;
    }
    SCB_CPACR |= 0xFu << 20;
    __asm__ volatile("dsb\n\tisb" ::: "memory");
    uintptr_t sp;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    for (volatile uint32_t *p = &_ebss; (uintptr_t)(p + 1) <= sp - PAINT_GUARD; p++) {
        *p = STACK_PAINT;
    }
    semihost_exit(main() == 0);
}

uint32_t stack_high_water(void) {
    const volatile uint32_t *p = &_ebss;
    while (p < &_stack_top && *p == STACK_PAINT) {
        p++;
    }
    return (uint32_t)((uintptr_t)&_stack_top - (uintptr_t)p);
}

uint32_t stack_reserved(void) { return (uint32_t)((uintptr_t)&_stack_top - (uintptr_t)&_ebss); }

static void fail(const char *why, uint32_t len) {
    semihost_write(why, len);
    semihost_exit(0);
}

void hard_fault_handler(void) { fail("hard fault\n", 11); }

void default_handler(void) { fail("unexpected exception\n", 21); }

typedef void (*vector_t)(void);

/* Initial stack pointer, then the Cortex-M system exceptions (no interrupt is enabled). */
__attribute__((section(".vectors"), used)) static const vector_t vectors[16] = {
    (vector_t)(uintptr_t)&_stack_top,
    reset_handler,
    default_handler,    /* NMI */
    hard_fault_handler, /* HardFault */
    hard_fault_handler, /* MemManage */
    hard_fault_handler, /* BusFault */
    hard_fault_handler, /* UsageFault (a trap such as the library's panic backstop, `udf`) */
    0, 0, 0, 0,
    default_handler, /* SVCall */
    default_handler, /* DebugMonitor */
    0,
    default_handler, /* PendSV */
    default_handler, /* SysTick */
};
