/* The controller FMU's model: the paper's discrete PID (Eq. 24/25) against a step reference, as a model
 * of the FMI glue (maglev_fmi_common.h): build/maglev_pid.fmu (FMI 2.0, with maglev_fmu.c) and
 * build/maglev_pid3.fmu (FMI 3.0, with maglev_fmi3.c) link this file. The difference equation is
 * maglev_pid_step (maglev_replay.c), the one the closed-loop replay and the Python toolkit's fast path
 * run; the FMI rules (state machine, checks, FMU states with the experiment) are the glue's.
 *
 * Timing, as loop.simulate has it: the controller samples at t_k = t0 + k*ts. A step from t to t + h
 * takes every sample t_k in [t, t + h): it reads the inputs y and w_in as they are set, and from then
 * on the output u is u[k] = PID(w[k] - y[k]), held until the next sample. A master that steps this FMU
 * before the plant at each communication point (Gauss-Seidel, communication step = ts) so applies u[k]
 * to the plant over [t_k, t_k + ts], as loop.simulate does; a master that steps both on the old values
 * (Jacobi) adds one sample of delay. The reference is w[k] = (t_k >= t_step ? w1 : w0) + w_in. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "maglev_fmi_common.h"
#include "maglev_pid_fmu.h"
#include "maglev_replay.h"

/* Must equal the guid of modelDescription_pid.xml and the instantiationToken of modelDescription_pid3.xml
 * (tests/test_loopfmu.py). */
#define MAGLEV_PID_GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0101}"
/* Samples one step may take: bounds the work of a call (never a hang). */
#define MAX_SAMPLES_PER_STEP 10000000.0
#define LIM 1e3 /* [MU] range of readings, references and limits */
#define GAIN 1e6

