/* C tests of the replay library (c/maglev_replay.c) under ASan/UBSan: the closed loop and the
 * prediction-error replay with the delay line and both lags on (every copy of the plant and its
 * input history is released), exact predictions of an exact model, and refused settings. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "maglev_plant.h"
#include "maglev_replay.h"
#include "check.h"

#define N 1500

static void params_with(double *p, MaglevVR vr, double value) { p[vr - MAGLEV_FIRST_PARAM] = value; }

/* The defaults with a 2 ms current lag, the ball settled at 3.2 mm (pt: that operating point). */
static void settled(double *p, MaglevPoint *pt) {
    char msg[256];
    for (int k = 0; k < MAGLEV_NPARAMS; k++) p[k] = maglev_replay_param_default(k);
    params_with(p, VR_T_a, 2e-3);
    CHECK(maglev_replay_point(p, 0.0032, NAN, pt, msg, sizeof msg) == 0, "%s", msg);
    params_with(p, VR_x_start, 0.0032);
    params_with(p, VR_i_start, pt->i);
}

/* The cascade and the state feedback: the controller replayed alone on the loop's own signals gives
 * the loop's inputs back (one set of equations in both), an exact model predicts its own loop, and
 * bad settings are refused. */
static void test_other_controllers(void) {
    double p[MAGLEV_NPARAMS];
    MaglevPoint pt;
    char msg[256];
    settled(p, &pt);
    /* position loop: reading error [MU] -> current reference [A]; current loop: [A] -> u [MU] */
    MaglevController cas = {.kind = 1, .pid = {1e-3, 3.0, 4.5, 0.015, 0.0, 1.5, 2e-4, 2, 0, 0, 1},
                            .inner = {1e-3, 2.0, 400.0, 0.0, 0.0, 1.0, 0.0, 1, 0, 0, 1}};
    MaglevController sf = {.kind = 2, .pid = {1e-3, 0, 0, 0, 0.0, 1.0, 0.0, 1, 0, 0, 1}, .K = {-900.0, -40.0, 1.5},
                           .k_int = -20.0, .u_eq = pt.u, .y_eq = pt.y, .i_eq = pt.i, .x_eq = {0.0032, 0.0, pt.i},
                           .Phi = {{1, 1e-3, 0}, {0, 1, 0}, {0, 0, 0.6}}, .Gam = {0, 0, 0.3},
                           .C = {{300, 0, 0}, {0, 0, 1}}, .L = {{1e-3, 0}, {0, 0}, {0, 0.5}}};
    static double w[N], u[N], y[N], x[N], v[N], cur[N], u2[N], yp[N], up[N];
    for (int k = 0; k < N; k++) w[k] = pt.y + (k > 300 ? 0.03 : 0.0);
    const MaglevController *ctls[] = {&cas, &sf};
    for (int c = 0; c < 2; c++) {
        CHECK(maglev_replay_closed_loop(p, ctls[c], w, N, pt.u, u, y, x, v, cur, msg, sizeof msg) == 0, "%s", msg);
        double x0[3] = {x[0], v[0], cur[0]}, worst = 0.0;
        CHECK(maglev_replay_control(ctls[c], w, y, cur, N, pt.u, x0, u2, msg, sizeof msg) == 0, "%s", msg);
        for (int k = 0; k < N; k++) worst = fmax(worst, fabs(u2[k] - u[k]));
        CHECK(worst == 0.0, "controller %d alone on the loop's signals: off by %g MU", c, worst);
        MaglevFilter f = {2.5e-4, 8.0, 2.5e-4, 10, 7, 0, 0.0, 0.0, 0, 0};
        CHECK(maglev_replay_predict(p, ctls[c], &f, w, y, u, N, pt.u, yp, up, NULL, NULL, msg, sizeof msg) == 0,
              "%s", msg);
        worst = 0.0;
        for (int k = 0; k < N; k++)
            if (!isnan(yp[k])) worst = fmax(worst, fmax(fabs(yp[k] - y[k]), fabs(up[k] - u[k])));
        CHECK(worst < 1e-5, "controller %d: an exact model predicts its own loop: worst error %g", c, worst);
        CHECK(maglev_replay_control(ctls[c], w, y, NULL, N, pt.u, x0, u2, msg, sizeof msg) == -1 &&
                  strstr(msg, "current"), "%s", msg);
    }
    /* the cascade settles: the ball follows the step */
    CHECK(maglev_replay_closed_loop(p, &cas, w, N, pt.u, u, y, x, v, cur, msg, sizeof msg) == 0, "%s", msg);
    CHECK(fabs(y[N - 1] - w[N - 1]) < 2e-3, "cascade: y %g against w %g at the end", y[N - 1], w[N - 1]);
    cas.inner.ts = 2e-3;
    CHECK(maglev_replay_closed_loop(p, &cas, w, N, pt.u, u, y, x, v, cur, msg, sizeof msg) == -1 &&
              strstr(msg, "cascade"), "%s", msg);
    sf.K[1] = NAN;
    CHECK(maglev_replay_closed_loop(p, &sf, w, N, pt.u, u, y, x, v, cur, msg, sizeof msg) == -1 &&
              strstr(msg, "state-feedback"), "%s", msg);
    sf.K[1] = 0.0;
    sf.kind = 7;
    CHECK(maglev_replay_closed_loop(p, &sf, w, N, pt.u, u, y, x, v, cur, msg, sizeof msg) == -1 &&
              strstr(msg, "kind"), "%s", msg);
}

