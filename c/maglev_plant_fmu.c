/* The CE152 plant (maglev_plant.c) as a model of the FMI glue (maglev_fmi_common.h): build/maglev.fmu
 * and build/maglev3.fmu link this file. Each function adapts one of the plant's own; what is the FMI's
 * (the state machine, the checks every call needs, FMU states) is the glue's. */
#include "maglev_fmi_common.h"

/* Must equal the guid (2.0) / instantiationToken (3.0) of modelDescription.xml and modelDescription3.xml
 * (tests/test_model_description.py). */
#define MAGLEV_GUID "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"

static void defaults(void *m) { maglev_defaults(m); }

static int check_value(unsigned int vr, double value, char *msg, size_t len) {
    return maglev_check_value((MaglevVR)vr, value, msg, len);
}

/* The input u is held from now on; once the plant runs, that is a breakpoint of the delay's history. */
static int set(void *m, unsigned int vr, double value, const MaglevAllocator *a, char *msg, size_t len) {
    MaglevPlant *p = m;
    if (vr != VR_u) {
        maglev_set_param(p, (MaglevVR)vr, value);
        return 0;
    }
    if (p->initialized) return maglev_set_input(p, value, a, msg, len);
    p->u = value;
    return 0;
}

static double get(const void *m, unsigned int vr) { return maglev_get(m, (MaglevVR)vr); }
static double time_of(const void *m) { return ((const MaglevPlant *)m)->time; }
static void set_time(void *m, double t) { ((MaglevPlant *)m)->time = t; }

static int preview(const void *m, double t0, void *view, char *msg, size_t len) {
    return maglev_preview(m, t0, view, msg, len);
}

/* from the input set before initialisation: the settled current of T_a = 0, the delay's history */
static int initialize(void *m, double t0, const MaglevAllocator *a, char *msg, size_t len) {
    return maglev_initialize(m, t0, ((MaglevPlant *)m)->u, a, msg, len);
}

static int initialized(const void *m) { return ((const MaglevPlant *)m)->initialized; }

static int step(void *m, double h, const MaglevAllocator *a, char *msg, size_t len) {
    return maglev_step(m, h, a, msg, len);
}

static int copy(void *dst, const void *src, const MaglevAllocator *a) { return maglev_copy(dst, src, a); }
static void release(void *m, const MaglevAllocator *a) { maglev_release(m, a); }
static size_t serialized_size(const void *m) { return maglev_serialized_size(m); }

static void serialize(const void *m, const MaglevTag *tag, unsigned char *buf) { maglev_serialize(m, tag, buf); }

static int deserialize(void *m, MaglevTag *tag, const unsigned char *buf, size_t size, const MaglevAllocator *a,
                       char *msg, size_t len) {
    return maglev_deserialize(m, tag, buf, size, a, msg, len);
}

const MfModel maglev_fmu_model = {
    .guid = MAGLEV_GUID, .variables = maglev_variables, .nvars = MAGLEV_NVARS, .size = sizeof(MaglevPlant),
    .defaults = defaults, .check_value = check_value, .set = set, .get = get, .time = time_of,
    .set_time = set_time, .preview = preview, .initialize = initialize, .initialized = initialized, .step = step,
    .copy = copy, .release = release, .serialized_size = serialized_size, .serialize = serialize,
    .deserialize = deserialize,
};
