/* See replay.h. The calls file is guidance_calls.rs's calls.bin: "LTGC", u32 format 3, u32
 * problem (LT_PROBLEM_*), u32 count, the onboard aids' 16 little-endian f64s (the spacecraft:
 * thrust, exhaust speed; the lookahead settings: goal position, goal velocity, accuracy floor,
 * fuel weight, thrust margin, cycle, max cycles, arrival margin, rollout budget; the terminal
 * settings: goal position, goal velocity, cycle, cycles, iterations), then per call f64s: the aid
 * (AID_*), the navigation state (x, y, vx, vy, m; in three dimensions x, y, z, vx, vy, vz, m),
 * the target (a, e, omega, 0 or the body's x, y, vx, vy; in three dimensions a, e, omega,
 * inclination, raan, 0 or the body's x, y, z, vx, vy, vz), the time to go: 11 values per planar
 * call, 15 in three dimensions. */
#include "replay.h"

#include "lowthrust.h"

#define BASE_HEADER 16u
#define AID_VALUES 16u
#define CALLS_HEADER (BASE_HEADER + 8u * AID_VALUES)
#define PLANAR_CALL_VALUES 11u
#define SPATIAL_CALL_VALUES 15u
#define MAX_CALL_VALUES SPATIAL_CALL_VALUES
#define MAX_COMMAND_VALUES 4u

/* An image built for one problem (-DREPLAY_PROBLEM=LT_PROBLEM_...) flies only that problem's
 * calls, so it links only that problem's steps and aids, as flight software would; without it
 * all four. */
#ifdef REPLAY_PROBLEM
#define FLOWN_PROBLEM(problem) ((void)(problem), (uint32_t)(REPLAY_PROBLEM))
#else
#define FLOWN_PROBLEM(problem) (problem)
#endif

/* How a call is flown: the network's step, or an onboard aid around it. */
enum { AID_NETWORK = 0, AID_LOOKAHEAD = 1, AID_TERMINAL = 2 };

/* The aids' spacecraft and settings, from the calls file's header. */
typedef struct {
    lt_spacecraft spacecraft;
    lt_lookahead_settings lookahead;
    lt_terminal_settings terminal;
} aids_t;

/* An aid's report, either dimension: the lookahead's chosen candidate or terminal targeting's
 * solved flag, whether an arrival was predicted, the predicted values (lookahead: position,
 * velocity, mass, cost; terminal: the network's miss, the plan's miss) and the network's own
 * command (throttle first). */
typedef struct {
    uint32_t flag;
    uint32_t predicted_valid;
    double predicted[4];
    uint32_t predicted_len;
    double network[MAX_COMMAND_VALUES];
} report_t;

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

#define LOOKAHEAD_REPORT(out, r)                                                                   \
    do {                                                                                           \
        (out)->flag = (r).chosen;                                                                  \
        (out)->predicted_valid = (r).predicted_valid;                                              \
        (out)->predicted[0] = (r).predicted_position;                                              \
        (out)->predicted[1] = (r).predicted_velocity;                                              \
        (out)->predicted[2] = (r).predicted_mass;                                                  \
        (out)->predicted[3] = (r).predicted_cost;                                                  \
        (out)->predicted_len = 4u;                                                                 \
    } while (0)

#define TERMINAL_REPORT(out, r)                                                                    \
    do {                                                                                           \
        (out)->flag = (r).solved;                                                                  \
        (out)->predicted_valid = (r).predicted_valid;                                              \
        (out)->predicted[0] = (r).network_miss;                                                    \
        (out)->predicted[1] = (r).planned_miss;                                                    \
        (out)->predicted_len = 2u;                                                                 \
    } while (0)

static void planar_values(const lt_thrust_command *c, double out[MAX_COMMAND_VALUES]) {
    out[0] = c->throttle;
    out[1] = c->alpha_r;
    out[2] = c->alpha_theta;
}

static void rtn_values(const lt_rtn_command *c, double out[MAX_COMMAND_VALUES]) {
    out[0] = c->throttle;
    out[1] = c->radial;
    out[2] = c->transverse;
    out[3] = c->normal;
}

