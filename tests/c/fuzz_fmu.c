/* Stateful fuzz test of the FMI 2.0 co-simulation API (docs/fuzz.md).
 *
 * Each seed drives one sequence of FMI calls on up to four interleaved instances, chosen by a
 * splitmix64 generator seeded with it, so a seed replays exactly (--seeds X:X+1). Every call goes
 * through one wrapper that times it and checks its status and the logger; the operations check what
 * the standard and the model's variable table promise; slot 0's operations are recorded and replayed
 * at the end of the sequence on a shadow instance that runs alone, which must give bit-identical
 * results; a counting allocator attributes every block to the instance whose call allocated it. Run
 * under ASan/UBSan in CI (ctest -L fuzz, MAGLEV_SANITIZE=ON).
 *
 * One harness for every model behind the FMI glue (c/maglev_fmi_common.h): built as fuzz_fmu it drives
 * the plant FMU (maglev_fmu.c, the glue, maglev_plant_fmu.c); built with -DFUZZ_PID as fuzz_fmu_pid, the
 * PID controller FMU (the same entry points and glue, maglev_pid_fmu.c). What differs is the model block
 * below: the variable table, the GUID, the serialized image's magic and header, and the scenario
 * generator. */
#define _POSIX_C_SOURCE 200809L
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"
#include "maglev_plant.h"

/* ---------------------------------------------------------------- the model under test */

#ifdef FUZZ_PID
#include "maglev_pid_fmu.h"
#define PROGRAM "fuzz_fmu_pid"
#define GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0101}"
#define VARS maglev_pid_variables
#define NV MAGLEV_PID_NVARS
#define FIRST_PARAM MAGLEV_PID_FIRST_PARAM
#define NPARAMS MAGLEV_PID_NPARAMS
#define SER_MAGIC "MGPID"      /* the serialized image (maglev_pid_fmu.c): its magic and header length */
#define SER_HEADER 24
static const fmi2ValueReference INPUTS[] = {PID_y, PID_w_in}, OUTPUTS[] = {PID_u, PID_w};
#else
#define PROGRAM "fuzz_fmu"
#define GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"
#define VARS maglev_variables
#define NV MAGLEV_NVARS
#define FIRST_PARAM MAGLEV_FIRST_PARAM
#define NPARAMS MAGLEV_NPARAMS
#define SER_MAGIC "MGLV"       /* the serialized image (maglev_plant.c) */
#define SER_HEADER 28
static const fmi2ValueReference INPUTS[] = {VR_u}, OUTPUTS[] = {VR_y, VR_x, VR_v, VR_i, VR_F};
#endif
#define N_INPUTS (sizeof INPUTS / sizeof INPUTS[0])
#define N_OUTPUTS (sizeof OUTPUTS / sizeof OUTPUTS[0])

#define NSLOT 4      /* fuzzed instances per sequence; slot 0 is replayed on the shadow */
#define SHADOW_ID NSLOT
#define MAXH 4       /* FMU states an instance holds at once */
#define MAXB 8       /* serialized buffers kept per sequence */
#define MAXV 64      /* value references per Get/SetReal call (more than the parameters) */
#define MAX_PRINTED 40

/* ---------------------------------------------------------------- random numbers (splitmix64) */

static uint64_t rng_state;
static uint64_t rnext(void) {
    uint64_t z = (rng_state += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}
static unsigned rbelow(unsigned n) { return (unsigned)(rnext() % n); }
static double runit(void) { return (double)(rnext() >> 11) * 0x1.0p-53; }
static int rchance(double p) { return runit() < p; }
static double rloguni(double lo, double hi) { return exp(log(lo) + runit() * (log(hi) - log(lo))); }
static double rsign(void) { return rchance(0.5) ? -1.0 : 1.0; }

/* ---------------------------------------------------------------- FMI functions and phases */

/* The states of the FMI 2.0 co-simulation state machine the fuzzer models (as a set: after an
 * fmi2Error the standard puts the slave into "error", while an FMU may stay where it was). */
#define P_INST 1u
#define P_INIT 2u
#define P_STEP 4u
#define P_FAILED 8u
#define P_TERM 16u
#define P_ERROR 32u
#define P_LIVE 63u
#define P_GETS (P_INIT | P_STEP | P_FAILED | P_TERM | P_ERROR)
#define P_SETS (P_INST | P_INIT | P_STEP)
#define P_STATUS (P_STEP | P_FAILED | P_TERM)

/* name, states in which the standard allows the call (FMI 2.0, section 4.2.4) */
#define FUNCS(X)                                                                                         \
    X(Instantiate, 0) X(FreeInstance, P_LIVE) X(SetupExperiment, P_INST) X(EnterInitializationMode, P_INST) \
    X(ExitInitializationMode, P_INIT) X(Terminate, P_STEP | P_FAILED) X(Reset, P_LIVE)                    \
    X(SetDebugLogging, P_LIVE) X(SetReal, P_SETS) X(GetReal, P_GETS) X(GetInteger, P_GETS)                \
    X(GetBoolean, P_GETS) X(GetString, P_GETS) X(SetInteger, P_SETS) X(SetBoolean, P_SETS)                \
    X(SetString, P_SETS) X(DoStep, P_STEP) X(CancelStep, 0) X(GetStatus, P_STATUS)                        \
    X(GetRealStatus, P_STATUS) X(GetIntegerStatus, P_STATUS) X(GetBooleanStatus, P_STATUS)                \
    X(GetStringStatus, P_STATUS) X(GetFMUstate, P_LIVE) X(SetFMUstate, P_LIVE) X(FreeFMUstate, P_LIVE)   \
    X(SerializedFMUstateSize, P_LIVE) X(SerializeFMUstate, P_LIVE) X(DeSerializeFMUstate, P_LIVE)        \
    X(GetDirectionalDerivative, P_GETS) X(SetRealInputDerivatives, P_SETS)                                \
    X(GetRealOutputDerivatives, P_STEP | P_FAILED | P_TERM | P_ERROR) X(ModelExchange, 0)                 \
    X(GetTypesPlatform, P_LIVE) X(GetVersion, P_LIVE)

#define AS_ENUM(name, allowed) FN_##name,
#define AS_NAME(name, allowed) "fmi2" #name,
#define AS_MASK(name, allowed) (allowed),
enum { FUNCS(AS_ENUM) FN_COUNT };
static const char *const fn_name[FN_COUNT] = {FUNCS(AS_NAME)};
static const unsigned fn_allowed[FN_COUNT] = {FUNCS(AS_MASK)};

#define NST 7 /* fmi2OK..fmi2Pending, then "not a fmi2Status" */
static const char *const st_name[NST] = {"ok", "warning", "discard", "error", "fatal", "pending", "illegal"};
static int st_index(fmi2Status st) { return (int)st >= 0 && (int)st <= 5 ? (int)st : 6; }
#define OKISH(st) ((st) == fmi2OK || (st) == fmi2Warning)

/* ---------------------------------------------------------------- instances and the model */

typedef struct {
    unsigned phases;           /* possible states; 0: no instance */
    double start;              /* startTime the instance holds (fmi2SetupExperiment, or an FMU state set) */
    int start_known;           /* 0 after setting a state deserialized from a corrupted buffer */
    int t_known;
    double t;                  /* the FMU's time, as the calls so far determine it */
    int hvalid[MAXH];          /* FMU states held, their states and times */
    unsigned hph[MAXH];
    int ht_known[MAXH];
    double ht[MAXH];
    int hstart_known[MAXH];    /* an FMU state holds the experiment too: its startTime */
    double hstart[MAXH];
} Model;

typedef struct {
    int id;                    /* owner of the blocks allocated during its calls */
    char name[32];
    fmi2CallbackFunctions cb;  /* componentEnvironment points back here */
    fmi2Component c;
    int logging;
    fmi2FMUstate h[MAXH];
    Model *model;              /* NULL for the shadow: its results are compared, not modelled */
} Inst;

static Model models[NSLOT];
static Inst insts[NSLOT + 1]; /* the slots, then the shadow */

/* ---------------------------------------------------------------- statistics and failures */

static struct {
    unsigned long long seed;
    long call;                 /* FMI calls in this sequence so far */
    long failures, sequences, calls;
    long per[FN_COUNT][NST];
    double tmax[FN_COUNT];
    double slowest;
    int slowest_fn;
    unsigned long long slowest_seed;
    long slowest_call;
    long vclass[16], corrupt[16], corrupt_accepted, foreign_buffers, oom_injected, roundtrips, replayed_ops;
    double max_call;           /* the bound on one call's wall time [s] */
    int trace;
} g;

static void failf(const char *fmt, ...) {
    g.failures++;
    if (g.failures > MAX_PRINTED) {
        if (g.failures == MAX_PRINTED + 1) fprintf(stderr, "FAIL ... (further failures counted, not printed)\n");
        return;
    }
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "FAIL seed %llu call %ld: ", g.seed, g.call);
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "   [replay: " PROGRAM " --seeds %llu:%llu --trace]\n", g.seed, g.seed + 1);
    va_end(ap);
}

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---------------------------------------------------------------- the call in progress */

static struct {
    int fn;                    /* -1 between calls */
    Inst *target;              /* NULL for a call on no instance (NULL component, fmi2GetVersion) */
    unsigned phases;           /* the model's states at the call (0: not checked) */
    long logs_at_start;
    double t0;
} cur = {-1, NULL, 0, 0, 0};
static long n_logs;
static char last_msg[600];

/* ---------------------------------------------------------------- counting allocator */

typedef struct { uint64_t magic; int owner; int pad; } Block; /* 16 bytes before each block */
#define BLOCK_MAGIC 0x6d61676c65764d4dULL
static long live_by_owner[NSLOT + 2];
static int oom_countdown = -1; /* the allocation that fails: 0 = the next; -1 = none */
static int oom_fired;

static void *fz_alloc(size_t n, size_t size) {
    if (size && n > (SIZE_MAX - sizeof(Block)) / size) return NULL;
    if (oom_countdown == 0) {
        oom_countdown = -1;
        oom_fired = 1;
        g.oom_injected++;
        return NULL;
    }
    if (oom_countdown > 0) oom_countdown--;
    int owner = cur.target ? cur.target->id : NSLOT + 1;
    if (!cur.target) failf("allocateMemory called outside a call on an instance (%s)", cur.fn >= 0 ? fn_name[cur.fn] : "no call");
    Block *b = calloc(1, sizeof(Block) + n * size);
    if (!b) return NULL;
    b->magic = BLOCK_MAGIC;
    b->owner = owner;
    live_by_owner[owner]++;
    return b + 1;
}

static void fz_free(void *p) {
    if (!p) return;
    Block *b = (Block *)p - 1;
    if (b->magic != BLOCK_MAGIC) {
        failf("freeMemory of a block allocateMemory did not hand out");
        return;
    }
    int owner = cur.target ? cur.target->id : NSLOT + 1;
    if (b->owner != owner)
        failf("freeMemory during a call on instance %d of a block allocated during a call on instance %d", owner,
              b->owner);
    live_by_owner[b->owner]--;
    b->magic = 0;
    free(b);
}

