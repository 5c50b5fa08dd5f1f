/* Replays recorded guidance calls through the C interface and prints each outcome, so the
 * output can be compared byte for byte with what the Rust crates computed (guidance_calls.rs
 * writes the calls and the expected output; scripts/c-sil.sh compares). Freestanding: no libc,
 * so the same code runs in the host program (fly.c) and the Cortex-M4F image (m4/main.c). */
#ifndef LOWTHRUST_REPLAY_H
#define LOWTHRUST_REPLAY_H

#include <stddef.h>
#include <stdint.h>

/* The calls file format this replay reads (guidance_calls.rs documents it). */
#define REPLAY_CALLS_FORMAT 3

/* What replay_calls returns: the calls were flown, or why nothing was. */
enum {
    REPLAY_OK = 0,
    /* Shorter than the header, or not starting with "LTGC". */
    REPLAY_NOT_CALLS = -1,
    /* A format other than REPLAY_CALLS_FORMAT. */
    REPLAY_UNKNOWN_FORMAT = -2,
    /* A problem other than the C interface's four (LT_PROBLEM_*). */
    REPLAY_UNKNOWN_PROBLEM = -3,
    /* The length is not the header's count of the problem's records. */
    REPLAY_WRONG_LENGTH = -4,
    /* lt_version refused. */
    REPLAY_NO_VERSION = -5,
    /* A count of the aids' settings is not a whole number, or a call's aid is unknown. */
    REPLAY_BAD_AIDS = -6
};

/* Receives the output, a piece at a time (lines end with '\n'). */
typedef void (*replay_write_fn)(void *context, const char *text, size_t len);

/* Loads `blob` as the calls file's problem says (transfer or rendezvous, planar or in three
 * dimensions), flies every call (the network's step, or lookahead or terminal targeting with the
 * file's settings), writes one line per call. Returns REPLAY_OK, or a refusal of
 * the calls file (nothing is written then). */
int replay_calls(const uint8_t *blob, size_t blob_len, const uint8_t *calls, size_t calls_len,
                 replay_write_fn write, void *context);

/* What a return value of replay_calls means, as a sentence without a final period. */
const char *replay_status_text(int status);

#endif /* LOWTHRUST_REPLAY_H */
