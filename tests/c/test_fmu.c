/* C tests of the FMI 2.0 layer: call sequences, bad arguments, several instances,
 * FMU state round trips. Run under ASan/UBSan in CI (MAGLEV_SANITIZE=ON). */
#define _POSIX_C_SOURCE 200809L /* mkdtemp (temp_dir.h), for the resources folders of the tests */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "maglev_fmi_common.h"
#include "maglev_plant.h"
#include "check.h"
#include "temp_dir.h"

#define GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"

#include "fmi2_host.h"

static const fmi2ValueReference VR_OUT[] = {VR_y, VR_x, VR_v, VR_i};

/* Initialised, with the ball at the 3.2 mm equilibrium of the Section 3 parameters, and one more
 * parameter set before initialisation (none when extra is VR_u). */
static fmi2Component make_levitating_with(const char *name, MaglevVR extra, double value, double *u_eq) {
    fmi2Component c = make(name);
    double x = 0.0032, m = 8.4e-3, g = 9.81, kc = 6.9e-6, x0 = 8.3e-3;
    double i = (x0 - x) * sqrt(m * g / kc);
    *u_eq = i / (0.3 * 5.0);
    fmi2ValueReference vr[] = {VR_x_start, VR_i_start, VR_u, extra};
    double val[] = {x, i, *u_eq, value};
    CHECK(fmi2SetReal(c, vr, extra == VR_u ? 3 : 4, val) == fmi2OK, "setting up %s: %s", name, last_log);
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "initialising %s: %s", name, last_log);
    return c;
}

static fmi2Component make_levitating(const char *name, double *u_eq) {
    return make_levitating_with(name, VR_u, 0.0, u_eq);
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
        {VR_F_c, -1e-3, "F_c"},     {VR_n_F, 5.0, "n_F"},      {VR_n_F, 0.5, "n_F"},
        {VR_u_dz, -0.1, "u_dz"},    {VR_x_n, 2.0, "x_n"},
        {VR_beta_F, -0.1, "beta_F"}, {VR_beta_F, 1.5, "beta_F"}, {VR_beta_F, NAN, "beta_F"},
        {VR_T_F2, 0.0, "T_F2"},     {VR_T_F2, 2.0, "T_F2"},
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
    fmi2ValueReference all_ones = 0xffffffffu; /* what the FMI 3.0 glue's "no time variable" marker is */
    CHECK(fmi2SetReal(c, &all_ones, 1, &one) == fmi2Error && logged("4294967295"), "vr 2^32-1: %s", last_log);
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

    /* a state moves to another instance through its serialization and continues identically;
     * the pointer itself belongs to the instance that made it */
    double u2;
    fmi2Component other = make_levitating("other", &u2);
    CHECK(fmi2SetFMUstate(other, s2) == fmi2Error && logged("not made by this instance"), "foreign state: %s", last_log);
    fmi2FMUstate moved = NULL;
    CHECK(fmi2DeSerializeFMUstate(other, buf, size, &moved) == fmi2OK, "deserialize into another instance");
    CHECK(fmi2SetFMUstate(other, moved) == fmi2OK, "state into another instance");
    t = t_saved;
    run(other, &t, 100, u_eq);
    fmi2GetReal(other, VR_OUT, 4, y2);
    for (int k = 0; k < 4; k++) CHECK(y1[k] == y2[k], "state moved to another instance differs in output %d", k);
    fmi2FreeInstance(other);

    fmi2FMUstate s3 = NULL;
    CHECK(fmi2DeSerializeFMUstate(c, buf, size - 9, &s3) == fmi2Error && s3 == NULL, "truncated accepted");
    CHECK(logged("truncated") || logged("bytes"), "truncation message: %s", last_log);
    /* every single-bit flip is refused, the FMU state's code included (issue 10, defect 9) */
    for (size_t pos = 0; pos < size; pos++) {
        for (int bit = 0; bit < 8; bit++) {
            buf[pos] = (fmi2Byte)(buf[pos] ^ (1 << bit));
            CHECK(fmi2DeSerializeFMUstate(c, buf, size, &s3) == fmi2Error && s3 == NULL,
                  "bit %d of byte %zu flipped accepted", bit, pos);
            buf[pos] = (fmi2Byte)(buf[pos] ^ (1 << bit));
        }
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


/* ---- regressions of the stateful fuzz campaign (issue 10): each failed before its fix ---- */

static fmi2Status set1(fmi2Component c, MaglevVR vr, double value) {
    fmi2ValueReference r = vr;
    return fmi2SetReal(c, &r, 1, &value);
}

static double get1(fmi2Component c, MaglevVR vr, fmi2Status *st) {
    fmi2ValueReference r = vr;
    double v = NAN;
    fmi2Status s = fmi2GetReal(c, &r, 1, &v);
    if (st) *st = s;
    return v;
}

static fmi2Component make_initialized(const char *name, MaglevVR vr, double value) {
    fmi2Component c = make(name);
    if (vr != VR_u || value != 0) set1(c, vr, value);
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    return c;
}

/* 1, 3: a tiny solver step is refused; a step needing more work than the budget is refused with
 * the state unchanged, and the instance goes on; a huge step leaves the time range (no UB). */
static void test_step_work_bounded(void) {
    fmi2Component c = make("tiny");
    last_log[0] = 0;
    CHECK(set1(c, VR_solver_step, 1e-11) == fmi2Error && logged("variable solver_step"), "1e-11 s: %s", last_log);
    CHECK(set1(c, VR_solver_step, 1e-6) == fmi2OK, "1e-6 s refused: %s", last_log);
    fmi2FreeInstance(c);

    double u_eq, t = 0;
    c = make_levitating("budget", &u_eq);
    CHECK(fmi2DoStep(c, 0, 1e-3, fmi2True) == fmi2OK, "ordinary step");
    t = 1e-3;
    double before[4], after[4];
    fmi2GetReal(c, VR_OUT, 4, before);
    fmi2FreeInstance(c);
    /* levitating at solver_step = 1e-6 the ball stays off the stops for about a second: 1e6 substeps */
    {
        double u_eq;
        c = make_levitating_with("budget2", VR_solver_step, 1e-6, &u_eq);
    }
    fmi2GetReal(c, VR_OUT, 4, before);
    last_log[0] = 0;
    CHECK(fmi2DoStep(c, 0, 10.0, fmi2True) == fmi2Error && logged("RK4 steps") && logged("shorter"),
          "10 s at 1e-6 s substeps: %s", last_log);
    fmi2GetReal(c, VR_OUT, 4, after);
    for (int k = 0; k < 4; k++) CHECK(before[k] == after[k], "refused step changed output %d", k);
    double lt = -1;
    fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &lt);
    CHECK(lt == 0.0, "refused step moved the time to %g", lt);
    CHECK(fmi2DoStep(c, 0, 1e-3, fmi2True) == fmi2OK, "instance unusable after a refused step: %s", last_log);
    last_log[0] = 0;
    CHECK(fmi2DoStep(c, 1e-3, 1e20, fmi2True) == fmi2Error && logged("time range"), "1e20 s step: %s", last_log);
    CHECK(fmi2DoStep(c, 1e-3, 1e-3, fmi2True) == fmi2OK, "instance unusable after a huge step: %s", last_log);
    fmi2FreeInstance(c);
    (void)t;
}

/* 2: long steps. A ball at rest on a stop is fast-forwarded exactly, whatever the step. A levitating ball
 * is counted in full before the step (defect 6 of docs/fuzz.md): 100 s of 0.1 ms substeps are over the
 * budget, although the ball would reach a stop within a second; 10 s are not, and after them the ball
 * rests there for the remaining 90 s. */
static void test_long_steps(void) {
    fmi2Component c = make_initialized("floor", VR_u, 0.0);
    CHECK(fmi2DoStep(c, 0, 100.0, fmi2True) == fmi2OK, "100 s on the floor: %s", last_log);
    CHECK(fmi2DoStep(c, 100.0, 1e6, fmi2True) == fmi2OK, "1e6 s on the floor: %s", last_log);
    double y[4], lt = 0;
    fmi2GetReal(c, VR_OUT, 4, y);
    CHECK(y[1] == 0.0 && y[2] == 0.0 && y[3] == 0.0, "not at rest on the floor: x %g v %g i %g", y[1], y[2], y[3]);
    fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &lt);
    CHECK(lt == 100.0 + 1e6, "time after long steps %.17g", lt);
    fmi2FreeInstance(c);

    double u_eq;
    c = make_levitating("lev", &u_eq);
    double up = u_eq * 1.05;
    set1(c, VR_u, up);
    CHECK(fmi2DoStep(c, 0, 100.0, fmi2True) == fmi2Error && logged("solver_step"), "100 s from levitation: %s",
          last_log);
    CHECK(fmi2DoStep(c, 0, 10.0, fmi2True) == fmi2OK, "10 s from levitation: %s", last_log);
    fmi2GetReal(c, VR_OUT, 4, y);
    CHECK(y[1] == 6.3e-3 && y[2] == 0.0, "more current must end at the upper stop: x %g v %g", y[1], y[2]);
    CHECK(fmi2DoStep(c, 10.0, 90.0, fmi2True) == fmi2OK, "90 s at rest on the upper stop: %s", last_log);
    fmi2FreeInstance(c);

    /* with a force lag the lag relaxes exactly while the ball rests: compare with 1 ms steps */
    fmi2Component a = make("lagA"), b = make("lagB");
    fmi2ValueReference vr[] = {VR_T_F, VR_u};
    double val[] = {5e-3, 0.0};
    fmi2Component both[2] = {a, b};
    for (int k = 0; k < 2; k++) {
        fmi2SetReal(both[k], vr, 2, val);
        fmi2SetupExperiment(both[k], fmi2False, 0, 0.0, fmi2False, 0);
        fmi2EnterInitializationMode(both[k]);
        fmi2ExitInitializationMode(both[k]);
        set1(both[k], VR_u, 0.3); /* 0.45 A: too little to lift the ball */
    }
    CHECK(fmi2DoStep(a, 0, 0.05, fmi2True) == fmi2OK, "one 50 ms step with a force lag");
    for (int k = 0; k < 50; k++) fmi2DoStep(b, k * 1e-3, 1e-3, fmi2True);
    double fa = get1(a, VR_F, NULL), fb = get1(b, VR_F, NULL);
    CHECK(fabs(fa - fb) <= 1e-9 * fabs(fb) && fa > 0, "force lag at rest: %.17g vs %.17g", fa, fb);
    fmi2FreeInstance(a);
    fmi2FreeInstance(b);
}

