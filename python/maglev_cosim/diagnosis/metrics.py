"""Model-versus-data figures as System Identification users know them.

- :func:`nrmse_fit`: the fit percentage of MATLAB's ``compare``,
  ``100·(1 − ‖y − ŷ‖ / ‖y − mean(y)‖)``: 100 % is perfect, 0 % is no better than the mean, and it
  is negative when the model is worse than the mean.
- :func:`resid`: the residual's autocorrelation and its cross-correlation with an input, with the
  confidence band of a white residual independent of the input (MATLAB's ``resid``).
- :func:`psd`: Welch's power spectral density (scipy), for plots on a log frequency axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

# Imported inside functions, on purpose: scipy.signal (0.7 s of imports with the scipy.stats it
# loads, which a diagnosis needs only at its figures; a real rig's loads it on its background thread).


def nrmse_fit(y: np.ndarray, y_hat: np.ndarray) -> float:
    """Fit [%] of ``y_hat`` to ``y``: ``100·(1 − ‖y − ŷ‖/‖y − mean y‖)`` (MATLAB ``compare``).

    Returns ``nan`` when ``y`` is constant (there is nothing to fit)."""
    y = np.asarray(y, dtype=float)
    y_hat = np.asarray(y_hat, dtype=float)
    spread = np.linalg.norm(y - y.mean())
    if spread <= 1e-12 * np.sqrt(len(y)) * max(np.abs(y).max(initial=0.0), 1e-300):  # constant, up to rounding
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(y - y_hat) / spread))


def chi2_quantile(q: float, dof: float) -> float:
    """The ``q`` quantile of the chi-square distribution with ``dof`` degrees of freedom: scipy.stats's
    ``chi2.ppf(q, dof)`` by its own formula (the inverse of the regularised lower incomplete gamma
    function), without the 0.4 s of importing scipy.stats."""
    return float(2.0 * special.gammaincinv(dof / 2.0, q))


def correlation(a: np.ndarray, b: np.ndarray | None, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised correlation ``r(τ) = Σ a[k]·b[k − τ] / (N·σ_a·σ_b)`` for ``τ = −max_lag … max_lag``
    (``b = None``: the autocorrelation of ``a``). Means are removed first."""
    from scipy.signal import correlate

    a = np.asarray(a, float) - np.mean(a)
    b = a if b is None else np.asarray(b, float) - np.mean(b)
    n = len(a)
    full = correlate(a, b, mode="full", method="fft") / (n * a.std() * b.std())
    mid = n - 1
    lags = np.arange(-max_lag, max_lag + 1)
    return lags, full[mid + lags]


@dataclass(frozen=True)
class Resid:
    """Residual tests: ``lags`` [samples], ``auto`` (autocorrelation of the residual), ``cross``
    (cross-correlation of residual and input, the input leading for positive lags) and ``band``,
    the ± level a white residual independent of the input stays within with probability
    ``confidence``; ``auto_out`` and ``cross_out`` count the lags outside it (lag 0 of ``auto``,
    always 1, excluded)."""

    lags: np.ndarray
    auto: np.ndarray
    cross: np.ndarray
    band: float
    confidence: float
    auto_out: int
    cross_out: int


def resid(e: np.ndarray, u: np.ndarray, *, max_lag: int = 25, confidence: float = 0.99) -> Resid:
    """Autocorrelation of the residual ``e`` and its cross-correlation with the input ``u``
    (MATLAB ``resid``), with the band ``z_(1+c)/2 / √N`` of the white-noise hypothesis."""
    lags, auto = correlation(e, None, max_lag)
    _, cross = correlation(e, u, max_lag)
    band = float(special.ndtri(0.5 + confidence / 2) / np.sqrt(len(e)))   # the normal quantile
    return Resid(lags, auto, cross, band, confidence, int(np.sum((np.abs(auto) > band) & (lags != 0))),
                 int(np.sum(np.abs(cross) > band)))


#: The band, in shares of the Nyquist frequency, where :func:`white_noise_rms` reads a residual's floor:
#: above a coil's or a loop's bandwidth, below the anti-aliasing edge.
NOISE_BAND = (0.4, 0.9)


def white_noise_rms(e: np.ndarray, ts: float) -> float:
    """The RMS of the white noise in ``e`` [its unit], sampled at ``ts`` [s]: Welch's density (:func:`psd`)
    averaged over :data:`NOISE_BAND` of the Nyquist frequency, times the Nyquist frequency (white noise
    of variance σ² has the one-sided density σ²/f_Nyquist). Of a model's residual, that is the
    measurement's own noise where the model predicts nothing in the band, and an upper bound on it
    where the model's error reaches the band. NaN for fewer than 16 samples."""
    e = np.asarray(e, float)
    if len(e) < 16:
        return float("nan")
    f, p = psd(e, ts)
    nyquist = 0.5 / ts
    band = (f >= NOISE_BAND[0] * nyquist) & (f <= NOISE_BAND[1] * nyquist)
    return float(np.sqrt(np.mean(p[band]) * nyquist)) if band.any() else float("nan")


def fit_ceiling(y: np.ndarray, noise_rms: float) -> float:
    """The NRMSE fit [%] (:func:`nrmse_fit`) of a prediction of ``y`` whose only error is white noise of
    RMS ``noise_rms`` (in ``y``'s unit): ``100·(1 − noise_rms/std(y))``, what no model of the signal can
    beat when that noise is the measurement's."""
    spread = float(np.std(np.asarray(y, float)))
    return float(100.0 * (1.0 - noise_rms / spread)) if spread > 0 else float("nan")


def psd(x: np.ndarray, ts: float, *, seconds_per_segment: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Welch's PSD of ``x`` sampled at ``ts`` [s]: frequencies [Hz] and density [unit²/Hz],
    Hann segments of ``seconds_per_segment`` (at most the record), half overlapping."""
    from scipy.signal import welch

    x = np.asarray(x, float)
    nper = int(min(len(x), max(16, round(seconds_per_segment / ts))))
    f, p = welch(x - x.mean(), fs=1.0 / ts, nperseg=nper)
    return f, p
