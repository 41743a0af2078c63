/* FMI 3.0 co-simulation entry points of every model: the plant (maglev_plant_fmu.c, build/maglev3.fmu)
 * and the PID controller (maglev_pid_fmu.c, build/maglev_pid3.fmu), whichever this binary links as
 * maglev_fmu_model. The instance logic is maglev_fmi_common.c, shared with the FMI 2.0 entry points
 * (maglev_fmu.c); this file maps the FMI 3.0 calls onto it. No event mode, no clocks, no structural
 * parameters, no intermediate update: those calls return fmi3Error with a message. The independent
 * variable time has the value reference after the model's table (its nvars), as modelDescription3.xml (the build's)
 * and modelDescription_pid3.xml say. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "maglev_fmi_common.h"

typedef struct {
    MfInstance base; /* first: an MfInstance* is a Fmu3* */
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback logger;
} Fmu3;

static void fmu3_log(const MfInstance *f, int status, const char *category, const char *message) {
    const Fmu3 *g = (const Fmu3 *)f;
    if (g->logger) g->logger(g->env, (fmi3Status)status, category, message);
}

static void emit(fmi3LogMessageCallback logger, fmi3InstanceEnvironment env, const char *fmt, ...) {
    if (!logger) return;
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    logger(env, fmi3Error, "logStatusError", buf);
}

#define F(c) ((MfInstance *)(c))
#define GUARD(fn, mask) \
    do { if (!mf_guard(F(instance), fn, mask)) return fmi3Error; } while (0)

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    GUARD("fmi3SetDebugLogging", MF_ANY_LIVE);
    return (fmi3Status)mf_set_debug_logging(F(instance), "fmi3SetDebugLogging", loggingOn, nCategories, categories);
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)visible; (void)earlyReturnAllowed; (void)requiredIntermediateVariables; (void)intermediateUpdate;
    const char *fn = "fmi3InstantiateCoSimulation";
    if (!instanceName || !*instanceName) {
        emit(logMessage, instanceEnvironment, "%s: instanceName must be a non-empty string", fn);
        return NULL;
    }
    const MfModel *model = &maglev_fmu_model;
    if (!instantiationToken || strcmp(instantiationToken, model->guid) != 0) {
        emit(logMessage, instanceEnvironment, "%s: instantiationToken %s does not match %s", fn,
             instantiationToken ? instantiationToken : "(null)", model->guid);
        return NULL;
    }
    if (eventModeUsed) {
        emit(logMessage, instanceEnvironment, "%s: eventModeUsed requested, but the FMU has no event mode "
             "(hasEventMode=false)", fn);
        return NULL;
    }
    if (nRequiredIntermediateVariables > 0) {
        emit(logMessage, instanceEnvironment, "%s: %zu intermediate variables requested, but the FMU provides no "
             "intermediate update (providesIntermediateUpdate=false)", fn, nRequiredIntermediateVariables);
        return NULL;
    }
    /* earlyReturnAllowed: accepted; the FMU never returns early from fmi3DoStep */
    Fmu3 *f = calloc(1, sizeof *f);
    if (!f) {
        emit(logMessage, instanceEnvironment, "%s: out of memory", fn);
        return NULL;
    }
    f->env = instanceEnvironment;
    f->logger = logMessage;
    char msg[MAGLEV_MSG_LEN];
    if (mf_init(&f->base, model, instanceName, loggingOn, fmu3_log, &maglev_std_allocator, model->nvars,
                resourcePath, msg, sizeof msg)) {
        emit(logMessage, instanceEnvironment, "%s: %s", fn, msg);
        free(f);
        return NULL;
    }
    mf_log(&f->base, MF_OK, "logCalls", "%s: %s", fn, model->guid);
    return f;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    emit(logMessage, instanceEnvironment, "fmi3InstantiateModelExchange: this FMU supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    emit(logMessage, instanceEnvironment, "fmi3InstantiateScheduledExecution: this FMU supports co-simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    if (!instance) return;
    mf_release(F(instance));
    free(instance);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    GUARD("fmi3EnterInitializationMode", MF_INSTANTIATED);
    int rc = mf_setup_experiment(F(instance), "fmi3EnterInitializationMode", toleranceDefined, tolerance, startTime,
                                 stopTimeDefined, stopTime);
    if (rc != MF_OK) return (fmi3Status)rc;
    return (fmi3Status)mf_enter_initialization(F(instance));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    GUARD("fmi3ExitInitializationMode", MF_INITIALIZATION_MODE);
    return (fmi3Status)mf_exit_initialization(F(instance), "fmi3ExitInitializationMode");
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    GUARD("fmi3Terminate", MF_STEP_COMPLETE);
    return (fmi3Status)mf_terminate(F(instance));
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    GUARD("fmi3Reset", MF_ANY_LIVE);
    return (fmi3Status)mf_reset(F(instance), "fmi3Reset");
}

