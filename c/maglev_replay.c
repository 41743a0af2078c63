/* Closed-loop replay (maglev_replay.h). */
#include "maglev_replay.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "maglev_plant.h"

int maglev_replay_nparams(void) { return MAGLEV_NPARAMS; }

const char *maglev_replay_param_name(int k) {
    if (k < 0 || k >= MAGLEV_NPARAMS) return NULL;
    return maglev_variables[MAGLEV_FIRST_PARAM + k].name;
}

double maglev_replay_param_default(int k) {
    if (k < 0 || k >= MAGLEV_NPARAMS) return NAN;
    return maglev_variables[MAGLEV_FIRST_PARAM + k].start;
}

static const MaglevVariable *param_row(int k) {
    return k >= 0 && k < MAGLEV_NPARAMS ? &maglev_variables[MAGLEV_FIRST_PARAM + k] : NULL;
}

double maglev_replay_param_min(int k) { return param_row(k) ? param_row(k)->min : NAN; }
double maglev_replay_param_max(int k) { return param_row(k) ? param_row(k)->max : NAN; }
const char *maglev_replay_param_unit(int k) { return param_row(k) ? param_row(k)->unit : NULL; }
const char *maglev_replay_param_effect(int k) { return param_row(k) ? param_row(k)->effect : NULL; }

static int load(MaglevPlant *m, const double *params, char *msg, size_t len) {
    maglev_defaults(m);
    for (int k = 0; k < MAGLEV_NPARAMS; k++) {
        if (maglev_check_value((MaglevVR)(MAGLEV_FIRST_PARAM + k), params[k], msg, len)) return -1;
        maglev_set_param(m, (MaglevVR)(MAGLEV_FIRST_PARAM + k), params[k]);
    }
    return 0;
}

/* The plant of a parameter vector, each value and the set checked: what every entry point starts from
 * (loaded once into the caller's plant, not checked on a copy and loaded again). */
static int checked(MaglevPlant *m, const double *params, char *msg, size_t len) {
    if (load(m, params, msg, len)) return -1;
    return maglev_check_params(m, msg, len);
}

int maglev_replay_check_params(const double *params, char *msg, size_t len) {
    MaglevPlant m;
    return checked(&m, params, msg, len);
}

int maglev_replay_point(const double *params, double x, double i, MaglevPoint *out, char *msg, size_t len) {
    MaglevPlant m;
    if (checked(&m, params, msg, len)) return -1;
    if (!isfinite(x)) {
        snprintf(msg, len, "position x = %g m is not finite", x);
        return -1;
    }
    if (isnan(i)) i = maglev_equilibrium_current(&m, x);
    double dv_dx;
    out->x = x;
    out->i = i;
    out->u = maglev_input_for_current(&m, i);
    out->F = maglev_force(&m, i, x, &out->dF_dx, &out->dF_di);
    maglev_sensor_volts(&m, x, &dv_dx);
    out->dy_dx = maglev_param(&m, VR_k_AD) * dv_dx;
    out->y = maglev_reading(&m, x, 0.0);
    return 0;
}

/* Positions [m] handed in by the caller: every one finite, else an error naming the first that is not. */
static int finite_positions(const double *x, size_t n, char *msg, size_t len) {
    for (size_t k = 0; k < n; k++) {
        if (!isfinite(x[k])) {
            snprintf(msg, len, "position x = %g m is not finite", x[k]);
            return -1;
        }
    }
    return 0;
}

int maglev_replay_forces(const double *params, const double *x, const double *i, size_t n, double *F, char *msg,
                         size_t len) {
    MaglevPlant m;
    if (checked(&m, params, msg, len)) return -1;
    if (finite_positions(x, n, msg, len)) return -1;
    for (size_t k = 0; k < n; k++)
        F[k] = maglev_force(&m, isnan(i[k]) ? maglev_equilibrium_current(&m, x[k]) : i[k], x[k], NULL, NULL);
    return 0;
}

int maglev_replay_readings(const double *params, const double *x, size_t n, double t, double *y, char *msg,
                           size_t len) {
    MaglevPlant m;
    if (checked(&m, params, msg, len)) return -1;
    if (finite_positions(x, n, msg, len)) return -1;
    for (size_t k = 0; k < n; k++) y[k] = maglev_reading(&m, x[k], t);
    return 0;
}

int maglev_replay_positions(const double *params, const double *y, size_t n, double t, double *x, char *msg,
                            size_t len) {
    MaglevPlant m;
    if (checked(&m, params, msg, len)) return -1;
    for (size_t k = 0; k < n; k++) {
        if (!isfinite(y[k])) {
            snprintf(msg, len, "reading y[%zu] = %g is not finite", k, y[k]);
            return -1;
        }
        x[k] = maglev_position_for_reading(&m, y[k], t);
    }
    return 0;
}

static int setup(MaglevPlant *m, const double *params, double u0, char *msg, size_t len) {
    if (load(m, params, msg, len)) return -1;
    if (!isfinite(u0)) {
        snprintf(msg, len, "initial input u_hold %g is not finite", u0);
        return -1;
    }
    return maglev_initialize(m, 0.0, u0, &maglev_std_allocator, msg, len);
}

static void sample(const MaglevPlant *m, size_t k, double *y, double *x, double *v, double *i, double *yk) {
    *yk = maglev_get(m, VR_y);
    if (y) y[k] = *yk;
    if (x) x[k] = m->x;
    if (v) v[k] = m->v;
    if (i) i[k] = maglev_get(m, VR_i);
}