static long live_total(void) {
    long n = 0;
    for (int k = 0; k < NSLOT + 2; k++) n += live_by_owner[k];
    return n;
}

/* ---------------------------------------------------------------- logger */

static void logger(fmi2ComponentEnvironment env, fmi2String instanceName, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    n_logs++;
    if (cur.fn < 0) failf("logger called between FMI calls");
    else if (!cur.target) failf("logger called during %s on no instance", fn_name[cur.fn]);
    else if (env != (void *)cur.target)
        failf("%s on instance %d logged through the callbacks of another instance", fn_name[cur.fn], cur.target->id);
    if ((int)status < 0 || (int)status > 4) failf("logger called with status %d", (int)status);
    if (!instanceName || !category || !message) {
        failf("logger called with a NULL instanceName, category or message");
        return;
    }
    /* the FMU passes no variadic arguments: the message must hold no conversion but %% */
    for (const char *p = message; *p; p++)
        if (*p == '%') {
            if (p[1] != '%') {
                failf("logger message has a conversion specification but no argument: %.200s", message);
                break;
            }
            p++;
        }
    snprintf(last_msg, sizeof last_msg, "[%s] %s", category, message);
}

/* ---------------------------------------------------------------- the call wrapper */

static void pre(int fn, Inst *target) {
    g.call++;
    g.calls++;
    cur.fn = fn;
    cur.target = target;
    cur.phases = target && target->model ? target->model->phases : 0;
    cur.logs_at_start = n_logs;
    last_msg[0] = 0;
    cur.t0 = now();
}

static void post_common(fmi2Status st, int checked) {
    double dt = now() - cur.t0;
    int fn = cur.fn, si = st_index(st);
    g.per[fn][si]++;
    if (dt > g.tmax[fn]) g.tmax[fn] = dt;
    if (dt > g.slowest) {
        g.slowest = dt;
        g.slowest_fn = fn;
        g.slowest_seed = g.seed;
        g.slowest_call = g.call;
    }
    if (g.trace)
        fprintf(stderr, "  call %ld %s inst %d -> %s (%.3f ms)%s%s\n", g.call, fn_name[fn],
                cur.target ? cur.target->id : -1, st_name[si], 1e3 * dt, last_msg[0] ? "  " : "", last_msg);
    if (dt > g.max_call) failf("%s took %.3f s, more than the bound %.3f s", fn_name[fn], dt, g.max_call);
    if (checked) {
        if (si == 6 || (st == fmi2Pending && fn != FN_DoStep))
            failf("%s returned %d, not a legal fmi2Status for it", fn_name[fn], (int)st);
        if ((st == fmi2Error || st == fmi2Fatal) && cur.target && cur.target->logging && n_logs == cur.logs_at_start)
            failf("%s returned %s without a logger call", fn_name[fn], st_name[si]);
        if (OKISH(st) && cur.phases && !(cur.phases & fn_allowed[fn]))
            failf("%s returned %s in a state where FMI 2.0 does not allow the call (possible states 0x%x)",
                  fn_name[fn], st_name[si], cur.phases);
    }
    cur.fn = -1;
    cur.target = NULL;
}

static fmi2Status post(fmi2Status st) {
    post_common(st, 1);
    return st;
}

#define CALL(fn, inst, expr) (pre((fn), (inst)), post(expr))

/* ---------------------------------------------------------------- operations */

enum {
    OP_INSTANTIATE, OP_INSTANTIATE_BAD, OP_FREE, OP_SETUP, OP_ENTER, OP_EXIT, OP_TERMINATE, OP_RESET, OP_DEBUGLOG,
    OP_SETREAL, OP_GETREAL, OP_OTHERTYPE, OP_DOSTEP, OP_CANCEL, OP_STATUS, OP_GETSTATE, OP_SETSTATE, OP_FREESTATE,
    OP_SERSIZE, OP_SERIALIZE, OP_DESERIALIZE, OP_DIRDER, OP_DERIVS, OP_ME, OP_ROUNDTRIP, OP_NULLINST, OP_VERSION,
    OP_COUNT
};
static const char *const op_name[OP_COUNT] = {
    "instantiate", "instantiate (bad arguments)", "free instance", "setup experiment", "enter initialization",
    "exit initialization", "terminate", "reset", "set debug logging", "set real", "get real",
    "get/set integer, boolean, string", "do step", "cancel step", "get status", "get FMU state", "set FMU state",
    "free FMU state", "serialized size", "serialize", "deserialize", "directional derivative",
    "input/output derivatives", "model-exchange function", "round trip", "NULL instance", "types platform, version"};

/* handle selectors besides an index 0..MAXH-1 */
#define HS_NULL (-1)    /* a NULL fmi2FMUstate */
#define HS_OTHER (-2)   /* op.other: a forged pointer or another instance's state */
#define HS_NULLPTR (-3) /* a NULL fmi2FMUstate* argument */

enum { VC_DEFAULT, VC_RANDOM, VC_MIN, VC_MAX, VC_BELOW, VC_ABOVE, VC_ZERO, VC_NEG, VC_HUGE, VC_INF, VC_NAN,
       VC_DENORMAL, VC_X1000, VC_X0001, VC_COUNT };
static const char *const vc_name[VC_COUNT] = {"default", "in-range random", "min", "max", "just below min",
                                              "just above max", "zero", "negative", "+-1e308", "+-Inf", "NaN",
                                              "denormal", "unit slip x1000", "unit slip x0.001"};

enum { CR_NONE, CR_BITFLIP, CR_BYTE, CR_TRUNC, CR_EXTEND, CR_RANDOM, CR_EMPTY, CR_VALUE_RESUM, CR_HEADER_RESUM,
       CR_COUNT };
static const char *const cr_name[CR_COUNT] = {"none", "bit flips", "random byte", "truncated", "extended",
                                              "random bytes", "empty", "value edit, checksum recomputed",
                                              "header edit, checksum recomputed"};

typedef struct {
    int op, var;               /* operation and its variant */
    int slot;
    size_t n;                  /* value references */
    fmi2ValueReference vr[MAXV];
    double val[MAXV];
    unsigned char vc[MAXV];
    int null_vr, null_val;     /* pass NULL arrays */
    double x1, x2, x3;         /* numbers: step size, times, tolerance */
    int i1, i2;
    int hsel, hdst;            /* FMU state to use, and where a new one goes */
    fmi2FMUstate other;        /* for HS_OTHER */
    unsigned char *bytes;      /* a buffer to deserialize (owned by the op) */
    size_t nbytes;
    int corrupt, buf_tknown, buf_start_known;
    unsigned buf_phases;
    double buf_t, buf_start;
    int oom;                   /* -1, or the allocation in this operation that fails */
} Op;

typedef struct {
    uint64_t digest;           /* statuses and outputs, for the shadow comparison */
    int nst;
    fmi2Status st[8];
    fmi2Status main;           /* the operation's own call */
    int any_error;
    unsigned char *bytes;      /* a serialized state produced */
    size_t nbytes;
    int complete;              /* a composite operation ran to its end with every call OK */
} Res;

static void res_mix(Res *r, const void *p, size_t n) {
    const unsigned char *b = p;
    for (size_t k = 0; k < n; k++) {
        r->digest ^= b[k];
        r->digest *= 1099511628211ULL;
    }
}
static fmi2Status res_st(Res *r, fmi2Status st) {
    if (r->nst < 8) r->st[r->nst] = st;
    r->nst++;
    if (st == fmi2Error || st == fmi2Fatal) r->any_error = 1;
    int v = (int)st;
    res_mix(r, &v, sizeof v);
    return st;
}
static void res_init(Res *r) {
    memset(r, 0, sizeof *r);
    r->digest = 1469598103934665603ULL;
    r->main = fmi2OK;
}

static unsigned char forged[64]; /* forged FMU state pointers point in here */

/* ---------------------------------------------------------------- checked wrappers used in several places */

static fmi2Status get_real(Inst *in, const fmi2ValueReference *vr, size_t n, double *v, Res *r) {
    if (v)
        for (size_t k = 0; k < n; k++) v[k] = NAN;
    fmi2Status st = res_st(r, CALL(FN_GetReal, in, fmi2GetReal(in->c, vr, n, v)));
    if (OKISH(st)) {
        if (n && (!vr || !v)) failf("fmi2GetReal with a NULL array returned %s", st_name[st_index(st)]);
        else
            for (size_t k = 0; k < n; k++) {
                if (vr[k] >= NV) failf("fmi2GetReal of unknown value reference %u returned OK", (unsigned)vr[k]);
                else if (!isfinite(v[k]))
                    failf("fmi2GetReal returned %g for %s with status %s", v[k], VARS[vr[k]].name,
                          st_name[st_index(st)]);
            }
    }
    if (v) res_mix(r, v, n * sizeof *v);
    return st;
}

static const fmi2ValueReference *all_vrs(void) {
    static fmi2ValueReference vr[NV];
    for (int k = 0; k < NV; k++) vr[k] = (fmi2ValueReference)k;
    return vr;
}

static fmi2FMUstate resolve(const Inst *in, const Op *op, int sel) {
    if (sel >= 0) return in->h[sel];
    if (sel == HS_OTHER) return op->other;
    return NULL;
}

/* A snapshot of the whole instance as bytes: fmi2GetFMUstate, serialize, free. 0 if refused. */
static size_t state_bytes(Inst *in, unsigned char **out, Res *r) {
    fmi2FMUstate s = NULL;
    *out = NULL;
    if (res_st(r, CALL(FN_GetFMUstate, in, fmi2GetFMUstate(in->c, &s))) != fmi2OK) return 0;
    size_t n = 0;
    if (res_st(r, CALL(FN_SerializedFMUstateSize, in, fmi2SerializedFMUstateSize(in->c, s, &n))) == fmi2OK && n > 0) {
        *out = malloc(n);
        if (res_st(r, CALL(FN_SerializeFMUstate, in, fmi2SerializeFMUstate(in->c, s, (fmi2Byte *)*out, n))) != fmi2OK) {
            free(*out);
            *out = NULL;
            n = 0;
        }
    } else {
        n = 0;
    }
    res_st(r, CALL(FN_FreeFMUstate, in, fmi2FreeFMUstate(in->c, &s)));
    if (*out) res_mix(r, *out, n);
    return n;
}

static int strict_set(const Op *op, int allow_params) {
    for (size_t k = 0; k < op->n; k++) {
        fmi2ValueReference v = op->vr[k];
        if (v >= NV || VARS[v].causality == MAGLEV_OUTPUT) return 0;
        if (!allow_params && VARS[v].causality == MAGLEV_PARAMETER) return 0;
    }
    return 1;
}

/* The round trip's continuation: a new input, one step from where the FMU says it is, all variables. */
static void continue_step(Inst *in, const Op *op, Res *r, fmi2Status st[4], double v[NV]) {
    fmi2ValueReference u = INPUTS[0];
    double t = 0;
    st[0] = res_st(r, CALL(FN_SetReal, in, fmi2SetReal(in->c, &u, 1, &op->x1)));
    st[1] = res_st(r, CALL(FN_GetRealStatus, in, fmi2GetRealStatus(in->c, fmi2LastSuccessfulTime, &t)));
    st[2] = OKISH(st[1]) ? res_st(r, CALL(FN_DoStep, in, fmi2DoStep(in->c, t, op->x2, fmi2False))) : fmi2Error;
    st[3] = get_real(in, all_vrs(), NV, v, r);
}

