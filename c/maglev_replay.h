/* Closed-loop replay in C: the plant of maglev_plant.c with the paper's discrete PID
 * (Eq. 24/25), a whole record in one call. The cffi fast path of the Python toolkit. */
#ifndef MAGLEV_REPLAY_H
#define MAGLEV_REPLAY_H

#include <stddef.h>

/* The paper's PID (Eq. 24/25) with the usual extensions: e = w - y,
 *   I[k] = I[k-1] + ki*ts*e[k]
 *   D[k] = kd*(e[k] - e[k-1])/ts, or with a filter (tf*D[k-1] + kd*(e[k] - e[k-1]))/(tf + ts)
 *   u[k] = clip(kp*e[k] + I[k] + D[k], u_min, u_max)
 * Anti-windup: 1 conditional integration (I is not updated while the output saturates and e
 * pushes further into the limit), 2 clamping (I is kept within [u_min, u_max]), 3 a band, as
 * microcontroller firmware often has it: I integrates only while i_lo < I[k-1] < i_hi, otherwise
 * I[k] = clip(I[k-1], backoff*i_lo, backoff*i_hi). */
typedef struct {
    double ts, kp, ki, kd, u_min, u_max;
    double tf;       /* derivative filter time constant [s], 0 = off */
    int anti_windup; /* 0 none, 1 conditional integration, 2 clamping, 3 band */
    double i_lo, i_hi, backoff; /* the band (anti_windup 3): i_lo < i_hi, 0 < backoff <= 1 */
    int d_on_y;      /* 0: the derivative of the error e (Eq. 24); 1: of -y alone, as PIDs that spare the
                        output a kick at each reference step compute it (last: a zeroed tail is Eq. 24) */
} MaglevPid;

/* The PID's memory between samples: integrator I[k-1], the derivative's argument at k-1 (e[k-1], or
 * -y[k-1] with d_on_y), derivative term D[k-1]. Settled start: integral = the holding input,
 * d_prev = 0, e_prev = 0 (or -w[0] with d_on_y: the reading was at the first reference, as e = 0 says);
 * from a reading y_b with an error e_b = w[0] - y_b standing (MaglevController.from_reading):
 * integral = the holding input - kp*e_b, e_prev = e_b (or -y_b), so the output holds the plant. */
typedef struct { double integral, e_prev, d_prev; } MaglevPidState;

/* Checks a PID's settings (finite, ts > 0, u_min < u_max, tf >= 0, anti_windup 0 to 3, the band, d_on_y 0 or 1).
 * Returns 0, or -1 with a message naming the first setting that is wrong. */
int maglev_pid_check(const MaglevPid *pid, char *msg, size_t msglen);

/* One sample of the PID above: u[k] [MU] from w[k] and y[k] [MU], s updated. The one difference
 * equation of the C side: the closed loops below and the controller FMU (maglev_pid_fmu.c) use it. */
double maglev_pid_step(const MaglevPid *pid, MaglevPidState *s, double w, double y);

/* The controller of a closed loop: at t_k it reads the reference w [MU], the plant's reading y [MU]
 * and the coil current i [A], and gives u [MU], held over the next sample. Kinds:
 *   0 PID: u = PID(w - y) (pid above);
 *   1 cascade: the position loop pid gives the current reference r = PID(w - y) [A] (its limits:
 *     the reference's range), the current loop inner gives u = PID(r - i) (sample time pid.ts);
 *   2 state feedback with an observer, on deviations from an operating point (x_eq [m, m/s, A],
 *     u_eq [MU], y_eq [MU], i_eq [A]); sample time, limits and anti-windup (0 or 1) from pid:
 *       e = (y - y_eq, i - i_eq) - C*xh,  xh = xh + L*e                  measurement update
 *       u = clip(u_eq + k_w*(w - y_eq) - K*xh - k_int*q, u_min, u_max)
 *       q = q + ts*(w - y)     (held while u saturates and q would push further: anti_windup 1)
 *       xh = Phi*xh + Gam*(u - u_eq)                                        time update
 * Settled start: a PID's output holds u_hold (above); a cascade's position loop holds the plant's
 * current at the start and its current loop u_hold; the observer starts at the plant's state, q
 * where u = u_hold. */
