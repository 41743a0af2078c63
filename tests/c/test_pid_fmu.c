/* C tests of the controller FMU (c/maglev_pid_fmu.c): call sequence, bad values named, the samples
 * and the hold against the controller alone (maglev_replay_control), the step reference, FMU state
 * and its serialisation, a bounded step. Run under ASan/UBSan in CI (MAGLEV_SANITIZE=ON). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "maglev_pid_fmu.h"
#include "maglev_replay.h"
#include "check.h"

#define GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0101}"

#include "fmi2_host.h"

static fmi2Status set1(fmi2Component c, MaglevPidVR vr, double v) {
    fmi2ValueReference r = vr;
    return fmi2SetReal(c, &r, 1, &v);
}

static double get1(fmi2Component c, MaglevPidVR vr) {
    fmi2ValueReference r = vr;
    double v = NAN;
    CHECK(fmi2GetReal(c, &r, 1, &v) == fmi2OK, "getting %s: %s", maglev_pid_variables[vr].name, last_log);
    return v;
}

/* An initialised PID with the step reference w0 -> w1 at t_step and the integrator at u_hold. */
static fmi2Component make_running(const char *name, double u_hold) {
    fmi2Component c = make(name);
    fmi2ValueReference vr[] = {PID_u_hold, PID_w0, PID_w1, PID_t_step, PID_anti_windup, PID_tf};
    double val[] = {u_hold, 0.40, 0.45, 0.005, 1, 0.002};
    CHECK(fmi2SetReal(c, vr, 6, val) == fmi2OK, "set-up: %s", last_log);
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "init: %s", last_log);
    return c;
}

static void test_instantiate_and_call_sequence(void) {
    CHECK(fmi2Instantiate("a", fmi2CoSimulation, "{wrong}", NULL, &callbacks, 0, 0) == NULL && logged("GUID"),
          "wrong GUID accepted");
    CHECK(fmi2Instantiate("a", fmi2ModelExchange, GUID, NULL, &callbacks, 0, 0) == NULL, "ME accepted");
    CHECK(fmi2Instantiate("", fmi2CoSimulation, GUID, NULL, &callbacks, 0, 0) == NULL, "empty name accepted");
    fmi2Component c = make("seq");
    fmi2ValueReference vr = PID_u;
    double v;
    CHECK(fmi2GetReal(c, &vr, 1, &v) == fmi2Error && logged("not allowed in state instantiated"), "get before init");
    CHECK(fmi2DoStep(c, 0, 1e-3, 1) == fmi2Error && logged("fmi2DoStep"), "step before init: %s", last_log);
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error, "exit init before enter");
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    CHECK(set1(c, PID_u_hold, 0.3) == fmi2OK, "u_hold in init mode");
    CHECK(get1(c, PID_u) == 0.3, "in init mode u is the settled start");
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "init: %s", last_log);
    CHECK(set1(c, PID_kp, 1.0) == fmi2Error && logged("kp") && logged("fixed parameter"), "kp after init: %s", last_log);
    CHECK(set1(c, PID_u, 1.0) == fmi2Error && logged("variable u is an output"), "output set: %s", last_log);
    CHECK(set1(c, PID_y, 0.4) == fmi2OK, "input after init: %s", last_log);
    CHECK(fmi2DoStep(c, 0.5, 1e-3, 1) == fmi2Error && logged("does not match"), "wrong communication point");
    CHECK(fmi2DoStep(c, 0, -1, 1) == fmi2Error && logged("communicationStepSize"), "negative step");
    CHECK(fmi2Terminate(c) == fmi2OK, "terminate");
    CHECK(fmi2DoStep(c, 0, 1e-3, 1) == fmi2Error && logged("terminated"), "step after terminate");
    CHECK(fmi2Reset(c) == fmi2OK, "reset");
    fmi2FreeInstance(c);
    fmi2FreeInstance(NULL);
}