static int same_values(const double *a, const double *b, const char *what) {
    for (int k = 0; k < NV; k++)
        if (memcmp(&a[k], &b[k], sizeof a[k]) != 0) {
            failf("%s: %s = %.17g, expected %.17g", what, VARS[k].name, b[k], a[k]);
            return 0;
        }
    return 1;
}

/* ---------------------------------------------------------------- executing an operation */

static void check_leak_after_free(Inst *in) {
    if (live_by_owner[in->id])
        failf("%ld blocks allocated during calls on instance %d are still live after fmi2FreeInstance",
              live_by_owner[in->id], in->id);
}

static void exec_op(Inst *in, const Op *op, Res *r) {
    fmi2Status st = fmi2OK;
    oom_fired = 0;
    oom_countdown = op->oom;
    switch (op->op) {
    case OP_INSTANTIATE:
    case OP_INSTANTIATE_BAD: {
        fmi2CallbackFunctions cbs = in->cb;
        const fmi2CallbackFunctions *cbp = &in->cb;
        const char *name = in->name, *guid = GUID;
        fmi2Type type = fmi2CoSimulation;
        int bad = op->op == OP_INSTANTIATE_BAD, log_expected = 1;
        if (bad) {
            switch (op->var) {
            case 0: guid = "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0002}"; break;
            case 1: guid = NULL; break;
            case 2: type = fmi2ModelExchange; break;
            case 3: type = (fmi2Type)7; break;
            case 4: name = NULL; break;
            case 5: name = ""; break;
            case 6: cbs.allocateMemory = NULL; cbp = &cbs; break;
            default: cbp = NULL; log_expected = 0; break; /* no callbacks: no logger to call */
            }
        }
        const char *res_loc = op->i1 == 0 ? NULL : op->i1 == 1 ? "file:///nonexistent/resources" : "\x01garbage";
        pre(FN_Instantiate, in);
        fmi2Component c = fmi2Instantiate(name, type, guid, res_loc, cbp, op->i2 & 1, fmi2True);
        if (!c && log_expected && n_logs == cur.logs_at_start)
            failf("fmi2Instantiate returned NULL without a logger call%s", oom_fired ? " (allocation failed)" : "");
        post_common(c ? fmi2OK : fmi2Error, 0);
        res_st(r, c ? fmi2OK : fmi2Error);
        r->main = c ? fmi2OK : fmi2Error;
        if (c && bad) {
            failf("fmi2Instantiate accepted bad arguments (variant %d)", op->var);
            pre(FN_FreeInstance, in);
            fmi2FreeInstance(c);
            post_common(fmi2OK, 0);
            c = NULL;
        }
        in->c = c;
        in->logging = 1;
        memset(in->h, 0, sizeof in->h);
        break;
    }
    case OP_FREE:
        pre(FN_FreeInstance, in);
        fmi2FreeInstance(in->c);
        post_common(fmi2OK, 0);
        res_st(r, fmi2OK);
        in->c = NULL;
        memset(in->h, 0, sizeof in->h);
        check_leak_after_free(in);
        break;
    case OP_SETUP:
        st = CALL(FN_SetupExperiment, in, fmi2SetupExperiment(in->c, op->i1, op->x3, op->x1, op->i2, op->x2));
        if (OKISH(st) && (!isfinite(op->x1) || (op->i1 && !(op->x3 > 0 && isfinite(op->x3))) ||
                          (op->i2 && !(op->x2 >= op->x1))))
            failf("fmi2SetupExperiment(tol %d %g, start %g, stop %d %g) accepted", op->i1, op->x3, op->x1, op->i2, op->x2);
        r->main = res_st(r, st);
        break;
    case OP_ENTER: r->main = res_st(r, CALL(FN_EnterInitializationMode, in, fmi2EnterInitializationMode(in->c))); break;
    case OP_EXIT: r->main = res_st(r, CALL(FN_ExitInitializationMode, in, fmi2ExitInitializationMode(in->c))); break;
    case OP_TERMINATE: r->main = res_st(r, CALL(FN_Terminate, in, fmi2Terminate(in->c))); break;
    case OP_RESET: r->main = res_st(r, CALL(FN_Reset, in, fmi2Reset(in->c))); break;
    case OP_DEBUGLOG: {
        const char *cats[3] = {"logAll", "logStatusError", "logCalls"};
        if (op->var == 1) cats[1] = "noSuchCategory";
        if (op->var == 2) cats[2] = NULL;
        st = CALL(FN_SetDebugLogging, in,
                  fmi2SetDebugLogging(in->c, op->i1, (size_t)op->i2, op->var == 3 ? NULL : cats));
        if (OKISH(st) && op->var == 3 && op->i2 > 0) failf("fmi2SetDebugLogging with NULL categories returned OK");
        if (OKISH(st)) in->logging = op->i1;
        r->main = res_st(r, st);
        break;
    }
    case OP_SETREAL: {
        st = CALL(FN_SetReal, in,
                  fmi2SetReal(in->c, op->null_vr ? NULL : op->vr, op->n, op->null_val ? NULL : op->val));
        r->main = res_st(r, st);
        unsigned ph = in->model ? in->model->phases : 0;
        if (OKISH(st)) {
            if (op->n && (op->null_vr || op->null_val)) failf("fmi2SetReal with a NULL array returned OK");
            for (size_t k = 0; k < op->n && !op->null_vr && !op->null_val; k++) {
                fmi2ValueReference v = op->vr[k];
                if (v >= NV) { failf("fmi2SetReal of unknown value reference %u returned OK", (unsigned)v); break; }
                const MaglevVariable *var = &VARS[v];
                if (var->causality == MAGLEV_OUTPUT) failf("fmi2SetReal of output %s returned OK", var->name);
                else if (!isfinite(op->val[k])) failf("fmi2SetReal of %s = %g returned OK", var->name, op->val[k]);
                else if (var->causality == MAGLEV_PARAMETER && (op->val[k] < var->min || op->val[k] > var->max))
                    failf("fmi2SetReal of %s = %.17g outside [%g, %g] returned OK", var->name, op->val[k], var->min, var->max);
                else if (var->causality == MAGLEV_PARAMETER && ph && !(ph & (P_INST | P_INIT)))
                    failf("fmi2SetReal of fixed parameter %s after initialization returned OK", var->name);
            }
        } else if (ph && !(ph & ~(P_INST | P_INIT)) && !oom_fired && op->n && !op->null_vr && !op->null_val &&
                   strict_set(op, 1)) {
            int all_default = 1;
            for (size_t k = 0; k < op->n; k++) all_default &= op->vc[k] == VC_DEFAULT;
            if (all_default) failf("fmi2SetReal of start values before initialization refused: %s", last_msg);
        }
        break;
    }
    case OP_GETREAL: {
        double v[MAXV];
        r->main = get_real(in, op->null_vr ? NULL : op->vr, op->n, op->null_val ? NULL : v, r);
        break;
    }
    case OP_OTHERTYPE: {
        fmi2Integer iv[MAXV] = {0};
        fmi2Boolean bv[MAXV] = {0};
        fmi2String sv[MAXV] = {0};
        const fmi2ValueReference *vr = op->null_vr ? NULL : op->vr;
        int fn;
        switch (op->var) {
        case 0: fn = FN_GetInteger; st = CALL(fn, in, fmi2GetInteger(in->c, vr, op->n, iv)); break;
        case 1: fn = FN_GetBoolean; st = CALL(fn, in, fmi2GetBoolean(in->c, vr, op->n, bv)); break;
        case 2: fn = FN_GetString; st = CALL(fn, in, fmi2GetString(in->c, vr, op->n, sv)); break;
        case 3: fn = FN_SetInteger; st = CALL(fn, in, fmi2SetInteger(in->c, vr, op->n, iv)); break;
        case 4: fn = FN_SetBoolean; st = CALL(fn, in, fmi2SetBoolean(in->c, vr, op->n, bv)); break;
        default:
            for (size_t k = 0; k < op->n; k++) sv[k] = "x";
            fn = FN_SetString;
            st = CALL(fn, in, fmi2SetString(in->c, vr, op->n, sv));
            break;
        }
        if (OKISH(st) && op->n > 0) failf("%s of %zu values returned OK, but the FMU has no such variable", fn_name[fn], op->n);
        r->main = res_st(r, st);
        break;
    }
    case OP_DOSTEP:
        st = CALL(FN_DoStep, in, fmi2DoStep(in->c, op->x1, op->x2, op->i1));
        if (OKISH(st) && !(isfinite(op->x1) && isfinite(op->x2) && op->x2 > 0))
            failf("fmi2DoStep(%g, %g) returned OK", op->x1, op->x2);
        r->main = res_st(r, st);
        break;
    case OP_CANCEL: r->main = res_st(r, CALL(FN_CancelStep, in, fmi2CancelStep(in->c))); break;
    case OP_STATUS: {
        fmi2StatusKind kind = (fmi2StatusKind)op->i1;
        int nul = op->i2;
        switch (op->var) {
        case 0: {
            fmi2Status v = (fmi2Status)99;
            st = CALL(FN_GetStatus, in, fmi2GetStatus(in->c, kind, nul ? NULL : &v));
            if (OKISH(st) && !nul && st_index(v) == 6) failf("fmi2GetStatus gave value %d", (int)v);
            if (OKISH(st)) res_mix(r, &v, sizeof v);
            break;
        }
        case 1: {
            double v = NAN;
            st = CALL(FN_GetRealStatus, in, fmi2GetRealStatus(in->c, kind, nul ? NULL : &v));
            if (OKISH(st) && !nul) {
                if (!isfinite(v)) failf("fmi2GetRealStatus gave %g with status OK", v);
                else if (kind == fmi2LastSuccessfulTime && in->model && in->model->t_known && v != in->model->t)
                    failf("fmi2GetRealStatus(LastSuccessfulTime) = %.17g, but the steps so far reached %.17g", v,
                          in->model->t);
                res_mix(r, &v, sizeof v);
            }
            break;
        }
        case 2: {
            fmi2Integer v = 0;
            st = CALL(FN_GetIntegerStatus, in, fmi2GetIntegerStatus(in->c, kind, nul ? NULL : &v));
            break;
        }
        case 3: {
            fmi2Boolean v = 0;
            st = CALL(FN_GetBooleanStatus, in, fmi2GetBooleanStatus(in->c, kind, nul ? NULL : &v));
            if (OKISH(st)) res_mix(r, &v, sizeof v);
            break;
        }
        default: {
            fmi2String v = NULL;
            st = CALL(FN_GetStringStatus, in, fmi2GetStringStatus(in->c, kind, nul ? NULL : &v));
            if (OKISH(st) && !nul && !v) failf("fmi2GetStringStatus gave NULL with status OK");
            break;
        }
        }
        if (OKISH(st) && nul) failf("a fmi2Get*Status with a NULL value pointer returned OK");
        r->main = res_st(r, st);
        break;
    }
    case OP_GETSTATE: {
        fmi2FMUstate s = resolve(in, op, op->hsel);
        st = CALL(FN_GetFMUstate, in, fmi2GetFMUstate(in->c, op->hsel == HS_NULLPTR ? NULL : &s));
        if (OKISH(st)) {
            if (op->hsel == HS_NULLPTR || op->hsel == HS_OTHER)
                failf("fmi2GetFMUstate with a %s returned OK", op->hsel == HS_OTHER ? "foreign FMU state" : "NULL pointer");
            else if (!s) failf("fmi2GetFMUstate returned OK and a NULL state");
            else in->h[op->hdst] = s;
        }
        r->main = res_st(r, st);
        break;
    }
    case OP_SETSTATE:
        st = CALL(FN_SetFMUstate, in, fmi2SetFMUstate(in->c, resolve(in, op, op->hsel)));
        if (OKISH(st) && op->hsel < 0) failf("fmi2SetFMUstate with a %s state returned OK", op->hsel == HS_OTHER ? "foreign" : "NULL");
        r->main = res_st(r, st);
        break;
    case OP_FREESTATE: {
        fmi2FMUstate s = resolve(in, op, op->hsel);
        st = CALL(FN_FreeFMUstate, in, fmi2FreeFMUstate(in->c, op->hsel == HS_NULLPTR ? NULL : &s));
        if (OKISH(st) && op->hsel == HS_OTHER) failf("fmi2FreeFMUstate of a foreign FMU state returned OK");
        if (OKISH(st) && op->hsel >= 0) {
            if (s) failf("fmi2FreeFMUstate returned OK but left the pointer set");
            in->h[op->hsel] = NULL;
        }
        r->main = res_st(r, st);
        break;
    }
    case OP_SERSIZE: {
        size_t n = 12345;
        st = CALL(FN_SerializedFMUstateSize, in,
                  fmi2SerializedFMUstateSize(in->c, resolve(in, op, op->hsel), op->i1 ? NULL : &n));
        if (OKISH(st) && (op->hsel < 0 || op->i1)) failf("fmi2SerializedFMUstateSize with a bad argument returned OK");
        if (OKISH(st)) res_mix(r, &n, sizeof n);
        r->main = res_st(r, st);
        break;
    }
    case OP_SERIALIZE: {
        fmi2FMUstate s = resolve(in, op, op->hsel);
        size_t need = 0;
        fmi2Status sz = res_st(r, CALL(FN_SerializedFMUstateSize, in, fmi2SerializedFMUstateSize(in->c, s, &need)));
        if (!OKISH(sz)) need = 64;
        /* variants: exact size, one byte short, larger, NULL buffer */
        size_t n = op->var == 1 ? (need ? need - 1 : 0) : op->var == 2 ? need + 1 + (size_t)op->i1 : need;
        unsigned char *buf = malloc(n ? n : 1);
        memset(buf, 0xA5, n ? n : 1);
        st = CALL(FN_SerializeFMUstate, in, fmi2SerializeFMUstate(in->c, s, op->var == 3 ? NULL : (fmi2Byte *)buf, n));
        r->main = res_st(r, st);
        if (OKISH(st)) {
            if (op->var == 1 || op->var == 3) failf("fmi2SerializeFMUstate into a %s buffer returned OK", op->var == 1 ? "too small" : "NULL");
            else if (op->hsel < 0) failf("fmi2SerializeFMUstate of a foreign/NULL state returned OK");
            else if (OKISH(sz)) {
                res_mix(r, buf, need);
                r->bytes = buf;
                r->nbytes = need;
                buf = NULL;
            }
        }
        free(buf);
        break;
    }
    case OP_DESERIALIZE: {
        fmi2FMUstate s = resolve(in, op, op->hsel);
        st = CALL(FN_DeSerializeFMUstate, in,
                  fmi2DeSerializeFMUstate(in->c, op->i1 ? NULL : (const fmi2Byte *)op->bytes, op->nbytes,
                                          op->hsel == HS_NULLPTR ? NULL : &s));
        r->main = res_st(r, st);
        int clean = op->corrupt == CR_NONE && !op->i1 && (op->hsel == HS_NULL || op->hsel >= 0);
        if (OKISH(st)) {
            if (op->i1 || op->hsel == HS_NULLPTR || op->hsel == HS_OTHER)
                failf("fmi2DeSerializeFMUstate with a NULL buffer, NULL pointer or foreign state returned OK");
            else {
                int k = op->hsel >= 0 ? op->hsel : op->hdst;
                in->h[k] = s;
                if (op->corrupt != CR_NONE && in->model) g.corrupt_accepted++;
                if (clean) { /* serialized again, the state must give the same bytes */
                    size_t n = 0;
                    if (res_st(r, CALL(FN_SerializedFMUstateSize, in, fmi2SerializedFMUstateSize(in->c, s, &n))) != fmi2OK ||
                        n != op->nbytes)
                        failf("deserialized state has serialized size %zu, the buffer %zu", n, op->nbytes);
                    else {
                        unsigned char *b2 = malloc(n);
                        if (res_st(r, CALL(FN_SerializeFMUstate, in, fmi2SerializeFMUstate(in->c, s, (fmi2Byte *)b2, n))) != fmi2OK ||
                            memcmp(b2, op->bytes, n) != 0)
                            failf("deserialized state serializes to different bytes");
                        free(b2);
                    }
                }
            }
        } else if (clean && !oom_fired) {
            failf("a buffer the FMU serialized (%zu bytes) was refused by fmi2DeSerializeFMUstate: %s", op->nbytes, last_msg);
        }
        break;
    }
    case OP_DIRDER: {
        double dk[MAXV], du[MAXV] = {0};
        for (size_t k = 0; k < op->n; k++) dk[k] = op->val[k];
        size_t nu = (size_t)op->i1 % 6;
        st = CALL(FN_GetDirectionalDerivative, in,
                  fmi2GetDirectionalDerivative(in->c, op->vr, nu, op->vr, op->n, op->null_val ? NULL : dk, du));
        if (OKISH(st))
            for (size_t k = 0; k < nu; k++)
                if (!isfinite(du[k])) failf("fmi2GetDirectionalDerivative gave %g with status OK", du[k]);
        r->main = res_st(r, st);
        break;
    }
    case OP_DERIVS: {
        fmi2Integer order[MAXV];
        double v[MAXV];
        for (size_t k = 0; k < op->n; k++) {
            order[k] = op->i1 % 3;
            v[k] = op->val[k];
        }
        if (op->var == 0) {
            st = CALL(FN_SetRealInputDerivatives, in,
                      fmi2SetRealInputDerivatives(in->c, op->null_vr ? NULL : op->vr, op->n, order, v));
            if (OKISH(st) && op->n) failf("fmi2SetRealInputDerivatives returned OK (canInterpolateInputs=false)");
        } else {
            st = CALL(FN_GetRealOutputDerivatives, in,
                      fmi2GetRealOutputDerivatives(in->c, op->null_vr ? NULL : op->vr, op->n, order, v));
            if (OKISH(st) && op->n) failf("fmi2GetRealOutputDerivatives returned OK (maxOutputDerivativeOrder=0)");
        }
        r->main = res_st(r, st);
        break;
    }
    case OP_ME: {
        double x[4] = {0, 0, 0, 0};
        fmi2Boolean b1 = 0, b2 = 0;
        fmi2EventInfo info;
        memset(&info, 0, sizeof info);
        switch (op->var) {
        case 0: st = CALL(FN_ModelExchange, in, fmi2EnterEventMode(in->c)); break;
        case 1: st = CALL(FN_ModelExchange, in, fmi2NewDiscreteStates(in->c, &info)); break;
        case 2: st = CALL(FN_ModelExchange, in, fmi2EnterContinuousTimeMode(in->c)); break;
        case 3: st = CALL(FN_ModelExchange, in, fmi2CompletedIntegratorStep(in->c, fmi2True, &b1, &b2)); break;
        case 4: st = CALL(FN_ModelExchange, in, fmi2SetTime(in->c, op->x1)); break;
        case 5: st = CALL(FN_ModelExchange, in, fmi2SetContinuousStates(in->c, x, 4)); break;
        case 6: st = CALL(FN_ModelExchange, in, fmi2GetDerivatives(in->c, x, 4)); break;
        case 7: st = CALL(FN_ModelExchange, in, fmi2GetEventIndicators(in->c, x, 0)); break;
        case 8: st = CALL(FN_ModelExchange, in, fmi2GetContinuousStates(in->c, x, 4)); break;
        default: st = CALL(FN_ModelExchange, in, fmi2GetNominalsOfContinuousStates(in->c, x, 4)); break;
        }
        if (OKISH(st)) failf("model-exchange function %d returned OK on a co-simulation instance", op->var);
        r->main = res_st(r, st);
        break;
    }
    case OP_ROUNDTRIP: {
        /* GetFMUstate, serialize, deserialize; one step from the live state, then SetFMUstate of the
         * deserialized state: every variable bit-exact as before, and the same step gives bit-exactly the
         * same statuses and variables (so nothing that matters later is lost); then SetFMUstate of the
         * original state, which must serialize to the same bytes. */
        g.roundtrips += in->model != NULL;
        const fmi2ValueReference *vr = all_vrs();
        double v0[NV], v1[NV], va[NV], vb[NV];
        fmi2Status ca[4], cb[4];
        fmi2Status g0 = get_real(in, vr, NV, v0, r);
        fmi2FMUstate s = NULL, s2 = NULL;
        unsigned char *b1 = NULL, *b3 = NULL;
        size_t n = 0, n3;
        r->complete = 0;
        if ((st = res_st(r, CALL(FN_GetFMUstate, in, fmi2GetFMUstate(in->c, &s)))) != fmi2OK) {
            failf("round trip: fmi2GetFMUstate refused: %s", last_msg);
            break;
        }
        if (res_st(r, CALL(FN_SerializedFMUstateSize, in, fmi2SerializedFMUstateSize(in->c, s, &n))) != fmi2OK || !n) {
            failf("round trip: fmi2SerializedFMUstateSize refused: %s", last_msg);
            goto rt_free;
        }
        b1 = malloc(n);
        if (res_st(r, CALL(FN_SerializeFMUstate, in, fmi2SerializeFMUstate(in->c, s, (fmi2Byte *)b1, n))) != fmi2OK) {
            failf("round trip: fmi2SerializeFMUstate refused: %s", last_msg);
            goto rt_free;
        }
        if (res_st(r, CALL(FN_DeSerializeFMUstate, in, fmi2DeSerializeFMUstate(in->c, (fmi2Byte *)b1, n, &s2))) != fmi2OK) {
            failf("round trip: the FMU refused its own serialized state (%zu bytes): %s", n, last_msg);
            goto rt_free;
        }
        continue_step(in, op, r, ca, va);
        if (res_st(r, CALL(FN_SetFMUstate, in, fmi2SetFMUstate(in->c, s2))) != fmi2OK) {
            failf("round trip: fmi2SetFMUstate refused the deserialized state: %s", last_msg);
            goto rt_free;
        }
        {
            fmi2Status g1 = get_real(in, vr, NV, v1, r);
            if (g1 != g0) failf("round trip: fmi2GetReal of all variables gave %s before, %s after", st_name[st_index(g0)], st_name[st_index(g1)]);
            else if (OKISH(g0) && !same_values(v0, v1, "round trip: restored"))
                goto rt_free;
        }
        continue_step(in, op, r, cb, vb);
        if (memcmp(ca, cb, sizeof ca) != 0)
            failf("round trip: the step from the restored state gave statuses %d%d%d%d, from the original %d%d%d%d",
                  (int)cb[0], (int)cb[1], (int)cb[2], (int)cb[3], (int)ca[0], (int)ca[1], (int)ca[2], (int)ca[3]);
        else if (OKISH(ca[3]) && !same_values(va, vb, "round trip: after one step from the restored state"))
            goto rt_free;
        if (res_st(r, CALL(FN_SetFMUstate, in, fmi2SetFMUstate(in->c, s))) != fmi2OK) {
            failf("round trip: fmi2SetFMUstate refused the original state: %s", last_msg);
            goto rt_free;
        }
        n3 = state_bytes(in, &b3, r);
        if (n3 != n || !b3 || memcmp(b1, b3, n) != 0) failf("round trip: the restored state serializes differently (%zu vs %zu bytes)", n3, n);
        else {
            r->complete = 1;
            r->bytes = b1; /* a serialized state for the pool */
            r->nbytes = n;
            b1 = NULL;
        }
    rt_free:
        if (s) res_st(r, CALL(FN_FreeFMUstate, in, fmi2FreeFMUstate(in->c, &s)));
        if (s2) res_st(r, CALL(FN_FreeFMUstate, in, fmi2FreeFMUstate(in->c, &s2)));
        if (s || s2) failf("round trip: fmi2FreeFMUstate left a pointer set");
        free(b1);
        free(b3);
        r->main = st;
        break;
    }
    case OP_NULLINST: {
        fmi2ValueReference vr = OUTPUTS[0];
        double v = 0;
        fmi2FMUstate s = NULL;
        int fn;
        switch (op->var) {
        case 0: fn = FN_GetReal; st = CALL(fn, NULL, fmi2GetReal(NULL, &vr, 1, &v)); break;
        case 1: fn = FN_SetReal; st = CALL(fn, NULL, fmi2SetReal(NULL, &vr, 1, &v)); break;
        case 2: fn = FN_DoStep; st = CALL(fn, NULL, fmi2DoStep(NULL, 0.0, 1e-3, fmi2True)); break;
        case 3: fn = FN_GetFMUstate; st = CALL(fn, NULL, fmi2GetFMUstate(NULL, &s)); break;
        case 4: fn = FN_Reset; st = CALL(fn, NULL, fmi2Reset(NULL)); break;
        case 5: fn = FN_SetDebugLogging; st = CALL(fn, NULL, fmi2SetDebugLogging(NULL, fmi2True, 0, NULL)); break;
        default:
            fn = FN_FreeInstance; /* void: must merely return */
            pre(fn, NULL);
            fmi2FreeInstance(NULL);
            post_common(fmi2OK, 0);
            st = fmi2Error;
            break;
        }
        if (OKISH(st)) failf("%s on a NULL instance returned OK", fn_name[fn]);
        r->main = res_st(r, st);
        break;
    }
    case OP_VERSION:
        pre(FN_GetTypesPlatform, NULL);
        if (strcmp(fmi2GetTypesPlatform(), fmi2TypesPlatform) != 0) failf("fmi2GetTypesPlatform is not %s", fmi2TypesPlatform);
        post_common(fmi2OK, 0);
        pre(FN_GetVersion, NULL);
        if (strcmp(fmi2GetVersion(), fmi2Version) != 0) failf("fmi2GetVersion is not %s", fmi2Version);
        post_common(fmi2OK, 0);
        res_st(r, fmi2OK);
        break;
    }
    oom_countdown = -1;
}

