"""Replaying a record in closed loop on the C plant (cffi fast path).

The record's controller and reference drive the model (:func:`maglev_cosim.loop.simulate.simulate`); the
loop starts settled at the first reading ``y[0]``: the ball at rest where the model's sensor
reads ``y[0]``, the current at equilibrium there, ``e[−1] = 0`` and the integrator holding the
equilibrium input. A record read from a settled point after a start that moved
(:func:`~maglev_cosim.records.settled.from_settled`) starts where it stood, ``Record.y_before``: the
ball at rest where the sensor reads it, and the controller's output holding the equilibrium input
with the error ``w[0] − y_before`` standing (its integrator may still creep towards the reference).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from ..loop import fast_loop
from ..loop.fast_loop import settled_start_vector
from ..loop.controllers import Controller
from ..loop.pid import PID
from ..plant import fast, formulas
from ..plant.params import as_params, get_params
from ..records.record import Record
from .acceptance import accept_nll, fit_blocks
from .memo import Memo


def baseline_params() -> dict[str, float]:
    """FMU parameter values of the diagnosis baseline: the paper's simulation model, Section 3 with
    T_a neglected (Eq. 5), the ``baseline`` set of :mod:`maglev_cosim.plant.params`."""
    return get_params("baseline").to_start_values()


def record_controller(rec: Record) -> Controller:
    """The controller a record declares: the controller file its metadata names, or the PID of its
    metadata (the paper's where it is silent)."""
    return rec.controller if rec.controller is not None else PID(**rec.pid_kwargs())


def _settled_at_first_reading(rec: Record, params: Mapping[str, float] | np.ndarray) -> tuple[np.ndarray, float]:
    """``params`` checked as the FMU would, as a parameter vector with the start state where every
    replay of a record starts: at rest where the model reads ``y[0]`` (``rec.y_before`` where the
    record has one, :func:`~maglev_cosim.records.settled.from_settled`), the current at equilibrium
    there (:func:`~maglev_cosim.loop.simulate.settled_start`); and the hold input [MU]. It works on the
    vector: a fit replays thousands of times, and building parameter objects cost a third of each."""
    pv = fast.param_vector(params)
    return settled_start_vector(pv, formulas.position(pv, float(rec.y[0]) if rec.y_before is None else rec.y_before))


def replay(rec: Record, params: Mapping[str, float] | np.ndarray, *, w: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The record's closed loop simulated with ``params`` (FMU parameter values, or a vector of
    them), settled at the position where the model reads ``y[0]``: the loop of
    :func:`maglev_cosim.loop.simulate.simulate` (``backend="fast"``, ``x_op`` there), in one C call.

    Returns arrays t [s], w, u, y [MU], x [m], v [m/s], i [A]. Raises ``ValueError`` (one line
    naming the variable) for a parameter set the FMU would refuse."""
    return replay_injected(rec, params, w=w)


def replay_injected(rec: Record, params: Mapping[str, float] | np.ndarray, *, du: np.ndarray | None = None,
                    dF: np.ndarray | None = None, dy: np.ndarray | None = None,
                    w: np.ndarray | None = None, y_step: float = 0.0, u_step: float = 0.0) -> dict[str, np.ndarray]:
    """:func:`replay` with signals injected where a model error can enter the loop: ``du`` [MU]
    added to the controller's output on its way to the plant (actuator), ``dF`` [N] a force on the
    ball held over each sample (mechanics), ``dy`` [MU] added to the reading (sensor); each one
    value per sample, or None; ``y_step``, ``u_step`` [MU]: the converters' steps (0: none). Same
    start as :func:`replay`; with no injection the same result."""
    start, u_hold = _settled_at_first_reading(rec, params)
    return fast_loop.closed_loop(start, rec.w if w is None else w, pid=record_controller(rec), u_hold=u_hold,
                                 du=du, dF=dF, dy=dy, y_step=y_step, u_step=u_step, y_before=rec.y_before)

# ----------------------------------------------------------------------------- prediction-error replay

@dataclass(frozen=True)
class NoiseModel:
    """The disturbances of a record, as the prediction-error replay models them.

    Parameters
    ----------
    q_force : float
        RMS of the random force on the ball [N] (a first-order Gauss-Markov process).
    f_force : float
        Its corner frequency [Hz]: small for a slow drift, large for white noise.
    r_sensor : float
        RMS of the white sensor noise on the reading [MU].
    f_sensor : float
        Corner [Hz] of a coloured part of the sensor noise, a first-order Gauss-Markov process on
        the reading beside the white part (a sensor whose noise is low-passed before the A/D
        samples it); 0: none, the sensor noise is white.
    r_coloured : float
        RMS of that coloured part [MU] (0 when ``f_sensor`` is 0).
    """

    q_force: float
    f_force: float
    r_sensor: float
    f_sensor: float = 0.0
    r_coloured: float = 0.0

    @property
    def coloured(self) -> bool:
        """Whether the sensor noise has a coloured part."""
        return self.f_sensor > 0

    @property
    def sensor_rms(self) -> float:
        """RMS of the whole sensor noise, white and coloured [MU]."""
        return float(np.hypot(self.r_sensor, self.r_coloured if self.coloured else 0.0))

    def to_json(self) -> dict[str, float]:
        return {"q_force_N": self.q_force, "f_force_Hz": self.f_force, "r_sensor_MU": self.r_sensor,
                "f_sensor_Hz": self.f_sensor, "r_coloured_MU": self.r_coloured if self.coloured else 0.0}


#: Default prediction horizon [s]: well inside the loop's bandwidth (about 30 Hz), long enough for
#: lags and delays of a few ms to show.
HORIZON_S = 0.02


def horizon_samples(horizon_s: float, ts: float) -> int:
    """A prediction horizon [s] in whole samples: at least one, or 0 (the filter alone) for 0 s."""
    return max(1, int(round(horizon_s / ts))) if horizon_s > 0 else 0


def predict(rec: Record, params: Mapping[str, float], noise: NoiseModel, *, horizon_s: float = HORIZON_S,
            stride: int = 1) -> dict[str, np.ndarray]:
    """The record replayed by prediction: an extended Kalman filter on the C plant follows the
    measured past, and the closed loop (plant + the record's PID) is predicted ``horizon_s``
    ahead from every ``stride``-th sample.

    Parameters
    ----------
    rec : Record
        The closed-loop record.
    params : mapping
        FMU parameter values [SI units] over the C defaults.
    noise : NoiseModel
        The random force and sensor noise the filter assumes (:func:`estimate_noise`).
    horizon_s : float
        Prediction horizon [s] (rounded to whole samples, at least one); 0: no predictions, the
        filter's innovations only.
    stride : int
        A prediction from every ``stride``-th sample (1: every sample).

    Returns
    -------
    dict of ndarray
        ``y_pred``, ``u_pred`` [MU]: the predictions of y[k], u[k] made ``horizon`` samples
        earlier (NaN where none ends); ``innov`` [MU], ``innov_var`` [MU²]: one-step innovations.
    """
    start, u_hold = _settled_at_first_reading(rec, params)
    horizon = horizon_samples(horizon_s, rec.ts)
    return fast_loop.predict(start, record_controller(rec), rec.w, rec.y, rec.u, u_hold,
                        q_force=noise.q_force, f_force=noise.f_force, r_sensor=noise.r_sensor, horizon=horizon,
                        stride=stride, f_sensor=noise.f_sensor, r_coloured=noise.r_coloured,
                        y_before=rec.y_before)


def _usable(out: Mapping[str, np.ndarray], mask: np.ndarray | None, skip: int) -> tuple[np.ndarray, np.ndarray]:
    """The innovations e and their variances s that a likelihood uses: finite, s > 0, from ``skip``
    on, within ``mask`` (all when None)."""
    e, s = out["innov"], out["innov_var"]
    ok = np.isfinite(e) & np.isfinite(s) & (s > 0)
    ok[:skip] = False
    if mask is not None:
        ok &= mask
    return e[ok], s[ok]


def _nll(out: Mapping[str, np.ndarray], mask: np.ndarray | None = None, skip: int = 200) -> float:
    """Mean of ``log(s) + e²/s`` over the usable innovations from ``skip`` on (within ``mask``)."""
    e, s = _usable(out, mask, skip)
    return float(np.mean(np.log(s) + e ** 2 / s)) if len(e) else float("inf")


def _scaled_nll(out: Mapping[str, np.ndarray], skip: int = 200,
                c_range: tuple[float, float] = (0.0, np.inf)) -> tuple[float, float]:
    """:func:`_nll` at the best common factor ``c`` of every noise variance within ``c_range``, and ``c``.

    The random force and the sensor noise (white and coloured) are the only noises of the filter's
    model, so multiplying all their variances by ``c`` multiplies every covariance it propagates by
    ``c`` (but for the fixed part of its start covariance, forgotten within the skipped samples):
    the gain, the state estimates and the innovations e stay the same and their variances s become
    c·s. The mean of ``log(c·s) + e²/(c·s)`` is least at ``c = mean(e²/s)``, where it is
    ``mean(log s) + log c + 1``: the likelihood concentrated on the levels' ratios, one dimension
    fewer for the search (Harvey 1989, *Forecasting, structural time series models and the Kalman
    filter*, Sec. 3.4). Held within ``c_range`` (the levels' bounds; a record without noise has
    ``mean(e²/s)`` near 0), the mean is ``mean(log s) + log c + mean(e²/s)/c``."""
    e, s = _usable(out, None, skip)
    if not len(e):
        return float("inf"), 1.0
    m = float(np.mean(e ** 2 / s))
    c = float(np.clip(m, *c_range))
    if not c > 0:
        return float("inf"), 1.0
    return float(np.mean(np.log(s))) + float(np.log(c)) + m / c, c


def innovation_nll(rec: Record, params: Mapping[str, float], noise: NoiseModel, skip: int = 200,
                   mask: np.ndarray | None = None) -> float:
    """Mean negative log-likelihood of the one-step innovations (Gaussian; constants dropped, times
    2), over the samples of ``mask`` (all when None)."""
    return _nll(predict(rec, params, noise, horizon_s=0.0), mask, skip)


#: The coloured part's corner [Hz] is searched from this up to the Nyquist frequency. Within the
#: loop's bandwidth (about 30 Hz) a coloured reading error is what a model that lacks a dynamic
#: effect leaves: a model without the record's 3 ms amplifier lag took its ringing for sensor noise
#: with a 2 Hz corner (3e-3 MU), and a baseline without a 37 Hz pickup took the pickup for sensor
#: noise with a 20 Hz corner. So sensor noise is coloured only above the loop's bandwidth, and a
#: fit whose corner ends on this bound (within 1 %), or whose coloured RMS ends below a tenth of the
#: white one (1 % of the variance), is practically off: the model stays white.
F_SENSOR_MIN = 30.0
#: The coloured part is tried only when the white filter's innovations have a lag-1 correlation
#: beyond this many standard errors (1/√N) of a white sequence's.
COLOURED_SCREEN = 3.0


#: The disturbance levels' Nelder-Mead searches (the random force's RMS and corner, the sensor
#: noise) start again from where they stop, with a fresh simplex around that point, up to this many
#: times, while a restart lowers the mean ``log s + e²/s`` by more than :data:`RESTART_GAIN`. The
#: likelihood is a long, flat ridge along the force's RMS and corner, on which a search stops where
#: its simplex has shrunk, not at the optimum: on the project emulator's 37 Hz pickup of seed 6300
#: the final model's search ended at a 17.5 Hz corner, 0.0098 a sample (118 nats) below the 2.5 Hz
#: one that a restart reaches, and its 20 ms prediction missed the true model's by 21 %. A restart
#: is the usual cure of a Nelder-Mead that stagnates (Kelley 1999, SIAM J. Optim. 10(1), 43-55; scipy's
#: search has no restart of its own).
NOISE_RESTARTS = 2
#: ... the fall of the mean ``log s + e²/s`` below which a restart counts as none: the searches' own
#: ``fatol``.
RESTART_GAIN = 1e-4
#: ... and the evaluations a restart may make.
RESTART_MAXFEV = 40


def minimize_restarted(cost, z0: np.ndarray, *, maxfev: int, restarts: int = NOISE_RESTARTS,
                       xatol: float = 0.05, fatol: float = RESTART_GAIN, step: float | None = None,
                       bounds: tuple[np.ndarray, np.ndarray] | None = None):
    """scipy's Nelder-Mead from ``z0``, then again from its end (a fresh simplex: scipy's default,
    5 % of each coordinate) up to ``restarts`` times while that lowers the cost by more than
    ``fatol``. ``step``: the first simplex's edge along each coordinate (default: scipy's).
    Returns scipy's result of the best run, with ``nfev`` summed over the runs."""
    opts = {"xatol": xatol, "fatol": fatol}
    z0 = np.asarray(z0, dtype=float)
    first = {} if step is None else {"initial_simplex": np.vstack([z0, z0 + step * np.eye(len(z0))])}
    box = None if bounds is None else list(zip(*bounds))
    res = minimize(cost, z0, method="Nelder-Mead", bounds=box, options={**opts, "maxfev": maxfev, **first})
    nfev = res.nfev
    for _ in range(restarts):
        again = minimize(cost, res.x, method="Nelder-Mead", bounds=box, options={**opts, "maxfev": RESTART_MAXFEV})
        nfev += again.nfev
        gained = res.fun - again.fun if np.isfinite(again.fun) else 0.0    # inf - inf: no gain
        if again.fun < res.fun:
            res = again
        if not gained > fatol:
            break
    res.nfev = nfev
    return res