/* 4: a frequency that overflows the phase is refused; the largest allowed one at the far end of
 * the time range gives a finite y. */
static void test_pickup_phase_finite(void) {
    fmi2Component c = make("pickup");
    last_log[0] = 0;
    CHECK(set1(c, VR_f_d, 1e308) == fmi2Error && logged("variable f_d"), "f_d = 1e308: %s", last_log);
    fmi2ValueReference vr[] = {VR_f_d, VR_A_d};
    double val[] = {1e5, 1e-3};
    CHECK(fmi2SetReal(c, vr, 2, val) == fmi2OK, "largest f_d refused: %s", last_log);
    CHECK(fmi2SetupExperiment(c, fmi2False, 0, 1e9 - 1.0, fmi2False, 0) == fmi2OK, "start near the time limit");
    CHECK(fmi2SetupExperiment(c, fmi2False, 0, 2e9, fmi2False, 0) == fmi2Error, "start beyond the time limit");
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    fmi2Status st;
    double y = get1(c, VR_y, &st);
    CHECK(st == fmi2OK && isfinite(y), "y = %g", y);
    CHECK(fmi2DoStep(c, 1e9 - 1.0, 0.5, fmi2True) == fmi2OK, "step near the time limit: %s", last_log);
    y = get1(c, VR_y, &st);
    CHECK(st == fmi2OK && isfinite(y), "y = %g after the step", y);
    fmi2FreeInstance(c);
}

/* 5: in initialization mode the outputs need consistent parameters; parameters stay readable. */
static void test_init_mode_outputs(void) {
    fmi2Component c = make("initmode");
    set1(c, VR_x_start, 8.3e-3); /* = x_0: the force law is singular there */
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    fmi2Status st;
    last_log[0] = 0;
    double F = get1(c, VR_F, &st);
    CHECK(st == fmi2Error && logged("x_start"), "F = %g with status %d: %s", F, (int)st, last_log);
    double xs = get1(c, VR_x_start, &st);
    CHECK(st == fmi2OK && xs == 8.3e-3, "parameter unreadable: %g", xs);
    set1(c, VR_x_start, 3e-3);
    double y = get1(c, VR_y, &st);
    CHECK(st == fmi2OK && fabs(y - 0.2 * (612.3 * 3e-3 + 0.0125)) < 1e-12, "y in initialization mode: %.17g", y);
    fmi2FreeInstance(c);
}