/* After each of slot 0's operations: all variables, now and then the whole state as bytes. */
static void probe(Inst *in, Res *r, int full) {
    if (!in->c) return;
    double v[NV];
    get_real(in, all_vrs(), NV, v, r);
    if (full) {
        unsigned char *b = NULL;
        state_bytes(in, &b, r);
        free(b);
    }
}

/* ---------------------------------------------------------------- the model follows the real instance */

static void transition(Model *m, int fn, fmi2Status st, unsigned target) {
    if (!m->phases) return;
    if (OKISH(st)) {
        unsigned a = m->phases & fn_allowed[fn];
        m->phases = target ? target : (a ? a : P_LIVE);
    } else if (st == fmi2Discard && fn == FN_DoStep) {
        m->phases = P_FAILED;
    } else if (st == fmi2Fatal) {
        m->phases = P_LIVE;
    }
}

typedef struct {
    unsigned char *b;
    size_t n;
    unsigned phases;
    int t_known, start_known;
    double t, start;
    int origin;
} Buf;
static Buf pool[MAXB];

static void pool_put(int slot, Res *r, unsigned phases, int t_known, double t, int start_known, double start) {
    Buf *b = &pool[rbelow(MAXB)];
    free(b->b);
    b->b = r->bytes;
    b->n = r->nbytes;
    b->phases = phases;
    b->t_known = t_known;
    b->t = t;
    b->start_known = start_known;
    b->start = start;
    b->origin = slot;
    r->bytes = NULL;
}

