/* The Cortex-M4F image (QEMU mps2-an386): flies the guidance calls linked into flash through
 * liblowthrust.a (thumbv7em-none-eabihf) with replay.c, the host program's code, and writes the
 * same lines through semihosting, then a comment with the stack's peak. */
#include <stdint.h>

#include "../replay.h"
#include "semihost.h"
#include "stack.h"

extern const uint8_t lt_blob[], lt_blob_end[], lt_calls[], lt_calls_end[];

/* One semihosting call per line rather than per piece (each call traps into QEMU). */
typedef struct {
    char text[256];
    uint32_t len;
    int failed;
} line_t;

static void flush(line_t *line) {
    if (line->len > 0u && semihost_write(line->text, line->len) != 0) {
        line->failed = 1;
    }
    line->len = 0;
}

static void write_line(void *context, const char *text, size_t len) {
    line_t *line = context;
    for (size_t i = 0; i < len; i++) {
        if (line->len == sizeof line->text) {
            flush(line);
        }
        line->text[line->len++] = text[i];
        if (text[i] == '\n') {
            flush(line);
        }
    }
}

static void write_text(line_t *line, const char *text) {
    size_t len = 0;
    while (text[len] != '\0') {
        len++;
    }
    write_line(line, text, len);
}

static void put_number(line_t *line, uint32_t v) {
    char digits[10];
    size_t i = sizeof digits;
    do {
        digits[--i] = (char)('0' + v % 10u);
        v /= 10u;
    } while (v != 0u);
    write_line(line, digits + i, sizeof digits - i);
}

int main(void) {
    static line_t line;
    const int status = replay_calls(lt_blob, (size_t)(lt_blob_end - lt_blob), lt_calls,
                                    (size_t)(lt_calls_end - lt_calls), write_line, &line);
    if (status != REPLAY_OK) {
        /* Not a comment: the comparison must show why nothing was flown. */
        write_text(&line, "replay refused the calls file: ");
        write_text(&line, replay_status_text(status));
        write_text(&line, "\n");
    }
    /* A comment line (the comparison skips lines starting with '#'). */
    write_text(&line, "# stack high-water ");
    put_number(&line, stack_high_water());
    write_text(&line, " bytes of ");
    put_number(&line, stack_reserved());
    write_text(&line, "\n");
    flush(&line);
    return status == REPLAY_OK && !line.failed ? 0 : 1;
}