/* 6: a non-physical start velocity is refused; the values after any failed step stay finite. */
static void test_start_velocity(void) {
    fmi2Component c = make("vstart");
    last_log[0] = 0;
    CHECK(set1(c, VR_v_start, 1e308) == fmi2Error && logged("variable v_start"), "v_start = 1e308: %s", last_log);
    CHECK(set1(c, VR_v_start, 100.0) == fmi2OK, "v_start = 100 m/s refused");
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    fmi2Status ok = fmi2DoStep(c, 0, 1e-3, fmi2True);
    double y[4];
    fmi2Status st = fmi2GetReal(c, VR_OUT, 4, y);
    CHECK(ok == fmi2OK && st == fmi2OK, "fast start: step %d get %d: %s", (int)ok, (int)st, last_log);
    for (int k = 0; k < 4; k++) CHECK(isfinite(y[k]), "output %d = %g", k, y[k]);
    /* thrown up at 100 m/s it hits the upper stop within 63 us, stops dead and falls away */
    CHECK(y[1] < 6.3e-3 && y[1] > 6.29e-3 && y[2] < 0, "after 1 ms: x = %.17g v = %g", y[1], y[2]);
    fmi2FreeInstance(c);
}

/* 7: every state the FMU hands out can be restored, also one taken before initialization with a
 * start value that only the relations at initialization refuse. */
static void test_state_before_init_restores(void) {
    fmi2Component c = make("preinit");
    CHECK(set1(c, VR_x_start, 1.0) == fmi2OK, "x_start = 1 m on its own is in range");
    CHECK(set1(c, VR_x_start, 5.0) == fmi2Error && logged("variable x_start"), "x_start = 5 m: %s", last_log);
    fmi2FMUstate s = NULL, r = NULL;
    CHECK(fmi2GetFMUstate(c, &s) == fmi2OK, "get state before init");
    size_t size = 0;
    fmi2SerializedFMUstateSize(c, s, &size);
    fmi2Byte *buf = malloc(size);
    CHECK(fmi2SerializeFMUstate(c, s, buf, size) == fmi2OK, "serialize before init");
    CHECK(fmi2DeSerializeFMUstate(c, buf, size, &r) == fmi2OK, "own pre-init state refused: %s", last_log);
    CHECK(fmi2SetFMUstate(c, r) == fmi2OK, "set restored pre-init state");
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "restored state is instantiated");
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("x_start"), "relations at init: %s", last_log);
    free(buf);
    fmi2FreeInstance(c);
}

/* 8: FMU states still held at fmi2FreeInstance are freed with it. */
static long live_blocks = 0;
static void *count_calloc(size_t n, size_t size) {
    void *p = calloc(n, size);
    if (p) live_blocks++;
    return p;
}
static void count_free(void *p) {
    if (p) live_blocks--;
    free(p);
}
static const fmi2CallbackFunctions counting = {logger, count_calloc, count_free, NULL, NULL};

static void test_free_instance_frees_states(void) {
    fmi2Component c = fmi2Instantiate("leak", fmi2CoSimulation, GUID, NULL, &counting, fmi2False, fmi2False);
    fmi2ValueReference vr[] = {VR_T_d, VR_u};
    double val[] = {2e-3, 0.3};
    fmi2SetReal(c, vr, 2, val);
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    for (int k = 0; k < 5; k++) {
        double u = 0.3 + 0.01 * k;
        set1(c, VR_u, u);
        fmi2DoStep(c, k * 1e-3, 1e-3, fmi2True);
    }
    fmi2FMUstate s1 = NULL, s2 = NULL, s3 = NULL;
    fmi2GetFMUstate(c, &s1);
    fmi2GetFMUstate(c, &s2);
    fmi2GetFMUstate(c, &s2); /* reused in place */
    size_t size = 0;
    fmi2SerializedFMUstateSize(c, s1, &size);
    fmi2Byte *buf = malloc(size);
    fmi2SerializeFMUstate(c, s1, buf, size);
    fmi2DeSerializeFMUstate(c, buf, size, &s3);
    free(buf);
    CHECK(live_blocks > 1, "states hold no memory? %ld blocks", live_blocks);
    fmi2FreeInstance(c);
    CHECK(live_blocks == 0, "%ld blocks left after fmi2FreeInstance with three states held", live_blocks);
}

/* 10: a buffer with a recomputed checksum is still checked value by value, as fmi2SetReal would. */
static unsigned long long fnv1a(const fmi2Byte *b, size_t n) {
    unsigned long long h = 1469598103934665603ULL;
    for (size_t k = 0; k < n; k++) {
        h ^= (unsigned char)b[k];
        h *= 1099511628211ULL;
    }
    return h;
}

/* The effects coulomb_friction, force_exponent and amplifier_dead_zone (docs/model.md): off by
 * default, each changes the levitating ball's response when on, and x_n must lie below x_0. */
static double levitate_with(MaglevVR vr, double value, double *x_end) {
    double u_eq;
    fmi2Component c = make_levitating_with(maglev_variables[vr].name, vr, value, &u_eq);
    fmi2ValueReference u = VR_u, out[] = {VR_y, VR_x};
    double kick = u_eq * 1.02, y[2] = {0, 0};
    fmi2SetReal(c, &u, 1, &kick);
    for (int k = 0; k < 20; k++) CHECK(fmi2DoStep(c, k * 1e-3, 1e-3, fmi2True) == fmi2OK, "step: %s", last_log);
    fmi2GetReal(c, out, 2, y);
    *x_end = y[1];
    fmi2FreeInstance(c);
    return y[0];
}

