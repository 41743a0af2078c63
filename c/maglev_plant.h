/* The CE152 plant (docs/model.md). No FMI types here: the FMU glue
 * (maglev_fmu.c) and the cffi fast path (maglev_replay.c) both build on this. */
#ifndef MAGLEV_PLANT_H
#define MAGLEV_PLANT_H

#include <stddef.h>

/* Value references: VR_<name> for each row of the variable list MAGLEV_VARIABLES at the top of
 * maglev_plant.c, in its order (the FMU's interface: modelDescription.xml lists the same names with the same
 * numbers, tests/test_model_description.py). The list is read from there, alone, so that a variable is
 * declared in one place. */
#ifndef MAGLEV_VARIABLES
#define MAGLEV_VARIABLES_ONLY
#include "maglev_plant.c"
#undef MAGLEV_VARIABLES_ONLY
#endif
#define MAGLEV_VR_NAME(name, ...) VR_##name,
typedef enum { MAGLEV_VARIABLES(MAGLEV_VR_NAME) MAGLEV_NVARS } MaglevVR;
#undef MAGLEV_VR_NAME

#define MAGLEV_FIRST_PARAM VR_k_DA
#define MAGLEV_NPARAMS (VR_solver_step - VR_k_DA + 1)

typedef enum { MAGLEV_INPUT, MAGLEV_OUTPUT, MAGLEV_PARAMETER } MaglevCausality;

/* min/max: the inclusive range maglev_check_value enforces (-inf/inf where the value is
 * only required to be finite, and for outputs the range the plant keeps them in).
 * effect: the effect of the diagnosis's catalogue a parameter belongs to ("delay", "force_lag", ...;
 * "" for the baseline plant, its inputs and outputs). It is the one place that says which parameters
 * make which effect: PlantParams, the catalogue, synth, the emulators' effect lists and the model
 * descriptions read it (docs/adding-an-effect.md). */
typedef struct {
    const char *name;
    MaglevCausality causality;
    double start;
    double min, max;
    const char *unit;
    const char *description;
    const char *effect;
} MaglevVariable;

/* The FMU libraries hide every symbol but the FMI functions (an importer that loads two FMUs with
 * global symbols must not bind one's calls to the other's plant) and their own variable table: the
 * build reads the table from the library to write modelDescription.xml (plant/model_description.py),
 * and the tests check a shipped binary against its own table. The plant's table is exported by the
 * plant FMU only (CMake defines MAGLEV_EXPORT_PLANT_TABLE there), not by the controller FMU, which
 * links the plant for the replay. Elsewhere (the cffi library) every symbol is visible anyway. */
#if defined(__GNUC__) && !defined(_WIN32)
#define MAGLEV_VISIBLE __attribute__((visibility("default")))
#else
#define MAGLEV_VISIBLE
#endif
#ifdef MAGLEV_EXPORT_PLANT_TABLE
#define MAGLEV_PLANT_TABLE_EXPORT MAGLEV_VISIBLE
#else
#define MAGLEV_PLANT_TABLE_EXPORT
#endif

/* One row per value reference, indexed by MaglevVR. */
extern MAGLEV_PLANT_TABLE_EXPORT const MaglevVariable maglev_variables[MAGLEV_NVARS];

typedef enum { CONTACT_NONE = 0, CONTACT_LOWER = -1, CONTACT_UPPER = 1 } MaglevContact;

/* Input history for the transport delay: (time, value) breakpoints, oldest first. */
typedef struct {
    double *t;
    double *u;
    size_t len;
    size_t cap;
} MaglevHistory;

/* |time| never exceeds this: the clock then still resolves the smallest solver step to
 * about a tenth, and every phase 2*pi*f_d*t stays finite. */
#define MAGLEV_TIME_MAX 1e9

