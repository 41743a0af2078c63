/* C tests of the FMI 2.0 layer: call sequences, bad arguments, several instances,
 * FMU state round trips. Run under ASan/UBSan in CI (MAGLEV_SANITIZE=ON). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "maglev_plant.h"

#define GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"

static int failures = 0, checks = 0;
static char last_log[1024];
static int n_logs = 0;

#define CHECK(cond, ...)                                                    \
    do {                                                                    \
        checks++;                                                           \
        if (!(cond)) {                                                      \
            failures++;                                                     \
            fprintf(stderr, "FAIL %s:%d: %s -- ", __FILE__, __LINE__, #cond); \
            fprintf(stderr, __VA_ARGS__);                                   \
            fprintf(stderr, "\n");                                          \
        }                                                                   \
    } while (0)

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String fmt, ...) {
    (void)env; (void)name; (void)status; (void)category;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(last_log, sizeof last_log, fmt, ap);
    va_end(ap);
    n_logs++;
}

static const fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};

static int logged(const char *needle) { return strstr(last_log, needle) != NULL; }

static fmi2Component make(const char *name) {
    return fmi2Instantiate(name, fmi2CoSimulation, GUID, NULL, &callbacks, fmi2False, fmi2False);
}

static const fmi2ValueReference VR_OUT[] = {VR_y, VR_x, VR_v, VR_i};

/* Instantiated, with the ball at the 3.2 mm equilibrium of the Section 3 parameters. */
static fmi2Component make_levitating(const char *name, double *u_eq) {
    fmi2Component c = make(name);
    double x = 0.0032, m = 8.4e-3, g = 9.81, kc = 6.9e-6, x0 = 8.3e-3;
    double i = (x0 - x) * sqrt(m * g / kc);
    *u_eq = i / (0.3 * 5.0);
    fmi2ValueReference vr[] = {VR_x_start, VR_i_start, VR_u};
    double val[] = {x, i, *u_eq};
    fmi2SetReal(c, vr, 3, val);
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    return c;
}

static void test_instantiate_arguments(void) {
    CHECK(fmi2Instantiate("a", fmi2CoSimulation, "{wrong}", NULL, &callbacks, 0, 0) == NULL, "wrong GUID accepted");
    CHECK(logged("GUID"), "no GUID message: %s", last_log);
    CHECK(fmi2Instantiate("a", fmi2ModelExchange, GUID, NULL, &callbacks, 0, 0) == NULL, "ME accepted");
    CHECK(fmi2Instantiate("", fmi2CoSimulation, GUID, NULL, &callbacks, 0, 0) == NULL, "empty name accepted");
    CHECK(fmi2Instantiate(NULL, fmi2CoSimulation, GUID, NULL, &callbacks, 0, 0) == NULL, "NULL name accepted");
    CHECK(fmi2Instantiate("a", fmi2CoSimulation, GUID, NULL, NULL, 0, 0) == NULL, "NULL callbacks accepted");
}

