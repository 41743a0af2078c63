/* C tests of the controller FMU (the PID model c/maglev_pid_fmu.c behind the FMI glue
 * c/maglev_fmi_common.c): call sequence, bad values named, the samples and the hold against the
 * controller alone (maglev_replay_control), the step reference, FMU state and its serialisation with the
 * experiment, a bounded step; the FMI 3.0 entry points (c/maglev_fmi3.c, linked in too) against the 2.0
 * ones. Run under ASan/UBSan in CI (MAGLEV_SANITIZE=ON), and under wine in the win64 build. */
#define _POSIX_C_SOURCE 200809L /* mkdtemp (temp_dir.h), for a resources folder */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"
#include "maglev_pid_fmu.h"
#include "maglev_replay.h"
#include "check.h"
#include "temp_dir.h"

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
    MaglevPid p = {1e-3, 2.0, 2.97, 0.01, 0.0, 1.0, 0.002, 1, 0.0, 0.0, 1.0, 0};
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

/* Its previous format (version 1: "MGPID\1", no experiment) is refused by its version. */
static void pid_v1_image_refused(fmi2Component d, const fmi2Byte *buf, size_t size) {
    fmi2Byte *old = malloc(size);
    memcpy(old, buf, size);
    old[5] = 1;
    fmi2FMUstate o = NULL;
    last_log[0] = 0;
    CHECK(fmi2DeSerializeFMUstate(d, old, size, &o) == fmi2Error && o == NULL && logged("version 1"),
          "a version-1 image: '%s'", last_log);
    free(old);
}

/* The FMU state holds the experiment (the defect fixed for the plant in docs/fuzz.md, 5, which the
 * controller had too: its stop time lived outside its FMU states, so a state set after a reset, or
 * deserialized into another instance, stepped past the stop time it was taken with). */
static void test_state_holds_experiment(void) { check_state_holds_experiment(pid_v1_image_refused); }

/* Every state the FMU hands out can be restored: also one taken before initialization with parameters that
 * only the relations at initialization refuse (the controller's own FMI layer checked them in every
 * deserialized state, so it refused its own instantiated state with u_min > u_max). */
static void test_state_before_init_restores(void) {
    fmi2Component c = make("preinit");
    CHECK(set1(c, PID_u_min, 2.0) == fmi2OK, "u_min = 2 > u_max on its own is in range");
    fmi2FMUstate s = NULL, r = NULL;
    CHECK(fmi2GetFMUstate(c, &s) == fmi2OK, "get state before init");
    size_t size = 0;
    fmi2Byte *buf = serialize(c, s, &size);
    CHECK(buf && fmi2DeSerializeFMUstate(c, buf, size, &r) == fmi2OK, "own pre-init state refused: %s", last_log);
    CHECK(fmi2SetFMUstate(c, r) == fmi2OK, "set restored pre-init state");
    fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
    CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "restored state is instantiated");
    CHECK(fmi2ExitInitializationMode(c) == fmi2Error && logged("u_min < u_max"), "relations at init: %s", last_log);
    /* an initialised state with the relations broken (edited, checksum recomputed) is refused */
    set1(c, PID_u_min, 0.0);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "init: %s", last_log);
    fmi2FMUstate t = NULL;
    fmi2GetFMUstate(c, &t);
    size_t n = 0;
    fmi2Byte *b = serialize(c, t, &n);
    if (b) {
        double bad = 2.0;
        memcpy(b + 24 + 8 * PID_u_min, &bad, 8); /* the variables follow the 24-byte header (maglev_pid_fmu.c) */
        unsigned long long h = 1469598103934665603ULL;
        for (size_t k = 0; k + 8 < n; k++) h = (h ^ (unsigned char)b[k]) * 1099511628211ULL;
        memcpy(b + n - 8, &h, 8);
        fmi2FMUstate o = NULL;
        CHECK(fmi2DeSerializeFMUstate(c, b, n, &o) == fmi2Error && logged("cannot have") && logged("u_min"),
              "initialised state with u_min > u_max: %s", last_log);
    }
    free(b);
    free(buf);
    fmi2FreeInstance(c);
}

