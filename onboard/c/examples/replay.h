/* Replays recorded guidance calls through the C interface and prints each outcome, so the
 * output can be compared byte for byte with what the Rust crates computed (guidance_calls.rs
 * writes the calls and the expected output; scripts/c-sil.sh compares). Freestanding: no libc,
 * so the same code runs in the host program (fly.c) and the Cortex-M4F image (m4/main.c). */
#ifndef LOWTHRUST_REPLAY_H
#define LOWTHRUST_REPLAY_H

#include <stddef.h>
#include <stdint.h>

/* Receives the output, a piece at a time (lines end with '\n'). */
typedef void (*replay_write_fn)(void *context, const char *text, size_t len);

/* Loads `blob` as the calls file says (transfer or rendezvous), flies every call, writes one
 * line per call. Returns 0, or -1 if `calls` is not a calls file (nothing is flown then). */
int replay_calls(const uint8_t *blob, size_t blob_len, const uint8_t *calls, size_t calls_len,
                 replay_write_fn write, void *context);

#endif /* LOWTHRUST_REPLAY_H */
