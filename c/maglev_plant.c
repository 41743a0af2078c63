/* The CE152 plant equations (paper Eq. 1, 2/5, 8, 12, 13; docs/model.md). */

/* The variables, declared here once (docs/adding-an-effect.md): one row per FMU variable, in value-reference
 * order, X(name, causality, start, min, max, unit, description, effect). min, max: the inclusive range
 * maglev_check_value enforces (ANY, POS_M: the ranges defined below); effect: the diagnosis catalogue's
 * effect a parameter belongs to ("" for the baseline plant). maglev_plant.h includes this list alone
 * (MAGLEV_VARIABLES_ONLY) and makes the MaglevVR enum from its names (VR_<name>); the table
 * maglev_variables below is made from its rows. Parameters are the span from k_DA to solver_step: a new
 * effect's parameters go just before solver_step, which moves solver_step and F up one value reference
 * (every effect so far has; all other value references stay). */
#ifndef MAGLEV_VARIABLES
#define MAGLEV_VARIABLES(X) \
    X(u, MAGLEV_INPUT, 0.0, ANY, "MU", "D/A converter input (controller output), limited to +-1 MU by the converter", "") \
    X(y, MAGLEV_OUTPUT, 0.0, -MU_LIMIT, MU_LIMIT, "MU", "A/D converter output (position measurement), Eq. 13, limited to +-1 MU", "") \
    X(x, MAGLEV_OUTPUT, 0.0, ANY, "m", "Ball position, growing towards the coil", "") \
    X(v, MAGLEV_OUTPUT, 0.0, ANY, "m/s", "Ball velocity", "") \
    X(i, MAGLEV_OUTPUT, 0.0, ANY, "A", "Coil current, Eq. 2 (Eq. 5 when T_a = 0)", "") \
    X(k_DA, MAGLEV_PARAMETER, 5.0, 1e-3, 1e3, "V/MU", "D/A converter gain, Eq. 1 (Sec. 3.1)", "") \
    X(u_0, MAGLEV_PARAMETER, 0.0, -100.0, 100.0, "V", "D/A converter offset, Eq. 1 (Sec. 3.1)", "") \
    X(k_i, MAGLEV_PARAMETER, 0.3, 1e-6, 1e3, "A/V", "Power amplifier gain, Eq. 2 (Sec. 3.2)", "") \
    X(T_a, MAGLEV_PARAMETER, 0.3e-3, 0.0, 1.0, "s", "Power amplifier time constant, Eq. 2 (Sec. 3.2); 0 means i = k_i*u, Eq. 5", "amplifier_lag") \
    X(m_k, MAGLEV_PARAMETER, 8.4e-3, 1e-6, 100.0, "kg", "Ball mass, Eq. 8 (Sec. 3.4.1)", "") \
    X(g, MAGLEV_PARAMETER, 9.81, 1e-3, 100.0, "m/s2", "Gravitational acceleration, Eq. 8", "") \
    X(k_c, MAGLEV_PARAMETER, 6.9e-6, 0.0, 1.0, "N.m2/A2", "Coil constant, Eq. 8 (Sec. 3.4.2, LQ fit)", "") \
    X(x_0, MAGLEV_PARAMETER, 8.3e-3, POS_M, "m", "Coil offset, Eq. 8 (Sec. 3.4.2, LQ fit)", "") \
    X(k_FV, MAGLEV_PARAMETER, 0.03, 0.0, 1e3, "N.s/m", "Viscous damping constant, Eq. 8 (Sec. 3.4.3)", "") \
    X(k_x, MAGLEV_PARAMETER, 612.3, 1e-3, 1e6, "V/m", "Position sensor gain, Eq. 12 (Sec. 3.3)", "") \
    X(y_0, MAGLEV_PARAMETER, 0.0125, -100.0, 100.0, "V", "Position sensor offset, Eq. 12 (Table 3)", "") \
    X(k_AD, MAGLEV_PARAMETER, 0.2, 1e-3, 1e3, "MU/V", "A/D converter gain, Eq. 13 (Sec. 3.1)", "") \
    X(y_MU0, MAGLEV_PARAMETER, 0.0, -10.0, 10.0, "MU", "A/D converter offset, Eq. 13 (Sec. 3.1)", "") \
    X(x_min, MAGLEV_PARAMETER, 0.0, POS_M, "m", "Lower mechanical stop", "") \
    X(x_max, MAGLEV_PARAMETER, 6.3e-3, POS_M, "m", "Upper mechanical stop, below x_0", "") \
    X(i_max, MAGLEV_PARAMETER, 1.5, 1e-6, 1e3, "A", "Largest current the amplifier delivers (lowered: a current limit)", "current_saturation") \
    X(x_start, MAGLEV_PARAMETER, 0.0, POS_M, "m", "Initial ball position, between the stops", "") \
    X(v_start, MAGLEV_PARAMETER, 0.0, -100.0, 100.0, "m/s", "Initial ball velocity", "") \
    X(i_start, MAGLEV_PARAMETER, 0.0, 0.0, 1e3, "A", "Initial coil current (used when T_a > 0), at most i_max", "") \
    X(T_F, MAGLEV_PARAMETER, 0.0, 0.0, 1.0, "s", "Time constant of the force lag behind the static force law (0 = off, else >= 1e-6 s)", "force_lag") \
    X(T_d, MAGLEV_PARAMETER, 0.0, 0.0, T_D_MAX, "s", "Transport delay of the D/A signal (0 = off)", "delay") \
    X(k_x2, MAGLEV_PARAMETER, 0.0, -1e8, 1e8, "V/m2", "Sensor deviation k_x2*x*(x - x_cal) from the two-point fit of Eq. 12 (0 = off)", "sensor_nonlinearity") \
    X(x_cal, MAGLEV_PARAMETER, 6.3e-3, 1e-6, 1.0, "m", "Second calibration point of the sensor (Table 3); the first is x = 0", "") \
    X(A_d, MAGLEV_PARAMETER, 0.0, -100.0, 100.0, "V", "Amplitude of sinusoidal pickup on the sensor voltage (0 = off)", "periodic_disturbance") \
    X(f_d, MAGLEV_PARAMETER, 50.0, 0.0, 1e5, "Hz", "Frequency of the sensor pickup", "periodic_disturbance") \
    X(phi_d, MAGLEV_PARAMETER, 0.0, -1e3, 1e3, "rad", "Phase of the sensor pickup at t = 0", "periodic_disturbance") \
    X(F_c, MAGLEV_PARAMETER, 0.0, 0.0, 100.0, "N", "Coulomb friction force on the moving ball, smoothed as F_c*tanh(v/v_c) (0 = off)", "coulomb_friction") \
    X(v_c, MAGLEV_PARAMETER, 1e-4, 1e-6, 1.0, "m/s", "Speed over which the Coulomb friction is smoothed: F_c*tanh(v/v_c) (a guide's or cable's stick-slip blurred by the ball's wobble)", "coulomb_friction") \
    X(n_F, MAGLEV_PARAMETER, 2.0, 1.0, 4.0, "1", "Force-law exponent: F = k_c*i^2/(x_0 - x)^2 * ((x_0 - x_n)/(x_0 - x))^(n_F - 2) (2 = Eq. 8)", "force_exponent") \
    X(x_n, MAGLEV_PARAMETER, 3.2e-3, POS_M, "m", "Position where a force-law exponent other than 2 leaves the force unchanged (the paper's operating point), below x_0", "force_exponent") \
    X(u_dz, MAGLEV_PARAMETER, 0.0, 0.0, 100.0, "V", "Half-width of the amplifier's dead zone around 0 V input (0 = off)", "amplifier_dead_zone") \
    X(k_e, MAGLEV_PARAMETER, 0.0, 0.0, 1e3, "N/A2", "Gain of an exponential force law k_e*exp(-(x_0 - x)/z_e)*i^2 added to Eq. 8 (the form Inteco publishes; a rig with it sets k_c = 0; 0 = off)", "") \
    X(z_e, MAGLEV_PARAMETER, 5e-3, 1e-6, 1.0, "m", "Decay length of the exponential force law", "") \
    X(R_c, MAGLEV_PARAMETER, 0.0, 0.0, 1e4, "Ohm", "Coil resistance; > 0 selects a voltage drive: L(x, i)*di/dt = V - R_c*i - i*dL/dx*v with V the D/A voltage (Eq. 1, at least V_min), k_i and T_a unused; 0 = the current amplifier of Eq. 2", "") \
    X(L_0, MAGLEV_PARAMETER, 0.1, 1e-6, 100.0, "H", "Coil inductance of a voltage drive far from the ball: L = L_0 + L_x*exp(-(x_0 - x)/z_L) + L_g/(x_0 - x) + L_i*atan(a_i*i - b_i)", "") \
    X(L_x, MAGLEV_PARAMETER, 0.0, 0.0, 100.0, "H", "Inductance the ball adds at the coil (x = x_0)", "") \
    X(z_L, MAGLEV_PARAMETER, 5e-3, 1e-6, 1.0, "m", "Decay length of the ball's inductance", "") \
    X(L_g, MAGLEV_PARAMETER, 0.0, 0.0, 10.0, "H.m", "Inductance of the inverse-gap form L_g/(x_0 - x) (a rig whose force follows Eq. 8 from L(x): L_g = 2*k_c)", "") \
    X(L_i, MAGLEV_PARAMETER, 0.0, 0.0, 100.0, "H", "Current dependence (saturation) of the inductance, below L_0*2/pi", "") \
    X(a_i, MAGLEV_PARAMETER, 1.0, 0.0, 1e3, "1/A", "Current scale of the inductance's current dependence", "") \
    X(b_i, MAGLEV_PARAMETER, 0.0, -1e3, 1e3, "1", "Offset of the inductance's current dependence", "") \
    X(V_min, MAGLEV_PARAMETER, 0.0, -1e3, 1e3, "V", "Lowest coil voltage a voltage drive applies (a PWM stage's floor)", "") \
    X(T_y, MAGLEV_PARAMETER, 0.0, 0.0, 1.0, "s", "Time constant of a first-order lag through which the sensor sees the position (0 = off)", "sensor_lag") \
    X(r_y, MAGLEV_PARAMETER, 0.0, -10.0, 10.0, "V/s", "Rate at which the sensor voltage's offset drifts, r_y*t added to Eq. 12 (the sensor electronics warming up; 0 = off)", "sensor_drift") \
    X(beta_F, MAGLEV_PARAMETER, 0.0, 0.0, 1.0, "1", "Share of the force that follows the static force law through a second, slower lag T_F2 (eddy currents in the core; the ball feels (1 - beta_F)*F_fast + beta_F*F2, F_fast the force lag's output or the static force; 0 = off)", "eddy_lag") \
    X(T_F2, MAGLEV_PARAMETER, 0.01, T_F_MIN, 1.0, "s", "Time constant of the second force lag F2' = (F_s - F2)/T_F2 (used when beta_F > 0)", "eddy_lag") \
    X(kappa_c, MAGLEV_PARAMETER, 0.0, -0.05, 0.05, "1/s", "Rate at which the force gain changes: the force law (Eq. 8, and the exponential law) times max(0, 1 + kappa_c*t) (the coil and magnet heating; 0 = off)", "force_gain_drift") \
    X(kappa_R, MAGLEV_PARAMETER, 0.0, -0.05, 0.05, "1/s", "Rate at which a voltage drive's coil resistance changes: R_c*max(0, 1 + kappa_R*t) (the winding heating during the run, about 0.39 %/K for copper; 0 = off)", "") \
    X(solver_step, MAGLEV_PARAMETER, 1e-4, STEP_MIN, STEP_MAX, "s", "Largest internal RK4 step", "") \
    X(F, MAGLEV_OUTPUT, 0.0, ANY, "N", "Magnetic force on the ball, Eq. 8", "")