/* Every variable is a scalar: nValues must equal nValueReferences. */
static int scalars(fmi3Instance instance, const char *fn, size_t nvr, size_t nvalues) {
    if (nvr == nvalues) return 1;
    mf_error(F(instance), "%s: nValues = %zu but nValueReferences = %zu (every variable is a scalar)", fn, nvalues,
             nvr);
    return 0;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          fmi3Float64 values[], size_t nValues) {
    GUARD("fmi3GetFloat64", MF_MASK_GET);
    if (!scalars(instance, "fmi3GetFloat64", nValueReferences, nValues)) return fmi3Error;
    return (fmi3Status)mf_get_real(F(instance), "fmi3GetFloat64", valueReferences, nValueReferences, values);
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          const fmi3Float64 values[], size_t nValues) {
    GUARD("fmi3SetFloat64", MF_MASK_SET);
    if (!scalars(instance, "fmi3SetFloat64", nValueReferences, nValues)) return fmi3Error;
    return (fmi3Status)mf_set_real(F(instance), "fmi3SetFloat64", valueReferences, nValueReferences, values);
}

/* The types the FMU has no variable of. */
#define NO_SUCH_GET(T)                                                                                          \
    fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],                   \
                          size_t nValueReferences, fmi3##T values[], size_t nValues) {                         \
        (void)values; (void)nValues;                                                                            \
        return (fmi3Status)mf_no_such_type(F(instance), "fmi3Get" #T, MF_MASK_GET, nValueReferences,            \
                                           valueReferences);                                                    \
    }
#define NO_SUCH_SET(T)                                                                                          \
    fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],                   \
                          size_t nValueReferences, const fmi3##T values[], size_t nValues) {                   \
        (void)values; (void)nValues;                                                                            \
        return (fmi3Status)mf_no_such_type(F(instance), "fmi3Set" #T, MF_MASK_SET, nValueReferences,            \
                                           valueReferences);                                                    \
    }
#define NO_SUCH(T) NO_SUCH_GET(T) NO_SUCH_SET(T)
NO_SUCH(Float32)
NO_SUCH(Int8)
NO_SUCH(UInt8)
NO_SUCH(Int16)
NO_SUCH(UInt16)
NO_SUCH(Int32)
NO_SUCH(UInt32)
NO_SUCH(Int64)
NO_SUCH(UInt64)
NO_SUCH(Boolean)
NO_SUCH(String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    return (fmi3Status)mf_no_such_type(F(instance), "fmi3GetBinary", MF_MASK_GET, nValueReferences, valueReferences);
}
fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    return (fmi3Status)mf_no_such_type(F(instance), "fmi3SetBinary", MF_MASK_SET, nValueReferences, valueReferences);
}
fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Clock values[]) {
    (void)values;
    return (fmi3Status)mf_no_such_type(F(instance), "fmi3GetClock", MF_MASK_GET, nValueReferences, valueReferences);
}
fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Clock values[]) {
    (void)values;
    return (fmi3Status)mf_no_such_type(F(instance), "fmi3SetClock", MF_MASK_SET, nValueReferences, valueReferences);
}

/* Functions of capabilities the FMU does not declare: allowed nowhere here, so every call is an error. */
static fmi3Status unsupported(fmi3Instance instance, const char *fn, const char *why) {
    GUARD(fn, MF_ANY_LIVE);
    return (fmi3Status)mf_error(F(instance), "%s: %s", fn, why);
}

#define NO_DEPENDENCIES "not provided (the model description's ModelStructure states the dependencies)"
fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    return unsupported(instance, "fmi3GetNumberOfVariableDependencies", NO_DEPENDENCIES);
}
fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents; (void)elementIndicesOfIndependents;
    (void)dependencyKinds; (void)nDependencies;
    return unsupported(instance, "fmi3GetVariableDependencies", NO_DEPENDENCIES);
}