static void test_new_effects(void) {
    double x_base, x_eff;
    double y_base = levitate_with(VR_F_c, 0.0, &x_base);
    CHECK(levitate_with(VR_n_F, 2.0, &x_eff) == y_base && x_eff == x_base, "n_F = 2 is not Eq. 8 exactly");
    CHECK(levitate_with(VR_u_dz, 0.0, &x_eff) == y_base, "u_dz = 0 changes the response");
    levitate_with(VR_F_c, 2e-3, &x_eff);
    CHECK(x_eff < x_base - 1e-7, "friction does not slow the rising ball: %g vs %g", x_eff, x_base);
    levitate_with(VR_n_F, 3.0, &x_eff);
    CHECK(fabs(x_eff - x_base) > 1e-7, "n_F = 3 changes nothing: %g vs %g", x_eff, x_base);
    levitate_with(VR_u_dz, 0.2, &x_eff);
    CHECK(x_eff < x_base - 1e-6, "a dead zone does not lower the current: %g vs %g", x_eff, x_base);
    /* the second force lag (eddy_lag): off at beta_F = 0 whatever T_F2, and a share of the force that
     * follows the kick late slows the rising ball */
    CHECK(levitate_with(VR_beta_F, 0.0, &x_eff) == y_base && x_eff == x_base, "beta_F = 0 changes the response");
    CHECK(levitate_with(VR_T_F2, 0.5, &x_eff) == y_base && x_eff == x_base, "T_F2 alone changes the response");
    levitate_with(VR_beta_F, 0.6, &x_eff);
    CHECK(x_eff < x_base - 1e-7, "a slow force share does not slow the rising ball: %g vs %g", x_eff, x_base);
    {   /* its state F2 goes through the serialized image: a restored plant steps on as the original */
        char msg[MAGLEV_MSG_LEN] = "";
        MaglevPlant a, b;
        maglev_defaults(&a);
        maglev_defaults(&b);
        double x = 0.0032, i = (8.3e-3 - x) * sqrt(8.4e-3 * 9.81 / 6.9e-6);
        maglev_set_param(&a, VR_x_start, x);
        maglev_set_param(&a, VR_beta_F, 0.6);
        maglev_set_param(&a, VR_T_F2, 0.015);
        maglev_set_param(&a, VR_T_F, 1e-3);
        CHECK(maglev_initialize(&a, 0.0, i / 1.5 * 1.02, &maglev_std_allocator, msg, sizeof msg) == 0, "init: %s", msg);
        CHECK(maglev_step(&a, 5e-3, &maglev_std_allocator, msg, sizeof msg) == 0, "step: %s", msg);
        CHECK(a.F2 > 0 && a.F2 != maglev_force(&a, maglev_get(&a, VR_i), a.x, NULL, NULL), "F2 = %g not lagging", a.F2);
        MaglevTag tag = {0, 0, {0, 0, 0}};
        size_t n = maglev_serialized_size(&a);
        unsigned char *buf = malloc(n);
        maglev_serialize(&a, &tag, buf);
        CHECK(maglev_deserialize(&b, &tag, buf, n, &maglev_std_allocator, msg, sizeof msg) == 0, "restore: %s", msg);
        CHECK(b.F2 == a.F2, "F2 restored as %g, was %g", b.F2, a.F2);
        maglev_step(&a, 5e-3, &maglev_std_allocator, msg, sizeof msg);
        maglev_step(&b, 5e-3, &maglev_std_allocator, msg, sizeof msg);
        CHECK(a.x == b.x && a.F2 == b.F2, "restored plant differs: x %g vs %g", b.x, a.x);
        b.F2 = -1.0; /* a negative slow force is no state the plant can have */
        CHECK(maglev_check_plant(&b, msg, sizeof msg) != 0 && strstr(msg, "variable F2"), "F2 < 0 accepted: %s", msg);
        free(buf);
        maglev_release(&a, &maglev_std_allocator);
        maglev_release(&b, &maglev_std_allocator);
    }
    /* lags far below a substep, down to denormals (h/T overflows to inf: fuzz seed 3978), are no lag */
    const MaglevVR lags[] = {VR_T_y, VR_T_a};
    const double tiny[] = {1e-300, 4.9e-324};
    for (int k = 0; k < 2; k++)
        for (int j = 0; j < 2; j++) {
            double y_none = levitate_with(lags[k], 0.0, &x_eff), y_lag = levitate_with(lags[k], tiny[j], &x_eff);
            CHECK(isfinite(y_lag) && fabs(y_lag - y_none) < 1e-9, "%s = %g: y %g against %g without it",
                  maglev_variables[lags[k]].name, tiny[j], y_lag, y_none);
        }
    /* x_n at or beyond x_0 is refused when initialisation ends, naming x_n */
    fmi2Component c = make("xn");
    fmi2ValueReference xn = VR_x_n;
    double bad = 9e-3;
    CHECK(fmi2SetReal(c, &xn, 1, &bad) == fmi2OK, "x_n alone is fine");
    fmi2SetupExperiment(c, 0, 0, 0, 0, 0);
    fmi2EnterInitializationMode(c);
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("variable x_n"), "x_n >= x_0 accepted: %s", last_log);
    fmi2FreeInstance(c);
}

/* The physics rig files need (docs/model.md, "Other rigs"): Inteco's exponential force law and a
 * voltage-driven coil with L(x, i), checked against their closed forms on the plant API. */
