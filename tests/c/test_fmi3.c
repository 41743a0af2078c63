/* C tests of the FMI 3.0 layer (maglev_fmi3.c): call sequences, bad arguments and values, NaN,
 * FMU state save/restore and serialisation, the independent variable time, and that it steps the
 * plant exactly as the FMI 2.0 layer does (both are linked in: they share maglev_fmi_common.c).
 * Run under ASan/UBSan in CI (MAGLEV_SANITIZE=ON). */
#define _POSIX_C_SOURCE 200809L /* mkdtemp (temp_dir.h), for a rig's resources folder */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"
#include "maglev_plant.h"
#include "check.h"
#include "temp_dir.h"

/* Must equal the instantiationToken of build/modelDescription3.xml (tests/test_model_description.py). */
#define MAGLEV_GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"
#define VR_TIME ((fmi3ValueReference)MAGLEV_NVARS)

static char last_log[1024];

static void logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    (void)env; (void)status; (void)category;
    snprintf(last_log, sizeof last_log, "%s", message);
}

static int logged(const char *needle) { return strstr(last_log, needle) != NULL; }

static fmi3Instance make(const char *name) {
    return fmi3InstantiateCoSimulation(name, MAGLEV_GUID, NULL, fmi3False, fmi3False, fmi3False, fmi3False, NULL, 0,
                                       NULL, logger, NULL);
}

static const fmi3ValueReference VR_OUT[] = {VR_y, VR_x, VR_v, VR_i};

static double set1(fmi3Instance c, MaglevVR vr, double value, fmi3Status *st) {
    fmi3ValueReference r = vr;
    *st = fmi3SetFloat64(c, &r, 1, &value, 1);
    return value;
}

/* Initialised at the 3.2 mm equilibrium of the Section 3 parameters. */
static fmi3Instance make_levitating(const char *name, double *u_eq) {
    fmi3Instance c = make(name);
    double x = 0.0032, m = 8.4e-3, g = 9.81, kc = 6.9e-6, x0 = 8.3e-3;
    double i = (x0 - x) * sqrt(m * g / kc);
    *u_eq = i / (0.3 * 5.0);
    fmi3ValueReference vr[] = {VR_x_start, VR_i_start, VR_u};
    double val[] = {x, i, *u_eq};
    CHECK(fmi3SetFloat64(c, vr, 3, val, 3) == fmi3OK, "setting up %s: %s", name, last_log);
    CHECK(fmi3EnterInitializationMode(c, fmi3False, 0, 0.0, fmi3False, 0) == fmi3OK, "enter init: %s", last_log);
    CHECK(fmi3ExitInitializationMode(c) == fmi3OK, "initialising %s: %s", name, last_log);
    return c;
}

static fmi3Status step(fmi3Instance c, double t, double h, double *last) {
    fmi3Boolean ev = fmi3True, term = fmi3True, early = fmi3True;
    fmi3Status st = fmi3DoStep(c, t, h, fmi3True, &ev, &term, &early, last);
    CHECK(!ev && !term && !early, "doStep out-arguments: %d %d %d", ev, term, early);
    return st;
}