int maglev_pid_check(const MaglevPid *pid, char *msg, size_t len) {
    const char *bad = NULL;
    if (!pid) bad = "the PID settings are missing";
    else if (!(pid->ts > 0) || !isfinite(pid->ts)) bad = "ts must be > 0 and finite";
    else if (!isfinite(pid->kp) || !isfinite(pid->ki) || !isfinite(pid->kd)) bad = "kp, ki and kd must be finite";
    else if (!isfinite(pid->u_min) || !isfinite(pid->u_max) || !(pid->u_min < pid->u_max))
        bad = "u_min < u_max must hold, both finite";
    else if (!(pid->tf >= 0) || !isfinite(pid->tf)) bad = "tf must be >= 0 and finite";
    else if (pid->anti_windup < 0 || pid->anti_windup > 3) bad = "anti_windup must be 0, 1, 2 or 3";
    else if (pid->anti_windup == 3 && !(isfinite(pid->i_lo) && isfinite(pid->i_hi) && pid->i_lo < pid->i_hi))
        bad = "the band needs i_lo < i_hi, both finite (anti_windup 3)";
    else if (pid->anti_windup == 3 && !(pid->backoff > 0 && pid->backoff <= 1))
        bad = "the band needs 0 < backoff <= 1 (anti_windup 3)";
    else if (pid->d_on_y != 0 && pid->d_on_y != 1) bad = "d_on_y must be 0 (derivative of the error) or 1 (of -y)";
    if (!bad) return 0;
    snprintf(msg, len, "PID: %s", bad);
    return -1;
}

static int pid_valid(const MaglevPid *pid) {
    char msg[8];
    return maglev_pid_check(pid, msg, sizeof msg) == 0;
}

/* One sample of the PID (maglev_replay.h), the one difference equation of the C side. */
double maglev_pid_step(const MaglevPid *pid, MaglevPidState *s, double w, double y) {
    double e = w - y;
    double integ = s->integral + pid->ki * pid->ts * e;
    if (pid->anti_windup == 3 && !(pid->i_lo < s->integral && s->integral < pid->i_hi)) {
        double lo = pid->backoff * pid->i_lo, hi = pid->backoff * pid->i_hi;
        integ = s->integral < lo ? lo : (s->integral > hi ? hi : s->integral);
    }
    double de = pid->d_on_y ? -y : e; /* the derivative's argument */
    double d = pid->tf > 0 ? (pid->tf * s->d_prev + pid->kd * (de - s->e_prev)) / (pid->tf + pid->ts)
                           : pid->kd * (de - s->e_prev) / pid->ts;
    double raw = pid->kp * e + integ + d;
    double uk = raw < pid->u_min ? pid->u_min : (raw > pid->u_max ? pid->u_max : raw);
    if (pid->anti_windup == 1 && uk != raw && (raw - uk) * e > 0) integ = s->integral;
    if (pid->anti_windup == 2) integ = integ < pid->u_min ? pid->u_min : (integ > pid->u_max ? pid->u_max : integ);
    s->integral = integ;
    s->e_prev = de;
    s->d_prev = d;
    return uk;
}

/* ---- the controllers (maglev_replay.h) ---- */

typedef struct {
    MaglevPidState outer, inner;
    double xh[3], q;
} CtlState;

static int finite_all(const double *a, int n) {
    for (int k = 0; k < n; k++)
        if (!isfinite(a[k])) return 0;
    return 1;
}

static int ctl_check(const MaglevController *c, double u_hold, char *msg, size_t len) {
    if (!c || c->kind < 0 || c->kind > 2) {
        snprintf(msg, len, "controller kind must be 0 (PID), 1 (cascade) or 2 (state feedback)");
        return -1;
    }
    if (!pid_valid(&c->pid) || (c->kind == 1 && (!pid_valid(&c->inner) || c->inner.ts != c->pid.ts))) {
        snprintf(msg, len, "invalid %s settings (ts > 0, finite gains and limits, u_min < u_max, tf >= 0, "
                 "anti_windup 0 to 3, a band i_lo < i_hi with 0 < backoff <= 1%s)", c->kind == 1 ? "cascade" : (c->kind == 2 ? "state-feedback" : "PID"),
                 c->kind == 1 ? ", both loops at one ts" : "");
        return -1;
    }
    if (c->kind == 2 && (!finite_all(&c->Phi[0][0], 9) || !finite_all(c->Gam, 3) || !finite_all(&c->C[0][0], 6) ||
                         !finite_all(&c->L[0][0], 6) || !finite_all(c->K, 3) || !finite_all(c->x_eq, 3) ||
                         !isfinite(c->k_w) || !isfinite(c->k_int) || !isfinite(c->u_eq) || !isfinite(c->y_eq) ||
                         !isfinite(c->i_eq) || c->pid.anti_windup > 1)) {
        snprintf(msg, len, "invalid state-feedback settings (finite matrices and operating point, anti_windup 0 or 1)");
        return -1;
    }
    if (!isfinite(u_hold)) {
        snprintf(msg, len, "initial input u_hold %g is not finite", u_hold);
        return -1;
    }
    if ((c->from_reading != 0 && c->from_reading != 1) || (c->from_reading && !isfinite(c->y_before))) {
        snprintf(msg, len, "controller start: from_reading = %d must be 0 or 1, and y_before = %g finite with 1",
                 c->from_reading, c->y_before);
        return -1;
    }
    return 0;
}

static double sf_raw(const MaglevController *c, const CtlState *s, double w) {
    return c->u_eq + c->k_w * (w - c->y_eq) - c->K[0] * s->xh[0] - c->K[1] * s->xh[1] - c->K[2] * s->xh[2] -
           c->k_int * s->q;
}

/* Settled start (maglev_replay.h): x0 is the plant's state (x, v, i), w0 the first reference.
 * From a reading (from_reading): the loop was at rest before t = 0 with the reading at y_before,
 * the error e_b = w0 - y_before standing and the PID's output holding the plant, so its integrator
 * is the holding output less the proportional part and its derivative's argument is e_b (or
 * -y_before), without a kick. A record cut from a running loop reads away from its reference while
 * the integrator still creeps (project emulator, seed 7701, 0.1 s after a step: e_b = 0.012 MU);
 * started at zero error, the replay's first sample kicked the output by kd*e_b/ts and its
 * integrator sat kp*e_b off the rig's. */