static void test_rig_physics(void) {
    char msg[MAGLEV_MSG_LEN];
    MaglevPlant m;
    maglev_defaults(&m);
    /* exponential law alone: F = k_e*exp(-(x_0 - x)/z_e)*i^2, its partials, the current that holds */
    maglev_set_param(&m, VR_k_c, 0.0);
    maglev_set_param(&m, VR_k_e, 3.0);
    maglev_set_param(&m, VR_z_e, 5.8e-3);
    maglev_set_param(&m, VR_m_k, 0.06);
    CHECK(maglev_check_params(&m, msg, sizeof msg) == 0, "exponential law refused: %s", msg);
    double x = 2e-3, i = 1.1, dFdx, dFdi, gap = 8.3e-3 - x;
    double F = maglev_force(&m, i, x, &dFdx, &dFdi), want = 3.0 * exp(-gap / 5.8e-3) * i * i;
    CHECK(fabs(F - want) <= 1e-14 * want, "exponential force %.17g, want %.17g", F, want);
    CHECK(fabs(dFdx - want / 5.8e-3) <= 1e-12 * dFdx, "dF/dx %.17g, want %.17g", dFdx, want / 5.8e-3);
    CHECK(fabs(dFdi - 2 * want / i) <= 1e-12 * dFdi, "dF/di %.17g, want %.17g", dFdi, 2 * want / i);
    double ieq = maglev_equilibrium_current(&m, x);
    CHECK(fabs(maglev_force(&m, ieq, x, NULL, NULL) - 0.06 * 9.81) <= 1e-12, "equilibrium current %g does not hold", ieq);
    maglev_set_param(&m, VR_k_e, 0.0);
    CHECK(maglev_check_params(&m, msg, sizeof msg) != 0 && strstr(msg, "variable k_c"), "no force law accepted: %s", msg);

    /* a voltage drive with the ball held on the lower stop: L di/dt = V - R i, so
     * i(t) = V/R*(1 - exp(-t*R/L)) with L = L_0 + L_x*exp(-(x_0 - x_min)/z_L) */
    maglev_defaults(&m);
    double R = 4.17, L0 = 0.065, Lx = 0.04, zL = 6.3e-3, V = 2.0;
    maglev_set_param(&m, VR_R_c, R);
    maglev_set_param(&m, VR_L_0, L0);
    maglev_set_param(&m, VR_L_x, Lx);
    maglev_set_param(&m, VR_z_L, zL);
    maglev_set_param(&m, VR_k_DA, 10.0);
    maglev_set_param(&m, VR_k_c, 1e-9); /* too weak to lift the ball: it stays on the stop */
    CHECK(maglev_initialize(&m, 0.0, V / 10.0, &maglev_std_allocator, msg, sizeof msg) == 0, "init: %s", msg);
    double L = L0 + Lx * exp(-8.3e-3 / zL), worst = 0;
    for (int k = 1; k <= 100; k++) {
        CHECK(maglev_step(&m, 1e-3, &maglev_std_allocator, msg, sizeof msg) == 0, "step: %s", msg);
        double exact = V / R * (1 - exp(-k * 1e-3 * R / L));
        if (fabs(maglev_get(&m, VR_i) - exact) > worst) worst = fabs(maglev_get(&m, VR_i) - exact);
    }
    CHECK(worst < 1e-9, "voltage-driven current off its closed form by %g A", worst);
    CHECK(m.x == 0.0 && m.contact == CONTACT_LOWER, "the ball left the stop: x = %g", m.x);
    /* the steady input for a current: V = R*i */
    double u = maglev_input_for_current(&m, 0.3);
    CHECK(fabs(u * 10.0 - R * 0.3) < 1e-12, "input for 0.3 A is %g MU, want %g", u, R * 0.3 / 10.0);
    maglev_release(&m, &maglev_std_allocator);

    /* the floor V_min and a current-dependent L: with v = 0, (L + i dL/di) di/dt = V - R i. The
     * steady state is V/R whatever L(i) is; a floor above the commanded voltage wins. */
    maglev_defaults(&m);
    maglev_set_param(&m, VR_R_c, R);
    maglev_set_param(&m, VR_L_0, L0);
    maglev_set_param(&m, VR_L_i, 0.03);
    maglev_set_param(&m, VR_a_i, 5.3);
    maglev_set_param(&m, VR_b_i, 1.04);
    maglev_set_param(&m, VR_V_min, 0.5);
    maglev_set_param(&m, VR_k_DA, 10.0);
    maglev_set_param(&m, VR_k_c, 1e-9);
    CHECK(maglev_initialize(&m, 0.0, 0.01, &maglev_std_allocator, msg, sizeof msg) == 0, "init: %s", msg);
    CHECK(maglev_step(&m, 2.0, &maglev_std_allocator, msg, sizeof msg) == 0, "step: %s", msg);
    CHECK(fabs(maglev_get(&m, VR_i) - 0.5 / R) < 1e-9, "floor V_min: i = %.12g, want %.12g", maglev_get(&m, VR_i), 0.5 / R);
    maglev_release(&m, &maglev_std_allocator);
    maglev_set_param(&m, VR_L_i, 0.05); /* L_0 - L_i*pi/2 < 0 */
    CHECK(maglev_check_params(&m, msg, sizeof msg) != 0 && strstr(msg, "variable L_i"), "negative L accepted: %s", msg);
}

static void test_deserialize_checks_values(void) {
    double u_eq;
    fmi2Component c = make_levitating("values", &u_eq);
    fmi2DoStep(c, 0, 1e-3, fmi2True);
    fmi2FMUstate s = NULL;
    fmi2GetFMUstate(c, &s);
    size_t size = 0;
    fmi2SerializedFMUstateSize(c, s, &size);
    fmi2Byte *buf = malloc(size), *bad = malloc(size);
    fmi2SerializeFMUstate(c, s, buf, size);
    /* layout (maglev_plant.c): 28-byte header, the parameters, then time, u, x, v, i, F, xs, F2, the experiment
     * (startTime, stopTime, tolerance; neither of the last two defined here), contact, the experiment's flags */
    size_t state_at = 28 + 8 * (size_t)MAGLEV_NPARAMS, flags_at = state_at + 11 * 8 + 4;
    struct { size_t at; double value; const char *what; } cases[] = {
        {state_at + 2 * 8, 8.3e-3, "x = x_0"},   {state_at + 2 * 8, -5.0, "x = -5 m"},
        {state_at + 4 * 8, -1.0, "i = -1 A"},    {state_at + 4 * 8, 2.0, "i above i_max"},
        {state_at + 3 * 8, NAN, "v = NaN"},      {state_at + 0 * 8, 1e300, "time = 1e300 s"},
        {28 + 8 * (size_t)(VR_x_max - MAGLEV_FIRST_PARAM), 9e-3, "x_max above x_0"},
        {28 + 8 * (size_t)(VR_m_k - MAGLEV_FIRST_PARAM), -1.0, "m_k < 0"},
        {state_at + 7 * 8, 0.5, "F2 = 0.5 N without the second force lag"},
        {state_at + 8 * 8, NAN, "startTime NaN"}, {state_at + 8 * 8, 2e9, "startTime 2e9 s"},
        {state_at + 9 * 8, 1.0, "an undefined stopTime of 1 s"}, {state_at + 10 * 8, 1e-6, "an undefined tolerance"},
        {flags_at, 0.0, "flags: tolerance 0 defined"}, {flags_at, 0.0, "flags: unknown bit"},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        memcpy(bad, buf, size);
        if (cases[k].at == flags_at) {
            unsigned int flags = strstr(cases[k].what, "unknown") ? 4u : 2u;
            memcpy(bad + flags_at, &flags, 4);
        } else {
            memcpy(bad + cases[k].at, &cases[k].value, 8);
        }
        unsigned long long sum = fnv1a(bad, size - 8);
        memcpy(bad + size - 8, &sum, 8);
        fmi2FMUstate r = NULL;
        last_log[0] = 0;
        CHECK(fmi2DeSerializeFMUstate(c, bad, size, &r) == fmi2Error && r == NULL, "%s accepted", cases[k].what);
        CHECK(logged("cannot have"), "%s: %s", cases[k].what, last_log);
        CHECK(cases[k].at < state_at + 8 * 8 || logged("experiment"), "%s: %s", cases[k].what, last_log);
    }
    /* the untouched buffer, its checksum recomputed, still restores: the test edits only values */
    memcpy(bad, buf, size);
    fmi2FMUstate r = NULL;
    CHECK(fmi2DeSerializeFMUstate(c, bad, size, &r) == fmi2OK, "valid buffer refused: %s", last_log);
    free(buf);
    free(bad);
    fmi2FreeInstance(c);
}

