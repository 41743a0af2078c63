/* Closed-loop replay (maglev_replay.h). */
#include "maglev_replay.h"

#include <math.h>
#include <stdio.h>

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

static int load(MaglevPlant *m, const double *params, char *msg, size_t len) {
    maglev_defaults(m);
    for (int k = 0; k < MAGLEV_NPARAMS; k++) {
        if (maglev_check_value((MaglevVR)(MAGLEV_FIRST_PARAM + k), params[k], msg, len)) return -1;
        maglev_set_param(m, (MaglevVR)(MAGLEV_FIRST_PARAM + k), params[k]);
    }
    return 0;
}

int maglev_replay_check_params(const double *params, char *msg, size_t len) {
    MaglevPlant m;
    if (load(&m, params, msg, len)) return -1;
    return maglev_check_params(&m, msg, len);
}

int maglev_replay_point(const double *params, double x, double i, MaglevPoint *out, char *msg, size_t len) {
    MaglevPlant m;
    if (maglev_replay_check_params(params, msg, len)) return -1;
    load(&m, params, msg, len);
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

int maglev_replay_positions(const double *params, const double *y, size_t n, double t, double *x, char *msg,
                            size_t len) {
    MaglevPlant m;
    if (maglev_replay_check_params(params, msg, len)) return -1;
    load(&m, params, msg, len);
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

typedef struct { double integral, e_prev, d_prev; } PidState;

static int pid_check(const MaglevPid *pid, double u_hold, char *msg, size_t len) {
    if (!pid || !(pid->ts > 0) || !isfinite(pid->ts) || !isfinite(pid->kp) || !isfinite(pid->ki) ||
        !isfinite(pid->kd) || !isfinite(pid->u_min) || !isfinite(pid->u_max) || !(pid->u_min < pid->u_max) ||
        !(pid->tf >= 0) || !isfinite(pid->tf) || pid->anti_windup < 0 || pid->anti_windup > 2) {
        snprintf(msg, len, "invalid PID settings (ts > 0, finite gains and limits, u_min < u_max, tf >= 0, "
                 "anti_windup 0, 1 or 2)");
        return -1;
    }
    if (!isfinite(u_hold)) {
        snprintf(msg, len, "initial input u_hold %g is not finite", u_hold);
        return -1;
    }
    return 0;
}

/* One sample of the PID (maglev_replay.h), the one difference equation of the C side. */
static double pid_step(const MaglevPid *pid, PidState *s, double w, double y) {
    double e = w - y;
    double integ = s->integral + pid->ki * pid->ts * e;
    double d = pid->tf > 0 ? (pid->tf * s->d_prev + pid->kd * (e - s->e_prev)) / (pid->tf + pid->ts)
                           : pid->kd * (e - s->e_prev) / pid->ts;
    double raw = pid->kp * e + integ + d;
    double uk = raw < pid->u_min ? pid->u_min : (raw > pid->u_max ? pid->u_max : raw);
    if (pid->anti_windup == 1 && uk != raw && (raw - uk) * e > 0) integ = s->integral;
    if (pid->anti_windup == 2) integ = integ < pid->u_min ? pid->u_min : (integ > pid->u_max ? pid->u_max : integ);
    s->integral = integ;
    s->e_prev = e;
    s->d_prev = d;
    return uk;
}

int maglev_replay_pid(const MaglevPid *pid, const double *w, const double *y, size_t n, double u_hold, double *u,
                      char *msg, size_t len) {
    if (pid_check(pid, u_hold, msg, len)) return -1;
    PidState s = {u_hold, 0.0, 0.0};
    for (size_t k = 0; k < n; k++) {
        if (!isfinite(w[k]) || !isfinite(y[k])) {
            snprintf(msg, len, "w[%zu] = %g or y[%zu] = %g is not finite", k, w[k], k, y[k]);
            return -1;
        }
        u[k] = pid_step(pid, &s, w[k], y[k]);
    }
    return 0;
}

int maglev_replay_closed_loop(const double *params, const MaglevPid *pid, const double *w, size_t n,
                              double u_hold, double *u, double *y, double *x, double *v, double *i,
                              char *msg, size_t len) {
    MaglevPlant m;
    if (pid_check(pid, u_hold, msg, len)) return -1;
    if (setup(&m, params, u_hold, msg, len)) {
        maglev_release(&m, &maglev_std_allocator);
        return -1;
    }
    PidState ps = {u_hold, 0.0, 0.0};
    double t = 0.0;
    int rc = 0;
    for (size_t k = 0; k < n; k++) {
        if (!isfinite(w[k])) {
            snprintf(msg, len, "reference w[%zu] = %g is not finite", k, w[k]);
            rc = -1;
            break;
        }
        double yk;
        sample(&m, k, y, x, v, i, &yk);
        double uk = pid_step(pid, &ps, w[k], yk);
        if (u) u[k] = uk;
        /* the FMU's clock: the master adds ts to the previous communication point */
        m.time = t;
        if (maglev_set_input(&m, uk, &maglev_std_allocator, msg, len) ||
            maglev_step(&m, pid->ts, &maglev_std_allocator, msg, len)) {
            rc = -1;
            break;
        }
        t += pid->ts;
    }
    maglev_release(&m, &maglev_std_allocator);
    return rc;
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