static void apply(int slot, const Op *op, Res *r) {
    Model *m = &models[slot];
    Inst *in = &insts[slot];
    fmi2Status st = r->main;
    switch (op->op) {
    case OP_INSTANTIATE:
    case OP_INSTANTIATE_BAD:
        memset(m, 0, sizeof *m);
        if (in->c) {
            m->phases = P_INST;
            m->t_known = 1;
            m->start_known = 1;
        }
        break;
    case OP_FREE: memset(m, 0, sizeof *m); break;
    case OP_SETUP:
        if (OKISH(st)) {
            m->start = op->x1;
            m->start_known = 1;
        }
        transition(m, FN_SetupExperiment, st, 0);
        break;
    case OP_ENTER: transition(m, FN_EnterInitializationMode, st, P_INIT); break;
    case OP_EXIT:
        transition(m, FN_ExitInitializationMode, st, P_STEP);
        if (OKISH(st)) {
            m->t_known = m->start_known;
            m->t = m->start;
        }
        break;
    case OP_TERMINATE: transition(m, FN_Terminate, st, P_TERM); break;
    case OP_RESET:
        transition(m, FN_Reset, st, P_INST);
        if (OKISH(st)) {
            m->start = 0;
            m->start_known = 1;
            m->t = 0;
            m->t_known = 1;
        }
        break;
    case OP_DOSTEP:
        transition(m, FN_DoStep, st, P_STEP);
        if (OKISH(st)) m->t = op->x1 + op->x2;
        break;
    case OP_GETSTATE:
        if (OKISH(st) && op->hsel != HS_OTHER && op->hsel != HS_NULLPTR) {
            m->hvalid[op->hdst] = 1;
            m->hph[op->hdst] = m->phases;
            m->ht_known[op->hdst] = m->t_known;
            m->ht[op->hdst] = m->t;
            m->hstart_known[op->hdst] = m->start_known;
            m->hstart[op->hdst] = m->start;
        }
        transition(m, FN_GetFMUstate, st, 0);
        break;
    case OP_SETSTATE:
        if (OKISH(st) && op->hsel >= 0) {
            m->phases = m->hph[op->hsel];
            m->t_known = m->ht_known[op->hsel];
            m->t = m->ht[op->hsel];
            m->start_known = m->hstart_known[op->hsel];
            m->start = m->hstart[op->hsel];
        } else {
            transition(m, FN_SetFMUstate, st, 0);
        }
        break;
    case OP_FREESTATE:
        if (OKISH(st) && op->hsel >= 0) m->hvalid[op->hsel] = 0;
        transition(m, FN_FreeFMUstate, st, 0);
        break;
    case OP_SERIALIZE:
        if (r->bytes && op->hsel >= 0)
            pool_put(slot, r, m->hph[op->hsel], m->ht_known[op->hsel], m->ht[op->hsel], m->hstart_known[op->hsel],
                     m->hstart[op->hsel]);
        transition(m, FN_SerializeFMUstate, st, 0);
        break;
    case OP_DESERIALIZE:
        if (OKISH(st) && op->hsel != HS_OTHER && op->hsel != HS_NULLPTR && !op->i1) {
            int k = op->hsel >= 0 ? op->hsel : op->hdst;
            int clean = op->corrupt == CR_NONE;
            m->hvalid[k] = 1;
            m->hph[k] = clean ? op->buf_phases : P_LIVE;
            m->ht_known[k] = clean && op->buf_tknown;
            m->ht[k] = op->buf_t;
            m->hstart_known[k] = clean && op->buf_start_known;
            m->hstart[k] = op->buf_start;
        }
        transition(m, FN_DeSerializeFMUstate, st, 0);
        break;
    case OP_ROUNDTRIP:
        if (!r->complete) {
            m->phases = m->phases ? P_LIVE : 0;
            m->t_known = 0;
        } else {
            pool_put(slot, r, m->phases, m->t_known, m->t, m->start_known, m->start);
        }
        break;
    case OP_NULLINST:
    case OP_VERSION: return;
    default: {
        static const int fn_of[OP_COUNT] = {
            [OP_DEBUGLOG] = FN_SetDebugLogging, [OP_SETREAL] = FN_SetReal, [OP_GETREAL] = FN_GetReal,
            [OP_OTHERTYPE] = FN_GetInteger, [OP_CANCEL] = FN_CancelStep, [OP_STATUS] = FN_GetStatus,
            [OP_SERSIZE] = FN_SerializedFMUstateSize, [OP_DIRDER] = FN_GetDirectionalDerivative,
            [OP_DERIVS] = FN_SetRealInputDerivatives, [OP_ME] = FN_ModelExchange};
        /* none of these changes the state when it succeeds; the filter only drops impossible states */
        if (OKISH(st) && op->op != OP_OTHERTYPE && op->op != OP_DERIVS && op->op != OP_ME) transition(m, fn_of[op->op], st, 0);
        break;
    }
    }
    /* an fmi2Error puts a slave into the error state, unless the FMU stays where it was */
    if (m->phases && r->any_error && op->op != OP_FREE) m->phases |= P_ERROR;
}

/* ---------------------------------------------------------------- generating an operation */