/* The glue reads resources/start_values.txt for every model: the controller's parameters too, kept by a
 * reset, and a name that is no parameter of the controller refused. */
static void test_start_values_from_resources(void) {
    char dir[512], file[600], uri[700];
    if (!make_temp_dir(dir, sizeof dir, "pid_start")) {
        CHECK(0, "no temporary folder");
        return;
    }
    snprintf(file, sizeof file, "%s/start_values.txt", dir);
    folder_uri(dir, uri, sizeof uri);
    CHECK(write_text(file, "kp 3.5  # a rig's gain\nts 0.002\n") == 0, "cannot write %s", file);
    fmi2Component c = fmi2Instantiate("rig", fmi2CoSimulation, GUID, uri, &callbacks, fmi2False, fmi2False);
    CHECK(c != NULL, "instantiate with start_values.txt: %s", last_log);
    if (c) {
        fmi2SetupExperiment(c, fmi2False, 0, 0.0, fmi2False, 0);
        fmi2EnterInitializationMode(c);
        CHECK(get1(c, PID_kp) == 3.5 && get1(c, PID_ts) == 0.002, "start values not read");
        set1(c, PID_kp, 1.0);
        CHECK(fmi2Reset(c) == fmi2OK, "reset");
        fmi2EnterInitializationMode(c);
        CHECK(get1(c, PID_kp) == 3.5, "reset dropped the start value: kp = %g", get1(c, PID_kp));
        fmi2FreeInstance(c);
    }
    CHECK(write_text(file, "k_c 1e-5\n") == 0, "cannot write %s", file);
    last_log[0] = 0;
    CHECK(fmi2Instantiate("rig", fmi2CoSimulation, GUID, uri, &callbacks, fmi2False, fmi2False) == NULL &&
          logged("k_c is not a parameter"), "a plant parameter for the controller: '%s'", last_log);
    remove(file);
    remove_dir(dir);
}

/* ---- FMI 3.0 (c/maglev_fmi3.c over the same glue and model) ---- */

static char last_log3[1024];
static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    (void)env; (void)status; (void)category;
    snprintf(last_log3, sizeof last_log3, "%s", message);
}

static fmi3Instance make3(const char *name) {
    return fmi3InstantiateCoSimulation(name, GUID, NULL, fmi3False, fmi3False, fmi3False, fmi3False, NULL, 0, NULL,
                                       logger3, NULL);
}

static fmi3Status step3(fmi3Instance c, double t, double h, double *last) {
    fmi3Boolean ev, term, early;
    return fmi3DoStep(c, t, h, fmi3True, &ev, &term, &early, last);
}

/* The FMI 3.0 controller takes the same samples as the FMI 2.0 one, bit for bit; time is value reference
 * MAGLEV_PID_NVARS; its FMU state holds the experiment fmi3EnterInitializationMode gave. */
