"""Closed-loop prediction for a record whose controller is unknown: the model and the controller's reaction.

In a closed loop the actuator signal after a prediction's start is the controller's reaction to
where the ball went meanwhile. A model driven by that signal runs the unstable plant forward from an
uncertain state and cannot read the reaction; a black box that regresses on the same signal can
(docs/diagnosis.md, "Model against black box"). Where the controller is declared, the model runs in
closed loop with it (:mod:`.compare`). Where it is not (a real rig's Kalman filter and MPC), this
module identifies it from the record and reads the reaction through it, as a measurement:

1. **The controller, identified** (:class:`LinearController`): a linear difference equation from the
   measured reading ``y``, the reference ``w`` and the actuator signal's own past to the actuator
   signal ``u`` (an ARX model, least squares):
   ``u[t] = Σ_{m=1..na} a_m·u[t−m] + Σ_{m=0..nb} b_m·y[t−m] + Σ_{m=0..nw} d_m·w[t−m] + c``.
2. **The reaction**: from a prediction's start ``k``, the model's trajectory ``ŷ[k+j]`` (the filter's
   prediction driven by the measured actuator signal) stands in for the readings not yet seen. The
   identified controller's residual ``r_j = u[k+j] − ARX(…, ŷ, …)`` is then, to first order, the
   controller's response to the model's error: ``r_j = Σ_m b_m·e[k+j−m] + ε_j`` with
   ``e[k+i] = y[k+i] − ŷ[k+i]`` (zero up to ``k``).
3. **The model's error, estimated** from ``r_1..r_{h−1}`` (the actuator signal up to the sample
   before the predicted instant, :data:`READ_BEFORE`: the information a current measured at that
   instant carries, which the black box reads; the actuator value of the predicted instant is
   computed from the predicted reading itself wherever the controller has a direct feedthrough, and
   reading it would read the answer) by Gaussian conditioning: with ``Σ`` the model's own
   error covariance over the horizon and ``B`` the lower-triangular Toeplitz matrix of the ``b_m``
   (its first ``h − 1`` rows), ``ê_h = Σ_{h,·}·Bᵀ·(B·Σ·Bᵀ + σ²·I)⁻¹·r`` (:func:`last_error_gain`);
   the prediction is ``ŷ[k+h] + ê_h``. ``σ²`` is the controller's
   one-step residual variance (the larger of its own and, fitted on half of its samples, on the
   other half's) times a trust factor.

Everything the correction learns from the record is cross-fitted: the record is cut into blocks of
:data:`BLOCK_S`, and each pair of consecutive blocks gives one to each of two folds (which one by a
fixed pseudo-random coin, :func:`_split`); the controller, the error covariance and the trust
factor are fitted on one fold and used on predictions that start in the other, and the other way
round. A fit sample or
a start whose window reaches into the other parity is not used, so no prediction is judged on a
reading its own correction was fitted on. The trust factor is chosen per horizon on the fitting
blocks from :data:`TRUST` (each half of them judged with a controller fitted on the other half), or
no correction at all when none lowers the error there, or where the loop has no excitation (:data:`EXCITATION`: its actuator signal follows its own
recurrence, from which no reaction to the reading can be identified): a controller
the linear model does not describe (gain scheduling, saturation) gives way to the model driven by
the actuator signal, instead of pulling the prediction off.

It is not a second black box: the prediction is the physics model's trajectory; what the record
adds is the controller, a linear map from the readings to the actuator signal, and the size of the
model's own errors. The correction's trust per horizon is reported.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

#: Orders of the identified controller: the lags of each signal it reads (``u`` from lag 1, the
#: others from lag 0): its own past, the reading, the reference and the measured current.
ORDERS = {"u": 10, "y": 10, "w": 3, "i": 10}
#: Blocks [s] of the two-fold cross-fitting.
BLOCK_S = 1.0
#: Trust factors tried: the controller's residual variance assumed ``factor·σ²_one-step``.
TRUST = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0, 1e3, 1e4)
#: A controller whose actuator signal its own past (with the reference and the current) predicts on
#: unseen samples to within this share of its variance has no excitation to identify a reaction from.
EXCITATION = 1e-10
#: Samples skipped at a record's start, while the filter that makes the trajectories settles [s].
SETTLE_S = 0.2
#: The prediction of the reading ``h`` samples ahead reads the actuator signal up to this many
#: samples before the predicted instant (the reactions ``r_1..r_{h−READ_BEFORE}``).
READ_BEFORE = 1


@dataclass
class LinearController:
    """An identified linear controller (module docstring, step 1): ``coef[name]`` the coefficients
    on each signal it reads at lags ``first..`` (``u`` from 1, the others from 0: ``coef["y"][m]``
    multiplies ``y[t−m]``), ``c`` the constant; ``residual_var`` [u²] its one-step residual
    variance on its fit samples, ``samples`` their number."""

    coef: dict[str, np.ndarray]
    c: float
    residual_var: float
    samples: int

    @staticmethod
    def first(name: str) -> int:
        """The first lag of a signal: the actuator signal's own past from 1, the others from 0."""
        return 1 if name == "u" else 0

    @property
    def b(self) -> np.ndarray:
        """The coefficients on the reading, ``b[m]`` on ``y[t−m]``."""
        return self.coef["y"]

    @property
    def lags(self) -> int:
        """The longest lag it reads [samples]."""
        return max(self.first(k) + len(v) - 1 for k, v in self.coef.items())

    @classmethod
    def regressors(cls, signals: dict[str, np.ndarray], t: np.ndarray, orders: dict[str, int]) -> np.ndarray:
        """The regressors of samples ``t`` (each at least the longest lag): every signal of
        ``signals`` at its lags, then 1."""
        cols = [signals[k][t - m] for k in signals for m in range(cls.first(k), orders[k] + 1)]
        return np.column_stack(cols + [np.ones(len(t))])

    @classmethod
    def fit(cls, signals: dict[str, np.ndarray], rows: np.ndarray,
            orders: dict[str, int] | None = None) -> LinearController:
        """Least squares of ``signals["u"][rows]`` on the regressors of ``rows``. ``signals``: the
        actuator signal ``u``, the reading ``y``, and any of the reference ``w`` and the measured
        current ``i`` the record has (the same unit as ``y`` for ``w``)."""
        orders = {**ORDERS, **(orders or {})}
        width = sum(orders[k] + 1 - cls.first(k) for k in signals) + 1
        if len(rows) < 5 * width:
            raise ValueError(f"{len(rows)} samples are too few to identify a controller with {width} coefficients")
        X = cls.regressors(signals, rows, orders)
        sol = np.linalg.lstsq(X, signals["u"][rows], rcond=None)[0]
        res = signals["u"][rows] - X @ sol
        coef, at = {}, 0
        for k in signals:
            nk = orders[k] + 1 - cls.first(k)
            coef[k], at = sol[at:at + nk], at + nk
        return cls(coef, float(sol[-1]), float(np.mean(res ** 2)), len(rows))

    def _value(self, signals: dict[str, np.ndarray], t: np.ndarray, skip: str | None = None) -> np.ndarray:
        v = np.full(len(t), self.c)
        for k, cf in self.coef.items():
            if k != skip:
                for m, c in enumerate(cf, start=self.first(k)):
                    v += c * signals[k][t - m]
        return v

    def residuals(self, signals: dict[str, np.ndarray]) -> np.ndarray:
        """The one-step residual ``u[t] − ARX(t)`` on the measured signals (NaN before the lags)."""
        u = signals["u"]
        t = np.arange(self.lags, len(u))
        out = np.full(len(u), np.nan)
        out[t] = u[t] - self._value(signals, t)
        return out

    def reaction(self, signals: dict[str, np.ndarray], traj: np.ndarray, starts: np.ndarray, h: int) -> np.ndarray:
        """``r[s, j−1]`` for ``j = 1..h`` from each of ``starts`` (module docstring, step 2): the
        measured ``u[k+j]`` minus what this controller makes of the measured signals and the model's
        trajectory ``traj[k, i]`` (the reading ``i`` samples after ``k``) in place of the readings
        after ``k``."""
        y, u = signals["y"], signals["u"]
        if not len(starts):
            return np.empty((0, h))
        # the part of the ARX value that does not read y, once at every sample a start's window reaches
        t_all = np.arange(int(starts.min()) + 1, int(starts.max()) + h + 1)
        not_y = self._value(signals, t_all, skip="y")
        t = starts[:, None] + np.arange(1, h + 1)[None, :]            # t[s, j-1] = starts[s] + j
        v = not_y[t - t_all[0]]
        # the readings the controller reads, per start: the measured ones up to the start (column
        # c <= 0: y[start + c]), the model's trajectory after it (c = 1..h: traj[start, c]); the term
        # b[m]·y(t − m) of step j is then column j − m, a slice of this one table for each lag m
        back = len(self.b) - 1       # the longest lag on y: step 1 reads y[start + 1 - back]
        seen = np.empty((len(starts), back + h))
        seen[:, :back] = y[starts[:, None] + np.arange(1 - back, 1)[None, :]]
        seen[:, back:] = traj[starts, 1:h + 1]
        for m, b in enumerate(self.b):
            v += b * seen[:, back - m: back - m + h]
        return u[t] - v

    def to_json(self) -> dict:
        return {"coefficients": {k: v.tolist() for k, v in self.coef.items()}, "c": self.c,
                "residual_var": self.residual_var, "samples": self.samples}


