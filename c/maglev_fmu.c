/* FMI 2.0 co-simulation entry points for the CE152 plant (maglev_plant.c). */
#include <ctype.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "maglev_plant.h"

/* Must equal the guid attribute of modelDescription.xml (tests/test_model_description.py). */
#define MAGLEV_GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"

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

/* An FMU state. The instance that made it owns it (a list, so that fmi2FreeInstance frees what
 * the importer left behind, and a foreign or stale pointer is refused instead of followed). */
typedef struct Snapshot {
    FmuState state;
    MaglevPlant plant;
    struct Snapshot *prev, *next;
} Snapshot;

typedef struct {
    char name[128];
    fmi2CallbackFunctions cb;
    int logging;
    FmuState state;
    double start_time, stop_time;
    int stop_defined;
    MaglevAllocator alloc;
    MaglevPlant plant;
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

/* The message goes as the format itself (with '%' doubled), because importers written in
 * languages without C varargs (fmpy's ctypes logger) never see variadic arguments. */
static void vemit(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status, const char *category,
                  const char *fmt, va_list ap) {
    if (!cb->logger) return;
    char buf[512], esc[1024];
    vsnprintf(buf, sizeof buf, fmt, ap);
    size_t n = 0;
    for (const char *p = buf; *p && n + 2 < sizeof esc; p++) {
        if (*p == '%') esc[n++] = '%';
        esc[n++] = *p;
    }
    esc[n] = 0;
    cb->logger(cb->componentEnvironment, name, status, category, esc);
}

static void emit(const fmi2CallbackFunctions *cb, const char *name, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vemit(cb, name, fmi2Error, "logStatusError", fmt, ap);
    va_end(ap);
}

static void logmsg(const Fmu *f, fmi2Status status, const char *category, const char *fmt, ...) {
    if (status == fmi2OK && !f->logging) return;
    va_list ap;
    va_start(ap, fmt);
    vemit(&f->cb, f->name, status, category, fmt, ap);
    va_end(ap);
}

static fmi2Status error(Fmu *f, const char *fmt, ...) {
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    logmsg(f, fmi2Error, "logStatusError", "%s", buf);
    return fmi2Error;
}

/* The one guard every entry point passes: instance present and call allowed in its state. */
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

static void *fmu_alloc(size_t n, size_t size, void *env) {
    Fmu *f = env;
    return f->cb.allocateMemory(n, size);
}

static void fmu_release(void *p, void *env) {
    Fmu *f = env;
    f->cb.freeMemory(p);
}

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

static void plant_reset(Fmu *f) {
    maglev_release(&f->plant, &f->alloc);
    maglev_defaults(&f->plant);
    f->start_time = 0;
    f->stop_time = 0;
    f->stop_defined = 0;
}

/* A rig's FMU (maglev-cosim fmu --rig) carries its parameters in resources/start_values.txt, one
 * "name value" per line: they replace the C defaults, so that the FMU uses the start values its
 * modelDescription.xml states. No file (the CE152 FMU): the defaults. Returns 0, or -1 with msg. */
#define START_VALUES_FILE "start_values.txt"
/* A calibrated or rig FMU is a model of its own with a GUID of its own, issued by the packager
 * (maglev_cosim.report.calibrated_fmu) and stated in resources/guid.txt: with that file the binary
 * accepts exactly that GUID, without it exactly MAGLEV_GUID, so a description and a binary or
 * resources that do not belong together are still refused. */
#define GUID_FILE "guid.txt"
static int resource_path(const char *uri, const char *file, char *out, size_t len) {
    const char *p;
    if (strncmp(uri, "file:///", 8) == 0) p = uri + 7;       /* file:///path */
    else if (strncmp(uri, "file://localhost/", 17) == 0) p = uri + 16;
    else if (strncmp(uri, "file:/", 6) == 0) p = uri + 5;     /* file:/path */
    else return -1;
    size_t n = 0;
    for (; *p && n + 1 < len; p++) {
        if (p[0] == '%' && isxdigit((unsigned char)p[1]) && isxdigit((unsigned char)p[2])) {
            char hex[3] = {p[1], p[2], 0};
            out[n++] = (char)strtol(hex, NULL, 16);
            p += 2;
        } else {
            out[n++] = *p;
        }
    }
    if (*p) return -1;
    while (n > 0 && out[n - 1] == '/') n--;
    size_t fl = strlen(file);
    if (n + 2 + fl > len) return -1;
    out[n] = '/';
    memcpy(out + n + 1, file, fl + 1);
    return 0;
}

/* The GUID this FMU accepts (above): 0 with guid set, or -1 with msg when resources/guid.txt is
 * there but holds no GUID. */
static int accepted_guid(const char *uri, char *guid, size_t glen, char *msg, size_t len) {
    char path[4096], line[128];
    snprintf(guid, glen, "%s", MAGLEV_GUID);
    if (!uri || resource_path(uri, GUID_FILE, path, sizeof path)) return 0;
    FILE *fp = fopen(path, "r");
    if (!fp) return 0;
    int ok = fgets(line, sizeof line, fp) != NULL;
    fclose(fp);
    size_t n = ok ? strcspn(line, "\r\n") : 0;
    line[n] = 0;
    if (n < 3 || n + 1 > glen || line[0] != '{' || line[n - 1] != '}') {
        snprintf(msg, len, "resources/%s: expected one GUID in braces on its first line", GUID_FILE);
        return -1;
    }
    memcpy(guid, line, n + 1);
    return 0;
}

static int load_start_values(MaglevPlant *m, const char *uri, char *msg, size_t len) {
    char path[4096];
    if (!uri || resource_path(uri, START_VALUES_FILE, path, sizeof path)) return 0;
    FILE *fp = fopen(path, "r");
    if (!fp) return 0;
    char line[512];
    int ln = 0, rc = 0;
    while (rc == 0 && fgets(line, sizeof line, fp)) {
        ln++;
        if (!strchr(line, '\n') && !feof(fp)) {
            snprintf(msg, len, "resources/%s line %d: longer than %d characters", START_VALUES_FILE, ln,
                     (int)sizeof line - 2);
            rc = -1;
            break;
        }
        char name[64], extra[2];
        double value;
        char *hash = strchr(line, '#');
        if (hash) *hash = 0;
        int k = sscanf(line, "%63s %lf %1s", name, &value, extra);
        if (k <= 0) continue; /* blank or comment */
        if (k != 2) {
            snprintf(msg, len, "resources/%s line %d: expected 'name value'", START_VALUES_FILE, ln);
            rc = -1;
            break;
        }
        int vr = -1;
        for (int j = MAGLEV_FIRST_PARAM; j <= VR_solver_step; j++)
            if (strcmp(maglev_variables[j].name, name) == 0) vr = j;
        if (vr < 0) {
            snprintf(msg, len, "resources/%s line %d: %s is not a parameter of this FMU", START_VALUES_FILE, ln,
                     name);
            rc = -1;
        } else {
            char why[MAGLEV_MSG_LEN - 56]; /* room for the file and line in msg */
            if (maglev_check_value((MaglevVR)vr, value, why, sizeof why)) {
                snprintf(msg, len, "resources/%s line %d: %s", START_VALUES_FILE, ln, why);
                rc = -1;
            } else {
                maglev_set_param(m, (MaglevVR)vr, value);
            }
        }
    }
    fclose(fp);
    return rc;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)visible;
    /* every NULL returned is explained through the logger, when there is one (FMI 2.0, fmi2Instantiate) */
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
    char guid[80], msg[MAGLEV_MSG_LEN];
    if (accepted_guid(fmuResourceLocation, guid, sizeof guid, msg, sizeof msg)) {
        emit(functions, nm, "fmi2Instantiate: %s", msg);
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, guid) != 0) {
        emit(functions, nm, "fmi2Instantiate: GUID %s does not match %s%s", fmuGUID ? fmuGUID : "(null)", guid,
             strcmp(guid, MAGLEV_GUID) ? " (issued in resources/" GUID_FILE ")" : "");
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
    f->alloc.alloc = fmu_alloc;
    f->alloc.release = fmu_release;
    f->alloc.env = f;
    maglev_defaults(&f->plant);
    if (load_start_values(&f->plant, fmuResourceLocation, msg, sizeof msg)) {
        emit(functions, nm, "fmi2Instantiate: %s", msg);
        functions->freeMemory(f);
        return NULL;
    }
    f->state = Instantiated;
    logmsg(f, fmi2OK, "logCalls", "fmi2Instantiate: %s", guid);
    return f;
}

