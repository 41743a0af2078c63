/* The one FMI glue of every model: what the FMI 2.0 entry points (maglev_fmu.c) and the FMI 3.0 entry
 * points (maglev_fmi3.c) share: the instance, its state machine, logging, argument and value checks, FMU
 * states and their serialisation with the experiment, the step. It runs a model through MfModel, a
 * table of functions each model file fills in (the plant: maglev_plant_fmu.c; the PID controller:
 * maglev_pid_fmu.c), so the FMI rules are written once whatever the FMU computes (in the manner of the
 * Modelica Association's Reference-FMUs). An FMU binary links one entry-point file, this glue and one
 * model file, which defines maglev_fmu_model. No FMI types here: statuses are the numbers both standards
 * give them (OK 0, Warning 1, Error 3), and every function takes the calling entry point's name for its
 * messages. */
#ifndef MAGLEV_FMI_COMMON_H
#define MAGLEV_FMI_COMMON_H

#include <stddef.h>

#include "maglev_plant.h" /* MaglevVariable, MaglevAllocator, MaglevTag, MAGLEV_MSG_LEN, MAGLEV_TIME_MAX */

/* A model behind the glue. Its state is a plain struct of `size` bytes that the glue allocates and
 * passes as void *; it must move by memcpy (nothing in it points into itself), because the glue builds
 * a state in scratch space and then moves it in place, so that a refused call changes nothing. What it
 * owns beyond the struct (the plant's input history) it allocates through the allocator it is given
 * and frees in release. Messages go into msg, naming the variable; the glue adds the function's name. */
typedef struct {
    const char *guid;                 /* FMI 2.0 guid and FMI 3.0 instantiationToken of its descriptions */
    const MaglevVariable *variables;  /* indexed by value reference 0..nvars-1; FMI 3.0 time is nvars */
    unsigned int nvars;
    size_t size;                      /* sizeof the model's state struct */
    /* The start values of the table, no state. */
    void (*defaults)(void *m);
    /* One value of an input or parameter on its own (finite, in its range): 0, or -1 with msg. */
    int (*check_value)(unsigned int vr, double value, char *msg, size_t len);
    /* Sets an input or parameter that check_value has accepted. Parameters are set only before the model
     * is initialised; an input after it may need memory (the plant's delay history): 0, or -1 with msg. */
    int (*set)(void *m, unsigned int vr, double value, const MaglevAllocator *a, char *msg, size_t len);
    double (*get)(const void *m, unsigned int vr);
    /* The model's time; before initialisation the glue keeps it at the experiment's start. */
    double (*time)(const void *m);
    void (*set_time)(void *m, double t);
    /* The model as initialize would make it at t0, into view (a scratch state of `size` bytes that is
     * never released), without changing m or allocating: its outputs in initialization mode. */
    int (*preview)(const void *m, double t0, void *view, char *msg, size_t len);
    /* The end of initialization mode: the relations between the parameters, then the state at t0. */
    int (*initialize)(void *m, double t0, const MaglevAllocator *a, char *msg, size_t len);
    int (*initialized)(const void *m);
    /* From time() by h > 0: 0; MAGLEV_REFUSED with the model as it was (too much work, out of the time
     * range: shorter steps will do); -1 with the model as it was, for a state that broke down. */
    int (*step)(void *m, double h, const MaglevAllocator *a, char *msg, size_t len);
    /* Deep copy into a zeroed dst: 0, or -1 (out of memory) with dst holding nothing. */
    int (*copy)(void *dst, const void *src, const MaglevAllocator *a);
    void (*release)(void *m, const MaglevAllocator *a);
    /* The model's byte image with the glue's tag (its FMU state code and experiment) under the image's
     * version and checksum; deserialize checks every value as set and initialize would (a checksum only
     * catches accidents) and, into a zeroed m, leaves m zeroed when it refuses. */
    size_t (*serialized_size)(const void *m);
    void (*serialize)(const void *m, const MaglevTag *tag, unsigned char *buf);
    int (*deserialize)(void *m, MaglevTag *tag, const unsigned char *buf, size_t size, const MaglevAllocator *a,
                       char *msg, size_t len);
} MfModel;

/* The model of this FMU binary: defined by the one model file linked in. */
extern const MfModel maglev_fmu_model;

enum { MF_OK = 0, MF_WARNING = 1, MF_ERROR = 3 };

/* The states both standards share (FMI 3.0 calls StepComplete "Step Mode"; StepFailed is FMI 2.0's). */
typedef enum {
    MF_START_AND_END = 1 << 0,
    MF_INSTANTIATED = 1 << 1,
    MF_INITIALIZATION_MODE = 1 << 2,
    MF_STEP_COMPLETE = 1 << 3,
    MF_STEP_FAILED = 1 << 4,
    MF_TERMINATED = 1 << 5,
    MF_ERROR_STATE = 1 << 6,
} MfState;

#define MF_ANY_LIVE (MF_INSTANTIATED | MF_INITIALIZATION_MODE | MF_STEP_COMPLETE | MF_STEP_FAILED | MF_TERMINATED \
                     | MF_ERROR_STATE)