/* ---- FMU state ---- */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    GUARD("fmi3GetFMUState", MF_MASK_FMUSTATE);
    return (fmi3Status)mf_get_state(F(instance), "fmi3GetFMUState", FMUState);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    GUARD("fmi3SetFMUState", MF_MASK_FMUSTATE);
    return (fmi3Status)mf_set_state(F(instance), "fmi3SetFMUState", FMUState);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    GUARD("fmi3FreeFMUState", MF_MASK_FMUSTATE);
    return (fmi3Status)mf_free_state(F(instance), "fmi3FreeFMUState", FMUState);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    GUARD("fmi3SerializedFMUStateSize", MF_MASK_FMUSTATE);
    return (fmi3Status)mf_serialized_size(F(instance), "fmi3SerializedFMUStateSize", FMUState, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    GUARD("fmi3SerializeFMUState", MF_MASK_FMUSTATE);
    return (fmi3Status)mf_serialize(F(instance), "fmi3SerializeFMUState", FMUState, serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    GUARD("fmi3DeserializeFMUState", MF_MASK_FMUSTATE);
    return (fmi3Status)mf_deserialize(F(instance), "fmi3DeserializeFMUState", serializedState, size, FMUState);
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed; (void)sensitivity;
    (void)nSensitivity;
    return unsupported(instance, "fmi3GetDirectionalDerivative", "not provided (providesDirectionalDerivatives=false)");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed; (void)sensitivity;
    (void)nSensitivity;
    return unsupported(instance, "fmi3GetAdjointDerivative", "not provided (providesAdjointDerivatives=false)");
}

/* ---- configuration mode: the FMU has no structural parameters ---- */

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterConfigurationMode", "the FMU has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    GUARD("fmi3ExitConfigurationMode", 0); /* configuration mode is never entered */
    return fmi3Error;
}

/* ---- clocks: none ---- */

#define NO_CLOCKS "the FMU has no clocks"
fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalDecimal", NO_CLOCKS);
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalFraction", NO_CLOCKS);
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return unsupported(instance, "fmi3GetShiftDecimal", NO_CLOCKS);
}
fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3GetShiftFraction", NO_CLOCKS);
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    return unsupported(instance, "fmi3SetIntervalDecimal", NO_CLOCKS);
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetIntervalFraction", NO_CLOCKS);
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return unsupported(instance, "fmi3SetShiftDecimal", NO_CLOCKS);
}
fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetShiftFraction", NO_CLOCKS);
}
fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return unsupported(instance, "fmi3ActivateModelPartition", "this FMU supports co-simulation only");
}

/* ---- event mode: not offered (hasEventMode=false) ---- */

#define NO_EVENTS "the FMU has no event mode (hasEventMode=false)"
fmi3Status fmi3EnterEventMode(fmi3Instance instance) { return unsupported(instance, "fmi3EnterEventMode", NO_EVENTS); }
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return unsupported(instance, "fmi3EvaluateDiscreteStates", NO_EVENTS);
}
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate; (void)terminateSimulation; (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged; (void)nextEventTimeDefined; (void)nextEventTime;
    return unsupported(instance, "fmi3UpdateDiscreteStates", NO_EVENTS);
}
fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    GUARD("fmi3EnterStepMode", 0); /* only from event mode, which is never entered */
    return fmi3Error;
}

/* ---- co-simulation ---- */

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)valueReferences; (void)orders; (void)values; (void)nValues;
    GUARD("fmi3GetOutputDerivatives", MF_STEP_COMPLETE | MF_TERMINATED | MF_ERROR_STATE);
    if (nValueReferences == 0) return fmi3OK;
    return (fmi3Status)mf_error(F(instance), "fmi3GetOutputDerivatives: not supported (maxOutputDerivativeOrder=0)");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    (void)noSetFMUStatePriorToCurrentPoint;
    /* defined out-arguments even for a refused call: no events, no early return, the time reached */
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime && instance) *lastSuccessfulTime = mf_time(F(instance));
    GUARD("fmi3DoStep", MF_STEP_COMPLETE);
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime)
        return (fmi3Status)mf_error(F(instance), "fmi3DoStep: an output argument (eventHandlingNeeded, "
                                    "terminateSimulation, earlyReturn, lastSuccessfulTime) is NULL");
    int rc = mf_do_step(F(instance), "fmi3DoStep", currentCommunicationPoint, communicationStepSize);
    *lastSuccessfulTime = mf_time(F(instance)); /* a refused step leaves it where it was */
    return (fmi3Status)rc;
}

/* ---- model exchange: not offered; present so every importer finds the symbols ---- */

#define ME_ONLY "this FMU is co-simulation only"
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterContinuousTimeMode", ME_ONLY);
}
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return unsupported(instance, "fmi3CompletedIntegratorStep", ME_ONLY);
}
fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return unsupported(instance, "fmi3SetTime", ME_ONLY);
}
fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return unsupported(instance, "fmi3SetContinuousStates", ME_ONLY);
}
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetContinuousStateDerivatives", ME_ONLY);
}
fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    (void)eventIndicators; (void)nEventIndicators;
    return unsupported(instance, "fmi3GetEventIndicators", ME_ONLY);
}
fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[], size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetContinuousStates", ME_ONLY);
}
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[], size_t nContinuousStates) {
    (void)nominals; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetNominalsOfContinuousStates", ME_ONLY);
}
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)nEventIndicators;
    return unsupported(instance, "fmi3GetNumberOfEventIndicators", ME_ONLY);
}
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    (void)nContinuousStates;
    return unsupported(instance, "fmi3GetNumberOfContinuousStates", ME_ONLY);
}