/* Most RK4 substeps one maglev_step may take. It counts them before integrating, from the substep
 * length the parameters set (solver_step, or shorter: the force lag T_F, the friction F_c, a voltage
 * drive's electrical time constant, an amplifier transient under a force lag), and refuses a step that
 * needs more at once, with the plant unchanged, naming what sets the length. A ball at rest on a stop
 * needs none, so any step passes there; a ball that would only come to rest during the step is counted
 * in full (that cannot be known before integrating). 500000 substeps cost 0.03 s of CPU at -O2 with the
 * paper's equations, 0.07-0.12 s with friction, a voltage drive or every effect on, 0.16 s in the
 * costliest case the fuzz met (a voltage drive at R_c = 1e4 Ohm decaying through denormal currents, with
 * the exponential law, sensor deviation and pickup, a delay); measured 2026-11-25 on the x86-64 build
 * machine, about 3x that under ASan. */
#define MAGLEV_STEP_BUDGET 500000L
/* Most RK4 evaluations a step may spend in all: its substeps and the root finding at impacts on the
 * stops, which cannot be counted beforehand. A step that reaches it (a ball chattering on a stop) is
 * refused after the work, with the plant unchanged, so that no call can hang its caller. */
#define MAGLEV_WORK_MAX (2 * MAGLEV_STEP_BUDGET)

/* The force lag's ETDRK4 weights for one substep h at one T_F (maglev_plant.c): derived data,
 * cached for the two substep lengths used last (a delay splits each step into two pieces). */
typedef struct { double h, T, e, e2, a2, f1, f2, f3; } MaglevEtd;

/* The weights that integrate a current transient exactly over one substep h at one T_a
 * (maglev_plant.c, transient_squares): q = e^-r, phi_1 and phi_2 at -r and -2r, r = h/T_a. */
typedef struct { double h, T, q, a1, b1, a2, b2; } MaglevTransient;

typedef struct {
    double p[MAGLEV_NPARAMS];   /* indexed by VR - MAGLEV_FIRST_PARAM */
    int initialized;            /* set by maglev_initialize; parameters are fixed from then on */
    double time;                /* [s] */
    double u;                   /* [MU] input held since the last communication point */
    double x, v, i, F;          /* [m] [m/s] [A] [N] */
    double F2;                  /* [N] the slow part of the force (eddy_lag: beta_F > 0), else 0 */
    double xs;                  /* [m] the position the sensor sees (x itself unless T_y > 0) */
    int contact;                /* MaglevContact */
    MaglevHistory hist;
    MaglevEtd etd[2];           /* a cache, not state: rebuilt from h and T_F when they differ */
    int etd_next;               /* the slot the next new weights replace */
    MaglevTransient tr[2];      /* a cache like etd, for the current's transient */
    int tr_next;
    double atan_b_key, atan_b;  /* a cache like etd: atan(-b_i) for b_i = atan_b_key (zeroed: b_i = 0, atan 0) */
    long work;                  /* RK4 evaluations the last maglev_step spent: a statistic, not state (0 for a
                                   step refused before integrating; not serialized) */
} MaglevPlant;

/* Allocation hooks, so the FMU can use the importer's allocator. */
typedef struct {
    void *(*alloc)(size_t n, size_t size, void *env);
    void (*release)(void *ptr, void *env);
    void *env;
} MaglevAllocator;

#define MAGLEV_MSG_LEN 256

/* Parameter access; p is the parameter's value reference. */
double maglev_param(const MaglevPlant *m, MaglevVR vr);
void maglev_set_param(MaglevPlant *m, MaglevVR vr, double value);

/* All parameters to their defaults, state cleared, no history. */
void maglev_defaults(MaglevPlant *m);

/* Checks one value for a variable on its own (finite, sign); 0 if fine,
 * otherwise writes a message naming the variable into msg. */
int maglev_check_value(MaglevVR vr, double value, char *msg, size_t msglen);

/* Checks the whole parameter set (the relations between parameters). */
int maglev_check_params(const MaglevPlant *m, char *msg, size_t msglen);

/* Checks a whole plant as a restore would meet it: every parameter on its own, and once
 * initialised the relations and a state the plant can have reached (ball between the stops,
 * current within [0, i_max], a sorted delay history...). */
int maglev_check_plant(const MaglevPlant *m, char *msg, size_t msglen);

/* Sets the state from x_start, v_start, i_start at time t0 with input u0.
 * Returns 0 or -1 with a message. */