#: The white disturbance estimate's coarse grid (:func:`_concentrated_search`): the ratio of the
#: random force's RMS to the sensor noise's as these multiples of the start's (0.3 % of the weight
#: over the reading's white noise; a 50 Hz pickup the model lacked was best taken by a force some 50 times
#: that ratio), each at these corners [Hz]; and the edge of the first simplex around the grid's
#: best point [natural log: a factor 1.65].
NOISE_GRID_RATIOS = (1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3)
NOISE_GRID_CORNERS_HZ = (2.0, 20.0, 200.0)
NOISE_STEP = 0.5

#: The positions, in a noise model's levels (q_force, f_force, r_sensor, f_sensor, r_coloured), of
#: those that are RMS values: a common factor of their variances is concentrated out of the
#: likelihood (:func:`_scaled_nll`).
_RMS_LEVELS = (0, 2, 4)


def _concentrated_search(rec: Record, params: Mapping[str, float], z0: np.ndarray, lo: np.ndarray,
                         hi: np.ndarray, *, maxfev: int, grid: bool = False) -> tuple[np.ndarray, float]:
    """The logarithms of the noise levels of greatest innovation likelihood (3: q_force, f_force,
    r_sensor; or 5: and f_sensor, r_coloured), searched from ``z0`` within ``lo``..``hi``.

    The search (:func:`minimize_restarted`) holds r_sensor at its start and moves the others; the
    common factor of the variances is then the closed-form optimum of :func:`_scaled_nll`, which
    scales every RMS level. The same maximum as a search over every level, with one coordinate
    fewer. With ``grid``, the search starts from the best point of a coarse grid
    (:data:`NOISE_GRID_RATIOS` × :data:`NOISE_GRID_CORNERS_HZ` around ``z0``'s force), whose
    likelihood has plateaus: a record with a 50 Hz pickup the model lacked has one where the sensor
    noise takes it and a deeper one where a random force does, and a search from the usual start
    ended on the first. Returns the levels' logarithms (clipped to ``lo``..``hi``) and the mean
    ``log s + e²/s`` there."""
    n = len(z0)
    rms = [i for i in _RMS_LEVELS if i < n]
    moved = [i for i in range(n) if i != 2]
    # an RMS level moves relative to the held r_sensor: its bounds widen by r_sensor's range
    span = hi[2] - lo[2]
    lo_m, hi_m = lo.astype(float).copy(), hi.astype(float).copy()
    lo_m[rms] -= span
    hi_m[rms] += span

    # the factor keeps r_sensor within its bounds
    c_range = (float(np.exp(2.0 * (lo[2] - z0[2]))), float(np.exp(2.0 * (hi[2] - z0[2]))))

    def levels(zm: np.ndarray) -> np.ndarray:
        z = np.array(z0, dtype=float)
        z[moved] = np.clip(zm, lo_m[moved], hi_m[moved])
        return z

    def run(zm: np.ndarray) -> tuple[float, float]:
        try:
            return _scaled_nll(predict(rec, params, NoiseModel(*np.exp(levels(zm))), horizon_s=0.0),
                               c_range=c_range)
        except ValueError:
            return float("inf"), 1.0

    start = np.asarray(z0, dtype=float)[moved]
    if grid:
        points = [np.array([start[0] + np.log(k), np.log(f), *start[2:]])
                  for k in NOISE_GRID_RATIOS for f in NOISE_GRID_CORNERS_HZ]
        start = min(points, key=lambda zm: run(zm)[0])
    res = minimize_restarted(lambda zm: run(zm)[0], start, maxfev=maxfev, step=NOISE_STEP,
                             bounds=(lo_m[moved], hi_m[moved]))
    cost, c = run(res.x)
    z = levels(res.x)
    z[rms] += 0.5 * np.log(c)
    return np.clip(z, lo, hi), cost