static void test_bad_values_named(void) {
    fmi2Component c = make("bad");
    CHECK(set1(c, PID_y, NAN) == fmi2Error && logged("variable y"), "NaN y: %s", last_log);
    CHECK(set1(c, PID_ts, 0.0) == fmi2Error && logged("variable ts"), "ts = 0: %s", last_log);
    CHECK(set1(c, PID_kp, INFINITY) == fmi2Error && logged("variable kp"), "infinite kp: %s", last_log);
    CHECK(set1(c, PID_anti_windup, 1.5) == fmi2Error && logged("anti_windup"), "anti_windup 1.5: %s", last_log);
    CHECK(set1(c, PID_tf, -1) == fmi2Error && logged("variable tf"), "tf < 0: %s", last_log);
    fmi2ValueReference vr[] = {PID_kp, PID_ki};
    double val[] = {5.0, NAN};
    CHECK(fmi2SetReal(c, vr, 2, val) == fmi2Error && logged("variable ki"), "NaN ki: %s", last_log);
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    CHECK(get1(c, PID_u) == 0.0, "a rejected call changed u_hold or kp");
    set1(c, PID_u_min, 2.0); /* u_min > u_max = 1 */
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("u_min < u_max"), "u_min > u_max: %s", last_log);
    set1(c, PID_u_min, 0.0);
    set1(c, PID_u_hold, 1.5);
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("u_hold"), "u_hold beyond u_max: %s", last_log);
    set1(c, PID_u_hold, 0.5);
    set1(c, PID_anti_windup, 3); /* a band with i_lo = i_hi = 0 */
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("i_lo < i_hi"), "empty band: %s", last_log);
    fmi2FreeInstance(c);
}

/* Communication step ts: the FMU gives u[k] = maglev_replay_control's u[k] on the same w and y,
 * exactly; with half steps each sample is taken once and u is held in between. */
static void test_samples_match_the_controller_alone(void) {
    enum { N = 60 };
    double w[N], y[N], u_ref[N];
    for (int k = 0; k < N; k++) {
        w[k] = k * 1e-3 >= 0.005 - 1e-12 ? 0.45 : 0.40;
        y[k] = 0.40 + 0.03 * sin(0.3 * k) + (k > 40 ? 0.5 : 0.0); /* drives u into its limit too */
    }
    MaglevController ctl;
    memset(&ctl, 0, sizeof ctl);
    ctl.kind = 0;
    MaglevPid p = {1e-3, 2.0, 2.97, 0.01, 0.0, 1.0, 0.002, 1, 0.0, 0.0, 1.0};
    ctl.pid = p;
    char msg[256];
    CHECK(maglev_replay_control(&ctl, w, y, NULL, N, 0.37, NULL, u_ref, msg, sizeof msg) == 0, "%s", msg);
    fmi2Component a = make_running("full", 0.37), b = make_running("half", 0.37);
    CHECK(get1(a, PID_u) == 0.37, "after init u is u_hold");
    int same = 1, held = 1;
    double t = 0.0;
    for (int k = 0; k < N; k++) {
        set1(a, PID_y, y[k]);
        set1(b, PID_y, y[k]);
        CHECK(fmi2DoStep(a, k * 1e-3, 1e-3, 1) == fmi2OK, "step %d: %s", k, last_log);
        same &= get1(a, PID_u) == u_ref[k] && get1(a, PID_w) == w[k];
        CHECK(fmi2DoStep(b, t, 0.5e-3, 1) == fmi2OK, "half step %d: %s", k, last_log);
        t += 0.5e-3;
        double u1 = get1(b, PID_u);
        set1(b, PID_y, 99.0); /* no sample in the second half: the input is not read */
        CHECK(fmi2DoStep(b, t, 0.5e-3, 1) == fmi2OK, "half step %d: %s", k, last_log);
        t += 0.5e-3;
        held &= get1(b, PID_u) == u1 && u1 == u_ref[k];
    }
    CHECK(same, "FMU differs from maglev_replay_control at a communication step of ts");
    CHECK(held, "half steps: u not held between samples, or a sample read twice");
    CHECK(u_ref[N - 1] == 0.0 && u_ref[10] > 0.0, "the test does not reach the limit");
    /* a step of 3 ts takes three samples, on the input as it is */
    fmi2Component d = make_running("multi", 0.37);
    set1(d, PID_y, 0.4);
    CHECK(fmi2DoStep(d, 0.0, 3e-3, 1) == fmi2OK, "3 ts step: %s", last_log);
    double yy[3] = {0.4, 0.4, 0.4}, ww[3] = {0.4, 0.4, 0.4}, uu[3];
    maglev_replay_control(&ctl, ww, yy, NULL, 3, 0.37, NULL, uu, msg, sizeof msg);
    CHECK(get1(d, PID_u) == uu[2], "3 ts step: u %.17g, expected %.17g", get1(d, PID_u), uu[2]);
    fmi2FreeInstance(a);
    fmi2FreeInstance(b);
    fmi2FreeInstance(d);
}

