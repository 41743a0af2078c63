"""The black-box baseline a grey-box model must beat: direct linear predictors, one per horizon.

A MATLAB user judges a physical model against ``arx`` or ``n4sid`` models fitted on the same
data; this module is that comparison, made by the tool itself. For each horizon ``h`` one ridge
regression predicts the position's change ``y[k+h] − y[k]`` from

- the last ``past_s`` (30 ms) of position differences ``y[k−j+1] − y[k−j]``, and
- the actuator signal ``a`` (the measured coil current where the record has one, else the
  actuator input) and its square, from ``k − past_s`` up to ``k + h``: the same information a
  prediction driven by the measured actuator signal uses.

It is a *direct* multi-step predictor (one regression per horizon, no recursion), so it is never
run through the unstable plant: the hardest competitor for the long horizons. Features are
standardised on the calibration records; the ridge weight is chosen from a grid by leave-one-
record-out cross-validation (by halves of the record when there is one). Everything is numpy.

:func:`skill` is the figure every table shows: ``1 − ‖y − ŷ‖/‖y − ŷ_stays-put‖`` (> 0: better
than "stays put", 1: perfect), for the model, this baseline and the naive predictors alike.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

#: Past window of position differences and actuator samples [s].
PAST_S = 0.030
#: Ridge weights tried (on standardised features, per sample of the fit).
ALPHAS = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)


@dataclass(frozen=True)
class Series:
    """One record's signals for the baseline: ``y`` position (any unit, kept), ``a`` the actuator
    signal (current [A] or input), both sampled every ``ts`` [s]."""

    y: np.ndarray
    a: np.ndarray
    ts: float


def _lags(ts: float, horizon_s: float) -> tuple[int, int]:
    return max(1, int(round(PAST_S / ts))), max(1, int(round(horizon_s / ts)))


def features(s: Series, horizon_s: float, future: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The regressors of every sample ``k`` that has its full window (rows) and the indices ``k``;
    ``future`` False: the actuator signal only up to ``k`` (none after the prediction's start)."""
    p, h = _lags(s.ts, horizon_s)
    y = np.asarray(s.y, float)
    a = np.asarray(s.a, float)
    n = len(y)
    k = np.arange(p, n - h)
    last = h if future else 0
    if len(k) == 0:
        return np.empty((0, p + 2 * (p + last + 1))), k
    dy = np.diff(y)  # dy[j] = y[j+1] - y[j]
    cols = [dy[k - j - 1] for j in range(p)]                 # y[k-j] - y[k-j-1]
    win = [a[k + j] for j in range(-p, last + 1)]
    cols += win + [w * w for w in win]
    return np.column_stack(cols), k


@dataclass
class DirectPredictor:
    """A fitted direct predictor for one horizon (:func:`fit`)."""

    horizon_s: float
    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    alpha: float
    samples: int
    cv_rms: dict[float, float] = field(default_factory=dict)
    future: bool = True              #: whether it reads the actuator signal up to the predicted instant

    def predict(self, s: Series) -> np.ndarray:
        """``ŷ[k]`` made at ``k − h`` (NaN where no prediction ends), in ``s.y``'s unit."""
        X, k = features(s, self.horizon_s, self.future)
        _, h = _lags(s.ts, self.horizon_s)
        out = np.full(len(s.y), np.nan)
        if len(k):
            out[k + h] = np.asarray(s.y, float)[k] + ((X - self.mean) / self.scale) @ self.coef + self.intercept
        return out


@dataclass
class _Moments:
    """Sufficient statistics of a block of rows: count, sums and cross-products of regressors and target."""

    n: int
    sx: np.ndarray
    st: float
    xx: np.ndarray
    xt: np.ndarray
    tt: float

    @classmethod
    def of(cls, X: np.ndarray, t: np.ndarray) -> _Moments:
        return cls(len(t), X.sum(0), float(t.sum()), X.T @ X, X.T @ t, float(t @ t))

    def __add__(self, o: _Moments) -> _Moments:
        return _Moments(self.n + o.n, self.sx + o.sx, self.st + o.st, self.xx + o.xx, self.xt + o.xt, self.tt + o.tt)

    def __sub__(self, o: _Moments) -> _Moments:
        return _Moments(self.n - o.n, self.sx - o.sx, self.st - o.st, self.xx - o.xx, self.xt - o.xt, self.tt - o.tt)

    def standardised(self, mean: np.ndarray, scale: np.ndarray) -> _Moments:
        """The same statistics of ``(X − mean)/scale``."""
        sx = (self.sx - self.n * mean) / scale
        xx = (self.xx - np.outer(self.sx, mean) - np.outer(mean, self.sx) + self.n * np.outer(mean, mean))
        return _Moments(self.n, sx, self.st, xx / np.outer(scale, scale), (self.xt - mean * self.st) / scale, self.tt)

    def solve(self, alpha: float) -> tuple[np.ndarray, float]:
        """Ridge coefficients (intercept unpenalised) and intercept."""
        zm, tm = self.sx / self.n, self.st / self.n
        A = self.xx - self.n * np.outer(zm, zm) + alpha * self.n * np.eye(len(zm))
        coef = np.linalg.solve(A, self.xt - self.n * zm * tm)
        return coef, float(tm - zm @ coef)

    def sse(self, coef: np.ndarray, b: float) -> float:
        """Σ (z·coef + b − t)² from the statistics alone."""
        return float(coef @ self.xx @ coef + 2 * b * (self.sx @ coef) + self.n * b * b
                     - 2 * (coef @ self.xt) - 2 * b * self.st + self.tt)