#: The last disturbance estimates (:func:`estimate_noise`), by record and arguments: the diagnosis asks
#: for the same model's estimate at several stages (a fit's check, then the verdict), and each is a
#: Nelder-Mead search of up to 80 filter passes. An entry holds its record, so that the record's
#: ``id`` in the key is never reused while the entry lives.
ESTIMATES_KEPT = 8
_ESTIMATES = Memo(ESTIMATES_KEPT)


def estimate_noise(rec: Record, params: Mapping[str, float], *, coloured: bool = True,
                   info: dict | None = None, sensor: NoiseModel | None = None) -> NoiseModel:
    """:func:`_estimate_noise`, or the same estimate made before for the same record and arguments
    (``info``, which receives the figures of a fresh estimate, bypasses it)."""
    if info is not None:
        return _estimate_noise(rec, params, coloured=coloured, info=info, sensor=sensor)
    key = (id(rec), tuple(sorted((k, float(v)) for k, v in params.items())), coloured, sensor)
    return _ESTIMATES.get(key, lambda: (rec, _estimate_noise(rec, params, coloured=coloured, sensor=sensor)),
                          valid=lambda hit: hit[0] is rec)[1]


def _estimate_noise(rec: Record, params: Mapping[str, float], *, coloured: bool = True,
                    info: dict | None = None, sensor: NoiseModel | None = None) -> NoiseModel:
    """The record's disturbance levels by maximum likelihood of the filter's innovations: the
    random force's RMS and corner and the sensor noise's RMS: the likelihood concentrated on the
    force's RMS relative to the sensor noise's and the corner (:func:`_concentrated_search`), searched
    by Nelder-Mead over their logarithms from the best point of a coarse grid around the reading's
    white noise and 0.3 % of the weight, and again from where it stops (:func:`minimize_restarted`).

    Then, with ``coloured``, whether the sensor noise has a coloured part (``f_sensor``,
    ``r_coloured``), chosen by the held-out criterion of the effects (:func:`.acceptance.accept`):
    the split of the sensor noise into a white and a coloured part, with its corner (from
    :data:`F_SENSOR_MIN`, above the loop's bandwidth), is fitted on
    the fit blocks (alternating :data:`.acceptance.BLOCK` s) with the random force of the white fit,
    and kept only when, on the held-out blocks, its likelihood-ratio statistic against the white
    model (``N·Δ`` of the mean ``log s + e²/s``, 2 more parameters) exceeds the χ²(2) quantile at
    1 − 0.001 and the innovations' held-out cost falls by at least 3 %; the five levels are then
    refitted on the whole record, and the white model kept when that fit ends practically off (its
    corner on :data:`F_SENSOR_MIN`, or its RMS below a tenth of the white part's). The split is tried only when the white filter's innovations are
    correlated from one sample to the next (:data:`COLOURED_SCREEN`). A record whose sensor noise
    is white keeps the white model, the one of before. ``info`` (a dict) receives the choice's figures.

    With ``sensor`` (a noise model with a coloured part), that coloured part is held and only the
    random force and the white sensor noise are fitted: the sensor's noise is the record's, not the
    model's, and a model that lacks an effect (a pickup) would otherwise take it for coloured sensor
    noise, which makes its random force incomparable with another model's (the force growth of the
    noise-floor rule)."""
    p = as_params(params)
    d2 = np.diff(rec.y, 2)
    r0 = max(float(1.4826 * np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0), 1e-5)
    z0 = np.log([3e-3 * p.m_k * p.g, 20.0, r0])
    lo, hi = np.log([1e-6 * p.m_k * p.g, 0.05, 1e-6]), np.log([0.5 * p.m_k * p.g, 1.0 / rec.ts, 0.05])

    held = sensor is not None and sensor.coloured
    if held:
        # the coloured part held: its RMS does not scale with the others, so every level is searched
        extra = (sensor.f_sensor, sensor.r_coloured)
        z0[2] = np.log(max(min(sensor.r_sensor, 0.05), 1e-6))

        def cost(z: np.ndarray) -> float:
            z = np.clip(z, lo, hi)
            try:
                return innovation_nll(rec, params, NoiseModel(*np.exp(z), *extra))
            except ValueError:
                return float("inf")

        res = minimize_restarted(cost, z0, maxfev=80)
        return NoiseModel(*(float(v) for v in np.exp(np.clip(res.x, lo, hi))), *extra)
    z, _ = _concentrated_search(rec, params, z0, lo, hi, maxfev=80, grid=True)
    white = NoiseModel(*(float(v) for v in np.exp(z)))
    if not coloured:
        return white
    return _coloured_choice(rec, params, white, info)