static void test_instantiate_arguments(void) {
    CHECK(fmi3InstantiateCoSimulation("a", "{wrong}", NULL, 0, 0, 0, 0, NULL, 0, NULL, logger, NULL) == NULL,
          "wrong token accepted");
    CHECK(logged("instantiationToken"), "no token message: %s", last_log);
    CHECK(fmi3InstantiateCoSimulation("", MAGLEV_GUID, NULL, 0, 0, 0, 0, NULL, 0, NULL, logger, NULL) == NULL,
          "empty name accepted");
    CHECK(fmi3InstantiateCoSimulation(NULL, MAGLEV_GUID, NULL, 0, 0, 0, 0, NULL, 0, NULL, logger, NULL) == NULL,
          "NULL name accepted");
    CHECK(fmi3InstantiateCoSimulation("a", MAGLEV_GUID, NULL, 0, 0, fmi3True, 0, NULL, 0, NULL, logger, NULL) == NULL,
          "event mode accepted");
    CHECK(logged("hasEventMode"), "log: %s", last_log);
    fmi3ValueReference iv = VR_y;
    CHECK(fmi3InstantiateCoSimulation("a", MAGLEV_GUID, NULL, 0, 0, 0, 0, &iv, 1, NULL, logger, NULL) == NULL,
          "intermediate variables accepted");
    CHECK(fmi3InstantiateModelExchange("a", MAGLEV_GUID, NULL, 0, 0, NULL, logger) == NULL, "ME accepted");
    CHECK(fmi3InstantiateScheduledExecution("a", MAGLEV_GUID, NULL, 0, 0, NULL, logger, NULL, NULL, NULL) == NULL,
          "SE accepted");
    /* no logger: still refused, and no crash */
    CHECK(fmi3InstantiateCoSimulation("a", "{x}", NULL, 0, 0, 0, 0, NULL, 0, NULL, NULL, NULL) == NULL, "no logger");
    fmi3Instance c = fmi3InstantiateCoSimulation("a", MAGLEV_GUID, NULL, 0, 0, 0, fmi3True, NULL, 0, NULL, NULL, NULL);
    CHECK(c != NULL, "earlyReturnAllowed without a logger refused");
    fmi3FreeInstance(c);
    fmi3FreeInstance(NULL);
}

static void test_call_sequence(void) {
    fmi3Instance c = make("seq");
    double v = 0, last = -1;
    fmi3ValueReference vr = VR_y;
    CHECK(step(c, 0, 1e-3, &last) == fmi3Error, "doStep before init");
    CHECK(logged("fmi3DoStep") && logged("instantiated"), "log: %s", last_log);
    CHECK(fmi3GetFloat64(c, &vr, 1, &v, 1) == fmi3Error, "get in instantiated");
    CHECK(fmi3ExitInitializationMode(c) == fmi3Error, "exit init before enter");
    CHECK(fmi3Terminate(c) == fmi3Error, "terminate in instantiated");
    CHECK(fmi3EnterConfigurationMode(c) == fmi3Error && logged("structural"), "configuration mode: %s", last_log);
    CHECK(fmi3ExitConfigurationMode(c) == fmi3Error, "exit configuration mode");
    CHECK(fmi3EnterInitializationMode(c, fmi3True, -1.0, 0, fmi3False, 0) == fmi3Error && logged("tolerance"),
          "negative tolerance: %s", last_log);
    CHECK(fmi3EnterInitializationMode(c, fmi3False, 0, NAN, fmi3False, 0) == fmi3Error && logged("startTime"),
          "NaN start time: %s", last_log);
    CHECK(fmi3EnterInitializationMode(c, fmi3False, 0, 1.0, fmi3True, 0.5) == fmi3Error && logged("stopTime"),
          "stop before start: %s", last_log);
    CHECK(fmi3EnterInitializationMode(c, fmi3False, 0, 0, fmi3True, 2e-3) == fmi3OK, "enter init: %s", last_log);
    CHECK(fmi3EnterInitializationMode(c, fmi3False, 0, 0, fmi3False, 0) == fmi3Error, "enter init twice");
    CHECK(step(c, 0, 1e-3, &last) == fmi3Error, "doStep in init mode");
    CHECK(fmi3GetFloat64(c, &vr, 1, &v, 1) == fmi3OK, "get in init mode: %s", last_log);
    CHECK(fmi3ExitInitializationMode(c) == fmi3OK, "exit init: %s", last_log);
    CHECK(fmi3EnterStepMode(c) == fmi3Error, "enterStepMode outside event mode");
    CHECK(fmi3EnterEventMode(c) == fmi3Error && logged("event mode"), "event mode: %s", last_log);
    CHECK(step(c, 0, 1e-3, &last) == fmi3OK && last == 1e-3, "doStep: last %g: %s", last, last_log);
    CHECK(step(c, 0, 1e-3, &last) == fmi3Error && logged("currentCommunicationPoint") && last == 1e-3,
          "stale point: %s", last_log);
    CHECK(step(c, 1e-3, 0.0, &last) == fmi3Error && logged("communicationStepSize"), "zero step: %s", last_log);
    CHECK(step(c, 1e-3, NAN, &last) == fmi3Error, "NaN step");
    CHECK(step(c, 1e-3, 5e-3, &last) == fmi3Error && logged("stopTime"), "step past stop time: %s", last_log);
    fmi3Boolean b;
    CHECK(fmi3DoStep(c, 1e-3, 1e-3, fmi3True, NULL, &b, &b, &last) == fmi3Error && logged("NULL"),
          "NULL out-argument: %s", last_log);
    fmi3ValueReference tvr = VR_TIME;
    double t = -1;
    CHECK(fmi3GetFloat64(c, &tvr, 1, &t, 1) == fmi3OK && t == 1e-3, "time %g", t);
    CHECK(fmi3Terminate(c) == fmi3OK, "terminate");
    CHECK(step(c, 1e-3, 1e-3, &last) == fmi3Error, "doStep after terminate");
    CHECK(fmi3GetFloat64(c, &vr, 1, &v, 1) == fmi3OK, "get after terminate");
    CHECK(fmi3Reset(c) == fmi3OK, "reset");
    CHECK(step(c, 0, 1e-3, &last) == fmi3Error, "doStep after reset");
    CHECK(fmi3SetTime(c, 0.0) == fmi3Error && logged("co-simulation only"), "ME function: %s", last_log);
    CHECK(fmi3GetFloat64(NULL, &vr, 1, &v, 1) == fmi3Error, "NULL instance");
    size_t n;
    CHECK(fmi3GetNumberOfVariableDependencies(c, VR_y, &n) == fmi3Error, "dependencies");
    fmi3FreeInstance(c);
}