/* 11: an fmi2Instantiate that returns NULL has told the logger why (FMI 2.0, fmi2Instantiate), also when
 * the importer's allocator fails or is missing (found by tests/c/fuzz_fmu.c). */
static void *failing_calloc(size_t n, size_t size) {
    (void)n; (void)size;
    return NULL;
}

static void test_instantiate_failure_logged(void) {
    fmi2CallbackFunctions cb = {logger, failing_calloc, free, NULL, NULL};
    int before = n_logs;
    last_log[0] = 0;
    CHECK(fmi2Instantiate("oom", fmi2CoSimulation, GUID, NULL, &cb, fmi2False, fmi2False) == NULL, "no memory, yet an instance");
    CHECK(n_logs > before && logged("memory"), "NULL without a log message on a failed allocation: %s", last_log);
    cb.allocateMemory = NULL;
    before = n_logs;
    last_log[0] = 0;
    CHECK(fmi2Instantiate("noalloc", fmi2CoSimulation, GUID, NULL, &cb, fmi2False, fmi2False) == NULL, "no allocator accepted");
    CHECK(n_logs > before && logged("allocateMemory"), "NULL without a log message on a missing allocator: %s", last_log);
}

/* 12: a refused fmi2DoStep leaves the time where it was, although the FMU absorbs a communication point
 * within rounding of its time: near the end of the time range, the point it was handed would lie outside,
 * and the FMU's own state could no longer be restored (found by tests/c/fuzz_fmu.c). */
static void test_refused_step_keeps_time(void) {
    fmi2Component c = make("edge");
    const double t0 = -MAGLEV_TIME_MAX;
    fmi2SetupExperiment(c, fmi2False, 0, t0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "init at t = %g: %s", t0, last_log);
    /* 0.5 s before t0 is within the matching tolerance at |t| = 1e9; the step would end before -1e9 s */
    CHECK(fmi2DoStep(c, t0 - 0.5, 1e-3, fmi2True) == fmi2Error && logged("time range"), "step out of range: %s", last_log);
    double t = 0;
    CHECK(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &t) == fmi2OK && t == t0, "refused step moved the time to %.17g", t);
    fmi2FMUstate s = NULL, r = NULL;
    size_t size = 0;
    fmi2GetFMUstate(c, &s);
    fmi2SerializedFMUstateSize(c, s, &size);
    fmi2Byte *buf = malloc(size);
    fmi2SerializeFMUstate(c, s, buf, size);
    CHECK(fmi2DeSerializeFMUstate(c, buf, size, &r) == fmi2OK, "own state after a refused step refused: %s", last_log);
    free(buf);
    /* a step refused for its work budget keeps the time too (levitating at 1 us substeps, as in test 4) */
    fmi2Component d = make("budget");
    double x = 0.0032, i = (8.3e-3 - x) * sqrt(8.4e-3 * 9.81 / 6.9e-6);
    fmi2ValueReference vr[] = {VR_x_start, VR_i_start, VR_u, VR_solver_step};
    double val[] = {x, i, i / 1.5, 1e-6};
    fmi2SetReal(d, vr, 4, val);
    fmi2SetupExperiment(d, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(d);
    fmi2ExitInitializationMode(d);
    double t1 = 1e-13; /* within rounding of 0: a step that is taken starts there */
    CHECK(fmi2DoStep(d, t1, 10.0, fmi2True) == fmi2Error && logged("RK4 steps"), "10 s at 1 us substeps: %s", last_log);
    CHECK(fmi2GetRealStatus(d, fmi2LastSuccessfulTime, &t) == fmi2OK && t == 0.0, "refused step moved the time to %.17g", t);
    fmi2FreeInstance(c);
    fmi2FreeInstance(d);
}

/* A calibrated FMU's GUID, issued by the packager in resources/guid.txt: exactly that GUID is
 * accepted (the built-in one no longer), and a guid.txt without a GUID is refused, naming the file. */
static void write_file(const char *path, const char *text) {
    CHECK(write_text(path, text) == 0, "cannot write %s", path);
}

static void test_issued_guid(void) {
    char dir[512], uri[600], file[600];
    CHECK(make_temp_dir(dir, sizeof dir, "guid") != NULL, "cannot make a temporary folder");
    folder_uri(dir, uri, sizeof uri); /* file:///C:/x on Windows: mf_uri_to_path turns it into C:/x */
    snprintf(file, sizeof file, "%s/guid.txt", dir);
    const char *issued = "{0b6c2a8e-1111-5222-8333-444455556666}";
    write_file(file, "{0b6c2a8e-1111-5222-8333-444455556666}\n");
    fmi2Component c = fmi2Instantiate("cal", fmi2CoSimulation, issued, uri, &callbacks, 0, 0);
    CHECK(c != NULL, "issued GUID refused: %s", last_log);
    fmi2FreeInstance(c);
    CHECK(fmi2Instantiate("cal", fmi2CoSimulation, GUID, uri, &callbacks, 0, 0) == NULL && logged(issued) &&
          logged("guid.txt"), "built-in GUID accepted by a calibrated FMU: %s", last_log);
    CHECK(fmi2Instantiate("cal", fmi2CoSimulation, "{0b6c2a8e-1111-5222-8333-444455556667}", uri, &callbacks, 0, 0) ==
          NULL, "a tampered GUID accepted");
    write_file(file, "not a guid\n");
    CHECK(fmi2Instantiate("cal", fmi2CoSimulation, GUID, uri, &callbacks, 0, 0) == NULL && logged("resources/guid.txt"),
          "a guid.txt without a GUID accepted: %s", last_log);
    remove(file);
    remove_dir(dir);
    /* no guid.txt: the built-in GUID, as before */
    c = fmi2Instantiate("nominal", fmi2CoSimulation, GUID, uri, &callbacks, 0, 0);
    CHECK(c != NULL, "built-in GUID refused without guid.txt: %s", last_log);
    fmi2FreeInstance(c);
}