def _coloured_choice(rec: Record, params: Mapping[str, float], white: NoiseModel, info: dict | None) -> NoiseModel:
    """:func:`estimate_noise`'s choice of a coloured part of the sensor noise beside ``white``."""
    fit = fit_blocks(rec.t)
    held = ~fit
    out_w = predict(rec, params, white, horizon_s=0.0)
    # a screen that saves the fits on white sensor noise: a coloured part the white filter lacks
    # leaves its innovations correlated from one sample to the next
    e = out_w["innov"][200:]
    e = e[np.isfinite(e)] - np.mean(e[np.isfinite(e)]) if np.isfinite(e).any() else np.zeros(0)
    rho = float(np.dot(e[1:], e[:-1]) / np.dot(e, e)) if len(e) > 2 and np.dot(e, e) > 0 else 0.0
    if info is not None:
        info.update({"lag1_correlation": rho, "lag1_threshold": COLOURED_SCREEN / np.sqrt(max(len(e), 1))})
    if abs(rho) * np.sqrt(len(e)) < COLOURED_SCREEN:
        if info is not None:
            info.update({"coloured_tried": False, "coloured_accepted": False})
        return white
    nll_w_fit, nll_w_held = _nll(out_w, fit), _nll(out_w, held)
    f_hi = 0.5 / rec.ts
    # the white fit's sensor noise split between a white and a coloured part, from a corner of 1/10
    # of the sample rate: log(r_white), log(r_coloured), log(f_sensor)
    lo3, hi3 = np.log([1e-6, 1e-6, F_SENSOR_MIN]), np.log([0.05, 0.05, f_hi])
    z3 = np.log([0.6 * white.r_sensor, 0.8 * white.r_sensor, 0.1 / rec.ts])

    def model3(z: np.ndarray) -> NoiseModel:
        rw, rc, fs = np.exp(np.clip(z, lo3, hi3))
        return NoiseModel(white.q_force, white.f_force, float(rw), float(fs), float(rc))

    def cost3(z: np.ndarray) -> float:
        try:
            return innovation_nll(rec, params, model3(z), mask=fit)
        except ValueError:
            return float("inf")

    res3 = minimize(cost3, z3, method="Nelder-Mead", options={"xatol": 0.05, "fatol": 1e-4, "maxfev": 60})
    split = model3(res3.x)
    if not res3.fun < nll_w_fit:
        if info is not None:
            info.update({"coloured_tried": True, "coloured_accepted": False, "fit_nll_white": nll_w_fit,
                         "fit_nll_coloured": float(res3.fun)})
        return white
    try:
        nll_c_held = innovation_nll(rec, params, split, mask=held)
    except ValueError:
        return white
    n_held = int(np.sum(held[200:]))
    ok, figs = accept_nll(nll_w_held, nll_c_held, n_held, 2)
    if info is not None:
        info.update({"coloured_tried": True, "coloured_accepted": ok, "held_out_nll_white": nll_w_held,
                     "held_out_nll_coloured": nll_c_held, "split": split, **figs})
    if not ok:
        return white
    # all five levels on the whole record, from the split
    lo5 = np.log([1e-6 * as_params(params).m_k * as_params(params).g, 0.05, 1e-6, F_SENSOR_MIN, 1e-6])
    hi5 = np.log([0.5 * as_params(params).m_k * as_params(params).g, 1.0 / rec.ts, 0.05, f_hi, 0.05])
    z5 = np.log([split.q_force, split.f_force, split.r_sensor, split.f_sensor, split.r_coloured])

    best, cost5 = _concentrated_search(rec, params, z5, lo5, hi5, maxfev=80)
    # and from the split's sensor noise with the random force where the white fit started: the white
    # fit's force has taken the coloured noise's share of the innovations (a corner near the sample
    # rate), and from there the search may not find its way back to a slow force
    z5b = np.concatenate([np.log([3e-3 * as_params(params).m_k * as_params(params).g, 20.0]), z5[2:]])
    other, cost5b = _concentrated_search(rec, params, z5b, lo5, hi5, maxfev=80)
    if cost5b < cost5:
        best = other
    nm = NoiseModel(*(float(v) for v in np.exp(best)))
    off = nm.f_sensor <= 1.01 * F_SENSOR_MIN or nm.r_coloured < 0.1 * nm.r_sensor
    if info is not None:
        info.update({"coloured_off": off, "whole_record": nm})
        if off:
            info["coloured_accepted"] = False
    return white if off else nm
