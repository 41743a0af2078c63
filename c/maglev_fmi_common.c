/* The instance logic both FMI glues share (maglev_fmi_common.h). */
#include "maglev_fmi_common.h"

#include <ctype.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* An FMU state. The instance that made it owns it (a list, so that freeing the instance frees what
 * the importer left behind, and a foreign or stale pointer is refused instead of followed). */
struct MfSnapshot {
    MfState state;
    MfExperiment exp;
    MaglevPlant plant;
    struct MfSnapshot *prev, *next;
};

const char *mf_state_name(MfState s) {
    switch (s) {
    case MF_START_AND_END: return "startAndEnd";
    case MF_INSTANTIATED: return "instantiated";
    case MF_INITIALIZATION_MODE: return "initializationMode";
    case MF_STEP_COMPLETE: return "stepComplete";
    case MF_STEP_FAILED: return "stepFailed";
    case MF_TERMINATED: return "terminated";
    case MF_ERROR_STATE: return "error";
    }
    return "?";
}

static void vlog(const MfInstance *f, int status, const char *category, const char *fmt, va_list ap) {
    if (!f->log || (status == MF_OK && !f->logging)) return;
    char buf[512];
    vsnprintf(buf, sizeof buf, fmt, ap);
    f->log(f, status, category, buf);
}

void mf_log(const MfInstance *f, int status, const char *category, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog(f, status, category, fmt, ap);
    va_end(ap);
}

int mf_error(MfInstance *f, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog(f, MF_ERROR, "logStatusError", fmt, ap);
    va_end(ap);
    return MF_ERROR;
}

int mf_guard(MfInstance *f, const char *fn, int mask) {
    if (!f) return 0;
    if (!(f->state & mask)) {
        mf_error(f, "%s: not allowed in state %s", fn, mf_state_name(f->state));
        return 0;
    }
    return 1;
}

int mf_set_debug_logging(MfInstance *f, const char *fn, int on, size_t n, const char *const categories[]) {
    if (n > 0 && !categories) return mf_error(f, "%s: categories is NULL", fn);
    for (size_t k = 0; k < n; k++) {
        const char *cat = categories[k];
        if (!cat || (strcmp(cat, "logAll") && strcmp(cat, "logStatusError") && strcmp(cat, "logCalls")))
            return mf_error(f, "%s: unknown log category '%s'", fn, cat ? cat : "(null)");
    }
    f->logging = on ? 1 : 0;
    return MF_OK;
}

/* ---- instance ---- */

int mf_uri_to_path(const char *uri, char *out, size_t len) {
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
    out[n] = 0;
#ifdef _WIN32
    /* file:///C:/dir is the path C:/dir on Windows (RFC 8089), not /C:/dir */
    if (n >= 3 && out[0] == '/' && isalpha((unsigned char)out[1]) && out[2] == ':') memmove(out, out + 1, n);
#endif
    return 0;
}

/* A path separator: '/', and on Windows '\\' too (an FMI 3.0 resourcePath there ends with one). */
static int is_separator(char c) {
#ifdef _WIN32
    if (c == '\\') return 1;
#endif
    return c == '/';
}

#define GUID_FILE "guid.txt"
int mf_accepted_guid(const char *dir, char *guid, size_t glen, char *msg, size_t len) {
    char path[4096], line[128];
    snprintf(guid, glen, "%s", MAGLEV_GUID);
    if (!dir) return 0;
    size_t n = strlen(dir);
    while (n > 0 && is_separator(dir[n - 1])) n--;
    if (n + 1 + sizeof GUID_FILE > sizeof path) return 0;
    memcpy(path, dir, n);
    path[n] = '/';
    memcpy(path + n + 1, GUID_FILE, sizeof GUID_FILE);
    FILE *fp = fopen(path, "r");
    if (!fp) return 0;
    int ok = fgets(line, sizeof line, fp) != NULL;
    fclose(fp);
    n = ok ? strcspn(line, "\r\n") : 0;
    line[n] = 0;
    if (n < 3 || n + 1 > glen || line[0] != '{' || line[n - 1] != '}') {
        snprintf(msg, len, "resources/%s: expected one GUID in braces on its first line", GUID_FILE);
        return -1;
    }
    memcpy(guid, line, n + 1);
    return 0;
}

/* A rig's FMU (maglev-cosim fmu --rig) carries its parameters in resources/start_values.txt, one
 * "name value" per line: they replace the C defaults, so that the FMU uses the start values its
 * model description states. No file (the CE152 FMU): the defaults. Returns 0, or -1 with msg. */
