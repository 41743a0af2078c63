"""The fit problem: a record, the parameter values the free ones are applied to, the weights of
the y and u errors, and the samples that count; least squares over parameterizations."""

from __future__ import annotations

import hashlib
import inspect
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np
from scipy.optimize import least_squares

from ..records.record import Record
from .memo import Memo
from .replay import HORIZON_S, NoiseModel, estimate_noise, horizon_samples, predict, record_controller, replay

#: Shortest and longest RK4 substep [s] of the replays the fits run (:func:`fit_solver_step`; the
#: plant shortens it further where friction, an eddy lag or a voltage drive needs it).
FIT_SOLVER_STEP = 2.5e-4
FIT_SOLVER_STEP_MAX = 1e-3


def fit_solver_step(values: Mapping[str, float]) -> float:
    """The RK4 substep [s] of a fit's replay: :data:`FIT_SOLVER_STEP_MAX`, shortened to a sixth of
    a force lag ``T_F`` and half an amplifier lag ``T_a``, never below :data:`FIT_SOLVER_STEP`
    (nor below the plant's own ``solver_step``).

    Measured against 0.1 ms on a 12 s closed-loop record of the benchmark family (seed 3900) with
    each catalogue effect's example: at most 7.7e-7 MU in y and 3.7e-6 MU in u (a 0.5 ms force
    lag, at the 0.25 ms floor; a 3 ms amplifier lag, a 2 ms sensor lag at 1 ms: 2.4e-6 and
    2.8e-6 MU in u), a few thousandths of the sensor noise and of u's noise response. A replay
    without lags takes 1.3 ms at 1 ms against 2.8 ms at 0.25 ms. The lags' own errors grow as
    (h/T)^3 to (h/T)^4: a 3 ms force lag at 1 ms moved u by 2.2e-5 MU, a 0.3 ms amplifier lag at
    1 ms by 5.2e-5 MU, hence their bounds."""
    h = FIT_SOLVER_STEP_MAX
    if values.get("T_F", 0.0) > 0:
        h = min(h, values["T_F"] / 6)
    if values.get("T_a", 0.0) > 0:
        h = min(h, values["T_a"] / 2)
    return max(h, FIT_SOLVER_STEP, values.get("solver_step", 0.0))


def on_fit_steps(values: Mapping[str, float]) -> dict[str, float]:
    """``values`` with the RK4 substep of the fits' replays (:func:`fit_solver_step`)."""
    return {**values, "solver_step": fit_solver_step(values)}

#: Threads that evaluate independent replays side by side: a fit's finite-difference Jacobian
#: columns and a batch of an effect's starts (:func:`thread_map`). The replays run in C with the GIL
#: released (cffi), so two threads use two cores; the numbers are those of one thread, evaluation by
#: evaluation. The search's worker processes, which keep the cores busy themselves, take one each
#: (:func:`one_thread`): with two there, four threads shared two cores, and the bench's 12 s record
#: took 3.7-3.9 s with one effect and 4.6-4.8 s with two, against 3.55-3.64 s and 4.43-4.57 s.
THREADS = min(2, os.cpu_count() or 1)


def one_thread() -> None:
    """Replays one at a time in this process (a worker process of the search)."""
    global THREADS
    THREADS = 1

#: Whether scipy's least squares takes ``workers`` (SciPy 1.16 on); older ones take the columns one by one.
_LSQ_WORKERS = "workers" in inspect.signature(least_squares).parameters

_T = TypeVar("_T")
_R = TypeVar("_R")


def thread_map(fn: Callable[[_T], _R], items: Iterable[_T]) -> list[_R]:
    """``[fn(x) for x in items]``, in order, on :data:`THREADS` threads (for replays, which release
    the GIL)."""
    items = list(items)
    if THREADS <= 1 or len(items) < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=min(THREADS, len(items))) as ex:
        return list(ex.map(fn, items))


@dataclass(frozen=True)
class Coord:
    """One fit coordinate: name, scale (a typical size, so the solver sees order 1) and bounds."""

    name: str
    scale: float
    lo: float
    hi: float


class Parameterization:
    """A set of FMU parameters fitted in coordinates ``coords`` (the identity map by default)."""

    params: tuple[str, ...] = ()
    coords: tuple[Coord, ...] = ()

    def to_params(self, z: Sequence[float]) -> dict[str, float]:
        """Parameter values [SI units] from coordinates ``z``."""
        return {c.name: float(v) for c, v in zip(self.coords, z)}

    def to_coords(self, values: Mapping[str, float]) -> list[float]:
        """Coordinates of parameter values."""
        return [float(values[c.name]) for c in self.coords]

    def uncertainty_scales(self) -> dict[str, float]:
        """A step size per FMU parameter for Jacobians of the parameters themselves."""
        return {c.name: c.scale for c in self.coords}


