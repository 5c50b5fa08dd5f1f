/* See replay.h. The calls file is guidance_calls.rs's calls.bin: "LTGC", u32 format 2, u32
 * problem (LT_PROBLEM_*), u32 count, then per call little-endian f64s: the navigation state
 * (x, y, vx, vy, m; in three dimensions x, y, z, vx, vy, vz, m), the target (a, e, omega, 0 or
 * the body's x, y, vx, vy; in three dimensions a, e, omega, inclination, raan, 0 or the body's
 * x, y, z, vx, vy, vz), the time to go: 10 values per planar call, 14 in three dimensions. */
#include "replay.h"

#include "lowthrust.h"

#define CALLS_HEADER 16u
#define PLANAR_CALL_VALUES 10u
#define SPATIAL_CALL_VALUES 14u
#define MAX_CALL_VALUES SPATIAL_CALL_VALUES
#define MAX_COMMAND_VALUES 4u

/* Each problem of the C interface, by its LT_PROBLEM_* number. */
typedef struct {
    const char *name;
    uint32_t call_values;
    lt_status (*load)(lt_policy *policy, const uint8_t *blob, size_t blob_len);
} problem_t;

static const problem_t problems[] = {
    [LT_PROBLEM_TRANSFER] = {"transfer", PLANAR_CALL_VALUES, lt_transfer_load},
    [LT_PROBLEM_RENDEZVOUS] = {"rendezvous", PLANAR_CALL_VALUES, lt_rendezvous_load},
    [LT_PROBLEM_TRANSFER3] = {"transfer3", SPATIAL_CALL_VALUES, lt_transfer3_load},
    [LT_PROBLEM_RENDEZVOUS3] = {"rendezvous3", SPATIAL_CALL_VALUES, lt_rendezvous3_load},
};
#define PROBLEM_COUNT (sizeof problems / sizeof problems[0])

/* The format number in the refusal's text, from its one definition. */
#define QUOTED(x) #x
#define QUOTED_VALUE(x) QUOTED(x)

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

/* One call of `problem` from its values: the command's values (throttle first) to `command`,
 * their count to `*command_len`. */
static lt_status fly_call(uint32_t problem, const lt_policy *policy, const double *v,
                          double command[MAX_COMMAND_VALUES], uint32_t *command_len) {
    lt_status status;
    if (problem == LT_PROBLEM_TRANSFER || problem == LT_PROBLEM_RENDEZVOUS) {
        const lt_navigation_state navigation = {{v[0], v[1]}, {v[2], v[3]}, v[4]};
        const double time_to_go = v[PLANAR_CALL_VALUES - 1u];
        lt_thrust_command c;
        if (problem == LT_PROBLEM_TRANSFER) {
            const lt_target_orbit target = {v[5], v[6], v[7]};
            status = lt_transfer_step(policy, &navigation, &target, time_to_go, &c);
        } else {
            const lt_body_state body = {{v[5], v[6]}, {v[7], v[8]}};
            status = lt_rendezvous_step(policy, &navigation, &body, time_to_go, &c);
        }
        command[0] = c.throttle;
        command[1] = c.alpha_r;
        command[2] = c.alpha_theta;
        *command_len = 3u;
    } else {
        const lt_navigation_state3 navigation = {{v[0], v[1], v[2]}, {v[3], v[4], v[5]}, v[6]};
        const double time_to_go = v[SPATIAL_CALL_VALUES - 1u];
        lt_rtn_command c;
        if (problem == LT_PROBLEM_TRANSFER3) {
            const lt_target_orbit3 target = {v[7], v[8], v[9], v[10], v[11]};
            status = lt_transfer3_step(policy, &navigation, &target, time_to_go, &c);
        } else {
            const lt_body_state3 body = {{v[7], v[8], v[9]}, {v[10], v[11], v[12]}};
            status = lt_rendezvous3_step(policy, &navigation, &body, time_to_go, &c);
        }
        command[0] = c.throttle;
        command[1] = c.radial;
        command[2] = c.transverse;
        command[3] = c.normal;
        *command_len = 4u;
    }
    return status;
}