static void test_state_and_serialisation(void) {
    fmi2Component c = make_running("state", 0.37);
    set1(c, PID_y, 0.41);
    fmi2DoStep(c, 0.0, 1e-3, 1);
    fmi2FMUstate s = NULL;
    CHECK(fmi2GetFMUstate(c, &s) == fmi2OK, "get state");
    fmi2DoStep(c, 1e-3, 1e-3, 1);
    double u2 = get1(c, PID_u);
    size_t size = 0;
    CHECK(fmi2SerializedFMUstateSize(c, s, &size) == fmi2OK && size > 0, "size");
    fmi2Byte *buf = malloc(size);
    CHECK(fmi2SerializeFMUstate(c, s, buf, size) == fmi2OK, "serialise");
    CHECK(fmi2SerializeFMUstate(c, s, buf, size - 1) == fmi2Error && logged("needed"), "short buffer");
    fmi2Component d = make("other");
    fmi2FMUstate r = NULL;
    CHECK(fmi2DeSerializeFMUstate(d, buf, size, &r) == fmi2OK, "deserialise: %s", last_log);
    CHECK(fmi2SetFMUstate(d, r) == fmi2OK, "set state on another instance");
    CHECK(fmi2DoStep(d, 1e-3, 1e-3, 1) == fmi2OK && get1(d, PID_u) == u2, "restored instance diverges");
    CHECK(fmi2SetFMUstate(c, r) == fmi2Error && logged("not made by this instance"), "foreign state accepted");
    buf[30] ^= 1;
    CHECK(fmi2DeSerializeFMUstate(d, buf, size, &r) == fmi2Error && logged("checksum"), "corrupt state accepted");
    CHECK(fmi2DeSerializeFMUstate(d, buf, size - 1, &r) == fmi2Error, "short state accepted");
    free(buf);
    CHECK(fmi2SetFMUstate(c, s) == fmi2OK && fmi2DoStep(c, 1e-3, 1e-3, 1) == fmi2OK && get1(c, PID_u) == u2,
          "state round trip");
    fmi2FreeFMUstate(c, &s);
    CHECK(s == NULL, "freed state not cleared");
    fmi2FreeInstance(c);
    fmi2FreeInstance(d); /* frees r */
}

static void test_step_work_bounded(void) {
    fmi2Component c = make("bounded");
    set1(c, PID_ts, 1e-6);
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    CHECK(fmi2DoStep(c, 0.0, 1e3, 1) == fmi2Error && logged("samples"), "1e9 samples in one call: %s", last_log);
    CHECK(fmi2DoStep(c, 0.0, 1e-3, 1) == fmi2OK, "the FMU goes on after a refused step: %s", last_log);
    fmi2FreeInstance(c);
}

int main(void) {
    test_instantiate_and_call_sequence();
    test_bad_values_named();
    test_samples_match_the_controller_alone();
    test_state_and_serialisation();
    test_step_work_bounded();
    printf("%d checks: %d passed, %d failed\n", checks, checks - failures, failures);
    return failures ? 1 : 0;
}