#define START_VALUES_FILE "start_values.txt"
static int load_start_values(MaglevPlant *m, const char *dir, int *count, char *msg, size_t len) {
    char path[4096];
    if (!dir) return 0;
    size_t n = strlen(dir);
    while (n > 0 && is_separator(dir[n - 1])) n--;
    if (n + 1 + sizeof START_VALUES_FILE > sizeof path) return 0;
    memcpy(path, dir, n);
    path[n] = '/';
    memcpy(path + n + 1, START_VALUES_FILE, sizeof START_VALUES_FILE);
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
                ++*count;
            }
        }
    }
    fclose(fp);
    return rc;
}

int mf_init(MfInstance *f, const char *name, int logging, MfLogFn log, const MaglevAllocator *alloc,
            unsigned int time_vr, const char *resources_dir, char *msg, size_t msglen) {
    memset(f, 0, sizeof *f);
    snprintf(f->name, sizeof f->name, "%s", name);
    f->log = log;
    f->logging = logging ? 1 : 0;
    f->alloc = *alloc;
    f->time_vr = time_vr;
    maglev_defaults(&f->plant);
    if (load_start_values(&f->plant, resources_dir, &f->n_start_values, msg, msglen)) return -1;
    memcpy(f->start_params, f->plant.p, sizeof f->start_params);
    f->state = MF_INSTANTIATED;
    return 0;
}

static void snapshot_free(MfInstance *f, MfSnapshot *s) {
    if (s->prev) s->prev->next = s->next; else f->snapshots = s->next;
    if (s->next) s->next->prev = s->prev;
    maglev_release(&s->plant, &f->alloc);
    f->alloc.release(s, f->alloc.env);
}

void mf_release(MfInstance *f) {
    while (f->snapshots) snapshot_free(f, f->snapshots);
    maglev_release(&f->plant, &f->alloc);
    f->state = MF_START_AND_END;
}

/* ---- modes ---- */

/* An experiment as the standards allow it (the same checks for fmi2SetupExperiment, fmi3EnterInitializationMode
 * and a deserialized FMU state); 0, or -1 with msg. */
static int check_experiment(const MfExperiment *e, char *msg, size_t len) {
    if (e->tol_defined ? !(isfinite(e->tolerance) && e->tolerance > 0) : e->tolerance != 0) {
        snprintf(msg, len, "tolerance %g must be > 0 and finite%s", e->tolerance,
                 e->tol_defined ? "" : " (or 0 when undefined)");
        return -1;
    }
    if (!(fabs(e->start_time) <= MAGLEV_TIME_MAX)) {
        snprintf(msg, len, "startTime %g must be finite and within +-%g s", e->start_time, MAGLEV_TIME_MAX);
        return -1;
    }
    if (e->stop_defined ? !(e->stop_time >= e->start_time && e->stop_time <= MAGLEV_TIME_MAX) : e->stop_time != 0) {
        snprintf(msg, len, "stopTime %g must be >= startTime %g and <= %g s%s", e->stop_time, e->start_time,
                 MAGLEV_TIME_MAX, e->stop_defined ? "" : " (or 0 when undefined)");
        return -1;
    }
    return 0;
}

int mf_setup_experiment(MfInstance *f, const char *fn, int tol_defined, double tol, double start, int stop_defined,
                        double stop) {
    char msg[MAGLEV_MSG_LEN];
    MfExperiment e = {start, stop_defined ? stop : 0.0, tol_defined ? tol : 0.0, stop_defined ? 1 : 0,
                      tol_defined ? 1 : 0};
    if (check_experiment(&e, msg, sizeof msg)) return mf_error(f, "%s: %s", fn, msg);
    f->exp = e;
    f->plant.time = start;
    return MF_OK;
}

int mf_enter_initialization(MfInstance *f) {
    f->plant.time = f->exp.start_time;
    f->state = MF_INITIALIZATION_MODE;
    return MF_OK;
}

int mf_exit_initialization(MfInstance *f, const char *fn) {
    char msg[MAGLEV_MSG_LEN];
    if (maglev_initialize(&f->plant, f->exp.start_time, f->plant.u, &f->alloc, msg, sizeof msg))
        return mf_error(f, "%s: %s", fn, msg);
    f->state = MF_STEP_COMPLETE;
    return MF_OK;
}

int mf_terminate(MfInstance *f) {
    f->state = MF_TERMINATED;
    return MF_OK;
}

