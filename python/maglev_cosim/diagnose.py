"""Closing the loop with measured data: replay, calibrate, find the residual, trace it to the
effect the model lacks, add it, and report the error before and after.

Pipeline (``maglev-cosim diagnose RECORD.csv --out DIR``):

1. Replay the record in closed loop on the C plant (cffi fast path, :mod:`.replay`) with the
   record's PID and reference; compare simulated with measured ``u`` and ``y``.
2. Calibrate the baseline's free parameters (:data:`CALIBRATED`: ``k_c``, ``x_0``, ``k_FV``
   and the D/A offset ``u_0``) by least squares on the replay error. The A/D offset ``y_MU0``
   is not calibrated: in a regulated loop it shifts the picture exactly as ``x_0`` does, so the
   two cannot be told apart. The calibrated baseline's error is the "before" figure.
3. Analyse the residual, then fit each candidate effect of :data:`CATALOGUE` together with the
   recalibrated baseline on the *fit* blocks of the record and judge it on the *held-out* blocks
   (alternating 0.8 s blocks). Accept per :func:`accept`; keep the best accepted one and repeat
   on the new residual until nothing more is justified.
4. Refit the final model on the whole record: its error is the "after" figure; parameter
   uncertainties come from the Jacobian, corrected for the residual's autocorrelation.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2

from .record import Record
from .replay import baseline_params, replay

#: Baseline parameters calibrated on every record: (name, scale, lower, upper).
CALIBRATED: tuple[tuple[str, float, float, float], ...] = (
    ("k_c", 1e-6, 1e-7, 1e-4),
    ("x_0", 1e-3, 6.8e-3, 0.03),
    ("k_FV", 1e-2, 0.0, 0.5),
    ("u_0", 0.05, -1.0, 1.0),
)

BLOCK = 0.8                  # [s] alternating fit / held-out blocks
ALPHA = 1e-3                 # false-acceptance probability of the likelihood-ratio test
MIN_GAIN = 0.03              # smallest held-out cost reduction worth an effect (3 %)
MAX_EFFECTS = 3


@dataclass(frozen=True)
class Effect:
    """A candidate effect: its FMU parameters with scales and bounds, and how to start a fit."""

    name: str
    params: tuple[str, ...]
    scales: tuple[float, ...]
    bounds: tuple[tuple[float, float], ...]
    description: str


CATALOGUE: dict[str, Effect] = {e.name: e for e in (
    Effect("amplifier_lag", ("T_a",), (1e-3,), ((0.0, 0.05),),
           "the amplifier's first-order lag T_a (Eq. 2), neglected in Eq. 5"),
    Effect("force_lag", ("T_F",), (1e-3,), ((5e-5, 0.05),),   # below 50 us the lag is invisible at 1 kHz
           "the magnetic force following the static law through a lag T_F (eddy currents)"),
    Effect("delay", ("T_d",), (1e-3,), ((0.0, 0.05),),
           "a transport delay T_d of the D/A signal (computation and I/O)"),
    Effect("sensor_nonlinearity", ("k_x2",), (1e4,), ((-1e6, 1e6),),
           "the sensor's deviation k_x2*x*(x - x_cal) from the two-point fit of Eq. 12"),
    Effect("current_saturation", ("i_max",), (0.05,), ((0.2, 1.5),),
           "an amplifier current limit i_max below the 1.5 A the D/A range implies"),
    Effect("periodic_disturbance", ("A_d", "f_d", "phi_d"), (0.01, 0.01, 1.0),
           ((0.0, 1.0), (0.5, 450.0), (-math.pi, math.pi)),
           "sinusoidal pickup A_d*sin(2*pi*f_d*t + phi_d) on the sensor voltage"),
)}


# ----------------------------------------------------------------------------- the fit problem

@dataclass
class Problem:
    """What every fit needs; picklable so that candidates can be fitted in worker processes."""

    rec: Record
    base: dict[str, float]          # complete parameter set the free parameters are applied to
    sigma_y: float                  # [MU] weights: residuals are divided by these
    sigma_u: float
    mask: np.ndarray                # samples whose error counts in the fit


def residuals(prob: Problem, values: Mapping[str, float], mask: np.ndarray | None = None) -> np.ndarray:
    """Weighted residual vector (y errors, then u errors) of a replay with ``values`` applied.
    A parameter set the plant rejects (say x_0 pushed below x_max) costs as much as a ball
    lying on a stop: the search then turns away from it instead of failing."""
    m = prob.mask if mask is None else mask
    try:
        sim = replay(prob.rec, {**prob.base, **values})
    except ValueError:
        sim = {"y": np.zeros(prob.rec.n), "u": np.full(prob.rec.n, prob.rec.u_max)}
    return np.concatenate([(prob.rec.y - sim["y"])[m] / prob.sigma_y, (prob.rec.u - sim["u"])[m] / prob.sigma_u])


@dataclass
class Fit:
    """The result of fitting a set of free parameters."""

    values: dict[str, float]
    cost: float                      # mean squared weighted residual on the fit samples
    nfev: int = 0


def _periodic_transform(z_names: Sequence[str], v: np.ndarray) -> dict[str, float]:
    """(a, b) = A_d·(cos φ, sin φ) are fitted instead of (A_d, phi_d): the loop's response to a
    small pickup is nearly linear in (a, b), while A_d, phi_d make a poorly shaped problem."""
    out = dict(zip(z_names, v))
    if "_a" in out:
        a, b = out.pop("_a"), out.pop("_b")
        out["A_d"] = math.hypot(a, b)
        out["phi_d"] = math.atan2(b, a)
    return out


def fit(prob: Problem, names: Sequence[str], x0: Sequence[float], scales: Sequence[float],
        bounds: Sequence[tuple[float, float]], *, max_nfev: int = 60) -> Fit:
    """Least squares (trust-region reflective) over ``names`` in scaled coordinates."""
    x0 = np.asarray(x0, float)
    sc = np.asarray(scales, float)
    lo = np.array([b[0] for b in bounds]) / sc
    hi = np.array([b[1] for b in bounds]) / sc
    z0 = np.clip(x0 / sc, lo + 1e-12, hi - 1e-12)

    def fun(z: np.ndarray) -> np.ndarray:
        return residuals(prob, _periodic_transform(names, z * sc))

    r = least_squares(fun, z0, bounds=(lo, hi), diff_step=1e-6, x_scale=1.0, max_nfev=max_nfev,
                      ftol=1e-8, xtol=1e-8, gtol=1e-10)
    values = _periodic_transform(names, r.x * sc)
    return Fit(values, float(np.mean(r.fun**2)), int(r.nfev))


def cost_on(prob: Problem, values: Mapping[str, float], mask: np.ndarray) -> float:
    """Mean squared weighted residual on the samples of ``mask``."""
    return float(np.mean(residuals(prob, values, mask) ** 2))


# ----------------------------------------------------------------------------- residual analysis

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
    and the controller's response to that noise (the PID of Eq. 24 as an FIR on white noise)."""
    d2 = np.diff(rec.y, 2)
    sigma = float(np.std(d2) / math.sqrt(6.0))
    b0 = rec.kp + rec.ki * rec.ts + rec.kd / rec.ts
    b1 = -rec.kd / rec.ts
    return {"sigma_y": sigma, "rms_u_from_sensor_noise": sigma * math.hypot(b0, b1)}