static void test_call_sequence(void) {
    fmi2Component c = make("seq");
    double v = 0;
    fmi2ValueReference vr = VR_y;
    CHECK(fmi2DoStep(c, 0, 1e-3, fmi2True) == fmi2Error, "doStep before init");
    CHECK(logged("fmi2DoStep") && logged("instantiated"), "log: %s", last_log);
    CHECK(fmi2GetReal(c, &vr, 1, &v) == fmi2Error, "getReal in instantiated");
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error, "exit init before enter");
    CHECK(fmi2Terminate(c) == fmi2Error, "terminate in instantiated");
    CHECK(fmi2SetupExperiment(c, 0, 0, 0, 0, 0) == fmi2OK, "setupExperiment");
    CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "enter init");
    CHECK(fmi2SetupExperiment(c, 0, 0, 0, 0, 0) == fmi2Error, "setupExperiment in init mode");
    CHECK(fmi2EnterInitializationMode(c) == fmi2Error, "enter init twice");
    CHECK(fmi2DoStep(c, 0, 1e-3, fmi2True) == fmi2Error, "doStep in init mode");
    CHECK(fmi2GetReal(c, &vr, 1, &v) == fmi2OK, "getReal in init mode");
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "exit init");
    CHECK(fmi2DoStep(c, 0, 1e-3, fmi2True) == fmi2OK, "doStep");
    CHECK(fmi2DoStep(c, 0, 1e-3, fmi2True) == fmi2Error, "doStep at a stale communication point");
    CHECK(logged("currentCommunicationPoint"), "log: %s", last_log);
    CHECK(fmi2DoStep(c, 1e-3, 0.0, fmi2True) == fmi2Error, "zero step");
    CHECK(logged("communicationStepSize"), "log: %s", last_log);
    CHECK(fmi2DoStep(c, 1e-3, -1e-3, fmi2True) == fmi2Error, "negative step");
    CHECK(fmi2DoStep(c, 1e-3, NAN, fmi2True) == fmi2Error, "NaN step");
    CHECK(fmi2CancelStep(c) == fmi2Error, "cancelStep with no step in progress");
    fmi2Status st;
    CHECK(fmi2GetStatus(c, fmi2DoStepStatus, &st) == fmi2OK && st == fmi2OK, "getStatus");
    double lt = -1;
    CHECK(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &lt) == fmi2OK && fabs(lt - 1e-3) < 1e-15, "last time %g", lt);
    CHECK(fmi2Terminate(c) == fmi2OK, "terminate");
    CHECK(fmi2DoStep(c, 1e-3, 1e-3, fmi2True) == fmi2Error, "doStep after terminate");
    CHECK(fmi2GetReal(c, &vr, 1, &v) == fmi2OK, "getReal after terminate");
    CHECK(fmi2Reset(c) == fmi2OK, "reset");
    CHECK(fmi2DoStep(c, 0, 1e-3, fmi2True) == fmi2Error, "doStep after reset");
    CHECK(fmi2EnterEventMode(c) == fmi2Error, "ME function on a CS FMU");
    CHECK(fmi2GetReal(NULL, &vr, 1, &v) == fmi2Error, "NULL instance");
    fmi2FreeInstance(c);
}

