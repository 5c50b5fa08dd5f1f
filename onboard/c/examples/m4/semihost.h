/* ARM semihosting (QEMU -semihosting-config enable=on,target=native): output on the host's
 * stdout, and the exit status of the QEMU process. */
#ifndef LOWTHRUST_SEMIHOST_H
#define LOWTHRUST_SEMIHOST_H

#include <stddef.h>

/* Writes `len` bytes to the host's stdout; 0 on success. */
int semihost_write(const char *text, size_t len);

/* Ends the run: QEMU exits with status 0 when `ok`, 1 otherwise. */
void semihost_exit(int ok) __attribute__((noreturn));

#endif /* LOWTHRUST_SEMIHOST_H */