# ----------------------------------------------------------------------------- acceptance

def accept(cost_before: float, cost_after: float, n_eff: float, n_params: int) -> tuple[bool, dict]:
    """The acceptance criterion, applied to the held-out blocks.

    An effect with ``p`` parameters is accepted when (1) the likelihood-ratio statistic
    ``N_eff·ln(J_before/J_after)`` exceeds the χ²(p) quantile at 1 − α (α = 0.001), where
    ``N_eff`` is the held-out residual's effective number of independent samples (corrected for
    autocorrelation, :func:`effective_samples`), so a reduction that noise explains is rejected
    with probability 0.999; and (2) the held-out cost falls by at least 3 %.
    """
    gain = 1.0 - cost_after / cost_before if cost_before > 0 else 0.0
    stat = n_eff * math.log(cost_before / cost_after) if cost_after > 0 else math.inf
    threshold = float(chi2.ppf(1 - ALPHA, n_params))
    ok = bool(stat > threshold and gain >= MIN_GAIN)
    return ok, {"lr_statistic": float(stat), "threshold": threshold, "held_out_gain": float(gain),
                "n_eff": float(n_eff)}


CRITERION = (f"An effect is accepted when, on the held-out blocks (alternating {BLOCK} s blocks not used "
             f"for fitting), the likelihood-ratio statistic N_eff*ln(J_before/J_after) exceeds the "
             f"chi-square quantile with p degrees of freedom at 1 - {ALPHA} (p = the effect's parameter "
             f"count; N_eff = held-out samples corrected for the residual's autocorrelation), and the "
             f"held-out cost J (mean squared residual of y and u, each divided by the calibrated "
             f"baseline's RMS) falls by at least {MIN_GAIN:.0%}. Among accepted effects the one with the "
             f"largest held-out reduction is added, and the search repeats on the new residual.")