/* One planar call flown with `aid`: the command to `c`, an aid's report to `report`. */
static lt_status fly_planar(uint32_t problem, uint32_t aid, const aids_t *aids, const lt_policy *policy,
                            const double *v, lt_thrust_command *c, report_t *report) {
    const lt_navigation_state navigation = {{v[0], v[1]}, {v[2], v[3]}, v[4]};
    const double time_to_go = v[PLANAR_CALL_VALUES - 2u];
    const lt_target_orbit target = {v[5], v[6], v[7]};
    const lt_body_state body = {{v[5], v[6]}, {v[7], v[8]}};
    const int transfer = problem == LT_PROBLEM_TRANSFER;
    lt_status status;
    if (aid == AID_LOOKAHEAD) {
        lt_lookahead_report r;
        status = transfer ? lt_transfer_lookahead_step(policy, &navigation, &target, time_to_go,
                                                       &aids->spacecraft, &aids->lookahead, c, &r)
                          : lt_rendezvous_lookahead_step(policy, &navigation, &body, time_to_go,
                                                         &aids->spacecraft, &aids->lookahead, c, &r);
        LOOKAHEAD_REPORT(report, r);
        planar_values(&r.network, report->network);
    } else if (aid == AID_TERMINAL) {
        lt_terminal_report r;
        status = transfer ? lt_transfer_terminal_step(policy, &navigation, &target, time_to_go,
                                                      &aids->spacecraft, &aids->terminal, c, &r)
                          : lt_rendezvous_terminal_step(policy, &navigation, &body, time_to_go,
                                                        &aids->spacecraft, &aids->terminal, c, &r);
        TERMINAL_REPORT(report, r);
        planar_values(&r.network, report->network);
    } else {
        status = transfer ? lt_transfer_step(policy, &navigation, &target, time_to_go, c)
                          : lt_rendezvous_step(policy, &navigation, &body, time_to_go, c);
    }
    return status;
}

/* One call in three dimensions flown with `aid`, as fly_planar. */
static lt_status fly_spatial(uint32_t problem, uint32_t aid, const aids_t *aids, const lt_policy *policy,
                             const double *v, lt_rtn_command *c, report_t *report) {
    const lt_navigation_state3 navigation = {{v[0], v[1], v[2]}, {v[3], v[4], v[5]}, v[6]};
    const double time_to_go = v[SPATIAL_CALL_VALUES - 2u];
    const lt_target_orbit3 target = {v[7], v[8], v[9], v[10], v[11]};
    const lt_body_state3 body = {{v[7], v[8], v[9]}, {v[10], v[11], v[12]}};
    const int transfer = problem == LT_PROBLEM_TRANSFER3;
    lt_status status;
    if (aid == AID_LOOKAHEAD) {
        lt_lookahead_report3 r;
        status = transfer ? lt_transfer3_lookahead_step(policy, &navigation, &target, time_to_go,
                                                        &aids->spacecraft, &aids->lookahead, c, &r)
                          : lt_rendezvous3_lookahead_step(policy, &navigation, &body, time_to_go,
                                                          &aids->spacecraft, &aids->lookahead, c, &r);
        LOOKAHEAD_REPORT(report, r);
        rtn_values(&r.network, report->network);
    } else if (aid == AID_TERMINAL) {
        lt_terminal_report3 r;
        status = transfer ? lt_transfer3_terminal_step(policy, &navigation, &target, time_to_go,
                                                       &aids->spacecraft, &aids->terminal, c, &r)
                          : lt_rendezvous3_terminal_step(policy, &navigation, &body, time_to_go,
                                                         &aids->spacecraft, &aids->terminal, c, &r);
        TERMINAL_REPORT(report, r);
        rtn_values(&r.network, report->network);
    } else {
        status = transfer ? lt_transfer3_step(policy, &navigation, &target, time_to_go, c)
                          : lt_rendezvous3_step(policy, &navigation, &body, time_to_go, c);
    }
    return status;
}

/* One call of `problem` flown with `aid` from its values (after the aid): the command's values
 * (throttle first) to `command`, their count to `*command_len`, an aid's report to `report`. */
static lt_status fly_call(uint32_t calls_problem, uint32_t aid, const aids_t *aids, const lt_policy *policy,
                          const double *v, double command[MAX_COMMAND_VALUES], uint32_t *command_len,
                          report_t *report) {
    const uint32_t problem = FLOWN_PROBLEM(calls_problem);
    lt_status status;
    if (problem == LT_PROBLEM_TRANSFER || problem == LT_PROBLEM_RENDEZVOUS) {
        lt_thrust_command c;
        status = fly_planar(problem, aid, aids, policy, v, &c, report);
        planar_values(&c, command);
        *command_len = 3u;
    } else {
        lt_rtn_command c;
        status = fly_spatial(problem, aid, aids, policy, v, &c, report);
        rtn_values(&c, command);
        *command_len = 4u;
    }
    return status;
}