int replay_calls(const uint8_t *blob, size_t blob_len, const uint8_t *calls, size_t calls_len,
                 replay_write_fn write, void *context) {
    const out_t out = {write, context};
    if (calls_len < CALLS_HEADER || calls[0] != 'L' || calls[1] != 'T' || calls[2] != 'G' ||
        calls[3] != 'C') {
        return REPLAY_NOT_CALLS;
    }
    if (u32_at(calls + 4) != REPLAY_CALLS_FORMAT) {
        return REPLAY_UNKNOWN_FORMAT;
    }
    const uint32_t problem = u32_at(calls + 8);
    const uint32_t count = u32_at(calls + 12);
    if (problem >= PROBLEM_COUNT) {
        return REPLAY_UNKNOWN_PROBLEM;
    }
    const size_t call_bytes = problems[problem].call_values * 8u;
    if ((calls_len - CALLS_HEADER) / call_bytes != count || (calls_len - CALLS_HEADER) % call_bytes != 0u) {
        return REPLAY_WRONG_LENGTH;
    }

    lt_version_info version;
    if (lt_version(&version) != LT_OK) {
        return REPLAY_NO_VERSION;
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
    const lt_status loaded = problems[problem].load(&policy, blob, blob_len);
    put(&out, "load ");
    put(&out, problems[problem].name);
    put(&out, " ");
    put_signed(&out, loaded);
    put(&out, " ");
    put(&out, lt_error_name(loaded));
    put(&out, "\n");
    lt_policy_info info;
    if (lt_policy_describe(&policy, &info) == LT_OK) {
        put(&out, "policy ");
        put(&out, info.problem < PROBLEM_COUNT ? problems[info.problem].name : "unknown");
        put(&out, info.quantization == LT_QUANTIZATION_F32 ? " f32\n" : " int8\n");
    }

    /* A refused load is flown on anyway: every step must then refuse with thrust off, which is
     * what flight software in safe mode would command. */
    for (uint32_t i = 0; i < count; i++) {
        double v[MAX_CALL_VALUES];
        const uint8_t *record = calls + CALLS_HEADER + (size_t)i * call_bytes;
        for (uint32_t k = 0; k < problems[problem].call_values; k++) {
            v[k] = f64_at(record + 8u * k);
        }
        double command[MAX_COMMAND_VALUES];
        uint32_t command_len;
        const lt_status status = fly_call(problem, &policy, v, command, &command_len);
        put(&out, "call ");
        put_unsigned(&out, i);
        if (status != LT_OK) {
            put(&out, " refused ");
            put_signed(&out, status);
            put(&out, " ");
            put(&out, lt_error_name(status));
        }
        put(&out, " cmd");
        for (uint32_t k = 0; k < command_len; k++) {
            put(&out, " ");
            put_bits(&out, command[k]);
        }
        put(&out, "\n");
    }
    put(&out, "end ");
    put_unsigned(&out, count);
    put(&out, " calls\n");
    return REPLAY_OK;
}

const char *replay_status_text(int status) {
    switch (status) {
    case REPLAY_OK:
        return "flown";
    case REPLAY_NOT_CALLS:
        return "not a calls file (no \"LTGC\" header)";
    case REPLAY_UNKNOWN_FORMAT:
        return "a calls file format this replay does not read (it reads format "
               QUOTED_VALUE(REPLAY_CALLS_FORMAT) ")";
    case REPLAY_UNKNOWN_PROBLEM:
        return "a problem this replay does not fly (it flies 0 transfer, 1 rendezvous, 2 transfer3, "
               "3 rendezvous3)";
    case REPLAY_WRONG_LENGTH:
        return "the length is not the header's count of the problem's calls";
    case REPLAY_NO_VERSION:
        return "lt_version refused";
    default:
        return "unknown replay status";
    }
}