static void test_bad_values(void) {
    fmi3Instance c = make("bad");
    fmi3Status st;
    struct { MaglevVR vr; double value; const char *name; } bad[] = {
        {VR_m_k, 0.0, "m_k"},  {VR_k_c, NAN, "k_c"}, {VR_x_0, INFINITY, "x_0"}, {VR_u, NAN, "u"},
        {VR_T_d, 2.0, "T_d"},  {VR_n_F, 5.0, "n_F"}, {VR_solver_step, 0.0, "solver_step"},
    };
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        last_log[0] = 0;
        set1(c, bad[k].vr, bad[k].value, &st);
        CHECK(st == fmi3Error, "%s = %g accepted", bad[k].name, bad[k].value);
        char needle[64];
        snprintf(needle, sizeof needle, "variable %s", bad[k].name);
        CHECK(logged(needle), "message does not name %s: %s", bad[k].name, last_log);
    }
    /* the table's range is what is refused: its ends are accepted, the next doubles are not */
    for (int vr = MAGLEV_FIRST_PARAM; vr <= VR_solver_step; vr++) {
        const MaglevVariable *var = &maglev_variables[vr];
        set1(c, (MaglevVR)vr, var->min, &st);
        CHECK(st == fmi3OK, "%s = min %g refused: %s", var->name, var->min, last_log);
        set1(c, (MaglevVR)vr, nextafter(var->min, -INFINITY), &st);
        CHECK(st == fmi3Error, "%s below min accepted", var->name);
        set1(c, (MaglevVR)vr, var->max, &st);
        CHECK(st == fmi3OK, "%s = max %g refused: %s", var->name, var->max, last_log);
        set1(c, (MaglevVR)vr, nextafter(var->max, INFINITY), &st);
        CHECK(st == fmi3Error, "%s above max accepted", var->name);
        set1(c, (MaglevVR)vr, var->start, &st);
    }
    fmi3ValueReference two[] = {VR_m_k, VR_k_c};
    double vals[] = {1.0, 1e-5}, got[2];
    CHECK(fmi3SetFloat64(c, two, 2, vals, 1) == fmi3Error && logged("nValues"), "nValues mismatch: %s", last_log);
    CHECK(fmi3GetFloat64(c, two, 2, got, 3) == fmi3Error, "nValues mismatch on get");
    fmi3ValueReference unknown = 9999, tvr = VR_TIME, outvr = VR_y;
    double one = 0.5;
    CHECK(fmi3SetFloat64(c, &unknown, 1, &one, 1) == fmi3Error && logged("9999"), "unknown vr: %s", last_log);
    fmi3ValueReference all_ones = 0xffffffffu;
    CHECK(fmi3SetFloat64(c, &all_ones, 1, &one, 1) == fmi3Error, "vr 2^32-1 accepted");
    CHECK(fmi3SetFloat64(c, &tvr, 1, &one, 1) == fmi3Error && logged("time"), "time set: %s", last_log);
    CHECK(fmi3SetFloat64(c, &outvr, 1, &one, 1) == fmi3Error && logged("output"), "output set: %s", last_log);
    CHECK(fmi3SetFloat64(c, NULL, 1, &one, 1) == fmi3Error, "NULL vr");
    fmi3Int32 iv = 1;
    CHECK(fmi3SetInt32(c, &outvr, 1, &iv, 1) == fmi3Error && logged("no variable of this type"), "Int32: %s",
          last_log);
    CHECK(fmi3SetInt32(c, NULL, 0, NULL, 0) == fmi3OK, "empty Int32 set");
    fmi3EnterInitializationMode(c, fmi3False, 0, 0, fmi3False, 0);
    CHECK(fmi3GetFloat64(c, two, 2, got, 2) == fmi3OK && got[0] == 8.4e-3 && got[1] == 6.9e-6,
          "rejected calls changed values: %g %g", got[0], got[1]);
    CHECK(fmi3ExitInitializationMode(c) == fmi3OK, "exit init: %s", last_log);
    set1(c, VR_m_k, 1e-2, &st);
    CHECK(st == fmi3Error && logged("m_k"), "fixed parameter set in step mode: %s", last_log);
    set1(c, VR_u, NAN, &st);
    CHECK(st == fmi3Error && logged("variable u"), "NaN input: %s", last_log);
    double last, y[4];
    CHECK(step(c, 0, 1e-3, &last) == fmi3OK, "step after rejected input");
    CHECK(fmi3GetFloat64(c, VR_OUT, 4, y, 4) == fmi3OK, "outputs");
    for (int k = 0; k < 4; k++) CHECK(isfinite(y[k]), "output %d not finite", k);
    fmi3FreeInstance(c);
}