static double gen_value(fmi2ValueReference vr, int vc) {
    const MaglevVariable *var = vr < NV ? &VARS[vr] : NULL;
    double def = var ? var->start : 1.0, lo = var ? var->min : -1e3, hi = var ? var->max : 1e3;
    double base = def != 0 ? def : (isfinite(hi) && hi > 0 ? hi / 10 : 1.0);
    switch (vc) {
    case VC_DEFAULT: return def;
    case VC_RANDOM: /* an input as a controller or a plant gives it (MU), whatever its range */
        if (var && var->causality == MAGLEV_INPUT) return 2.4 * runit() - 1.2;
        if (!isfinite(lo) || !isfinite(hi)) return rsign() * rloguni(1e-6, 1e3);
        if (lo > 0 && hi / lo > 1e3) return rloguni(lo, hi);
        return lo + runit() * (hi - lo);
    case VC_MIN: return lo;
    case VC_MAX: return hi;
    case VC_BELOW: return nextafter(lo, -INFINITY);
    case VC_ABOVE: return nextafter(hi, INFINITY);
    case VC_ZERO: return rchance(0.5) ? 0.0 : -0.0;
    case VC_NEG: return -fabs(base) * (rchance(0.5) ? 1.0 : runit());
    case VC_HUGE: return rsign() * 1e308;
    case VC_INF: return rsign() * INFINITY;
    case VC_NAN: return copysign(NAN, rsign());
    case VC_DENORMAL: return rsign() * ldexp(1.0 + runit(), -1023 - (int)rbelow(51));
    case VC_X1000: return base * 1000;
    default: return base * 0.001;
    }
}

/* One of the inputs (no draw when there is one: the plant's sequences stay those of its own harness). */
static fmi2ValueReference any_input(void) { return N_INPUTS == 1 ? INPUTS[0] : INPUTS[rbelow(N_INPUTS)]; }

static fmi2ValueReference gen_vr(int hostile, unsigned phases) {
    unsigned r = rbelow(100);
    if (hostile && r < 10) {
        static const fmi2ValueReference bad[] = {NV, NV + 1, 0x7fffffffu, 0xffffffffu, 1000};
        return r < 8 ? bad[r % 5] : (fmi2ValueReference)rnext();
    }
    if (hostile && r < 22) return OUTPUTS[rbelow(N_OUTPUTS)];
    if ((phases & P_STEP) && !(phases & (P_INST | P_INIT)) && !hostile) return any_input();
    if (r < 45) return any_input();
    return (fmi2ValueReference)(FIRST_PARAM + rbelow(NPARAMS));
}

static int gen_vc(int hostile) {
    if (hostile) return (int)rbelow(VC_COUNT);
    unsigned r = rbelow(100);
    return r < 30 ? VC_DEFAULT : r < 90 ? VC_RANDOM : r < 95 ? VC_MIN : VC_MAX;
}

static void gen_values(Op *op, int hostile, unsigned phases) {
    unsigned r = rbelow(100);
    op->n = r < 60 ? 1 : r < 85 ? 2 + rbelow(6) : r < 92 ? 0 : (size_t)MAXV;
    if (op->n == MAXV && !hostile) op->n = NPARAMS;
    for (size_t k = 0; k < op->n; k++) {
        op->vr[k] = gen_vr(hostile, phases);
        op->vc[k] = (unsigned char)gen_vc(hostile);
        op->val[k] = gen_value(op->vr[k], op->vc[k]);
    }
    if (hostile && rchance(0.05)) op->null_vr = 1;
    if (hostile && rchance(0.05)) op->null_val = 1;
}

/* FNV-1a over all but the last 8 bytes, stored there: the checksum the serialized format ends with */
static void recompute_sum(unsigned char *b, size_t n) {
    if (n < 8) return;
    unsigned long long h = 1469598103934665603ULL;
    for (size_t k = 0; k + 8 < n; k++) {
        h ^= b[k];
        h *= 1099511628211ULL;
    }
    memcpy(b + n - 8, &h, 8);
}

static void gen_buffer(Op *op, int slot) {
    int have = 0;
    for (int k = 0; k < MAXB; k++) have += pool[k].b != NULL;
    const Buf *src = NULL;
    if (have) {
        int pick = (int)rbelow((unsigned)have);
        for (int k = 0; k < MAXB; k++)
            if (pool[k].b && pick-- == 0) src = &pool[k];
    }
    size_t n = src ? src->n : 64 + rbelow(400);
    op->corrupt = src ? (rchance(0.4) ? CR_NONE : 1 + (int)rbelow(CR_COUNT - 1)) : CR_RANDOM;
    if (op->corrupt == CR_EXTEND) n += 1 + rbelow(16);
    if (op->corrupt == CR_EMPTY) n = 0;
    op->bytes = malloc(n ? n : 1);
    op->nbytes = n;
    if (src) {
        memcpy(op->bytes, src->b, src->n < n ? src->n : n);
        op->buf_phases = src->phases;
        op->buf_tknown = src->t_known;
        op->buf_t = src->t;
        op->buf_start_known = src->start_known;
        op->buf_start = src->start;
        if (src->origin != slot) g.foreign_buffers += 1;
    }
    unsigned char *b = op->bytes;
    switch (op->corrupt) {
    case CR_BITFLIP:
        for (int k = 1 + (int)rbelow(3); k > 0; k--) {
            size_t at = rbelow((unsigned)n);
            b[at] ^= (unsigned char)(1u << rbelow(8));
        }
        break;
    case CR_BYTE: b[rbelow((unsigned)n)] = (unsigned char)rnext(); break;
    case CR_TRUNC: op->nbytes = rchance(0.5) ? n - 1 : rbelow((unsigned)n); break;
    case CR_EXTEND:
        for (size_t k = src->n; k < n; k++) b[k] = (unsigned char)rnext();
        break;
    case CR_RANDOM:
        for (size_t k = 0; k < n; k++) b[k] = (unsigned char)rnext();
        if (rchance(0.5) && n >= sizeof SER_MAGIC - 1) memcpy(b, SER_MAGIC, sizeof SER_MAGIC - 1); /* past the magic */
        break;
    case CR_VALUE_RESUM:
        if (n >= SER_HEADER + 16) {
            size_t at = SER_HEADER + 8 * rbelow((unsigned)((n - SER_HEADER - 8) / 8)); /* an 8-byte field after the header */
            if (at + 8 <= n - 8) {
                double v = gen_value((fmi2ValueReference)rbelow(NV), (int)rbelow(VC_COUNT));
                if (rchance(0.3)) v = rsign() * runit();
                memcpy(b + at, &v, 8);
            }
        }
        recompute_sum(b, n);
        break;
    case CR_HEADER_RESUM:
        if (n > SER_HEADER) {
            size_t at = 4 + rbelow(SER_HEADER - 4);
            b[at] = rchance(0.5) ? (unsigned char)rnext() : (unsigned char)(b[at] + 1);
        }
        recompute_sum(b, n);
        break;
    default: break;
    }
    g.corrupt[op->corrupt]++;
}

#ifdef FUZZ_PID
/* A random but consistent controller (in range, relations kept, so that initialization accepts it): any
 * sample time from 1 us (the step's sample bound then matters) to 10 ms, gains from gentle to harsh, with or
 * without the derivative filter, every anti-windup mode with its band, limits anywhere in the range and the
 * settled start between them, a reference step before, at or after the start. */
static void gen_scenario(Op *op) {
    struct { MaglevPidVR vr; double v; } s[24];
    int n = 0;
    double u_min = rchance(0.3) ? 0.0 : rsign() * rloguni(1e-3, 10.0), u_max = u_min + rloguni(1e-2, 100.0);
    int aw = (int)rbelow(4);
    s[n].vr = PID_ts, s[n++].v = rchance(0.05) ? 1e-6 : rloguni(1e-5, 1e-2);
    s[n].vr = PID_kp, s[n++].v = (rchance(0.1) ? -1.0 : 1.0) * rloguni(1e-2, 1e3);
    s[n].vr = PID_ki, s[n++].v = rchance(0.2) ? 0.0 : rloguni(1e-2, 1e4);
    s[n].vr = PID_kd, s[n++].v = rchance(0.3) ? 0.0 : rloguni(1e-5, 1.0);
    s[n].vr = PID_tf, s[n++].v = rchance(0.4) ? 0.0 : rloguni(1e-5, 1e-1);
    s[n].vr = PID_u_min, s[n++].v = u_min;
    s[n].vr = PID_u_max, s[n++].v = u_max;
    s[n].vr = PID_anti_windup, s[n++].v = aw;
    if (aw == 3 || rchance(0.2)) {
        double lo = u_min + runit() * (u_max - u_min);
        s[n].vr = PID_i_lo, s[n++].v = lo;
        s[n].vr = PID_i_hi, s[n++].v = lo + rloguni(1e-3, 10.0);
        s[n].vr = PID_backoff, s[n++].v = rchance(0.3) ? 1.0 : 1e-3 + runit() * (1 - 1e-3);
    }
    s[n].vr = PID_u_hold, s[n++].v = u_min + runit() * (u_max - u_min);
    s[n].vr = PID_w0, s[n++].v = 2 * runit() - 1;
    s[n].vr = PID_w1, s[n++].v = 2 * runit() - 1;
    s[n].vr = PID_t_step, s[n++].v = rchance(0.2) ? 0.0 : rsign() * rloguni(1e-4, 1.0);
    s[n].vr = PID_y, s[n++].v = 2.4 * runit() - 1.2;
    if (rchance(0.5)) s[n].vr = PID_w_in, s[n++].v = 0.2 * runit() - 0.1;
    op->n = (size_t)n;
    for (int k = 0; k < n; k++) {
        op->vr[k] = (fmi2ValueReference)s[k].vr;
        op->val[k] = s[k].v;
        op->vc[k] = VC_RANDOM;
    }
}
#else
/* A random but consistent plant (in range, relations kept, with the default stops): the ball anywhere
 * between the stops, moving or not, with or without delay, force lag, amplifier lag, sensor pickup and
 * deviation, fine or coarse solver steps. This is what takes the sequences deep into the plant. */