#endif

#ifndef MAGLEV_VARIABLES_ONLY
#include "maglev_plant.h"

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846
#define MU_LIMIT 1.0
#define T_D_MAX 1.0
#define STEP_MAX 1e-3
#define STEP_MIN 1e-6 /* [s] finer RK4 steps buy no accuracy at double precision and cost time */
#define TIME_EPS 1e-12
#define T_F_MIN 1e-6 /* [s] a shorter force lag is no lag at any sample rate the plant serves */
#define TRANSIENT_EPS 1e-6 /* [A] current transient below which RK4 may take full steps */
#define FRICTION_RATE_STEP 0.5 /* the largest h*F_c/(m_k*v_c) of an RK4 substep with friction (substep_max) */
#define IMPULSE_RATIO 64.0 /* with a force lag, a current transient with T_a <= substep/64 is an impulse */
#define FF_CURRENT_EPS 1e-12 /* [A] current transient that no longer moves a force lag's input */

/* The ranges are physical plausibility bounds, far wider than any rig, that keep every product
 * of the equations finite: a value outside them is a unit error or a typing slip. */
#define ANY -INFINITY, INFINITY
#define POS_M -1.0, 1.0 /* [m] positions: the rig is a few mm tall */

/* The table of every FMU variable, from the rows of MAGLEV_VARIABLES above. */
#define MAGLEV_ROW(name, ...) [VR_##name] = {#name, __VA_ARGS__},
const MaglevVariable maglev_variables[MAGLEV_NVARS] = {MAGLEV_VARIABLES(MAGLEV_ROW)};
#undef MAGLEV_ROW

#define P(m, name) ((m)->p[VR_##name - MAGLEV_FIRST_PARAM])

static void *std_alloc(size_t n, size_t size, void *env) { (void)env; return calloc(n, size); }
static void std_release(void *ptr, void *env) { (void)env; free(ptr); }
const MaglevAllocator maglev_std_allocator = {std_alloc, std_release, NULL};

static int fail(char *msg, size_t len, const char *fmt, ...) {
    if (msg && len) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(msg, len, fmt, ap);
        va_end(ap);
    }
    return -1;
}