static void run(fmi3Instance c, double *t, int n, double u) {
    fmi3ValueReference uvr = VR_u;
    double last;
    for (int k = 0; k < n; k++) {
        fmi3SetFloat64(c, &uvr, 1, &u, 1);
        CHECK(step(c, *t, 1e-3, &last) == fmi3OK, "step at %g: %s", *t, last_log);
        *t += 1e-3;
    }
}

static void test_state_save_restore_and_serialization(void) {
    double u_eq, t = 0;
    fmi3Instance c = make_levitating("state", &u_eq);
    run(c, &t, 50, u_eq + 0.02);
    fmi3FMUState s = NULL;
    CHECK(fmi3GetFMUState(c, &s) == fmi3OK && s, "getFMUState: %s", last_log);
    double t_saved = t, y1[4], y2[4], y3[4];
    run(c, &t, 100, u_eq - 0.03);
    fmi3GetFloat64(c, VR_OUT, 4, y1, 4);
    CHECK(fmi3SetFMUState(c, s) == fmi3OK, "setFMUState: %s", last_log);
    t = t_saved;
    run(c, &t, 100, u_eq - 0.03);
    fmi3GetFloat64(c, VR_OUT, 4, y2, 4);
    for (int k = 0; k < 4; k++) CHECK(y1[k] == y2[k], "restore does not replay output %d: %g %g", k, y1[k], y2[k]);
    size_t size = 0;
    CHECK(fmi3SerializedFMUStateSize(c, s, &size) == fmi3OK && size > 0, "size: %s", last_log);
    fmi3Byte *buf = malloc(size);
    CHECK(fmi3SerializeFMUState(c, s, buf, size - 1) == fmi3Error && logged("bytes"), "short buffer: %s", last_log);
    CHECK(fmi3SerializeFMUState(c, s, buf, size) == fmi3OK, "serialize: %s", last_log);
    /* into another instance */
    fmi3Instance d = make("other");
    fmi3FMUState r = NULL;
    CHECK(fmi3SetFMUState(d, s) == fmi3Error && logged("not made by this instance"), "foreign state: %s", last_log);
    CHECK(fmi3DeserializeFMUState(d, buf, size, &r) == fmi3OK && r, "deserialize: %s", last_log);
    CHECK(fmi3SetFMUState(d, r) == fmi3OK, "set deserialized: %s", last_log);
    t = t_saved;
    run(d, &t, 100, u_eq - 0.03);
    fmi3GetFloat64(d, VR_OUT, 4, y3, 4);
    for (int k = 0; k < 4; k++) CHECK(y1[k] == y3[k], "deserialized state differs in output %d", k);
    buf[size / 2] ^= 0x40;
    CHECK(fmi3DeserializeFMUState(d, buf, size, &r) == fmi3Error, "corrupted image accepted");
    CHECK(fmi3DeserializeFMUState(d, buf, 3, &r) == fmi3Error, "truncated image accepted");
    CHECK(fmi3FreeFMUState(d, &r) == fmi3OK && r == NULL, "free");
    CHECK(fmi3FreeFMUState(c, &s) == fmi3OK && s == NULL, "free");
    CHECK(fmi3FreeFMUState(c, &s) == fmi3OK, "freeing NULL is a no-op");
    fmi3FMUState leak = NULL;
    fmi3GetFMUState(d, &leak); /* left to fmi3FreeInstance (ASan checks) */
    free(buf);
    fmi3FreeInstance(c);
    fmi3FreeInstance(d);
}

