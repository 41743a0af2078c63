/* Stateful fuzz test of the FMI 2.0 layer (issue 10): random call sequences with hostile values,
 * several interleaved instances, FMU states saved, serialized, corrupted and restored.
 *
 *   fuzz_fmu [--seeds A:B] [--random N] [--seconds S] [--quiet]
 *
 * Each seed is one sequence, fully determined by the seed (replay a failure with --seeds X:X+1).
 * Slot 0 and slot 1 are twins: every call on slot 0 is repeated on slot 1 with the same
 * arguments, and the two must answer alike to the bit while slots 2 and 3 get calls of their
 * own: a check that instances share nothing. Checks, each a counted failure naming seed and call:
 *   - every status is a legal fmi2Status, every call returns within CALL_BOUND seconds;
 *   - GetReal never returns a non-finite value with fmi2OK or fmi2Warning;
 *   - every fmi2Error or fmi2Fatal is logged during its call;
 *   - every buffer the FMU serialized deserializes again, and GetFMUstate, serialize,
 *     deserialize, SetFMUstate reproduces every variable to the bit;
 *   - the twins agree; no memory is left allocated once every instance is freed.
 * Run under ASan + UBSan (-fsanitize=address,undefined,float-cast-overflow) by ctest. */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"
#include "maglev_plant.h"

#define GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"
#define SLOTS 4
#define STATES 4
#define CALL_BOUND 2.0 /* [s] per call, under sanitizers */

/* ---- deterministic randomness: splitmix64 ---- */
typedef struct { uint64_t s; } Rng;
static uint64_t next(Rng *r) {
    uint64_t z = (r->s += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}
static int below(Rng *r, int n) { return (int)(next(r) % (uint64_t)n); }
static double unit(Rng *r) { return (double)(next(r) >> 11) / 9007199254740992.0; }

/* ---- counting allocator and logger ---- */
static long live_allocations = 0;
static long log_calls = 0;
static void *count_alloc(size_t n, size_t size) {
    void *p = calloc(n ? n : 1, size ? size : 1);
    if (p) live_allocations++;
    return p;
}
static void count_free(void *p) {
    if (p) live_allocations--;
    free(p);
}
static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String fmt, ...) {
    (void)env; (void)name; (void)status; (void)category; (void)fmt;
    log_calls++;
}
static const fmi2CallbackFunctions callbacks = {logger, count_alloc, count_free, NULL, NULL};

/* ---- bookkeeping ---- */
enum { K_INSTANTIATE, K_BAD_INSTANTIATE, K_SETUP, K_ENTER, K_EXIT, K_SETREAL, K_GETREAL, K_OTHER_TYPES, K_DOSTEP,
       K_CANCEL, K_STATUS, K_TERMINATE, K_RESET, K_FREE, K_GETSTATE, K_SETSTATE, K_FREESTATE, K_SERIALIZE,
       K_CORRUPT, K_ROUNDTRIP, K_DERIVATIVES, K_ME_ONLY, NKINDS };
static const char *kind_name[NKINDS] = {
    "Instantiate", "Instantiate (bad)", "SetupExperiment", "EnterInitializationMode", "ExitInitializationMode",
    "SetReal", "GetReal", "Get/Set Integer/Boolean/String", "DoStep", "CancelStep", "Get*Status", "Terminate",
    "Reset", "FreeInstance", "GetFMUstate", "SetFMUstate", "FreeFMUstate", "Serialize+DeSerialize",
    "DeSerialize corrupted", "state round trip", "directional/input derivatives", "ModelExchange-only calls"};
static const int weight[NKINDS] = {4, 1, 4, 4, 4, 14, 10, 2, 16, 1, 2, 2, 2, 1, 4, 3, 2, 3, 3, 2, 1, 1};

enum { V_DEFAULT, V_RANGE, V_MIN, V_MAX, V_BEYOND, V_ZERO, V_NEG, V_HUGE, V_INF, V_NAN, V_DENORMAL, V_UNIT_SLIP,
       NVCLASSES };