static void ctl_start(const MaglevController *c, CtlState *s, double u_hold, const double x0[3], double w0) {
    memset(s, 0, sizeof *s);
    const int from = c->kind != 2 && c->from_reading;
    const double e_b = from ? w0 - c->y_before : 0.0;
    s->outer.integral = (c->kind == 1 ? x0[2] : u_hold) - (from ? c->pid.kp * e_b : 0.0);
    s->inner.integral = u_hold;
    /* a derivative of -y starts settled at the reading before (outer) and the start current (inner) */
    s->outer.e_prev = c->pid.d_on_y ? -(from ? c->y_before : w0) : e_b;
    s->inner.e_prev = c->kind == 1 && c->inner.d_on_y ? -x0[2] : 0.0;
    if (c->kind == 2) {
        for (int j = 0; j < 3; j++) s->xh[j] = x0[j] - c->x_eq[j];
        s->q = c->k_int != 0 ? (sf_raw(c, s, w0) - u_hold) / c->k_int : 0.0;
    }
}

static double ctl_step(const MaglevController *c, CtlState *s, double w, double y, double i) {
    if (c->kind == 0) return maglev_pid_step(&c->pid, &s->outer, w, y);
    if (c->kind == 1) return maglev_pid_step(&c->inner, &s->inner, maglev_pid_step(&c->pid, &s->outer, w, y), i);
    const double meas[2] = {y - c->y_eq, i - c->i_eq};
    double e[2];
    for (int r = 0; r < 2; r++) e[r] = meas[r] - (c->C[r][0] * s->xh[0] + c->C[r][1] * s->xh[1] + c->C[r][2] * s->xh[2]);
    for (int j = 0; j < 3; j++) s->xh[j] += c->L[j][0] * e[0] + c->L[j][1] * e[1];
    double raw = sf_raw(c, s, w);
    double uk = raw < c->pid.u_min ? c->pid.u_min : (raw > c->pid.u_max ? c->pid.u_max : raw);
    double dq = c->pid.ts * (w - y);
    if (!(c->pid.anti_windup == 1 && uk != raw && (raw - uk) * (-c->k_int * dq) > 0)) s->q += dq;
    double xn[3];
    for (int j = 0; j < 3; j++)
        xn[j] = c->Phi[j][0] * s->xh[0] + c->Phi[j][1] * s->xh[1] + c->Phi[j][2] * s->xh[2] + c->Gam[j] * (uk - c->u_eq);
    memcpy(s->xh, xn, sizeof xn);
    return uk;
}

int maglev_replay_control(const MaglevController *c, const double *w, const double *y, const double *i, size_t n,
                          double u_hold, const double *x0, double *u, char *msg, size_t len) {
    if (ctl_check(c, u_hold, msg, len)) return -1;
    if (c->kind != 0 && (!i || !x0 || !finite_all(x0, 3))) {
        snprintf(msg, len, "a cascade or state feedback needs the measured current and a finite start state");
        return -1;
    }
    const double zero[3] = {0, 0, 0};
    CtlState s;
    ctl_start(c, &s, u_hold, x0 ? x0 : zero, n ? w[0] : 0.0);
    for (size_t k = 0; k < n; k++) {
        if (!isfinite(w[k]) || !isfinite(y[k]) || (i && !isfinite(i[k]))) {
            snprintf(msg, len, "sample %zu: w, y or the current is not finite", k);
            return -1;
        }
        u[k] = ctl_step(c, &s, w[k], y[k], i ? i[k] : 0.0);
    }
    return 0;
}

int maglev_replay_open_loop(const double *params, const double *u_in, size_t n, double ts, double *y,
                            double *x, double *v, double *i, char *msg, size_t len) {
    MaglevPlant m;
    if (!(ts > 0) || !isfinite(ts)) {
        snprintf(msg, len, "sample time ts = %g must be > 0", ts);
        return -1;
    }
    if (n == 0) return 0;
    if (setup(&m, params, u_in[0], msg, len)) {
        maglev_release(&m, &maglev_std_allocator);
        return -1;
    }
    int rc = 0;
    double t = 0.0;
    for (size_t k = 0; k < n; k++) {
        double yk;
        sample(&m, k, y, x, v, i, &yk);
        m.time = t;
        if (maglev_set_input(&m, u_in[k], &maglev_std_allocator, msg, len) ||
            maglev_step(&m, ts, &maglev_std_allocator, msg, len)) {
            rc = -1;
            break;
        }
        t += ts;
    }
    maglev_release(&m, &maglev_std_allocator);
    return rc;
}

/* ---- prediction-error replay: the extended Kalman filter (maglev_replay.h) ---- */

#define NS 8 /* x, v, i, F, d, xs (the position the sensor sees), c (the coloured sensor noise), F2 (the second
                force lag's slow part, eddy_lag) */
#define JAC_EVERY 10 /* also maglev_cosim.plant.fast.JAC_EVERY: a replay of a record's later part keeps this grid */

/* P = M P M' (the time update, M the step's Jacobian) over the active states idx[0..na) (ascending)
 * alone: the other rows and columns of P are zero (the filter keeps them so), so the terms skipped are
 * exact zeros, and each entry's products are summed in the order of the full product: the active block
 * is the same as the full product's, to the bit. The inactive rows and columns are left as they are,
 * and M's are not read. Every loop runs over the active states alone: with the columns
 * of all NS states, the filter took 5.6 ms on a 12 s record, against 5.3 ms (the innovations, the
 * 20 ms predictions and u's, the same to the bit on three models with lags and coloured noise). */