/* The two glues drive the same plant code: identical inputs give bit-identical outputs. */
static void fmi2_logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                        fmi2String fmt, ...) {
    (void)env; (void)name; (void)status; (void)category; (void)fmt;
}

static void test_same_as_fmi2(void) {
    const fmi2CallbackFunctions cb = {fmi2_logger, calloc, free, NULL, NULL};
    fmi2Component c2 = fmi2Instantiate("two", fmi2CoSimulation, MAGLEV_GUID, NULL, &cb, fmi2False, fmi2False);
    fmi3Instance c3 = make("three");
    fmi3ValueReference vr[] = {VR_x_start, VR_T_d, VR_F_c};
    double val[] = {0.002, 0.004, 1e-3};
    fmi2SetReal(c2, vr, 3, val);
    fmi3SetFloat64(c3, vr, 3, val, 3);
    fmi2SetupExperiment(c2, fmi2False, 0, 0, fmi2False, 0);
    fmi2EnterInitializationMode(c2);
    fmi2ExitInitializationMode(c2);
    fmi3EnterInitializationMode(c3, fmi3False, 0, 0, fmi3False, 0);
    fmi3ExitInitializationMode(c3);
    fmi3ValueReference uvr = VR_u;
    double t = 0, last, y2[4], y3[4];
    int same = 1;
    for (int k = 0; k < 500; k++, t += 1e-3) {
        double u = 0.6 + 0.4 * sin(k * 0.05);
        fmi2SetReal(c2, &uvr, 1, &u);
        fmi3SetFloat64(c3, &uvr, 1, &u, 1);
        fmi2DoStep(c2, t, 1e-3, fmi2True);
        step(c3, t, 1e-3, &last);
        fmi2GetReal(c2, VR_OUT, 4, y2);
        fmi3GetFloat64(c3, VR_OUT, 4, y3, 4);
        for (int j = 0; j < 4; j++) same &= y2[j] == y3[j];
    }
    CHECK(same, "FMI 2.0 and 3.0 glues differ: y %g vs %g", y2[0], y3[0]);
    CHECK(y3[1] != 0.002, "the ball never moved");
    fmi2FreeInstance(c2);
    fmi3FreeInstance(c3);
}

/* fmi3Reset puts the FMU into the state right after fmi3InstantiateCoSimulation, a rig's start values
 * (resources/start_values.txt) included: it shares mf_reset with fmi2Reset, which put the C defaults there. */