static const char *vclass_name[NVCLASSES] = {"default", "in range", "min", "max", "just outside", "0", "negated",
                                             "+-1e308", "+-Inf", "NaN", "denormal", "unit slip x1e3/x1e-3"};

typedef struct {
    long calls, failures, sequences;
    long per_kind[NKINDS];
    long per_status[6];
    long per_vclass[NVCLASSES];
    double slowest[NKINDS];
    int quiet;
} Stats;
static Stats st;

typedef struct {
    fmi2Component c;
    fmi2FMUstate states[STATES];
    double time; /* the communication point we believe the instance is at */
    int phase;   /* what we believe: 1 instantiated, 2 initialising, 3 stepping, 4 terminated or failed */
} Slot;

static uint64_t cur_seed;
static long cur_call;

static void fail(const char *fmt, ...) {
    st.failures++;
    if (st.failures > 50) return;
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "FAIL seed %llu call %ld: ", (unsigned long long)cur_seed, cur_call);
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
}

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Every status: legal, logged when an error, within the time bound. */
static fmi2Status seen(int kind, fmi2Status s, long logs_before, double t0, int slot) {
    double dt = now() - t0;
    st.calls++;
    st.per_kind[kind]++;
    if (dt > st.slowest[kind]) st.slowest[kind] = dt;
    if (dt > CALL_BOUND) fail("%s on slot %d took %.2f s", kind_name[kind], slot, dt);
    if ((int)s < 0 || (int)s > 5) {
        fail("%s on slot %d returned status %d", kind_name[kind], slot, (int)s);
        return s;
    }
    st.per_status[s]++;
    if ((s == fmi2Error || s == fmi2Fatal) && log_calls == logs_before)
        fail("%s on slot %d returned %d without a logged message", kind_name[kind], slot, (int)s);
    return s;
}

static double hostile(Rng *r, fmi2ValueReference vr, int *vclass) {
    const MaglevVariable *v = vr < MAGLEV_NVARS ? &maglev_variables[vr] : NULL;
    double def = v ? v->start : 1.0, lo = v && isfinite(v->min) ? v->min : -10.0,
           hi = v && isfinite(v->max) ? v->max : 10.0;
    int c = below(r, NVCLASSES);
    /* most values are plausible, so that sequences get deep into stepping */
    if (below(r, 3) == 0) c = below(r, 2) ? V_DEFAULT : V_RANGE;
    *vclass = c;
    st.per_vclass[c]++;
    switch (c) {
    case V_DEFAULT: return def;
    case V_RANGE: return lo + (hi - lo) * unit(r);
    case V_MIN: return lo;
    case V_MAX: return hi;
    case V_BEYOND: return below(r, 2) ? nextafter(lo, -INFINITY) - fabs(lo) * 1e-9 : nextafter(hi, INFINITY) + fabs(hi) * 1e-9;
    case V_ZERO: return 0.0;
    case V_NEG: return -(def != 0 ? def : 1.0);
    case V_HUGE: return below(r, 2) ? 1e308 : -1e308;
    case V_INF: return below(r, 2) ? INFINITY : -INFINITY;
    case V_NAN: return NAN;
    case V_DENORMAL: return 4.9e-324 * (double)(1 + below(r, 1000));
    default: return def * (below(r, 2) ? 1e3 : 1e-3);
    }
}

static double step_size(Rng *r) {
    switch (below(r, 10)) {
    case 0: return 0.0;
    case 1: return -1e-3;
    case 2: return NAN;
    case 3: return below(r, 2) ? 1e20 : 1e6;
    case 4: return 1e-9 * (1 + below(r, 100));
    case 5: return 0.1 + unit(r);
    default: return 1e-4 + 1e-2 * unit(r);
    }
}

static int bit_equal(double a, double b) { return memcmp(&a, &b, sizeof a) == 0; }