static void sandwich(double M[NS][NS], double P[NS][NS], const int *idx, int na) { /* M is only read */
    /* the active blocks of M and P gathered into dense arrays first: the products then read
     * contiguous rows (with the scattered reads, this function was a quarter of a filter pass of an
     * Inteco record under perf; the sums run in the same order, so the result is the same) */
    double Mc[NS][NS], Pc[NS][NS], MP[NS][NS];
    for (int a = 0; a < na; a++)
        for (int c = 0; c < na; c++) {
            Mc[a][c] = M[idx[a]][idx[c]];
            Pc[a][c] = P[idx[a]][idx[c]];
        }
    for (int a = 0; a < na; a++)
        for (int c = 0; c < na; c++) {
            double sum = 0.0;
            for (int b = 0; b < na; b++) sum += Mc[a][b] * Pc[b][c];
            MP[a][c] = sum;
        }
    for (int a = 0; a < na; a++)
        for (int c = 0; c < na; c++) {
            double sum = 0.0;
            for (int b = 0; b < na; b++) sum += MP[a][b] * Mc[c][b];
            P[idx[a]][idx[c]] = sum;
        }
}

static void get_state(const MaglevPlant *m, double d, double c, double s[NS]) {
    s[0] = m->x;
    s[1] = m->v;
    s[2] = m->i;
    s[3] = m->F;
    s[4] = d;
    s[5] = m->xs;
    s[6] = c;
    s[7] = m->F2;
}

/* Puts a filtered state into the plant: the ball between the stops and free (the plant finds an
 * impact again if it presses on a stop), the current within the amplifier's range. */
static void put_state(MaglevPlant *m, const double s[NS]) {
    double lo = maglev_param(m, VR_x_min), hi = maglev_param(m, VR_x_max);
    m->x = s[0] < lo ? lo : (s[0] > hi ? hi : s[0]);
    m->xs = maglev_param(m, VR_T_y) > 0 ? (s[5] < lo ? lo : (s[5] > hi ? hi : s[5])) : m->x;
    m->v = s[1];
    if (maglev_param(m, VR_T_a) > 0 || maglev_param(m, VR_R_c) > 0) {
        double imax = maglev_param(m, VR_i_max);
        m->i = s[2] < 0 ? 0 : (s[2] > imax ? imax : s[2]);
    }
    if (maglev_param(m, VR_T_F) > 0) m->F = s[3];
    if (maglev_param(m, VR_beta_F) > 0) m->F2 = s[7];
    m->contact = CONTACT_NONE;
}

/* A copy of the plant into a scratch plant that keeps its history buffers (maglev_copy_into): the
 * filter copies the plant several times a sample, and allocating each copy's history was a tenth of it */
static int reuse_plant(MaglevPlant *dst, const MaglevPlant *src, char *msg, size_t len) {
    if (maglev_copy_into(dst, src, &maglev_std_allocator) == 0) return 0;
    snprintf(msg, len, "out of memory in the prediction-error replay");
    return -1;
}

/* One sample of the model, in place, with input u and disturbance force d held over it: the
 * plant step, then d's effect on the ball (exact for a force held constant: it adds linearly to
 * the mechanics, whatever the plant does). */
double maglev_correction_force(const MaglevCorrection *c, double x, double v) {
    if (!c || c->n_x <= 0) return 0.0;
    double xi = (x - c->x_c) / c->x_s;
    xi = xi < -1.5 ? -1.5 : (xi > 1.5 ? 1.5 : xi);
    const double b[3] = {1.0, v / c->v_s, tanh(v / c->v_c)};
    double p0 = 1.0, p1 = xi, f = 0.0;
    for (int j = 0; j < c->n_x; j++) {
        double pj = j == 0 ? 1.0 : (j == 1 ? xi : ((2.0 * j - 1.0) * xi * p1 - (j - 1.0) * p0) / j);
        if (j >= 2) {
            p0 = p1;
            p1 = pj;
        }
        f += pj * (c->coef[3 * j] * b[0] + c->coef[3 * j + 1] * b[1] + c->coef[3 * j + 2] * b[2]);
    }
    return f;
}

static int correction_check(const MaglevCorrection *c, char *msg, size_t len) {
    if (!c || c->n_x == 0) return 0;
    int ok = c->n_x > 0 && c->n_x <= 4 && isfinite(c->x_c) && c->x_s > 0 && isfinite(c->x_s) && c->v_s > 0 &&
             isfinite(c->v_s) && c->v_c > 0 && isfinite(c->v_c);
    for (int k = 0; ok && k < 3 * c->n_x; k++) ok = isfinite(c->coef[k]);
    if (!ok) {
        snprintf(msg, len, "invalid correction (n_x 0 to 4, x_s, v_s, v_c > 0, finite coefficients)");
        return -1;
    }
    return 0;
}

static int advance(MaglevPlant *m, double u, double d, double ts, char *msg, size_t len) {
    if (maglev_set_input(m, u, &maglev_std_allocator, msg, len) || maglev_step(m, ts, &maglev_std_allocator, msg, len))
        return -1;
    if (d != 0.0) {
        double acc = d / maglev_param(m, VR_m_k);
        m->contact = CONTACT_NONE;
        m->x += 0.5 * acc * ts * ts;
        m->v += acc * ts;
        double lo = maglev_param(m, VR_x_min), hi = maglev_param(m, VR_x_max);
        if (m->x < lo) { m->x = lo; m->v = 0; }
        if (m->x > hi) { m->x = hi; m->v = 0; }
        if (!(maglev_param(m, VR_T_y) > 0)) m->xs = m->x; /* a lag's xs moves with x in the next steps */
    }
    return 0;
}