#define MF_MASK_GET (MF_INITIALIZATION_MODE | MF_STEP_COMPLETE | MF_STEP_FAILED | MF_TERMINATED | MF_ERROR_STATE)
#define MF_MASK_SET (MF_INSTANTIATED | MF_INITIALIZATION_MODE | MF_STEP_COMPLETE)
#define MF_MASK_FMUSTATE MF_ANY_LIVE

struct MfInstance;
/* Hands one finished message to the importer's logger. */
typedef void (*MfLogFn)(const struct MfInstance *f, int status, const char *category, const char *message);

typedef struct MfSnapshot MfSnapshot;

/* The experiment fmi2SetupExperiment (FMI 2.0) or fmi3EnterInitializationMode (FMI 3.0) gave. It is part of
 * an FMU state, so that a state restored after a reset, or in another instance, starts and stops where it
 * did. What is not defined is 0, so that the same experiment always serializes to the same bytes. */
typedef struct {
    double start_time, stop_time, tolerance;
    int stop_defined, tol_defined;
} MfExperiment;

typedef struct MfInstance {
    char name[128];
    MfLogFn log;
    int logging;
    MfState state;
    MfExperiment exp;
    unsigned int time_vr;        /* value reference of the independent variable time (FMI 3.0), or MF_NO_TIME_VR */
    MaglevAllocator alloc;
    const MfModel *model;
    void *data;                  /* the model's state */
    void *scratch;               /* a second state's room: previews, and copies built before they replace one */
    /* The parameters right after instantiation (the table's start values, then resources/start_values.txt),
     * by value reference: a reset goes back to them without reading the file again, which the importer may
     * have removed since. */
    double *start;
    int n_start_values;          /* how many of them came from start_values.txt */
    MfSnapshot *snapshots;
} MfInstance;

#define MF_NO_TIME_VR 0xffffffffu

/* Sets up an instance of model the glue has allocated (alloc's env reaches the importer's allocator):
 * the model's start values, then the rig's from resources_dir/start_values.txt when that file exists
 * (resources_dir NULL: none). Returns 0, or -1 with a message in msg and nothing left allocated. */
int mf_init(MfInstance *f, const MfModel *model, const char *name, int logging, MfLogFn log,
            const MaglevAllocator *alloc, unsigned int time_vr, const char *resources_dir, char *msg, size_t msglen);
/* Frees what the instance owns (not the instance itself). */
void mf_release(MfInstance *f);

/* The directory a file: URI names (FMI 2.0's fmuResourceLocation); 0, or -1 if it is not one. */
int mf_uri_to_path(const char *uri, char *out, size_t len);

/* The GUID an instance of model accepts. A calibrated or rig FMU is a model of its own with a GUID of its
 * own, issued by the packager (maglev_cosim.plant.calibrated_fmu) and stated in resources_dir/guid.txt:
 * with that file exactly that GUID, without it exactly model->guid, so a description and a binary or
 * resources that do not belong together are still refused. Returns 0 with guid set, or -1 with msg when
 * guid.txt is there but holds no GUID. */
int mf_accepted_guid(const MfModel *model, const char *resources_dir, char *guid, size_t glen, char *msg,
                     size_t len);

const char *mf_state_name(MfState s);
void mf_log(const MfInstance *f, int status, const char *category, const char *fmt, ...);
int mf_error(MfInstance *f, const char *fmt, ...);
/* Instance present and call allowed in its state; 0 (with a message) when not. */
int mf_guard(MfInstance *f, const char *fn, int mask);
/* The model's time: what FMI 2.0's LastSuccessfulTime, FMI 3.0's time variable and lastSuccessfulTime say. */
double mf_time(const MfInstance *f);

int mf_set_debug_logging(MfInstance *f, const char *fn, int on, size_t n, const char *const categories[]);
int mf_setup_experiment(MfInstance *f, const char *fn, int tol_defined, double tol, double start, int stop_defined,
                        double stop);
int mf_enter_initialization(MfInstance *f);
int mf_exit_initialization(MfInstance *f, const char *fn);
int mf_terminate(MfInstance *f);
/* Back to the state right after instantiation (FMI 2.0 fmi2Reset, FMI 3.0 fmi3Reset): the start values
 * the instance was made with, no experiment, the state machine in instantiated. */
int mf_reset(MfInstance *f, const char *fn);

int mf_get_real(MfInstance *f, const char *fn, const unsigned int vr[], size_t nvr, double value[]);
int mf_set_real(MfInstance *f, const char *fn, const unsigned int vr[], size_t nvr, const double value[]);
/* For the types the FMU has no variable of: nothing to get or set, so any reference is an error. */
int mf_no_such_type(MfInstance *f, const char *fn, int mask, size_t nvr, const unsigned int vr[]);

/* The step from the importer's currentCommunicationPoint t by h. */
int mf_do_step(MfInstance *f, const char *fn, double t, double h);

/* FMU states (opaque pointers the importer holds). */
int mf_get_state(MfInstance *f, const char *fn, void **state);
int mf_set_state(MfInstance *f, const char *fn, void *state);
int mf_free_state(MfInstance *f, const char *fn, void **state);
int mf_serialized_size(MfInstance *f, const char *fn, void *state, size_t *size);
int mf_serialize(MfInstance *f, const char *fn, void *state, unsigned char *buf, size_t size);
int mf_deserialize(MfInstance *f, const char *fn, const unsigned char *buf, size_t size, void **state);

#endif
