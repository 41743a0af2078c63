/* FMI 2.0 co-simulation entry points of the controller FMU: the paper's discrete PID (Eq. 24/25)
 * against a step reference. The difference equation is maglev_pid_step (maglev_replay.c), the one
 * the closed-loop replay and the Python toolkit's fast path run.
 *
 * Timing, as loop.simulate has it: the controller samples at t_k = t0 + k*ts. fmi2DoStep from t
 * to t + h takes every sample t_k in [t, t + h): it reads the inputs y and w_in as they are set,
 * and from then on the output u is u[k] = PID(w[k] - y[k]), held until the next sample. A master
 * that steps this FMU before the plant at each communication point (Gauss-Seidel, communication
 * step = ts) so applies u[k] to the plant over [t_k, t_k + ts], as loop.simulate does; a master
 * that steps both on the old values (Jacobi) adds one sample of delay. The reference is
 * w[k] = (t_k >= t_step ? w1 : w0) + w_in. */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "maglev_pid_fmu.h"
#include "maglev_replay.h"

/* Must equal the guid of modelDescription_pid.xml (tests/test_model_description.py). */
#define MAGLEV_PID_GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0101}"
/* Samples one fmi2DoStep may take: bounds the work of a call (never a hang). */
#define MAX_SAMPLES_PER_STEP 10000000.0
#define LIM 1e3 /* [MU] range of readings, references and limits */
#define GAIN 1e6