/* A deterministic standard normal draw (Box-Muller on a 64-bit LCG whose state the caller holds). */
static double normal(unsigned long long *st) {
    double u1, u2;
    do {
        *st = *st * 6364136223846793005ULL + 1442695040888963407ULL;
        u1 = (double)(*st >> 11) / 9007199254740992.0;
    } while (u1 <= 0.0);
    *st = *st * 6364136223846793005ULL + 1442695040888963407ULL;
    u2 = (double)(*st >> 11) / 9007199254740992.0;
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

/* Mean of log(s) + e^2/s over the innovations from sample 100 on, and their lag-1 correlation. */
static void innov_stats(const double *e, const double *s, double *nll, double *rho) {
    double acc = 0.0, c0 = 0.0, c1 = 0.0;
    int cnt = 0;
    for (int k = 100; k < N; k++) {
        acc += log(s[k]) + e[k] * e[k] / s[k];
        c0 += e[k] * e[k];
        if (k > 100) c1 += e[k] * e[k - 1];
        cnt++;
    }
    *nll = acc / cnt;
    *rho = c1 / c0;
}

/* The coloured sensor-noise state (f_sensor, r_coloured): 0 means white, bit for bit whatever
 * r_coloured holds; on a reading with low-passed sensor noise (100 Hz, as the independent emulator
 * makes it) the filter with that state leaves white innovations and a higher likelihood than the
 * white filter, in all three entry points; an exact noise-free model still predicts exactly; bad
 * settings are refused naming the field. */
static void test_coloured_sensor_noise(void) {
    double p[MAGLEV_NPARAMS];
    MaglevPoint pt;
    char msg[256];
    settled(p, &pt);
    MaglevPid pid = {1e-3, 2.0, 2.97, 0.01, 0.0, 1.0, 0.0, 0, 0, 0, 1, 0};
    MaglevController ctl = {.kind = 0, .pid = pid};
    static double w[N], u[N], y[N], yn[N], yp[N], up[N], e[N], s[N], e0[N], s0[N], ip[N], de[N], ds[N];
    for (int k = 0; k < N; k++) w[k] = pt.y + (k > 300 ? 0.04 : 0.0) - (k > 900 ? 0.07 : 0.0);
    CHECK(maglev_replay_closed_loop(p, &ctl, w, N, pt.u, u, y, NULL, NULL, NULL, msg, sizeof msg) == 0, "%s", msg);

    /* noise-free: the coloured filter predicts the exact model's loop exactly */
    MaglevFilter fc = {2.5e-4, 8.0, 1e-4, 20, 3, 0, 100.0, 2e-4, 0, 0};
    CHECK(maglev_replay_predict(p, &ctl, &fc, w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == 0, "%s", msg);
    double worst = 0.0;
    for (int k = 0; k < N; k++)
        if (!isnan(yp[k])) worst = fmax(worst, fmax(fabs(yp[k] - y[k]), fabs(up[k] - u[k])));
    CHECK(worst < 1e-5, "coloured filter, exact noise-free model: worst error %g", worst);

    /* the reading with coloured (100 Hz, 2e-4 MU) and white (1e-4 MU) noise; the input as recorded */
    const double b = exp(-6.283185307179586 * 100.0 * 1e-3);
    unsigned long long st = 2200;
    double cn = 2e-4 * normal(&st);
    for (int k = 0; k < N; k++) {
        yn[k] = y[k] + cn + 1e-4 * normal(&st);
        cn = b * cn + 2e-4 * sqrt(1.0 - b * b) * normal(&st);
    }

    /* 0 means white: the same innovations bit for bit whatever r_coloured holds */
    MaglevFilter fw = {2.5e-4, 8.0, 2.24e-4, 0, 1, 0, 0.0, 0.0, 0, 0}, fw2 = fw;
    fw2.r_coloured = 5.0;
    CHECK(maglev_replay_predict(p, &ctl, &fw, w, yn, u, N, pt.u, NULL, NULL, e0, s0, msg, sizeof msg) == 0, "%s", msg);
    CHECK(maglev_replay_predict(p, &ctl, &fw2, w, yn, u, N, pt.u, NULL, NULL, e, s, msg, sizeof msg) == 0, "%s", msg);
    for (int k = 0; k < N; k++)
        CHECK((isnan(e0[k]) && isnan(e[k])) || (e0[k] == e[k] && s0[k] == s[k]), "f_sensor = 0, sample %d: %g != %g",
              k, e0[k], e[k]);

    /* white against coloured, in the three entry points */
    MaglevCorrection corr = {.n_x = 1, .x_c = 0.0032, .x_s = 1e-3, .v_s = 0.01, .v_c = 1e-3, .coef = {0.0}};
    fc.horizon = 0;
    for (int entry = 0; entry < 3; entry++) {
        double nll_w, rho_w, nll_c, rho_c;
        for (int col = 0; col < 2; col++) {
            const MaglevFilter *f = col ? &fc : &fw;
            int rc = entry == 0 ? maglev_replay_predict(p, &ctl, f, w, yn, u, N, pt.u, NULL, NULL, e, s, msg, sizeof msg)
                     : entry == 1 ? maglev_replay_predict_measured(p, f, 1e-3, yn, u, NULL, 0.0, N, NULL, ip, e, s, de, ds,
                                                                   msg, sizeof msg)
                                  : maglev_replay_predict_corrected(p, f, &corr, 1e-3, yn, u, NULL, 0.0, N, NULL, ip, e,
                                                                    s, de, ds, msg, sizeof msg);
            CHECK(rc == 0, "entry %d: %s", entry, msg);
            for (int k = 0; k < N; k++) CHECK(isfinite(e[k]) && s[k] > 0, "entry %d, sample %d: %g, %g", entry, k, e[k], s[k]);
            innov_stats(e, s, col ? &nll_c : &nll_w, col ? &rho_c : &rho_w);
        }
        CHECK(rho_w > 0.2 && fabs(rho_c) < 0.1, "entry %d: lag-1 correlation of the innovations, white %g, coloured %g",
              entry, rho_w, rho_c);
        CHECK(nll_c < nll_w - 0.1, "entry %d: mean NLL white %g, coloured %g", entry, nll_w, nll_c);
    }

    /* refusals, naming the field */
    MaglevFilter bad[] = {{2.5e-4, 8.0, 1e-4, 0, 1, 0, -1.0, 2e-4, 0, 0}, {2.5e-4, 8.0, 1e-4, 0, 1, 0, NAN, 2e-4, 0, 0},
                          {2.5e-4, 8.0, 1e-4, 0, 1, 0, 100.0, 0.0, 0, 0}, {2.5e-4, 8.0, 1e-4, 0, 1, 0, 100.0, INFINITY, 0, 0}};
    const char *field[] = {"f_sensor", "f_sensor", "r_coloured", "r_coloured"};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        msg[0] = 0;
        CHECK(maglev_replay_predict(p, &ctl, &bad[k], w, yn, u, N, pt.u, NULL, NULL, e, s, msg, sizeof msg) == -1 &&
                  strstr(msg, field[k]), "case %zu: %s", k, msg);
        msg[0] = 0;
        CHECK(maglev_replay_predict_measured(p, &bad[k], 1e-3, yn, u, NULL, 0.0, N, NULL, NULL, e, s, NULL, NULL, msg,
                                             sizeof msg) == -1 && strstr(msg, field[k]), "measured, case %zu: %s", k, msg);
    }
}

/* The derivative of the reading alone (d_on_y): a reference step moves the output by kp*dw and the
 * integrator's ki*ts*e alone (no kd*dw/ts kick), while at every other sample both forms give the same
 * output; the start is settled at the first reference (no kick at the first sample either); a d_on_y
 * other than 0 or 1 is refused naming it. */
static void test_derivative_of_the_reading(void) {
    char msg[256];
    MaglevPid pe = {1e-3, 2.0, 2.97, 0.01, -10.0, 10.0, 0.0, 0, 0, 0, 1, 0}, pm = pe;
    pm.d_on_y = 1;
    MaglevController ce = {.kind = 0, .pid = pe}, cm = {.kind = 0, .pid = pm};
    enum { M = 6 };
    const double w[M] = {0.4, 0.4, 0.45, 0.45, 0.45, 0.45}, y[M] = {0.4, 0.401, 0.402, 0.404, 0.404, 0.403};
    double ue[M], um[M];
    CHECK(maglev_replay_control(&ce, w, y, NULL, M, 0.3, NULL, ue, msg, sizeof msg) == 0, "%s", msg);
    CHECK(maglev_replay_control(&cm, w, y, NULL, M, 0.3, NULL, um, msg, sizeof msg) == 0, "%s", msg);
    CHECK(fabs(um[0] - 0.3) < 1e-12, "derivative of the reading: settled start gives u_hold, got %.15g", um[0]);
    /* the step at k = 2: the error form kicks by kd*0.05/ts = 0.5, the reading's does not */
    CHECK(fabs((ue[2] - um[2]) - 0.01 * 0.05 / 1e-3) < 1e-9, "kick at the step: %.15g", ue[2] - um[2]);
    for (int k = 0; k < M; k++)
        if (k != 2) CHECK(fabs(ue[k] - um[k]) < 1e-12, "still reference, sample %d: %.15g", k, ue[k] - um[k]);
    pm.d_on_y = 2;
    CHECK(maglev_pid_check(&pm, msg, sizeof msg) == -1 && strstr(msg, "d_on_y"), "d_on_y 2 refused: %s", msg);
}

/* The start from a reading (from_reading): a PID that stood at the reading y_before with the error
 * w[0] - y_before holds u_hold at the first sample while the reading stays, and moves by the integrator
 * alone; a closed loop started there rests where it stood at first. from_reading other than 0 or 1, or
 * a y_before that is not finite, is refused naming them. */
static void test_start_from_a_reading(void) {
    char msg[256];
    MaglevPid pid = {1e-3, 2.0, 2.97, 0.01, -10.0, 10.0, 0.0, 0, 0, 0, 1, 0};
    MaglevController c = {.kind = 0, .pid = pid, .from_reading = 1, .y_before = 0.388};
    enum { M = 4 };
    const double w[M] = {0.4, 0.4, 0.4, 0.4}, y[M] = {0.388, 0.388, 0.388, 0.388};
    double u[M];
    for (int d = 0; d < 2; d++) {
        c.pid.d_on_y = d;
        CHECK(maglev_replay_control(&c, w, y, NULL, M, 0.3, NULL, u, msg, sizeof msg) == 0, "%s", msg);
        for (int k = 0; k < M; k++)
            CHECK(fabs(u[k] - (0.3 + 2.97e-3 * 0.012 * (k + 1))) < 1e-12, "d_on_y %d, sample %d: %.15g", d, k, u[k]);
    }
    c.from_reading = 2;
    CHECK(maglev_replay_control(&c, w, y, NULL, M, 0.3, NULL, u, msg, sizeof msg) == -1 && strstr(msg, "from_reading"),
          "from_reading 2 refused: %s", msg);
    c.from_reading = 1;
    c.y_before = NAN;
    CHECK(maglev_replay_control(&c, w, y, NULL, M, 0.3, NULL, u, msg, sizeof msg) == -1 && strstr(msg, "y_before"),
          "y_before NaN refused: %s", msg);
}

int main(void) {
    double p[MAGLEV_NPARAMS];
    MaglevPoint pt;
    char msg[256];
    settled(p, &pt);
    params_with(p, VR_T_F, 1e-3);   /* the lags and the delay do not move the operating point */
    params_with(p, VR_T_d, 2.5e-3);
    MaglevPid pid = {1e-3, 2.0, 2.97, 0.01, 0.0, 1.0, 0.0, 0, 0, 0, 1, 0};
    MaglevController ctl = {.kind = 0, .pid = pid};
    static double w[N], u[N], y[N], yp[N], up[N], e[N], s[N];
    for (int k = 0; k < N; k++) w[k] = pt.y + (k > 300 ? 0.04 : 0.0) - (k > 900 ? 0.07 : 0.0);
    CHECK(maglev_replay_closed_loop(p, &ctl, w, N, pt.u, u, y, NULL, NULL, NULL, msg, sizeof msg) == 0, "%s", msg);

    MaglevFilter f = {2.5e-4, 8.0, 2.5e-4, 20, 3, 0, 0.0, 0.0, 0, 0};
    CHECK(maglev_replay_predict(p, &ctl, &f, w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == 0, "%s", msg);
    int made = 0;
    double worst = 0.0;
    for (int k = 0; k < N; k++) {
        if (isnan(yp[k])) continue;
        made++;
        worst = fmax(worst, fmax(fabs(yp[k] - y[k]), fabs(up[k] - u[k])));
    }
    CHECK(made == (N - 20 + 2) / 3, "%d predictions", made);
    CHECK(worst < 1e-5, "an exact model predicts its own noise-free loop: worst error %g", worst);
    for (int k = 1; k < N; k++) CHECK(isfinite(e[k]) && s[k] > 0, "innovation %d: %g, variance %g", k, e[k], s[k]);

    /* a wrong model (no delay) predicts worse */
    double q[MAGLEV_NPARAMS];
    memcpy(q, p, sizeof q);
    params_with(q, VR_T_d, 0.0);
    CHECK(maglev_replay_predict(q, &ctl, &f, w, y, u, N, pt.u, yp, up, NULL, NULL, msg, sizeof msg) == 0, "%s", msg);
    double wrong = 0.0;
    for (int k = 0; k < N; k++)
        if (!isnan(yp[k])) wrong = fmax(wrong, fabs(yp[k] - y[k]));
    CHECK(wrong > 100 * worst && wrong > 1e-4, "wrong model: %g, exact: %g", wrong, worst);

    /* the unknown-controller path: the same record replayed without the PID, the predictions driven
     * by the measured input, the filter also fed the measured current; exact model, exact predictions */
    static double cur[N], ip[N];
    CHECK(maglev_replay_closed_loop(p, &ctl, w, N, pt.u, NULL, NULL, NULL, NULL, cur, msg, sizeof msg) == 0, "%s", msg);
    /* with_i: 0 no measured current, 1 measured current in the filter, 2 also driving the predictions */
    for (int with_i = 0; with_i < 3; with_i++) {
        f.current_input = with_i == 2;
        CHECK(maglev_replay_predict_measured(p, &f, 1e-3, y, u, with_i ? cur : NULL, 1e-3, N, yp, ip, e, s, NULL, NULL,
                                             msg, sizeof msg) == 0, "%s", msg);
        double wy = 0.0, wi = 0.0;
        made = 0;
        for (int k = 0; k < N; k++) {
            if (isnan(yp[k])) continue;
            made++;
            wy = fmax(wy, fabs(yp[k] - y[k]));
            wi = fmax(wi, fabs(ip[k] - cur[k]));
        }
        CHECK(made == (N - 20 + 2) / 3, "%d predictions", made);
        CHECK(wy < 1e-5 && wi < 1e-5, "measured-input predictions (current %s): y off by %g MU, i by %g A",
              with_i == 2 ? "driving" : (with_i ? "measured" : "not measured"), wy, wi);
    }
    f.current_input = 0;
    /* the filtered random force: finite with a positive spread at every sample, and near zero for
     * the exact model (no force is missing) */
    static double de[N], ds[N];
    CHECK(maglev_replay_predict_measured(p, &f, 1e-3, y, u, cur, 1e-3, N, NULL, NULL, NULL, NULL, de, ds, msg,
                                         sizeof msg) == 0, "%s", msg);
    double dmax = 0.0;
    for (int k = 0; k < N; k++) {
        CHECK(isfinite(de[k]) && ds[k] > 0 && ds[k] <= 2.5e-4 * 1.0001, "sample %d: d %g, sd %g", k, de[k], ds[k]);
        dmax = fmax(dmax, fabs(de[k]));
    }
    CHECK(dmax < 1e-5, "the exact model's random force reaches %g N", dmax);
    CHECK(maglev_replay_predict_measured(q, &f, 1e-3, y, u, cur, 1e-3, N, yp, ip, NULL, NULL, NULL, NULL, msg, sizeof msg) == 0,
          "%s", msg);
    wrong = 0.0;
    for (int k = 0; k < N; k++)
        if (!isnan(yp[k])) wrong = fmax(wrong, fabs(yp[k] - y[k]));
    CHECK(wrong > 1e-4, "wrong model, measured input: %g", wrong);
    CHECK(maglev_replay_predict_measured(p, &f, 1e-3, y, u, cur, 0.0, N, yp, ip, NULL, NULL, NULL, NULL, msg, sizeof msg) == -1 &&
              strstr(msg, "r_current"), "%s", msg);

    /* several horizons in one pass: each row equals the call with that horizon alone, also where a
     * shorter horizon's predictions end past the longest one's last start */
    {
        static double yh[3 * N], ih[3 * N], y1[N], i1[N];
        const int hz[3] = {5, 20, 50};
        CHECK(maglev_replay_predict_horizons(q, &f, NULL, 1e-3, y, u, cur, 1e-3, N, 3, hz, yh, ih, NULL, NULL, NULL,
                                             NULL, msg, sizeof msg) == 0, "%s", msg);
        for (int r = 0; r < 3; r++) {
            MaglevFilter g = f;
            g.horizon = hz[r];
            CHECK(maglev_replay_predict_measured(q, &g, 1e-3, y, u, cur, 1e-3, N, y1, i1, NULL, NULL, NULL, NULL, msg,
                                                 sizeof msg) == 0, "%s", msg);
            int same = 1;
            for (int k = 0; k < N; k++) {
                double a = yh[r * N + k], b = y1[k], c = ih[r * N + k], d2 = i1[k];
                same &= (isnan(a) && isnan(b)) || a == b;
                same &= (isnan(c) && isnan(d2)) || c == d2;
            }
            CHECK(same, "horizon %d: one pass differs from the single call", hz[r]);
        }
        const int none[2] = {5, 0};
        CHECK(maglev_replay_predict_horizons(q, &f, NULL, 1e-3, y, u, cur, 1e-3, N, 2, none, yh, ih, NULL, NULL, NULL,
                                             NULL, msg, sizeof msg) == -1 && strstr(msg, "horizon 0"), "%s", msg);
        CHECK(maglev_replay_predict_horizons(q, &f, NULL, 1e-3, y, u, cur, 1e-3, N, 0, hz, yh, ih, NULL, NULL, NULL,
                                             NULL, msg, sizeof msg) == -1 && strstr(msg, "horizons needed"), "%s", msg);
    }

    /* the closed loop at several horizons in one pass: each row equals maglev_replay_predict with
     * that horizon alone; no controller is refused */
    {
        static double yh[3 * N], uh[3 * N], y1[N], u1[N];
        const int hz[3] = {5, 20, 50};
        CHECK(maglev_replay_predict_closed(p, &ctl, &f, w, y, u, NULL, 0.0, N, pt.u, 3, hz, yh, uh, NULL, NULL, NULL,
                                           NULL, NULL, msg, sizeof msg) == 0, "%s", msg);
        for (int r = 0; r < 3; r++) {
            MaglevFilter g = f;
            g.horizon = hz[r];
            CHECK(maglev_replay_predict(p, &ctl, &g, w, y, u, N, pt.u, y1, u1, NULL, NULL, msg, sizeof msg) == 0, "%s",
                  msg);
            int same = 1, made = 0;
            for (int k = 0; k < N; k++) {
                double a = yh[r * N + k], b = y1[k], c = uh[r * N + k], d2 = u1[k];
                same &= (isnan(a) && isnan(b)) || a == b;
                same &= (isnan(c) && isnan(d2)) || c == d2;
                made += !isnan(a);
            }
            CHECK(same && made > 0, "closed loop, horizon %d: one pass differs from the single call (%d made)", hz[r],
                  made);
        }
        CHECK(maglev_replay_predict_closed(p, NULL, &f, w, y, u, NULL, 0.0, N, pt.u, 3, hz, yh, uh, NULL, NULL, NULL,
                                           NULL, NULL, msg, sizeof msg) == -1 && strstr(msg, "no controller"), "%s", msg);
    }

    /* refusals: one message, nothing computed */
    MaglevFilter bad[] = {{0.0, 8.0, 2.5e-4, 20, 1, 0, 0, 0, 0, 0}, {2.5e-4, NAN, 2.5e-4, 20, 1, 0, 0, 0, 0, 0},
                          {2.5e-4, 8.0, -1.0, 20, 1, 0, 0, 0, 0, 0}, {2.5e-4, 8.0, 2.5e-4, -1, 1, 0, 0, 0, 0, 0},
                          {2.5e-4, 8.0, 2.5e-4, 20, 0, 0, 0, 0, 0, 0}, {2.5e-4, 8.0, 2.5e-4, 20, 1, 0, 0, 0, 0, 2}};
    for (size_t b = 0; b < sizeof bad / sizeof bad[0]; b++) {
        msg[0] = 0;
        CHECK(maglev_replay_predict(p, &ctl, &bad[b], w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == -1 &&
                  strstr(msg, "invalid filter settings"), "case %zu: %s", b, msg);
    }
    y[700] = NAN;
    CHECK(maglev_replay_predict(p, &ctl, &f, w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == -1 &&
              strstr(msg, "sample 700"), "%s", msg);
    y[700] = 0.4;
    params_with(p, VR_k_c, -1.0);
    CHECK(maglev_replay_predict(p, &ctl, &f, w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == -1 &&
              strstr(msg, "k_c"), "%s", msg);

    test_other_controllers();
    test_derivative_of_the_reading();
    test_start_from_a_reading();
    test_coloured_sensor_noise();
    printf("%d checks, %d failures\n", checks, failures);
    return failures ? 1 : 0;
}