static void test_reset_keeps_start_values(void) {
    char dir[512], res[600], file[600];
    if (!make_temp_dir(dir, sizeof dir, "reset3")) {
        CHECK(0, "cannot make a temporary folder");
        return;
    }
    snprintf(res, sizeof res, "%s/", dir); /* FMI 3.0: a path with a trailing separator, no URI */
    snprintf(file, sizeof file, "%s/start_values.txt", dir);
    CHECK(write_text(file, "k_c 1.5e-05\n") == 0, "cannot write %s", file);
    fmi3Instance c = fmi3InstantiateCoSimulation("rig", MAGLEV_GUID, res, fmi3False, fmi3False, fmi3False, fmi3False,
                                                 NULL, 0, NULL, logger, NULL);
    CHECK(c != NULL, "rig FMU refused: %s", last_log);
    remove(file);
    remove_dir(dir);
    if (!c) return;
    fmi3ValueReference kvr = VR_k_c;
    for (int round = 0; round < 2; round++) {
        double kc = -1, last;
        fmi3Status st;
        CHECK(fmi3EnterInitializationMode(c, fmi3False, 0, 0.0, fmi3False, 0) == fmi3OK, "round %d: enter: %s", round,
              last_log);
        CHECK(fmi3GetFloat64(c, &kvr, 1, &kc, 1) == fmi3OK && kc == 1.5e-5, "round %d: k_c = %g, not the rig's "
              "1.5e-05", round, kc);
        set1(c, VR_k_c, 2e-5, &st);
        CHECK(fmi3ExitInitializationMode(c) == fmi3OK, "round %d: exit: %s", round, last_log);
        CHECK(step(c, 0.0, 1e-3, &last) == fmi3OK, "round %d: step: %s", round, last_log);
        CHECK(fmi3Reset(c) == fmi3OK, "round %d: reset: %s", round, last_log);
    }
    fmi3FreeInstance(c);
}

/* An FMU state holds the experiment fmi3EnterInitializationMode gave (start, stop, tolerance): after a reset
 * and fmi3SetFMUState the FMU started at 0 instead of 5 s and stepped past the stop time. */
static void check_experiment_restored(fmi3Instance c, const char *what) {
    double last = -1;
    CHECK(fmi3ExitInitializationMode(c) == fmi3OK, "%s: exit: %s", what, last_log);
    last_log[0] = 0;
    CHECK(step(c, 5.0, 1e-3, &last) == fmi3OK && last == 5.001, "%s: step from startTime 5 s: last %g: %s", what,
          last, last_log);
    last_log[0] = 0;
    CHECK(step(c, 5.001, 10.0, &last) == fmi3Error && logged("stopTime"), "%s: a step past stopTime 6 s not "
          "refused: '%s'", what, last_log);
}

static void test_state_holds_experiment(void) {
    fmi3Instance c = make("experiment");
    CHECK(fmi3EnterInitializationMode(c, fmi3True, 1e-6, 5.0, fmi3True, 6.0) == fmi3OK, "enter: %s", last_log);
    fmi3FMUState s = NULL, r = NULL;
    CHECK(fmi3GetFMUState(c, &s) == fmi3OK, "state in initialization mode: %s", last_log);
    size_t size = 0;
    CHECK(fmi3SerializedFMUStateSize(c, s, &size) == fmi3OK, "size: %s", last_log);
    fmi3Byte *buf = malloc(size ? size : 1);
    CHECK(fmi3SerializeFMUState(c, s, buf, size) == fmi3OK, "serialize: %s", last_log);
    CHECK(fmi3Reset(c) == fmi3OK, "reset: %s", last_log);
    CHECK(fmi3SetFMUState(c, s) == fmi3OK, "set state: %s", last_log);
    check_experiment_restored(c, "after a reset");
    fmi3Instance d = make("experiment2");
    CHECK(fmi3DeserializeFMUState(d, buf, size, &r) == fmi3OK, "deserialize: %s", last_log);
    CHECK(fmi3SetFMUState(d, r) == fmi3OK, "set the deserialized state: %s", last_log);
    check_experiment_restored(d, "deserialized into another instance");
    free(buf);
    fmi3FreeInstance(c);
    fmi3FreeInstance(d);
}

int main(void) {
    test_instantiate_arguments();
    test_call_sequence();
    test_bad_values();
    test_state_save_restore_and_serialization();
    test_same_as_fmi2();
    test_reset_keeps_start_values();
    test_state_holds_experiment();
    printf("%d checks: %d passed, %d failed\n", checks, checks - failures, failures);
    return failures ? 1 : 0;
}
