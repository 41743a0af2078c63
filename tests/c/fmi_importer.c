/* A small FMI importer: loads an extracted FMU's binary for the platform it was compiled for
 * (LoadLibrary/GetProcAddress on Windows, dlopen/dlsym elsewhere), and runs the closed loop of the
 * plant FMU with the paper's PID (maglev_pid_step of maglev_replay.c, the one PID of the C side) or,
 * with --pid-fmu, with the controller FMU maglev_pid. It prints the trajectory, one line per sample
 * t_k = k*ts, with %.17g:  t w y u x v i  (the PID's reference, the plant's reading, the input held
 * over [t_k, t_k + ts), the plant's states at t_k).
 *
 * The same file is built for Linux (fmi_importer) and, cross-compiled with mingw-w64, for Windows
 * (fmi_importer.exe, run under wine): tests/test_win64.py compares the two runs, maglev.so against
 * maglev.dll, FMI 2.0 and 3.0.
 *
 *   fmi_importer FMU_DIR STOP [--pid-fmu PID_FMU_DIR] [name=value ...]
 *
 * FMU_DIR: the extracted plant FMU (modelDescription.xml, binaries/); the FMI version, the GUID or
 * instantiation token and the value references are read from its modelDescription.xml. STOP: the
 * duration [s]. name=value: a start value of a plant variable (x_start, i_start, u, ...) or a setting
 * of the PID and its step reference (ts kp ki kd tf u_min u_max anti_windup i_lo i_hi backoff u_hold
 * w0 w1 t_step; default: the paper's PID, Eq. 22, at 1 kHz; the PID FMU gets them as its parameters).
 * The loop is the one loop.simulate runs: at t_k the plant's reading y[k] is taken, u[k] = PID(w[k] -
 * y[k]) is set, the plant steps ts. Exit status 0, or 1 with a message on stderr. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"
#include "maglev_replay.h"

#ifdef _WIN32
#include <windows.h>
#define FMI2_PLATFORM "win64"
#define FMI3_PLATFORM "x86_64-windows"
#define LIB_EXT ".dll"
typedef HMODULE Lib;
static Lib lib_open(const char *path) { return LoadLibraryA(path); }
static void *lib_sym(Lib lib, const char *name) {
    FARPROC p = GetProcAddress(lib, name);
    void *q;
    memcpy(&q, &p, sizeof q); /* a function pointer as void * without a cast ISO C forbids */
    return q;
}
static void lib_close(Lib lib) { FreeLibrary(lib); }
#else
#include <dlfcn.h>
#define FMI2_PLATFORM "linux64"
#define FMI3_PLATFORM "x86_64-linux"
#define LIB_EXT ".so"
typedef void *Lib;
static Lib lib_open(const char *path) { return dlopen(path, RTLD_NOW | RTLD_LOCAL); }
static void *lib_sym(Lib lib, const char *name) { return dlsym(lib, name); }
static void lib_close(Lib lib) { dlclose(lib); }
#endif

#define MAX_NAME 64
#define MAX_VARS 256

static void die(const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    fputs("fmi_importer: ", stderr);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
    exit(1);
}

/* ---- modelDescription.xml: just what this importer needs, by plain string search ---- */

typedef struct {
    int fmi3;
    char token[128];     /* guid (2.0) or instantiationToken (3.0) */
    char model_id[128];  /* modelIdentifier of <CoSimulation> */
    int nvars;
    char names[MAX_VARS][MAX_NAME];
    unsigned int vrs[MAX_VARS];
} Description;

static char *read_file(const char *path) {
    FILE *fp = fopen(path, "rb");
    if (!fp) die("cannot open %s", path);
    size_t cap = 1 << 16, n = 0;
    char *buf = malloc(cap);
    for (size_t got; buf && (got = fread(buf + n, 1, cap - n - 1, fp)) > 0;) {
        n += got;
        if (n + 1 == cap) buf = realloc(buf, cap *= 2);
    }
    fclose(fp);
    if (!buf) die("out of memory reading %s", path);
    buf[n] = 0;
    return buf;
}

