/* The instance logic both FMI glues share (maglev_fmi_common.h). */
#include "maglev_fmi_common.h"

#include <ctype.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Room for any model's state after a struct: the alignment of everything a model's struct may hold. */
typedef union {
    double d;
    long long ll;
    void *p;
} MfAlign;

/* An FMU state. The instance that made it owns it (a list, so that freeing the instance frees what
 * the importer left behind, and a foreign or stale pointer is refused instead of followed). */
struct MfSnapshot {
    MfState state;
    MfExperiment exp;
    struct MfSnapshot *prev, *next;
    MfAlign data[]; /* the model's state, model->size bytes */
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

/* The file name in the resources folder dir, open for reading; NULL when there is no folder or no such
 * file (an FMU without it), or the path would not fit. */
static FILE *open_resource(const char *dir, const char *name) {
    char path[4096];
    if (!dir) return NULL;
    size_t n = strlen(dir), len = strlen(name);
    while (n > 0 && is_separator(dir[n - 1])) n--;
    if (n + 1 + len + 1 > sizeof path) return NULL;
    memcpy(path, dir, n);
    path[n] = '/';
    memcpy(path + n + 1, name, len + 1);
    return fopen(path, "r");
}

#define GUID_FILE "guid.txt"
int mf_accepted_guid(const MfModel *model, const char *dir, char *guid, size_t glen, char *msg, size_t len) {
    char line[128];
    snprintf(guid, glen, "%s", model->guid);
    FILE *fp = open_resource(dir, GUID_FILE);
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

/* A rig's FMU (maglev-cosim fmu --rig) carries its parameters in resources/start_values.txt, one
 * "name value" per line: they replace the model's start values, so that the FMU uses the start values its
 * model description states. No file (the CE152 FMU, the controller): the table's. Returns 0, or -1 with
 * msg. */
#define START_VALUES_FILE "start_values.txt"
static int load_start_values(MfInstance *f, const char *dir, char *msg, size_t len) {
    const MfModel *model = f->model;
    FILE *fp = open_resource(dir, START_VALUES_FILE);
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
        unsigned int vr = model->nvars;
        for (unsigned int j = 0; j < model->nvars; j++)
            if (model->variables[j].causality == MAGLEV_PARAMETER && strcmp(model->variables[j].name, name) == 0)
                vr = j;
        if (vr == model->nvars) {
            snprintf(msg, len, "resources/%s line %d: %s is not a parameter of this FMU", START_VALUES_FILE, ln,
                     name);
            rc = -1;
        } else {
            char why[MAGLEV_MSG_LEN - 56]; /* room for the file and line in msg */
            if (model->check_value(vr, value, why, sizeof why)) {
                snprintf(msg, len, "resources/%s line %d: %s", START_VALUES_FILE, ln, why);
                rc = -1;
            } else {
                f->start[vr] = value;
                ++f->n_start_values;
            }
        }
    }
    fclose(fp);
    return rc;
}

/* The parameters of instantiation into the model, which holds the table's start values (defaults). A
 * parameter is set before initialisation, which needs no memory: nothing can fail. */
static void apply_start_values(MfInstance *f) {
    char msg[MAGLEV_MSG_LEN];
    for (unsigned int vr = 0; vr < f->model->nvars; vr++)
        if (f->model->variables[vr].causality == MAGLEV_PARAMETER)
            (void)f->model->set(f->data, vr, f->start[vr], &f->alloc, msg, sizeof msg);
}

/* A model's state rounded up to whole MfAlign units, so that the states after it in one block are aligned. */
static size_t state_room(const MfModel *model) {
    return (model->size + sizeof(MfAlign) - 1) / sizeof(MfAlign) * sizeof(MfAlign);
}

int mf_init(MfInstance *f, const MfModel *model, const char *name, int logging, MfLogFn log,
            const MaglevAllocator *alloc, unsigned int time_vr, const char *resources_dir, char *msg,
            size_t msglen) {
    memset(f, 0, sizeof *f);
    snprintf(f->name, sizeof f->name, "%s", name);
    f->log = log;
    f->logging = logging ? 1 : 0;
    f->alloc = *alloc;
    f->time_vr = time_vr;
    f->model = model;
    /* one block: the state, the scratch state, the start values (a failed instantiation frees one thing) */
    size_t room = state_room(model);
    unsigned char *block = alloc->alloc(1, 2 * room + model->nvars * sizeof(double), alloc->env);
    if (!block) {
        snprintf(msg, msglen, "out of memory for the model's state");
        return -1;
    }
    f->data = block;
    f->scratch = block + room;
    f->start = (double *)(void *)(block + 2 * room);
    for (unsigned int vr = 0; vr < model->nvars; vr++) f->start[vr] = model->variables[vr].start;
    if (load_start_values(f, resources_dir, msg, msglen)) {
        alloc->release(block, alloc->env);
        f->data = NULL;
        return -1;
    }
    model->defaults(f->data);
    apply_start_values(f);
    f->state = MF_INSTANTIATED;
    return 0;
}

static void snapshot_free(MfInstance *f, MfSnapshot *s) {
    if (s->prev) s->prev->next = s->next; else f->snapshots = s->next;
    if (s->next) s->next->prev = s->prev;
    f->model->release(s->data, &f->alloc);
    f->alloc.release(s, f->alloc.env);
}

void mf_release(MfInstance *f) {
    while (f->snapshots) snapshot_free(f, f->snapshots);
    if (f->data) {
        f->model->release(f->data, &f->alloc);
        f->alloc.release(f->data, f->alloc.env); /* the block that holds scratch and start too */
        f->data = f->scratch = NULL;
        f->start = NULL;
    }
    f->state = MF_START_AND_END;
}

double mf_time(const MfInstance *f) { return f->model->time(f->data); }

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
    f->model->set_time(f->data, start);
    return MF_OK;
}

