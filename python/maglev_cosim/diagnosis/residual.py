"""Describing a residual: effective sample count, spectrum and its peaks, whiteness,
correlations, and the noise floor a record implies."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ..loop import fast_loop
from ..loop.controllers import needs_current
from ..plant import formulas
from ..plant.params import get_params
from ..records.record import Record, RecordError
from .metrics import nrmse_fit
from .replay import record_controller


def effective_samples(r: np.ndarray, max_lag: int = 2000) -> float:
    """N/(1 + 2·Σρ_k): the number of independent samples an autocorrelated residual is worth
    (the sum runs until the autocorrelation first drops below 0.05)."""
    r = np.asarray(r, float) - np.mean(r)
    n = len(r)
    if n < 4 or not np.any(r):
        return float(n)
    f = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[: min(max_lag, n - 1)]
    ac /= ac[0]
    tau = 1.0
    for k in range(1, len(ac)):
        if ac[k] < 0.05:
            break
        tau += 2 * ac[k]
    return n / tau


def spectrum(r: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided amplitude spectrum [MU] of a residual (Hann window, zero-padded ×4)."""
    n = len(r)
    win = np.hanning(n)
    amp = np.abs(np.fft.rfft((r - r.mean()) * win, 4 * n)) * 2 / win.sum()
    return np.fft.rfftfreq(4 * n, ts), amp


def spectral_peaks(r: np.ndarray, ts: float, *, fmin: float = 2.0, count: int = 5) -> list[dict[str, float]]:
    """The strongest narrow peaks above ``fmin`` Hz: frequency [Hz], amplitude [MU] and
    prominence (peak over the median spectrum level)."""
    f, a = spectrum(r, ts)
    sel = f >= fmin
    f, a = f[sel], a[sel]
    if len(a) < 3:
        return []
    floor = float(np.median(a)) + 1e-300
    loc = np.nonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:]))[0] + 1
    loc = loc[np.argsort(a[loc])[::-1]]
    out: list[dict[str, float]] = []
    for k in loc:
        if all(abs(f[k] - p["f"]) > 1.0 for p in out):
            # parabolic interpolation of the peak on a log scale
            y0, y1, y2 = np.log(a[k - 1]), np.log(a[k]), np.log(a[k + 1])
            d = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2) if (y0 - 2 * y1 + y2) != 0 else 0.0
            out.append({"f": float(f[k] + d * (f[1] - f[0])), "amplitude": float(a[k]),
                        "prominence": float(a[k] / floor)})
        if len(out) == count:
            break
    return out


def analyse_residual(rec: Record, sim: Mapping[str, np.ndarray]) -> dict:
    """Numbers that describe a residual: RMS, spectrum peaks, whiteness, correlations with the
    reference, the input and the operating point, and the error around reference steps."""
    ey, eu = rec.y - sim["y"], rec.u - sim["u"]
    n = rec.n
    lags = np.arange(1, 51)

    def acf(r: np.ndarray) -> np.ndarray:
        r = r - r.mean()
        d = float(np.dot(r, r)) or 1.0
        return np.array([np.dot(r[:-k], r[k:]) / d for k in lags])

    def corr(a: np.ndarray, b: np.ndarray) -> float:
        if np.std(a) == 0 or np.std(b) == 0:
            return 0.0
        return float(np.corrcoef(a, b)[0, 1])

    steps = np.nonzero(np.abs(np.diff(rec.w)) > 1e-9)[0] + 1
    near = np.zeros(n, bool)
    for s in steps:
        near[s: s + int(0.3 / rec.ts)] = True
    bound = 1.96 / math.sqrt(n)
    return {
        "rms_y": float(np.sqrt(np.mean(ey**2))),
        "rms_u": float(np.sqrt(np.mean(eu**2))),
        "mean_y": float(np.mean(ey)),
        "mean_u": float(np.mean(eu)),
        "peaks_y": spectral_peaks(ey, rec.ts),
        "peaks_u": spectral_peaks(eu, rec.ts),
        "whiteness": {
            "fraction_of_lags_outside_95pct_y": float(np.mean(np.abs(acf(ey)) > bound)),
            "fraction_of_lags_outside_95pct_u": float(np.mean(np.abs(acf(eu)) > bound)),
            "effective_samples_y": effective_samples(ey),
            "effective_samples_u": effective_samples(eu),
        },
        "correlation": {
            "y_error_vs_reference": corr(ey, rec.w), "u_error_vs_reference": corr(eu, rec.w),
            "y_error_vs_input": corr(ey, rec.u), "u_error_vs_input": corr(eu, rec.u),
            "y_error_vs_operating_point": corr(ey, rec.y), "u_error_vs_operating_point": corr(eu, rec.y),
        },
        "around_steps": {
            "steps": int(len(steps)),
            "rms_y_near_steps": float(np.sqrt(np.mean(ey[near] ** 2))) if near.any() else None,
            "rms_y_elsewhere": float(np.sqrt(np.mean(ey[~near] ** 2))) if (~near).any() else None,
            "rms_u_near_steps": float(np.sqrt(np.mean(eu[near] ** 2))) if near.any() else None,
            "rms_u_elsewhere": float(np.sqrt(np.mean(eu[~near] ** 2))) if (~near).any() else None,
        },
    }


