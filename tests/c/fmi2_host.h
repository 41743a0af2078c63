/* What the FMI 2.0 C tests share as the importer: a logger that keeps the last message, the
 * callbacks, make(name), which instantiates the FMU whose GUID the test defines first, serialize(),
 * and the check that an FMU state holds the experiment, which every model behind the glue passes. */
#ifndef MAGLEV_TEST_FMI2_HOST_H
#define MAGLEV_TEST_FMI2_HOST_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "fmi2Functions.h"

#ifndef GUID
#error "define GUID, the FMU's guid, before including fmi2_host.h"
#endif

static char last_log[1024];
static int n_logs = 0;

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

/* Serializes an FMU state into a new buffer (*size bytes); NULL when refused. */
static fmi2Byte *serialize(fmi2Component c, fmi2FMUstate s, size_t *size) {
    *size = 0;
    if (fmi2SerializedFMUstateSize(c, s, size) != fmi2OK || *size == 0) return NULL;
    fmi2Byte *buf = malloc(*size);
    if (buf && fmi2SerializeFMUstate(c, s, buf, *size) != fmi2OK) {
        free(buf);
        return NULL;
    }
    return buf;
}

/* After fmi2SetFMUstate, the instance starts and stops where the state's experiment (start 5 s, stop
 * 6 s) says: enter and exit initialization, the time is 5 s, a step past stop is refused and leaves
 * the instance usable, a step from start runs, a later step past stop is refused too. */
static void check_experiment_restored(fmi2Component c, const char *what) {
    CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "%s: enter: %s", what, last_log);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "%s: exit: %s", what, last_log);
    double t = -1;
    CHECK(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &t) == fmi2OK && t == 5.0, "%s: time %g after "
          "initialization, not the startTime 5 s", what, t);
    last_log[0] = 0;
    CHECK(fmi2DoStep(c, 5.0, 2.0, fmi2True) == fmi2Error && logged("stopTime"), "%s: a step past stopTime 6 s not "
          "refused: '%s'", what, last_log);
    last_log[0] = 0;
    CHECK(fmi2DoStep(c, 5.0, 1e-3, fmi2True) == fmi2OK, "%s: step from startTime 5 s: %s", what, last_log);
    last_log[0] = 0;
    CHECK(fmi2DoStep(c, 5.001, 10.0, fmi2True) == fmi2Error && logged("stopTime"), "%s: a step past stopTime 6 s "
          "not refused: '%s'", what, last_log);
}

/* An FMU state holds the experiment fmi2SetupExperiment gave (start, stop and whether it is defined,
 * tolerance; docs/fuzz.md, defect 5): a state set after a reset, or deserialized into another
 * instance, starts at 5 s and refuses a step past 6 s, and the tolerance is in the serialized bytes.
 * old_image(d, image, size) gets the serialized instantiated state to check that the model's previous
 * format (made from it) is refused by its version. */
static void check_state_holds_experiment(void (*old_image)(fmi2Component d, const fmi2Byte *image, size_t size)) {
    fmi2Component c = make("experiment");
    CHECK(fmi2SetupExperiment(c, fmi2True, 1e-6, 5.0, fmi2True, 6.0) == fmi2OK, "setup: %s", last_log);
    fmi2FMUstate inst = NULL, init = NULL;
    CHECK(fmi2GetFMUstate(c, &inst) == fmi2OK, "state in instantiated: %s", last_log);
    size_t size = 0;
    fmi2Byte *buf = serialize(c, inst, &size);
    CHECK(buf != NULL, "serialize: %s", last_log);
    CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "enter: %s", last_log);
    CHECK(fmi2GetFMUstate(c, &init) == fmi2OK, "state in initialization mode: %s", last_log);
    CHECK(fmi2Reset(c) == fmi2OK, "reset: %s", last_log);
    CHECK(fmi2SetFMUstate(c, inst) == fmi2OK, "set the instantiated state: %s", last_log);
    check_experiment_restored(c, "instantiated state after a reset");
    CHECK(fmi2Reset(c) == fmi2OK, "reset: %s", last_log);
    CHECK(fmi2SetFMUstate(c, init) == fmi2OK, "set the initialization-mode state: %s", last_log);
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "exit: %s", last_log);
    double t = -1;
    CHECK(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &t) == fmi2OK && t == 5.0, "initialization-mode state: "
          "time %g, not 5 s", t);
    CHECK(fmi2DoStep(c, 5.0, 2.0, fmi2True) == fmi2Error && logged("stopTime"), "initialization-mode state: a step "
          "past stopTime 6 s not refused: '%s'", last_log);

    fmi2Component d = make("experiment2");
    fmi2FMUstate r = NULL;
    CHECK(buf && fmi2DeSerializeFMUstate(d, buf, size, &r) == fmi2OK, "deserialize: %s", last_log);
    CHECK(fmi2SetFMUstate(d, r) == fmi2OK, "set the deserialized state: %s", last_log);
    check_experiment_restored(d, "deserialized into another instance");
    /* the tolerance is part of it: the same experiment without one serializes differently */
    fmi2Component e = make("experiment3");
    fmi2SetupExperiment(e, fmi2False, 0, 5.0, fmi2True, 6.0);
    fmi2FMUstate q = NULL;
    fmi2GetFMUstate(e, &q);
    size_t size2 = 0;
    fmi2Byte *buf2 = serialize(e, q, &size2);
    CHECK(buf && buf2 && size2 == size && memcmp(buf, buf2, size) != 0, "the tolerance is not in the serialized "
          "state");
    if (buf) old_image(d, buf, size);
    free(buf);
    free(buf2);
    fmi2FreeInstance(c);
    fmi2FreeInstance(d);
    fmi2FreeInstance(e);
}

#endif