int maglev_replay_closed_loop_injected(const double *params, const MaglevController *c, const double *w, size_t n,
                                       double u_hold, const double *du, const double *dF, const double *dy,
                                       double y_step, double u_step, double *u, double *y, double *x, double *v,
                                       double *i, char *msg, size_t len) {
    MaglevPlant m;
    if (ctl_check(c, u_hold, msg, len)) return -1;
    if (!(y_step >= 0 && isfinite(y_step)) || !(u_step >= 0 && isfinite(u_step))) {
        snprintf(msg, len, "converter steps y_step = %g, u_step = %g MU must be >= 0 and finite", y_step, u_step);
        return -1;
    }
    for (size_t k = 0; k < n; k++)
        if ((du && !isfinite(du[k])) || (dF && !isfinite(dF[k])) || (dy && !isfinite(dy[k]))) {
            snprintf(msg, len, "sample %zu: an injected signal (du, dF or dy) is not finite", k);
            return -1;
        }
    if (setup(&m, params, u_hold, msg, len)) {
        maglev_release(&m, &maglev_std_allocator);
        return -1;
    }
    const double x0[3] = {m.x, m.v, maglev_get(&m, VR_i)};
    CtlState cs;
    ctl_start(c, &cs, u_hold, x0, n ? w[0] : 0.0);
    double t = 0.0;
    int rc = 0;
    for (size_t k = 0; k < n; k++) {
        if (!isfinite(w[k])) {
            snprintf(msg, len, "reference w[%zu] = %g is not finite", k, w[k]);
            rc = -1;
            break;
        }
        /* the reading and the current once a sample: the record's columns and the controller's inputs
         * (a PID reads no current) */
        double yk = maglev_get(&m, VR_y), ik = (i || c->kind != 0) ? maglev_get(&m, VR_i) : 0.0;
        if (y) y[k] = yk;
        if (x) x[k] = m.x;
        if (v) v[k] = m.v;
        if (i) i[k] = ik;
        if (dy || y_step > 0) {
            if (dy) yk += dy[k];
            if (y_step > 0) yk = y_step * round(yk / y_step);
            if (y) y[k] = yk;
        }
        double uk = ctl_step(c, &cs, w[k], yk, ik);
        if (u_step > 0) uk = u_step * round(uk / u_step);
        if (u) u[k] = uk;
        /* the FMU's clock: the master adds ts to the previous communication point */
        m.time = t;
        if (advance(&m, du ? uk + du[k] : uk, dF ? dF[k] : 0.0, c->pid.ts, msg, len)) {
            rc = -1;
            break;
        }
        t += c->pid.ts;
    }
    maglev_release(&m, &maglev_std_allocator);
    return rc;
}

int maglev_replay_closed_loop(const double *params, const MaglevController *c, const double *w, size_t n,
                              double u_hold, double *u, double *y, double *x, double *v, double *i,
                              char *msg, size_t len) {
    return maglev_replay_closed_loop_injected(params, c, w, n, u_hold, NULL, NULL, NULL, 0.0, 0.0, u, y, x, v, i, msg,
                                              len);
}

/* The Kalman update with one scalar measurement whose row of H has the entry h at state j and, when
 * h2 != 0, the entry h2 at state j2 (the coloured sensor noise): gain, state (put back into the
 * plant, d and c beside it), and the covariance in Joseph form, P = (I - K H) P (I - K H)' + K r2 K', over the
 * active states idx[0..na) (an inactive state's gain is zero, as its rows and columns of P are). */
static void scalar_update(MaglevPlant *m, double *d, double *c, double P[NS][NS], const int *idx, int na, int j,
                          double h, int j2, double h2, double e, double r2) {
    double S = h * h * P[j][j] + 2.0 * h * h2 * P[j][j2] + h2 * h2 * P[j2][j2] + r2, K[NS], s[NS];
    for (int i = 0; i < NS; i++) K[i] = (P[i][j] * h + P[i][j2] * h2) / S;
    get_state(m, *d, *c, s);
    for (int i = 0; i < NS; i++) s[i] += K[i] * e;
    put_state(m, s);
    *d = s[4];
    *c = s[6];
    /* the Joseph form P = (I - K H) P (I - K H)' + K r2 K' as its two rank-one products, in
     * O(na^2): M = (I - K H) P (rows: P minus K times H P), then M (I - K H)' (columns likewise).
     * The factors are multiplied out, not expanded: the algebraically equal P - K PH' - PH K' + S K K'
     * moved an Inteco record's predictions by 70 %; this moves them by rounding (2e-9 of their
     * largest value) against the dense sandwich of I - K H it replaces (a filter pass 31 -> 18-26 ms). */
    double HP[NS], MH[NS];
    for (int l = 0; l < NS; l++) HP[l] = h * P[j][l] + h2 * P[j2][l];
    for (int a = 0; a < na; a++)
        for (int b = 0; b < na; b++) {
            int i = idx[a], l = idx[b];
            P[i][l] -= K[i] * HP[l];
        }
    for (int i = 0; i < NS; i++) MH[i] = P[i][j] * h + P[i][j2] * h2;
    for (int a = 0; a < na; a++)
        for (int b = 0; b < na; b++) {
            int i = idx[a], l = idx[b];
            P[i][l] += -MH[i] * K[l] + K[i] * r2 * K[l];
        }
}

static int filter_check(const MaglevFilter *f, char *msg, size_t len) {
    if (!f || !(f->q_force > 0) || !isfinite(f->q_force) || !(f->f_force > 0) || !isfinite(f->f_force) ||
        !(f->r_sensor > 0) || !isfinite(f->r_sensor) || f->horizon < 0 || f->stride < 1 || f->offset < 0 ||
        f->offset >= f->stride || (f->coil_free != 0 && f->coil_free != 1)) {
        snprintf(msg, len, "invalid filter settings (q_force > 0 N, f_force > 0 Hz, r_sensor > 0 MU, "
                 "horizon >= 0, stride >= 1, 0 <= offset < stride, coil_free 0 or 1)");
        return -1;
    }
    if (!(f->f_sensor >= 0) || !isfinite(f->f_sensor)) {
        snprintf(msg, len, "invalid filter settings: f_sensor = %g Hz must be >= 0 and finite (0: white sensor noise)",
                 f->f_sensor);
        return -1;
    }
    if (f->f_sensor > 0 && (!(f->r_coloured > 0) || !isfinite(f->r_coloured))) {
        snprintf(msg, len, "invalid filter settings: r_coloured = %g MU must be > 0 and finite when f_sensor > 0",
                 f->r_coloured);
        return -1;
    }
    return 0;
}