def _toeplitz(b: np.ndarray, h: int) -> np.ndarray:
    """The lower-triangular Toeplitz matrix (h × h) of the controller's coefficients on y:
    ``r = B·e`` (module docstring, step 2)."""
    B = np.zeros((h, h))
    for m, bm in enumerate(b[:h]):
        B[np.arange(m, h), np.arange(0, h - m)] = bm
    return B


def last_error_gain(b: np.ndarray, cov: np.ndarray, var: float, seen: int) -> np.ndarray:
    """The gain ``g`` (``seen``) with ``ê_h = g·r[:seen]`` (module docstring, step 3): the model's
    error at the last step ``h = len(cov)`` estimated from the first ``seen`` reactions by Gaussian
    conditioning; ``cov`` the model's error covariance over the horizon (h × h), ``b`` the
    controller's coefficients on y, ``var`` its residual variance."""
    h = len(cov)
    if seen <= 0:
        return np.zeros(0)
    B = _toeplitz(b, h)[:seen]
    S = B @ cov @ B.T + var * np.eye(seen)
    return np.linalg.solve(S, B @ cov[:, h - 1])


@dataclass
class ReactionPrediction:
    """The model's closed-loop predictions with the identified controller: ``y_pred[q]`` the reading
    ``horizons[q]`` samples ahead (NaN where no prediction ends; the model's own trajectory where no
    correction is made), ``trust[q]`` the factor chosen per
    fold (None: no correction on that fold), the two folds' ``controllers``, and the RMS error of
    the model's own trajectory and of the corrected one on each fold's fitting starts."""

    horizons: tuple[int, ...]
    y_pred: np.ndarray
    trust: list[list[float | None]]
    controllers: list[LinearController]
    fit_rms: list[list[dict[str, float]]] = field(default_factory=list)
    identified: list[dict] = field(default_factory=list)    #: per fitting fold: unseen residuals, excitation
    orders: dict[str, int] = field(default_factory=lambda: dict(ORDERS))   #: the lags the controllers read

    def to_json(self) -> dict:
        return {"horizons": list(self.horizons), "trust": self.trust, "identified": self.identified,
                "block_s": BLOCK_S, "orders": dict(self.orders),
                "controllers": [c.to_json() for c in self.controllers], "fit_rms": self.fit_rms}