/* `x` as a count: 1 and the count to `*out` when `x` is a whole number in the u32 range, else 0
 * (converting any other double to uint32_t is undefined). */
static int whole_u32(double x, uint32_t *out) {
    if (!(x >= 0.0 && x <= 4294967295.0)) {
        return 0;
    }
    *out = (uint32_t)x;
    return (double)*out == x;
}

/* The aids' values of the header at `p` to `*aids`: 1, or 0 when a count is not a whole u32. */
static int read_aids(const uint8_t *p, aids_t *aids) {
    double v[AID_VALUES];
    for (uint32_t k = 0; k < AID_VALUES; k++) {
        v[k] = f64_at(p + 8u * k);
    }
    aids->spacecraft.thrust = v[0];
    aids->spacecraft.exhaust_speed = v[1];
    aids->lookahead.goal_position = v[2];
    aids->lookahead.goal_velocity = v[3];
    aids->lookahead.accuracy_floor = v[4];
    aids->lookahead.fuel_weight = v[5];
    aids->lookahead.thrust_margin = v[6];
    aids->lookahead.cycle = v[7];
    aids->terminal.goal_position = v[11];
    aids->terminal.goal_velocity = v[12];
    aids->terminal.cycle = v[13];
    return whole_u32(v[8], &aids->lookahead.max_cycles) && whole_u32(v[9], &aids->lookahead.arrival_margin) &&
           whole_u32(v[10], &aids->lookahead.rollout_budget) && whole_u32(v[14], &aids->terminal.cycles) &&
           whole_u32(v[15], &aids->terminal.iterations);
}

/* Whether `x` is a call's aid (AID_*). */
static int is_aid(double x) { return x == AID_NETWORK || x == AID_LOOKAHEAD || x == AID_TERMINAL; }

int replay_calls(const uint8_t *blob, size_t blob_len, const uint8_t *calls, size_t calls_len,
                 replay_write_fn write, void *context) {
    const out_t out = {write, context};
    if (calls_len < BASE_HEADER || calls[0] != 'L' || calls[1] != 'T' || calls[2] != 'G' ||
        calls[3] != 'C') {
        return REPLAY_NOT_CALLS;
    }
    if (u32_at(calls + 4) != REPLAY_CALLS_FORMAT) {
        return REPLAY_UNKNOWN_FORMAT;
    }
    const uint32_t problem = u32_at(calls + 8);
    const uint32_t count = u32_at(calls + 12);
    if (problem >= PROBLEM_COUNT || problem != FLOWN_PROBLEM(problem)) {
        return REPLAY_UNKNOWN_PROBLEM;
    }
    const size_t call_bytes = problems[problem].call_values * 8u;
    if (calls_len < CALLS_HEADER || (calls_len - CALLS_HEADER) / call_bytes != count ||
        (calls_len - CALLS_HEADER) % call_bytes != 0u) {
        return REPLAY_WRONG_LENGTH;
    }
    aids_t aids;
    if (!read_aids(calls + BASE_HEADER, &aids)) {
        return REPLAY_BAD_AIDS;
    }
    for (uint32_t i = 0; i < count; i++) {
        if (!is_aid(f64_at(calls + CALLS_HEADER + (size_t)i * call_bytes))) {
            return REPLAY_BAD_AIDS;
        }
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
        report_t report = {0};
        /* A whole number 0 to 2: every call's aid was checked before any was flown. */
        const uint32_t aid = (uint32_t)v[0];
        const lt_status status = fly_call(problem, aid, &aids, &policy, v + 1, command, &command_len, &report);
        put(&out, "call ");
        put_unsigned(&out, i);
        put(&out, aid == AID_LOOKAHEAD ? " lookahead" : aid == AID_TERMINAL ? " terminal" : "");
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
        if (aid != AID_NETWORK) {
            put(&out, aid == AID_LOOKAHEAD ? " chosen " : " solved ");
            put_unsigned(&out, report.flag);
            put(&out, " predicted ");
            put_unsigned(&out, report.predicted_valid);
            for (uint32_t k = 0; k < report.predicted_len; k++) {
                put(&out, " ");
                put_bits(&out, report.predicted[k]);
            }
            put(&out, " network");
            for (uint32_t k = 0; k < command_len; k++) {
                put(&out, " ");
                put_bits(&out, report.network[k]);
            }
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
    case REPLAY_BAD_AIDS:
        return "an aid's count in the header is not a whole number, or a call's aid is not 0, 1 or 2";
    default:
        return "unknown replay status";
    }
}