/* The filter of both entry points: with a PID (closed-loop predictions) or without (pid NULL: the
 * predictions are driven by the measured input), and with an optional measured current. */
static int predict(const double *params, const MaglevController *ctl, const MaglevCorrection *corr, double ts,
                   const MaglevFilter *f, const double *w,
                   const double *y, const double *u, const double *i_meas, double r_current, size_t n,
                   double u_hold, int n_h, const int *horizons, const unsigned char *starts, double *y_pred,
                   double *u_pred, double *i_pred, double *innov, double *innov_var, double *d_est, double *d_sd,
                   char *msg, size_t len) {
    /* the plant (*pm), and scratch copies: the step (*pn), its Jacobian's, a prediction's. The step is taken
     * on *pn and the two pointers swapped: copying the 784-byte plants back (m = nom) was half of this
     * function's own time under perf */
    MaglevPlant plants[2], pert, cur, *pm = &plants[0], *pn = &plants[1];
    memset(&pn->hist, 0, sizeof pn->hist);
    memset(&pert.hist, 0, sizeof pert.hist);
    memset(&cur.hist, 0, sizeof cur.hist);
    if ((ctl && ctl_check(ctl, u_hold, msg, len)) || filter_check(f, msg, len) || correction_check(corr, msg, len))
        return -1;
    /* the horizons: one trajectory from each stride-th sample to the longest, read at each */
    int h_max = 0;
    if (n_h < 1 || n_h > MAGLEV_MAX_HORIZONS || !horizons) {
        snprintf(msg, len, "between 1 and %d horizons needed, got %d", MAGLEV_MAX_HORIZONS, n_h);
        return -1;
    }
    for (int q = 0; q < n_h; q++) {
        if (horizons[q] < 0 || (n_h > 1 && horizons[q] < 1)) {
            snprintf(msg, len, "horizon %d must be >= 1 (or a single horizon 0: filter only)", horizons[q]);
            return -1;
        }
        if (horizons[q] > h_max) h_max = horizons[q];
    }
    if (!ctl && (!(ts > 0) || !isfinite(ts) || !isfinite(u_hold))) {
        snprintf(msg, len, "sample time %g s must be > 0 and the initial input finite", ts);
        return -1;
    }
    if (i_meas && (!(r_current > 0) || !isfinite(r_current))) {
        snprintf(msg, len, "the current's noise RMS r_current must be > 0 A, got %g", r_current);
        return -1;
    }
    for (size_t k = 0; k < n; k++) {
        if ((ctl && !isfinite(w[k])) || !isfinite(y[k]) || !isfinite(u[k]) || (i_meas && !isfinite(i_meas[k]))) {
            snprintf(msg, len, "sample %zu: a measured signal (w, y, u or the current) is not finite", k);
            return -1;
        }
        for (int q = 0; q < n_h; q++) {
            if (y_pred) y_pred[(size_t)q * n + k] = NAN;
            if (u_pred) u_pred[(size_t)q * n + k] = NAN;
            if (i_pred) i_pred[(size_t)q * n + k] = NAN;
        }
        if (innov) innov[k] = NAN;
        if (innov_var) innov_var[k] = NAN;
        if (d_est) d_est[k] = NAN;
        if (d_sd) d_sd[k] = NAN;
    }
    if (setup(pm, params, u_hold, msg, len)) {
        maglev_release(pm, &maglev_std_allocator);
        return -1;
    }
    const double mk = maglev_param(pm, VR_m_k), mg = mk * maglev_param(pm, VR_g);
    const double a = exp(-6.283185307179586 * f->f_force * ts), r2 = f->r_sensor * f->r_sensor;
    const int current_state = maglev_param(pm, VR_T_a) > 0 || maglev_param(pm, VR_R_c) > 0;
    const int sensor_lag = maglev_param(pm, VR_T_y) > 0, ys = sensor_lag ? 5 : 0; /* the state y reads */
    const int drive_by_current = !ctl && i_meas && current_state && f->current_input;
    /* the coil's free run (coil_free): the current takes no part in the reading's updates */
    const int coil_free = !i_meas && current_state && f->coil_free;
    const int coloured = f->f_sensor > 0;
    const double b = coloured ? exp(-6.283185307179586 * f->f_sensor * ts) : 0.0;
    const double rc2 = coloured ? f->r_coloured * f->r_coloured : 0.0;
    const int active[NS] = {1, 1, current_state, maglev_param(pm, VR_T_F) > 0, 1, sensor_lag, coloured,
                            maglev_param(pm, VR_beta_F) > 0};
    int idx[NS], na = 0; /* the active states: the covariance's products run over them alone */
    for (int j = 0; j < NS; j++)
        if (active[j]) idx[na++] = j;
    const double delta[NS] = {1e-7, 1e-5, 1e-6, 1e-6 * mg, 1e-6 * mg, 1e-7, 0, 1e-6 * mg};
    /* process noise besides d's and c's own: tiny, to keep the lags' covariance well conditioned */
    const double q_extra[NS] = {0, 0, 1e-8, 1e-12 * mg * mg, 0, 1e-16, 0, 1e-12 * mg * mg};
    double P[NS][NS] = {{0}};
    double dv_dx;
    maglev_sensor_volts(pm, pm->x, &dv_dx);
    double slope = maglev_param(pm, VR_k_AD) * dv_dx;
    P[0][0] = r2 / (slope * slope) + 1e-10;
    P[1][1] = 1e-6;
    P[2][2] = active[2] ? 1e-4 : 0;
    P[3][3] = active[3] ? 1e-4 * mg * mg : 0;
    P[4][4] = f->q_force * f->q_force;
    P[5][5] = sensor_lag ? P[0][0] : 0;
    P[0][5] = P[5][0] = sensor_lag ? P[0][0] : 0; /* at the start the sensor has settled on x */
    P[6][6] = rc2;
    P[7][7] = active[7] ? 1e-4 * mg * mg : 0;
    double d = 0.0, c = 0.0, A[NS][NS] = {{0}};
    CtlState cs;
    if (ctl) {
        const double x0[3] = {pm->x, pm->v, maglev_get(pm, VR_i)};
        ctl_start(ctl, &cs, u_hold, x0, n ? w[0] : 0.0);
    }
    int rc = 0;
    for (size_t k = 0; k < n && rc == 0; k++) {
        pm->time = (double)k * ts;
        /* measurement update with y[k] */
        double yhat = maglev_get(pm, VR_y);
        if (fabs(yhat) < 1.0 && fabs(y[k]) < 1.0) {
            double h = 1e-7, H = (maglev_reading(pm, pm->xs + h, pm->time) - maglev_reading(pm, pm->xs - h, pm->time)) / (2 * h);
            double hc = coloured ? 1.0 : 0.0, e = y[k] - yhat - c;
            if (innov) innov[k] = e;
            if (innov_var) innov_var[k] = H * H * P[ys][ys] + 2.0 * H * hc * P[ys][6] + hc * hc * P[6][6] + r2;
            scalar_update(pm, &d, &c, P, idx, na, ys, H, 6, hc, e, r2);
        }
        /* measurement update with the measured current (a state of its own only with a lag or a
         * voltage drive; otherwise it is a function of the input and carries nothing new) */
        if (i_meas && active[2])
            scalar_update(pm, &d, &c, P, idx, na, 2, 1.0, 6, 0.0, i_meas[k] - pm->i, r_current * r_current);
        /* the random force after both updates: its trajectory is how a drift shows (a force the
         * mechanics lacks, or a gain that changes during the run) */
        if (d_est) d_est[k] = d;
        if (d_sd) d_sd[k] = sqrt(P[4][4]);
        /* the controller, on the measured reading (and current, or the filter's): its state for the
         * predictions */
        if (ctl) (void)ctl_step(ctl, &cs, w[k], y[k], i_meas ? i_meas[k] : maglev_get(pm, VR_i));
        /* prediction from here */
        /* (a single horizon predicts only from where it ends inside the record; several horizons
         * each end where the record allows, the same predictions as one call per horizon) */
        int h_run = h_max;
        if (n_h > 1 && k + (size_t)h_run >= n) h_run = (int)(n - 1 - k);
        if (h_run > 0 && k % (size_t)f->stride == (size_t)f->offset && (!starts || starts[k]) &&
            k + (size_t)h_run < n) {
            CtlState pp = cs;
            double dd = d, cc = c, uin = u[k], yj = 0.0;
            if (reuse_plant(&cur, pm, msg, len)) {
                rc = -1;
                break;
            }
            for (int j = 1; j <= h_run; j++) {
                cur.time = (double)(k + (size_t)j - 1) * ts;
                if (drive_by_current && j > 1) {
                    /* the measured current at the sample's start; the actuator signal still moves
                     * it within the sample (the coil's own dynamics) */
                    double imax = maglev_param(&cur, VR_i_max), ic = i_meas[k + (size_t)j - 1];
                    cur.i = ic < 0 ? 0 : (ic > imax ? imax : ic);
                }
                if (advance(&cur, uin, dd + maglev_correction_force(corr, cur.x, cur.v), ts, msg, len)) {
                    rc = -1;
                    break;
                }
                dd *= a;
                cc *= b;
                cur.time = (double)(k + (size_t)j) * ts;
                yj = maglev_get(&cur, VR_y) + cc;
                uin = ctl ? ctl_step(ctl, &pp, w[k + (size_t)j], yj, maglev_get(&cur, VR_i)) : u[k + (size_t)j];
                for (int q = 0; q < n_h; q++) {
                    if (horizons[q] != j) continue;
                    size_t at = (size_t)q * n + k + (size_t)j;
                    if (y_pred) y_pred[at] = yj;
                    if (u_pred && ctl) u_pred[at] = uin;
                    if (i_pred) i_pred[at] = maglev_get(&cur, VR_i);
                }
            }
            if (rc) break;
        }
        /* time update: the nominal step, and its Jacobian by finite differences; the Jacobian
         * changes slowly along a levitating record, so it is refreshed every JAC_EVERY samples
         * (and whenever the ball touches a stop), which makes the filter about three times cheaper */
        double s0[NS], s1[NS];
        get_state(pm, d, c, s0);
        if (reuse_plant(pn, pm, msg, len)) {
            rc = -1;
            break;
        }
        if (advance(pn, u[k], d + maglev_correction_force(corr, pm->x, pm->v), ts, msg, len)) {
            rc = -1;
            break;
        }
        get_state(pn, a * d, b * c, s1);
        int refresh = k % JAC_EVERY == 0 || pn->contact != CONTACT_NONE || pm->contact != CONTACT_NONE;
        for (int j = 0; j < NS && rc == 0 && refresh; j++) {
            if (!active[j]) continue;
            if (j == 4) { /* d enters the mechanics linearly (advance), and decays by a */
                A[0][4] = 0.5 * ts * ts / mk;
                A[1][4] = ts / mk;
                A[4][4] = a;
                continue;
            }
            if (j == 6) { /* c is the sensor's alone: it decays by b and moves nothing else */
                A[6][6] = b;
                continue;
            }
            double sp[NS];
            memcpy(sp, s0, sizeof sp);
            sp[j] += delta[j];
            if (reuse_plant(&pert, pm, msg, len)) {
                rc = -1;
                break;
            }
            put_state(&pert, sp);
            if (advance(&pert, u[k], d + maglev_correction_force(corr, pert.x, pert.v), ts, msg, len)) {
                rc = -1;
                break;
            }
            double s2[NS];
            get_state(&pert, a * d, b * c, s2);
            for (int i = 0; i < NS; i++)
                if (i != 4 && i != 6) A[i][j] = (s2[i] - s1[i]) / delta[j];
        }
        {   /* the step taken: *pn is the plant now, and *pm's buffers its scratch for the next copy */
            MaglevPlant *was = pm;
            pm = pn;
            pn = was;
        }
        d = a * d;
        c = b * c;
        if (rc) break;
        sandwich(A, P, idx, na);
        for (int i = 0; i < NS; i++)
            for (int j = 0; j < NS; j++)
                if (!active[i] || !active[j]) P[i][j] = 0.0;
        for (int i = 0; i < NS; i++) P[i][i] += active[i] ? q_extra[i] : 0.0;
        if (coil_free) /* no covariance of the current with the rest: the updates leave it alone */
            for (int i = 0; i < NS; i++)
                if (i != 2) P[i][2] = P[2][i] = 0.0;
        P[4][4] += f->q_force * f->q_force * (1.0 - a * a);
        P[6][6] += rc2 * (1.0 - b * b);
        for (int i = 0; i < NS; i++)
            if (!isfinite(P[i][i])) {
                snprintf(msg, len, "the filter diverged at sample %zu", k);
                rc = -1;
            }
    }
    maglev_release(pm, &maglev_std_allocator);
    maglev_release(pn, &maglev_std_allocator);
    maglev_release(&pert, &maglev_std_allocator);
    maglev_release(&cur, &maglev_std_allocator);
    return rc;
}