static void gen_scenario(Op *op) {
    struct { MaglevVR vr; double v; } s[32];
    int n = 0;
    double x_max = VARS[VR_x_max].start, i_max = VARS[VR_i_max].start;
    s[n].vr = VR_x_start, s[n++].v = rchance(0.3) ? (rchance(0.5) ? 0.0 : x_max) : runit() * x_max;
    s[n].vr = VR_v_start, s[n++].v = rchance(0.5) ? 0.0 : rsign() * rloguni(1e-4, 1.0);
    if (rchance(0.2)) s[n].vr = VR_i_max, i_max = s[n++].v = rloguni(1.0, 10.0);
    s[n].vr = VR_i_start, s[n++].v = runit() * i_max;
    s[n].vr = VR_u, s[n++].v = 2.4 * runit() - 1.2;
    s[n].vr = VR_T_d, s[n++].v = rchance(0.5) ? 0.0 : rloguni(1e-5, 2e-2);
    s[n].vr = VR_T_F, s[n++].v = rchance(0.6) ? 0.0 : rloguni(1e-6, 1e-2);
    s[n].vr = VR_T_a, s[n++].v = rchance(0.2) ? 0.0 : rloguni(1e-5, 1e-2);
    s[n].vr = VR_T_y, s[n++].v = rchance(0.6) ? 0.0 : rloguni(1e-7, 1.0);
    s[n].vr = VR_solver_step, s[n++].v = rloguni(1e-6, 1e-3);
    if (rchance(0.3)) s[n].vr = VR_A_d, s[n++].v = rsign() * rloguni(1e-3, 1.0);
    if (rchance(0.3)) s[n].vr = VR_f_d, s[n++].v = rloguni(1.0, 1e5);
    if (rchance(0.3)) s[n].vr = VR_k_x2, s[n++].v = rsign() * rloguni(1.0, 1e5);
    if (rchance(0.3)) s[n].vr = VR_k_FV, s[n++].v = rloguni(1e-4, 10.0);
    if (rchance(0.25)) { /* the exponential force law (Inteco's), alone or beside Eq. 8 */
        s[n].vr = VR_k_e, s[n++].v = rloguni(1e-6, 1e-2);
        s[n].vr = VR_z_e, s[n++].v = rloguni(1e-4, 1e-1);
        if (rchance(0.5)) s[n].vr = VR_k_c, s[n++].v = 0.0;
    }
    if (rchance(0.25)) { /* a voltage drive: the current becomes a state */
        double L_0 = rloguni(1e-3, 1.0);
        s[n].vr = VR_R_c, s[n++].v = rloguni(0.1, 100.0);
        s[n].vr = VR_L_0, s[n++].v = L_0;
        s[n].vr = VR_L_x, s[n++].v = rchance(0.3) ? 0.0 : rloguni(1e-4, 1.0);
        s[n].vr = VR_z_L, s[n++].v = rloguni(1e-4, 1e-1);
        s[n].vr = VR_L_i, s[n++].v = rchance(0.5) ? 0.0 : runit() * 0.6 * L_0;
        s[n].vr = VR_L_g, s[n++].v = rchance(0.7) ? 0.0 : rloguni(1e-6, 1e-2);
        s[n].vr = VR_a_i, s[n++].v = rloguni(0.1, 10.0);
        s[n].vr = VR_b_i, s[n++].v = 4 * runit() - 2;
        s[n].vr = VR_V_min, s[n++].v = rchance(0.5) ? 0.0 : 2 * runit() - 1;
    }
    op->n = (size_t)n;
    for (int k = 0; k < n; k++) {
        op->vr[k] = (fmi2ValueReference)s[k].vr;
        op->val[k] = s[k].v;
        op->vc[k] = VC_RANDOM;
    }
}
#endif

static fmi2FMUstate foreign_state(int slot) {
    if (slot != 0 && rchance(0.6)) { /* a live state of another instance (slot 0's too) */
        int o = (int)rbelow(NSLOT);
        for (int k = 0; k < MAXH; k++)
            if (o != slot && insts[o].h[k]) return insts[o].h[k];
    }
    return (fmi2FMUstate)(forged + 16 * rbelow(4)); /* never a state: forged */
}

static int pick_handle(int slot, int hostile, int allow_nullptr) {
    Model *m = &models[slot];
    int valid[MAXH], nv = 0;
    for (int k = 0; k < MAXH; k++)
        if (m->hvalid[k]) valid[nv++] = k;
    if (nv && (!hostile || rchance(0.5))) return valid[rbelow((unsigned)nv)];
    unsigned r = rbelow(10);
    if (r < 4) return HS_OTHER;
    if (r < 6 && allow_nullptr) return HS_NULLPTR;
    return HS_NULL;
}

static int free_index(int slot) {
    for (int k = 0; k < MAXH; k++)
        if (!models[slot].hvalid[k]) return k;
    return -1;
}

/* op weights: everything is possible everywhere; what advances the state machine is likelier */
static int choose_op(int slot) {
    const Model *m = &models[slot];
    if (!m->phases) {
        unsigned r = rbelow(100);
        return r < 85 ? OP_INSTANTIATE : r < 93 ? OP_INSTANTIATE_BAD : r < 97 ? OP_NULLINST : OP_VERSION;
    }
    int w[OP_COUNT];
    for (int k = 0; k < OP_COUNT; k++) w[k] = 2;
    w[OP_INSTANTIATE] = w[OP_INSTANTIATE_BAD] = 0;
    w[OP_FREE] = 1;
    w[OP_GETREAL] = 6;
    w[OP_SETREAL] = 6;
    w[OP_ROUNDTRIP] = 3;
    w[OP_GETSTATE] = w[OP_SERIALIZE] = w[OP_DESERIALIZE] = 4;
    if (m->phases & P_INST) w[OP_SETUP] += 10, w[OP_ENTER] += 14, w[OP_SETREAL] += 6;
    if (m->phases & P_INIT) w[OP_EXIT] += 16, w[OP_SETREAL] += 8, w[OP_GETREAL] += 4;
    if (m->phases & P_STEP) w[OP_DOSTEP] += 40, w[OP_SETREAL] += 10, w[OP_GETREAL] += 4;
    if (m->phases & (P_TERM | P_ERROR)) w[OP_RESET] += 8, w[OP_SETSTATE] += 4;
    int total = 0;
    for (int k = 0; k < OP_COUNT; k++) total += w[k];
    int r = (int)rbelow((unsigned)total);
    for (int k = 0; k < OP_COUNT; k++)
        if ((r -= w[k]) < 0) return k;
    return OP_GETREAL;
}

static void gen_op(int slot, Op *op) {
    memset(op, 0, sizeof *op);
    const Model *m = &models[slot];
    int hostile = rchance(slot == 0 ? 0.25 : 0.6);
    op->slot = slot;
    op->oom = -1;
    op->op = choose_op(slot);
    op->hsel = HS_NULL;
    if (slot != 0 && op->op != OP_ROUNDTRIP && rchance(0.04))
        op->oom = (int)rbelow(3); /* never on slot 0 (the shadow must match), nor in a round trip (must succeed) */
    switch (op->op) {
    case OP_INSTANTIATE: op->i1 = (int)rbelow(3); op->i2 = (int)rbelow(2); break;
    case OP_INSTANTIATE_BAD: op->var = (int)rbelow(8); break;
    case OP_SETUP:
        op->i1 = rchance(0.3);
        op->x3 = hostile && rchance(0.3) ? (rchance(0.5) ? NAN : -1e-6) : 1e-6;
        op->x1 = rchance(0.6) ? 0.0 : rchance(0.7) ? rsign() * rloguni(1e-3, 1e3) : rsign() * (1e9 - rloguni(1e-3, 10));
        op->i2 = rchance(0.3);
        op->x2 = op->x1 + rloguni(1e-3, 10);
        if (hostile) {
            unsigned r = rbelow(6);
            if (r == 0) op->x1 = NAN;
            else if (r == 1) op->x1 = rsign() * INFINITY;
            else if (r == 2) op->x1 = rsign() * 2e9;
            else if (r == 3) op->i2 = 1, op->x2 = op->x1 - 1.0;
            else if (r == 4) op->i2 = 1, op->x2 = NAN;
        }
        break;
    case OP_DEBUGLOG:
        op->i1 = !rchance(0.05);
        op->var = hostile ? (int)rbelow(4) : 0;
        op->i2 = (int)rbelow(4);
        break;
    case OP_SETREAL:
        if (!hostile && (m->phases & (P_INST | P_INIT)) && rchance(0.3)) {
            gen_scenario(op);
        } else if (!hostile && (m->phases & (P_INST | P_INIT)) && rchance(0.15)) { /* back to the start values */
            op->n = NPARAMS;
            for (size_t k = 0; k < op->n; k++) {
                op->vr[k] = (fmi2ValueReference)(FIRST_PARAM + k);
                op->vc[k] = VC_DEFAULT;
                op->val[k] = VARS[op->vr[k]].start;
            }
        } else {
            gen_values(op, hostile, m->phases);
        }
        for (size_t k = 0; k < op->n; k++) g.vclass[op->vc[k]]++;
        break;
    case OP_GETREAL:
    case OP_OTHERTYPE:
    case OP_DIRDER:
    case OP_DERIVS:
        gen_values(op, hostile || op->op != OP_GETREAL, m->phases);
        if (op->op == OP_GETREAL && !hostile)
            for (size_t k = 0; k < op->n; k++) op->vr[k] = (fmi2ValueReference)rbelow(NV);
        if (op->op == OP_GETREAL && rchance(0.2)) { /* all variables and then some */
            op->n = MAXV;
            for (size_t k = 0; k < op->n; k++) op->vr[k] = (fmi2ValueReference)(hostile ? rbelow(NV + 3) : k % NV);
        }
        op->var = (int)rbelow(op->op == OP_OTHERTYPE ? 6 : 2);
        op->i1 = (int)rbelow(100);
        break;
    case OP_DOSTEP: {
        op->x1 = m->t_known ? m->t : 0.0;
        op->i1 = rchance(0.5);
        unsigned r = rbelow(100);
        if (!hostile || r < 40) op->x2 = rloguni(1e-4, 1e-2);
        else if (r < 50) op->x2 = rloguni(1e-15, 1e-7);
        else if (r < 55) op->x2 = 0.0;
        else if (r < 60) op->x2 = -rloguni(1e-6, 1.0);
        else if (r < 65) op->x2 = 1e20;
        else if (r < 70) op->x2 = NAN;
        else if (r < 73) op->x2 = INFINITY;
        else if (r < 76) op->x2 = rloguni(0.05, 5.0); /* long: the work budget decides */
        else if (r < 80) op->x2 = ldexp(1.0, -1060);
        else op->x2 = rloguni(1e-4, 1e-2);
        if (hostile && rchance(0.4)) { /* a communication point that does not match */
            unsigned q = rbelow(7);
            op->x1 = q == 0 ? op->x1 + 1e-3 : q == 1 ? op->x1 - 1.0 : q == 2 ? 0.0 : q == 3 ? NAN
                   : q == 4 ? 1e300 : q == 5 ? op->x1 * (1 + 1e-13) : -INFINITY;
        }
        break;
    }
    case OP_STATUS:
        op->var = (int)rbelow(5);
        op->i1 = hostile && rchance(0.3) ? (int)rbelow(8) : op->var == 1 ? (int)fmi2LastSuccessfulTime
               : op->var == 0 ? (int)fmi2DoStepStatus : op->var == 3 ? (int)fmi2Terminated : (int)fmi2PendingStatus;
        op->i2 = hostile && rchance(0.2);
        break;
    case OP_GETSTATE: {
        int k = free_index(slot);
        op->hsel = hostile ? pick_handle(slot, 1, 1) : (k >= 0 ? HS_NULL : pick_handle(slot, 0, 0));
        if (op->hsel == HS_NULL && k < 0) op->hsel = pick_handle(slot, 0, 0); /* every index in use: reuse one */
        if (op->hsel == HS_NULL && k < 0) op->hsel = HS_OTHER;
        op->hdst = op->hsel >= 0 ? op->hsel : (k >= 0 ? k : 0);
        break;
    }
    case OP_SETSTATE:
    case OP_FREESTATE:
    case OP_SERSIZE:
    case OP_SERIALIZE:
        op->hsel = pick_handle(slot, hostile, op->op == OP_FREESTATE);
        if (op->hsel == HS_NULLPTR && op->op != OP_FREESTATE) op->hsel = HS_NULL;
        op->i1 = op->op == OP_SERSIZE ? hostile && rchance(0.2) : (int)rbelow(16);
        op->var = hostile ? (int)rbelow(4) : 0;
        break;
    case OP_DESERIALIZE: {
        gen_buffer(op, slot);
        int k = free_index(slot);
        op->hsel = k >= 0 && (!hostile || rchance(0.5)) ? HS_NULL : pick_handle(slot, hostile, 1);
        if (op->hsel == HS_NULL && k < 0) op->hsel = pick_handle(slot, 0, 0);
        if (op->hsel == HS_NULL && k < 0) op->hsel = HS_OTHER;
        op->hdst = op->hsel >= 0 ? op->hsel : (k >= 0 ? k : 0);
        op->i1 = hostile && rchance(0.05); /* NULL buffer */
        break;
    }
    case OP_ME: op->var = (int)rbelow(10); op->x1 = runit(); break;
    case OP_ROUNDTRIP: op->x1 = 2.4 * runit() - 1.2; op->x2 = rloguni(1e-4, 1e-2); break;
    case OP_NULLINST: op->var = (int)rbelow(7); break;
    default: break;
    }
    if (op->hsel == HS_OTHER) op->other = foreign_state(slot);
}