int mf_reset(MfInstance *f, const char *fn) {
    maglev_release(&f->plant, &f->alloc);
    maglev_defaults(&f->plant);
    /* the start values of instantiation, not the C defaults: a rig's or calibrated FMU's parameters */
    memcpy(f->plant.p, f->start_params, sizeof f->start_params);
    if (f->n_start_values > 0)
        mf_log(f, MF_OK, "logCalls", "%s: back to the state after instantiation, with the %d start values of "
               "resources/start_values.txt", fn, f->n_start_values);
    else
        mf_log(f, MF_OK, "logCalls", "%s: back to the state after instantiation", fn);
    memset(&f->exp, 0, sizeof f->exp);
    f->state = MF_INSTANTIATED;
    return MF_OK;
}

/* ---- values ---- */

/* The FMI 3.0 independent variable; never a match in a 2.0 instance (whose time_vr is MF_NO_TIME_VR, which
 * an importer may well pass as a value reference). */
static int is_time(const MfInstance *f, unsigned int vr) { return f->time_vr != MF_NO_TIME_VR && vr == f->time_vr; }

static int check_vrs(MfInstance *f, const char *fn, const unsigned int vr[], size_t nvr, const void *value) {
    if (nvr == 0) return 1;
    if (!vr || !value) {
        mf_error(f, "%s: vr or value array is NULL", fn);
        return 0;
    }
    for (size_t k = 0; k < nvr; k++)
        if (vr[k] >= MAGLEV_NVARS && !is_time(f, vr[k])) {
            mf_error(f, "%s: unknown value reference %u", fn, (unsigned)vr[k]);
            return 0;
        }
    return 1;
}

int mf_get_real(MfInstance *f, const char *fn, const unsigned int vr[], size_t nvr, double value[]) {
    if (!check_vrs(f, fn, vr, nvr, value)) return MF_ERROR;
    /* Before initialisation ends the state is not set yet: outputs are what initialisation would
     * give, and cannot be given while the parameters contradict each other. */
    MaglevPlant view;
    const MaglevPlant *p = &f->plant;
    char msg[MAGLEV_MSG_LEN];
    if (f->state == MF_INITIALIZATION_MODE) {
        for (size_t k = 0; k < nvr; k++) {
            if (is_time(f, vr[k]) || maglev_variables[vr[k]].causality != MAGLEV_OUTPUT) continue;
            if (maglev_preview(&f->plant, f->exp.start_time, &view, msg, sizeof msg))
                return mf_error(f, "%s: output %s is undefined until the parameters agree: %s", fn,
                                maglev_variables[vr[k]].name, msg);
            p = &view;
            break;
        }
    }
    for (size_t k = 0; k < nvr; k++) {
        if (is_time(f, vr[k])) {
            value[k] = f->plant.time;
            continue;
        }
        value[k] = maglev_get(p, (MaglevVR)vr[k]);
        if (!isfinite(value[k]))
            return mf_error(f, "%s: variable %s is not finite (%g)", fn, maglev_variables[vr[k]].name, value[k]);
    }
    return MF_OK;
}

int mf_set_real(MfInstance *f, const char *fn, const unsigned int vr[], size_t nvr, const double value[]) {
    char msg[MAGLEV_MSG_LEN];
    if (!check_vrs(f, fn, vr, nvr, value)) return MF_ERROR;
    /* validate everything first, so a rejected call changes nothing */
    for (size_t k = 0; k < nvr; k++) {
        if (is_time(f, vr[k]))
            return mf_error(f, "%s: variable time is the independent variable and cannot be set", fn);
        const MaglevVariable *var = &maglev_variables[vr[k]];
        if (var->causality == MAGLEV_OUTPUT)
            return mf_error(f, "%s: variable %s is an output and cannot be set", fn, var->name);
        if (var->causality == MAGLEV_PARAMETER && f->state == MF_STEP_COMPLETE)
            return mf_error(f, "%s: variable %s is a fixed parameter, settable only before the end of "
                            "initialization mode", fn, var->name);
        if (maglev_check_value((MaglevVR)vr[k], value[k], msg, sizeof msg))
            return mf_error(f, "%s: %s", fn, msg);
    }
    for (size_t k = 0; k < nvr; k++) {
        if (vr[k] == VR_u) {
            if (f->state == MF_STEP_COMPLETE) {
                if (maglev_set_input(&f->plant, value[k], &f->alloc, msg, sizeof msg)) {
                    f->state = MF_ERROR_STATE;
                    return mf_error(f, "%s: %s", fn, msg);
                }
            } else {
                f->plant.u = value[k];
            }
        } else {
            maglev_set_param(&f->plant, (MaglevVR)vr[k], value[k]);
        }
    }
    return MF_OK;
}