static void test_bad_values(void) {
    fmi2Component c = make("bad");
    struct { MaglevVR vr; double value; const char *name; } bad[] = {
        {VR_m_k, 0.0, "m_k"},       {VR_m_k, -1.0, "m_k"},        {VR_k_i, 0.0, "k_i"},
        {VR_T_a, -1e-3, "T_a"},     {VR_k_c, NAN, "k_c"},         {VR_x_0, INFINITY, "x_0"},
        {VR_u, NAN, "u"},           {VR_u, -INFINITY, "u"},       {VR_k_FV, -0.1, "k_FV"},
        {VR_T_d, 2.0, "T_d"},       {VR_solver_step, 0.0, "solver_step"}, {VR_i_max, 0.0, "i_max"},
        {VR_T_F, -1.0, "T_F"},      {VR_g, 0.0, "g"},
    };
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        fmi2ValueReference vr = bad[k].vr;
        last_log[0] = 0;
        CHECK(fmi2SetReal(c, &vr, 1, &bad[k].value) == fmi2Error, "%s = %g accepted", bad[k].name, bad[k].value);
        char needle[64];
        snprintf(needle, sizeof needle, "variable %s", bad[k].name);
        CHECK(logged(needle), "message does not name %s: %s", bad[k].name, last_log);
    }
    /* a rejected call changes nothing, even its valid part */
    fmi2ValueReference two[] = {VR_m_k, VR_k_c};
    double vals[] = {1.0, NAN}, got[2];
    CHECK(fmi2SetReal(c, two, 2, vals) == fmi2Error, "partly bad call accepted");
    fmi2ValueReference outvr = VR_y;
    double one = 0.5;
    CHECK(fmi2SetReal(c, &outvr, 1, &one) == fmi2Error && logged("output"), "output set: %s", last_log);
    fmi2ValueReference unknown = 9999;
    CHECK(fmi2SetReal(c, &unknown, 1, &one) == fmi2Error && logged("9999"), "unknown vr: %s", last_log);
    /* relations between parameters are checked when initialisation ends */
    fmi2ValueReference xmax = VR_x_max;
    double too_high = 9e-3;
    CHECK(fmi2SetReal(c, &xmax, 1, &too_high) == fmi2OK, "single x_max value is fine on its own");
    fmi2SetupExperiment(c, 0, 0, 0, 0, 0);
    fmi2EnterInitializationMode(c);
    fmi2GetReal(c, two, 2, got);
    CHECK(got[0] == 8.4e-3 && got[1] == 6.9e-6, "rejected call changed values: %g %g", got[0], got[1]);
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("x_max"), "x_max >= x_0 accepted: %s", last_log);
    double ok = 6e-3;
    fmi2SetReal(c, &xmax, 1, &ok);
    fmi2ValueReference xmin = VR_x_min;
    double xm = 7e-3;
    fmi2SetReal(c, &xmin, 1, &xm);
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("x_min"), "x_min >= x_max accepted: %s", last_log);
    xm = 0;
    fmi2SetReal(c, &xmin, 1, &xm);
    fmi2ValueReference xs = VR_x_start;
    double xsv = 7e-3;
    fmi2SetReal(c, &xs, 1, &xsv);
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("x_start"), "x_start outside stops: %s", last_log);
    xsv = 3e-3;
    fmi2SetReal(c, &xs, 1, &xsv);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "valid parameters rejected: %s", last_log);
    /* fixed parameters cannot change during the simulation; NaN input is rejected */
    double mk = 1e-2;
    fmi2ValueReference mvr = VR_m_k;
    CHECK(fmi2SetReal(c, &mvr, 1, &mk) == fmi2Error && logged("m_k"), "fixed parameter set in stepComplete");
    fmi2ValueReference uvr = VR_u;
    double nan = NAN, y[4];
    CHECK(fmi2SetReal(c, &uvr, 1, &nan) == fmi2Error && logged("variable u"), "NaN input: %s", last_log);
    CHECK(fmi2DoStep(c, 0, 1e-3, fmi2True) == fmi2OK, "step after rejected input");
    fmi2GetReal(c, VR_OUT, 4, y);
    for (int k = 0; k < 4; k++) CHECK(isfinite(y[k]), "output %d not finite", k);
    fmi2FreeInstance(c);
}

static void test_instances_independent(void) {
    double u_eq;
    fmi2Component a = make_levitating("a", &u_eq);
    fmi2Component b = make_levitating("b", &u_eq);
    fmi2Component ref = make_levitating("ref", &u_eq);
    fmi2ValueReference uvr = VR_u;
    double up = u_eq + 0.05, down = 0.0;
    fmi2SetReal(a, &uvr, 1, &up);
    fmi2SetReal(b, &uvr, 1, &down);
    fmi2SetReal(ref, &uvr, 1, &up);
    double t = 0;
    for (int k = 0; k < 200; k++, t += 1e-3) {
        fmi2DoStep(a, t, 1e-3, fmi2True);
        fmi2DoStep(b, t, 1e-3, fmi2True);
    }
    t = 0;
    for (int k = 0; k < 200; k++, t += 1e-3) fmi2DoStep(ref, t, 1e-3, fmi2True);
    double ya[4], yb[4], yr[4];
    fmi2GetReal(a, VR_OUT, 4, ya);
    fmi2GetReal(b, VR_OUT, 4, yb);
    fmi2GetReal(ref, VR_OUT, 4, yr);
    for (int k = 0; k < 4; k++) CHECK(ya[k] == yr[k], "interleaved instance differs in output %d", k);
    CHECK(ya[1] > 0.0032 && yb[1] < 0.0032, "instances did not move apart: %g %g", ya[1], yb[1]);
    fmi2FreeInstance(a);
    fmi2FreeInstance(b);
    fmi2FreeInstance(ref);
}