static void snapshot_free(Fmu *f, Snapshot *s) {
    if (s->prev) s->prev->next = s->next; else f->snapshots = s->next;
    if (s->next) s->next->prev = s->prev;
    maglev_release(&s->plant, &f->alloc);
    f->cb.freeMemory(s);
}

void fmi2FreeInstance(fmi2Component c) {
    Fmu *f = c;
    if (!f) return;
    while (f->snapshots) snapshot_free(f, f->snapshots);
    maglev_release(&f->plant, &f->alloc);
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
    f->start_time = startTime;
    f->stop_defined = stopTimeDefined ? 1 : 0;
    f->stop_time = stopTime;
    f->plant.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    GUARD("fmi2EnterInitializationMode", Instantiated);
    Fmu *f = c;
    f->plant.time = f->start_time;
    f->state = InitializationMode;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    GUARD("fmi2ExitInitializationMode", InitializationMode);
    Fmu *f = c;
    char msg[MAGLEV_MSG_LEN];
    if (maglev_initialize(&f->plant, f->start_time, f->plant.u, &f->alloc, msg, sizeof msg))
        return error(f, "fmi2ExitInitializationMode: %s", msg);
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
    plant_reset(f);
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
        if (vr[k] >= MAGLEV_NVARS) {
            error(f, "%s: unknown value reference %u", fn, (unsigned)vr[k]);
            return 0;
        }
    return 1;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    GUARD("fmi2GetReal", MASK_GET);
    Fmu *f = c;
    if (!check_vrs(f, "fmi2GetReal", vr, nvr, value)) return fmi2Error;
    /* Before initialisation ends the state is not set yet: outputs are what initialisation would
     * give, and cannot be given while the parameters contradict each other. */
    MaglevPlant view;
    const MaglevPlant *p = &f->plant;
    char msg[MAGLEV_MSG_LEN];
    if (f->state == InitializationMode) {
        for (size_t k = 0; k < nvr; k++) {
            if (maglev_variables[vr[k]].causality != MAGLEV_OUTPUT) continue;
            if (maglev_preview(&f->plant, f->start_time, &view, msg, sizeof msg))
                return error(f, "fmi2GetReal: output %s is undefined until the parameters agree: %s",
                             maglev_variables[vr[k]].name, msg);
            p = &view;
            break;
        }
    }
    for (size_t k = 0; k < nvr; k++) {
        value[k] = maglev_get(p, (MaglevVR)vr[k]);
        if (!isfinite(value[k]))
            return error(f, "fmi2GetReal: variable %s is not finite (%g)", maglev_variables[vr[k]].name, value[k]);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    GUARD("fmi2SetReal", MASK_SET);
    Fmu *f = c;
    char msg[MAGLEV_MSG_LEN];
    if (!check_vrs(f, "fmi2SetReal", vr, nvr, value)) return fmi2Error;
    /* validate everything first, so a rejected call changes nothing */
    for (size_t k = 0; k < nvr; k++) {
        const MaglevVariable *var = &maglev_variables[vr[k]];
        if (var->causality == MAGLEV_OUTPUT)
            return error(f, "fmi2SetReal: variable %s is an output and cannot be set", var->name);
        if (var->causality == MAGLEV_PARAMETER && f->state == StepComplete)
            return error(f, "fmi2SetReal: variable %s is a fixed parameter, settable only before "
                         "fmi2ExitInitializationMode", var->name);
        if (maglev_check_value((MaglevVR)vr[k], value[k], msg, sizeof msg))
            return error(f, "fmi2SetReal: %s", msg);
    }
    for (size_t k = 0; k < nvr; k++) {
        if (vr[k] == VR_u) {
            if (f->state == StepComplete) {
                if (maglev_set_input(&f->plant, value[k], &f->alloc, msg, sizeof msg)) {
                    f->state = Error;
                    return error(f, "fmi2SetReal: %s", msg);
                }
            } else {
                f->plant.u = value[k];
            }
        } else {
            maglev_set_param(&f->plant, (MaglevVR)vr[k], value[k]);
        }
    }
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

/* ---- FMU state ---- */

#define MASK_FMUSTATE (Instantiated | InitializationMode | StepComplete | StepFailed | Terminated | Error)

static Snapshot *owned(Fmu *f, const char *fn, fmi2FMUstate state) {
    for (Snapshot *s = f->snapshots; s; s = s->next)
        if (s == state) return s;
    error(f, "%s: FMUstate %p was not made by this instance or was freed (move states between instances "
          "with fmi2SerializeFMUstate)", fn, state);
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
    GUARD("fmi2GetFMUstate", MASK_FMUSTATE);
    Fmu *f = c;
    if (!FMUstate) return error(f, "fmi2GetFMUstate: FMUstate pointer is NULL");
    MaglevPlant copy;
    if (maglev_copy(&copy, &f->plant, &f->alloc)) return error(f, "fmi2GetFMUstate: out of memory");
    Snapshot *s;
    if (*FMUstate) {
        if (!(s = owned(f, "fmi2GetFMUstate", *FMUstate))) {
            maglev_release(&copy, &f->alloc);
            return fmi2Error;
        }
        maglev_release(&s->plant, &f->alloc);
    } else if (!(s = snapshot_new(f))) {
        maglev_release(&copy, &f->alloc);
        return error(f, "fmi2GetFMUstate: out of memory");
    }
    s->plant = copy;
    s->state = f->state;
    *FMUstate = s;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    GUARD("fmi2SetFMUstate", MASK_FMUSTATE);
    Fmu *f = c;
    if (!FMUstate) return error(f, "fmi2SetFMUstate: FMUstate is NULL");
    const Snapshot *s = owned(f, "fmi2SetFMUstate", FMUstate);
    if (!s) return fmi2Error;
    MaglevPlant copy;
    if (maglev_copy(&copy, &s->plant, &f->alloc)) return error(f, "fmi2SetFMUstate: out of memory");
    maglev_release(&f->plant, &f->alloc);
    f->plant = copy;
    f->state = s->state;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    GUARD("fmi2FreeFMUstate", MASK_FMUSTATE);
    Fmu *f = c;
    if (!FMUstate) return error(f, "fmi2FreeFMUstate: FMUstate pointer is NULL");
    if (!*FMUstate) return fmi2OK;
    Snapshot *s = owned(f, "fmi2FreeFMUstate", *FMUstate);
    if (!s) return fmi2Error;
    snapshot_free(f, s);
    *FMUstate = NULL;
    return fmi2OK;
}

static int state_code(FmuState s) {
    for (int k = 0; k < 7; k++)
        if ((int)s == 1 << k) return k;
    return -1;
}

/* Serialised form: the plant image, with the FMU state's code as its checksummed tag. */
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    GUARD("fmi2SerializedFMUstateSize", MASK_FMUSTATE);
    Fmu *f = c;
    if (!FMUstate || !size) return error(f, "fmi2SerializedFMUstateSize: FMUstate or size is NULL");
    const Snapshot *s = owned(f, "fmi2SerializedFMUstateSize", FMUstate);
    if (!s) return fmi2Error;
    *size = maglev_serialized_size(&s->plant);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    GUARD("fmi2SerializeFMUstate", MASK_FMUSTATE);
    Fmu *f = c;
    if (!FMUstate || !serializedState) return error(f, "fmi2SerializeFMUstate: FMUstate or buffer is NULL");
    const Snapshot *s = owned(f, "fmi2SerializeFMUstate", FMUstate);
    if (!s) return fmi2Error;
    size_t need = maglev_serialized_size(&s->plant);
    if (size < need) return error(f, "fmi2SerializeFMUstate: buffer of %zu bytes, %zu needed", size, need);
    maglev_serialize(&s->plant, (unsigned int)state_code(s->state), (unsigned char *)serializedState);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    GUARD("fmi2DeSerializeFMUstate", MASK_FMUSTATE);
    Fmu *f = c;
    char msg[MAGLEV_MSG_LEN];
    if (!serializedState || !FMUstate) return error(f, "fmi2DeSerializeFMUstate: NULL buffer or FMUstate pointer");
    if (*FMUstate && !owned(f, "fmi2DeSerializeFMUstate", *FMUstate)) return fmi2Error;
    MaglevPlant p;
    unsigned int code;
    memset(&p, 0, sizeof p);
    if (maglev_deserialize(&p, &code, (const unsigned char *)serializedState, size, &f->alloc, msg, sizeof msg))
        return error(f, "fmi2DeSerializeFMUstate: %s", msg);
    /* the state machine's state must be one the plant can be in */
    FmuState st = code >= 1 && code <= 6 ? (FmuState)(1 << code) : StartAndEnd;
    int needs_init = st & (StepComplete | StepFailed | Terminated);
    int needs_fresh = st & (Instantiated | InitializationMode);
    if (st == StartAndEnd || (needs_init && !p.initialized) || (needs_fresh && p.initialized)) {
        maglev_release(&p, &f->alloc);
        return error(f, "fmi2DeSerializeFMUstate: FMU state code %u does not fit the plant's state", code);
    }
    Snapshot *s = *FMUstate;
    if (s) {
        maglev_release(&s->plant, &f->alloc);
    } else if (!(s = snapshot_new(f))) {
        maglev_release(&p, &f->alloc);
        return error(f, "fmi2DeSerializeFMUstate: out of memory");
    }
    s->plant = p;
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
    GUARD("fmi2SetRealInputDerivatives", Instantiated | InitializationMode | StepComplete);
    if (nvr == 0) return fmi2OK;
    return error((Fmu *)c, "fmi2SetRealInputDerivatives: input derivatives are not supported "
                 "(canInterpolateInputs=false); the input is held constant over a step");
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
    char msg[MAGLEV_MSG_LEN];
    double t = f->plant.time;
    if (!isfinite(currentCommunicationPoint))
        return error(f, "fmi2DoStep: currentCommunicationPoint %g is not finite", currentCommunicationPoint);
    if (!isfinite(communicationStepSize) || communicationStepSize <= 0)
        return error(f, "fmi2DoStep: communicationStepSize %g must be > 0 and finite", communicationStepSize);
    if (fabs(currentCommunicationPoint - t) > 1e-9 * (1.0 + fabs(t)))
        return error(f, "fmi2DoStep: currentCommunicationPoint %.17g does not match the FMU time %.17g",
                     currentCommunicationPoint, t);
    if (f->stop_defined && currentCommunicationPoint + communicationStepSize > f->stop_time * (1 + 1e-12) + 1e-12)
        return error(f, "fmi2DoStep: step to %.17g goes past stopTime %.17g",
                     currentCommunicationPoint + communicationStepSize, f->stop_time);
    /* the importer's time is the reference: absorb rounding between its clock and ours (for a step
     * taken; a refused step leaves the time as it was, which may be the only one in range) */
    f->plant.time = currentCommunicationPoint;
    int rc = maglev_step(&f->plant, communicationStepSize, &f->alloc, msg, sizeof msg);
    if (rc) f->plant.time = t;
    if (rc == MAGLEV_REFUSED) return error(f, "fmi2DoStep: %s", msg); /* nothing changed: shorter steps will do */
    if (rc) {
        f->state = Error; /* the model broke down; the values are those before the step */
        return error(f, "fmi2DoStep: %s", msg);
    }
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
    *value = fmi2OK; /* doStep is synchronous: it never returns fmi2Pending */
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    GUARD("fmi2GetRealStatus", MASK_STATUS);
    Fmu *f = c;
    if (!value) return error(f, "fmi2GetRealStatus: value is NULL");
    if (s != fmi2LastSuccessfulTime) return error(f, "fmi2GetRealStatus: status kind %d not available", (int)s);
    *value = f->plant.time;
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