# ----------------------------------------------------------------------------- candidate fits

def _calibrated_x0(values: Mapping[str, float]) -> list[float]:
    return [values[n] for n, *_ in CALIBRATED]


def starts_for(effect: Effect, prob: Problem, current: Mapping[str, float]) -> list[list[float]]:
    """Starting values for an effect's parameters (in fit coordinates). One-parameter effects get
    a dense grid: near the stability limit the replay error is far from quadratic in a lag or a
    delay, and a coarse start can leave least squares in a side valley."""
    if effect.name in ("amplifier_lag", "force_lag", "delay"):
        lo = max(effect.bounds[0][0], 2.5e-4)
        return [[float(v)] for v in np.concatenate([np.linspace(lo, 4e-3, 16), np.linspace(4.5e-3, 1.5e-2, 15)])]
    if effect.name == "sensor_nonlinearity":
        return [[float(v)] for v in np.linspace(-6e4, 6e4, 24)]     # 0 excluded: the fit starts off it
    if effect.name == "current_saturation":
        sim = replay(prob.rec, {**prob.base, **current})
        i = np.sort(sim["i"])
        return [[float(i[int(q * (len(i) - 1))])] for q in (0.9999, 0.999, 0.995, 0.99, 0.98, 0.95, 0.9, 0.8, 0.7)]
    if effect.name == "periodic_disturbance":
        sim = replay(prob.rec, {**prob.base, **current})
        peaks = spectral_peaks(prob.rec.u - sim["u"], prob.rec.ts, count=2)
        peaks += spectral_peaks(prob.rec.y - sim["y"], prob.rec.ts, count=1)
        out = []
        for p in peaks:
            for ph in (0.0, math.pi / 2, math.pi, -math.pi / 2):
                out.append([0.01 * math.cos(ph), 0.01 * math.sin(ph), p["f"]])
        return out or [[0.0, 0.0, 50.0]]
    raise KeyError(effect.name)


