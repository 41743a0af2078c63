/* FMI 2.0 co-simulation entry points of every model: the plant (maglev_plant_fmu.c, build/maglev.fmu)
 * and the PID controller (maglev_pid_fmu.c, build/maglev_pid.fmu), whichever this binary links as
 * maglev_fmu_model. The instance logic is maglev_fmi_common.c, shared with the FMI 3.0 entry points
 * (maglev_fmi3.c); this file maps the FMI 2.0 calls onto it. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "maglev_fmi_common.h"

typedef struct {
    MfInstance base; /* first: an MfInstance* is a Fmu* */
    fmi2CallbackFunctions cb;
} Fmu;

/* The message goes as the format itself (with '%' doubled), because importers written in
 * languages without C varargs (fmpy's ctypes logger) never see variadic arguments. */
static void emit_text(const fmi2CallbackFunctions *cb, const char *name, int status, const char *category,
                      const char *text) {
    if (!cb->logger) return;
    char esc[1024];
    size_t n = 0;
    for (const char *p = text; *p && n + 2 < sizeof esc; p++) {
        if (*p == '%') esc[n++] = '%';
        esc[n++] = *p;
    }
    esc[n] = 0;
    cb->logger(cb->componentEnvironment, name, (fmi2Status)status, category, esc);
}

static void fmu_log(const MfInstance *f, int status, const char *category, const char *message) {
    emit_text(&((const Fmu *)f)->cb, f->name, status, category, message);
}

/* Before an instance exists: every NULL fmi2Instantiate returns is explained this way. */
static void emit(const fmi2CallbackFunctions *cb, const char *name, const char *fmt, ...) {
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    emit_text(cb, name, fmi2Error, "logStatusError", buf);
}

#define F(c) ((MfInstance *)(c))
#define GUARD(fn, mask) \
    do { if (!mf_guard(F(c), fn, mask)) return fmi2Error; } while (0)

static void *fmu_alloc(size_t n, size_t size, void *env) { return ((Fmu *)env)->cb.allocateMemory(n, size); }
static void fmu_release(void *p, void *env) { ((Fmu *)env)->cb.freeMemory(p); }

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    GUARD("fmi2SetDebugLogging", MF_ANY_LIVE);
    return (fmi2Status)mf_set_debug_logging(F(c), "fmi2SetDebugLogging", loggingOn, nCategories, categories);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)visible;
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
    const MfModel *model = &maglev_fmu_model;
    char dir[4096], msg[MAGLEV_MSG_LEN], guid[80];
    const char *resources = fmuResourceLocation && !mf_uri_to_path(fmuResourceLocation, dir, sizeof dir) ? dir : NULL;
    if (mf_accepted_guid(model, resources, guid, sizeof guid, msg, sizeof msg)) {
        emit(functions, nm, "fmi2Instantiate: %s", msg);
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, guid) != 0) {
        emit(functions, nm, "fmi2Instantiate: GUID %s does not match %s%s", fmuGUID ? fmuGUID : "(null)", guid,
             strcmp(guid, model->guid) ? " (issued in resources/guid.txt)" : "");
        return NULL;
    }
    Fmu *f = functions->allocateMemory(1, sizeof *f);
    if (!f) {
        emit(functions, nm, "fmi2Instantiate: out of memory (allocateMemory returned NULL)");
        return NULL;
    }
    f->cb = *functions;
    MaglevAllocator alloc = {fmu_alloc, fmu_release, f};
    if (mf_init(&f->base, model, instanceName, loggingOn, fmu_log, &alloc, MF_NO_TIME_VR, resources, msg,
                sizeof msg)) {
        emit(functions, nm, "fmi2Instantiate: %s", msg);
        functions->freeMemory(f);
        return NULL;
    }
    mf_log(&f->base, MF_OK, "logCalls", "fmi2Instantiate: %s", guid);
    return f;
}