/* GetReal of every variable; checks no non-finite value comes with OK. Returns the status. */
static fmi2Status get_all(Slot *s, int slot, double out[MAGLEV_NVARS]) {
    fmi2ValueReference vr[MAGLEV_NVARS];
    for (int k = 0; k < MAGLEV_NVARS; k++) vr[k] = (fmi2ValueReference)k;
    long lb = log_calls;
    double t0 = now();
    fmi2Status rc = seen(K_GETREAL, fmi2GetReal(s->c, vr, MAGLEV_NVARS, out), lb, t0, slot);
    if (rc == fmi2OK || rc == fmi2Warning)
        for (int k = 0; k < MAGLEV_NVARS; k++)
            if (!isfinite(out[k])) fail("GetReal(%s) = %g with status %d", maglev_variables[k].name, out[k], (int)rc);
    return rc;
}

/* One random call on a slot. Returns a code of what was called and its status, for the twin check
 * (the twin gets the same call from a generator copied before it). */
typedef struct { int kind; fmi2Status status; double values[8]; int nvalues; } Outcome;

static void call(Rng *r, Slot *slots, int si, Outcome *o) {
    Slot *s = &slots[si];
    int total = 0;
    for (int k = 0; k < NKINDS; k++) total += weight[k];
    int pick = below(r, total), kind = 0;
    while (pick >= weight[kind]) pick -= weight[kind++];
    /* half the calls follow the life cycle, so that sequences get deep into stepping */
    if (s->c && below(r, 2)) {
        static const int by_phase[5][4] = {{K_SETUP, K_ENTER, K_SETREAL, K_ENTER},
                                           {K_SETUP, K_ENTER, K_SETREAL, K_ENTER},
                                           {K_EXIT, K_SETREAL, K_EXIT, K_GETREAL},
                                           {K_DOSTEP, K_DOSTEP, K_SETREAL, K_GETREAL},
                                           {K_RESET, K_RESET, K_GETREAL, K_FREE}};
        kind = by_phase[s->phase < 5 ? s->phase : 4][below(r, 4)];
    }
    if (!s->c && kind != K_BAD_INSTANTIATE) kind = K_INSTANTIATE;
    if (s->c && kind == K_INSTANTIATE) kind = K_SETREAL;
    o->kind = kind;
    o->status = fmi2OK;
    o->nvalues = 0;
    long lb = log_calls;
    double t0 = now();
    char name[32];
    snprintf(name, sizeof name, "fuzz%d", si);
    switch (kind) {
    case K_INSTANTIATE:
        s->c = fmi2Instantiate(name, fmi2CoSimulation, GUID, NULL, &callbacks, fmi2False, fmi2True);
        seen(kind, s->c ? fmi2OK : fmi2Error, lb, t0, si);
        s->time = 0.0;
        s->phase = 1;
        memset(s->states, 0, sizeof s->states);
        if (!s->c) fail("Instantiate with valid arguments failed");
        o->status = s->c ? fmi2OK : fmi2Error;
        break;
    case K_BAD_INSTANTIATE: {
        int which = below(r, 4);
        fmi2Component c = fmi2Instantiate(which == 0 ? "" : name, which == 1 ? fmi2ModelExchange : fmi2CoSimulation,
                                          which == 2 ? "{not-the-guid}" : (which == 3 ? NULL : GUID), NULL,
                                          &callbacks, fmi2False, fmi2True);
        seen(kind, c ? fmi2OK : fmi2Error, lb, t0, si);
        if (c) {
            fail("Instantiate with a bad argument (%d) returned an instance", which);
            fmi2FreeInstance(c);
        }
        o->status = c ? fmi2OK : fmi2Error;
        break;
    }
    case K_SETUP: {
        double start = below(r, 4) ? 0.0 : (below(r, 2) ? NAN : 1e12 * unit(r) - 5e11);
        double stop = below(r, 2) ? start + 10 : (below(r, 2) ? start - 1 : INFINITY);
        o->status = seen(kind, fmi2SetupExperiment(s->c, below(r, 2), below(r, 3) ? 1e-6 : NAN, start, below(r, 2), stop),
                         lb, t0, si);
        if (o->status == fmi2OK) s->time = start;
        break;
    }
    case K_ENTER:
        o->status = seen(kind, fmi2EnterInitializationMode(s->c), lb, t0, si);
        if (o->status == fmi2OK) s->phase = 2;
        break;
    case K_EXIT:
        o->status = seen(kind, fmi2ExitInitializationMode(s->c), lb, t0, si);
        s->phase = o->status == fmi2OK ? 3 : (s->phase == 2 ? 2 : s->phase);
        break;
    case K_SETREAL: {
        int n = 1 + below(r, 3), vc;
        fmi2ValueReference vr[3];
        double val[3];
        for (int k = 0; k < n; k++) {
            vr[k] = (fmi2ValueReference)(below(r, 20) ? below(r, MAGLEV_NVARS) : MAGLEV_NVARS + below(r, 5));
            val[k] = hostile(r, vr[k], &vc);
        }
        if (s->phase == 3 && below(r, 2)) { /* the controller's output, as a master would set it */
            n = 1;
            vr[0] = VR_u;
            val[0] = 0.2 + 0.3 * unit(r);
        }
        lb = log_calls;
        t0 = now();
        o->status = seen(kind, fmi2SetReal(s->c, vr, (size_t)n, val), lb, t0, si);
        break;
    }
    case K_GETREAL: {
        int n = 1 + below(r, 4);
        fmi2ValueReference vr[4];
        double val[4] = {0};
        for (int k = 0; k < n; k++)
            vr[k] = (fmi2ValueReference)(below(r, 25) ? below(r, MAGLEV_NVARS) : MAGLEV_NVARS + below(r, 5));
        o->status = seen(kind, fmi2GetReal(s->c, vr, (size_t)n, val), lb, t0, si);
        if (o->status == fmi2OK || o->status == fmi2Warning)
            for (int k = 0; k < n; k++) {
                if (!isfinite(val[k])) fail("GetReal(vr %u) = %g with status %d", vr[k], val[k], (int)o->status);
                o->values[o->nvalues++] = val[k];
            }
        break;
    }
    case K_OTHER_TYPES: {
        fmi2ValueReference vr = (fmi2ValueReference)below(r, MAGLEV_NVARS);
        fmi2Integer iv = 3;
        fmi2Boolean bv = fmi2True;
        fmi2String sv = "x";
        switch (below(r, 6)) {
        case 0: o->status = fmi2GetInteger(s->c, &vr, 1, &iv); break;
        case 1: o->status = fmi2GetBoolean(s->c, &vr, 1, &bv); break;
        case 2: o->status = fmi2GetString(s->c, &vr, 1, &sv); break;
        case 3: o->status = fmi2SetInteger(s->c, &vr, 1, &iv); break;
        case 4: o->status = fmi2SetBoolean(s->c, &vr, 1, &bv); break;
        default: o->status = fmi2SetString(s->c, &vr, 1, &sv); break;
        }
        seen(kind, o->status, lb, t0, si);
        if (o->status == fmi2OK) fail("a non-Real variable access succeeded (vr %u)", vr);
        break;
    }
    case K_DOSTEP: {
        double h = step_size(r);
        double at = below(r, 8) ? s->time : s->time + (below(r, 2) ? 1e-3 : -1.0);
        if (s->phase == 3 && below(r, 2)) { /* a plausible step from where the instance is */
            at = s->time;
            h = 1e-4 + 2e-3 * unit(r);
        }
        o->status = seen(kind, fmi2DoStep(s->c, at, h, below(r, 2)), lb, t0, si);
        if (o->status == fmi2OK) s->time = at + h;
        if (o->status == fmi2Error && s->phase == 3) s->phase = 4;
        break;
    }
    case K_CANCEL: o->status = seen(kind, fmi2CancelStep(s->c), lb, t0, si); break;
    case K_STATUS: {
        fmi2Status sv;
        fmi2Real rv;
        fmi2Integer iv;
        fmi2Boolean bv;
        fmi2String strv;
        fmi2StatusKind sk = (fmi2StatusKind)below(r, 4);
        switch (below(r, 5)) {
        case 0: o->status = fmi2GetStatus(s->c, sk, &sv); break;
        case 1:
            o->status = fmi2GetRealStatus(s->c, sk, &rv);
            if (o->status == fmi2OK && !isfinite(rv)) fail("GetRealStatus = %g with OK", rv);
            break;
        case 2: o->status = fmi2GetIntegerStatus(s->c, sk, &iv); break;
        case 3: o->status = fmi2GetBooleanStatus(s->c, sk, &bv); break;
        default: o->status = fmi2GetStringStatus(s->c, sk, &strv); break;
        }
        seen(kind, o->status, lb, t0, si);
        break;
    }
    case K_TERMINATE:
        o->status = seen(kind, fmi2Terminate(s->c), lb, t0, si);
        if (o->status == fmi2OK) s->phase = 4;
        break;
    case K_RESET:
        o->status = seen(kind, fmi2Reset(s->c), lb, t0, si);
        if (o->status == fmi2OK) {
            s->time = 0.0;
            s->phase = 1;
        }
        break;
    case K_FREE:
        /* the standard lets FreeInstance free what the instance still holds: its FMU states */
        fmi2FreeInstance(s->c);
        seen(kind, fmi2OK, lb, t0, si);
        s->c = NULL;
        memset(s->states, 0, sizeof s->states);
        break;
    case K_GETSTATE: {
        int k = below(r, STATES);
        o->status = seen(kind, fmi2GetFMUstate(s->c, &s->states[k]), lb, t0, si);
        break;
    }
    case K_SETSTATE: {
        /* one of this instance's states, or another instance's (which must be refused) */
        int other = below(r, 6) == 0;
        Slot *from = other ? &slots[si < 2 ? 2 : 5 - si] : s; /* the twins share their foreign slot */
        fmi2FMUstate fs = from->c ? from->states[below(r, STATES)] : NULL;
        o->status = seen(kind, fmi2SetFMUstate(s->c, fs), lb, t0, si);
        if (other && fs && o->status == fmi2OK) fail("SetFMUstate accepted another instance's state");
        break;
    }
    case K_FREESTATE: {
        int k = below(r, STATES);
        o->status = seen(kind, fmi2FreeFMUstate(s->c, &s->states[k]), lb, t0, si);
        break;
    }
    case K_SERIALIZE: {
        fmi2FMUstate fs = s->states[below(r, STATES)];
        size_t size = 0;
        o->status = seen(kind, fmi2SerializedFMUstateSize(s->c, fs, &size), lb, t0, si);
        if (o->status != fmi2OK) break;
        if (size == 0 || size > 1u << 26) {
            fail("serialized size %zu", size);
            break;
        }
        fmi2Byte *buf = malloc(size);
        lb = log_calls;
        t0 = now();
        o->status = seen(kind, fmi2SerializeFMUstate(s->c, fs, buf, size), lb, t0, si);
        if (o->status == fmi2OK) {
            fmi2FMUstate back = NULL;
            lb = log_calls;
            t0 = now();
            fmi2Status d = seen(kind, fmi2DeSerializeFMUstate(s->c, buf, size, &back), lb, t0, si);
            if (d != fmi2OK) fail("a state the FMU serialized does not deserialize (status %d)", (int)d);
            if (back) {
                lb = log_calls;
                t0 = now();
                seen(K_FREESTATE, fmi2FreeFMUstate(s->c, &back), lb, t0, si);
            }
        }
        free(buf);
        break;
    }
    case K_CORRUPT: {
        fmi2FMUstate fs = s->states[below(r, STATES)];
        size_t size = 0;
        o->status = seen(kind, fmi2SerializedFMUstateSize(s->c, fs, &size), lb, t0, si);
        if (o->status != fmi2OK || size == 0) break;
        size_t cap = size + 64;
        fmi2Byte *buf = calloc(cap, 1);
        fmi2SerializeFMUstate(s->c, fs, buf, size);
        size_t use = size;
        switch (below(r, 4)) {
        case 0: buf[below(r, (int)size)] ^= (fmi2Byte)(1u << below(r, 8)); break;
        case 1: use = (size_t)below(r, (int)size); break;
        case 2: use = size + 1 + (size_t)below(r, 63); break;
        default:
            for (size_t k = 0; k < size; k++) buf[k] = (fmi2Byte)next(r);
            break;
        }
        fmi2FMUstate back = NULL;
        lb = log_calls;
        t0 = now();
        o->status = seen(kind, fmi2DeSerializeFMUstate(s->c, buf, use, &back), lb, t0, si);
        if (back) {
            /* accepted (a flip the checksum cannot see is possible only in theory): it must be usable */
            double out[MAGLEV_NVARS];
            if (fmi2SetFMUstate(s->c, back) == fmi2OK) get_all(s, si, out);
            fmi2FreeFMUstate(s->c, &back);
        }
        free(buf);
        break;
    }
    case K_ROUNDTRIP: {
        double before[MAGLEV_NVARS], after[MAGLEV_NVARS];
        fmi2Status g = get_all(s, si, before);
        fmi2FMUstate fs = NULL, back = NULL;
        lb = log_calls;
        t0 = now();
        o->status = seen(kind, fmi2GetFMUstate(s->c, &fs), lb, t0, si);
        if (o->status != fmi2OK) break;
        size_t size = 0;
        fmi2SerializedFMUstateSize(s->c, fs, &size);
        fmi2Byte *buf = malloc(size ? size : 1);
        if (fmi2SerializeFMUstate(s->c, fs, buf, size) != fmi2OK) fail("serializing a fresh state failed");
        /* disturb the instance, then restore it from the bytes */
        double junk = 0.123;
        fmi2ValueReference vr = VR_u;
        fmi2SetReal(s->c, &vr, 1, &junk);
        fmi2DoStep(s->c, s->time, 1e-3, fmi2True);
        lb = log_calls;
        t0 = now();
        fmi2Status d = seen(kind, fmi2DeSerializeFMUstate(s->c, buf, size, &back), lb, t0, si);
        if (d != fmi2OK) fail("round trip: deserializing the instance's own state failed (%d)", (int)d);
        else if (fmi2SetFMUstate(s->c, back) != fmi2OK) fail("round trip: SetFMUstate of it failed");
        else if (get_all(s, si, after) == g && (g == fmi2OK || g == fmi2Warning))
            for (int k = 0; k < MAGLEV_NVARS; k++)
                if (!bit_equal(before[k], after[k]))
                    fail("round trip changed %s: %.17g -> %.17g", maglev_variables[k].name, before[k], after[k]);
        fmi2FreeFMUstate(s->c, &back);
        fmi2FreeFMUstate(s->c, &fs);
        free(buf);
        break;
    }
    case K_DERIVATIVES: {
        fmi2ValueReference vr = VR_u, vy = VR_y;
        fmi2Integer order = 1;
        fmi2Real dv = 1.0, out = 0.0;
        switch (below(r, 3)) {
        case 0: o->status = fmi2GetDirectionalDerivative(s->c, &vy, 1, &vr, 1, &dv, &out); break;
        case 1: o->status = fmi2SetRealInputDerivatives(s->c, &vr, 1, &order, &dv); break;
        default: o->status = fmi2GetRealOutputDerivatives(s->c, &vy, 1, &order, &out); break;
        }
        seen(kind, o->status, lb, t0, si);
        if (o->status == fmi2OK && !isfinite(out)) fail("a derivative call returned %g with OK", out);
        break;
    }
    default: {
        fmi2Real x[4];
        switch (below(r, 4)) {
        case 0: o->status = fmi2EnterEventMode(s->c); break;
        case 1: o->status = fmi2SetTime(s->c, 1.0); break;
        case 2: o->status = fmi2GetContinuousStates(s->c, x, 4); break;
        default: o->status = fmi2EnterContinuousTimeMode(s->c); break;
        }
        seen(kind, o->status, lb, t0, si);
        if (o->status == fmi2OK) fail("a Model-Exchange-only call succeeded on a co-simulation FMU");
        break;
    }
    }
}