static double clip(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

double maglev_param(const MaglevPlant *m, MaglevVR vr) { return m->p[vr - MAGLEV_FIRST_PARAM]; }

void maglev_set_param(MaglevPlant *m, MaglevVR vr, double value) { m->p[vr - MAGLEV_FIRST_PARAM] = value; }

void maglev_defaults(MaglevPlant *m) {
    memset(m, 0, sizeof *m);
    for (int vr = MAGLEV_FIRST_PARAM; vr <= VR_solver_step; vr++)
        m->p[vr - MAGLEV_FIRST_PARAM] = maglev_variables[vr].start;
}

int maglev_check_value(MaglevVR vr, double value, char *msg, size_t len) {
    if (vr < 0 || vr >= MAGLEV_NVARS) return fail(msg, len, "unknown value reference %d", (int)vr);
    const MaglevVariable *var = &maglev_variables[vr];
    if (!isfinite(value)) return fail(msg, len, "variable %s: value %g is not finite", var->name, value);
    if (var->causality == MAGLEV_PARAMETER && (value < var->min || value > var->max))
        return fail(msg, len, "variable %s: must be in [%g, %g] %s, got %g", var->name, var->min, var->max, var->unit,
                    value);
    if (vr == VR_T_F && value > 0 && value < T_F_MIN)
        return fail(msg, len, "variable T_F: must be 0 (off) or >= %g s, got %g", T_F_MIN, value);
    return 0;
}

int maglev_check_params(const MaglevPlant *m, char *msg, size_t len) {
    for (int vr = MAGLEV_FIRST_PARAM; vr <= VR_solver_step; vr++)
        if (maglev_check_value((MaglevVR)vr, maglev_param(m, (MaglevVR)vr), msg, len)) return -1;
    /* Eq. 8 is singular at x_0; the exponential law alone (k_c = 0) lets the ball touch the coil */
    if (P(m, k_c) > 0 ? !(P(m, x_max) < P(m, x_0)) : !(P(m, x_max) <= P(m, x_0)))
        return fail(msg, len, "variable x_max: must be below x_0 = %g m (force law singular at x_0), got %g",
                    P(m, x_0), P(m, x_max));
    if (!(P(m, x_min) < P(m, x_max)))
        return fail(msg, len, "variable x_min: must be below x_max = %g m, got %g", P(m, x_max), P(m, x_min));
    if (P(m, L_g) > 0 && !(P(m, x_max) < P(m, x_0)))
        return fail(msg, len, "variable L_g: the inverse-gap inductance needs x_max below x_0 = %g m, got x_max = %g",
                    P(m, x_0), P(m, x_max));
    if (!(P(m, k_c) > 0 || P(m, k_e) > 0))
        return fail(msg, len, "variable k_c: the force law needs k_c > 0 or k_e > 0, got k_c = %g, k_e = %g",
                    P(m, k_c), P(m, k_e));
    if (!(P(m, L_0) - P(m, L_i) * PI / 2 > 0))
        return fail(msg, len, "variable L_i: must stay below L_0*2/pi = %g H so that the inductance stays positive, "
                    "got %g", P(m, L_0) * 2 / PI, P(m, L_i));
    if (!(P(m, x_n) < P(m, x_0)))
        return fail(msg, len, "variable x_n: must be below x_0 = %g m, got %g", P(m, x_0), P(m, x_n));
    if (P(m, x_start) < P(m, x_min) || P(m, x_start) > P(m, x_max))
        return fail(msg, len, "variable x_start: must lie between the stops [%g, %g] m, got %g", P(m, x_min),
                    P(m, x_max), P(m, x_start));
    if (P(m, i_start) < 0 || P(m, i_start) > P(m, i_max))
        return fail(msg, len, "variable i_start: must lie in [0, i_max = %g] A, got %g", P(m, i_max), P(m, i_start));
    return 0;
}

int maglev_check_plant(const MaglevPlant *m, char *msg, size_t len) {
    for (int vr = MAGLEV_FIRST_PARAM; vr <= VR_solver_step; vr++)
        if (maglev_check_value((MaglevVR)vr, maglev_param(m, (MaglevVR)vr), msg, len)) return -1;
    if (!isfinite(m->time) || fabs(m->time) > MAGLEV_TIME_MAX)
        return fail(msg, len, "time %g must be finite and within +-%g s", m->time, MAGLEV_TIME_MAX);
    if (!isfinite(m->u)) return fail(msg, len, "variable u: value %g is not finite", m->u);
    const MaglevHistory *h = &m->hist;
    for (size_t k = 0; k < h->len; k++) {
        if (!isfinite(h->u[k])) return fail(msg, len, "delay history: input %g is not finite", h->u[k]);
        if (isnan(h->t[k]) || h->t[k] == INFINITY || (k > 0 && !(h->t[k] > h->t[k - 1])))
            return fail(msg, len, "delay history: times are not finite and increasing at entry %zu", k);
    }
    if (!m->initialized) return 0; /* before initialisation only the values on their own count */
    if (maglev_check_params(m, msg, len)) return -1;
    if (!(m->x >= P(m, x_min) && m->x <= P(m, x_max)))
        return fail(msg, len, "variable x: %g m lies outside the stops [%g, %g] m", m->x, P(m, x_min), P(m, x_max));
    if (!isfinite(m->v)) return fail(msg, len, "variable v: value %g is not finite", m->v);
    if (!(m->i >= 0 && m->i <= P(m, i_max)))
        return fail(msg, len, "variable i: %g A lies outside [0, i_max = %g] A", m->i, P(m, i_max));
    if (P(m, T_y) > 0 ? !(m->xs >= P(m, x_min) && m->xs <= P(m, x_max)) : m->xs != m->x)
        return fail(msg, len, "variable xs: the position the sensor sees, %g m, %s", m->xs,
                    P(m, T_y) > 0 ? "lies outside the stops" : "differs from x without a sensor lag");
    if (P(m, T_F) > 0 ? !(m->F >= 0 && isfinite(m->F)) : m->F != 0)
        return fail(msg, len, "variable F: %g N is not a force the lag can hold", m->F);
    if (P(m, beta_F) > 0 ? !(m->F2 >= 0 && isfinite(m->F2)) : m->F2 != 0)
        return fail(msg, len, "variable F2: %g N is not a force the second lag (beta_F = %g) can hold", m->F2,
                    P(m, beta_F));
    if (m->contact < CONTACT_LOWER || m->contact > CONTACT_UPPER)
        return fail(msg, len, "contact mode %d is invalid", m->contact);
    if (m->contact && (m->v != 0 || m->x != (m->contact == CONTACT_UPPER ? P(m, x_max) : P(m, x_min))))
        return fail(msg, len, "contact with a stop, but x = %g m and v = %g m/s", m->x, m->v);
    if (P(m, T_d) > 0 && h->len == 0) return fail(msg, len, "delay T_d > 0 but no input history");
    return 0;
}

/* ---- the equations ---- */

static double drive_volts(const MaglevPlant *m, double u_mu) {
    double u_volt = P(m, k_DA) * clip(u_mu, -MU_LIMIT, MU_LIMIT) + P(m, u_0); /* Eq. 1 */
    if (P(m, u_dz) > 0) /* the amplifier's dead zone: no current for |u_volt| <= u_dz */
        u_volt = u_volt > P(m, u_dz) ? u_volt - P(m, u_dz) : (u_volt < -P(m, u_dz) ? u_volt + P(m, u_dz) : 0.0);
    return u_volt;
}

/* A voltage drive makes the current a state of its own (R_c > 0); otherwise it follows Eq. 2/5. */
static int voltage_drive(const MaglevPlant *m) { return P(m, R_c) > 0; }

static double current_command(const MaglevPlant *m, double u_mu) {
    return clip(P(m, k_i) * drive_volts(m, u_mu), 0.0, P(m, i_max)); /* Eq. 2/5 */
}

/* The coil voltage of a voltage drive for input u_mu. */
static double coil_volts(const MaglevPlant *m, double u_mu) {
    double v = drive_volts(m, u_mu);
    return v < P(m, V_min) ? P(m, V_min) : v;
}

/* The coil resistance of a voltage drive at time t: R_c*max(0, 1 + kappa_R*t) (the winding heating). */
static double coil_resistance(const MaglevPlant *m, double t) {
    double g = 1.0 + P(m, kappa_R) * t;
    return P(m, R_c) * (g > 0 ? g : 0.0);
}

/* The atan of the coil's inductance (coil_rate) at the stages of one RK4 substep: the first stage's
 * argument a0 and its library atan, and whether they are set yet (a substep starts with set = 0). */
typedef struct {
    double a, at;
    int set;
} CoilAnchor;

#define COIL_ATAN_NEAR 0.0625 /* |a - a0| up to which a stage's atan is taken from the first stage's */

/* atan(a) at an RK4 stage. The stages of a substep see nearly the same current, so from the first
 * stage's a0: atan(a) = atan(a0) + atan(w), w = (a - a0)/(1 + a*a0) (exact where a*a0 > -1, which
 * |a - a0| <= 1/16 ensures), and atan(w) by its series to w^13 (|w| < 0.063: the next term is below
 * 1e-18 of w). The library's atan, which sets and restores the rounding mode on each call, was a fifth of the
 * cycles of an Inteco record's diagnosis (four calls a substep); this takes one. The result depends on
 * the substep's own states alone, so a restored FMU state steps as the live one. */
static double coil_atan(CoilAnchor *an, double a) {
    if (!an->set) {
        an->a = a;
        an->at = atan(a);
        an->set = 1;
        return an->at;
    }
    double d = a - an->a;
    if (!(fabs(d) <= COIL_ATAN_NEAR)) return atan(a);
    double w = d / (1.0 + a * an->a), z = w * w;
    double p = -1.0 / 3 + z * (1.0 / 5 + z * (-1.0 / 7 + z * (1.0 / 9 + z * (-1.0 / 11 + z * (1.0 / 13)))));
    return an->at + (w + w * z * p);
}

/* di/dt of a voltage drive: d(L i)/dt = V - R(t)*i with L(x, i) and R(t) the coil resistance at t;
 * the ball's motion induces i*dL/dx*v. A current at 0 (the drive's freewheel diode) or at i_max does
 * not pass it. an: the substep's atan anchor (coil_atan). */
static double coil_rate(const MaglevPlant *m, double volts, double i, double x, double v, double t, CoilAnchor *an) {
    double gap = P(m, x_0) - x, e = P(m, L_x) * exp(-gap / P(m, z_L));
    double a = P(m, a_i) * i - P(m, b_i);
    double L = P(m, L_0) + e + P(m, L_i) * coil_atan(an, a), dL_dx = e / P(m, z_L);
    if (P(m, L_g) > 0) {
        L += P(m, L_g) / gap;
        dL_dx += P(m, L_g) / (gap * gap);
    }
    double dL_di = P(m, L_i) * P(m, a_i) / (1 + a * a);
    double rate = (volts - coil_resistance(m, t) * i - i * dL_dx * v) / (L + i * dL_di);
    if ((i <= 0 && rate < 0) || (i >= P(m, i_max) && rate > 0)) return 0.0;
    return rate;
}

/* (x_0 - x_n)/(x_0 - x) to the power n_F - 2: 1 for the paper's law (n_F = 2). */
static double exponent_factor(const MaglevPlant *m, double gap) {
    return P(m, n_F) == 2.0 ? 1.0 : pow((P(m, x_0) - P(m, x_n)) / gap, P(m, n_F) - 2.0);
}

/* The force per i^2 at x: Eq. 8 plus the exponential law. */
static double force_gain(const MaglevPlant *m, double x) {
    double gap = P(m, x_0) - x;
    double k = P(m, k_c) > 0 ? P(m, k_c) / (gap * gap) * exponent_factor(m, gap) : 0.0; /* Eq. 8 */
    if (P(m, k_e) > 0) k += P(m, k_e) * exp(-gap / P(m, z_e));
    return k;
}

static double static_force(const MaglevPlant *m, double i, double x) {
    if (P(m, k_e) > 0) return force_gain(m, x) * i * i;
    double gap = P(m, x_0) - x;
    return P(m, k_c) * i * i / (gap * gap) * exponent_factor(m, gap); /* Eq. 8 */
}

/* Effect force_gain_drift: the factor max(0, 1 + kappa_c*t) on the force law at time t (the coil and
 * magnet heating; a gain that has drifted to nothing stays nothing). */
static double gain_drift(const MaglevPlant *m, double t) {
    double g = 1.0 + P(m, kappa_c) * t;
    return g > 0 ? g : 0.0;
}

/* Current at tau into a piece whose command is ic and whose start current is i0. */
static double current_at(const MaglevPlant *m, double i0, double ic, double tau) {
    if (P(m, T_a) <= 0) return ic;
    return ic + (i0 - ic) * exp(-tau / P(m, T_a));
}

/* The delayed input in force at time t (history sorted by time, oldest first). */
static double delayed_input(const MaglevPlant *m, double t) {
    if (P(m, T_d) <= 0 || m->hist.len == 0) return m->u;
    double ts = t - P(m, T_d);
    const MaglevHistory *h = &m->hist;
    if (ts < h->t[0]) return h->u[0];
    size_t lo = 0, hi = h->len - 1;
    while (lo < hi) { /* last breakpoint with t <= ts, to rounding of t + T_d - T_d */
        size_t mid = (lo + hi + 1) / 2;
        if (h->t[mid] <= ts + TIME_EPS) lo = mid; else hi = mid - 1;
    }
    return h->u[lo];
}

/* The RK4 stages are the hot path of every replay: GCC's heuristics leave deriv() and rk4_i()
 * as calls (about twice the cost per step); forced inline, the output is bit-identical. */
#if defined(__GNUC__)
#define HOT static inline __attribute__((always_inline))
#define COLD static __attribute__((noinline, cold))
#else
#define HOT static inline
#define COLD static
#endif

/* The RK4 state: the current is integrated only with a voltage drive (else it is given); t is the
 * simulation time (dt/dt = 1), which the force law needs with the effect force_gain_drift. */
typedef struct { double x, v, F, i, F2, t; } Mech;

/* phi_0..phi_4 of the exponential integrators at z <= 0: phi_0 = e^z, phi_(k+1) = (phi_k - 1/k!)/z.
 * Where |z| < 1 that recursion would cancel: phi_4 by its series, then phi_k = z*phi_(k+1) + 1/k!. */
static void phi_functions(double z, double phi[5]) {
    phi[0] = exp(z);
    if (z > -1.0) {
        double term = 1.0 / 24, sum = 0.0;
        for (int j = 0; j < 40 && fabs(term) > 1e-19; j++) {
            sum += term;
            term *= z / (j + 5);
        }
        phi[4] = sum;
        phi[3] = z * phi[4] + 1.0 / 6;
        phi[2] = z * phi[3] + 0.5;
        phi[1] = z * phi[2] + 1.0;
    } else {
        double fact = 1.0;
        for (int k = 0; k < 4; k++) {
            if (k > 0) fact *= k;
            phi[k + 1] = (phi[k] - 1.0 / fact) / z;
        }
    }
}

/* The ETDRK4 weights are those of the substep length rounded to 32 significant bits (ETD_BITS): a
 * delay's pieces are differences of sample times (k*ts + T_d - t), which differ in their last bits from
 * sample to sample (3e-15 s at 15 s), so weights of the exact length missed the cache nearly every time
 * and were 7 % of an Inteco record's filter pass. Rounded, the lengths of a piece agree, and the weights
 * are a function of the length alone, never of what the cache held before (a restored FMU state, which
 * has none, steps bit for bit as the live one). The rounding moves the weights by at most 2^-33 of h/T_F. */
#define ETD_BITS 32

static double etd_length(double h) {
    uint64_t b;
    memcpy(&b, &h, sizeof b);
    const uint64_t drop = 52 - ETD_BITS;
    b = (b + ((uint64_t)1 << (drop - 1))) & ~(((uint64_t)1 << drop) - 1); /* to nearest; a carry moves the exponent */
    memcpy(&h, &b, sizeof h);
    return h;
}

/* The force lag F' = (F_s - F)/T_F is stiff when T_F is short: plain RK4 needs substeps below
 * 2.8*T_F to stay stable, and below T_F/2 to be accurate (a lag of 50 us cost 6 lag-free replays). Cox and Matthews' ETDRK4 takes
 * its linear part -F/T_F exactly and reduces to the classic RK4 of x and v, whose stages it
 * shares; these are its weights for a substep h (z = -h/T_F): the stages' e^(z/2) and
 * (h/2)*phi_1(z/2), the step's e^z and h*(phi_1 - 3phi_2 + 4phi_3), 2h*(phi_2 - 2phi_3),
 * h*(4phi_3 - phi_2), which tend to RK4's h/6, h/3, h/6 as T_F grows. */
static const MaglevEtd *etd_weights(MaglevPlant *m, double h) {
    const double T = P(m, T_F);
    h = etd_length(h); /* (h > 0 and finite here: a substep) */
    for (int k = 0; k < 2; k++)
        if (m->etd[k].h == h && m->etd[k].T == T) return &m->etd[k];
    MaglevEtd *c = &m->etd[m->etd_next];
    m->etd_next ^= 1;
    double p[5], q[5];
    phi_functions(-h / T, p);
    phi_functions(-h / (2 * T), q);
    c->h = h;
    c->T = T;
    c->e = p[0];
    c->e2 = q[0];
    c->a2 = h / 2 * q[1];
    c->f1 = h * (p[1] - 3 * p[2] + 4 * p[3]);
    c->f2 = 2 * h * (p[2] - 2 * p[3]);
    c->f3 = h * (4 * p[3] - p[2]);
    return c;
}

typedef struct {
    const MaglevPlant *m;
    double i0, ic;          /* current at the piece's start and its command */
    double kc_m, kfv_m, x0; /* k_c/m_k, k_FV/m_k, x_0: the hot loop's constants */
    double fc_m;            /* F_c/m_k [m/s2] */
    double vc;              /* v_c [m/s] */
    int exponent;           /* n_F != 2 */
    int law_e;              /* the exponential force law is on (k_e > 0) */
    int voltage;            /* a voltage drive: the current is a state */
    double volts;           /* its coil voltage in this piece */
    long *work;             /* RK4 evaluations spent in this maglev_step, against the budget */
    MaglevPlant *cache;     /* the same plant: its caches of ETDRK4 and transient weights */
    int exact;              /* the current's transient enters RK4 through transient_squares */
    double beta;            /* beta_F: the share of the force behind the second lag (0: off) */
    double kappa;           /* kappa_c: the force gain's drift (0: off) */
} Piece;

static Piece make_piece(MaglevPlant *m, double i0, double ic, double volts, long *work) {
    Piece pc = {m, i0, ic, P(m, k_c) / P(m, m_k), P(m, k_FV) / P(m, m_k), P(m, x_0), P(m, F_c) / P(m, m_k),
                P(m, v_c), P(m, n_F) != 2.0, P(m, k_e) > 0, voltage_drive(m), volts, work, m,
                !voltage_drive(m) && P(m, T_a) > 0 && P(m, T_F) <= 0, P(m, beta_F), P(m, kappa_c)};
    return pc;
}

/* The derivatives with the current's square isq given: a point value, or a stage weight that
 * integrates a fast current transient exactly (transient_squares). */
HOT Mech deriv(const Piece *pc, double isq, Mech s, int contact, CoilAnchor *an) {
    const MaglevPlant *m = pc->m;
    Mech d;
    d.i = 0.0;
    d.t = 1.0;
    if (pc->voltage) {
        d.i = coil_rate(m, pc->volts, s.i, s.x, contact ? 0.0 : s.v, s.t, an);
        isq = s.i * s.i;
    }
    if (pc->kappa != 0) isq *= gain_drift(m, s.t); /* effect force_gain_drift: the whole force law scales */
    d.F2 = 0.0;
    if (pc->beta > 0) { /* effect eddy_lag: a share beta of the force behind the second lag T_F2 */
        double fs = force_gain(m, s.x) * isq, fast = P(m, T_F) > 0 ? s.F : fs;
        d.F = P(m, T_F) > 0 ? fs / P(m, T_F) : 0.0; /* the fast lag's input, as below */
        d.F2 = (fs - s.F2) / P(m, T_F2);
        d.x = contact ? 0.0 : s.v;
        d.v = contact ? 0.0 : ((1.0 - pc->beta) * fast + pc->beta * s.F2) / P(m, m_k) - pc->kfv_m * s.v - P(m, g);
        if (pc->fc_m > 0 && !contact) d.v -= pc->fc_m * tanh(s.v / pc->vc);
        return d;
    }
    if (P(m, T_F) > 0) { /* d.F: the lag's input F_s/T_F (its linear part -F/T_F is the ETD's) */
        d.F = force_gain(m, s.x) * isq / P(m, T_F);
        d.x = contact ? 0.0 : s.v;
        d.v = contact ? 0.0 : s.F / P(m, m_k) - pc->kfv_m * s.v - P(m, g); /* Eq. 8 */
        if (pc->fc_m > 0 && !contact) d.v -= pc->fc_m * tanh(s.v / pc->vc);
        return d;
    }
    double gap = pc->x0 - s.x;
    d.F = 0.0;
    d.x = contact ? 0.0 : s.v;
    double force = 0.0;
    if (pc->kc_m > 0) {
        force = pc->kc_m * isq / (gap * gap);
        if (pc->exponent) force *= exponent_factor(m, gap);
    }
    if (pc->law_e) force += P(m, k_e) / P(m, m_k) * exp(-gap / P(m, z_e)) * isq;
    d.v = contact ? 0.0 : force - pc->kfv_m * s.v - P(m, g); /* Eq. 8 */
    if (pc->fc_m > 0 && !contact) d.v -= pc->fc_m * tanh(s.v / pc->vc);
    return d;
}

HOT Mech axpy(Mech s, double a, Mech d) {
    Mech r = {s.x + a * d.x, s.v + a * d.v, s.F + a * d.F, s.i + a * d.i, s.F2 + a * d.F2, s.t + a * d.t};
    return r;
}

/* One RK4 step with the current's squares at its start, middle and end given. */
HOT Mech rk4_plain(const Piece *pc, Mech s, double h, int contact, double qa, double qm, double qb) {
    CoilAnchor an = {0.0, 0.0, 0};
    Mech k1 = deriv(pc, qa, s, contact, &an);
    Mech k2 = deriv(pc, qm, axpy(s, h / 2, k1), contact, &an);
    Mech k3 = deriv(pc, qm, axpy(s, h / 2, k2), contact, &an);
    Mech k4 = deriv(pc, qb, axpy(s, h, k3), contact, &an);
    Mech r;
    r.x = s.x + h / 6 * (k1.x + 2 * k2.x + 2 * k3.x + k4.x);
    r.v = s.v + h / 6 * (k1.v + 2 * k2.v + 2 * k3.v + k4.v);
    r.F = s.F;
    r.i = s.i;
    r.t = s.t + h;
    r.F2 = pc->beta > 0 ? s.F2 + h / 6 * (k1.F2 + 2 * k2.F2 + 2 * k3.F2 + k4.F2) : s.F2;
    if (pc->voltage) r.i = clip(s.i + h / 6 * (k1.i + 2 * k2.i + 2 * k3.i + k4.i), 0.0, P(pc->m, i_max));
    return r;
}

/* The same step with a force lag: ETDRK4 for F, the classic RK4 for the rest. */
static Mech rk4_etd(const Piece *pc, Mech s, double h, int contact, double qa, double qm, double qb) {
    const MaglevEtd *c = etd_weights(pc->cache, h);
    CoilAnchor an = {0.0, 0.0, 0};
    Mech k1 = deriv(pc, qa, s, contact, &an);
    Mech sa = axpy(s, h / 2, k1);
    sa.F = c->e2 * s.F + c->a2 * k1.F;
    Mech k2 = deriv(pc, qm, sa, contact, &an);
    Mech sb = axpy(s, h / 2, k2);
    sb.F = c->e2 * s.F + c->a2 * k2.F;
    Mech k3 = deriv(pc, qm, sb, contact, &an);
    Mech sc = axpy(s, h, k3);
    sc.F = c->e2 * sa.F + c->a2 * (2 * k3.F - k1.F);
    Mech k4 = deriv(pc, qb, sc, contact, &an);
    Mech r;
    r.x = s.x + h / 6 * (k1.x + 2 * k2.x + 2 * k3.x + k4.x);
    r.v = s.v + h / 6 * (k1.v + 2 * k2.v + 2 * k3.v + k4.v);
    r.F = c->e * s.F + c->f1 * k1.F + c->f2 * (k2.F + k3.F) + c->f3 * k4.F;
    r.i = s.i;
    r.t = s.t + h;
    r.F2 = pc->beta > 0 ? s.F2 + h / 6 * (k1.F2 + 2 * k2.F2 + 2 * k3.F2 + k4.F2) : s.F2;
    if (pc->voltage) r.i = clip(s.i + h / 6 * (k1.i + 2 * k2.i + 2 * k3.i + k4.i), 0.0, P(pc->m, i_max));
    return r;
}

HOT Mech rk4_i(const Piece *pc, Mech s, double h, int contact, double qa, double qm, double qb) {
    ++*pc->work;
    return P(pc->m, T_F) > 0 ? rk4_etd(pc, s, h, contact, qa, qm, qb) : rk4_plain(pc, s, h, contact, qa, qm, qb);
}

static void transient_squares(const Piece *pc, const MaglevTransient *w, double D, double out[3]);
COLD const MaglevTransient *transient_weights(MaglevPlant *m, double h);

static Mech rk4(const Piece *pc, double tau, Mech s, double h, int contact) {
    double q[3];
    if (pc->exact) {
        transient_squares(pc, transient_weights(pc->cache, h), current_at(pc->m, pc->i0, pc->ic, tau) - pc->ic, q);
    } else {
        for (int k = 0; k < 3; k++) {
            double i = current_at(pc->m, pc->i0, pc->ic, tau + k * h / 2);
            q[k] = i * i;
        }
    }
    return rk4_i(pc, s, h, contact, q[0], q[1], q[2]);
}

static double force_now(const Piece *pc, double tau, Mech s) {
    const MaglevPlant *m = pc->m;
    double fast = P(m, T_F) > 0 ? s.F
                                : static_force(m, pc->voltage ? s.i : current_at(m, pc->i0, pc->ic, tau), s.x) *
                                      gain_drift(m, s.t);
    return pc->beta > 0 ? (1.0 - pc->beta) * fast + pc->beta * s.F2 : fast;
}

/* Net force pressing the ball onto the stop it touches (>= 0: stays). */
static double press(const Piece *pc, double tau, Mech s, int contact) {
    double net = force_now(pc, tau, s) - P(pc->m, m_k) * P(pc->m, g);
    return contact == CONTACT_UPPER ? net : -net;
}

/* Regula falsi (Illinois) for the root of f on [a, b] with f(a), f(b) of opposite sign. */
typedef double (*RootFn)(const void *ctx, double tau);

static double illinois(RootFn f, const void *ctx, double a, double fa, double b, double fb, double tol) {
    int side = 0;
    for (int it = 0; it < 100; it++) {
        double c = (a * fb - b * fa) / (fb - fa);
        if (!(c > a && c < b)) c = 0.5 * (a + b);
        double fc = f(ctx, c);
        if (fabs(fc) <= tol || b - a < 1e-16) return c;
        if ((fc > 0) == (fb > 0)) {
            b = c; fb = fc;
            if (side == -1) fa /= 2;
            side = -1;
        } else {
            a = c; fa = fc;
            if (side == 1) fb /= 2;
            side = 1;
        }
    }
    return 0.5 * (a + b);
}

typedef struct { const Piece *pc; double tau; Mech s; double stop; int contact; } RootCtx;

static double impact_fn(const void *vctx, double dt) {
    const RootCtx *c = vctx;
    return rk4(c->pc, c->tau, c->s, dt, 0).x - c->stop;
}

static double release_fn(const void *vctx, double dt) {
    const RootCtx *c = vctx;
    Mech s = dt > 0 ? rk4(c->pc, c->tau, c->s, dt, c->contact) : c->s;
    return press(c->pc, c->tau + dt, s, c->contact);
}

/* Advances the mechanics by one substep h from tau, handling the stops. sq holds the RK4 stages'
 * squared currents for the whole substep, so that the common case needs no exp(). */
static void substep(const Piece *pc, double tau, Mech *s, int *contact, double h, const double sq[3]) {
    const MaglevPlant *m = pc->m;
    int full = 1; /* still the whole substep from its start: the given squares apply */
    for (int events = 0; h > 0; events++, full = 0) {
        if (events > 16) { /* chattering at a stop: finish the substep where the ball is */
            *s = rk4(pc, tau, *s, h, *contact);
            s->x = clip(s->x, P(m, x_min), P(m, x_max));
            return;
        }
        if (*contact) {
            Mech e = full ? rk4_i(pc, *s, h, *contact, sq[0], sq[1], sq[2]) : rk4(pc, tau, *s, h, *contact);
            double p1 = press(pc, tau + h, e, *contact);
            if (p1 >= 0) { *s = e; return; }
            RootCtx c = {pc, tau, *s, 0.0, *contact};
            double dt = illinois(release_fn, &c, 0.0, press(pc, tau, *s, *contact), h, p1, 1e-15);
            if (dt > 0) *s = rk4(pc, tau, *s, dt, *contact);
            *contact = CONTACT_NONE;
            tau += dt;
            h -= dt;
            continue;
        }
        Mech e = full ? rk4_i(pc, *s, h, 0, sq[0], sq[1], sq[2]) : rk4(pc, tau, *s, h, 0);
        int hit = e.x > P(m, x_max) ? CONTACT_UPPER : (e.x < P(m, x_min) ? CONTACT_LOWER : CONTACT_NONE);
        if (!hit) { *s = e; return; }
        double stop = hit == CONTACT_UPPER ? P(m, x_max) : P(m, x_min);
        RootCtx c = {pc, tau, *s, stop, 0};
        double dt = illinois(impact_fn, &c, 0.0, s->x - stop, h, e.x - stop, 1e-14);
        *s = rk4(pc, tau, *s, dt, 0);
        s->x = stop;
        s->v = 0.0; /* inelastic impact */
        tau += dt;
        h -= dt;
        *contact = press(pc, tau, *s, hit) >= 0 ? hit : CONTACT_NONE;
    }
}

/* Whether a ball on a stop stays there, unmoving, for the rest of a piece whose current is now
 * i_now: the current runs monotonically from i_now to its command, so the static force does
 * too, and a force lag's output stays between its value now and the static force. Then x and v
 * are exactly constant and the remaining piece needs no integration. With a force lag the
 * current transient must be over, so that the lag's input is constant. */
static int stays_on_stop(const Piece *pc, Mech s, int contact, double i_now) {
    const MaglevPlant *m = pc->m;
    if (!contact || s.v != 0.0 || pc->voltage) return 0; /* a voltage drive's current has no closed form */
    if (pc->kappa != 0) return 0; /* a drifting force gain: the substeps follow it on the stop (no shortcut) */
    if ((P(m, T_F) > 0 || pc->beta > 0) && fabs(i_now - pc->ic) > FF_CURRENT_EPS) return 0;
    double w = P(m, m_k) * P(m, g), sign = contact == CONTACT_UPPER ? 1.0 : -1.0;
    if (pc->beta > 0) { /* each lag's output stays between its value now and the static force: the worst mix */
        double fs = static_force(m, pc->ic, s.x), fast = P(m, T_F) > 0 ? s.F : static_force(m, i_now, s.x);
        double lo_fast = sign > 0 ? fmin(fast, fs) : fmax(fast, fs), lo_slow = sign > 0 ? fmin(s.F2, fs) : fmax(s.F2, fs);
        return sign * ((1.0 - pc->beta) * lo_fast + pc->beta * lo_slow - w) >= 0;
    }
    if (sign * (static_force(m, pc->ic, s.x) - w) < 0) return 0;
    if (P(m, T_F) > 0) return sign * (s.F - w) >= 0;
    return sign * (static_force(m, i_now, s.x) - w) >= 0;
}

/* The sensor lag x_s' = (x - x_s)/T_y over a substep h = r*T_y, exactly, for x(theta*h) =
 * sum_k c_k theta^k (k <= 3): x_s(h) = w[0]*x_s(0) + sum_k w[k+1]*c_k with w[0] = e^-r and
 * w[k+1] = r*k!*phi_{k+1}(-r), the exponential integrators' phi functions (series for small r, where
 * their recursion would cancel). */
static void lag_weights(double r, double w[5]) {
    double phi[5];
    phi_functions(-r, phi);
    w[0] = phi[0];
    if (r > 1.0) { /* r*phi_(k+1)(-r) = 1/k! - phi_k(-r): no inf*0 where h/T_y overflows (a denormal T_y) */
        w[1] = 1.0 - phi[0];
        w[2] = 1.0 - phi[1];
        w[3] = 1.0 - 2 * phi[2];
        w[4] = 1.0 - 6 * phi[3];
        return;
    }
    w[1] = r * phi[1];
    w[2] = r * phi[2];
    w[3] = 2 * r * phi[3];
    w[4] = 6 * r * phi[4];
}

/* The current into a piece is i = i_c + D*e^(-s/T_a) from a substep's start, and the force goes
 * with i^2 = f(s). RK4's stages sample f at 0, h/2, h, which resolves the transient only on
 * substeps well below T_a (they cost ~45 substeps a step at T_a = 0.3 ms). Instead the stages get
 * values f0, fm, f1 that make RK4 integrate f exactly into v and x: for x' = v, v' = c*f(s),
 * RK4 gives v(h) = v0 + c*h*(f0 + 4*fm + f1)/6 and x(h) = x0 + h*v0 + c*h^2*(f0 + 2*fm)/6, so
 * with A = int f/h and B = int (h - s)*f/h^2 (closed forms in phi_1, phi_2) and f1 = f(h):
 * fm = 3A - 3B - f1/2 and f0 = 12B - 6A + f1. For a polynomial f of degree 2 these are f's own
 * values, so RK4's order stays; a transient far below h becomes the exact impulse. */
COLD const MaglevTransient *transient_weights(MaglevPlant *m, double h) {
    const double T = P(m, T_a);
    for (int k = 0; k < 2; k++)
        if (m->tr[k].h == h && m->tr[k].T == T) return &m->tr[k];
    MaglevTransient *w = &m->tr[m->tr_next];
    m->tr_next ^= 1;
    double p[5], p2[5];
    phi_functions(-h / T, p);
    phi_functions(-2 * h / T, p2);
    w->h = h;
    w->T = T;
    w->q = p[0];
    w->a1 = p[1];
    w->b1 = p[2];
    w->a2 = p2[1];
    w->b2 = p2[2];
    return w;
}

static void transient_squares(const Piece *pc, const MaglevTransient *w, double D, double out[3]) {
    double ic = pc->ic, end = ic + D * w->q;
    double A = ic * ic + 2 * ic * D * w->a1 + D * D * w->a2;
    double B = ic * ic / 2 + 2 * ic * D * w->b1 + D * D * w->b2;
    out[0] = 12 * B - 6 * A + end * end;
    out[1] = 3 * A - 3 * B - end * end / 2;
    out[2] = end * end;
}

/* With a force lag (ETDRK4, not RK4: transient_squares does not apply), a current transient
 * i = i_c + d*e^(-t/T_a) far below the substep is an impulse: with the force g(x)*i^2 and
 * phi = i^2 - i_c^2, F takes g*int(e^(t/T_F)*phi)/T_F and v the difference that keeps the total
 * impulse g*int(phi), exact up to x's change during the transient. On a stop, the stop takes v's. */
COLD void transient_impulse(const MaglevPlant *m, const Piece *pc, Mech *s, int contact) {
    double T = P(m, T_a), ic = pc->ic, d = pc->i0 - pc->ic, g = force_gain(m, s->x) * gain_drift(m, s->t);
    double I = (2 * ic * d + d * d / 2) * T;
    double r = 1.0 / T - 1.0 / P(m, T_F), J = 2 * ic * d / r + d * d / (r + 1.0 / T);
    s->F += g / P(m, T_F) * J;
    if (pc->beta > 0) { /* the second lag takes its share the same way; v what neither holds */
        double r2 = 1.0 / T - 1.0 / P(m, T_F2), J2 = 2 * ic * d / r2 + d * d / (r2 + 1.0 / T);
        s->F2 += g / P(m, T_F2) * J2;
        if (!contact) s->v += g / P(m, m_k) * ((1.0 - pc->beta) * (I - J) + pc->beta * (I - J2));
        return;
    }
    if (!contact) s->v += g / P(m, m_k) * (I - J);
}

/* What sets the length of the RK4 substeps: a step refused for its work budget names it, since a shorter
 * solver_step does not help where one of the others sets it. */
typedef enum { BY_SOLVER_STEP, BY_FORCE_LAG, BY_FRICTION, BY_VOLTAGE_DRIVE, BY_AMPLIFIER_LAG, BY_EDDY_LAG, BY_COUNT } SetBy;

/* The longest substep the parameters allow, and what sets it. */
static double substep_max(const MaglevPlant *m, SetBy *by) {
    double h = P(m, solver_step);
    *by = BY_SOLVER_STEP;
    /* ETDRK4 is stable at any T_F, but where T_F << h its force stages trail the static force by
     * about h/2 (3e-4 MU at T_F = 1 us, h = 0.25 ms); h <= 2*T_F keeps that below 1e-5 MU */
    if (P(m, T_F) > 0 && 2 * P(m, T_F) < h) {
        h = 2 * P(m, T_F);
        *by = BY_FORCE_LAG;
    }
    /* the second force lag is integrated by the classic RK4: h <= T_F2/2 keeps it stable and accurate */
    if (P(m, beta_F) > 0 && P(m, T_F2) / 2 < h) {
        h = P(m, T_F2) / 2;
        *by = BY_EDDY_LAG;
    }
    /* the smoothed friction's slope F_c/(m_k*v_c) is a fast rate near v = 0: keep RK4's h*rate <= 0.5.
     * That mode decays (RK4 is stable to h*rate = 2.78); at 0.5 RK4's factor per substep, 0.6068, is
     * within 0.05 % of the exact e^-0.5. (The bound was 0.1: five times the substeps for nothing the
     * fits could see, and a diagnosis's friction candidates cost 8-17 times a plain replay.) */
    if (P(m, F_c) > 0 && FRICTION_RATE_STEP * P(m, m_k) * P(m, v_c) / P(m, F_c) < h) {
        h = FRICTION_RATE_STEP * P(m, m_k) * P(m, v_c) / P(m, F_c);
        *by = BY_FRICTION;
    }
    if (voltage_drive(m)) { /* RK4 on the coil equation: keep h below a fifth of its smallest time constant */
        double r = coil_resistance(m, m->time); /* the resistance now, when kappa_R has raised it */
        /* the smallest inductance the current can meet: i >= 0 and a_i >= 0, so atan(a_i*i - b_i) >=
         * atan(-b_i), and the ball's terms (L_x, L_g >= 0) only add. (The bound was L_0 - L_i*pi/2, a
         * current far below 0: on the Inteco rig 3.3 ms against 9.4 ms, which held a 1 kHz replay to
         * substeps of 0.66 ms, and the coil's atan was a quarter of a real-record diagnosis.) */
        double lowest = m->atan_b_key == P(m, b_i) ? m->atan_b : atan(-P(m, b_i)); /* maglev_step's cache */
        double tau_e = (P(m, L_0) + P(m, L_i) * lowest) / (r > P(m, R_c) ? r : P(m, R_c));
        if (tau_e / 5 < h) {
            h = tau_e / 5;
            *by = BY_VOLTAGE_DRIVE;
        }
    }
    return h;
}

/* A dry run's count of the substeps a step will take at most: maglev_step decides on it before it
 * integrates anything. */
typedef struct {
    double substeps[BY_COUNT]; /* by what sets their length; doubles: a count beyond any integer type is refused */
    size_t pieces;
    int known;                 /* the mechanics are still known: every piece so far left the ball at rest */
} Plan;

/* Integrates [t0, t0 + len) with a constant delayed input, in parts of equal substeps (at most
 * substep_max). With plan, a dry run: a ball that rests on a stop throughout is moved on as the step
 * would (no substep needed); otherwise the piece's substeps are counted, the current is moved on (it
 * has a closed form, and the next piece's substeps depend on it) and the mechanics become unknown.
 * Returns -1 when the evaluations at impacts exceed MAGLEV_WORK_MAX (never in a dry run). */
static int integrate_piece(MaglevPlant *m, double len, double u_eff, long *work, Plan *plan) {
    enum { MAX_PARTS = 12 };
    Piece pc = make_piece(m, m->i, current_command(m, u_eff), coil_volts(m, u_eff), work);
    Mech s = {m->x, m->v, m->F, m->i, m->F2, m->time};
    SetBy by;
    double hmax = substep_max(m, &by);
    double bounds[MAX_PARTS], hs[MAX_PARTS], tau = 0.0, di = fabs(pc.i0 - pc.ic), i_start = pc.i0;
    int nparts = 0;
    if (!pc.voltage && P(m, T_a) > 0 && P(m, T_F) > 0 && di > TRANSIENT_EPS &&
        IMPULSE_RATIO * P(m, T_a) <= hmax && IMPULSE_RATIO * P(m, T_a) <= P(m, T_F) &&
        (pc.beta <= 0 || IMPULSE_RATIO * P(m, T_a) <= P(m, T_F2))) {
        /* resolving it would cost ~45 substeps a step, which a fit of T_a towards 0 pays on every replay */
        transient_impulse(m, &pc, &s, m->contact);
        pc.i0 = pc.ic;
        di = 0.0;
    }
    if (!pc.voltage && !pc.exact && P(m, T_a) > 0 && di > TRANSIENT_EPS) {
        /* ETDRK4 (a force lag) sees the current's transient d*e^(-t/T_a) as a fast forcing term,
         * with an error per substep of about its size times (h/T_a)^4: the substeps start at
         * T_a/8 (the 1 kHz closed loop then agrees with the solve_ivp reference to 1e-8 MU) and
         * double each time it has shrunk 16-fold, until it is below 1 uA or they reach hmax */
        double T = P(m, T_a), t_fine = fmin(T * log(di / TRANSIENT_EPS), len), h = T / 8, t = 0.0;
        while (h < hmax && t < t_fine && nparts < MAX_PARTS - 1) {
            t = fmin(t + 4 * 0.69314718055994531 * T, t_fine);
            bounds[nparts] = t;
            hs[nparts++] = h;
            h *= 2;
        }
    }
    bounds[nparts] = len;
    hs[nparts++] = hmax;
    /* each part's substeps: the fewest of equal length at most hs[part] */
    double nd[MAX_PARTS], from = 0.0;
    for (int part = 0; part < nparts; part++) {
        double span = bounds[part] - from;
        /* (a span within one substep is one: the same as the formula's, without its division and ceil,
         * which were a tenth of this function under perf; a delay makes two such pieces a sample) */
        nd[part] = span > 0 ? (span <= hs[part] ? 1.0 : fmax(1.0, ceil(span / hs[part] - 1e-9))) : 0.0;
        if (span > 0) from = bounds[part];
    }
    /* the current at the piece's end, where it has a closed form; clipped against rounding past the ends */
    const double i_end = pc.voltage ? 0.0 : clip(current_at(m, i_start, pc.ic, len), 0.0, P(m, i_max));
    /* A dry run stops at the first substep (below): where the ball cannot rest from the start, that is
     * known here, without the parts' weights. The same test as stays_on_stop's first line. */
    int counted = plan && !(plan->known && m->contact && s.v == 0.0 && !pc.voltage);
    double d = pc.i0 - pc.ic;
    int resting = 0;
    const double Ty = P(m, T_y);
    double xs = m->xs;
    for (int part = 0; part < nparts && !resting && !counted; part++) {
        double span = bounds[part] - tau;
        if (span <= 0) continue;
        /* A part of more substeps than the budget (no cast of such a count) passed maglev_step's count
         * only with a ball resting from its first substep on: the loop ends there. */
        int over = !(nd[part] <= MAGLEV_STEP_BUDGET);
        long n = over ? 1 : (long)nd[part];
        double h = over ? hs[part] : (nd[part] == 1.0 ? span : span / nd[part]);
        /* the current's exponential by recurrence: e^(-(k+1)h/T) = e^(-kh/T) * q */
        double E = 1.0, q = 0.0, qh = 0.0;
        double ws[5] = {0};
        /* a copy: an impact's root finding inside substep() takes other lengths through the cache */
        MaglevTransient twc = {0};
        if (pc.exact) twc = *transient_weights(m, h);
        const MaglevTransient *tw = pc.exact ? &twc : NULL;
        if (Ty > 0) lag_weights(h / Ty, ws);
        if (P(m, T_a) > 0) {
            E = exp(-tau / P(m, T_a));
            q = tw ? tw->q : exp(-h / P(m, T_a));
            qh = tw ? 0.0 : exp(-h / (2 * P(m, T_a)));
        }
        for (long k = 0; k < n; k++) {
            double i_now = P(m, T_a) > 0 ? pc.ic + d * E : pc.ic, sq[3];
            if (tw) {
                transient_squares(&pc, tw, d * E, sq);
            } else {
                double im = P(m, T_a) > 0 ? pc.ic + d * E * qh : pc.ic, ie = P(m, T_a) > 0 ? pc.ic + d * E * q : pc.ic;
                sq[0] = i_now * i_now;
                sq[1] = im * im;
                sq[2] = ie * ie;
            }
            if (m->contact && stays_on_stop(&pc, s, m->contact, i_now)) {
                tau += k * h;
                resting = 1;
                break;
            }
            if (plan) { /* the piece needs substeps: all of them count */
                counted = 1;
                break;
            }
            if (over || *work >= MAGLEV_WORK_MAX) return -1; /* over: never, maglev_step counted the substeps */
            double xa = s.x, va = s.v;
            substep(&pc, tau + k * h, &s, &m->contact, h, sq);
            if (Ty > 0) { /* x over the substep as the cubic through its ends' positions and velocities */
                double dx = s.x - xa, c2 = 3 * dx - (2 * va + s.v) * h, c3 = -2 * dx + (va + s.v) * h;
                xs = ws[0] * xs + ws[1] * xa + ws[2] * va * h + ws[3] * c2 + ws[4] * c3;
                /* an average of positions between the stops stays there; the cubic may not (an
                 * impact inside the substep), nor rounding */
                xs = clip(xs, P(m, x_min), P(m, x_max));
            }
            E *= q;
        }
        if (!resting) tau = bounds[part];
    }
    if (plan) plan->pieces++;
    if (counted) {
        for (int part = 0; part < nparts; part++) /* the parts before the last are the transient's (T_a) */
            plan->substeps[part < nparts - 1 ? BY_AMPLIFIER_LAG : by] += nd[part];
        plan->known = 0;
        if (!pc.voltage) m->i = i_end;
        return 0;
    }
    if (resting && P(m, T_F) > 0) { /* the lag relaxes towards a constant static force */
        double Fs = static_force(m, pc.ic, s.x);
        s.F = Fs + (s.F - Fs) * exp(-(len - tau) / P(m, T_F));
    }
    if (resting && pc.beta > 0) {
        double Fs = static_force(m, pc.ic, s.x);
        s.F2 = Fs + (s.F2 - Fs) * exp(-(len - tau) / P(m, T_F2));
    }
    if (resting && Ty > 0) xs = s.x + (xs - s.x) * exp(-(len - tau) / Ty);
    m->x = s.x;
    m->xs = Ty > 0 ? xs : s.x;
    m->v = s.v;
    m->F = P(m, T_F) > 0 ? s.F : 0.0;
    m->F2 = pc.beta > 0 ? s.F2 : 0.0;
    m->i = pc.voltage ? s.i : i_end;
    return 0;
}

/* ---- the formulas the toolkit needs besides the simulation (one place: here) ---- */

double maglev_force(const MaglevPlant *m, double i, double x, double *dF_dx, double *dF_di) {
    double gap = P(m, x_0) - x, F = static_force(m, i, x);
    double Fp = P(m, k_c) > 0 ? P(m, k_c) * i * i / (gap * gap) * exponent_factor(m, gap) : 0.0; /* Eq. 8's share */
    double Fe = P(m, k_e) > 0 ? P(m, k_e) * exp(-gap / P(m, z_e)) * i * i : 0.0;
    if (dF_dx) *dF_dx = (P(m, k_c) > 0 ? P(m, n_F) * Fp / gap : 0.0) + Fe / P(m, z_e); /* Eq. 16 */
    if (dF_di) *dF_di = P(m, k_e) > 0 ? 2 * i * force_gain(m, x)
                                      : 2 * P(m, k_c) * i / (gap * gap) * exponent_factor(m, gap); /* Eq. 17 */
    return F;
}

double maglev_sensor_volts(const MaglevPlant *m, double x, double *dV_dx) {
    if (dV_dx) *dV_dx = P(m, k_x) + P(m, k_x2) * (2 * x - P(m, x_cal));
    return P(m, k_x) * x + P(m, y_0) + P(m, k_x2) * x * (x - P(m, x_cal)); /* Eq. 12 */
}

double maglev_reading(const MaglevPlant *m, double x, double t) {
    double volts = maglev_sensor_volts(m, x, NULL);
    if (P(m, A_d) != 0) volts += P(m, A_d) * sin(2 * PI * P(m, f_d) * t + P(m, phi_d));
    volts += P(m, r_y) * t; /* effect sensor_drift: the offset drifts from its calibrated y_0 at t = 0 */
    return P(m, k_AD) * volts + P(m, y_MU0); /* Eq. 13, before the converter's limits */
}

double maglev_position_for_reading(const MaglevPlant *m, double y, double t) {
    double lo = P(m, x_min), hi = P(m, x_max);
    double r_lo = maglev_reading(m, lo, t), r_hi = maglev_reading(m, hi, t);
    int rising = r_hi >= r_lo;
    if (rising ? y <= r_lo : y >= r_lo) return lo;
    if (rising ? y >= r_hi : y <= r_hi) return hi;
    for (int k = 0; k < 200 && hi - lo > 1e-15 * (1 + fabs(lo)); k++) { /* bracketed: bisection */
        double mid = 0.5 * (lo + hi);
        if ((maglev_reading(m, mid, t) < y) == rising) lo = mid; else hi = mid;
    }
    return 0.5 * (lo + hi);
}

double maglev_equilibrium_current(const MaglevPlant *m, double x) {
    double gap = P(m, x_0) - x;
    if (P(m, k_e) > 0) return sqrt(P(m, m_k) * P(m, g) / force_gain(m, x));
    return gap * sqrt(P(m, m_k) * P(m, g) / (P(m, k_c) * exponent_factor(m, gap))); /* Eq. 8 at rest */
}

double maglev_input_for_current(const MaglevPlant *m, double i) {
    double volts = (voltage_drive(m) ? P(m, R_c) * i : i / P(m, k_i)) + (i > 0 ? P(m, u_dz) : 0.0); /* Eq. 5 inverted, past the dead zone */
    return (volts - P(m, u_0)) / P(m, k_DA);                      /* Eq. 1 inverted */
}

/* ---- history of the input, for the delay ---- */

static int hist_push(MaglevPlant *m, double t, double u, const MaglevAllocator *a, char *msg, size_t len) {
    MaglevHistory *h = &m->hist;
    if (h->len > 0 && h->u[h->len - 1] == u) return 0;
    if (h->len > 0 && h->t[h->len - 1] >= t) { /* same instant: the later value wins */
        h->u[h->len - 1] = u;
        return 0;
    }
    /* drop breakpoints no longer needed: keep the last one at or before now - T_d */
    size_t keep = 0;
    while (keep + 1 < h->len && h->t[keep + 1] <= t - P(m, T_d)) keep++;
    if (keep > 0) {
        memmove(h->t, h->t + keep, (h->len - keep) * sizeof *h->t);
        memmove(h->u, h->u + keep, (h->len - keep) * sizeof *h->u);
        h->len -= keep;
    }
    if (h->len == h->cap) {
        size_t cap = h->cap ? 2 * h->cap : 64;
        double *nt = a->alloc(cap, sizeof *nt, a->env), *nu = a->alloc(cap, sizeof *nu, a->env);
        if (!nt || !nu) {
            if (nt) a->release(nt, a->env);
            if (nu) a->release(nu, a->env);
            return fail(msg, len, "out of memory for the input history of the delay T_d");
        }
        if (h->len) {
            memcpy(nt, h->t, h->len * sizeof *nt);
            memcpy(nu, h->u, h->len * sizeof *nu);
        }
        if (h->t) a->release(h->t, a->env);
        if (h->u) a->release(h->u, a->env);
        h->t = nt;
        h->u = nu;
        h->cap = cap;
    }
    h->t[h->len] = t;
    h->u[h->len] = u;
    h->len++;
    return 0;
}

int maglev_set_input(MaglevPlant *m, double u, const MaglevAllocator *a, char *msg, size_t len) {
    if (!isfinite(u)) return fail(msg, len, "variable u: value %g is not finite", u);
    m->u = u;
    if (P(m, T_d) > 0) return hist_push(m, m->time, u, a, msg, len);
    return 0;
}

/* The state at t0 from the start values, without the delay history (shared by initialisation
 * and its preview). */
static int start_state(MaglevPlant *m, double t0, double u0, char *msg, size_t len) {
    if (maglev_check_params(m, msg, len)) return -1;
    if (!isfinite(t0) || fabs(t0) > MAGLEV_TIME_MAX)
        return fail(msg, len, "start time %g must be finite and within +-%g s", t0, MAGLEV_TIME_MAX);
    if (!isfinite(u0)) return fail(msg, len, "variable u: value %g is not finite", u0);
    m->time = t0;
    m->u = u0;
    m->x = P(m, x_start);
    m->v = P(m, v_start);
    m->i = (P(m, T_a) > 0 || voltage_drive(m)) ? P(m, i_start) : current_command(m, u0);
    m->F = P(m, T_F) > 0 ? static_force(m, m->i, m->x) * gain_drift(m, t0) : 0.0;
    m->F2 = P(m, beta_F) > 0 ? static_force(m, m->i, m->x) * gain_drift(m, t0) : 0.0;
    m->xs = m->x; /* the sensor has settled on the start position */
    m->contact = CONTACT_NONE;
    long work = 0;
    Piece pc = make_piece(m, m->i, m->i, coil_volts(m, u0), &work);
    Mech s = {m->x, m->v, m->F, m->i, m->F2, t0};
    if (m->x >= P(m, x_max) && (m->v > 0 || (m->v == 0 && press(&pc, 0, s, CONTACT_UPPER) >= 0))) {
        m->contact = CONTACT_UPPER;
        m->v = 0;
    } else if (m->x <= P(m, x_min) && (m->v < 0 || (m->v == 0 && press(&pc, 0, s, CONTACT_LOWER) >= 0))) {
        m->contact = CONTACT_LOWER;
        m->v = 0;
    }
    return 0;
}

int maglev_preview(const MaglevPlant *m, double t0, MaglevPlant *view, char *msg, size_t len) {
    *view = *m;
    memset(&view->hist, 0, sizeof view->hist);
    return start_state(view, t0, m->u, msg, len);
}

int maglev_initialize(MaglevPlant *m, double t0, double u0, const MaglevAllocator *a, char *msg, size_t len) {
    if (start_state(m, t0, u0, msg, len)) return -1;
    m->hist.len = 0;
    if (maglev_set_input(m, u0, a, msg, len)) return -1;
    /* the delay's "before the start" value is the initial input */
    if (P(m, T_d) > 0 && m->hist.len) m->hist.t[0] = -INFINITY;
    m->initialized = 1;
    return 0;
}

/* The step from m->time to t_end in pieces: the delayed input is constant between the instants it
 * changes, and each piece is integrated with it held (integrate_piece, plan: a dry run). */
static int step_pieces(MaglevPlant *m, double t_end, long *work, Plan *plan) {
    if (P(m, T_a) <= 0 && !voltage_drive(m)) m->i = current_command(m, delayed_input(m, m->time));
    size_t from = 0; /* where the history scan resumes: the pieces' starts only grow */
    while (m->time < t_end) {
        double next = t_end;
        if (P(m, T_d) > 0) { /* the next instant the delayed input changes */
            const MaglevHistory *hs = &m->hist;
            for (size_t k = from; k < hs->len; k++) {
                double tc = hs->t[k] + P(m, T_d);
                if (tc > m->time + TIME_EPS) {
                    if (tc < next - TIME_EPS) next = tc;
                    from = k;
                    break;
                }
            }
        }
        if (integrate_piece(m, next - m->time, delayed_input(m, 0.5 * (m->time + next)), work, plan)) return -1;
        m->time = next;
    }
    return 0;
}

/* The message of a step refused for its work budget: how many substeps, and what sets their length. */
static void budget_message(const MaglevPlant *m, double h, const Plan *plan, char *msg, size_t len) {
    double total = 0.0;
    int top = 0;
    for (int k = 0; k < BY_COUNT; k++) {
        total += plan->substeps[k];
        if (plan->substeps[k] > plan->substeps[top]) top = k;
    }
    SetBy by;
    double hmax = substep_max(m, &by);
    char what[160], pieces[48] = "";
    switch ((SetBy)top) {
    case BY_FORCE_LAG:
        snprintf(what, sizeof what, "the force lag T_F = %g s sets their length to 2*T_F", P(m, T_F));
        break;
    case BY_EDDY_LAG:
        snprintf(what, sizeof what, "the second force lag T_F2 = %g s (beta_F = %g) sets their length to T_F2/2",
                 P(m, T_F2), P(m, beta_F));
        break;
    case BY_FRICTION:
        snprintf(what, sizeof what, "the friction F_c = %g N sets their length to 0.1*m_k*v_c/F_c = %g s (m_k = %g kg, "
                 "v_c = %g m/s)", P(m, F_c), hmax, P(m, m_k), P(m, v_c));
        break;
    case BY_VOLTAGE_DRIVE:
        snprintf(what, sizeof what, "the voltage drive (R_c = %g Ohm, L_0 = %g H, L_i = %g H) sets their length to "
                 "(L_0 + L_i*atan(-b_i))/R_c/5 = %g s", P(m, R_c), P(m, L_0), P(m, L_i), hmax);
        break;
    case BY_AMPLIFIER_LAG:
        snprintf(what, sizeof what, "the amplifier lag T_a = %g s under the force lag T_F sets their length to T_a/8 "
                 "at first", P(m, T_a));
        break;
    default: snprintf(what, sizeof what, "solver_step = %g s sets their length", P(m, solver_step)); break;
    }
    if (plan->pieces > 1) snprintf(pieces, sizeof pieces, " in %zu pieces (the delay T_d)", plan->pieces);
    fail(msg, len, "a step of %g s needs %.3g RK4 steps%s, over the budget of %ld: %s; take shorter communication "
         "steps", h, total, pieces, MAGLEV_STEP_BUDGET, what);
}

/* What stepping changes (besides the caches, which depend on h, T_F and T_a alone, and the work statistic):
 * a failed step puts it back. A copy of these instead of the whole plant (784 bytes with its parameters),
 * since every step of a replay takes one. */
typedef struct {
    double time, x, v, i, F, F2, xs;
    int contact;
} StepState;

static StepState step_state(const MaglevPlant *m) {
    StepState s = {m->time, m->x, m->v, m->i, m->F, m->F2, m->xs, m->contact};
    return s;
}

static void restore_step_state(MaglevPlant *m, const StepState *s) {
    m->time = s->time;
    m->x = s->x;
    m->v = s->v;
    m->i = s->i;
    m->F = s->F;
    m->F2 = s->F2;
    m->xs = s->xs;
    m->contact = s->contact;
}

int maglev_step(MaglevPlant *m, double h, const MaglevAllocator *a, char *msg, size_t len) {
    (void)a;
    m->work = 0;
    if (!(h > 0) || !isfinite(h)) return fail(msg, len, "communication step size %g must be > 0 and finite", h);
    double t_end = m->time + h;
    if (!(fabs(t_end) <= MAGLEV_TIME_MAX)) {
        fail(msg, len, "a step to t = %g s leaves the time range +-%g s", t_end, MAGLEV_TIME_MAX);
        return MAGLEV_REFUSED;
    }
    if (m->atan_b_key != P(m, b_i)) { /* substep_max's bound on a voltage drive's inductance, once per b_i: it
                                          * is asked three times a step, and atan was a fifth of a real-rig diagnosis */
        m->atan_b_key = P(m, b_i);
        m->atan_b = atan(-P(m, b_i));
    }
    long work = 0;
    /* The work budget is decided before integrating, so that a step it refuses costs nothing. A piece
     * takes at most len/hmax + 1 substeps, and at most 57 more while an amplifier transient lasts under a
     * force lag (integrate_piece): where that bound fits the budget, as at every ordinary step, the count
     * is not needed. Otherwise a dry run on a copy counts them (the copy shares the delay history, which
     * stepping only reads). */
    SetBy by;
    double pieces_max = P(m, T_d) > 0 ? (double)m->hist.len + 1.0 : 1.0;
    if (!(h / substep_max(m, &by) + 64.0 * pieces_max <= MAGLEV_STEP_BUDGET)) {
        Plan plan;
        memset(&plan, 0, sizeof plan);
        plan.known = 1;
        MaglevPlant dry = *m;
        step_pieces(&dry, t_end, &work, &plan);
        double total = 0.0;
        for (int k = 0; k < BY_COUNT; k++) total += plan.substeps[k];
        if (!(total <= MAGLEV_STEP_BUDGET)) {
            budget_message(m, h, &plan, msg, len);
            return MAGLEV_REFUSED;
        }
    }
    /* a failed step leaves the plant as it was (the history is not touched by stepping) */
    const StepState before = step_state(m);
    if (step_pieces(m, t_end, &work, NULL)) {
        restore_step_state(m, &before);
        m->work = work;
        fail(msg, len, "a step of %g s needs more than %ld RK4 evaluations, most of them finding impacts at the "
             "stops; take shorter communication steps", h, MAGLEV_WORK_MAX);
        return MAGLEV_REFUSED;
    }
    m->work = work;
    m->time = t_end;
    if (P(m, T_a) <= 0 && !voltage_drive(m)) m->i = current_command(m, delayed_input(m, m->time));
    if (!isfinite(m->x) || !isfinite(m->xs) || !isfinite(m->v) || !isfinite(m->i) || !isfinite(m->F) ||
        !isfinite(m->F2)) {
        double x = m->x, v = m->v, i = m->i;
        restore_step_state(m, &before);
        m->work = work;
        return fail(msg, len, "state became non-finite at t = %g (x = %g, v = %g, i = %g); the state before "
                    "the step is kept", t_end, x, v, i);
    }
    return 0;
}

double maglev_get(const MaglevPlant *m, MaglevVR vr) {
    switch (vr) {
    case VR_u: return m->u;
    case VR_x: return m->x;
    case VR_v: return m->v;
    case VR_i:
        return (P(m, T_a) > 0 || voltage_drive(m)) ? m->i : current_command(m, delayed_input(m, m->time));
    case VR_F: {
        double fast = P(m, T_F) > 0 ? m->F : static_force(m, maglev_get(m, VR_i), m->x) * gain_drift(m, m->time);
        return P(m, beta_F) > 0 ? (1.0 - P(m, beta_F)) * fast + P(m, beta_F) * m->F2 : fast;
    }
    case VR_y: return clip(maglev_reading(m, m->xs, m->time), -MU_LIMIT, MU_LIMIT); /* Eq. 13 */
    default:
        if (vr >= MAGLEV_FIRST_PARAM && vr <= VR_solver_step) return maglev_param(m, vr);
        return NAN;
    }
}

/* ---- copy and serialisation ---- */

void maglev_release(MaglevPlant *m, const MaglevAllocator *a) {
    if (m->hist.t) a->release(m->hist.t, a->env);
    if (m->hist.u) a->release(m->hist.u, a->env);
    m->hist.t = m->hist.u = NULL;
    m->hist.len = m->hist.cap = 0;
}

int maglev_copy(MaglevPlant *dst, const MaglevPlant *src, const MaglevAllocator *a) {
    *dst = *src;
    dst->hist.t = dst->hist.u = NULL;
    dst->hist.cap = dst->hist.len = 0;
    if (src->hist.len) {
        dst->hist.t = a->alloc(src->hist.len, sizeof(double), a->env);
        dst->hist.u = a->alloc(src->hist.len, sizeof(double), a->env);
        if (!dst->hist.t || !dst->hist.u) {
            maglev_release(dst, a);
            return -1;
        }
        memcpy(dst->hist.t, src->hist.t, src->hist.len * sizeof(double));
        memcpy(dst->hist.u, src->hist.u, src->hist.len * sizeof(double));
        dst->hist.len = dst->hist.cap = src->hist.len;
    }
    return 0;
}

int maglev_copy_into(MaglevPlant *dst, const MaglevPlant *src, const MaglevAllocator *a) {
    MaglevHistory own = dst->hist;
    if (src->hist.len > own.cap) { /* grown with room to spare: the copy's next input needs no new buffer */
        size_t cap = 2 * src->hist.len + 8;
        double *nt = a->alloc(cap, sizeof(double), a->env), *nu = a->alloc(cap, sizeof(double), a->env);
        if (!nt || !nu) {
            if (nt) a->release(nt, a->env);
            if (nu) a->release(nu, a->env);
            return -1;
        }
        if (own.t) a->release(own.t, a->env);
        if (own.u) a->release(own.u, a->env);
        own.t = nt;
        own.u = nu;
        own.cap = cap;
    }
    *dst = *src;
    dst->hist = own;
    dst->hist.len = src->hist.len;
    if (src->hist.len) {
        memcpy(dst->hist.t, src->hist.t, src->hist.len * sizeof(double));
        memcpy(dst->hist.u, src->hist.u, src->hist.len * sizeof(double));
    }
    return 0;
}

/* Layout: magic "MGLV", u32 version, u32 nparams, u64 hist len, u32 tag code, i32 initialized, doubles
 * (params, time, u, x, v, i, F, xs, F2, the tag's values), i32 contact, u32 tag flags, hist pairs, u64 FNV-1a
 * of all before. Version 4 added the tag's values and flags (the FMU's experiment): an image of version 3
 * lacks them, and is refused by its version rather than misread. Version 5 added the second force lag's
 * state F2 (after xs) and its two parameters. */
#define SER_MAGIC "MGLV"
#define SER_VERSION 5u
#define SER_NSTATE 8

static size_t ser_header(void) { return 4 + 4 + 4 + 8 + 4 + 4; }

size_t maglev_serialized_size(const MaglevPlant *m) {
    return ser_header() + (MAGLEV_NPARAMS + SER_NSTATE + MAGLEV_TAG_NVALUES) * 8 + 4 + 4 + m->hist.len * 16 + 8;
}

unsigned long long maglev_checksum(const unsigned char *b, size_t n) {
    unsigned long long h = 1469598103934665603ULL;
    for (size_t k = 0; k < n; k++) {
        h ^= b[k];
        h *= 1099511628211ULL;
    }
    return h;
}

static unsigned char *put(unsigned char *b, const void *v, size_t n) {
    memcpy(b, v, n);
    return b + n;
}

static const unsigned char *get(const unsigned char *b, void *v, size_t n) {
    memcpy(v, b, n);
    return b + n;
}

void maglev_serialize(const MaglevPlant *m, const MaglevTag *tag, unsigned char *buf) {
    unsigned char *b = buf;
    unsigned int version = SER_VERSION, np = MAGLEV_NPARAMS;
    unsigned long long hl = m->hist.len;
    int contact = m->contact, initialized = m->initialized;
    double st[SER_NSTATE] = {m->time, m->u, m->x, m->v, m->i, m->F, m->xs, m->F2};
    b = put(b, SER_MAGIC, 4);
    b = put(b, &version, 4);
    b = put(b, &np, 4);
    b = put(b, &hl, 8);
    b = put(b, &tag->code, 4);
    b = put(b, &initialized, 4);
    b = put(b, m->p, sizeof m->p);
    b = put(b, st, sizeof st);
    b = put(b, tag->value, sizeof tag->value);
    b = put(b, &contact, 4);
    b = put(b, &tag->flags, 4);
    for (size_t k = 0; k < m->hist.len; k++) {
        b = put(b, &m->hist.t[k], 8);
        b = put(b, &m->hist.u[k], 8);
    }
    unsigned long long sum = maglev_checksum(buf, (size_t)(b - buf));
    put(b, &sum, 8);
}

int maglev_deserialize(MaglevPlant *m, MaglevTag *tag, const unsigned char *buf, size_t size,
                       const MaglevAllocator *a, char *msg, size_t len) {
    if (!buf) return fail(msg, len, "serialized state is NULL");
    if (size < ser_header() + 8) return fail(msg, len, "serialized state too short (%zu bytes)", size);
    unsigned int version, np, tg;
    MaglevTag tg_read;
    unsigned long long hl, sum;
    int initialized;
    const unsigned char *b = buf;
    if (memcmp(b, SER_MAGIC, 4) != 0) return fail(msg, len, "serialized state has a wrong magic number");
    b = get(b + 4, &version, 4);
    b = get(b, &np, 4);
    b = get(b, &hl, 8);
    b = get(b, &tg, 4);
    b = get(b, &initialized, 4);
    if (version != SER_VERSION) return fail(msg, len, "serialized state has version %u, expected %u", version, SER_VERSION);
    if (np != MAGLEV_NPARAMS) return fail(msg, len, "serialized state has %u parameters, expected %d", np, MAGLEV_NPARAMS);
    if (hl > (size - ser_header()) / 16) return fail(msg, len, "serialized state truncated (history of %llu entries)", hl);
    MaglevPlant tmp;
    memset(&tmp, 0, sizeof tmp);
    tmp.hist.len = (size_t)hl;
    size_t need = maglev_serialized_size(&tmp);
    if (size != need) return fail(msg, len, "serialized state has %zu bytes, expected %zu (truncated or padded)", size, need);
    get(buf + size - 8, &sum, 8);
    if (sum != maglev_checksum(buf, size - 8)) return fail(msg, len, "serialized state is corrupted (checksum mismatch)");
    if (initialized != 0 && initialized != 1) return fail(msg, len, "serialized state has an invalid initialized flag");
    double st[SER_NSTATE];
    b = get(b, tmp.p, sizeof tmp.p);
    b = get(b, st, sizeof st);
    b = get(b, tg_read.value, sizeof tg_read.value);
    b = get(b, &tmp.contact, 4);
    b = get(b, &tg_read.flags, 4);
    tg_read.code = tg;
    tmp.time = st[0]; tmp.u = st[1]; tmp.x = st[2]; tmp.v = st[3]; tmp.i = st[4]; tmp.F = st[5]; tmp.xs = st[6]; tmp.F2 = st[7];
    tmp.initialized = initialized;
    tmp.hist.len = 0;
    if (hl) {
        tmp.hist.t = a->alloc((size_t)hl, sizeof(double), a->env);
        tmp.hist.u = a->alloc((size_t)hl, sizeof(double), a->env);
        if (!tmp.hist.t || !tmp.hist.u) {
            maglev_release(&tmp, a);
            return fail(msg, len, "out of memory while restoring the input history");
        }
        for (size_t k = 0; k < hl; k++) {
            b = get(b, &tmp.hist.t[k], 8);
            b = get(b, &tmp.hist.u[k], 8);
        }
        tmp.hist.len = tmp.hist.cap = (size_t)hl;
    }
    char why[MAGLEV_MSG_LEN];
    if (maglev_check_plant(&tmp, why, sizeof why)) {
        maglev_release(&tmp, a);
        return fail(msg, len, "serialized state holds values the plant cannot have: %s", why);
    }
    maglev_release(m, a);
    *m = tmp;
    *tag = tg_read;
    return 0;
}
#endif /* MAGLEV_VARIABLES_ONLY */