void fmi2FreeInstance(fmi2Component c) {
    Fmu *f = c;
    if (!f) return;
    mf_release(&f->base);
    f->cb.freeMemory(f);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    GUARD("fmi2SetupExperiment", MF_INSTANTIATED);
    return (fmi2Status)mf_setup_experiment(F(c), "fmi2SetupExperiment", toleranceDefined, tolerance, startTime,
                                           stopTimeDefined, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    GUARD("fmi2EnterInitializationMode", MF_INSTANTIATED);
    return (fmi2Status)mf_enter_initialization(F(c));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    GUARD("fmi2ExitInitializationMode", MF_INITIALIZATION_MODE);
    return (fmi2Status)mf_exit_initialization(F(c), "fmi2ExitInitializationMode");
}

fmi2Status fmi2Terminate(fmi2Component c) {
    GUARD("fmi2Terminate", MF_STEP_COMPLETE | MF_STEP_FAILED);
    return (fmi2Status)mf_terminate(F(c));
}

fmi2Status fmi2Reset(fmi2Component c) {
    GUARD("fmi2Reset", MF_ANY_LIVE);
    return (fmi2Status)mf_reset(F(c), "fmi2Reset");
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    GUARD("fmi2GetReal", MF_MASK_GET);
    return (fmi2Status)mf_get_real(F(c), "fmi2GetReal", vr, nvr, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    GUARD("fmi2SetReal", MF_MASK_SET);
    return (fmi2Status)mf_set_real(F(c), "fmi2SetReal", vr, nvr, value);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)value;
    return (fmi2Status)mf_no_such_type(F(c), "fmi2GetInteger", MF_MASK_GET, nvr, vr);
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)value;
    return (fmi2Status)mf_no_such_type(F(c), "fmi2GetBoolean", MF_MASK_GET, nvr, vr);
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)value;
    return (fmi2Status)mf_no_such_type(F(c), "fmi2GetString", MF_MASK_GET, nvr, vr);
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    (void)value;
    return (fmi2Status)mf_no_such_type(F(c), "fmi2SetInteger", MF_MASK_SET, nvr, vr);
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    (void)value;
    return (fmi2Status)mf_no_such_type(F(c), "fmi2SetBoolean", MF_MASK_SET, nvr, vr);
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)value;
    return (fmi2Status)mf_no_such_type(F(c), "fmi2SetString", MF_MASK_SET, nvr, vr);
}