def noise_floor(rec: Record) -> dict[str, float]:
    """What sensor noise alone leaves, estimated from the record itself: the white part of the
    reading from its second differences (the ball moves too slowly to show in them at 1 kHz),
    and the controller's response to that noise (the PID of Eq. 24 as an FIR on white noise; a
    declared controller file's controller, run on a seeded white noise of that level)."""
    d2 = np.diff(rec.y, 2)
    sigma = float(np.std(d2) / math.sqrt(6.0))
    if rec.controller is None:
        b0 = rec.kp + rec.ki * rec.ts + rec.kd / rec.ts
        b1 = -rec.kd / rec.ts
        return {"sigma_y": sigma, "rms_u_from_sensor_noise": sigma * math.hypot(b0, b1)}
    return {"sigma_y": sigma, "rms_u_from_sensor_noise": _controller_noise_gain(rec) * sigma}


def _controller_noise_gain(rec: Record, n: int = 4000) -> float:
    """RMS change of the declared controller's output per unit RMS of white noise on its reading,
    around the record's mean operating point (a small noise, so the limits do not act)."""
    c = record_controller(rec)
    p = get_params("baseline")
    y0 = float(np.mean(rec.y))
    x0 = formulas.position(p, y0)
    op = formulas.point(p, x0)
    level = 1e-5
    noise = level * np.random.default_rng(0).standard_normal(n)
    w = np.full(n, y0)
    cur = np.full(n, op.i) if needs_current(c) else None
    u0 = fast_loop.control(c, w, w, cur, op.u, (x0, 0.0, op.i))
    u1 = fast_loop.control(c, w, w + noise, cur, op.u, (x0, 0.0, op.i))
    return float(np.std(u1 - u0) / level)


#: The least NRMSE fit [%] of the recorded u by the declared controller run on the recorded w and y
#: (:func:`check_controller`). The fit is low on honest records with a noisy sensor, where the PID's
#: derivative of the noise dominates u and any difference of timing or rounding shows: 1 to 98 % on
#: the two emulators' records of the disturbance family (seeds 2100-2111, 3 s; the lowest at sensor
#: noise above 1e-3 MU). Below -100 % the recomputed u is more than twice as
#: far from the recorded u as u's own mean: the controller is not the one that ran, or u and y are
#: swapped (-526 % on a swapped record).
CONTROLLER_FIT_MIN = -100.0


def check_controller(rec: Record) -> float | None:
    """Checks at once that the recorded u is what the record's declared controller makes of the
    recorded w and y, and raises :class:`~maglev_cosim.records.record.RecordError` at the header's u
    column when it is not, saying whether the columns u and y look swapped. Returns the fit [%], or
    None when the check cannot run (a controller that reads the coil current, which the record lacks)."""
    ctl = record_controller(rec)
    if needs_current(ctl):
        return None
    fit = nrmse_fit(rec.u, fast_loop.control(ctl, rec.w, rec.y, None, float(rec.u[0]), y_before=rec.y_before))
    if fit >= CONTROLLER_FIT_MIN:
        return fit
    swapped = nrmse_fit(rec.y, fast_loop.control(ctl, rec.w, rec.u, None, float(rec.y[0])))
    what = f"the controller file {rec.controller_file}" if rec.controller_file else (
        f"the PID of its metadata, kp {rec.kp:g}, ki {rec.ki:g}, kd {rec.kd:g}")
    hint = (f"; with the columns u and y swapped it fits {swapped:.1f} %: are u and y swapped?"
            if swapped > max(fit, CONTROLLER_FIT_MIN) + 50.0 else
            ": is the controller the record declares (its metadata or controller file) the one that ran?")
    raise RecordError(rec.path, rec.header_line, rec.header_columns.get("u", 0),
                      f"the recorded u is not what the declared controller ({what}) makes of the recorded w "
                      f"and y: NRMSE fit {fit:.1f} %, above {CONTROLLER_FIT_MIN:.0f} % expected{hint}")