int mf_no_such_type(MfInstance *f, const char *fn, int mask, size_t nvr, const unsigned int vr[]) {
    if (!mf_guard(f, fn, mask)) return MF_ERROR;
    if (nvr == 0) return MF_OK;
    return mf_error(f, "%s: the FMU has no variable of this type (value reference %u)", fn, vr ? (unsigned)vr[0] : 0u);
}

/* ---- step ---- */

int mf_do_step(MfInstance *f, const char *fn, double t_importer, double h) {
    char msg[MAGLEV_MSG_LEN];
    double t = f->plant.time;
    if (!isfinite(t_importer))
        return mf_error(f, "%s: currentCommunicationPoint %g is not finite", fn, t_importer);
    if (!isfinite(h) || h <= 0)
        return mf_error(f, "%s: communicationStepSize %g must be > 0 and finite", fn, h);
    if (fabs(t_importer - t) > 1e-9 * (1.0 + fabs(t)))
        return mf_error(f, "%s: currentCommunicationPoint %.17g does not match the FMU time %.17g", fn, t_importer, t);
    if (f->exp.stop_defined && t_importer + h > f->exp.stop_time * (1 + 1e-12) + 1e-12)
        return mf_error(f, "%s: step to %.17g goes past stopTime %.17g", fn, t_importer + h, f->exp.stop_time);
    /* the importer's time is the reference: absorb rounding between its clock and ours (for a step
     * taken; a refused step leaves the time as it was, which may be the only one in range) */
    f->plant.time = t_importer;
    int rc = maglev_step(&f->plant, h, &f->alloc, msg, sizeof msg);
    if (rc) f->plant.time = t;
    if (rc == MAGLEV_REFUSED) return mf_error(f, "%s: %s", fn, msg); /* nothing changed: shorter steps will do */
    if (rc) {
        f->state = MF_ERROR_STATE; /* the model broke down; the values are those before the step */
        return mf_error(f, "%s: %s", fn, msg);
    }
    return MF_OK;
}

/* ---- FMU states ---- */

static MfSnapshot *owned(MfInstance *f, const char *fn, const void *state) {
    for (MfSnapshot *s = f->snapshots; s; s = s->next)
        if (s == state) return s;
    mf_error(f, "%s: FMU state %p was not made by this instance or was freed (move states between instances "
             "by serializing them)", fn, state);
    return NULL;
}

static MfSnapshot *snapshot_new(MfInstance *f) {
    MfSnapshot *s = f->alloc.alloc(1, sizeof *s, f->alloc.env);
    if (!s) return NULL;
    memset(s, 0, sizeof *s);
    s->next = f->snapshots;
    if (s->next) s->next->prev = s;
    f->snapshots = s;
    return s;
}

int mf_get_state(MfInstance *f, const char *fn, void **state) {
    if (!state) return mf_error(f, "%s: FMU state pointer is NULL", fn);
    MaglevPlant copy;
    if (maglev_copy(&copy, &f->plant, &f->alloc)) return mf_error(f, "%s: out of memory", fn);
    MfSnapshot *s;
    if (*state) {
        if (!(s = owned(f, fn, *state))) {
            maglev_release(&copy, &f->alloc);
            return MF_ERROR;
        }
        maglev_release(&s->plant, &f->alloc);
    } else if (!(s = snapshot_new(f))) {
        maglev_release(&copy, &f->alloc);
        return mf_error(f, "%s: out of memory", fn);
    }
    s->plant = copy;
    s->state = f->state;
    s->exp = f->exp;
    *state = s;
    return MF_OK;
}

int mf_set_state(MfInstance *f, const char *fn, void *state) {
    if (!state) return mf_error(f, "%s: FMU state is NULL", fn);
    const MfSnapshot *s = owned(f, fn, state);
    if (!s) return MF_ERROR;
    MaglevPlant copy;
    if (maglev_copy(&copy, &s->plant, &f->alloc)) return mf_error(f, "%s: out of memory", fn);
    maglev_release(&f->plant, &f->alloc);
    f->plant = copy;
    f->state = s->state;
    f->exp = s->exp;
    return MF_OK;
}

int mf_free_state(MfInstance *f, const char *fn, void **state) {
    if (!state) return mf_error(f, "%s: FMU state pointer is NULL", fn);
    if (!*state) return MF_OK;
    MfSnapshot *s = owned(f, fn, *state);
    if (!s) return MF_ERROR;
    snapshot_free(f, s);
    *state = NULL;
    return MF_OK;
}