def fit_candidate(prob: Problem, current: dict[str, float], effect_name: str) -> dict:
    """Fits one effect together with the baseline's calibrated parameters on the fit blocks."""
    eff = CATALOGUE[effect_name]
    # effects selected in earlier rounds stay in the model while this one is fitted
    prob = Problem(prob.rec, {**prob.base, **current}, prob.sigma_y, prob.sigma_u, prob.mask)
    cal_names = [n for n, *_ in CALIBRATED]
    cal_scales = [s for _, s, _, _ in CALIBRATED]
    cal_bounds = [(lo, hi) for _, _, lo, hi in CALIBRATED]
    if eff.name == "periodic_disturbance":
        e_names = ["_a", "_b", "f_d"]
        e_scales = [0.01, 0.01, 0.01]
        e_bounds = [(-1.0, 1.0), (-1.0, 1.0), (0.5, 450.0)]
    else:
        e_names, e_scales, e_bounds = list(eff.params), list(eff.scales), list(eff.bounds)
    starts = starts_for(eff, prob, current)

    def start_values(z: Sequence[float]) -> dict[str, float]:
        vals = {**current, **_periodic_transform(e_names, np.array(z))}
        if eff.name == "sensor_nonlinearity":
            # a bent sensor also shifts the reading at the operating point, which x_0 absorbs once
            # recalibrated: shift x_0 with it, so that the grid judges the bend, not the offset
            k_x = prob.base["k_x"]
            xbar = float(np.mean((prob.rec.y - prob.base["y_MU0"]) / prob.base["k_AD"] - prob.base["y_0"])) / k_x
            k2 = vals["k_x2"] - current.get("k_x2", 0.0)
            x0 = current["x_0"] - k2 * xbar * (xbar - prob.base["x_cal"]) / (k_x + k2 * (2 * xbar - prob.base["x_cal"]))
            lo, hi = next((lo, hi) for n, _, lo, hi in CALIBRATED if n == "x_0")
            vals["x_0"] = min(max(x0, lo), hi)
        return vals

    # choose the best start with the baseline held, then fit everything from it
    best, best_cost = None, math.inf
    for z in starts:
        c = float(np.mean(residuals(prob, start_values(z)) ** 2))
        if c < best_cost:
            best, best_cost = z, c
    start_cal = _calibrated_x0(start_values(best))
    if eff.name == "periodic_disturbance":
        # amplitude and phase first (a nearly linear problem), then all together
        pre = fit(Problem(prob.rec, {**prob.base, **current, "f_d": best[2]}, prob.sigma_y, prob.sigma_u, prob.mask),
                  ["_a", "_b"], best[:2], [0.01, 0.01], [(-1.0, 1.0), (-1.0, 1.0)], max_nfev=20)
        a, b = pre.values["A_d"] * math.cos(pre.values["phi_d"]), pre.values["A_d"] * math.sin(pre.values["phi_d"])
        best = [a, b, best[2]]
    f = fit(prob, cal_names + e_names, start_cal + list(best), cal_scales + e_scales, cal_bounds + e_bounds)
    return {"effect": effect_name, "values": {**current, **f.values}, "fit_cost": f.cost, "nfev": f.nfev}


def _worker(args: tuple[Problem, dict[str, float], str]) -> dict:
    return fit_candidate(*args)


# ----------------------------------------------------------------------------- the pipeline

@dataclass
class Diagnosis:
    """Everything the diagnosis found; :meth:`to_json` gives the ``diagnosis.json`` content."""

    record: str
    before: dict[str, float]
    after: dict[str, float]
    selected: list[str]
    parameters: dict[str, float]
    uncertainties: dict[str, float]
    candidates: list[dict]
    calibrated_baseline: dict[str, float]
    residual_before: dict
    residual_after: dict
    noise: dict[str, float]
    rounds: list[dict]
    elapsed: float
    sims: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    unexplained: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "record": self.record,
            "before": self.before,
            "after": self.after,
            "selected": self.selected,
            "parameters": self.parameters,
            "uncertainties": self.uncertainties,
            "candidates": self.candidates,
            "calibrated": [n for n, *_ in CALIBRATED],
            "calibrated_baseline": self.calibrated_baseline,
            "criterion": CRITERION,
            "rounds": self.rounds,
            "residual_before": self.residual_before,
            "residual_after": self.residual_after,
            "noise_floor": self.noise,
            "unexplained": self.unexplained,
            "elapsed_s": self.elapsed,
        }


def _rms(rec: Record, sim: Mapping[str, np.ndarray]) -> dict[str, float]:
    return {"rms_y": float(np.sqrt(np.mean((rec.y - sim["y"]) ** 2))),
            "rms_u": float(np.sqrt(np.mean((rec.u - sim["u"]) ** 2)))}