int mf_enter_initialization(MfInstance *f) {
    f->model->set_time(f->data, f->exp.start_time);
    f->state = MF_INITIALIZATION_MODE;
    return MF_OK;
}

int mf_exit_initialization(MfInstance *f, const char *fn) {
    char msg[MAGLEV_MSG_LEN];
    if (f->model->initialize(f->data, f->exp.start_time, &f->alloc, msg, sizeof msg))
        return mf_error(f, "%s: %s", fn, msg);
    f->state = MF_STEP_COMPLETE;
    return MF_OK;
}

int mf_terminate(MfInstance *f) {
    f->state = MF_TERMINATED;
    return MF_OK;
}

int mf_reset(MfInstance *f, const char *fn) {
    f->model->release(f->data, &f->alloc);
    f->model->defaults(f->data);
    /* the start values of instantiation, not the table's: a rig's or calibrated FMU's parameters */
    apply_start_values(f);
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
        if (vr[k] >= f->model->nvars && !is_time(f, vr[k])) {
            mf_error(f, "%s: unknown value reference %u", fn, (unsigned)vr[k]);
            return 0;
        }
    return 1;
}

int mf_get_real(MfInstance *f, const char *fn, const unsigned int vr[], size_t nvr, double value[]) {
    const MfModel *model = f->model;
    if (!check_vrs(f, fn, vr, nvr, value)) return MF_ERROR;
    /* Before initialisation ends the state is not set yet: outputs are what initialisation would
     * give, and cannot be given while the parameters contradict each other. */
    const void *src = f->data;
    char msg[MAGLEV_MSG_LEN];
    if (f->state == MF_INITIALIZATION_MODE) {
        for (size_t k = 0; k < nvr; k++) {
            if (is_time(f, vr[k]) || model->variables[vr[k]].causality != MAGLEV_OUTPUT) continue;
            if (model->preview(f->data, f->exp.start_time, f->scratch, msg, sizeof msg))
                return mf_error(f, "%s: output %s is undefined until the parameters agree: %s", fn,
                                model->variables[vr[k]].name, msg);
            src = f->scratch;
            break;
        }
    }
    for (size_t k = 0; k < nvr; k++) {
        if (is_time(f, vr[k])) {
            value[k] = mf_time(f);
            continue;
        }
        value[k] = model->get(src, vr[k]);
        if (!isfinite(value[k]))
            return mf_error(f, "%s: variable %s is not finite (%g)", fn, model->variables[vr[k]].name, value[k]);
    }
    return MF_OK;
}