/* The value of attribute attr in the element starting at el (before its closing '>'). */
static int attribute(const char *el, const char *attr, char *out, size_t len) {
    const char *end = strchr(el, '>');
    size_t alen = strlen(attr);
    for (const char *p = el; (p = strstr(p, attr)) != NULL && (!end || p < end); p += alen) {
        if (p[alen] != '=' || p[alen + 1] != '"' || (p > el && p[-1] != ' ' && p[-1] != '\n' && p[-1] != '\t'))
            continue;
        const char *v = p + alen + 2, *q = strchr(v, '"');
        if (!q || (size_t)(q - v) + 1 > len) return -1;
        memcpy(out, v, (size_t)(q - v));
        out[q - v] = 0;
        return 0;
    }
    return -1;
}

static void describe(const char *fmu_dir, Description *d) {
    char path[4096], version[16], vr[32];
    snprintf(path, sizeof path, "%s/modelDescription.xml", fmu_dir);
    char *xml = read_file(path);
    const char *root = strstr(xml, "<fmiModelDescription");
    if (!root || attribute(root, "fmiVersion", version, sizeof version)) die("%s: no fmiModelDescription", path);
    d->fmi3 = version[0] == '3';
    if (attribute(root, d->fmi3 ? "instantiationToken" : "guid", d->token, sizeof d->token))
        die("%s: no %s", path, d->fmi3 ? "instantiationToken" : "guid");
    const char *cs = strstr(xml, "<CoSimulation");
    if (!cs || attribute(cs, "modelIdentifier", d->model_id, sizeof d->model_id))
        die("%s: no CoSimulation modelIdentifier", path);
    d->nvars = 0;
    /* 2.0: <ScalarVariable name=.. valueReference=..>; 3.0: <Float64 name=.. valueReference=..> */
    const char *tag = d->fmi3 ? "<Float64 " : "<ScalarVariable ";
    for (const char *p = xml; (p = strstr(p, tag)) != NULL; p++) {
        if (d->nvars == MAX_VARS) die("%s: more than %d variables", path, MAX_VARS);
        if (attribute(p, "name", d->names[d->nvars], MAX_NAME) || attribute(p, "valueReference", vr, sizeof vr))
            die("%s: a variable without name or valueReference", path);
        d->vrs[d->nvars++] = (unsigned int)strtoul(vr, NULL, 10);
    }
    free(xml);
}

static int find_vr(const Description *d, const char *name, unsigned int *vr) {
    for (int k = 0; k < d->nvars; k++)
        if (strcmp(d->names[k], name) == 0) {
            *vr = d->vrs[k];
            return 0;
        }
    return -1;
}

/* ---- one FMU instance, FMI 2.0 or 3.0, behind the few calls the loop needs ---- */

typedef struct {
    Description d;
    Lib lib;
    void *inst;
    fmi2CallbackFunctions cb2;
    /* FMI 2.0 */
    fmi2InstantiateTYPE *instantiate2;
    fmi2SetupExperimentTYPE *setup2;
    fmi2EnterInitializationModeTYPE *enter2;
    fmi2ExitInitializationModeTYPE *exit2;
    fmi2SetRealTYPE *set2;
    fmi2GetRealTYPE *get2;
    fmi2DoStepTYPE *step2;
    fmi2TerminateTYPE *terminate2;
    fmi2FreeInstanceTYPE *free2;
    /* FMI 3.0 */
    fmi3InstantiateCoSimulationTYPE *instantiate3;
    fmi3EnterInitializationModeTYPE *enter3;
    fmi3ExitInitializationModeTYPE *exit3;
    fmi3SetFloat64TYPE *set3;
    fmi3GetFloat64TYPE *get3;
    fmi3DoStepTYPE *step3;
    fmi3TerminateTYPE *terminate3;
    fmi3FreeInstanceTYPE *free3;
} Fmu;

static void logger2(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                    fmi2String message, ...) {
    (void)env;
    va_list ap;
    va_start(ap, message);
    fprintf(stderr, "[%s %d %s] ", name, (int)status, category);
    vfprintf(stderr, message, ap);
    fputc('\n', stderr);
    va_end(ap);
}

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    (void)env;
    fprintf(stderr, "[%d %s] %s\n", (int)status, category, message);
}

static void *sym(Fmu *f, const char *name) {
    void *p = lib_sym(f->lib, name);
    if (!p) die("%s: %s not exported", f->d.model_id, name);
    return p;
}

/* Function pointers from void *, without the cast ISO C forbids. */
#define LOAD(f, field, name) do { void *p_ = sym(f, name); memcpy(&(f)->field, &p_, sizeof p_); } while (0)

