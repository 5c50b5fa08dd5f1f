/* See replay.h. The calls file is guidance_calls.rs's calls.bin: "LTGC", u32 format 1, u32
 * problem (0 transfer, 1 rendezvous), u32 count, then per call 10 little-endian f64: x, y, vx,
 * vy, m, four target values (a, e, omega, 0 or the body's x, y, vx, vy), time to go. */
#include "replay.h"

#include "lowthrust.h"

#define CALLS_HEADER 16u
#define CALL_VALUES 10u
#define CALL_BYTES (CALL_VALUES * 8u)

typedef struct {
    replay_write_fn write;
    void *context;
} out_t;

static size_t text_len(const char *s) {
    size_t n = 0;
    while (s[n] != '\0') {
        n++;
    }
    return n;
}

static void put(const out_t *out, const char *s) { out->write(out->context, s, text_len(s)); }

static void put_unsigned(const out_t *out, uint32_t v) {
    char digits[11];
    size_t i = sizeof digits;
    do {
        digits[--i] = (char)('0' + v % 10u);
        v /= 10u;
    } while (v != 0u);
    out->write(out->context, digits + i, sizeof digits - i);
}

static void put_signed(const out_t *out, int32_t v) {
    if (v < 0) {
        put(out, "-");
        put_unsigned(out, (uint32_t)0 - (uint32_t)v);
    } else {
        put_unsigned(out, (uint32_t)v);
    }
}

/* A double as its 16 hex digits: equal text means equal bits. */
static void put_bits(const out_t *out, double x) {
    static const char hex[] = "0123456789abcdef";
    uint64_t b;
    char digits[16];
    __builtin_memcpy(&b, &x, sizeof b);
    for (int i = 15; i >= 0; i--) {
        digits[i] = hex[b & 0xfu];
        b >>= 4;
    }
    out->write(out->context, digits, sizeof digits);
}

static uint32_t u32_at(const uint8_t *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static double f64_at(const uint8_t *p) {
    uint64_t b = 0;
    double x;
    for (int i = 7; i >= 0; i--) {
        b = b << 8 | p[i];
    }
    __builtin_memcpy(&x, &b, sizeof x);
    return x;
}

int replay_calls(const uint8_t *blob, size_t blob_len, const uint8_t *calls, size_t calls_len,
                 replay_write_fn write, void *context) {
    const out_t out = {write, context};
    if (calls_len < CALLS_HEADER || calls[0] != 'L' || calls[1] != 'T' || calls[2] != 'G' ||
        calls[3] != 'C' || u32_at(calls + 4) != 1u) {
        return -1;
    }
    const uint32_t problem = u32_at(calls + 8);
    const uint32_t count = u32_at(calls + 12);
    if (problem > 1u || (calls_len - CALLS_HEADER) / CALL_BYTES != count ||
        (calls_len - CALLS_HEADER) % CALL_BYTES != 0u) {
        return -1;
    }

    lt_version_info version;
    if (lt_version(&version) != LT_OK) {
        return -1;
    }
    put(&out, "lowthrust ");
    put_unsigned(&out, version.major);
    put(&out, ".");
    put_unsigned(&out, version.minor);
    put(&out, ".");
    put_unsigned(&out, version.patch);
    put(&out, " blob format ");
    put_unsigned(&out, version.blob_format_version);
    put(&out, "\n");

    /* Static: zero-initialized storage is a policy not loaded, and flight software keeps its
     * policy in static storage too. The blob outlives it (the caller's, or flash). */
    static lt_policy policy;
    const char *problem_name = problem == 0u ? "transfer" : "rendezvous";
    const lt_status loaded = problem == 0u ? lt_transfer_load(&policy, blob, blob_len)
                                           : lt_rendezvous_load(&policy, blob, blob_len);
    put(&out, "load ");
    put(&out, problem_name);
    put(&out, " ");
    put_signed(&out, loaded);
    put(&out, " ");
    put(&out, lt_error_name(loaded));
    put(&out, "\n");
    lt_policy_info info;
    if (lt_policy_describe(&policy, &info) == LT_OK) {
        put(&out, "policy ");
        put(&out, info.problem == LT_PROBLEM_TRANSFER ? "transfer" : "rendezvous");
        put(&out, info.quantization == LT_QUANTIZATION_F32 ? " f32\n" : " int8\n");
    }

    /* A refused load is flown on anyway: every step must then refuse with thrust off, which is
     * what flight software in safe mode would command. */
    for (uint32_t i = 0; i < count; i++) {
        double v[CALL_VALUES];
        const uint8_t *record = calls + CALLS_HEADER + (size_t)i * CALL_BYTES;
        for (uint32_t k = 0; k < CALL_VALUES; k++) {
            v[k] = f64_at(record + 8u * k);
        }
        const lt_navigation_state navigation = {{v[0], v[1]}, {v[2], v[3]}, v[4]};
        const double time_to_go = v[9];
        lt_thrust_command command;
        lt_status status;
        if (problem == 0u) {
            const lt_target_orbit target = {v[5], v[6], v[7]};
            status = lt_transfer_step(&policy, &navigation, &target, time_to_go, &command);
        } else {
            const lt_body_state body = {{v[5], v[6]}, {v[7], v[8]}};
            status = lt_rendezvous_step(&policy, &navigation, &body, time_to_go, &command);
        }
        put(&out, "call ");
        put_unsigned(&out, i);
        if (status != LT_OK) {
            put(&out, " refused ");
            put_signed(&out, status);
            put(&out, " ");
            put(&out, lt_error_name(status));
        }
        put(&out, " cmd ");
        put_bits(&out, command.throttle);
        put(&out, " ");
        put_bits(&out, command.alpha_r);
        put(&out, " ");
        put_bits(&out, command.alpha_theta);
        put(&out, "\n");
    }
    put(&out, "end ");
    put_unsigned(&out, count);
    put(&out, " calls\n");
    return 0;
}