def _uncertainty(prob: Problem, names: Sequence[str], values: Mapping[str, float],
                 scales: Sequence[float]) -> dict[str, float]:
    """1-sigma standard errors from the Jacobian at the solution, inflated by N/N_eff for the
    residual's autocorrelation."""
    x = np.array([values[n] for n in names])
    sc = np.asarray(scales, float)
    r0 = residuals(prob, dict(zip(names, x)))
    jac = np.empty((len(r0), len(names)))
    for k in range(len(names)):
        h = 1e-4 * sc[k]
        xp = x.copy()
        xp[k] += h
        jac[:, k] = (residuals(prob, dict(zip(names, xp))) - r0) / (h / sc[k])
    half = len(r0) // 2
    n_eff = min(effective_samples(r0[:half]), effective_samples(r0[half:]))
    s2 = float(np.sum(r0**2)) / max(len(r0) - len(names), 1)
    try:
        cov = np.linalg.pinv(jac.T @ jac) * s2 * (len(r0) / 2) / max(n_eff, 1.0)
    except np.linalg.LinAlgError:
        return {n: math.nan for n in names}
    return {n: float(math.sqrt(max(cov[k, k], 0.0)) * sc[k]) for k, n in enumerate(names)}


def _static_start(rec: Record, base: dict[str, float], say: Callable[[str], None]) -> dict[str, float]:
    """Starting values of k_c and x_0 from the paper's least-squares fit of Eq. 14 on the record's
    settled segments (Sec. 3.4.2), when it has them and they lie inside the calibration bounds."""
    from .identify import equilibrium_points, least_squares_eq14

    try:
        x, u_v = equilibrium_points(rec, base)
        lq = least_squares_eq14(x, u_v, base["m_k"], base["g"])
    except ValueError:
        return {}
    k_c = lq["k_f"] / base["k_i"] ** 2
    bounds = {n: (lo, hi) for n, _, lo, hi in CALIBRATED}
    if not (bounds["k_c"][0] < k_c < bounds["k_c"][1] and bounds["x_0"][0] < lq["x_0"] < bounds["x_0"][1]):
        return {}
    say(f"starting from the Eq. 14 least-squares fit: k_c = {k_c:.4g} N.m2/A2, x_0 = {lq['x_0'] * 1e3:.3f} mm")
    return {"k_c": k_c, "x_0": lq["x_0"]}