int maglev_initialize(MaglevPlant *m, double t0, double u0, const MaglevAllocator *a,
                      char *msg, size_t msglen);

/* The plant as maglev_initialize would set it up at t0, written into view without touching m or
 * allocating (the delay history is left empty): what the outputs are in initialisation mode. */
int maglev_preview(const MaglevPlant *m, double t0, MaglevPlant *view, char *msg, size_t msglen);

/* Sets the input held from now on (records it in the delay history). */
int maglev_set_input(MaglevPlant *m, double u, const MaglevAllocator *a, char *msg, size_t msglen);

/* Advances by h > 0 seconds. Returns 0; or, with a message and the plant as it was,
 * MAGLEV_REFUSED for a step too long for the work budget (decided before integrating,
 * MAGLEV_STEP_BUDGET) or the time range (shorter steps will do), -1 for a state that became
 * non-finite. */
#define MAGLEV_REFUSED (-2)
int maglev_step(MaglevPlant *m, double h, const MaglevAllocator *a, char *msg, size_t msglen);

/* The value of any variable now (outputs are computed from the state). */
double maglev_get(const MaglevPlant *m, MaglevVR vr);

/* The formulas the toolkit needs besides the simulation, so that they live once.
 * Static force (Eq. 8) and, when the pointers are given, its partials (Eq. 16, 17). */
double maglev_force(const MaglevPlant *m, double i, double x, double *dF_dx, double *dF_di);
/* Sensor voltage (Eq. 12, with the k_x2 deviation, no pickup) and its slope dV/dx. */
double maglev_sensor_volts(const MaglevPlant *m, double x, double *dV_dx);
/* Noise-free A/D reading [MU] (Eq. 12, 13, pickup at time t), before the converter's limits. */
double maglev_reading(const MaglevPlant *m, double x, double t);
/* The position between the stops whose reading at time t is y (the nearest stop when none is). */
double maglev_position_for_reading(const MaglevPlant *m, double y, double t);
/* The current holding the ball at rest at x (Eq. 8 with x'' = x' = 0), and the D/A input giving a
 * steady current (Eq. 1, 5; with a voltage drive, R_c*i), neither limited. */
double maglev_equilibrium_current(const MaglevPlant *m, double x);
double maglev_input_for_current(const MaglevPlant *m, double i);

/* Deep copy (history included); dst must be released or zeroed beforehand. */
int maglev_copy(MaglevPlant *dst, const MaglevPlant *src, const MaglevAllocator *a);
/* maglev_copy into dst, a plant whose history buffers (none: zeroed) it keeps and grows only when too
 * small; on failure (-1, out of memory) dst is left as it was. */
int maglev_copy_into(MaglevPlant *dst, const MaglevPlant *src, const MaglevAllocator *a);
void maglev_release(MaglevPlant *m, const MaglevAllocator *a);

/* What a caller keeps in a plant's byte image, under the image's version and checksum, uninterpreted by
 * the plant: the FMU stores its state machine's state in code and its experiment in flags and value
 * (maglev_fmi_common.c). Its checks are the caller's. */
#define MAGLEV_TAG_NVALUES 3
typedef struct {
    unsigned int code;
    unsigned int flags;
    double value[MAGLEV_TAG_NVALUES];
} MaglevTag;

/* Serialisation: a versioned, checksummed byte image of the whole plant, with a caller's tag
 * under the same checksum. Deserialisation checks the values with maglev_check_plant: a checksum
 * only catches accidents. */
size_t maglev_serialized_size(const MaglevPlant *m);
void maglev_serialize(const MaglevPlant *m, const MaglevTag *tag, unsigned char *buf);
int maglev_deserialize(MaglevPlant *m, MaglevTag *tag, const unsigned char *buf, size_t size,
                       const MaglevAllocator *a, char *msg, size_t msglen);

/* The 64-bit FNV-1a checksum that ends a serialized image (the plant's, and the PID controller FMU's in
 * maglev_pid_fmu.c): it catches accidents, not edits. */
unsigned long long maglev_checksum(const unsigned char *buf, size_t n);

/* malloc/free allocator for users outside an FMU (tests, the fast path). */
extern const MaglevAllocator maglev_std_allocator;

#endif
