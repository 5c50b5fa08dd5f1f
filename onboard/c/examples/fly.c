/* Host program: flies the guidance calls of a calls file (guidance_calls.rs) with a weight blob
 * through liblowthrust.a, and prints the outcome of each (replay.c), for scripts/c-sil.sh to
 * compare with the Rust output.
 *
 *   fly BLOB CALLS.bin > out.txt
 *
 * Exit status 1 when the calls file is refused (a format or problem this replay does not know;
 * why on stderr) or the output cannot be written, 2 for wrong arguments or unreadable files.
 *
 * Build: cc -std=c99 -I onboard/c/include fly.c replay.c target/c-release/liblowthrust.a
 *        -lpthread -ldl -lm */
#include <stdio.h>
#include <stdlib.h>

#include "replay.h"

static void write_stdout(void *context, const char *text, size_t len) {
    (void)context;
    fwrite(text, 1, len, stdout);
}

/* The whole file in a heap buffer (freed at exit: the blob must outlive the policy). */
static uint8_t *read_file(const char *path, size_t *len) {
    FILE *f = fopen(path, "rb");
    if (f == NULL) {
        return NULL;
    }
    uint8_t *data = NULL;
    size_t size = 0;
    for (;;) {
        uint8_t *grown = realloc(data, size + 65536);
        if (grown == NULL) {
            free(data);
            fclose(f);
            return NULL;
        }
        data = grown;
        size_t n = fread(data + size, 1, 65536, f);
        size += n;
        if (n < 65536) {
            break;
        }
    }
    int failed = ferror(f);
    fclose(f);
    if (failed) {
        free(data);
        return NULL;
    }
    *len = size;
    return data;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: fly BLOB CALLS.bin\n");
        return 2;
    }
    size_t blob_len = 0, calls_len = 0;
    uint8_t *blob = read_file(argv[1], &blob_len);
    uint8_t *calls = read_file(argv[2], &calls_len);
    if (blob == NULL || calls == NULL) {
        fprintf(stderr, "fly: cannot read %s\n", blob == NULL ? argv[1] : argv[2]);
        return 2;
    }
    const int status = replay_calls(blob, blob_len, calls, calls_len, write_stdout, NULL);
    if (status != REPLAY_OK) {
        fprintf(stderr, "fly: %s: %s\n", argv[2], replay_status_text(status));
    }
    const int written = fflush(stdout) == 0;
    free(calls);
    free(blob);
    return status == REPLAY_OK && written ? 0 : 1;
}