typedef struct {
    int kind;        /* 0 PID, 1 cascade, 2 state feedback */
    MaglevPid pid;   /* the PID; the cascade's position loop; the state feedback's ts, limits, anti_windup */
    MaglevPid inner; /* the cascade's current loop */
    double Phi[3][3], Gam[3], C[2][3], L[3][2], K[3];
    double k_w, k_int, x_eq[3], u_eq, y_eq, i_eq;
    /* Where the settled start (above) stood before t = 0 (a PID and a cascade's position loop):
     * 0, at zero error with the reading at the first reference w[0] (a simulation whose reference
     * steps at t = 0: the step acts at the first sample); 1, at the reading y_before [MU] with the
     * error w[0] - y_before standing (a record cut from a running loop: the output holds u_hold). */
    int from_reading;
    double y_before;
} MaglevController;

/* The controller alone over given w, y [MU] and i [A] (i may be NULL for a PID), n samples,
 * settled before at u_hold [MU] with the plant at state x0 = (x [m], v [m/s], i [A]). */
int maglev_replay_control(const MaglevController *c, const double *w, const double *y, const double *i, size_t n,
                          double u_hold, const double *x0, double *u, char *msg, size_t msglen);

/* params: MAGLEV_NPARAMS values in value-reference order from VR_k_DA.
 * At t_k: y[k] is read, u[k] = controller(w[k], y[k], i(t_k)) is held over [t_k, t_k + ts).
 * The loop starts settled (above), plant input u_hold.
 * Any of u, y, x, v, i may be NULL. Returns 0, or -1 with a message. */
int maglev_replay_closed_loop(const double *params, const MaglevController *c, const double *w, size_t n,
                              double u_hold, double *u, double *y, double *x, double *v, double *i,
                              char *msg, size_t msglen);

/* The same closed loop with signals injected at the three places a model error can enter (each
 * may be NULL): du[k] [MU] added to the controller's output on its way to the plant (actuator),
 * dF[k] [N] a force on the ball held over sample k (mechanics, as the filter's random force), dy[k]
 * [MU] added to the reading the controller sees and y reports (sensor). y_step, u_step [MU]: the
 * A/D and D/A steps (0: none), to which the reading (after dy) and the controller's output are
 * rounded, as a record's converters do. u reports the controller's output. Used to locate a
 * residual no catalogue effect explains, and to simulate records of a model with its noise. */
int maglev_replay_closed_loop_injected(const double *params, const MaglevController *c, const double *w, size_t n,
                                       double u_hold, const double *du, const double *dF, const double *dy,
                                       double y_step, double u_step, double *u, double *y, double *x, double *v,
                                       double *i, char *msg, size_t msglen);

/* Prediction-error replay: an extended Kalman filter on the plant above, driven by the measured
 * input u, corrects the state with each measured reading y, and from every stride-th sample
 * predicts the closed loop horizon samples ahead (plant + controller on the predicted readings
 * and currents, the first input being the measured u[k]). The disturbance is part of the model: a random force d
 * on the ball, a first-order Gauss-Markov process (RMS q_force, corner f_force: d[k+1] =
 * a*d[k] + w[k], a = exp(-2*pi*f_force*ts)), and sensor noise on the reading: white of RMS
 * r_sensor, plus, when f_sensor > 0, a coloured part c, a first-order Gauss-Markov process of RMS
 * r_coloured and corner f_sensor (c[k+1] = b*c[k] + w_c[k], b = exp(-2*pi*f_sensor*ts); the reading
 * is the plant's plus c plus the white part), as a sensor whose noise is low-passed before the A/D
 * samples it. The EKF state is (x, v, i, F, d, xs, c, F2); i and F take part only when their lags T_a,
 * T_F are on, xs with a sensor lag, c when f_sensor > 0, F2 with the second force lag (beta_F > 0).
 * f_sensor = 0 (a zeroed field): white sensor
 * noise only, the filter of before the coloured part. The k-step predictions carry c's expected
 * decay b^j*c into the readings they predict and the controller sees. */
typedef struct {
    double q_force;  /* [N] RMS of the random force on the ball (> 0) */
    double f_force;  /* [Hz] its corner frequency (> 0; large: white) */
    double r_sensor; /* [MU] RMS of the sensor noise (> 0) */
    int horizon;     /* [samples] prediction horizon (>= 1), or 0: filter only */
    int stride;      /* a prediction from every stride-th sample (>= 1) */
    int current_input; /* measured-input predictions only: 1 drives them by the measured coil current
                        * (i_meas[k + j] put into the plant at each sample of the horizon, as a
                        * regression on the measured current would use it), 0 by the actuator signal */
    double f_sensor;   /* [Hz] corner of the coloured part of the sensor noise (>= 0; 0: white only) */
    double r_coloured; /* [MU] RMS of the coloured part (> 0 when f_sensor > 0; unused when f_sensor = 0) */
    int offset;      /* the predictions start at the samples k with k % stride == offset (0 <= offset < stride) */
    int coil_free;   /* without a measured current (i_meas NULL) only: 1 keeps the coil current out of the
                      * reading's updates (its covariance with the other states is dropped at every sample),
                      * so the current is the coil model's free run from the actuator signal along the
                      * tracked position, never pulled by the gap's innovations through the force law;
                      * 0 (a zeroed field): the current is a state of the filter like the others */
} MaglevFilter;