const MaglevVariable maglev_pid_variables[MAGLEV_PID_NVARS] = {
    {"y", MAGLEV_INPUT, 0.0, -LIM, LIM, "MU", "Plant reading (A/D output), sampled at t0 + k*ts"},
    {"w_in", MAGLEV_INPUT, 0.0, -LIM, LIM, "MU", "Reference input, added to the step reference"},
    {"u", MAGLEV_OUTPUT, 0.0, -LIM, LIM, "MU", "Controller output u[k] (Eq. 24), held until the next sample"},
    {"w", MAGLEV_OUTPUT, 0.0, -2 * LIM, 2 * LIM, "MU", "Reference w[k] of the last sample"},
    {"ts", MAGLEV_PARAMETER, 1e-3, 1e-6, 10.0, "s", "Sample time"},
    {"kp", MAGLEV_PARAMETER, 2.0, -GAIN, GAIN, "1", "Proportional gain (Eq. 22)"},
    {"ki", MAGLEV_PARAMETER, 2.97, -GAIN, GAIN, "1/s", "Integral gain (Eq. 22)"},
    {"kd", MAGLEV_PARAMETER, 0.01, -GAIN, GAIN, "s", "Derivative gain (Eq. 22)"},
    {"tf", MAGLEV_PARAMETER, 0.0, 0.0, 100.0, "s", "Derivative filter time constant, 0 = off"},
    {"u_min", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Lower output limit"},
    {"u_max", MAGLEV_PARAMETER, 1.0, -LIM, LIM, "MU", "Upper output limit"},
    {"anti_windup", MAGLEV_PARAMETER, 0.0, 0.0, 3.0, "1",
     "Anti-windup: 0 none, 1 conditional integration, 2 clamping, 3 band"},
    {"i_lo", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Lower edge of the integrator band (anti_windup 3)"},
    {"i_hi", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Upper edge of the integrator band (anti_windup 3)"},
    {"backoff", MAGLEV_PARAMETER, 1.0, 0.0, 1.0, "1", "Where the band pulls the integrator back to (0, 1]"},
    {"u_hold", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Settled start: the integrator's initial value"},
    {"w0", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Step reference before t_step"},
    {"w1", MAGLEV_PARAMETER, 0.0, -LIM, LIM, "MU", "Step reference from t_step on"},
    {"t_step", MAGLEV_PARAMETER, 0.0, -MAGLEV_TIME_MAX, MAGLEV_TIME_MAX, "s", "Time of the reference step"},
};

typedef enum {
    StartAndEnd = 1 << 0,
    Instantiated = 1 << 1,
    InitializationMode = 1 << 2,
    StepComplete = 1 << 3,
    StepFailed = 1 << 4,
    Terminated = 1 << 5,
    Error = 1 << 6,
} FmuState;

#define ANY_LIVE (Instantiated | InitializationMode | StepComplete | StepFailed | Terminated | Error)
#define MASK_GET (InitializationMode | StepComplete | StepFailed | Terminated | Error)
#define MASK_SET (Instantiated | InitializationMode | StepComplete)

/* Everything an FMU state holds. */
typedef struct {
    double v[MAGLEV_PID_NVARS]; /* inputs, outputs and parameters by value reference */
    MaglevPidState s;
    double t0, time, k;         /* start time, FMU time, index of the next sample */
    int initialized;
} Core;

typedef struct Snapshot {
    FmuState state;
    Core core;
    struct Snapshot *prev, *next;
} Snapshot;

typedef struct {
    char name[128];
    fmi2CallbackFunctions cb;
    int logging;
    FmuState state;
    double stop_time;
    int stop_defined;
    Core core;
    Snapshot *snapshots;
} Fmu;

static const char *state_name(FmuState s) {
    switch (s) {
    case StartAndEnd: return "startAndEnd";
    case Instantiated: return "instantiated";
    case InitializationMode: return "initializationMode";
    case StepComplete: return "stepComplete";
    case StepFailed: return "stepFailed";
    case Terminated: return "terminated";
    case Error: return "error";
    }
    return "?";
}

/* The message goes as the format itself, '%' doubled: importers without C varargs (fmpy's ctypes
 * logger) never see variadic arguments (as maglev_fmu.c). */
static void vemit(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status, const char *fmt, va_list ap) {
    if (!cb->logger) return;
    char buf[512], esc[1024];
    vsnprintf(buf, sizeof buf, fmt, ap);
    size_t n = 0;
    for (const char *p = buf; *p && n + 2 < sizeof esc; p++) {
        if (*p == '%') esc[n++] = '%';
        esc[n++] = *p;
    }
    esc[n] = 0;
    cb->logger(cb->componentEnvironment, name, status, status == fmi2OK ? "logCalls" : "logStatusError", esc);
}

static void emit(const fmi2CallbackFunctions *cb, const char *name, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vemit(cb, name, fmi2Error, fmt, ap);
    va_end(ap);
}

static fmi2Status error(Fmu *f, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vemit(&f->cb, f->name, fmi2Error, fmt, ap);
    va_end(ap);
    return fmi2Error;
}

static int guard(fmi2Component c, const char *fn, int mask) {
    Fmu *f = (Fmu *)c;
    if (!f) return 0;
    if (!(f->state & mask)) {
        error(f, "%s: not allowed in state %s", fn, state_name(f->state));
        return 0;
    }
    return 1;
}

#define GUARD(fn, mask) \
    do { if (!guard(c, fn, mask)) return fmi2Error; } while (0)

/* ---- the controller ---- */

static MaglevPid settings(const Core *c) {
    const double *v = c->v;
    MaglevPid p = {v[PID_ts], v[PID_kp], v[PID_ki], v[PID_kd], v[PID_u_min], v[PID_u_max], v[PID_tf],
                   (int)v[PID_anti_windup], v[PID_i_lo], v[PID_i_hi], v[PID_backoff]};
    return p;
}

static double reference(const Core *c, double t) {
    return (t >= c->v[PID_t_step] - 1e-12 ? c->v[PID_w1] : c->v[PID_w0]) + c->v[PID_w_in];
}

/* One variable's value: in its range, finite, and an integer where it must be. 0, or -1 with msg. */
static int check_value(fmi2ValueReference vr, double x, char *msg, size_t len) {
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
static int check_all(const Core *c, char *msg, size_t len) {
    for (int vr = 0; vr < MAGLEV_PID_NVARS; vr++)
        if (maglev_pid_variables[vr].causality != MAGLEV_OUTPUT && check_value((fmi2ValueReference)vr, c->v[vr], msg, len))
            return -1;
    MaglevPid p = settings(c);
    if (maglev_pid_check(&p, msg, len)) return -1;
    if (c->v[PID_u_hold] < p.u_min || c->v[PID_u_hold] > p.u_max) {
        snprintf(msg, len, "variable u_hold = %g lies outside [u_min, u_max] = [%g, %g] MU", c->v[PID_u_hold], p.u_min,
                 p.u_max);
        return -1;
    }
    return 0;
}

static void defaults(Core *c) {
    memset(c, 0, sizeof *c);
    for (int vr = 0; vr < MAGLEV_PID_NVARS; vr++) c->v[vr] = maglev_pid_variables[vr].start;
}

/* Settled start at t0: integrator at u_hold, previous error and derivative 0 (maglev_replay.h). */
static void start(Core *c, double t0) {
    c->s.integral = c->v[PID_u_hold];
    c->s.e_prev = c->s.d_prev = 0.0;
    c->t0 = c->time = t0;
    c->k = 0.0;
    c->v[PID_u] = c->v[PID_u_hold];
    c->v[PID_w] = reference(c, t0);
    c->initialized = 1;
}

/* ---- FMI ---- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    GUARD("fmi2SetDebugLogging", ANY_LIVE);
    Fmu *f = c;
    if (nCategories > 0 && !categories) return error(f, "fmi2SetDebugLogging: categories is NULL");
    for (size_t k = 0; k < nCategories; k++) {
        const char *cat = categories[k];
        if (!cat || (strcmp(cat, "logAll") && strcmp(cat, "logStatusError") && strcmp(cat, "logCalls")))
            return error(f, "fmi2SetDebugLogging: unknown log category '%s'", cat ? cat : "(null)");
    }
    f->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)visible;
    (void)fmuResourceLocation;
    if (!functions) return NULL;
    const char *nm = instanceName ? instanceName : "(null)";
    if (!functions->allocateMemory || !functions->freeMemory) {
        emit(functions, nm, "fmi2Instantiate: the callbacks allocateMemory and freeMemory must be given");
        return NULL;
    }
    if (!instanceName || !*instanceName) {
        emit(functions, nm, "fmi2Instantiate: instanceName must be a non-empty string");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        emit(functions, nm, "fmi2Instantiate: this FMU supports co-simulation only (fmuType = %d)", (int)fmuType);
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, MAGLEV_PID_GUID) != 0) {
        emit(functions, nm, "fmi2Instantiate: GUID %s does not match %s", fmuGUID ? fmuGUID : "(null)",
             MAGLEV_PID_GUID);
        return NULL;
    }
    Fmu *f = functions->allocateMemory(1, sizeof *f);
    if (!f) {
        emit(functions, nm, "fmi2Instantiate: out of memory (allocateMemory returned NULL)");
        return NULL;
    }
    memset(f, 0, sizeof *f);
    snprintf(f->name, sizeof f->name, "%s", instanceName);
    f->cb = *functions;
    f->logging = loggingOn ? 1 : 0;
    defaults(&f->core);
    f->state = Instantiated;
    return f;
}

static void snapshot_free(Fmu *f, Snapshot *s) {
    if (s->prev) s->prev->next = s->next; else f->snapshots = s->next;
    if (s->next) s->next->prev = s->prev;
    f->cb.freeMemory(s);
}

void fmi2FreeInstance(fmi2Component c) {
    Fmu *f = c;
    if (!f) return;
    while (f->snapshots) snapshot_free(f, f->snapshots);
    f->state = StartAndEnd;
    f->cb.freeMemory(f);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    GUARD("fmi2SetupExperiment", Instantiated);
    Fmu *f = c;
    if (toleranceDefined && (!isfinite(tolerance) || tolerance <= 0))
        return error(f, "fmi2SetupExperiment: tolerance %g must be > 0 and finite", tolerance);
    if (!(fabs(startTime) <= MAGLEV_TIME_MAX))
        return error(f, "fmi2SetupExperiment: startTime %g must be finite and within +-%g s", startTime, MAGLEV_TIME_MAX);
    if (stopTimeDefined && !(stopTime >= startTime && stopTime <= MAGLEV_TIME_MAX))
        return error(f, "fmi2SetupExperiment: stopTime %g must be >= startTime %g and <= %g s", stopTime, startTime,
                     MAGLEV_TIME_MAX);
    f->core.t0 = f->core.time = startTime;
    f->stop_defined = stopTimeDefined ? 1 : 0;
    f->stop_time = stopTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    GUARD("fmi2EnterInitializationMode", Instantiated);
    ((Fmu *)c)->state = InitializationMode;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    GUARD("fmi2ExitInitializationMode", InitializationMode);
    Fmu *f = c;
    char msg[256];
    if (check_all(&f->core, msg, sizeof msg)) return error(f, "fmi2ExitInitializationMode: %s", msg);
    start(&f->core, f->core.t0);
    f->state = StepComplete;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    GUARD("fmi2Terminate", StepComplete | StepFailed);
    ((Fmu *)c)->state = Terminated;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    GUARD("fmi2Reset", ANY_LIVE);
    Fmu *f = c;
    defaults(&f->core);
    f->stop_defined = 0;
    f->stop_time = 0;
    f->state = Instantiated;
    return fmi2OK;
}

static int check_vrs(Fmu *f, const char *fn, const fmi2ValueReference vr[], size_t nvr, const void *value) {
    if (nvr == 0) return 1;
    if (!vr || !value) {
        error(f, "%s: vr or value array is NULL", fn);
        return 0;
    }
    for (size_t k = 0; k < nvr; k++)
        if (vr[k] >= MAGLEV_PID_NVARS) {
            error(f, "%s: unknown value reference %u", fn, (unsigned)vr[k]);
            return 0;
        }
    return 1;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    GUARD("fmi2GetReal", MASK_GET);
    Fmu *f = c;
    if (!check_vrs(f, "fmi2GetReal", vr, nvr, value)) return fmi2Error;
    /* before initialisation ends, the outputs are those of the settled start */
    Core view = f->core;
    if (!view.initialized) start(&view, view.t0);
    for (size_t k = 0; k < nvr; k++) {
        value[k] = view.v[vr[k]];
        if (!isfinite(value[k]))
            return error(f, "fmi2GetReal: variable %s is not finite (%g)", maglev_pid_variables[vr[k]].name, value[k]);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    GUARD("fmi2SetReal", MASK_SET);
    Fmu *f = c;
    char msg[256];
    if (!check_vrs(f, "fmi2SetReal", vr, nvr, value)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) { /* validate everything first: a rejected call changes nothing */
        const MaglevVariable *var = &maglev_pid_variables[vr[k]];
        if (var->causality == MAGLEV_OUTPUT)
            return error(f, "fmi2SetReal: variable %s is an output and cannot be set", var->name);
        if (var->causality == MAGLEV_PARAMETER && f->state == StepComplete)
            return error(f, "fmi2SetReal: variable %s is a fixed parameter, settable only before "
                         "fmi2ExitInitializationMode", var->name);
        if (check_value(vr[k], value[k], msg, sizeof msg)) return error(f, "fmi2SetReal: %s", msg);
    }
    for (size_t k = 0; k < nvr; k++) f->core.v[vr[k]] = value[k];
    return fmi2OK;
}

static fmi2Status no_such_type(fmi2Component c, const char *fn, int mask, size_t nvr, const fmi2ValueReference vr[]) {
    GUARD(fn, mask);
    if (nvr == 0) return fmi2OK;
    return error((Fmu *)c, "%s: the FMU has no variable of this type (value reference %u)", fn,
                 vr ? (unsigned)vr[0] : 0u);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)value;
    return no_such_type(c, "fmi2GetInteger", MASK_GET, nvr, vr);
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)value;
    return no_such_type(c, "fmi2GetBoolean", MASK_GET, nvr, vr);
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)value;
    return no_such_type(c, "fmi2GetString", MASK_GET, nvr, vr);
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    (void)value;
    return no_such_type(c, "fmi2SetInteger", MASK_SET, nvr, vr);
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    (void)value;
    return no_such_type(c, "fmi2SetBoolean", MASK_SET, nvr, vr);
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)value;
    return no_such_type(c, "fmi2SetString", MASK_SET, nvr, vr);
}

/* ---- FMU state: owned by the instance that made it (a foreign or stale pointer is refused) ---- */

static Snapshot *owned(Fmu *f, const char *fn, fmi2FMUstate state) {
    for (Snapshot *s = f->snapshots; s; s = s->next)
        if (s == state) return s;
    error(f, "%s: FMUstate %p was not made by this instance or was freed", fn, state);
    return NULL;
}

static Snapshot *snapshot_new(Fmu *f) {
    Snapshot *s = f->cb.allocateMemory(1, sizeof *s);
    if (!s) return NULL;
    memset(s, 0, sizeof *s);
    s->next = f->snapshots;
    if (s->next) s->next->prev = s;
    f->snapshots = s;
    return s;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    GUARD("fmi2GetFMUstate", ANY_LIVE);
    Fmu *f = c;
    if (!FMUstate) return error(f, "fmi2GetFMUstate: FMUstate pointer is NULL");
    Snapshot *s = *FMUstate ? owned(f, "fmi2GetFMUstate", *FMUstate) : snapshot_new(f);
    if (!s) return *FMUstate ? fmi2Error : error(f, "fmi2GetFMUstate: out of memory");
    s->core = f->core;
    s->state = f->state;
    *FMUstate = s;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    GUARD("fmi2SetFMUstate", ANY_LIVE);
    Fmu *f = c;
    if (!FMUstate) return error(f, "fmi2SetFMUstate: FMUstate is NULL");
    const Snapshot *s = owned(f, "fmi2SetFMUstate", FMUstate);
    if (!s) return fmi2Error;
    f->core = s->core;
    f->state = s->state;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    GUARD("fmi2FreeFMUstate", ANY_LIVE);
    Fmu *f = c;
    if (!FMUstate) return error(f, "fmi2FreeFMUstate: FMUstate pointer is NULL");
    if (!*FMUstate) return fmi2OK;
    Snapshot *s = owned(f, "fmi2FreeFMUstate", *FMUstate);
    if (!s) return fmi2Error;
    snapshot_free(f, s);
    *FMUstate = NULL;
    return fmi2OK;
}

/* Serialised form: magic, FMU state code, the core's numbers (little or big endian as the machine
 * has them: a state moves between instances of one build), a 64-bit FNV-1a checksum of it all. */
#define MAGIC "MGPID\001\000\000"
#define NUMS (MAGLEV_PID_NVARS + 3 + 3 + 1)
#define SER_SIZE (8 + 8 + NUMS * 8 + 8)

static uint64_t fnv1a(const unsigned char *p, size_t n) {
    uint64_t h = 1469598103934665603ULL;
    for (size_t k = 0; k < n; k++) h = (h ^ p[k]) * 1099511628211ULL;
    return h;
}

static void core_numbers(const Core *c, double out[NUMS]) {
    memcpy(out, c->v, sizeof c->v);
    double *o = out + MAGLEV_PID_NVARS;
    o[0] = c->s.integral; o[1] = c->s.e_prev; o[2] = c->s.d_prev;
    o[3] = c->t0; o[4] = c->time; o[5] = c->k; o[6] = c->initialized;
}

static int state_code(FmuState s) {
    for (int k = 0; k < 7; k++)
        if ((int)s == 1 << k) return k;
    return -1;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    GUARD("fmi2SerializedFMUstateSize", ANY_LIVE);
    Fmu *f = c;
    if (!FMUstate || !size) return error(f, "fmi2SerializedFMUstateSize: FMUstate or size is NULL");
    if (!owned(f, "fmi2SerializedFMUstateSize", FMUstate)) return fmi2Error;
    *size = SER_SIZE;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    GUARD("fmi2SerializeFMUstate", ANY_LIVE);
    Fmu *f = c;
    if (!FMUstate || !serializedState) return error(f, "fmi2SerializeFMUstate: FMUstate or buffer is NULL");
    const Snapshot *s = owned(f, "fmi2SerializeFMUstate", FMUstate);
    if (!s) return fmi2Error;
    if (size < SER_SIZE) return error(f, "fmi2SerializeFMUstate: buffer of %zu bytes, %d needed", size, SER_SIZE);
    unsigned char *b = (unsigned char *)serializedState;
    double nums[NUMS];
    uint64_t code = (uint64_t)state_code(s->state);
    core_numbers(&s->core, nums);
    memcpy(b, MAGIC, 8);
    memcpy(b + 8, &code, 8);
    memcpy(b + 16, nums, sizeof nums);
    uint64_t h = fnv1a(b, SER_SIZE - 8);
    memcpy(b + SER_SIZE - 8, &h, 8);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    GUARD("fmi2DeSerializeFMUstate", ANY_LIVE);
    Fmu *f = c;
    char msg[256];
    if (!serializedState || !FMUstate) return error(f, "fmi2DeSerializeFMUstate: NULL buffer or FMUstate pointer");
    if (*FMUstate && !owned(f, "fmi2DeSerializeFMUstate", *FMUstate)) return fmi2Error;
    const unsigned char *b = (const unsigned char *)serializedState;
    uint64_t code, h;
    if (size != SER_SIZE) return error(f, "fmi2DeSerializeFMUstate: %zu bytes, a state has %d", size, SER_SIZE);
    memcpy(&h, b + SER_SIZE - 8, 8);
    if (memcmp(b, MAGIC, 8) != 0 || fnv1a(b, SER_SIZE - 8) != h)
        return error(f, "fmi2DeSerializeFMUstate: not a state of this FMU, or corrupted (magic or checksum)");
    memcpy(&code, b + 8, 8);
    double nums[NUMS];
    memcpy(nums, b + 16, sizeof nums);
    Core core;
    memset(&core, 0, sizeof core);
    memcpy(core.v, nums, sizeof core.v);
    const double *o = nums + MAGLEV_PID_NVARS;
    core.s.integral = o[0]; core.s.e_prev = o[1]; core.s.d_prev = o[2];
    core.t0 = o[3]; core.time = o[4]; core.k = o[5];
    FmuState st = code >= 1 && code <= 6 ? (FmuState)(1 << code) : StartAndEnd;
    int init = st & (StepComplete | StepFailed | Terminated | Error);
    for (int k = 0; k < NUMS; k++)
        if (!isfinite(nums[k])) return error(f, "fmi2DeSerializeFMUstate: value %d of the state is not finite", k);
    if (st == StartAndEnd || o[6] != (init ? 1.0 : 0.0) || !(core.k >= 0) || core.k != floor(core.k) ||
        fabs(core.time) > MAGLEV_TIME_MAX || fabs(core.t0) > MAGLEV_TIME_MAX)
        return error(f, "fmi2DeSerializeFMUstate: FMU state code %u does not fit the controller's state", (unsigned)code);
    core.initialized = init ? 1 : 0;
    if (check_all(&core, msg, sizeof msg)) return error(f, "fmi2DeSerializeFMUstate: %s", msg);
    Snapshot *s = *FMUstate ? (Snapshot *)*FMUstate : snapshot_new(f);
    if (!s) return error(f, "fmi2DeSerializeFMUstate: out of memory");
    s->core = core;
    s->state = st;
    *FMUstate = s;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    GUARD("fmi2GetDirectionalDerivative", MASK_GET);
    return error((Fmu *)c, "fmi2GetDirectionalDerivative: not provided (providesDirectionalDerivative=false)");
}

/* ---- co-simulation ---- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)order; (void)value;
    GUARD("fmi2SetRealInputDerivatives", MASK_SET);
    if (nvr == 0) return fmi2OK;
    return error((Fmu *)c, "fmi2SetRealInputDerivatives: not supported (canInterpolateInputs=false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)order; (void)value;
    GUARD("fmi2GetRealOutputDerivatives", StepComplete | StepFailed | Terminated | Error);
    if (nvr == 0) return fmi2OK;
    return error((Fmu *)c, "fmi2GetRealOutputDerivatives: not supported (maxOutputDerivativeOrder=0)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    GUARD("fmi2DoStep", StepComplete);
    Fmu *f = c;
    Core *core = &f->core;
    double t = core->time, h = communicationStepSize, ts = core->v[PID_ts];
    if (!isfinite(currentCommunicationPoint))
        return error(f, "fmi2DoStep: currentCommunicationPoint %g is not finite", currentCommunicationPoint);
    if (!isfinite(h) || h <= 0) return error(f, "fmi2DoStep: communicationStepSize %g must be > 0 and finite", h);
    if (fabs(currentCommunicationPoint - t) > 1e-9 * (1.0 + fabs(t)))
        return error(f, "fmi2DoStep: currentCommunicationPoint %.17g does not match the FMU time %.17g",
                     currentCommunicationPoint, t);
    double end = currentCommunicationPoint + h;
    if (fabs(end) > MAGLEV_TIME_MAX) return error(f, "fmi2DoStep: a step to %.17g s leaves the time range", end);
    if (f->stop_defined && end > f->stop_time * (1 + 1e-12) + 1e-12)
        return error(f, "fmi2DoStep: step to %.17g goes past stopTime %.17g", end, f->stop_time);
    /* the samples t_k in [t, end): counted first, so one call's work is bounded */
    double last = ceil((end - core->t0) / ts - 1e-9) - 1.0; /* index of the last sample before end */
    if (last - core->k + 1.0 > MAX_SAMPLES_PER_STEP)
        return error(f, "fmi2DoStep: communicationStepSize %g s holds more than %g samples of ts = %g s", h,
                     MAX_SAMPLES_PER_STEP, ts);
    MaglevPid pid = settings(core);
    Core next = *core;
    for (; next.k <= last; next.k += 1.0) {
        double tk = next.t0 + next.k * ts;
        next.v[PID_w] = reference(&next, tk);
        next.v[PID_u] = maglev_pid_step(&pid, &next.s, next.v[PID_w], next.v[PID_y]);
        if (!isfinite(next.v[PID_u]) || !isfinite(next.s.integral) || !isfinite(next.s.d_prev)) {
            f->state = Error; /* the values are those before the step */
            return error(f, "fmi2DoStep: variable u is not finite at t = %.17g s (integrator %g)", tk, next.s.integral);
        }
    }
    next.time = end;
    *core = next;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    GUARD("fmi2CancelStep", 0);
    return fmi2Error;
}

#define MASK_STATUS (StepComplete | StepFailed | Terminated)

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    GUARD("fmi2GetStatus", MASK_STATUS);
    Fmu *f = c;
    if (!value) return error(f, "fmi2GetStatus: value is NULL");
    if (s != fmi2DoStepStatus) return error(f, "fmi2GetStatus: status kind %d not available", (int)s);
    *value = fmi2OK;
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    GUARD("fmi2GetRealStatus", MASK_STATUS);
    Fmu *f = c;
    if (!value) return error(f, "fmi2GetRealStatus: value is NULL");
    if (s != fmi2LastSuccessfulTime) return error(f, "fmi2GetRealStatus: status kind %d not available", (int)s);
    *value = f->core.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    GUARD("fmi2GetIntegerStatus", MASK_STATUS);
    return error((Fmu *)c, "fmi2GetIntegerStatus: no integer status is available");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    GUARD("fmi2GetBooleanStatus", MASK_STATUS);
    Fmu *f = c;
    if (!value) return error(f, "fmi2GetBooleanStatus: value is NULL");
    if (s != fmi2Terminated) return error(f, "fmi2GetBooleanStatus: status kind %d not available", (int)s);
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    GUARD("fmi2GetStringStatus", MASK_STATUS);
    Fmu *f = c;
    if (!value) return error(f, "fmi2GetStringStatus: value is NULL");
    if (s != fmi2PendingStatus) return error(f, "fmi2GetStringStatus: status kind %d not available", (int)s);
    *value = "";
    return fmi2OK;
}

/* ---- model exchange: not offered; present so every importer finds the symbols ---- */

static fmi2Status me_only(fmi2Component c, const char *fn) {
    GUARD(fn, ANY_LIVE);
    return error((Fmu *)c, "%s: this FMU is co-simulation only", fn);
}

#include "maglev_fmi2_me_stubs.h"