static void test_fmi3(void) {
    CHECK(fmi3InstantiateCoSimulation("a", "{wrong}", NULL, 0, 0, 0, 0, NULL, 0, NULL, logger3, NULL) == NULL &&
          strstr(last_log3, "instantiationToken"), "wrong token: %s", last_log3);
    fmi3Instance c3 = make3("three");
    fmi2Component c2 = make("two");
    CHECK(c3 != NULL, "instantiate: %s", last_log3);
    fmi3ValueReference vr[] = {PID_u_hold, PID_w0, PID_w1, PID_t_step, PID_anti_windup, PID_tf};
    double val[] = {0.37, 0.40, 0.45, 0.005, 1, 0.002};
    CHECK(fmi3SetFloat64(c3, vr, 6, val, 6) == fmi3OK, "set-up: %s", last_log3);
    fmi2SetReal(c2, vr, 6, val);
    CHECK(fmi3EnterInitializationMode(c3, fmi3False, 0, 0.0, fmi3False, 0) == fmi3OK, "enter: %s", last_log3);
    fmi2SetupExperiment(c2, fmi2False, 0, 0.0, fmi2False, 0);
    fmi2EnterInitializationMode(c2);
    CHECK(fmi3ExitInitializationMode(c3) == fmi3OK && fmi2ExitInitializationMode(c2) == fmi2OK, "init: %s",
          last_log3);
    int same = 1;
    for (int k = 0; k < 50; k++) {
        double y = 0.40 + 0.05 * sin(0.2 * k), last = -1, u3 = NAN;
        fmi3ValueReference ry = PID_y, ru = PID_u;
        fmi3SetFloat64(c3, &ry, 1, &y, 1);
        set1(c2, PID_y, y);
        CHECK(step3(c3, k * 1e-3, 1e-3, &last) == fmi3OK && last == k * 1e-3 + 1e-3, "step %d: %s", k, last_log3);
        fmi2DoStep(c2, k * 1e-3, 1e-3, fmi2True);
        fmi3GetFloat64(c3, &ru, 1, &u3, 1);
        same &= u3 == get1(c2, PID_u);
    }
    CHECK(same, "FMI 3.0 and FMI 2.0 controllers differ");
    fmi3ValueReference vt = MAGLEV_PID_NVARS, bad = MAGLEV_PID_NVARS + 1;
    double t = -1, x;
    CHECK(fmi3GetFloat64(c3, &vt, 1, &t, 1) == fmi3OK && fabs(t - 0.05) < 1e-15, "time = %g", t);
    CHECK(fmi3GetFloat64(c3, &bad, 1, &x, 1) == fmi3Error && strstr(last_log3, "unknown value reference"),
          "vr after time: %s", last_log3);
    fmi3FreeInstance(c3);
    fmi2FreeInstance(c2);

    /* the experiment in the FMU state: taken in initialization mode, set after a reset */
    fmi3Instance e = make3("experiment");
    CHECK(fmi3EnterInitializationMode(e, fmi3True, 1e-6, 5.0, fmi3True, 6.0) == fmi3OK, "enter: %s", last_log3);
    fmi3FMUState s = NULL, r = NULL;
    CHECK(fmi3GetFMUState(e, &s) == fmi3OK, "get state: %s", last_log3);
    size_t size = 0;
    fmi3SerializedFMUStateSize(e, s, &size);
    fmi3Byte *buf = malloc(size);
    CHECK(fmi3SerializeFMUState(e, s, buf, size) == fmi3OK, "serialize: %s", last_log3);
    CHECK(fmi3Reset(e) == fmi3OK && fmi3SetFMUState(e, s) == fmi3OK, "reset, set: %s", last_log3);
    fmi3Instance f = make3("other");
    CHECK(fmi3DeserializeFMUState(f, buf, size, &r) == fmi3OK && fmi3SetFMUState(f, r) == fmi3OK,
          "into another instance: %s", last_log3);
    fmi3Instance both[2] = {e, f};
    for (int k = 0; k < 2; k++) {
        double last = -1;
        CHECK(fmi3ExitInitializationMode(both[k]) == fmi3OK, "exit %d: %s", k, last_log3);
        CHECK(step3(both[k], 5.0, 2.0, &last) == fmi3Error && strstr(last_log3, "stopTime") && last == 5.0,
              "%d: a step past stopTime 6 s not refused: %s", k, last_log3);
        CHECK(step3(both[k], 5.0, 1e-3, &last) == fmi3OK && last == 5.0 + 1e-3, "%d: step from 5 s: %s", k, last_log3);
    }
    free(buf);
    fmi3FreeInstance(e);
    fmi3FreeInstance(f);
}

int main(void) {
    test_instantiate_and_call_sequence();
    test_bad_values_named();
    test_samples_match_the_controller_alone();
    test_state_and_serialisation();
    test_step_work_bounded();
    test_state_holds_experiment();
    test_state_before_init_restores();
    test_start_values_from_resources();
    test_fmi3();
    printf("%d checks: %d passed, %d failed\n", checks, checks - failures, failures);
    return failures ? 1 : 0;
}