@dataclass
class Problem:
    """What every fit needs; picklable so that candidates can be fitted in worker processes."""

    rec: Record
    base: dict[str, float]          # complete parameter set the free parameters are applied to
    sigma_y: float                  # [MU] weights: residuals are divided by these
    sigma_u: float
    mask: np.ndarray                # samples whose error counts in the fit

    noise: NoiseModel | None = None  # set: the errors are those of the k-step prediction, not the free run
    stride: int = 5                 # prediction mode: a prediction from every stride-th sample
    horizon_s: float = HORIZON_S    # prediction mode: how far ahead [s] (one sample: the PEM criterion)

    @property
    def mode(self) -> str:
        """``free run`` or ``prediction``: which replay's errors the fits minimise."""
        return "free run" if self.noise is None else "prediction"

    def model(self, values: Mapping[str, float]) -> dict[str, float]:
        """The whole parameter set: ``values`` over the base. A parameter ``values`` lacks is the
        base's, never the C table's default (the baseline's T_a = 0 against the table's 0.3 ms
        amplifier lag)."""
        return {**self.base, **values}

    def disturbances(self, values: Mapping[str, float], *, fit_steps: bool = False) -> NoiseModel:
        """The record's disturbances estimated for the whole model (:func:`~.replay.estimate_noise`);
        ``fit_steps``: on the fits' RK4 substeps (:func:`on_fit_steps`), as the verdict estimates them."""
        full = self.model(values)
        return estimate_noise(self.rec, on_fit_steps(full) if fit_steps else full)

    def free_run(self, values: Mapping[str, float]) -> dict[str, np.ndarray]:
        """The record's closed loop replayed with ``values`` over the base (all signals)."""
        return replay(self.rec, self.model(values))

    def simulate(self, values: Mapping[str, float]) -> dict[str, np.ndarray]:
        """What the fits compare with the record: ``y`` and ``u`` of the free run, or of the
        ``HORIZON_S`` prediction (NaN where no prediction ends) in prediction mode; on RK4
        substeps of at most :func:`fit_solver_step` (the figures reported use the plant's own)."""
        vals = on_fit_steps(self.model(values))
        return _SIMULATED.get(self._key(vals), lambda: self._simulated(vals), seal=_read_only)

    def simulated(self, values: Mapping[str, float]) -> tuple[tuple, dict[str, np.ndarray]]:
        """:meth:`simulate` with the key under which it is kept, for :func:`remember` in another
        process (a worker's fit sends the replay of the values it ended at to the judgement)."""
        return self._key(on_fit_steps(self.model(values))), self.simulate(values)

    def _key(self, vals: Mapping[str, float]) -> tuple:
        pred = self.noise is not None
        return (record_fingerprint(self.rec), self.noise, self.stride if pred else 0,
                self.horizon_s if pred else 0.0, _values_key(vals))

    def _simulated(self, vals: dict[str, float]) -> dict[str, np.ndarray]:
        if self.noise is None:
            sim = replay(self.rec, vals)
            return {"y": sim["y"], "u": sim["u"]}
        pr = predict(self.rec, vals, self.noise, stride=self.stride, horizon_s=self.horizon_s)
        return {"y": pr["y_pred"], "u": pr["u_pred"]}

    def compared(self) -> np.ndarray:
        """Samples where :meth:`simulate` gives a value: all in free-run mode, the ends of the
        predictions in prediction mode (the same set for every parameter value)."""
        n = self.rec.n
        if self.noise is None:
            return np.ones(n, bool)
        k = horizon_samples(self.horizon_s, self.rec.ts)
        out = np.zeros(n, bool)
        out[np.arange(0, max(n - k, 0), self.stride) + k] = True
        return out

    def with_base(self, values: Mapping[str, float]) -> Problem:
        """The same problem with ``values`` folded into the base."""
        return replace(self, base={**self.base, **values})

    def with_mask(self, mask: np.ndarray) -> Problem:
        return replace(self, mask=mask)


#: The replays :meth:`Problem.simulate` keeps (y and u, 0.2 MB for a 12 s record), most recent last: a
#: fit's start is its scored start's replay, a candidate's fit to convergence and its refit to the
#: model's tolerance retrace its screen's path before they go on (the same replays, one by one), and
#: the judgement replays the values the fit ended at. The same numbers: a replay is a function of
#: the record and the whole parameter set.
SIMULATED_KEPT = 256
_SIMULATED = Memo(SIMULATED_KEPT)


def record_fingerprint(rec: Record) -> bytes:
    """A digest of what a replay of ``rec`` reads besides the parameters (the reference, the readings
    and the actuator signal, the sample time, the controller and its start), kept on the record beside
    the arrays it was taken of (taken again when one of them is replaced)."""
    arrays = (rec.w, rec.y, rec.u)
    extra = (float(rec.ts), rec.y_before, repr(record_controller(rec)))
    memo = rec.__dict__.get("_replay_fingerprint")
    if memo is not None and all(a is b for a, b in zip(memo[0], arrays)) and memo[1] == extra:
        return memo[2]
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    h.update(repr(extra).encode())
    rec.__dict__["_replay_fingerprint"] = (arrays, extra, h.digest())
    return rec.__dict__["_replay_fingerprint"][2]