static void free_all(Slot *slots) {
    for (int k = 0; k < SLOTS; k++) {
        if (!slots[k].c) continue;
        fmi2FreeInstance(slots[k].c); /* frees the FMU states it still holds */
        slots[k].c = NULL;
    }
}

static void run_sequence(uint64_t seed) {
    Rng r = {seed};
    Slot slots[SLOTS];
    memset(slots, 0, sizeof slots);
    cur_seed = seed;
    long length = 40 + below(&r, 200);
    for (cur_call = 0; cur_call < length; cur_call++) {
        int si = below(&r, 3); /* 0: the twins, 1: slot 2, 2: slot 3 */
        if (si == 0) {
            Rng twin = r; /* the same call, the same values */
            Outcome a, b;
            call(&r, slots, 0, &a);
            call(&twin, slots, 1, &b);
            if (a.kind != b.kind || a.status != b.status || a.nvalues != b.nvalues)
                fail("the twins disagree on %s: status %d vs %d", kind_name[a.kind], (int)a.status, (int)b.status);
            else
                for (int k = 0; k < a.nvalues; k++)
                    if (!bit_equal(a.values[k], b.values[k]))
                        fail("the twins disagree on GetReal: %.17g vs %.17g", a.values[k], b.values[k]);
        } else {
            Outcome o;
            call(&r, slots, si + 1, &o);
        }
    }
    free_all(slots);
    if (live_allocations != 0) {
        fail("%ld allocations still live after every instance was freed", live_allocations);
        live_allocations = 0;
    }
    st.sequences++;
}