int maglev_replay_predict(const double *params, const MaglevController *c, const MaglevFilter *f, const double *w,
                          const double *y, const double *u, size_t n, double u_hold, double *y_pred,
                          double *u_pred, double *innov, double *innov_var, char *msg, size_t len) {
    if (!c) {
        snprintf(msg, len, "no controller given (maglev_replay_predict_measured replays without one)");
        return -1;
    }
    return predict(params, c, NULL, c->pid.ts, f, w, y, u, NULL, 0.0, n, u_hold, 1, &f->horizon, NULL, y_pred, u_pred, NULL,
                   innov, innov_var, NULL, NULL, msg, len);
}

int maglev_replay_predict_measured(const double *params, const MaglevFilter *f, double ts, const double *y,
                                   const double *u, const double *i_meas, double r_current, size_t n,
                                   double *y_pred, double *i_pred, double *innov, double *innov_var, double *d_est,
                                   double *d_sd, char *msg, size_t len) {
    return predict(params, NULL, NULL, ts, f, NULL, y, u, i_meas, r_current, n, n ? u[0] : 0.0, 1, &f->horizon, NULL, y_pred,
                   NULL, i_pred, innov, innov_var, d_est, d_sd, msg, len);
}

int maglev_replay_predict_corrected(const double *params, const MaglevFilter *f, const MaglevCorrection *corr,
                                    double ts, const double *y, const double *u, const double *i_meas,
                                    double r_current, size_t n, double *y_pred, double *i_pred, double *innov,
                                    double *innov_var, double *d_est, double *d_sd, char *msg, size_t len) {
    return predict(params, NULL, corr, ts, f, NULL, y, u, i_meas, r_current, n, n ? u[0] : 0.0, 1, &f->horizon, NULL, y_pred,
                   NULL, i_pred, innov, innov_var, d_est, d_sd, msg, len);
}

