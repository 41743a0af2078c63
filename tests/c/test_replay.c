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

int main(void) {
    double p[MAGLEV_NPARAMS];
    for (int k = 0; k < MAGLEV_NPARAMS; k++) p[k] = maglev_replay_param_default(k);
    params_with(p, VR_T_a, 2e-3);
    params_with(p, VR_T_F, 1e-3);
    params_with(p, VR_T_d, 2.5e-3);
    MaglevPoint pt;
    char msg[256];
    CHECK(maglev_replay_point(p, 0.0032, NAN, &pt, msg, sizeof msg) == 0, "%s", msg);
    params_with(p, VR_x_start, 0.0032);
    params_with(p, VR_i_start, pt.i);
    MaglevPid pid = {1e-3, 2.0, 2.97, 0.01, 0.0, 1.0, 0.0, 0};
    static double w[N], u[N], y[N], yp[N], up[N], e[N], s[N];
    for (int k = 0; k < N; k++) w[k] = pt.y + (k > 300 ? 0.04 : 0.0) - (k > 900 ? 0.07 : 0.0);
    CHECK(maglev_replay_closed_loop(p, &pid, w, N, pt.u, u, y, NULL, NULL, NULL, msg, sizeof msg) == 0, "%s", msg);

    MaglevFilter f = {2.5e-4, 8.0, 2.5e-4, 20, 3};
    CHECK(maglev_replay_predict(p, &pid, &f, w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == 0, "%s", msg);
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
    CHECK(maglev_replay_predict(q, &pid, &f, w, y, u, N, pt.u, yp, up, NULL, NULL, msg, sizeof msg) == 0, "%s", msg);
    double wrong = 0.0;
    for (int k = 0; k < N; k++)
        if (!isnan(yp[k])) wrong = fmax(wrong, fabs(yp[k] - y[k]));
    CHECK(wrong > 100 * worst && wrong > 1e-4, "wrong model: %g, exact: %g", wrong, worst);

    /* the unknown-controller path: the same record replayed without the PID, the predictions driven
     * by the measured input, the filter also fed the measured current; exact model, exact predictions */
    static double cur[N], ip[N];
    CHECK(maglev_replay_closed_loop(p, &pid, w, N, pt.u, NULL, NULL, NULL, NULL, cur, msg, sizeof msg) == 0, "%s", msg);
    for (int with_i = 0; with_i < 2; with_i++) {
        CHECK(maglev_replay_predict_measured(p, &f, 1e-3, y, u, with_i ? cur : NULL, 1e-3, N, yp, ip, e, s, msg,
                                             sizeof msg) == 0, "%s", msg);
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
              with_i ? "measured" : "not measured", wy, wi);
    }
    CHECK(maglev_replay_predict_measured(q, &f, 1e-3, y, u, cur, 1e-3, N, yp, ip, NULL, NULL, msg, sizeof msg) == 0,
          "%s", msg);
    wrong = 0.0;
    for (int k = 0; k < N; k++)
        if (!isnan(yp[k])) wrong = fmax(wrong, fabs(yp[k] - y[k]));
    CHECK(wrong > 1e-4, "wrong model, measured input: %g", wrong);
    CHECK(maglev_replay_predict_measured(p, &f, 1e-3, y, u, cur, 0.0, N, yp, ip, NULL, NULL, msg, sizeof msg) == -1 &&
              strstr(msg, "r_current"), "%s", msg);

    /* refusals: one message, nothing computed */
    MaglevFilter bad[] = {{0.0, 8.0, 2.5e-4, 20, 1}, {2.5e-4, NAN, 2.5e-4, 20, 1}, {2.5e-4, 8.0, -1.0, 20, 1},
                          {2.5e-4, 8.0, 2.5e-4, -1, 1}, {2.5e-4, 8.0, 2.5e-4, 20, 0}};
    for (size_t b = 0; b < sizeof bad / sizeof bad[0]; b++) {
        msg[0] = 0;
        CHECK(maglev_replay_predict(p, &pid, &bad[b], w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == -1 &&
                  strstr(msg, "invalid filter settings"), "case %zu: %s", b, msg);
    }
    y[700] = NAN;
    CHECK(maglev_replay_predict(p, &pid, &f, w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == -1 &&
              strstr(msg, "sample 700"), "%s", msg);
    y[700] = 0.4;
    params_with(p, VR_k_c, -1.0);
    CHECK(maglev_replay_predict(p, &pid, &f, w, y, u, N, pt.u, yp, up, e, s, msg, sizeof msg) == -1 &&
              strstr(msg, "k_c"), "%s", msg);

    printf("%d checks, %d failures\n", checks, failures);
    return failures ? 1 : 0;
}