static int state_code(MfState s) {
    for (int k = 0; k < 7; k++)
        if ((int)s == 1 << k) return k;
    return -1;
}

/* Serialised form: the plant image (maglev_plant.c), with the FMU state's code and its experiment in the
 * image's tag, under its checksum: flags bit 0 stopTime defined, bit 1 tolerance defined; values startTime,
 * stopTime, tolerance. */
enum { EXP_STOP_DEFINED = 1u, EXP_TOL_DEFINED = 2u };

int mf_serialized_size(MfInstance *f, const char *fn, void *state, size_t *size) {
    if (!state || !size) return mf_error(f, "%s: FMU state or size is NULL", fn);
    const MfSnapshot *s = owned(f, fn, state);
    if (!s) return MF_ERROR;
    *size = maglev_serialized_size(&s->plant);
    return MF_OK;
}

int mf_serialize(MfInstance *f, const char *fn, void *state, unsigned char *buf, size_t size) {
    if (!state || !buf) return mf_error(f, "%s: FMU state or buffer is NULL", fn);
    const MfSnapshot *s = owned(f, fn, state);
    if (!s) return MF_ERROR;
    size_t need = maglev_serialized_size(&s->plant);
    if (size < need) return mf_error(f, "%s: buffer of %zu bytes, %zu needed", fn, size, need);
    MaglevTag tag = {(unsigned int)state_code(s->state),
                     (s->exp.stop_defined ? EXP_STOP_DEFINED : 0u) | (s->exp.tol_defined ? EXP_TOL_DEFINED : 0u),
                     {s->exp.start_time, s->exp.stop_time, s->exp.tolerance}};
    maglev_serialize(&s->plant, &tag, buf);
    return MF_OK;
}

int mf_deserialize(MfInstance *f, const char *fn, const unsigned char *buf, size_t size, void **state) {
    char msg[MAGLEV_MSG_LEN];
    if (!buf || !state) return mf_error(f, "%s: NULL buffer or FMU state pointer", fn);
    if (*state && !owned(f, fn, *state)) return MF_ERROR;
    MaglevPlant p;
    MaglevTag tag;
    memset(&p, 0, sizeof p);
    if (maglev_deserialize(&p, &tag, buf, size, &f->alloc, msg, sizeof msg)) return mf_error(f, "%s: %s", fn, msg);
    /* the state machine's state must be one the plant can be in */
    unsigned int code = tag.code;
    MfState st = code >= 1 && code <= 6 ? (MfState)(1 << code) : MF_START_AND_END;
    int needs_init = st & (MF_STEP_COMPLETE | MF_STEP_FAILED | MF_TERMINATED);
    int needs_fresh = st & (MF_INSTANTIATED | MF_INITIALIZATION_MODE);
    if (st == MF_START_AND_END || (needs_init && !p.initialized) || (needs_fresh && p.initialized)) {
        maglev_release(&p, &f->alloc);
        return mf_error(f, "%s: FMU state code %u does not fit the plant's state", fn, code);
    }
    /* an experiment SetupExperiment would accept; before initialisation ends the plant's time is its start */
    MfExperiment e = {tag.value[0], tag.value[1], tag.value[2], (tag.flags & EXP_STOP_DEFINED) != 0,
                      (tag.flags & EXP_TOL_DEFINED) != 0};
    msg[0] = 0; /* check_experiment writes it only when it refuses */
    if (tag.flags & ~(unsigned int)(EXP_STOP_DEFINED | EXP_TOL_DEFINED))
        snprintf(msg, sizeof msg, "unknown experiment flags 0x%x", tag.flags);
    else if (check_experiment(&e, msg, sizeof msg) == 0 && needs_fresh && p.time != e.start_time)
        snprintf(msg, sizeof msg, "time %g before initialization differs from startTime %g", p.time, e.start_time);
    if (msg[0]) {
        maglev_release(&p, &f->alloc);
        return mf_error(f, "%s: serialized state holds an experiment the FMU cannot have: %s", fn, msg);
    }
    MfSnapshot *s = *state;
    if (s) {
        maglev_release(&s->plant, &f->alloc);
    } else if (!(s = snapshot_new(f))) {
        maglev_release(&p, &f->alloc);
        return mf_error(f, "%s: out of memory", fn);
    }
    s->plant = p;
    s->state = st;
    s->exp = e;
    *state = s;
    return MF_OK;
}