/* ---- FMU state ---- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    GUARD("fmi2GetFMUstate", MF_MASK_FMUSTATE);
    return (fmi2Status)mf_get_state(F(c), "fmi2GetFMUstate", FMUstate);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    GUARD("fmi2SetFMUstate", MF_MASK_FMUSTATE);
    return (fmi2Status)mf_set_state(F(c), "fmi2SetFMUstate", FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    GUARD("fmi2FreeFMUstate", MF_MASK_FMUSTATE);
    return (fmi2Status)mf_free_state(F(c), "fmi2FreeFMUstate", FMUstate);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    GUARD("fmi2SerializedFMUstateSize", MF_MASK_FMUSTATE);
    return (fmi2Status)mf_serialized_size(F(c), "fmi2SerializedFMUstateSize", FMUstate, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    GUARD("fmi2SerializeFMUstate", MF_MASK_FMUSTATE);
    return (fmi2Status)mf_serialize(F(c), "fmi2SerializeFMUstate", FMUstate, (unsigned char *)serializedState, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    GUARD("fmi2DeSerializeFMUstate", MF_MASK_FMUSTATE);
    return (fmi2Status)mf_deserialize(F(c), "fmi2DeSerializeFMUstate", (const unsigned char *)serializedState, size,
                                      FMUstate);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    GUARD("fmi2GetDirectionalDerivative", MF_MASK_GET);
    return (fmi2Status)mf_error(F(c), "fmi2GetDirectionalDerivative: not provided (providesDirectionalDerivative=false)");
}

/* ---- co-simulation ---- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)order; (void)value;
    GUARD("fmi2SetRealInputDerivatives", MF_INSTANTIATED | MF_INITIALIZATION_MODE | MF_STEP_COMPLETE);
    if (nvr == 0) return fmi2OK;
    return (fmi2Status)mf_error(F(c), "fmi2SetRealInputDerivatives: input derivatives are not supported "
                                "(canInterpolateInputs=false); the input is held constant over a step");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)order; (void)value;
    GUARD("fmi2GetRealOutputDerivatives", MF_STEP_COMPLETE | MF_STEP_FAILED | MF_TERMINATED | MF_ERROR_STATE);
    if (nvr == 0) return fmi2OK;
    return (fmi2Status)mf_error(F(c), "fmi2GetRealOutputDerivatives: not supported (maxOutputDerivativeOrder=0)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    GUARD("fmi2DoStep", MF_STEP_COMPLETE);
    return (fmi2Status)mf_do_step(F(c), "fmi2DoStep", currentCommunicationPoint, communicationStepSize);
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    GUARD("fmi2CancelStep", 0);
    return fmi2Error;
}

#define MASK_STATUS (MF_STEP_COMPLETE | MF_STEP_FAILED | MF_TERMINATED)

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    GUARD("fmi2GetStatus", MASK_STATUS);
    if (!value) return (fmi2Status)mf_error(F(c), "fmi2GetStatus: value is NULL");
    if (s != fmi2DoStepStatus) return (fmi2Status)mf_error(F(c), "fmi2GetStatus: status kind %d not available", (int)s);
    *value = fmi2OK; /* doStep is synchronous: it never returns fmi2Pending */
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    GUARD("fmi2GetRealStatus", MASK_STATUS);
    if (!value) return (fmi2Status)mf_error(F(c), "fmi2GetRealStatus: value is NULL");
    if (s != fmi2LastSuccessfulTime)
        return (fmi2Status)mf_error(F(c), "fmi2GetRealStatus: status kind %d not available", (int)s);
    *value = mf_time(F(c));
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    GUARD("fmi2GetIntegerStatus", MASK_STATUS);
    return (fmi2Status)mf_error(F(c), "fmi2GetIntegerStatus: no integer status is available");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    GUARD("fmi2GetBooleanStatus", MASK_STATUS);
    if (!value) return (fmi2Status)mf_error(F(c), "fmi2GetBooleanStatus: value is NULL");
    if (s != fmi2Terminated)
        return (fmi2Status)mf_error(F(c), "fmi2GetBooleanStatus: status kind %d not available", (int)s);
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    GUARD("fmi2GetStringStatus", MASK_STATUS);
    if (!value) return (fmi2Status)mf_error(F(c), "fmi2GetStringStatus: value is NULL");
    if (s != fmi2PendingStatus)
        return (fmi2Status)mf_error(F(c), "fmi2GetStringStatus: status kind %d not available", (int)s);
    *value = "";
    return fmi2OK;
}

/* ---- model exchange: not offered; present so every importer finds the symbols ---- */

static fmi2Status me_only(fmi2Component c, const char *fn) {
    GUARD(fn, MF_ANY_LIVE);
    return (fmi2Status)mf_error(F(c), "%s: this FMU is co-simulation only", fn);
}

fmi2Status fmi2EnterEventMode(fmi2Component c) { return me_only(c, "fmi2EnterEventMode"); }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    (void)info;
    return me_only(c, "fmi2NewDiscreteStates");
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return me_only(c, "fmi2EnterContinuousTimeMode"); }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return me_only(c, "fmi2CompletedIntegratorStep");
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    (void)time;
    return me_only(c, "fmi2SetTime");
}
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    (void)x; (void)nx;
    return me_only(c, "fmi2SetContinuousStates");
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    (void)derivatives; (void)nx;
    return me_only(c, "fmi2GetDerivatives");
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators; (void)ni;
    return me_only(c, "fmi2GetEventIndicators");
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    (void)x; (void)nx;
    return me_only(c, "fmi2GetContinuousStates");
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    (void)x_nominal; (void)nx;
    return me_only(c, "fmi2GetNominalsOfContinuousStates");
}