int mf_set_real(MfInstance *f, const char *fn, const unsigned int vr[], size_t nvr, const double value[]) {
    const MfModel *model = f->model;
    char msg[MAGLEV_MSG_LEN];
    if (!check_vrs(f, fn, vr, nvr, value)) return MF_ERROR;
    /* validate everything first, so a rejected call changes nothing */
    for (size_t k = 0; k < nvr; k++) {
        if (is_time(f, vr[k]))
            return mf_error(f, "%s: variable time is the independent variable and cannot be set", fn);
        const MaglevVariable *var = &model->variables[vr[k]];
        if (var->causality == MAGLEV_OUTPUT)
            return mf_error(f, "%s: variable %s is an output and cannot be set", fn, var->name);
        if (var->causality == MAGLEV_PARAMETER && f->state == MF_STEP_COMPLETE)
            return mf_error(f, "%s: variable %s is a fixed parameter, settable only before the end of "
                            "initialization mode", fn, var->name);
        if (model->check_value(vr[k], value[k], msg, sizeof msg))
            return mf_error(f, "%s: %s", fn, msg);
    }
    for (size_t k = 0; k < nvr; k++)
        if (model->set(f->data, vr[k], value[k], &f->alloc, msg, sizeof msg)) {
            f->state = MF_ERROR_STATE; /* an input the model could not take after initialisation (memory) */
            return mf_error(f, "%s: %s", fn, msg);
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
    const MfModel *model = f->model;
    char msg[MAGLEV_MSG_LEN];
    double t = mf_time(f);
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
    model->set_time(f->data, t_importer);
    int rc = model->step(f->data, h, &f->alloc, msg, sizeof msg);
    if (rc) model->set_time(f->data, t);
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
    MfSnapshot *s = f->alloc.alloc(1, sizeof *s + f->model->size, f->alloc.env);
    if (!s) return NULL;
    memset(s, 0, sizeof *s + f->model->size);
    s->next = f->snapshots;
    if (s->next) s->next->prev = s;
    f->snapshots = s;
    return s;
}

/* Where a state built in scratch goes: into the FMU state *state (its old model state released), or into a
 * new one when *state is NULL. Releases scratch and returns NULL when there is no memory for it. */
static MfSnapshot *take_scratch(MfInstance *f, void **state) {
    MfSnapshot *s = *state;
    if (s) {
        f->model->release(s->data, &f->alloc);
    } else if (!(s = snapshot_new(f))) {
        f->model->release(f->scratch, &f->alloc);
        return NULL;
    }
    memcpy(s->data, f->scratch, f->model->size);
    *state = s;
    return s;
}

int mf_get_state(MfInstance *f, const char *fn, void **state) {
    if (!state) return mf_error(f, "%s: FMU state pointer is NULL", fn);
    memset(f->scratch, 0, f->model->size);
    if (f->model->copy(f->scratch, f->data, &f->alloc)) return mf_error(f, "%s: out of memory", fn);
    if (*state && !owned(f, fn, *state)) {
        f->model->release(f->scratch, &f->alloc);
        return MF_ERROR;
    }
    MfSnapshot *s = take_scratch(f, state);
    if (!s) return mf_error(f, "%s: out of memory", fn);
    s->state = f->state;
    s->exp = f->exp;
    return MF_OK;
}

int mf_set_state(MfInstance *f, const char *fn, void *state) {
    if (!state) return mf_error(f, "%s: FMU state is NULL", fn);
    const MfSnapshot *s = owned(f, fn, state);
    if (!s) return MF_ERROR;
    memset(f->scratch, 0, f->model->size);
    if (f->model->copy(f->scratch, s->data, &f->alloc)) return mf_error(f, "%s: out of memory", fn);
    f->model->release(f->data, &f->alloc);
    memcpy(f->data, f->scratch, f->model->size);
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

/* Serialised form: the model's image (maglev_plant.c, maglev_pid_fmu.c), with the FMU state's code and its
 * experiment in the image's tag, under its checksum: flags bit 0 stopTime defined, bit 1 tolerance defined;
 * values startTime, stopTime, tolerance. */
enum { EXP_STOP_DEFINED = 1u, EXP_TOL_DEFINED = 2u };

int mf_serialized_size(MfInstance *f, const char *fn, void *state, size_t *size) {
    if (!state || !size) return mf_error(f, "%s: FMU state or size is NULL", fn);
    const MfSnapshot *s = owned(f, fn, state);
    if (!s) return MF_ERROR;
    *size = f->model->serialized_size(s->data);
    return MF_OK;
}

int mf_serialize(MfInstance *f, const char *fn, void *state, unsigned char *buf, size_t size) {
    if (!state || !buf) return mf_error(f, "%s: FMU state or buffer is NULL", fn);
    const MfSnapshot *s = owned(f, fn, state);
    if (!s) return MF_ERROR;
    size_t need = f->model->serialized_size(s->data);
    if (size < need) return mf_error(f, "%s: buffer of %zu bytes, %zu needed", fn, size, need);
    MaglevTag tag = {(unsigned int)state_code(s->state),
                     (s->exp.stop_defined ? EXP_STOP_DEFINED : 0u) | (s->exp.tol_defined ? EXP_TOL_DEFINED : 0u),
                     {s->exp.start_time, s->exp.stop_time, s->exp.tolerance}};
    f->model->serialize(s->data, &tag, buf);
    return MF_OK;
}

/* Whether a deserialized model state with its tag is one this FMU can be in: 0, or -1 with msg. The
 * state machine's state must fit the model's (initialised or not), and the experiment must be one
 * SetupExperiment would accept, with the time of a model not yet initialised at its start. */
static int check_tag(const MfInstance *f, const void *m, const MaglevTag *tag, MfState *st, MfExperiment *e,
                     char *msg, size_t len) {
    unsigned int code = tag->code;
    *st = code >= 1 && code <= 6 ? (MfState)(1 << code) : MF_START_AND_END;
    int needs_init = *st & (MF_STEP_COMPLETE | MF_STEP_FAILED | MF_TERMINATED);
    int needs_fresh = *st & (MF_INSTANTIATED | MF_INITIALIZATION_MODE);
    int initialized = f->model->initialized(m);
    if (*st == MF_START_AND_END || (needs_init && !initialized) || (needs_fresh && initialized)) {
        snprintf(msg, len, "FMU state code %u does not fit the model's state", code);
        return -1;
    }
    MfExperiment ex = {tag->value[0], tag->value[1], tag->value[2], (tag->flags & EXP_STOP_DEFINED) != 0,
                       (tag->flags & EXP_TOL_DEFINED) != 0};
    char why[MAGLEV_MSG_LEN - 64]; /* room for the sentence around it */
    why[0] = 0; /* check_experiment writes it only when it refuses */
    if (tag->flags & ~(unsigned int)(EXP_STOP_DEFINED | EXP_TOL_DEFINED))
        snprintf(why, sizeof why, "unknown experiment flags 0x%x", tag->flags);
    else if (check_experiment(&ex, why, sizeof why) == 0 && needs_fresh && f->model->time(m) != ex.start_time)
        snprintf(why, sizeof why, "time %g before initialization differs from startTime %g", f->model->time(m),
                 ex.start_time);
    if (why[0]) {
        snprintf(msg, len, "serialized state holds an experiment the FMU cannot have: %s", why);
        return -1;
    }
    *e = ex;
    return 0;
}

int mf_deserialize(MfInstance *f, const char *fn, const unsigned char *buf, size_t size, void **state) {
    char msg[MAGLEV_MSG_LEN];
    if (!buf || !state) return mf_error(f, "%s: NULL buffer or FMU state pointer", fn);
    if (*state && !owned(f, fn, *state)) return MF_ERROR;
    MaglevTag tag;
    MfState st;
    MfExperiment e;
    memset(f->scratch, 0, f->model->size);
    if (f->model->deserialize(f->scratch, &tag, buf, size, &f->alloc, msg, sizeof msg))
        return mf_error(f, "%s: %s", fn, msg);
    if (check_tag(f, f->scratch, &tag, &st, &e, msg, sizeof msg)) {
        f->model->release(f->scratch, &f->alloc);
        return mf_error(f, "%s: %s", fn, msg);
    }
    MfSnapshot *s = take_scratch(f, state);
    if (!s) return mf_error(f, "%s: out of memory", fn);
    s->state = st;
    s->exp = e;
    return MF_OK;
}