def _split(n_blocks: int, seed: int) -> np.ndarray:
    """Two folds of ``n_blocks`` blocks: of each consecutive pair one goes to each fold, which one
    by a fixed pseudo-random coin (``seed``). Balanced like alternate blocks, but a reference whose
    period is a multiple of the block cannot put one operating point in each fold."""
    flip = np.random.default_rng(seed).integers(0, 2, size=(n_blocks + 1) // 2)
    k = np.arange(n_blocks)
    return (k % 2) ^ flip[k // 2]


def predict(y: np.ndarray, u: np.ndarray, w: np.ndarray | None, traj: np.ndarray, horizons: Sequence[int],
            ts: float, *, current: np.ndarray | None = None, orders: dict[str, int] | None = None) -> ReactionPrediction:
    """The cross-fitted closed-loop predictions of the module docstring.

    Parameters
    ----------
    y, u : numpy.ndarray
        The measured reading and the actuator signal (any units, the controller's own), one per sample.
    w : numpy.ndarray or None
        The reference, in ``y``'s unit (None: the record has none).
    traj : numpy.ndarray
        ``traj[k, j]`` the model's prediction of ``y[k+j]`` made at ``k`` (driven by the measured
        ``u``), for ``j = 1..max(horizons)`` (NaN where none); column 0 is not read.
    horizons : sequence of int
        Horizons [samples], each ``>= 1``.
    ts : float
        Sample time [s].
    current : numpy.ndarray, optional
        The measured coil current [A]: a controller that feeds it back reads it, and it is measured
        up to the predicted instant like the actuator signal.
    orders : dict, optional
        Lags per signal (default :data:`ORDERS`).

    Returns
    -------
    ReactionPrediction
    """
    y, u = np.asarray(y, float), np.asarray(u, float)
    signals = {"u": u, "y": y}
    if w is not None:
        signals["w"] = np.asarray(w, float)
    if current is not None:
        signals["i"] = np.asarray(current, float)
    orders = {**ORDERS, **(orders or {})}
    n, H = len(y), max(horizons)
    if traj.shape[0] != n or traj.shape[1] <= H:
        raise ValueError(f"traj has shape {traj.shape}, needs ({n}, > {H})")
    lag = max(orders[k] for k in signals)
    nb = max(1, int(round(BLOCK_S / ts)))
    block = np.arange(n) // nb
    fold_of_block = _split(int(block[-1]) + 1, 0)
    parity = fold_of_block[block]
    ks = np.arange(max(lag, int(round(SETTLE_S / ts))), n - H)
    # a start is used when its whole window (the controller's lags before, the horizon after) lies in one block
    ks = ks[(block[ks - lag] == block[ks]) & (block[ks + H] == block[ks])]
    ks = ks[np.all(np.isfinite(traj[ks, 1:H + 1]), axis=1)]
    rows_all = np.arange(lag, n)
    rows_all = rows_all[block[rows_all - lag] == block[rows_all]]
    # where no correction is made (a start whose window crosses a block's edge, a fold without an
    # identified reaction) the prediction is the model's own trajectory
    out = np.full((len(horizons), n), np.nan)
    for q, h in enumerate(horizons):
        out[q, h:] = traj[:n - h, h]
    trust: list[list[float | None]] = [[None, None] for _ in horizons]
    fit_rms: list[list[dict[str, float]]] = [[{}, {}] for _ in horizons]
    ctls, identifies = [], []
    half = np.zeros(n, int)             # within one parity, half of its blocks: the trust's own split
    for f in (0, 1):
        mine = np.flatnonzero(fold_of_block == f)
        half[np.isin(block, mine[_split(len(mine), 1) == 1])] = 1
    for f in (0, 1):
        fit_rows = rows_all[parity[rows_all] == f]
        ctl = LinearController.fit(signals, fit_rows, orders)
        ctls.append(ctl)
        fit_k, use_k = ks[parity[ks] == f], ks[parity[ks] != f]
        if not len(fit_k) or not len(use_k):
            continue
        E = y[fit_k[:, None] + np.arange(1, H + 1)] - traj[fit_k, 1:H + 1]      # the model's own errors
        # the trust is chosen as the predictions will be made: with a controller fitted on blocks
        # other than those of the starts it is judged on (the fitting blocks split in two)
        inner, unseen, blind = [], [], []
        without_y = {k: v for k, v in signals.items() if k != "y"}
        for s in (0, 1):
            rows_s, other = fit_rows[half[fit_rows] == s], fit_rows[half[fit_rows] != s]
            sub = LinearController.fit(signals, rows_s, orders)
            at = half[fit_k] != s
            inner.append((sub, at, sub.reaction(signals, traj, fit_k[at], H)))
            unseen.append(float(np.nanmean(sub.residuals(signals)[other] ** 2)))
            blind.append(float(np.nanmean(LinearController.fit(without_y, rows_s, orders).residuals(without_y)[other] ** 2)))
        # the residual variance the trust scales: the controller's on samples it was not fitted on
        # (a fit that is exact in-sample may be far from exact elsewhere)
        var = max(ctl.residual_var, float(np.mean(unseen)), 1e-300)
        # a loop without excitation obeys its own recurrence: the actuator signal's own past (with the
        # reference and the current) predicts it to rounding on unseen samples, and the "b" fitted
        # beside it mean nothing
        identified = float(np.mean(blind)) > EXCITATION * float(np.var(u[fit_rows]))
        identifies.append({"unseen_var": float(np.mean(unseen)), "unseen_var_without_y": float(np.mean(blind)),
                           "identified": identified})
        r_use = ctl.reaction(signals, traj, use_k, H)
        for q, h in enumerate(horizons):
            cov = E[:, :h].T @ E[:, :h] / len(E)
            own = float(np.sqrt(np.mean(E[:, h - 1] ** 2)))
            best, chosen = own, None
            for g in (TRUST if identified else ()):
                sq = 0.0
                for sub, at, r in inner:
                    k_h = last_error_gain(sub.b, cov, g * var, h - READ_BEFORE)
                    sq += float(np.sum((E[at, h - 1] - r[:, :h - READ_BEFORE] @ k_h) ** 2))
                rms = float(np.sqrt(sq / len(E)))
                if rms < best:
                    best, chosen = rms, g
            trust[q][1 - f] = chosen
            fit_rms[q][1 - f] = {"model": own, "corrected": best}
            pred = traj[use_k, h].copy()
            if chosen is not None:
                pred += r_use[:, :h - READ_BEFORE] @ last_error_gain(ctl.b, cov, chosen * var, h - READ_BEFORE)
            out[q, use_k + h] = pred
    return ReactionPrediction(tuple(int(h) for h in horizons), out, trust, ctls, fit_rms, identifies, orders)