/* A located correction at the mechanics: a force on the ball [N] (positive: along x, upward in
 * the paper's convention) that is a function of the ball's position and velocity, added over each
 * sample of the filter's and the predictions' model like the random force d (held over the sample,
 * from the state at its start: the location's injected force dF, made a function of the state):
 *   F = sum over j < n_x, l < 3 of coef[3*j + l] * P_j(xi) * b_l(v),
 *   xi = (x - x_c)/x_s (held within [-1.5, 1.5]), P_j the Legendre polynomials (1, xi, (3 xi^2 - 1)/2, ...),
 *   b_0 = 1 (a static force), b_1 = v/v_s (viscous), b_2 = tanh(v/v_c) (a friction: Coulomb smoothed over v_c).
 * Linear in coef, so a fit of it is a regression through the prediction errors. n_x = 0: none. */
typedef struct {
    int n_x;          /* position terms, 0 (off) to 4 */
    double x_c, x_s;  /* [m] centre and half width of the positions the basis spans (x_s > 0) */
    double v_s, v_c;  /* [m/s] velocity scale of the viscous term, smoothing speed of the friction (> 0) */
    double coef[12];  /* [N] */
} MaglevCorrection;

/* The correction's force [N] at position x [m] and velocity v [m/s] (0 for NULL or n_x = 0). */
double maglev_correction_force(const MaglevCorrection *c, double x, double v);

/* y_pred[k], u_pred[k]: the predictions of y[k] and u[k] made at k - horizon (NaN where none was
 * made); innov[k] = y[k] - (its one-step prediction), innov_var[k] its variance [MU^2] (NaN
 * where the reading sat at the converter's limit and was not used). Any output may be NULL.
 * Returns 0, or -1 with a message. */
int maglev_replay_predict(const double *params, const MaglevController *c, const MaglevFilter *filter,
                          const double *w, const double *y, const double *u, size_t n, double u_hold,
                          double *y_pred, double *u_pred, double *innov, double *innov_var,
                          char *msg, size_t msglen);

/* The same filter for a record whose controller is unknown (MPC, or anything the user cannot state):
 * the predictions are driven by the measured input u (the actuator signal as the plant's D/A input
 * [MU]), never by a controller and never by a free run of the unstable plant. With i_meas (may be
 * NULL) the measured coil current [A], white noise of RMS r_current, corrects the state too (when
 * the current is a state: T_a > 0 or a voltage drive). i_pred[k]: the current predicted at
 * k - horizon. d_est[k], d_sd[k]: the filtered random force on the ball at t_k [N] and its standard
 * deviation [N] (its trajectory shows a drift). ts: the sample time [s]. Any output may be NULL.
 * Returns 0, or -1 with a message. */
int maglev_replay_predict_measured(const double *params, const MaglevFilter *filter, double ts, const double *y,
                                   const double *u, const double *i_meas, double r_current, size_t n,
                                   double *y_pred, double *i_pred, double *innov, double *innov_var, double *d_est,
                                   double *d_sd, char *msg, size_t msglen);

/* maglev_replay_predict_measured with a located correction at the mechanics (corr, may be NULL:
 * none) in the filter's model and its predictions. */
int maglev_replay_predict_corrected(const double *params, const MaglevFilter *filter, const MaglevCorrection *corr,
                                    double ts, const double *y, const double *u, const double *i_meas,
                                    double r_current, size_t n, double *y_pred, double *i_pred, double *innov,
                                    double *innov_var, double *d_est, double *d_sd, char *msg, size_t msglen);

/* The most horizons maglev_replay_predict_horizons and maglev_replay_predict_closed take in one call. */
#define MAGLEV_MAX_HORIZONS 64

/* maglev_replay_predict_corrected at n_h horizons (samples, each >= 1; filter->horizon is not
 * used) in one pass: one trajectory from every stride-th sample to the longest horizon, read at
 * each; y_pred and i_pred hold n_h rows of n (row q: horizons[q]), each the same as a call with
 * that horizon alone, but the filter runs once and the shorter horizons cost nothing more. */