static void run(fmi2Component c, double *t, int n, double u) {
    fmi2ValueReference uvr = VR_u;
    for (int k = 0; k < n; k++) {
        double uk = u + 0.01 * sin(k * 0.1);
        fmi2SetReal(c, &uvr, 1, &uk);
        fmi2DoStep(c, *t, 1e-3, fmi2True);
        *t += 1e-3;
    }
}

static void test_fmu_state(void) {
    double u_eq, t = 0;
    fmi2Component c = make_levitating("state", &u_eq);
    fmi2ValueReference dvr = VR_T_d;
    (void)dvr;
    run(c, &t, 50, u_eq);
    fmi2FMUstate s = NULL;
    CHECK(fmi2GetFMUstate(c, &s) == fmi2OK && s, "getFMUstate");
    double t_saved = t, y1[4], y2[4];
    run(c, &t, 100, u_eq);
    fmi2GetReal(c, VR_OUT, 4, y1);
    CHECK(fmi2SetFMUstate(c, s) == fmi2OK, "setFMUstate");
    t = t_saved;
    run(c, &t, 100, u_eq);
    fmi2GetReal(c, VR_OUT, 4, y2);
    for (int k = 0; k < 4; k++) CHECK(y1[k] == y2[k], "get/set state not exact in output %d: %.17g %.17g", k, y1[k], y2[k]);

    size_t size = 0;
    CHECK(fmi2SerializedFMUstateSize(c, s, &size) == fmi2OK && size > 0, "size");
    fmi2Byte *buf = malloc(size);
    CHECK(fmi2SerializeFMUstate(c, s, buf, size) == fmi2OK, "serialize");
    CHECK(fmi2SerializeFMUstate(c, s, buf, size - 1) == fmi2Error, "serialize into short buffer");
    fmi2FMUstate s2 = NULL;
    CHECK(fmi2DeSerializeFMUstate(c, buf, size, &s2) == fmi2OK, "deserialize: %s", last_log);
    CHECK(fmi2SetFMUstate(c, s2) == fmi2OK, "set deserialized");
    t = t_saved;
    run(c, &t, 100, u_eq);
    fmi2GetReal(c, VR_OUT, 4, y2);
    for (int k = 0; k < 4; k++) CHECK(y1[k] == y2[k], "serialized round trip not exact in output %d", k);

    /* a state restored into another instance continues identically */
    double u2;
    fmi2Component other = make_levitating("other", &u2);
    CHECK(fmi2SetFMUstate(other, s2) == fmi2OK, "state into another instance");
    t = t_saved;
    run(other, &t, 100, u_eq);
    fmi2GetReal(other, VR_OUT, 4, y2);
    for (int k = 0; k < 4; k++) CHECK(y1[k] == y2[k], "state moved to another instance differs in output %d", k);
    fmi2FreeInstance(other);

    fmi2FMUstate s3 = NULL;
    CHECK(fmi2DeSerializeFMUstate(c, buf, size - 9, &s3) == fmi2Error && s3 == NULL, "truncated accepted");
    CHECK(logged("truncated") || logged("bytes"), "truncation message: %s", last_log);
    for (size_t pos = 0; pos < size; pos += 7) {
        fmi2Byte saved = buf[pos];
        buf[pos] = (fmi2Byte)(buf[pos] ^ 0x5a);
        CHECK(fmi2DeSerializeFMUstate(c, buf, size, &s3) == fmi2Error && s3 == NULL, "corruption at byte %zu accepted", pos);
        buf[pos] = saved;
    }
    CHECK(fmi2DeSerializeFMUstate(c, buf, 0, &s3) == fmi2Error, "empty accepted");
    free(buf);
    CHECK(fmi2FreeFMUstate(c, &s) == fmi2OK && s == NULL, "free state");
    CHECK(fmi2FreeFMUstate(c, &s2) == fmi2OK, "free state 2");
    fmi2FreeInstance(c);
}