const MaglevVariable maglev_pid_variables[MAGLEV_PID_NVARS] = {
    {"y", MAGLEV_INPUT, 0.0, -LIM, LIM, "MU", "Plant reading (A/D output), sampled at t0 + k*ts", ""},
    {"w_in", MAGLEV_INPUT, 0.0, -LIM, LIM, "MU", "Reference input, added to the step reference", ""},
    {"u", MAGLEV_OUTPUT, 0.0, -LIM, LIM, "MU", "Controller output u[k] (Eq. 24), held until the next sample", ""},
    {"w", MAGLEV_OUTPUT, 0.0, -2 * LIM, 2 * LIM, "MU", "Reference w[k] of the last sample", ""},
    {"ts", MAGLEV_PARAMETER, 1e-3, 1e-6, 10.0, "s", "Sample time", ""},
    {"kp", MAGLEV_PARAMETER, 2.0, -GAIN, GAIN, "1", "Proportional gain (Eq. 22)", ""},
    {"ki", MAGLEV_PARAMETER, 2.97, -GAIN, GAIN, "1/s", "Integral gain (Eq. 22)", ""},
    {"kd", MAGLEV_PARAMETER, 0.01, -GAIN, GAIN, "s", "Derivative gain (Eq. 22)", ""},
    {"tf", MAGLEV_PARAMETER, 0.0, 0.0, 100.0, "s", "Derivative filter time constant, 0 = off", ""},
    {"u_min", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Lower output limit", ""},
    {"u_max", MAGLEV_PARAMETER, 1.0, -LIM, LIM, "MU", "Upper output limit", ""},
    {"anti_windup", MAGLEV_PARAMETER, 0.0, 0.0, 3.0, "1",
     "Anti-windup: 0 none, 1 conditional integration, 2 clamping, 3 band", ""},
    {"i_lo", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Lower edge of the integrator band (anti_windup 3)", ""},
    {"i_hi", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Upper edge of the integrator band (anti_windup 3)", ""},
    {"backoff", MAGLEV_PARAMETER, 1.0, 0.0, 1.0, "1", "Where the band pulls the integrator back to (0, 1]", ""},
    {"u_hold", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Settled start: the integrator's initial value", ""},
    {"w0", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Step reference before t_step", ""},
    {"w1", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Step reference from t_step on", ""},
    {"t_step", MAGLEV_PARAMETER, 0.0, -MAGLEV_TIME_MAX, MAGLEV_TIME_MAX, "s", "Time of the reference step", ""},
};

/* The controller's state: everything an FMU state holds of it. */
typedef struct {
    double v[MAGLEV_PID_NVARS]; /* inputs, outputs and parameters by value reference */
    MaglevPidState s;
    double t0, time, k;         /* time of sample 0, the model's time, index of the next sample */
    int initialized;
} Pid;

static MaglevPid settings(const Pid *c) {
    const double *v = c->v;
    MaglevPid p = {v[PID_ts], v[PID_kp], v[PID_ki], v[PID_kd], v[PID_u_min], v[PID_u_max], v[PID_tf],
                   (int)v[PID_anti_windup], v[PID_i_lo], v[PID_i_hi], v[PID_backoff],
                   0 /* the derivative of the error: the paper's Eq. 24, which this FMU implements */};
    return p;
}

static double reference(const Pid *c, double t) {
    return (t >= c->v[PID_t_step] - 1e-12 ? c->v[PID_w1] : c->v[PID_w0]) + c->v[PID_w_in];
}

/* One variable's value: in its range, finite, and an integer where it must be. 0, or -1 with msg. */
static int check_value(unsigned int vr, double x, char *msg, size_t len) {
    const MaglevVariable *var = &maglev_pid_variables[vr];
    if (!isfinite(x) || x < var->min || x > var->max) {
        snprintf(msg, len, "variable %s = %g is outside [%g, %g] %s or not finite", var->name, x, var->min, var->max,
                 var->unit);
        return -1;
    }
    if (vr == PID_anti_windup && x != floor(x)) {
        snprintf(msg, len, "variable anti_windup = %g must be 0, 1, 2 or 3", x);
        return -1;
    }
    return 0;
}

/* The relations between the parameters, and the settled start (u_hold within the limits). */
static int check_relations(const Pid *c, char *msg, size_t len) {
    MaglevPid p = settings(c);
    if (maglev_pid_check(&p, msg, len)) return -1;
    if (c->v[PID_u_hold] < p.u_min || c->v[PID_u_hold] > p.u_max) {
        snprintf(msg, len, "variable u_hold = %g lies outside [u_min, u_max] = [%g, %g] MU", c->v[PID_u_hold], p.u_min,
                 p.u_max);
        return -1;
    }
    return 0;
}

static void defaults(void *m) {
    Pid *c = m;
    memset(c, 0, sizeof *c);
    for (int vr = 0; vr < MAGLEV_PID_NVARS; vr++) c->v[vr] = maglev_pid_variables[vr].start;
}

/* Inputs are read at the samples, so setting one needs nothing else, before initialisation or after. */
static int set(void *m, unsigned int vr, double value, const MaglevAllocator *a, char *msg, size_t len) {
    (void)a; (void)msg; (void)len;
    ((Pid *)m)->v[vr] = value;
    return 0;
}

static double get(const void *m, unsigned int vr) { return ((const Pid *)m)->v[vr]; }
static double time_of(const void *m) { return ((const Pid *)m)->time; }
static void set_time(void *m, double t) { ((Pid *)m)->time = t; }

/* Settled start at t0: integrator at u_hold, previous error and derivative 0 (maglev_replay.h). */
static void start(Pid *c, double t0) {
    c->s.integral = c->v[PID_u_hold];
    c->s.e_prev = c->s.d_prev = 0.0;
    c->t0 = c->time = t0;
    c->k = 0.0;
    c->v[PID_u] = c->v[PID_u_hold];
    c->v[PID_w] = reference(c, t0);
    c->initialized = 1;
}

/* before initialisation ends, the outputs are those of the settled start */
static int preview(const void *m, double t0, void *view, char *msg, size_t len) {
    (void)msg; (void)len;
    memcpy(view, m, sizeof(Pid));
    start(view, t0);
    return 0;
}

static int initialize(void *m, double t0, const MaglevAllocator *a, char *msg, size_t len) {
    (void)a;
    if (check_relations(m, msg, len)) return -1;
    start(m, t0);
    return 0;
}

static int initialized(const void *m) { return ((const Pid *)m)->initialized; }

static int step(void *m, double h, const MaglevAllocator *a, char *msg, size_t len) {
    (void)a;
    Pid *c = m;
    double end = c->time + h, ts = c->v[PID_ts];
    if (fabs(end) > MAGLEV_TIME_MAX) {
        snprintf(msg, len, "a step to %.17g s leaves the time range", end);
        return MAGLEV_REFUSED;
    }
    /* the samples t_k in [time, end): counted first, so one call's work is bounded */
    double last = ceil((end - c->t0) / ts - 1e-9) - 1.0; /* index of the last sample before end */
    if (last - c->k + 1.0 > MAX_SAMPLES_PER_STEP) {
        snprintf(msg, len, "communicationStepSize %g s holds more than %g samples of ts = %g s", h,
                 MAX_SAMPLES_PER_STEP, ts);
        return MAGLEV_REFUSED;
    }
    MaglevPid pid = settings(c);
    Pid next = *c;
    for (; next.k <= last; next.k += 1.0) {
        double tk = next.t0 + next.k * ts;
        next.v[PID_w] = reference(&next, tk);
        next.v[PID_u] = maglev_pid_step(&pid, &next.s, next.v[PID_w], next.v[PID_y]);
        if (!isfinite(next.v[PID_u]) || !isfinite(next.s.integral) || !isfinite(next.s.d_prev)) {
            snprintf(msg, len, "variable u is not finite at t = %.17g s (integrator %g)", tk, next.s.integral);
            return -1; /* the values are those before the step */
        }
    }
    next.time = end;
    *c = next;
    return 0;
}

/* Nothing is allocated: a state is its struct. */
static int copy(void *dst, const void *src, const MaglevAllocator *a) {
    (void)a;
    memcpy(dst, src, sizeof(Pid));
    return 0;
}

static void release(void *m, const MaglevAllocator *a) { (void)m; (void)a; }

/* Serialised form: "MGPID", the version byte, two zero bytes; u32 number of variables, the glue's tag code
 * and flags (the FMU state's code, the experiment's flags), i32 initialized; doubles: the variables by value
 * reference, integral, e_prev, d_prev, t0, time, k, the tag's values (the experiment); the plant's 64-bit
 * checksum of all before (maglev_checksum). Numbers as the machine has them: a state moves between instances
 * of one build. Version 2 added the tag (version 1 kept the stop time out of its FMU states): an image of
 * version 1 is refused by its version rather than misread. */
#define SER_MAGIC "MGPID"
#define SER_VERSION 2u
#define SER_HEADER 24
#define SER_NUMS (MAGLEV_PID_NVARS + 6 + MAGLEV_TAG_NVALUES)
#define SER_SIZE (SER_HEADER + SER_NUMS * 8 + 8)

static size_t serialized_size(const void *m) {
    (void)m;
    return SER_SIZE;
}

static void serialize(const void *m, const MaglevTag *tag, unsigned char *buf) {
    const Pid *c = m;
    unsigned int nvars = MAGLEV_PID_NVARS;
    int init = c->initialized;
    double nums[SER_NUMS];
    memcpy(nums, c->v, sizeof c->v);
    double *o = nums + MAGLEV_PID_NVARS;
    o[0] = c->s.integral; o[1] = c->s.e_prev; o[2] = c->s.d_prev;
    o[3] = c->t0; o[4] = c->time; o[5] = c->k;
    memcpy(o + 6, tag->value, sizeof tag->value);
    memset(buf, 0, SER_HEADER);
    memcpy(buf, SER_MAGIC, 5);
    buf[5] = (unsigned char)SER_VERSION;
    memcpy(buf + 8, &nvars, 4);
    memcpy(buf + 12, &tag->code, 4);
    memcpy(buf + 16, &tag->flags, 4);
    memcpy(buf + 20, &init, 4);
    memcpy(buf + SER_HEADER, nums, sizeof nums);
    unsigned long long sum = maglev_checksum(buf, SER_SIZE - 8);
    memcpy(buf + SER_SIZE - 8, &sum, 8);
}

/* A controller state as a restore meets it: every number finite, every input and parameter as
 * fmi2SetReal would take it, a sample index the steps can have reached, and once initialised the
 * relations initialize checks (before that the importer may still change the parameters). */
static int check_state(const Pid *c, const double *nums, char *msg, size_t len) {
    for (int k = 0; k < SER_NUMS - MAGLEV_TAG_NVALUES; k++)
        if (!isfinite(nums[k])) {
            snprintf(msg, len, "value %d is not finite", k);
            return -1;
        }
    for (unsigned int vr = 0; vr < MAGLEV_PID_NVARS; vr++)
        if (maglev_pid_variables[vr].causality != MAGLEV_OUTPUT && check_value(vr, c->v[vr], msg, len)) return -1;
    if (!(c->k >= 0) || c->k != floor(c->k) || fabs(c->time) > MAGLEV_TIME_MAX || fabs(c->t0) > MAGLEV_TIME_MAX) {
        snprintf(msg, len, "sample index %g, time %g s or sample 0 at %g s out of range", c->k, c->time, c->t0);
        return -1;
    }
    return c->initialized ? check_relations(c, msg, len) : 0;
}

static int deserialize(void *m, MaglevTag *tag, const unsigned char *buf, size_t size, const MaglevAllocator *a,
                       char *msg, size_t len) {
    (void)a;
    unsigned int nvars;
    int init;
    unsigned long long sum;
    /* magic and version first: an image of another kind or version is named as such, whatever its size */
    if (size < 8 || memcmp(buf, SER_MAGIC, 5) != 0) {
        snprintf(msg, len, "not a state of the controller FMU (too short, or a wrong magic number)");
        return -1;
    }
    if (buf[5] != SER_VERSION || buf[6] || buf[7]) {
        snprintf(msg, len, "serialized state has version %u, expected %u", (unsigned)buf[5], SER_VERSION);
        return -1;
    }
    if (size != SER_SIZE) {
        snprintf(msg, len, "serialized state has %zu bytes, expected %d (truncated or padded)", size, SER_SIZE);
        return -1;
    }
    memcpy(&sum, buf + SER_SIZE - 8, 8);
    if (sum != maglev_checksum(buf, SER_SIZE - 8)) {
        snprintf(msg, len, "serialized state is corrupted (checksum mismatch)");
        return -1;
    }
    memcpy(&nvars, buf + 8, 4);
    memcpy(&init, buf + 20, 4);
    if (nvars != MAGLEV_PID_NVARS || (init != 0 && init != 1)) {
        snprintf(msg, len, "serialized state has %u variables (expected %d) or an invalid initialized flag", nvars,
                 MAGLEV_PID_NVARS);
        return -1;
    }
    double nums[SER_NUMS];
    memcpy(nums, buf + SER_HEADER, sizeof nums);
    Pid c;
    memset(&c, 0, sizeof c);
    memcpy(c.v, nums, sizeof c.v);
    const double *o = nums + MAGLEV_PID_NVARS;
    c.s.integral = o[0]; c.s.e_prev = o[1]; c.s.d_prev = o[2];
    c.t0 = o[3]; c.time = o[4]; c.k = o[5];
    c.initialized = init;
    char why[MAGLEV_MSG_LEN - 64]; /* room for the sentence around it */
    if (check_state(&c, nums, why, sizeof why)) {
        snprintf(msg, len, "serialized state holds values the controller cannot have: %s", why);
        return -1;
    }
    memcpy(&tag->code, buf + 12, 4);
    memcpy(&tag->flags, buf + 16, 4);
    memcpy(tag->value, o + 6, sizeof tag->value);
    memcpy(m, &c, sizeof c);
    return 0;
}

const MfModel maglev_fmu_model = {
    .guid = MAGLEV_PID_GUID, .variables = maglev_pid_variables, .nvars = MAGLEV_PID_NVARS, .size = sizeof(Pid),
    .defaults = defaults, .check_value = check_value, .set = set, .get = get, .time = time_of,
    .set_time = set_time, .preview = preview, .initialize = initialize, .initialized = initialized, .step = step,
    .copy = copy, .release = release, .serialized_size = serialized_size, .serialize = serialize,
    .deserialize = deserialize,
};