def diagnose(rec: Record, *, effects: Sequence[str] | None = None, workers: int | None = None,
             progress: Callable[[str], None] | None = None, start: Mapping[str, float] | None = None) -> Diagnosis:
    """Runs the whole pipeline on a record. ``effects``: the catalogue entries to consider
    (default: all). ``start``: starting values for the calibrated parameters (e.g. from the
    paper's identification methods); default the Section 3 values."""
    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    effects = list(CATALOGUE) if effects is None else list(effects)
    for e in effects:
        if e not in CATALOGUE:
            raise ValueError(f"unknown effect {e!r}: choose from {', '.join(CATALOGUE)}")
    workers = workers or min(2, os.cpu_count() or 1)
    base = baseline_params()
    if start is None:
        start = _static_start(rec, base, say)
    base.update({k: float(v) for k, v in start.items()})
    n = rec.n
    block = (np.floor(rec.t / BLOCK).astype(int) % 2) == 0
    fit_mask, hold_mask, all_mask = block, ~block, np.ones(n, bool)

    # 1. replay the paper's model as it is
    say("replaying the record on the baseline model (Section 3, T_a = 0)")
    sim0 = replay(rec, base)
    raw = _rms(rec, sim0)
    sy, su = max(raw["rms_y"], 1e-6), max(raw["rms_u"], 1e-6)

    # 2. calibrate the baseline on the fit blocks, then take the weights from its residual
    say(f"calibrating {', '.join(n for n, *_ in CALIBRATED)} (raw replay error: rms_y {raw['rms_y']:.5f} MU, "
        f"rms_u {raw['rms_u']:.5f} MU)")
    prob = Problem(rec, base, sy, su, fit_mask)
    cal_names = [n for n, *_ in CALIBRATED]
    cal_scales = [s for _, s, _, _ in CALIBRATED]
    cal_bounds = [(lo, hi) for _, _, lo, hi in CALIBRATED]
    cal = fit(prob, cal_names, [base[n] for n in cal_names], cal_scales, cal_bounds)
    current = dict(cal.values)
    sim_before = replay(rec, {**base, **current})
    before = _rms(rec, sim_before)
    prob = Problem(rec, base, max(before["rms_y"], 1e-6), max(before["rms_u"], 1e-6), fit_mask)
    say(f"calibrated baseline: rms_y {before['rms_y']:.5f} MU, rms_u {before['rms_u']:.5f} MU")
    residual_before = analyse_residual(rec, sim_before)

    selected: list[str] = []
    candidates: list[dict] = []
    rounds: list[dict] = []
    ctx = get_context("fork") if sys.platform.startswith("linux") else get_context()
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx) if workers > 1 else None
    try:
        for rnd in range(1, MAX_EFFECTS + 1):
            remaining = [e for e in effects if e not in selected]
            if not remaining:
                break
            hold_before = cost_on(prob, current, hold_mask)
            say(f"round {rnd}: fitting {len(remaining)} candidate effect(s) on the fit blocks")
            jobs = [(prob, current, e) for e in remaining]
            results = []
            it = pool.map(_worker, jobs) if pool else map(_worker, jobs)
            for k, res in enumerate(it, 1):
                vals = res["values"]
                hold_after = cost_on(prob, vals, hold_mask)
                r_hold = residuals(prob, vals, hold_mask)
                half = len(r_hold) // 2
                n_eff = min(effective_samples(r_hold[:half]), effective_samples(r_hold[half:]))
                ok, stats = accept(hold_before, hold_after, n_eff, len(CATALOGUE[res["effect"]].params))
                sim = replay(rec, {**base, **vals})
                errs = _rms(rec, sim)
                eff_vals = {p: vals[p] for p in CATALOGUE[res["effect"]].params}
                entry = {"effect": res["effect"], "round": rnd, "parameters": eff_vals, **errs, "accepted": ok,
                         "held_out_cost_before": hold_before, "held_out_cost_after": hold_after, **stats,
                         "calibrated": {n: vals[n] for n in cal_names}}
                results.append((entry, vals))
                say(f"  [{k}/{len(jobs)}] {res['effect']}: "
                    + ", ".join(f"{p} = {v:.4g}" for p, v in eff_vals.items())
                    + f"; held-out cost change {-100 * stats['held_out_gain']:+.1f} % "
                    + f"(LR {stats['lr_statistic']:.1f} vs {stats['threshold']:.1f}) -> "
                    + ("accepted" if ok else "rejected"))
            accepted = [r for r in results if r[0]["accepted"]]
            for entry, _ in results:
                candidates.append(entry)
            rounds.append({"round": rnd, "held_out_cost_before": hold_before,
                           "accepted": [e["effect"] for e, _ in accepted]})
            if not accepted:
                break
            entry, vals = min(accepted, key=lambda r: r[0]["held_out_cost_after"])
            entry["selected"] = True
            selected.append(entry["effect"])
            current = dict(vals)
            say(f"round {rnd}: added {entry['effect']}")
    finally:
        if pool:
            pool.shutdown()

    # 4. the final model refitted on the whole record
    say(f"refitting the final model ({', '.join(selected) or 'baseline only'}) on the whole record")
    final_prob = Problem(rec, base, prob.sigma_y, prob.sigma_u, all_mask)
    names, x0, scales, bounds = list(cal_names), _calibrated_x0(current), list(cal_scales), list(cal_bounds)
    for e in selected:
        eff = CATALOGUE[e]
        if e == "periodic_disturbance":
            a = current["A_d"] * math.cos(current["phi_d"])
            b = current["A_d"] * math.sin(current["phi_d"])
            names += ["_a", "_b", "f_d"]
            x0 += [a, b, current["f_d"]]
            scales += [0.01, 0.01, 0.01]
            bounds += [(-1.0, 1.0), (-1.0, 1.0), (0.5, 450.0)]
        else:
            names += list(eff.params)
            x0 += [current[p] for p in eff.params]
            scales += list(eff.scales)
            bounds += list(eff.bounds)
    final = fit(final_prob, names, x0, scales, bounds, max_nfev=40)
    final_values = {**current, **final.values}
    unc_names = [n for n in names if not n.startswith("_")]
    unc_scales = [s for n, s in zip(names, scales) if not n.startswith("_")]
    if "periodic_disturbance" in selected:
        unc_names += ["A_d", "phi_d"]
        unc_scales += [0.01, 1.0]
    say("estimating parameter uncertainties")
    unc = _uncertainty(final_prob, unc_names, final_values, unc_scales)
    sim_after = replay(rec, {**base, **final_values})
    after = _rms(rec, sim_after)
    residual_after = analyse_residual(rec, sim_after)
    noise = noise_floor(rec)
    parameters = {k: float(v) for k, v in {**base, **final_values}.items()}
    ratio_u = after["rms_u"] / noise["rms_u_from_sensor_noise"] if noise["rms_u_from_sensor_noise"] > 0 else None
    unexplained = {
        "rms_y_over_sensor_noise": after["rms_y"] / noise["sigma_y"] if noise["sigma_y"] > 0 else None,
        "rms_u_over_noise_response": ratio_u,
        "peaks_left_u": [p for p in residual_after["peaks_u"] if p["prominence"] > 30],
        "ambiguous": [],
        "note": "",
    }
    # an effect chosen over a rival that explains nearly as much is a weak choice: say so
    for rnd in rounds:
        acc = sorted((c for c in candidates if c["round"] == rnd["round"] and c["accepted"]),
                     key=lambda c: -c["held_out_gain"])
        if len(acc) > 1 and acc[1]["held_out_gain"] > 0.8 * acc[0]["held_out_gain"]:
            unexplained["ambiguous"].append({"round": rnd["round"], "chosen": acc[0]["effect"],
                                             "rival": acc[1]["effect"], "gains": [acc[0]["held_out_gain"],
                                                                                  acc[1]["held_out_gain"]]})
    notes = []
    if unexplained["peaks_left_u"]:
        notes.append("narrow spectral peaks remain in the u residual: something periodic is still unexplained")
    if ratio_u is not None and ratio_u > 1.1:
        notes.append(f"the u residual is {ratio_u:.2f} times what sensor noise alone explains: the final model "
                     "still lacks something (an effect outside the catalogue, or disturbances the record does "
                     "not show)")
    elif ratio_u is not None:
        notes.append(f"the u residual is {ratio_u:.2f} times what sensor noise alone explains")
    for a in unexplained["ambiguous"]:
        notes.append(f"in round {a['round']} {a['rival']} explains nearly as much as {a['chosen']} (held-out "
                     f"reductions {100 * a['gains'][0]:.1f} % and {100 * a['gains'][1]:.1f} %): the choice is weak, "
                     "and an effect outside the catalogue with the same signature cannot be excluded")
    unexplained["note"] = "; ".join(notes)
    elapsed = time.perf_counter() - t0
    say(f"done in {elapsed:.1f} s: before rms_y {before['rms_y']:.5f} rms_u {before['rms_u']:.5f}; "
        f"after rms_y {after['rms_y']:.5f} rms_u {after['rms_u']:.5f}; selected: {selected or 'none'}")
    return Diagnosis(rec.path, before, after, selected, parameters,
                     {k: v for k, v in unc.items()}, candidates, {**base, **cal.values},
                     residual_before, residual_after, noise, rounds, elapsed,
                     sims={"raw": sim0, "before": sim_before, "after": sim_after}, unexplained=unexplained)
