"""Replaying a record in closed loop on the C plant (cffi fast path).

The record's controller and reference drive the model (:func:`maglev_cosim.loop.simulate.simulate`); the
loop starts settled at the first reading ``y[0]``: the ball at rest where the model's sensor
reads ``y[0]``, the current at equilibrium there, ``e[−1] = 0`` and the integrator holding the
equilibrium input.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from ..loop import fast_loop
from ..loop.controllers import Controller
from ..loop.pid import PID
from ..loop.simulate import settled_start_vector
from ..plant import fast, formulas
from ..plant.params import as_params, get_params
from ..records.record import Record


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
    replay of a record starts: at rest where the model reads ``y[0]``, the current at equilibrium
    there (:func:`~maglev_cosim.loop.simulate.settled_start`); and the hold input [MU]. It works on the
    vector: a fit replays thousands of times, and building parameter objects cost a third of each."""
    pv = fast.param_vector(params)
    return settled_start_vector(pv, formulas.position(pv, float(rec.y[0])))


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
                            du=du, dF=dF, dy=dy, y_step=y_step, u_step=u_step)

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
    """

    q_force: float
    f_force: float
    r_sensor: float

    def to_json(self) -> dict[str, float]:
        return {"q_force_N": self.q_force, "f_force_Hz": self.f_force, "r_sensor_MU": self.r_sensor}


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
                        stride=stride)


def innovation_nll(rec: Record, params: Mapping[str, float], noise: NoiseModel, skip: int = 200) -> float:
    """Mean negative log-likelihood of the one-step innovations (Gaussian; constants dropped)."""
    out = predict(rec, params, noise, horizon_s=0.0)
    e, s = out["innov"][skip:], out["innov_var"][skip:]
    ok = np.isfinite(e) & np.isfinite(s) & (s > 0)
    return float(np.mean(np.log(s[ok]) + e[ok] ** 2 / s[ok])) if ok.any() else float("inf")


def estimate_noise(rec: Record, params: Mapping[str, float]) -> NoiseModel:
    """The record's disturbance levels by maximum likelihood of the filter's innovations: the
    random force's RMS and corner and the sensor noise's RMS (Nelder-Mead over their logarithms,
    started from the reading's white noise and 0.3 % of the weight at 20 Hz)."""
    p = as_params(params)
    d2 = np.diff(rec.y, 2)
    r0 = max(float(1.4826 * np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0), 1e-5)
    z0 = np.log([3e-3 * p.m_k * p.g, 20.0, r0])
    lo, hi = np.log([1e-6 * p.m_k * p.g, 0.05, 1e-6]), np.log([0.5 * p.m_k * p.g, 1.0 / rec.ts, 0.05])

    def cost(z: np.ndarray) -> float:
        z = np.clip(z, lo, hi)
        try:
            return innovation_nll(rec, params, NoiseModel(*np.exp(z)))
        except ValueError:
            return float("inf")

    res = minimize(cost, z0, method="Nelder-Mead", options={"xatol": 0.05, "fatol": 1e-4, "maxfev": 80})
    return NoiseModel(*(float(v) for v in np.exp(np.clip(res.x, lo, hi))))