int maglev_replay_predict_horizons(const double *params, const MaglevFilter *f, const MaglevCorrection *corr,
                                   double ts, const double *y, const double *u, const double *i_meas,
                                   double r_current, size_t n, int n_h, const int *horizons, double *y_pred,
                                   double *i_pred, double *innov, double *innov_var, double *d_est, double *d_sd,
                                   char *msg, size_t len) {
    return predict(params, NULL, corr, ts, f, NULL, y, u, i_meas, r_current, n, n ? u[0] : 0.0, n_h, horizons, NULL, y_pred,
                   NULL, i_pred, innov, innov_var, d_est, d_sd, msg, len);
}

int maglev_replay_predict_closed(const double *params, const MaglevController *c, const MaglevFilter *f,
                                 const double *w, const double *y, const double *u, const double *i_meas,
                                 double r_current, size_t n, double u_hold, int n_h, const int *horizons,
                                 double *y_pred, double *u_pred, double *i_pred, double *innov, double *innov_var,
                                 double *d_est, double *d_sd, char *msg, size_t len) {
    if (!c) {
        snprintf(msg, len, "no controller given (maglev_replay_predict_horizons predicts without one)");
        return -1;
    }
    return predict(params, c, NULL, c->pid.ts, f, w, y, u, i_meas, r_current, n, u_hold, n_h, horizons, NULL, y_pred, u_pred,
                   i_pred, innov, innov_var, d_est, d_sd, msg, len);
}

int maglev_replay_predict_masked(const double *params, const MaglevFilter *f, const MaglevCorrection *corr, double ts,
                                 const double *y, const double *u, const double *i_meas, double r_current, size_t n,
                                 int n_h, const int *horizons, const unsigned char *starts, double *y_pred,
                                 double *i_pred, double *innov, double *innov_var, double *d_est, double *d_sd,
                                 char *msg, size_t len) {
    return predict(params, NULL, corr, ts, f, NULL, y, u, i_meas, r_current, n, n ? u[0] : 0.0, n_h, horizons, starts,
                   y_pred, NULL, i_pred, innov, innov_var, d_est, d_sd, msg, len);
}