/* 13 (defect 4 of docs/fuzz.md): fmi2Reset puts the FMU into the state right after fmi2Instantiate, and a
 * rig's or calibrated FMU's start values in resources/start_values.txt are part of that state: reset used to
 * put the C defaults in their place (k_c back to 6.9e-6), return OK and log nothing. The file is gone before
 * the reset: the instance keeps what it read, as an importer may clean up the unpacked FMU early. */
static void test_reset_keeps_start_values(void) {
    char dir[512], uri[600], file[600];
    if (!make_temp_dir(dir, sizeof dir, "reset")) {
        CHECK(0, "cannot make a temporary folder");
        return;
    }
    folder_uri(dir, uri, sizeof uri);
    snprintf(file, sizeof file, "%s/start_values.txt", dir);
    write_file(file, "# a rig's parameters\nk_c 1.5e-05\nsolver_step 5e-05\n");
    fmi2Component c = fmi2Instantiate("rig", fmi2CoSimulation, GUID, uri, &callbacks, fmi2False, fmi2True);
    CHECK(c != NULL, "rig FMU refused: %s", last_log);
    remove(file);
    remove_dir(dir);
    if (!c) return;
    for (int round = 0; round < 2; round++) {
        fmi2Status st;
        CHECK(fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0) == fmi2OK, "round %d: setup: %s", round,
              last_log);
        CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "round %d: enter: %s", round, last_log);
        double kc = get1(c, VR_k_c, &st), h = get1(c, VR_solver_step, NULL);
        CHECK(st == fmi2OK && kc == 1.5e-5 && h == 5e-5, "round %d: k_c = %g, solver_step = %g, not the rig's "
              "1.5e-05, 5e-05", round, kc, h);
        CHECK(set1(c, VR_k_c, 2e-5) == fmi2OK, "round %d: k_c settable in initialization mode", round);
        CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "round %d: exit: %s", round, last_log);
        CHECK(fmi2DoStep(c, 0.0, 1e-3, fmi2True) == fmi2OK, "round %d: step: %s", round, last_log);
        last_log[0] = 0;
        CHECK(fmi2Reset(c) == fmi2OK, "round %d: reset: %s", round, last_log);
        CHECK(logged("fmi2Reset") && logged("start_values.txt"), "round %d: reset logs no word of the start "
              "values (logging on): '%s'", round, last_log);
    }
    fmi2FreeInstance(c);
}

/* The plant's previous format (version 3: no experiment between xs and contact, no flags after it),
 * made from a version-4 image, is refused by its version, not misread. */
static void plant_v3_image_refused(fmi2Component d, const fmi2Byte *buf, size_t size) {
    size_t at = 28 + 8 * ((size_t)MAGLEV_NPARAMS + 7), old_size = size - 28;
    if (size <= at + 32) {
        CHECK(0, "the serialized state (%zu bytes) is shorter than its version-4 layout", size);
        return;
    }
    fmi2Byte *old = malloc(old_size);
    memcpy(old, buf, at);
    memcpy(old + at, buf + at + 24, 4);                      /* contact */
    memcpy(old + at + 4, buf + at + 32, size - at - 32 - 8); /* the delay history */
    unsigned int v3 = 3;
    memcpy(old + 4, &v3, 4);
    unsigned long long sum = fnv1a(old, old_size - 8);
    memcpy(old + old_size - 8, &sum, 8);
    fmi2FMUstate o = NULL;
    last_log[0] = 0;
    CHECK(fmi2DeSerializeFMUstate(d, old, old_size, &o) == fmi2Error && o == NULL && logged("version 3"),
          "a version-3 image: '%s'", last_log);
    free(old);
}

/* 14 (defect 5 of docs/fuzz.md): an FMU state holds the experiment fmi2SetupExperiment gave (start, stop and
 * whether it is defined, tolerance): it held the plant and the state machine only, so that after a reset and
 * fmi2SetFMUstate the FMU started at 0 instead of 5 s, refused DoStep(5, 1e-3) and stepped past the stop time.
 * The same through the serialized form, in another instance; the format's version went from 3 to 4 with it,
 * and old images are refused by their version. */
static void test_state_holds_experiment(void) { check_state_holds_experiment(plant_v3_image_refused); }

/* 15: the work budget is decided before integrating (defect 6 of docs/fuzz.md). A step it refuses spent the
 * whole budget first (500000 RK4 substeps, up to a quarter of a second), and its message blamed solver_step
 * also where the friction, the voltage drive or the force lag set the substeps. Now it is refused at once,
 * no RK4 evaluation spent (the plant's work counter), naming what sets the substeps; a long step within the
 * budget still runs. An amplifier transient under a force lag is named too (the plant case). The FMU cases
 * have a voltage drive (R_c > 0): its current has no closed form, so the ball never counts as at rest, and
 * every one of these steps was refused before too (after the work). */
static fmi2Component make_free_ball(const char *name, const MaglevVR *vr, const double *val, int n) {
    fmi2Component c = make(name);
    set1(c, VR_x_start, 0.0032); /* between the stops: the ball cannot be at rest */
    for (int k = 0; k < n; k++) CHECK(set1(c, vr[k], val[k]) == fmi2OK, "%s: %s", name, last_log);
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "%s: %s", name, last_log);
    return c;
}