def remember(key: tuple, sim: dict[str, np.ndarray]) -> None:
    """Keeps a replay made elsewhere (:meth:`Problem.simulated`) as if :meth:`Problem.simulate` had made it."""
    _SIMULATED.get(key, lambda: sim, seal=_read_only)


def _values_key(vals: Mapping[str, float]) -> tuple[tuple[str, ...], bytes]:
    names = tuple(sorted(vals))
    return names, np.array([vals[k] for k in names], dtype=float).tobytes()


def _read_only(sim: dict[str, np.ndarray]) -> None:
    for a in sim.values():
        a.flags.writeable = False


def residuals(prob: Problem, values: Mapping[str, float], mask: np.ndarray | None = None) -> np.ndarray:
    """Weighted residual vector (y errors, then u errors) of a replay with ``values`` applied.
    A parameter set the plant rejects (say x_0 pushed below x_max) costs as much as a ball
    lying on a stop: the search then turns away from it instead of failing."""
    m = prob.mask if mask is None else mask
    if prob.noise is not None:          # prediction mode: only where a prediction ends (free run: every sample)
        m = m & prob.compared()
    try:
        sim = prob.simulate(values)
    except ValueError:
        sim = {"y": np.zeros(prob.rec.n), "u": np.full(prob.rec.n, prob.rec.u_max)}
    return np.concatenate([(prob.rec.y - sim["y"])[m] / prob.sigma_y, (prob.rec.u - sim["u"])[m] / prob.sigma_u])


def stacked(probs: Problem | Sequence[Problem], values: Mapping[str, float]) -> np.ndarray:
    """:func:`residuals` of one problem, or of several records' problems one after the other (the
    same ``values`` on each: records calibrated together)."""
    if isinstance(probs, Problem):
        return residuals(probs, values)
    return np.concatenate([residuals(p, values) for p in probs])


def cost_on(prob: Problem, values: Mapping[str, float], mask: np.ndarray) -> float:
    """Mean squared weighted residual on the samples of ``mask``."""
    return float(np.mean(residuals(prob, values, mask) ** 2))


@dataclass
class Fit:
    """The result of fitting a set of free parameters."""

    values: dict[str, float]
    cost: float                      # mean squared weighted residual on the fit samples
    nfev: int = 0
    converged: bool = True           # ended by a tolerance, not by max_nfev: more evaluations change nothing


def _values(parts: Sequence[Parameterization], z: np.ndarray) -> dict[str, float]:
    out: dict[str, float] = {}
    k = 0
    for part in parts:
        n = len(part.coords)
        out.update(part.to_params(z[k:k + n]))
        k += n
    return out


#: The least-squares tolerances (``ftol`` and ``xtol``) of the model's own fits (:func:`fit`).
FIT_TOL = 1e-6


def fit(prob: Problem | Sequence[Problem], parts: Sequence[Parameterization], z0: Sequence[Sequence[float]], *,
        max_nfev: int = 60, tol: float = FIT_TOL) -> Fit:
    """Least squares (trust-region reflective) over the coordinates of ``parts``, started at
    ``z0`` (one coordinate list per part), in scaled coordinates; on several problems (records
    calibrated together) over all their residuals (:func:`stacked`). ``tol``: the relative fall of
    the cost (``ftol``) and step of the scaled coordinates (``xtol``) at which it ends (a candidate
    effect's fits take :data:`~.pipeline.CANDIDATE_TOL`)."""
    coords = [c for part in parts for c in part.coords]
    sc = np.array([c.scale for c in coords])
    lo = np.array([c.lo for c in coords]) / sc
    hi = np.array([c.hi for c in coords]) / sc
    start = np.array([v for z in z0 for v in z], dtype=float)
    zs = np.clip(start / sc, lo + 1e-12, hi - 1e-12)

    def fun(z: np.ndarray) -> np.ndarray:
        return stacked(prob, _values(parts, z * sc))

    # the Jacobian's columns (one replay each) on THREADS threads: the same evaluations as one by one
    with ThreadPoolExecutor(max_workers=THREADS) as ex:
        par = {"workers": ex.map} if _LSQ_WORKERS and THREADS > 1 else {}
        r = least_squares(fun, zs, bounds=(lo, hi), diff_step=1e-6, x_scale=1.0, max_nfev=max_nfev,
                          ftol=tol, xtol=tol, gtol=1e-10, **par)
    return Fit(_values(parts, r.x * sc), float(np.mean(r.fun**2)), int(r.nfev), bool(r.status != 0))