/* Delay history survives state save/restore (history is part of the state). */
static void test_delay_state(void) {
    fmi2Component c = make("delay");
    fmi2ValueReference vr[] = {VR_x_start, VR_i_start, VR_T_d, VR_u};
    double x = 0.0032, i = (8.3e-3 - x) * sqrt(8.4e-3 * 9.81 / 6.9e-6);
    double val[] = {x, i, 2.5e-3, i / 1.5};
    fmi2SetReal(c, vr, 4, val);
    fmi2SetupExperiment(c, 0, 0, 0, 0, 0);
    fmi2EnterInitializationMode(c);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "init with delay: %s", last_log);
    double t = 0, y1[4], y2[4];
    run(c, &t, 20, i / 1.5);
    fmi2FMUstate s = NULL;
    fmi2GetFMUstate(c, &s);
    size_t size;
    fmi2SerializedFMUstateSize(c, s, &size);
    fmi2Byte *buf = malloc(size);
    fmi2SerializeFMUstate(c, s, buf, size);
    double t0 = t;
    run(c, &t, 30, i / 1.5);
    fmi2GetReal(c, VR_OUT, 4, y1);
    fmi2FMUstate s2 = NULL;
    CHECK(fmi2DeSerializeFMUstate(c, buf, size, &s2) == fmi2OK, "deserialize with history");
    fmi2SetFMUstate(c, s2);
    t = t0;
    run(c, &t, 30, i / 1.5);
    fmi2GetReal(c, VR_OUT, 4, y2);
    for (int k = 0; k < 4; k++) CHECK(y1[k] == y2[k], "delay state round trip differs in output %d", k);
    free(buf);
    fmi2FreeFMUstate(c, &s);
    fmi2FreeFMUstate(c, &s2);
    fmi2FreeInstance(c);
}

/* Held at full current the ball rises to the upper stop, stays, and leaves when the current drops. */
static void test_stops(void) {
    fmi2Component c = make("stops");
    fmi2ValueReference vr[] = {VR_x_start, VR_u};
    double val[] = {0.0, 1.0};
    fmi2SetReal(c, vr, 2, val);
    fmi2SetupExperiment(c, 0, 0, 0, 0, 0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    double t = 0, y[4];
    fmi2ValueReference uvr = VR_u;
    for (int k = 0; k < 300; k++, t += 1e-3) fmi2DoStep(c, t, 1e-3, fmi2True);
    fmi2GetReal(c, VR_OUT, 4, y);
    CHECK(y[1] == 6.3e-3 && y[2] == 0.0, "not resting at the upper stop: x = %.17g v = %g", y[1], y[2]);
    double zero = 0.0;
    fmi2SetReal(c, &uvr, 1, &zero);
    for (int k = 0; k < 300; k++, t += 1e-3) fmi2DoStep(c, t, 1e-3, fmi2True);
    fmi2GetReal(c, VR_OUT, 4, y);
    CHECK(y[1] == 0.0 && y[2] == 0.0 && y[3] == 0.0, "not resting at the lower stop: x = %g v = %g i = %g", y[1], y[2], y[3]);
    fmi2FreeInstance(c);
}

int main(void) {
    test_instantiate_arguments();
    test_call_sequence();
    test_bad_values();
    test_instances_independent();
    test_fmu_state();
    test_delay_state();
    test_stops();
    printf("%d checks: %d passed, %d failed\n", checks, checks - failures, failures);
    return failures ? 1 : 0;
}