static void test_budget_decided_before_integrating(void) {
    /* the plant: a refused step has spent nothing, an accepted one its substeps */
    char msg[MAGLEV_MSG_LEN] = "";
    MaglevPlant m;
    maglev_defaults(&m);
    double x = 0.0032, i = (8.3e-3 - x) * sqrt(8.4e-3 * 9.81 / 6.9e-6);
    maglev_set_param(&m, VR_x_start, x);
    maglev_set_param(&m, VR_i_start, i);
    maglev_set_param(&m, VR_solver_step, 1e-6);
    CHECK(maglev_initialize(&m, 0.0, i / 1.5, &maglev_std_allocator, msg, sizeof msg) == 0, "init: %s", msg);
    m.work = -1;
    CHECK(maglev_step(&m, 10.0, &maglev_std_allocator, msg, sizeof msg) == MAGLEV_REFUSED && m.work == 0 &&
          strstr(msg, "solver_step"), "10 s at 1 us substeps: %ld RK4 evaluations spent: %s", m.work, msg);
    CHECK(maglev_step(&m, 0.2, &maglev_std_allocator, msg, sizeof msg) == 0 && m.work > 100000 &&
          m.work <= MAGLEV_STEP_BUDGET, "0.2 s at 1 us substeps: %ld RK4 evaluations: %s", m.work, msg);
    maglev_release(&m, &maglev_std_allocator);
    /* an amplifier transient under a force lag starts at T_a/8 substeps, in every piece a delayed input
     * change begins: 20000 changes within the delay T_d = 1 s put a 1 s step over the budget */
    maglev_defaults(&m);
    maglev_set_param(&m, VR_T_d, 1.0);
    maglev_set_param(&m, VR_T_F, 1e-3);
    maglev_set_param(&m, VR_T_a, 1e-5);
    CHECK(maglev_initialize(&m, 0.0, 0.3, &maglev_std_allocator, msg, sizeof msg) == 0, "init: %s", msg);
    int ok = 1;
    for (int k = 0; k < 20000 && ok; k++)
        ok = maglev_set_input(&m, k % 2 ? 0.3 : 0.5, &maglev_std_allocator, msg, sizeof msg) == 0 &&
             maglev_step(&m, 5e-5, &maglev_std_allocator, msg, sizeof msg) == 0;
    CHECK(ok, "20000 steps of 50 us: %s", msg);
    CHECK(maglev_step(&m, 0.999, &maglev_std_allocator, msg, sizeof msg) == MAGLEV_REFUSED && m.work == 0 &&
          strstr(msg, "T_a = 1e-05 s") && strstr(msg, "pieces (the delay T_d)") && !strstr(msg, "solver_step"),
          "a 1 s step through 20000 input changes: %ld RK4 evaluations: %s", m.work, msg);
    maglev_release(&m, &maglev_std_allocator);

    /* the FMU: the message names what sets the substeps; the instance carries on */
    struct {
        const char *what;
        int n;
        MaglevVR vr[2];
        double val[2], h;
        const char *names[2];
    } cases[] = { /* R_c = 1 Ohm with L_0 = 0.1 H: the coil allows substeps of 20 ms, so the others set them */
        {"solver_step", 2, {VR_R_c, VR_solver_step}, {1.0, 1e-6}, 10.0, {"solver_step = 1e-06 s"}},
        {"friction", 2, {VR_R_c, VR_F_c}, {1.0, 2e-2}, 100.0, {"F_c = 0.02 N"}}, /* substeps of 21 us */
        {"force lag", 2, {VR_R_c, VR_T_F}, {1.0, 1e-5}, 20.0, {"T_F = 1e-05 s"}},  /* 20 us */
        {"voltage drive", 2, {VR_R_c, VR_L_0}, {4.17, 1e-4}, 10.0, {"R_c = 4.17 Ohm", "L_0 = 0.0001 H"}}, /* 4.8 us */
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        fmi2Component c = make_free_ball(cases[k].what, cases[k].vr, cases[k].val, cases[k].n);
        last_log[0] = 0;
        CHECK(fmi2DoStep(c, 0.0, cases[k].h, fmi2True) == fmi2Error, "%s: a %g s step not refused", cases[k].what,
              cases[k].h);
        /* white box: the FMI 2.0 instance begins with the MfInstance that holds the plant as its model */
        long work = ((const MaglevPlant *)((const MfInstance *)c)->data)->work;
        CHECK(work == 0, "%s: the refused step spent %ld RK4 evaluations", cases[k].what, work);
        CHECK(logged("RK4 steps") && logged("over the budget") && logged("shorter communication steps"),
              "%s: message '%s'", cases[k].what, last_log);
        for (int j = 0; j < 2 && cases[k].names[j]; j++)
            CHECK(logged(cases[k].names[j]), "%s: the message does not name %s: '%s'", cases[k].what,
                  cases[k].names[j], last_log);
        CHECK(k == 0 || !logged("solver_step"), "%s: the message blames solver_step: '%s'", cases[k].what, last_log);
        double t = -1;
        CHECK(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &t) == fmi2OK && t == 0.0, "%s: time %g", cases[k].what, t);
        CHECK(fmi2DoStep(c, 0.0, 1e-3, fmi2True) == fmi2OK, "%s: no step after the refused one: %s", cases[k].what,
              last_log);
        fmi2FreeInstance(c);
    }
    /* a long step within the budget runs, every substep integrated: 40 s of 0.1 ms (the impact on the floor
     * adds a few evaluations) */
    const MaglevVR rc = VR_R_c;
    const double one = 1.0;
    fmi2Component c = make_free_ball("long", &rc, &one, 1);
    CHECK(fmi2DoStep(c, 0.0, 40.0, fmi2True) == fmi2OK, "40 s at 0.1 ms substeps: %s", last_log);
    long work = ((const MaglevPlant *)((const MfInstance *)c)->data)->work;
    CHECK(work >= 400000 && work <= MAGLEV_WORK_MAX, "40 s: %ld RK4 evaluations", work);
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
    test_step_work_bounded();
    test_long_steps();
    test_pickup_phase_finite();
    test_init_mode_outputs();
    test_start_velocity();
    test_state_before_init_restores();
    test_free_instance_frees_states();
    test_deserialize_checks_values();
    test_new_effects();
    test_rig_physics();
    test_instantiate_failure_logged();
    test_refused_step_keeps_time();
    test_issued_guid();
    test_reset_keeps_start_values();
    test_state_holds_experiment();
    test_budget_decided_before_integrating();
    printf("%d checks: %d passed, %d failed\n", checks, checks - failures, failures);
    return failures ? 1 : 0;
}