int main(int argc, char **argv) {
    uint64_t a = 0, b = 200;
    long random_seeds = 1;
    double seconds = 100.0;
    for (int k = 1; k < argc; k++) {
        if (!strcmp(argv[k], "--seeds") && k + 1 < argc) {
            unsigned long long x, y;
            if (sscanf(argv[++k], "%llu:%llu", &x, &y) != 2 || y <= x) {
                fprintf(stderr, "--seeds A:B with A < B\n");
                return 2;
            }
            a = x;
            b = y;
        } else if (!strcmp(argv[k], "--random") && k + 1 < argc) {
            random_seeds = atol(argv[++k]);
        } else if (!strcmp(argv[k], "--seconds") && k + 1 < argc) {
            seconds = atof(argv[++k]);
        } else if (!strcmp(argv[k], "--quiet")) {
            st.quiet = 1;
        } else {
            fprintf(stderr, "usage: fuzz_fmu [--seeds A:B] [--random N] [--seconds S] [--quiet]\n");
            return 2;
        }
    }
    double t0 = now();
    for (uint64_t seed = a; seed < b && now() - t0 < seconds; seed++) run_sequence(seed);
    uint64_t entropy = (uint64_t)time(NULL) ^ ((uint64_t)(now() * 1e9) << 20);
    for (long k = 0; k < random_seeds && now() - t0 < seconds; k++) {
        Rng e = {entropy + (uint64_t)k};
        uint64_t seed = next(&e);
        printf("random seed %llu (replay: fuzz_fmu --seeds %llu:%llu --random 0)\n", (unsigned long long)seed,
               (unsigned long long)seed, (unsigned long long)seed + 1);
        run_sequence(seed);
    }
    double dt = now() - t0;
    printf("%ld sequences, %ld calls in %.1f s (%.0f calls/s), %ld failures\n", st.sequences, st.calls, dt,
           (double)st.calls / dt, st.failures);
    if (!st.quiet) {
        const char *names[6] = {"OK", "Warning", "Discard", "Error", "Fatal", "Pending"};
        printf("statuses:");
        for (int k = 0; k < 6; k++) printf(" %s %ld", names[k], st.per_status[k]);
        printf("\n%-34s %10s %12s\n", "call kind", "calls", "slowest [s]");
        for (int k = 0; k < NKINDS; k++) printf("%-34s %10ld %12.4f\n", kind_name[k], st.per_kind[k], st.slowest[k]);
        printf("%-34s %10s\n", "SetReal value class", "values");
        for (int k = 0; k < NVCLASSES; k++) printf("%-34s %10ld\n", vclass_name[k], st.per_vclass[k]);
    }
    return st.failures ? 1 : 0;
}