static void fmu_load(Fmu *f, const char *dir, const char *instance_name) {
    char path[4096], res[4200];
    memset(f, 0, sizeof *f);
    describe(dir, &f->d);
    snprintf(path, sizeof path, "%s/binaries/%s/%s%s", dir, f->d.fmi3 ? FMI3_PLATFORM : FMI2_PLATFORM, f->d.model_id,
             LIB_EXT);
    f->lib = lib_open(path);
    if (!f->lib) die("cannot load %s", path);
    if (f->d.fmi3) {
        LOAD(f, instantiate3, "fmi3InstantiateCoSimulation");
        LOAD(f, enter3, "fmi3EnterInitializationMode");
        LOAD(f, exit3, "fmi3ExitInitializationMode");
        LOAD(f, set3, "fmi3SetFloat64");
        LOAD(f, get3, "fmi3GetFloat64");
        LOAD(f, step3, "fmi3DoStep");
        LOAD(f, terminate3, "fmi3Terminate");
        LOAD(f, free3, "fmi3FreeInstance");
        snprintf(res, sizeof res, "%s/resources/", dir); /* 3.0: a path */
        f->inst = f->instantiate3(instance_name, f->d.token, res, fmi3False, fmi3False, fmi3False, fmi3False, NULL, 0,
                                  NULL, logger3, NULL);
    } else {
        LOAD(f, instantiate2, "fmi2Instantiate");
        LOAD(f, setup2, "fmi2SetupExperiment");
        LOAD(f, enter2, "fmi2EnterInitializationMode");
        LOAD(f, exit2, "fmi2ExitInitializationMode");
        LOAD(f, set2, "fmi2SetReal");
        LOAD(f, get2, "fmi2GetReal");
        LOAD(f, step2, "fmi2DoStep");
        LOAD(f, terminate2, "fmi2Terminate");
        LOAD(f, free2, "fmi2FreeInstance");
        /* 2.0: a URI; a Windows path C:/x is file:///C:/x */
        snprintf(res, sizeof res, "file://%s%s/resources", dir[0] == '/' ? "" : "/", dir);
        for (char *p = res; *p; p++)
            if (*p == '\\') *p = '/';
        f->cb2.logger = logger2;
        f->cb2.allocateMemory = calloc;
        f->cb2.freeMemory = free;
        f->inst = f->instantiate2(instance_name, fmi2CoSimulation, f->d.token, res, &f->cb2, fmi2False, fmi2False);
    }
    if (!f->inst) die("%s: instantiation failed", path);
}

static void fmu_set(Fmu *f, const char *name, double value) {
    unsigned int vr;
    if (find_vr(&f->d, name, &vr)) die("%s has no variable %s", f->d.model_id, name);
    int st = f->d.fmi3 ? (int)f->set3(f->inst, &vr, 1, &value, 1) : (int)f->set2(f->inst, &vr, 1, &value);
    if (st != 0) die("%s: setting %s = %.17g failed (status %d)", f->d.model_id, name, value, st);
}

static double fmu_get(Fmu *f, const char *name) {
    unsigned int vr;
    double value = NAN;
    if (find_vr(&f->d, name, &vr)) die("%s has no variable %s", f->d.model_id, name);
    int st = f->d.fmi3 ? (int)f->get3(f->inst, &vr, 1, &value, 1) : (int)f->get2(f->inst, &vr, 1, &value);
    if (st != 0) die("%s: getting %s failed (status %d)", f->d.model_id, name, st);
    return value;
}

static void fmu_initialize(Fmu *f, double stop) {
    int st;
    if (f->d.fmi3) {
        st = f->enter3(f->inst, fmi3False, 0.0, 0.0, fmi3True, stop);
        if (st == 0) st = f->exit3(f->inst);
    } else {
        st = f->setup2(f->inst, fmi2False, 0.0, 0.0, fmi2True, stop);
        if (st == 0) st = f->enter2(f->inst);
        if (st == 0) st = f->exit2(f->inst);
    }
    if (st != 0) die("%s: initialisation failed (status %d)", f->d.model_id, st);
}

static void fmu_step(Fmu *f, double t, double h) {
    int st;
    if (f->d.fmi3) {
        fmi3Boolean event, terminate, early;
        fmi3Float64 last;
        st = f->step3(f->inst, t, h, fmi3True, &event, &terminate, &early, &last);
        if (st == 0 && (event || terminate || early)) die("%s: fmi3DoStep asks for an event or to stop", f->d.model_id);
    } else {
        st = f->step2(f->inst, t, h, fmi2True);
    }
    if (st != 0) die("%s: step at t = %.17g failed (status %d)", f->d.model_id, t, st);
}