/* ---------------------------------------------------------------- one sequence */

typedef struct { Op op; Res res; } Rec;
static Rec *recs;
static size_t nrec, caprec;

static void init_inst(Inst *in, int id, const char *name) {
    memset(in, 0, sizeof *in);
    in->id = id;
    snprintf(in->name, sizeof in->name, "%s", name);
    in->cb.logger = logger;
    in->cb.allocateMemory = fz_alloc;
    in->cb.freeMemory = fz_free;
    in->cb.stepFinished = NULL;
    in->cb.componentEnvironment = in;
    in->model = id < NSLOT ? &models[id] : NULL;
}

static void run_op(int slot, Op *op) {
    Res r;
    res_init(&r);
    exec_op(&insts[slot], op, &r);
    if (slot == 0) probe(&insts[0], &r, nrec % 8 == 0);
    apply(slot, op, &r);
    free(r.bytes);
    r.bytes = NULL;
    if (slot == 0) {
        if (nrec == caprec) {
            caprec = caprec ? 2 * caprec : 256;
            recs = realloc(recs, caprec * sizeof *recs);
            if (!recs) abort();
        }
        recs[nrec].op = *op;
        recs[nrec].res = r;
        nrec++;
    } else {
        free(op->bytes);
    }
}

static void run_sequence(unsigned long long seed, int max_ops) {
    g.seed = seed;
    g.call = 0;
    rng_state = seed;
    memset(models, 0, sizeof models);
    for (int k = 0; k < NSLOT; k++) {
        char name[32];
        snprintf(name, sizeof name, "fuzz%d", k);
        init_inst(&insts[k], k, name);
    }
    init_inst(&insts[SHADOW_ID], SHADOW_ID, "fuzz0"); /* the same name as slot 0 */
    memset(pool, 0, sizeof pool);
    nrec = 0;
    int n_ops = 20 + (int)rbelow((unsigned)max_ops);
    for (int k = 0; k < n_ops; k++) {
        Op op;
        int slot = rchance(0.4) ? 0 : 1 + (int)rbelow(NSLOT - 1);
        gen_op(slot, &op);
        run_op(slot, &op);
    }
    /* every instance freed: no block may remain */
    for (int k = 0; k < NSLOT; k++)
        if (insts[k].c) {
            Op op;
            memset(&op, 0, sizeof op);
            op.op = OP_FREE;
            op.slot = k;
            op.oom = -1;
            run_op(k, &op);
        }
    if (live_total()) failf("%ld blocks still allocated after every instance was freed", live_total());
    /* the shadow, alone, runs slot 0's operations: same statuses, same values, bit for bit */
    Inst *sh = &insts[SHADOW_ID];
    for (size_t k = 0; k < nrec; k++) {
        Res r;
        res_init(&r);
        exec_op(sh, &recs[k].op, &r);
        probe(sh, &r, k % 8 == 0);
        free(r.bytes);
        g.replayed_ops++;
        if (r.digest != recs[k].res.digest) {
            char a[64] = "", b[64] = "";
            for (int q = 0; q < recs[k].res.nst && q < 8; q++)
                snprintf(a + strlen(a), sizeof a - strlen(a), "%d", (int)recs[k].res.st[q]);
            for (int q = 0; q < r.nst && q < 8; q++) snprintf(b + strlen(b), sizeof b - strlen(b), "%d", (int)r.st[q]);
            failf("instance 0, interleaved with the others, and the shadow instance running alone differ at "
                  "its operation %zu (%s): statuses %s vs %s, or the values or bytes returned",
                  k, op_name[recs[k].op.op], a, b);
            break;
        }
    }
    if (sh->c) {
        pre(FN_FreeInstance, sh);
        fmi2FreeInstance(sh->c);
        post_common(fmi2OK, 0);
        sh->c = NULL;
        check_leak_after_free(sh);
    }
    for (size_t k = 0; k < nrec; k++) free(recs[k].op.bytes);
    for (int k = 0; k < MAXB; k++) free(pool[k].b);
    memset(pool, 0, sizeof pool);
    if (live_total()) failf("%ld blocks still allocated after the shadow was freed", live_total());
    for (int k = 0; k < NSLOT + 2; k++) live_by_owner[k] = 0;
    g.sequences++;
}

/* ---------------------------------------------------------------- command line and summary */

static unsigned long long random_seed(void) {
    unsigned long long s = 0;
    FILE *f = fopen("/dev/urandom", "rb");
    if (!f || fread(&s, sizeof s, 1, f) != 1) s = (unsigned long long)time(NULL) ^ (unsigned long long)(now() * 1e9);
    if (f) fclose(f);
    return s & 0xFFFFFFFFFFFFULL; /* 48 bits: short enough to type */
}

static void usage(void) {
    fprintf(stderr, "usage: " PROGRAM " [--seeds A:B] [--random N] [--seconds S] [--max-ops N] [--max-call S] [--trace]\n"
                    "  --seeds A:B   the fixed seeds A, A+1, ..., B-1 (default 1:201); --seeds X replays seed X\n"
                    "  --random N    N more seeds from /dev/urandom, printed for replay (default 0)\n"
                    "  --seconds S   stop starting sequences once S seconds have passed (default: no limit)\n"
                    "  --max-ops N   operations per sequence: 20 + a random number below N (default 1000)\n"
                    "  --max-call S  the bound on one call's wall time in seconds (default 2)\n"
                    "  --trace       print every call\n");
}

int main(int argc, char **argv) {
    unsigned long long a = 1, b = 201;
    long n_random = 0, max_ops = 1000;
    double seconds = 0;
    g.max_call = 2.0;
    for (int k = 1; k < argc; k++) {
        const char *arg = argv[k], *val = k + 1 < argc ? argv[k + 1] : NULL;
        if (!strcmp(arg, "--trace")) { g.trace = 1; continue; }
        if (!val) { usage(); return 2; }
        k++;
        char *end;
        if (!strcmp(arg, "--seeds")) {
            a = strtoull(val, &end, 10);
            if (*end == ':') b = strtoull(end + 1, &end, 10);
            else b = a + 1;
            if (*end || b <= a) { usage(); return 2; }
        } else if (!strcmp(arg, "--random")) {
            n_random = strtol(val, &end, 10);
            if (*end || n_random < 0) { usage(); return 2; }
        } else if (!strcmp(arg, "--seconds")) {
            seconds = strtod(val, &end);
            if (*end || !(seconds >= 0)) { usage(); return 2; }
        } else if (!strcmp(arg, "--max-ops")) {
            max_ops = strtol(val, &end, 10);
            if (*end || max_ops < 1) { usage(); return 2; }
        } else if (!strcmp(arg, "--max-call")) {
            g.max_call = strtod(val, &end);
            if (*end || !(g.max_call > 0)) { usage(); return 2; }
        } else { usage(); return 2; }
    }
    unsigned long long *rs = calloc((size_t)n_random + 1, sizeof *rs);
    for (long k = 0; k < n_random; k++) rs[k] = random_seed();
    printf(PROGRAM ": seeds %llu:%llu", a, b);
    if (n_random) {
        printf(" and %ld random seeds:", n_random);
        for (long k = 0; k < n_random; k++) printf("%s%llu", k % 8 ? " " : "\n  ", rs[k]);
    }
    printf("\n(replay one seed X with: " PROGRAM " --seeds X --trace)\n");
    fflush(stdout);
    g.slowest_fn = -1;
    double t0 = now();
    unsigned long long total = (b - a) + (unsigned long long)n_random, done = 0;
    int stopped = 0;
    for (unsigned long long q = 0; q < total; q++) {
        if (seconds > 0 && now() - t0 >= seconds) {
            stopped = 1;
            break;
        }
        run_sequence(q < b - a ? a + q : rs[q - (b - a)], (int)max_ops);
        done++;
    }
    double el = now() - t0;
    printf(PROGRAM ": %ld sequences, %ld calls in %.1f s = %.0f calls/s, %ld failures%s\n", g.sequences, g.calls, el,
           el > 0 ? (double)g.calls / el : 0.0, g.failures,
           stopped ? " (stopped by --seconds before the last seeds)" : "");
    if (stopped) printf("  ran %llu of %llu seeds\n", done, total);
    if (g.slowest_fn >= 0)
        printf("slowest call: %s %.3f ms (seed %llu, call %ld); bound %.3f s\n", fn_name[g.slowest_fn], 1e3 * g.slowest,
               g.slowest_seed, g.slowest_call, g.max_call);
    printf("%-32s %9s", "calls per function and status", "calls");
    for (int s = 0; s < NST; s++) printf(" %8s", st_name[s]);
    printf(" %9s\n", "max ms");
    for (int f = 0; f < FN_COUNT; f++) {
        long n = 0;
        for (int s = 0; s < NST; s++) n += g.per[f][s];
        if (!n) continue;
        printf("  %-30s %9ld", fn_name[f], n);
        for (int s = 0; s < NST; s++) printf(" %8ld", g.per[f][s]);
        printf(" %9.3f\n", 1e3 * g.tmax[f]);
    }
    printf("  (fmi2Instantiate: NULL counted as error; fmi2FreeInstance, fmi2GetVersion: as ok)\n");
    printf("SetReal value classes:");
    for (int k = 0; k < VC_COUNT; k++) printf(" %s %ld%s", vc_name[k], g.vclass[k], k + 1 < VC_COUNT ? "," : "\n");
    printf("DeSerialize corruption kinds:");
    for (int k = 0; k < CR_COUNT; k++) printf(" %s %ld%s", cr_name[k], g.corrupt[k], k + 1 < CR_COUNT ? "," : "\n");
    printf("buffers from another instance %ld, corrupted buffers accepted %ld, allocation failures injected %ld, "
           "round trips %ld, operations replayed on the shadow %ld\n",
           g.foreign_buffers, g.corrupt_accepted, g.oom_injected, g.roundtrips, g.replayed_ops);
    free(rs);
    free(recs);
    return g.failures ? 1 : 0;
}
