#ifndef LOWTHRUST_STACK_H
#define LOWTHRUST_STACK_H

#include <stdint.h>

/* Deepest stack use since boot, in bytes from the top of RAM (painted at boot). */
uint32_t stack_high_water(void);

/* Bytes of RAM between the end of .bss and the top: what the stack may use. */
uint32_t stack_reserved(void);

#endif /* LOWTHRUST_STACK_H */
