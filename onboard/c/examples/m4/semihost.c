#include "semihost.h"

#include <stdint.h>

#define SYS_OPEN 0x01
#define SYS_WRITE 0x05
#define SYS_EXIT 0x18
#define ADP_STOPPED_APPLICATION_EXIT 0x20026
#define ADP_STOPPED_RUNTIME_ERROR_UNKNOWN 0x20023
/* SYS_OPEN mode 4 ("w") on ":tt" is the console's output. */
#define OPEN_MODE_WRITE 4

static int semihost_call(int operation, const void *argument) {
    register int r0 __asm__("r0") = operation;
    register const void *r1 __asm__("r1") = argument;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

int semihost_write(const char *text, size_t len) {
    static int handle = -1;
    if (handle < 0) {
        const uintptr_t open[3] = {(uintptr_t)":tt", OPEN_MODE_WRITE, 3};
        handle = semihost_call(SYS_OPEN, open);
        if (handle < 0) {
            return -1;
        }
    }
    const uintptr_t write[3] = {(uintptr_t)handle, (uintptr_t)text, len};
    /* The call returns the number of bytes not written. */
    return semihost_call(SYS_WRITE, write) == 0 ? 0 : -1;
}

void semihost_exit(int ok) {
    /* On 32-bit Arm the argument of SYS_EXIT is the reason itself. */
    semihost_call(SYS_EXIT, (const void *)(uintptr_t)(ok ? ADP_STOPPED_APPLICATION_EXIT
                                                         : ADP_STOPPED_RUNTIME_ERROR_UNKNOWN));
    for (;;) {
        /* Without a semihosting host (a real board) stay here. */
    }
}