int maglev_replay_predict_horizons(const double *params, const MaglevFilter *filter, const MaglevCorrection *corr,
                                   double ts, const double *y, const double *u, const double *i_meas,
                                   double r_current, size_t n, int n_h, const int *horizons, double *y_pred,
                                   double *i_pred, double *innov, double *innov_var, double *d_est, double *d_sd,
                                   char *msg, size_t msglen);

/* maglev_replay_predict_horizons from the samples k with starts[k] != 0 alone (besides k % stride ==
 * offset; starts holds n flags, NULL: every one): the same predictions where made, NaN elsewhere; the
 * filter still follows every sample. A cost read on some samples only needs no other predictions. */
int maglev_replay_predict_masked(const double *params, const MaglevFilter *filter, const MaglevCorrection *corr,
                                 double ts, const double *y, const double *u, const double *i_meas,
                                 double r_current, size_t n, int n_h, const int *horizons,
                                 const unsigned char *starts, double *y_pred, double *i_pred, double *innov,
                                 double *innov_var, double *d_est, double *d_sd, char *msg, size_t msglen);

/* The closed loop predicted at n_h horizons (as maglev_replay_predict_horizons) with a controller:
 * the filter follows the measured y (and the measured current i_meas, may be NULL) driven by the
 * measured u; from every stride-th sample the plant and the controller run on their own predicted
 * readings and current, driven by the reference w alone (no measured signal after the sample the
 * prediction starts from). u_pred: the controller's predicted outputs. ts: the controller's. */
int maglev_replay_predict_closed(const double *params, const MaglevController *c, const MaglevFilter *filter,
                                 const double *w, const double *y, const double *u, const double *i_meas,
                                 double r_current, size_t n, double u_hold, int n_h, const int *horizons,
                                 double *y_pred, double *u_pred, double *i_pred, double *innov, double *innov_var,
                                 double *d_est, double *d_sd, char *msg, size_t msglen);

/* The plant driven by a given input sequence; y[k] is read at t_k before u_in[k] is applied;
 * u_in[0] is also the input before t = 0. */
int maglev_replay_open_loop(const double *params, const double *u_in, size_t n, double ts, double *y,
                            double *x, double *v, double *i, char *msg, size_t msglen);

/* Checks params as the FMU would: every value in its range, then the relations between them.
 * Returns 0, or -1 with a message naming the variable. */
int maglev_replay_check_params(const double *params, char *msg, size_t msglen);

/* The plant's formulas at position x [m] and current i [A] (NaN: the equilibrium current), for
 * params: the point, the equilibrium's D/A input, the reading and the slopes a linearisation needs. */
typedef struct {
    double x, i;        /* [m] [A] */
    double u;           /* [MU] D/A input giving i (Eq. 1, 5), unlimited */
    double y;           /* [MU] noise-free reading at t = 0 (Eq. 12, 13), unlimited */
    double F;           /* [N] static force (Eq. 8) */
    double dF_dx, dF_di; /* [N/m] [N/A] (Eq. 16, 17) */
    double dy_dx;       /* [MU/m] reading slope */
} MaglevPoint;

int maglev_replay_point(const double *params, double x, double i, MaglevPoint *out, char *msg, size_t msglen);

/* The static force F [N] of n positions x [m] with currents i [A] (MaglevPoint's F, one call for a
 * record; a current that is NaN: the equilibrium current at x, as maglev_replay_point takes it).
 * Returns 0, or -1 with a message (a position that is not finite). */
int maglev_replay_forces(const double *params, const double *x, const double *i, size_t n, double *F, char *msg,
                         size_t msglen);

/* The noise-free readings y [MU] at time t [s] of n positions x [m] (MaglevPoint's y, one call for a
 * record). Returns 0, or -1 with a message (a position that is not finite). */
int maglev_replay_readings(const double *params, const double *x, size_t n, double t, double *y, char *msg,
                           size_t msglen);

/* The position between the stops [m] where the model reads y [MU] at time t [s], for n readings;
 * readings beyond the travel give the nearest stop. Returns 0, or -1 with a message. */
int maglev_replay_positions(const double *params, const double *y, size_t n, double t, double *x,
                            char *msg, size_t msglen);

/* Number of parameters and their names, in the order params uses. */
int maglev_replay_nparams(void);
const char *maglev_replay_param_name(int k);
double maglev_replay_param_default(int k);
/* The range maglev_check_value enforces and the unit, from the C variable table. */
double maglev_replay_param_min(int k);
double maglev_replay_param_max(int k);
const char *maglev_replay_param_unit(int k);
/* The effect the parameter belongs to ("" for the baseline plant), from the C variable table. */
const char *maglev_replay_param_effect(int k);

#endif