def fit(records: Sequence[Series], horizon_s: float, *, alphas: Sequence[float] = ALPHAS,
        future: bool = True) -> DirectPredictor:
    """The ridge predictor of the position ``horizon_s`` ahead, fitted on ``records``. ``future``
    False: it reads the actuator signal only up to the prediction's start. In a closed loop the
    signal after it holds the controller's reaction to what moved the ball meanwhile; the two
    predictors' difference is how much of the skill comes from reading that reaction.

    Raises ``ValueError`` when the records have no sample with a full window."""
    blocks = []
    for s in records:
        X, k = features(s, horizon_s, future)
        _, h = _lags(s.ts, horizon_s)
        y = np.asarray(s.y, float)
        t = y[k + h] - y[k]
        if len(records) == 1:  # cross-validation by the record's two halves
            half = len(t) // 2
            blocks += [_Moments.of(X[:half], t[:half]), _Moments.of(X[half:], t[half:])]
        else:
            blocks.append(_Moments.of(X, t))
    total = blocks[0]
    for b in blocks[1:]:
        total = total + b
    need = 10 * len(total.sx)
    if total.n < need:
        raise ValueError(f"the black-box baseline needs at least {need} samples with a full window, the records "
                         f"hold {total.n}")
    mean = total.sx / total.n
    scale = np.sqrt(np.maximum(np.diag(total.xx) / total.n - mean**2, 0.0))
    scale[scale <= 1e-12 * np.maximum(np.abs(mean), 1e-300)] = 1.0
    total_z = total.standardised(mean, scale)
    blocks_z = [b.standardised(mean, scale) for b in blocks]
    cv = {}
    for alpha in alphas:
        err = sum(b.sse(*(total_z - b).solve(alpha)) for b in blocks_z)
        cv[float(alpha)] = float(np.sqrt(max(err, 0.0) / total.n))
    best = min(cv, key=cv.get)
    coef, intercept = total_z.solve(best)
    return DirectPredictor(horizon_s, mean, scale, coef, intercept, best, total.n, cv, future)


def stays_put(y: np.ndarray, h: int) -> np.ndarray:
    """The naive predictor ``ŷ[k] = y[k − h]`` (NaN for the first ``h`` samples)."""
    y = np.asarray(y, float)
    out = np.full(len(y), np.nan)
    out[h:] = y[:-h]
    return out


def constant_velocity(y: np.ndarray, h: int, ts: float, *, slope_s: float = 0.010) -> np.ndarray:
    """The naive predictor that carries the slope of the last ``slope_s`` on for ``h`` samples."""
    y = np.asarray(y, float)
    m = max(1, int(round(slope_s / ts)))
    out = np.full(len(y), np.nan)
    out[h + m:] = y[m:-h] + h * (y[m:-h] - y[:-h - m]) / m
    return out


def skill(y: np.ndarray, y_hat: np.ndarray, y_naive: np.ndarray, ok: np.ndarray | None = None) -> float:
    """``1 − ‖y − ŷ‖/‖y − ŷ_naive‖`` over the samples ``ok`` (default: where both are finite);
    NaN when the naive predictor is exact."""
    y, y_hat, y_naive = (np.asarray(v, float) for v in (y, y_hat, y_naive))
    sel = np.isfinite(y_hat) & np.isfinite(y_naive) if ok is None else ok & np.isfinite(y_hat) & np.isfinite(y_naive)
    den = np.linalg.norm(y[sel] - y_naive[sel])
    return float(1.0 - np.linalg.norm(y[sel] - y_hat[sel]) / den) if den > 0 else float("nan")