static void fmu_free(Fmu *f) {
    int st = f->d.fmi3 ? (int)f->terminate3(f->inst) : (int)f->terminate2(f->inst);
    if (st != 0) die("%s: terminate failed (status %d)", f->d.model_id, st);
    if (f->d.fmi3) f->free3(f->inst);
    else f->free2(f->inst);
    lib_close(f->lib);
}

/* ---- the closed loop ---- */

static const char *const PID_SETTINGS[] = {"ts", "kp", "ki", "kd", "tf", "u_min", "u_max", "anti_windup",
                                           "i_lo", "i_hi", "backoff", "u_hold", "w0", "w1", "t_step"};
#define NPID (sizeof PID_SETTINGS / sizeof PID_SETTINGS[0])

static double number(const char *s) {
    char *end;
    double v = strtod(s, &end);
    if (end == s || *end) die("not a number: %s", s);
    return v;
}

int main(int argc, char **argv) {
    if (argc < 3) die("usage: fmi_importer FMU_DIR STOP [--pid-fmu PID_FMU_DIR] [name=value ...]");
    const char *pid_dir = NULL;
    double stop = number(argv[2]);
    /* the paper's PID (Eq. 22) at 1 kHz, output 0..1 MU; no filter, no anti-windup */
    double pid_v[NPID] = {1e-3, 2.0, 2.97, 0.01, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0};
    Fmu plant, pidf;
    fmu_load(&plant, argv[1], "plant");
    for (int a = 3; a < argc; a++) {
        if (strcmp(argv[a], "--pid-fmu") == 0 && a + 1 < argc) {
            pid_dir = argv[++a];
            continue;
        }
        char name[MAX_NAME];
        const char *eq = strchr(argv[a], '=');
        if (!eq || (size_t)(eq - argv[a]) >= sizeof name) die("expected name=value: %s", argv[a]);
        memcpy(name, argv[a], (size_t)(eq - argv[a]));
        name[eq - argv[a]] = 0;
        size_t k = 0;
        while (k < NPID && strcmp(PID_SETTINGS[k], name) != 0) k++;
        if (k < NPID) pid_v[k] = number(eq + 1);
        else fmu_set(&plant, name, number(eq + 1));
    }
    MaglevPid pid = {pid_v[0], pid_v[1], pid_v[2], pid_v[3], pid_v[5], pid_v[6], pid_v[4], (int)pid_v[7],
                     pid_v[8], pid_v[9], pid_v[10], 0};
    char msg[256];
    if (maglev_pid_check(&pid, msg, sizeof msg)) die("PID: %s", msg);
    double ts = pid.ts, u_hold = pid_v[11], w0 = pid_v[12], w1 = pid_v[13], t_step = pid_v[14];
    MaglevPidState s = {u_hold, 0.0, 0.0}; /* settled start */
    if (pid_dir) {
        fmu_load(&pidf, pid_dir, "pid");
        for (size_t k = 0; k < NPID; k++) fmu_set(&pidf, PID_SETTINGS[k], pid_v[k]);
        fmu_initialize(&pidf, stop);
    }
    fmu_initialize(&plant, stop);
    long n = lround(stop / ts);
    printf("t w y u x v i\n");
    for (long k = 0; k < n; k++) {
        double t = (double)k * ts;
        double y = fmu_get(&plant, "y"), x = fmu_get(&plant, "x"), v = fmu_get(&plant, "v"), i = fmu_get(&plant, "i");
        double w = t >= t_step - 1e-12 ? w1 : w0, u; /* the step reference, as loop.reference_signal has it */
        if (pid_dir) { /* Gauss-Seidel: the controller first */
            fmu_set(&pidf, "y", y);
            fmu_step(&pidf, t, ts);
            u = fmu_get(&pidf, "u");
            w = fmu_get(&pidf, "w");
        } else {
            u = maglev_pid_step(&pid, &s, w, y);
        }
        fmu_set(&plant, "u", u);
        printf("%.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", t, w, y, u, x, v, i);
        fmu_step(&plant, t, ts);
    }
    if (pid_dir) fmu_free(&pidf);
    fmu_free(&plant);
    return 0;
}
