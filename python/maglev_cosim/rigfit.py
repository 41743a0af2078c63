"""Measured records of real rigs with any controller: prediction-error replay, figures, calibration.

A real rig's controller is often unknown (an MPC, a filter-based state feedback): the model is then
never run free (the plant is open-loop unstable) but replayed by prediction. An extended Kalman
filter on the C plant (``maglev_replay_predict_measured``) follows the measured gap and coil current,
and predicts them ``h`` ahead driven by the *measured* actuator signal (PWM duty or voltage). The
figures (:func:`figures`) are NRMSE fits as MATLAB's ``compare`` defines them:

- the coil current: from the actuator signal alone (the filter never sees the measured current;
  "free run" of the coil model along the tracked position), and ``h`` ahead with it;
- the position ``h`` ahead (5, 20, 50 ms), beside two naive predictors: "stays put"
  (ŷ[k+h] = y[k]) and "constant velocity" (the slope of the last 10 ms carried on). The skill
  ``1 − ‖y − ŷ_model‖ / ‖y − ŷ_stays-put‖`` says how much of the naive predictor's error the model
  removes (> 0: the model beats it).

:func:`calibrate` fits the force law, the coil resistance and the PWM-to-voltage map to one or
several records at once by least squares on the 20 ms prediction errors of gap and current.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import fast
from .measured import Measured, Segment, levitation_segments
from .metrics import nrmse_fit
from .params import PlantParams
from .rigs import Rig

#: Prediction horizons of the position figures [s].
HORIZONS_S = (0.005, 0.020, 0.050)
#: Samples at a segment's start the figures skip while the filter settles [s].
SETTLE_S = 0.5
#: Parameters :func:`calibrate` fits, by drive type (multiplicative factors on the rig's values).
CALIBRATED = {"voltage": ("k_e", "z_e", "R_c", "k_DA", "u_0"), "current": ("k_c", "x_0", "k_i", "T_a")}


@dataclass
class RigRecord:
    """One levitation segment of a measured record, in the plant's signals."""

    label: str
    ts: float
    y: np.ndarray          #: the plant's reading [MU] of the measured position
    u: np.ndarray          #: the actuator signal as the plant's input [MU]
    current: np.ndarray | None  #: measured coil current [A]
    position: np.ndarray   #: the record's position [m], its own convention
    segment: Segment


def prepare(rig: Rig, m: Measured, *, min_duration: float = 1.0) -> list[RigRecord]:
    """The levitation segments of ``m`` (:func:`maglev_cosim.measured.levitation_segments`: off the
    rig's two stops, coil on), each as plant signals."""
    if m.drive is None:
        raise ValueError(f"{m.path}: the record has no actuator signal: a replay needs it")
    if abs(m.ts - rig.ts) > 1e-3 * rig.ts:
        # any sample rate works, but a rig file states one: a mismatch is a wrong rig or file
        raise ValueError(f"{m.path}: sample time {m.ts:g} s, but rig {rig.name} samples at {rig.ts:g} s")
    check_units(rig, m)
    segs, _ = levitation_segments(m, rig.stops, min_duration=min_duration)
    out = []
    for s in segs:
        part = m.slice(s.start, s.stop)
        out.append(RigRecord(label=f"{m.label}[{part.t[0]:.2f}-{part.t[-1]:.2f} s]", ts=m.ts,
                             y=np.asarray(rig.reading(part.position)), u=np.asarray(rig.input_to_mu(part.drive)),
                             current=part.current, position=part.position, segment=s))
    return out


def check_units(rig: Rig, m: Measured) -> None:
    """Refuses a record whose position contradicts the rig's stops by a unit factor: most samples
    outside the travel widened by half of it on each side (mm read as m: 1000x too large; or the
    other way round, a travel squeezed into a thousandth). Names the file and the column."""
    from .record import RecordError

    lo, hi = rig.stops
    travel = hi - lo
    pos = np.asarray(m.position, float)
    outside = (pos < lo - 0.5 * travel) | (pos > hi + 0.5 * travel)
    if outside.mean() > 0.5:
        ratio = np.median(np.abs(pos)) / max(abs(lo), abs(hi))
        hint = " (mm read as m?)" if ratio > 100 else (" (m read as mm?)" if ratio < 1e-2 else "")
        raise RecordError(m.path, 0, 0, f"column 'position': {100 * outside.mean():.0f} % of the samples lie outside "
                          f"rig {rig.name}'s travel {lo:g}..{hi:g} m (median |position| {np.median(np.abs(pos)):.4g} m)"
                          f"{hint}: the record's units contradict the rig file")
    span = np.ptp(pos)
    if 0 < span < 1e-3 * travel and np.median(np.abs(pos)) < 1e-3 * max(abs(lo), abs(hi)):
        raise RecordError(m.path, 0, 0, f"column 'position': it spans {span:.3g} m against rig {rig.name}'s travel "
                          f"{travel:g} m (m read as mm?): the record's units contradict the rig file")


def _start(rig: Rig, r: RigRecord, params: PlantParams) -> PlantParams:
    p = params
    x0 = float(np.clip(rig.to_x(r.position[0]), p.x_min, p.x_max))
    i0 = float(np.clip(r.current[0], 0.0, p.i_max)) if r.current is not None else p.i_start
    return p.replace(x_start=x0, v_start=0.0, i_start=i0)


def noise_defaults(rig: Rig, params: PlantParams) -> dict[str, float]:
    """The filter's disturbance model for a real rig: a random force of 1 % of the weight with a
    20 Hz corner, the position's quantisation (or 10 µm) as sensor noise, 10 mA on the current."""
    res = rig.resolution or 1e-5
    return {"q_force": 0.01 * params.m_k * params.g, "f_force": 20.0,
            "r_sensor": res / rig.position_scale if rig.sensor == "position" else 1e-3, "r_current": 0.01}


def predict(rig: Rig, r: RigRecord, params: PlantParams, horizon_s: float, *, use_current: bool = True,
            stride: int = 1, noise: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """``y_pred`` [MU] and ``i_pred`` [A] ``horizon_s`` ahead (NaN where no prediction ends)."""
    nz = noise or noise_defaults(rig, params)
    h = max(1, int(round(horizon_s / r.ts)))
    return fast.predict_measured(_start(rig, r, params), r.y, r.u, ts=r.ts, q_force=nz["q_force"],
                                 f_force=nz["f_force"], r_sensor=nz["r_sensor"], horizon=h, stride=stride,
                                 current=r.current if use_current else None, r_current=nz["r_current"])


def _valid(n: int, h: int, ts: float) -> np.ndarray:
    k = np.arange(n)
    return k >= h + int(round(SETTLE_S / ts))


def figures(rig: Rig, r: RigRecord, params: PlantParams) -> dict:
    """The fit figures of one segment (module docstring); JSON-ready."""
    out: dict = {"label": r.label, "samples": len(r.y), "duration_s": len(r.y) * r.ts, "position": {}}
    if r.current is not None:
        o = predict(rig, r, params, r.ts, use_current=False)
        ok = _valid(len(r.y), 1, r.ts) & np.isfinite(o["i_pred"])
        cur = {"from_actuator": nrmse_fit(r.current[ok], o["i_pred"][ok])}
    else:
        cur = None
    for hs in HORIZONS_S:
        h = max(1, int(round(hs / r.ts)))
        o = predict(rig, r, params, hs)
        ok = _valid(len(r.y), h + 10, r.ts) & np.isfinite(o["y_pred"])
        y = r.y
        stay = np.full_like(y, np.nan)
        stay[h:] = y[:-h]
        cv = np.full_like(y, np.nan)
        m = max(1, int(round(0.01 / r.ts)))
        cv[h + m:] = y[m:-h] + h * (y[m:-h] - y[:-h - m]) / m
        e_model = np.linalg.norm(y[ok] - o["y_pred"][ok])
        e_stay = np.linalg.norm(y[ok] - stay[ok])
        out["position"][f"{hs * 1e3:g} ms"] = {
            "model": nrmse_fit(y[ok], o["y_pred"][ok]), "stays_put": nrmse_fit(y[ok], stay[ok]),
            "constant_velocity": nrmse_fit(y[ok], cv[ok]),
            "skill_vs_stays_put": float(1 - e_model / e_stay) if e_stay > 0 else float("nan")}
        if cur is not None:
            cur[f"{hs * 1e3:g} ms"] = nrmse_fit(r.current[ok], o["i_pred"][ok])
    out["current"] = cur
    return out


def calibrate(rig: Rig, records: Sequence[RigRecord], params: PlantParams | None = None, *,
              names: Sequence[str] | None = None, horizon_s: float = 0.020, stride: int = 10,
              progress=None) -> tuple[PlantParams, dict]:
    """One parameter set for several segments: least squares (scipy, trust-region reflective) on
    the ``horizon_s`` prediction errors of the reading and the current, each scaled by its noise
    level, over factors on the rig's values of ``names`` (default :data:`CALIBRATED`), bounded to
    [0.5, 2] (offsets: ±1 V).

    Returns the calibrated parameters and a summary (factors, cost before and after, evaluations)."""
    from scipy.optimize import least_squares

    p0 = params or rig.params
    names = tuple(names or CALIBRATED[rig.drive])
    nz = noise_defaults(rig, p0)
    base = np.array([getattr(p0, n) for n in names])
    additive = np.array([n in ("u_0", "x_0") for n in names])
    lo = np.where(additive, -1.0, 0.5)
    hi = np.where(additive, 1.0, 2.0)
    z0 = np.where(additive, 0.0, 1.0)
    evals = [0]

    def make(z: np.ndarray) -> PlantParams:
        vals = np.where(additive, base + z * np.where([n == "x_0" for n in names], 1e-3, 1.0), base * z)
        return p0.replace(**dict(zip(names, vals)))

    def resid(z: np.ndarray) -> np.ndarray:
        evals[0] += 1
        try:
            p = make(z)
            p.validate()
        except ValueError:
            return np.full(sum(len(r.y) // stride * 2 for r in records), 1e3)
        parts = []
        h = max(1, int(round(horizon_s / records[0].ts)))
        for r in records:
            o = predict(rig, r, p, horizon_s, stride=stride, noise=nz)
            ok = _valid(len(r.y), h, r.ts) & np.isfinite(o["y_pred"])
            ey = np.zeros(len(r.y) // stride + 1)
            sel = np.flatnonzero(ok)[: len(ey)]
            scale_y = max(float(np.std(r.y[ok])), 1e-9)
            e = (r.y[sel] - o["y_pred"][sel]) / scale_y
            ey[: len(e)] = np.nan_to_num(e, nan=10.0, posinf=10.0, neginf=-10.0)
            parts.append(ey / np.sqrt(len(records)))
            if r.current is not None:
                scale_i = max(float(np.std(r.current[ok])), 1e-9)
                ei = np.zeros_like(ey)
                e = (r.current[sel] - o["i_pred"][sel]) / scale_i
                ei[: len(e)] = np.nan_to_num(e, nan=10.0, posinf=10.0, neginf=-10.0)
                parts.append(ei / np.sqrt(len(records)))
        if progress:
            progress(evals[0])
        return np.concatenate(parts)

    r0 = resid(z0)
    sol = least_squares(resid, z0, bounds=(lo, hi), x_scale=np.where(additive, 0.1, 0.1), diff_step=1e-3,
                        max_nfev=40)
    p = make(sol.x)
    on_bound = [n for n, z, a, b in zip(names, sol.x, lo, hi) if min(z - a, b - z) < 1e-3 * (b - a)]
    return p, {"names": list(names), "values": {n: float(getattr(p, n)) for n in names},
               "rig_values": {n: float(v) for n, v in zip(names, base)},
               "cost_before": float(0.5 * r0 @ r0), "cost_after": float(sol.cost), "evaluations": evals[0],
               "on_bounds": on_bound}


# ----------------------------------------------------------------------------- effects on real records

#: The catalogue's effects that a real rig's plant can take, tried on a calibrated model: (name,
#: parameter, where it acts, starting grid, bounds). A start grid, because the prediction cost is
#: flat or multimodal in a time constant (the diagnosis's reason for its grids, too).
RIG_EFFECTS = (
    ("force_lag", "T_F", "mechanics", (5e-4, 1e-3, 2e-3, 4e-3, 8e-3), (1e-6, 0.05)),
    ("delay", "T_d", "actuator", (2.5e-4, 5e-4, 1e-3, 2e-3, 4e-3), (0.0, 0.02)),
    ("damping", "k_FV", "mechanics", (0.02, 0.1, 0.3, 1.0, 3.0), (0.0, 10.0)),
)
#: Held-out blocks [s]: the effect is fitted on the even blocks' predictions, judged on the odd ones.
EFFECT_BLOCK_S = 1.0
#: Relative reduction of the held-out prediction cost an effect must bring to be selected.
MIN_EFFECT_GAIN = 0.10


def prediction_cost(rig: Rig, records: Sequence[RigRecord], params: PlantParams, *, horizon_s: float = 0.020,
                    stride: int = 10, parity: int | None = None) -> dict[str, float]:
    """Mean squares of the ``horizon_s`` prediction errors of the reading (``"y"``) and of the
    current (``"i"``, where measured), each scaled by its record's spread (as :func:`calibrate`
    weighs them), and their mean (``"total"``), over the predictions that end in the even
    (``parity=0``) or odd (1) blocks of :data:`EFFECT_BLOCK_S`, or all (None)."""
    sums = {"y": [0.0, 0], "i": [0.0, 0]}
    for r in records:
        h = max(1, int(round(horizon_s / r.ts)))
        o = predict(rig, r, params, horizon_s, stride=stride)
        k = np.arange(len(r.y))
        ok = _valid(len(r.y), h, r.ts) & np.isfinite(o["y_pred"])
        if parity is not None:
            ok &= (k // max(1, int(round(EFFECT_BLOCK_S / r.ts)))) % 2 == parity
        if not ok.any():
            continue
        parts = {"y": (r.y[ok] - o["y_pred"][ok]) / max(float(np.std(r.y[ok])), 1e-9)}
        if r.current is not None:
            parts["i"] = (r.current[ok] - o["i_pred"][ok]) / max(float(np.std(r.current[ok])), 1e-9)
        for name, e in parts.items():
            sums[name][0] += float(np.sum(np.nan_to_num(e, nan=10.0, posinf=10.0, neginf=-10.0) ** 2))
            sums[name][1] += len(e)
    out = {name: s / n if n else float("nan") for name, (s, n) in sums.items()}
    used = [v for v in out.values() if np.isfinite(v)]
    out["total"] = float(np.mean(used)) if used else float("inf")
    return out


def _fit_one(rig: Rig, records: Sequence[RigRecord], params: PlantParams, name: str, grid, bounds,
             parity: int | None) -> tuple[float, float]:
    """The value of one effect parameter that minimises the prediction cost (grid, then a bounded
    scalar search around the best grid point), with the other parameters held: (value, cost)."""
    from scipy.optimize import minimize_scalar

    def cost(v: float) -> float:
        try:
            p = params.replace(**{name: float(v)})
            p.validate()
        except ValueError:
            return float("inf")
        return prediction_cost(rig, records, p, parity=parity)["total"]

    grid = [g for g in grid if bounds[0] <= g <= bounds[1]]
    costs = [cost(g) for g in grid]
    j = int(np.argmin(costs))
    lo = grid[j - 1] if j > 0 else bounds[0]
    hi = grid[j + 1] if j + 1 < len(grid) else bounds[1]
    res = minimize_scalar(cost, bounds=(max(lo, bounds[0]), min(hi, bounds[1])), method="bounded",
                          options={"xatol": 1e-3 * (hi - lo), "maxiter": 12})
    return (float(res.x), float(res.fun)) if res.fun < costs[j] else (float(grid[j]), float(costs[j]))


def effect_search(rig: Rig, records: Sequence[RigRecord], params: PlantParams, say=lambda s: None, *,
                  max_effects: int = 2) -> dict:
    """The catalogue's effects (:data:`RIG_EFFECTS`) tried on the calibrated model of a real rig,
    in greedy rounds: each effect not yet selected is fitted on the even held-out blocks and judged
    on the odd ones by the 20 ms prediction cost of the gap and of the current, each on its own (a
    mechanical effect shows in the gap, an actuator effect in the current, and either is diluted in
    their sum). The best one that lowers one signal's held-out cost by :data:`MIN_EFFECT_GAIN`
    without raising the other's by more than 1 % is selected, refitted on every block, and kept for
    the next round; at most ``max_effects``. JSON-ready: ``candidates`` (round, effect, parameter,
    value, location, held-out gain per signal), ``selected``, ``parameters`` (the selected effects'
    values) and ``held_out_cost`` of the model without an effect."""
    out: dict = {"held_out_cost": prediction_cost(rig, records, params, parity=1), "block_s": EFFECT_BLOCK_S,
                 "min_gain": MIN_EFFECT_GAIN, "candidates": [], "selected": [], "parameters": {}}
    current = params
    for rnd in range(1, max_effects + 1):
        base = prediction_cost(rig, records, current, parity=1)
        tried = []
        for name, param, location, grid, bounds in RIG_EFFECTS:
            if name in out["selected"]:
                continue
            say(f"round {rnd}: trying {name} ({param}) on the held-out blocks")
            v, _ = _fit_one(rig, records, current, param, grid, bounds, parity=0)
            held = prediction_cost(rig, records, current.replace(**{param: v}), parity=1)
            gains = {k: float(1 - held[k] / base[k]) for k in base if np.isfinite(base[k]) and base[k] > 0}
            worst = min(gains.values())
            gain = max(gains.get("y", -np.inf), gains.get("i", -np.inf)) if worst > -0.01 else worst
            tried.append({"round": rnd, "effect": name, "parameter": param, "value": v, "location": location,
                          "held_out_gain": gain, "held_out_gains": gains})
        out["candidates"] += tried
        best = max(tried, key=lambda c: c["held_out_gain"], default=None)
        if not best or best["held_out_gain"] < MIN_EFFECT_GAIN:
            break
        spec = next(e for e in RIG_EFFECTS if e[0] == best["effect"])
        v, _ = _fit_one(rig, records, current, spec[1], spec[3], spec[4], parity=None)
        current = current.replace(**{spec[1]: v})
        out["selected"].append(best["effect"])
        out["parameters"][spec[1]] = v
    return out


# ----------------------------------------------------------------------------- frequency response

def current_to_position(rig: Rig, r: RigRecord, params: PlantParams, *, seconds_per_segment: float = 2.0) -> dict:
    """The measured frequency response from coil current to position (Welch cross-spectra,
    ``G = P_iz / P_ii``, with the coherence) beside the model's, linearised at the segment's mean
    position: ``m·s²·x = dF/dx·x + dF/di·i`` (Eq. 16, 17), in the record's convention. In closed loop
    the estimate is biased where the coherence is low; the JSON gives both on 1–20 Hz."""
    from scipy import signal

    from .formulas import point

    if r.current is None:
        return {}
    fs = 1.0 / r.ts
    nper = min(len(r.y), int(seconds_per_segment * fs))
    z = r.position - r.position.mean()
    i = r.current - r.current.mean()
    f, Pii = signal.welch(i, fs=fs, nperseg=nper)
    _, Piz = signal.csd(i, z, fs=fs, nperseg=nper)
    _, coh = signal.coherence(i, z, fs=fs, nperseg=nper)
    G = Piz / np.where(Pii > 0, Pii, np.nan)
    pt = point(params, float(rig.to_x(r.position.mean())))
    s = 2j * np.pi * f
    sign = -1.0 if rig.convention == "gap" else 1.0
    M = sign * pt.dF_di / (params.m_k * s**2 - pt.dF_dx)
    band = (f >= 1.0) & (f <= 20.0)
    return {"f_Hz": f, "measured": G, "model": M, "coherence": coh,
            "summary": {"band_Hz": [1.0, 20.0], "mean_coherence": float(np.mean(coh[band])),
                        "gain_ratio_measured_over_model": float(np.median(np.abs(G[band]) / np.abs(M[band]))),
                        "phase_difference_deg": float(np.median(np.degrees(np.angle(G[band] / M[band]))))}}


# ----------------------------------------------------------------------------- verdict and report

#: A current model explaining less than this fit [%] from the actuator signal is at fault.
MIN_CURRENT_FIT = 80.0
#: Skill against "stays put" at 20 ms that a model of the mechanics must reach to count as explaining.
MIN_SKILL = 0.2


def information(rig: Rig, r: RigRecord) -> list[str]:
    """Why a segment carries too little information to judge a model (empty: enough)."""
    why = []
    if r.ts > 0.005:
        why.append(f"sampled every {r.ts * 1e3:g} ms: the 5 ms prediction is under one sample and the ball's "
                   "open-loop time constant (tens of ms) spans only a few samples")
    if rig.resolution:
        h = max(1, int(round(0.02 / r.ts)))
        moves = np.abs(r.position[h:] - r.position[:-h])
        if np.median(moves) < 2 * rig.resolution:
            why.append(f"the position moves less than two quantisation steps ({rig.resolution * 1e3:g} mm) in 20 ms "
                       f"on most samples (median {np.median(moves) * 1e3:.3f} mm)")
    return why


def conclude(rig: Rig, figs: list[dict], info: list[list[str]], cal: dict | None) -> tuple[str, list[str]]:
    """The verdict over the segments (``"explained"``, ``"unexplained: actuator"``, ``"unexplained:
    mechanics"``, ``"calibration failed"``, ``"too little information"``) and the reasons."""
    reasons: list[str] = []
    if not figs:
        return "calibration failed", ["no levitation segment of at least 1 s: nothing to calibrate on"]
    if all(info):
        reasons += sorted({w for ws in info for w in ws})
        cur = [f["current"]["from_actuator"] for f in figs if f.get("current")]
        if cur:
            reasons.append(f"for what it is worth, the rig file's coil model fits the current from the actuator "
                           f"signal at {np.median(cur):.1f} % (median over segments)")
        return "too little information", reasons
    if cal and cal.get("on_bounds"):
        return "calibration failed", [f"calibrated {', '.join(cal['on_bounds'])} ended on a bound"]
    cur = [f["current"]["from_actuator"] for f in figs if f.get("current")]
    skill = [f["position"]["20 ms"]["skill_vs_stays_put"] for f in figs
             if np.isfinite(f["position"]["20 ms"]["skill_vs_stays_put"])]
    if not skill:
        return "too little information", ["the gap never moves within a segment"]
    if cur and np.median(cur) < MIN_CURRENT_FIT:
        reasons.append(f"the coil current from the actuator signal fits only {np.median(cur):.1f} % "
                       f"(median over segments; at least {MIN_CURRENT_FIT:g} % expected)")
        return "unexplained: actuator", reasons
    if np.median(skill) < MIN_SKILL:
        reasons.append(f"the current path is explained ({np.median(cur):.1f} % fit) but the gap 20 ms ahead "
                       f"is predicted with skill {np.median(skill):+.2f} against 'stays put' (median; "
                       f"{MIN_SKILL:g} needed): what the model lacks acts on the force or the mechanics")
        return "unexplained: mechanics", reasons
    return "explained", [f"current fit {np.median(cur):.1f} %, skill at 20 ms {np.median(skill):+.2f}"]


#: A rig's force law that carries less or more of the ball's weight than this (median over the
#: levitating samples, at the measured gap and current) contradicts the record.
FORCE_BALANCE = (0.7, 1.4)
#: A declared controller that fits the recorded actuator signal (as a whole, or every loop of a
#: cascade fed the recorded intermediate signals) below this [%] is not the one that ran.
MIN_CONTROLLER_FIT = 50.0


def force_balance(rig: Rig, m: Measured, params: PlantParams | None = None) -> dict | None:
    """How much of the ball's weight the rig's force law carries at the record's measured gap and
    current, over the samples where the ball is off both stops (1 mm clear): the 10th, 50th and
    90th percentiles of ``F/(m·g)``. A ball that levitates for seconds is held, on average, by its
    weight: a median far from 1 is a force constant (or a current or position scale) that
    contradicts the record. ``None`` without a measured current or levitating samples."""
    from .formulas import point

    p = params or rig.params
    if m.current is None:
        return None
    x = rig.to_x(m.position)
    lev = (x > p.x_min + 1e-3) & (x < p.x_max - 1e-3)
    if lev.sum() < 10:
        return None
    step = max(1, int(lev.sum() // 2000))
    ratio = np.array([point(p, float(xk), float(ik)).F for xk, ik in
                      zip(x[lev][::step], np.clip(m.current[lev][::step], 0, None))]) / (p.m_k * p.g)
    q10, q50, q90 = np.percentile(ratio, [10, 50, 90])
    out = {"p10": float(q10), "median": float(q50), "p90": float(q90), "samples": int(lev.sum()),
           "consistent": bool(FORCE_BALANCE[0] <= q50 <= FORCE_BALANCE[1]),
           "current_scale_for_weight": float(1 / np.sqrt(q50)) if q50 > 0 else float("nan")}
    if rig.drive == "voltage" and m.drive is not None:
        # Ohm's law where the current settles (changes by under 2 % in 5 samples) and the drive
        # is inside its range: the voltage the rig file makes of the actuator signal over R·i
        u = np.asarray(rig.input_to_mu(m.drive))
        volts = np.maximum(p.k_DA * u + p.u_0, p.V_min)
        i = m.current
        still = np.zeros(len(i), bool)
        still[5:] = np.abs(i[5:] - i[:-5]) < 0.02 * np.abs(i[5:])
        lo, hi = rig.input_range
        span = rig.input_to_mu(np.array([lo, hi]))
        still &= (u > span[0] + 0.02 * (span[1] - span[0])) & (u < span[1] - 0.02 * (span[1] - span[0])) & (i > 0.05)
        if still.sum() >= 10:
            ohm = np.median(volts[still] / (p.R_c * i[still]))
            out["ohm"] = {"median_V_over_Ri": float(ohm), "samples": int(still.sum())}
    return out


def controller_check(rig: Rig, m: Measured, ctl) -> dict:
    """The declared controller replayed alone on the whole record's measured signals (reference,
    position, current): the NRMSE fit % of the actuator signal it gives against the recorded one.
    A cascade is also checked loop by loop when the record holds the current reference (each loop
    fed the recorded signals): the whole cascade compounds small errors of the first loop (a
    position printed to 0.1 mm through a derivative) in the second loop's integrator, so the
    per-loop fits say better whether the declaration is right. The controller's state at the first
    sample is unknown, and an integrator started off by a few mA drifts for the whole record: it is
    replayed from two starts, settled (holding the recorded current and actuator signal: a record
    cut from a running loop) and from rest (empty integrators, no current, no output: a controller
    switched on at the record's start), and the better fit is kept (``start``, ``fits_by_start``)."""
    from .controllers import Cascade, needs_current

    if m.reference is None or m.drive is None:
        raise ValueError(f"{m.path}: checking a declared controller needs the recorded reference and actuator signal")
    if needs_current(ctl) and m.current is None:
        raise ValueError(f"{m.path}: the declared controller reads the coil current, which the record lacks")
    y, w = np.asarray(rig.reading(m.position)), np.asarray(rig.reading(m.reference))
    u_meas = np.asarray(rig.input_to_mu(m.drive))
    x = float(rig.to_x(m.position[0]))
    starts = {"settled": ((x, 0.0, float(m.current[0]) if m.current is not None else 0.0), float(u_meas[0])),
              "rest": ((x, 0.0, 0.0), 0.0)}
    fits = {name: nrmse_fit(u_meas, fast.control(ctl, w, y, m.current, hold, x0))
            for name, (x0, hold) in starts.items()}
    start = max(fits, key=lambda k: fits[k] if np.isfinite(fits[k]) else -np.inf)
    out = {"actuator_fit": fits[start], "start": start, "fits_by_start": fits, "loops": {}}
    r_meas = m.extra.get("current_reference")
    if isinstance(ctl, Cascade) and r_meas is not None:
        r = fast.control(ctl.outer, w, y, None, float(r_meas[0]))
        ui = fast.control(ctl.inner, r_meas, m.current, None, float(u_meas[0]))
        out["loops"] = {"position -> current reference": {"fit": nrmse_fit(r_meas, r),
                                                         "rms_A": float(np.sqrt(np.mean((r - r_meas) ** 2)))},
                        "current -> actuator": {"fit": nrmse_fit(u_meas, ui),
                                                "rms_input_units": float(np.sqrt(np.mean((ui - u_meas) ** 2)))
                                                * (rig.params.k_DA if rig.input_unit == "V" else 1.0)}}
    return out


def closed_loop_figures(rig: Rig, r: RigRecord, m: Measured, params: PlantParams, ctl, horizon_s: float = 0.020) -> dict:
    """The declared controller replayed in closed loop with the model, by prediction: the filter
    follows the segment, and from every sample the model and the controller run ``horizon_s``
    ahead on their own predicted readings and current. Fit % of the gap and of the actuator signal."""
    seg = m.slice(r.segment.start, r.segment.stop)
    if seg.reference is None:
        raise ValueError(f"{m.path}: a closed-loop replay needs the recorded reference")
    w = np.asarray(rig.reading(seg.reference))
    h = max(1, int(round(horizon_s / r.ts)))
    nz = noise_defaults(rig, params)
    o = fast.predict(_start(rig, r, params), ctl, w, r.y, r.u, float(r.u[0]), q_force=nz["q_force"],
                     f_force=nz["f_force"], r_sensor=nz["r_sensor"], horizon=h)
    ok = _valid(len(r.y), h, r.ts) & np.isfinite(o["y_pred"]) & np.isfinite(o["u_pred"])
    return {"label": r.label, "horizon_s": horizon_s, "gap_fit": nrmse_fit(r.y[ok], o["y_pred"][ok]),
            "actuator_fit": nrmse_fit(r.u[ok], o["u_pred"][ok])}


# ----------------------------------------------------------------------------- the commands

def _load_all(rig: Rig, paths: Sequence[str | Path], resample: bool) -> list[tuple[Measured, list[RigRecord]]]:
    from .measured import read_measured

    out = []
    for p in paths:
        m = read_measured(p, resample=resample)
        out.append((m, prepare(rig, m)))
    return out


def run(rig: Rig, paths: Sequence[str | Path], out: str | Path, *, validate: Sequence[str | Path] = (),
        resample: bool = False, per_record: bool = True, progress=None, json_name: str = "rigfit.json",
        controller=None, effects: bool = True) -> dict:
    """Calibrates one parameter set on the records ``paths`` (all their levitation segments), reports
    every record's figures before and after, each record's own calibration (the spread between
    records: drift is a finding), the fit on the ``validate`` records not used, the verdict, and
    writes ``report.md``, the JSON and the plots into ``out``. Everything is read and checked
    before anything is written. ``controller``: a declared controller
    (:class:`maglev_cosim.controllers.ControllerFile`), checked against each record and replayed
    in closed loop (:func:`controller_check`, :func:`closed_loop_figures`). ``effects``: try the
    catalogue's effects on the calibrated model (:func:`effect_search`)."""
    import json

    say = progress or (lambda msg: None)
    train = _load_all(rig, paths, resample)
    held = _load_all(rig, validate, resample)
    segs = [r for _, rs in train for r in rs]
    out = Path(out)
    result: dict = {"rig": rig.name, "rig_file": str(rig.path), "records": [], "validation": [],
                    "horizons_s": list(HORIZONS_S)}
    cal = None
    params = rig.params
    info = [information(rig, r) for r in segs]
    lacking = {id(r): why for r, why in zip(segs, info)}
    if segs and not all(info):
        say(f"calibrating {', '.join(CALIBRATED[rig.drive])} on {len(segs)} segment(s)")
        params, cal = calibrate(rig, [r for r, why in zip(segs, info) if not why])
        say(f"calibrated in {cal['evaluations']} evaluations: cost {cal['cost_before']:.4g} -> {cal['cost_after']:.4g}")
    result["calibration"] = cal
    if cal is not None and effects:
        fit_on = [r for r, why in zip(segs, info) if not why]
        result["effects"] = effect_search(rig, fit_on, params, say)
        params = params.replace(**result["effects"]["parameters"])
    figs_after = []
    for m, rs in train:
        entry = {"file": str(m.path), "label": m.label, "warnings": m.warnings, "segments": [],
                 "force_balance": force_balance(rig, m)}
        if controller is not None:
            say(f"replaying the declared controller {controller.name} on {m.label}")
            entry["controller_check"] = controller_check(rig, m, controller.controller)
            entry["closed_loop"] = [closed_loop_figures(rig, r, m, params, controller.controller) for r in rs]
        for r in rs:
            say(f"figures of {r.label}")
            before, after = figures(rig, r, rig.params), figures(rig, r, params)
            seg = {"label": r.label, "before": before, "after": after}
            if per_record and cal and len(segs) > 1 and not lacking[id(r)]:
                own, own_info = calibrate(rig, [r])
                seg["own_calibration"] = own_info["values"]
            frf = current_to_position(rig, r, params)
            seg["frequency_response"] = frf.get("summary")
            entry["segments"].append(seg)
            figs_after.append(after)
        result["records"].append(entry)
    for m, rs in held:
        fb = force_balance(rig, m, params)
        for r in rs:
            say(f"validation figures of {r.label}")
            result["validation"].append({"file": str(m.path), "label": r.label, "before": figures(rig, r, rig.params),
                                         "after": figures(rig, r, params), "warnings": m.warnings,
                                         "force_balance_calibrated": fb})
    verdict, reasons = conclude(rig, figs_after, info, cal)
    held_skill = [v["after"]["position"]["20 ms"]["skill_vs_stays_put"] for v in result["validation"]]
    held_skill = [k for k in held_skill if np.isfinite(k)]
    if held_skill and np.median(held_skill) < MIN_SKILL:
        reasons.append(f"the calibration does not carry over to the {len(held_skill)} validation segment(s): their gap "
                       f"20 ms ahead has median skill {np.median(held_skill):+.2f} against 'stays put' ({MIN_SKILL:g} "
                       f"needed; best {max(held_skill):+.2f}, worst {min(held_skill):+.2f}): the verdict holds for the "
                       "calibration records only")
        own = [fb["median"] for fb in (force_balance(rig, m, params) for m, _ in train) if fb]
        for v in result["validation"]:
            k = v["after"]["position"]["20 ms"]["skill_vs_stays_put"]
            if not (np.isfinite(k) and k < MIN_SKILL):
                continue
            why = []
            fb = v["force_balance_calibrated"]
            if fb and own and not min(own) - 0.02 <= fb["median"] <= max(own) + 0.02:
                why.append(f"the calibrated force law carries {100 * fb['median']:.0f} % of the weight here against "
                           f"{100 * min(own):.0f}-{100 * max(own):.0f} % on the calibration records (the force gain "
                           "differs between runs)")
            cur = v["after"]["current"]
            if cur and cur["from_actuator"] < MIN_CURRENT_FIT:
                why.append(f"its coil current from the actuator signal fits only {cur['from_actuator']:.1f} %")
            why += [w for w in v["warnings"] if "Kalman" in w]
            if why:
                reasons.append(f"{v['label']} (skill {k:+.2f}): " + "; ".join(why))
    ef = result.get("effects")
    if ef:
        last = max(c["round"] for c in ef["candidates"])
        tried = ", ".join(f"{c['effect']} ({c['parameter']} = {c['value']:.4g}) {100 * c['held_out_gain']:+.1f} %"
                          for c in ef["candidates"] if c["round"] == last)
        if ef["selected"]:
            reasons.append(f"effects found: {', '.join(ef['selected'])} ("
                           + ", ".join(f"{k} = {v:.4g}" for k, v in ef["parameters"].items()) + ")")
        if last > len(ef["selected"]):   # the last round selected nothing
            reasons.append(("none of the remaining effects" if ef["selected"] else "no effect of the catalogue")
                           + f" explains enough on the held-out blocks: gains of the 20 ms prediction cost "
                           f"{tried} (at least {100 * MIN_EFFECT_GAIN:.0f} % needed)")
    for e in result["records"]:
        fb = e["force_balance"]
        if fb and not fb["consistent"]:
            reasons.append(f"{e['label']}: the rig file's force law carries {100 * fb['median']:.0f} % of the ball's "
                           f"weight at the recorded gap and current (median over {fb['samples']} levitating samples; "
                           f"10-90 %: {100 * fb['p10']:.0f}-{100 * fb['p90']:.0f} %): its force constant, or the "
                           "record's current or position scale, contradicts the record"
                           + (f"; the current would have to be {fb['current_scale_for_weight']:.2f}x the recorded "
                              "one to carry the weight" if np.isfinite(fb["current_scale_for_weight"]) else ""))
        ohm = (fb or {}).get("ohm")
        if ohm and not 0.7 <= ohm["median_V_over_Ri"] <= 1.4:
            both = (fb and not fb["consistent"]
                    and (ohm["median_V_over_Ri"] > 1) == (fb["current_scale_for_weight"] > 1))
            reasons.append(f"{e['label']}: where the current settles, the rig file's coil voltage is "
                           f"{ohm['median_V_over_Ri']:.2f}x R times the recorded current (median over {ohm['samples']} "
                           "samples; Ohm's law wants 1)"
                           + (f"; both checks find the recorded current too {'small' if ohm['median_V_over_Ri'] > 1 else 'large'} "
                              f"for the rig file ({fb['current_scale_for_weight']:.1f}x for the weight, "
                              f"{ohm['median_V_over_Ri']:.1f}x for Ohm's law): the record's current scale, or the rig "
                              "file's force constant and resistance, are wrong" if both else ""))
    if controller is not None:
        result["controller"] = {"name": controller.name, "file": str(controller.path), "type": controller.kind}
        for e in result["records"]:
            cc = e["controller_check"]
            loops = [v["fit"] for v in cc["loops"].values()]
            best = max(cc["actuator_fit"], min(loops) if loops else -np.inf)
            if best >= MIN_CONTROLLER_FIT:
                reasons.append(f"{e['label']}: the declared controller {controller.name} reproduces the recorded "
                               f"actuator signal (fit {cc['actuator_fit']:.1f} % from {cc['start']}"
                               + "".join(f"; {k} {v['fit']:.1f} %" for k, v in cc["loops"].items()) + ")")
            else:
                reasons.append(f"{e['label']}: the declared controller {controller.name} does not reproduce the "
                               f"recorded actuator signal (fit {cc['actuator_fit']:.1f} %, from rest or settled): the "
                               "declaration is not "
                               "the controller that ran; the figures above rest on the measured actuator signal "
                               "(the unknown-controller path) and do not depend on it")
    result["verdict"], result["reasons"] = verdict, reasons
    own = [s["own_calibration"] for e in result["records"] for s in e["segments"] if "own_calibration" in s]
    if len(own) > 1:
        result["spread"] = {n: {"min": min(o[n] for o in own), "max": max(o[n] for o in own),
                                "relative": float(np.ptp([o[n] for o in own]) / abs(np.mean([o[n] for o in own])))}
                            for n in own[0]}
    result["parameters"] = {**{n: float(getattr(params, n)) for n in CALIBRATED[rig.drive]},
                            **result.get("effects", {}).get("parameters", {})}
    out.mkdir(parents=True, exist_ok=True)
    plots = _plots(rig, segs[:1], params, out) if segs else []
    (out / json_name).write_text(json.dumps(_finite(result), indent=2, allow_nan=False) + "\n")
    (out / "report.md").write_text(_markdown(result, plots))
    result["written"] = [str(out / json_name), str(out / "report.md"), *map(str, plots)]
    return result


def _finite(v):
    """JSON-safe: non-finite numbers become null (strict JSON has no NaN or Infinity)."""
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


def _row(label: str, f: dict) -> str:
    cur = f.get("current") or {}
    cells = [label, f"{cur.get('from_actuator', float('nan')):.1f}"]
    for h in ("5 ms", "20 ms", "50 ms"):
        p = f["position"][h]
        cells.append(f"{p['model']:.1f} / {p['stays_put']:.1f} / {p['constant_velocity']:.1f} ({p['skill_vs_stays_put']:+.2f})")
    cells.append(f"{cur.get('20 ms', float('nan')):.1f}")
    return "| " + " | ".join(cells) + " |"


def _markdown(res: dict, plots: list[Path]) -> str:
    head = ("| segment | current from actuator, fit % | gap 5 ms: model / stays put / const. velocity (skill) "
            "| 20 ms | 50 ms | current 20 ms ahead, fit % |\n|---|---|---|---|---|---|")
    lines = [f"# Rig {res['rig']}: measured records", "", f"**Verdict: {res['verdict']}**", ""]
    lines += [f"- {r}" for r in res["reasons"]]
    lines += ["", "Fits are NRMSE fit % (MATLAB `compare`); the gap is predicted by the prediction-error replay "
              "driven by the measured actuator signal (the controller is not replayed); skill = 1 − ‖error of "
              "the model‖/‖error of 'stays put'‖ (> 0: the model beats the naive predictor).", ""]
    cal = res.get("calibration")
    if cal:
        lines += ["## Calibration", "", "| parameter | rig file | calibrated |", "|---|---|---|"]
        lines += [f"| {n} | {cal['rig_values'][n]:.6g} | {cal['values'][n]:.6g} |" for n in cal["names"]]
        lines += ["", f"Cost {cal['cost_before']:.4g} → {cal['cost_after']:.4g} in {cal['evaluations']} evaluations."]
        if res.get("spread"):
            lines += ["", "Each record calibrated on its own (the spread between records):", "",
                      "| parameter | min | max | spread (max − min)/mean |", "|---|---|---|---|"]
            lines += [f"| {n} | {s['min']:.6g} | {s['max']:.6g} | {100 * s['relative']:.1f} % |"
                      for n, s in res["spread"].items()]
        lines.append("")
    ef = res.get("effects")
    if ef:
        lines += ["## Effects of the catalogue on the calibrated model", "",
                  f"Each fitted on the even {ef['block_s']:g} s blocks, judged on the odd ones: the reduction of the "
                  f"20 ms prediction cost (at least {100 * ef['min_gain']:.0f} % to be selected).", "",
                  "| round | effect | acts on | parameter | fitted value | held-out gain: gap / current |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {c['round']} | {c['effect']} | {c['location']} | {c['parameter']} | {c['value']:.4g} | "
                  + " / ".join(f"{100 * c['held_out_gains'][k]:+.1f} %" if k in c["held_out_gains"] else "-"
                               for k in ("y", "i")) + " |" for c in ef["candidates"]]
        lines += ["", f"Selected: {', '.join(ef['selected']) or 'none'}.", ""]
    for title, key in (("Before calibration (the rig file's values)", "before"), ("After calibration", "after")):
        lines += [f"## {title}", "", head]
        lines += [_row(s["label"], s[key]) for e in res["records"] for s in e["segments"]]
        lines.append("")
    if res["validation"]:
        lines += ["## Validation on records not used for calibration", "", head]
        lines += [_row(v["label"], v["after"]) for v in res["validation"]]
        lines.append("")
    fr = [s["frequency_response"] for e in res["records"] for s in e["segments"] if s.get("frequency_response")]
    if fr:
        lines += ["## Current to gap: measured against the model (1–20 Hz)", "",
                  "| segment | mean coherence | gain measured/model | phase difference [deg] |", "|---|---|---|---|"]
        lines += [f"| {s['label']} | {s['frequency_response']['mean_coherence']:.2f} | "
                  f"{s['frequency_response']['gain_ratio_measured_over_model']:.2f} | "
                  f"{s['frequency_response']['phase_difference_deg']:+.0f} |"
                  for e in res["records"] for s in e["segments"] if s.get("frequency_response")]
        lines.append("")
    fbs = [(e["label"], e["force_balance"]) for e in res["records"] if e.get("force_balance")]
    if fbs:
        lines += ["## Force balance: the share of the weight the force law carries at the measured gap and current",
                  "", "| record | 10 % | median | 90 % | levitating samples |", "|---|---|---|---|---|"]
        lines += [f"| {lab} | {100 * f['p10']:.0f} % | {100 * f['median']:.0f} % | {100 * f['p90']:.0f} % | "
                  f"{f['samples']} |" for lab, f in fbs]
        lines.append("")
    if res.get("controller"):
        c = res["controller"]
        lines += [f"## The declared controller: {c['name']} ({c['type']})", "",
                  "Replayed alone on each record's measured signals, against the recorded actuator signal "
                  "(and loop by loop, when the record holds the current reference); then in closed loop with "
                  "the calibrated model, 20 ms ahead from every sample.", "",
                  "| record | actuator fit % | per loop | closed loop 20 ms: gap fit % / actuator fit % |",
                  "|---|---|---|---|"]
        for e in res["records"]:
            cc = e.get("controller_check", {})
            loops = "; ".join(f"{k}: {v['fit']:.1f} %" for k, v in cc.get("loops", {}).items()) or "-"
            cl = ", ".join(f"{x['gap_fit']:.1f} / {x['actuator_fit']:.1f}" for x in e.get("closed_loop", [])) or "-"
            lines.append(f"| {e['label']} | {cc.get('actuator_fit', float('nan')):.1f} | {loops} | {cl} |")
        lines.append("")
    lines += [f"![{p.stem}]({p.name})" for p in plots]
    return "\n".join(lines) + "\n"


def _plots(rig: Rig, segs: list[RigRecord], params: PlantParams, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = segs[0]
    written = []
    o = predict(rig, r, params, 0.020)
    oc = predict(rig, r, params, r.ts, use_current=False)
    n = len(r.y)
    k0 = min(n - 1, int(round(2.0 / r.ts)))
    k1 = min(n, k0 + int(round(3.0 / r.ts)))
    t = np.arange(n) * r.ts
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax[0].plot(t[k0:k1], 1e3 * r.position[k0:k1], "k", lw=1, label="measured")
    ax[0].plot(t[k0:k1], 1e3 * rig.position_for_reading(o["y_pred"][k0:k1]), "C1", lw=1, label="model, 20 ms ahead")
    ax[0].set_ylabel(f"position ({rig.convention}) [mm]")
    ax[0].legend(loc="best")
    if r.current is not None:
        ax[1].plot(t[k0:k1], r.current[k0:k1], "k", lw=1, label="measured")
        ax[1].plot(t[k0:k1], oc["i_pred"][k0:k1], "C0", lw=1, label="model from the actuator signal")
        ax[1].legend(loc="best")
    ax[1].set_ylabel("coil current [A]")
    ax[1].set_xlabel("time in segment [s]")
    fig.suptitle(r.label)
    fig.tight_layout()
    p = out / "prediction.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(p)
    frf = current_to_position(rig, r, params)
    if frf:
        f = frf["f_Hz"]
        band = (f > 0.3) & (f < 60)
        fig, ax = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
        ax[0].loglog(f[band], np.abs(frf["measured"][band]), "k", label="measured (Welch)")
        ax[0].loglog(f[band], np.abs(frf["model"][band]), "C1", label="model, linearised")
        ax[0].set_ylabel("|gap/current| [m/A]")
        ax[0].legend()
        ax[1].semilogx(f[band], np.degrees(np.angle(frf["measured"][band])), "k")
        ax[1].semilogx(f[band], np.degrees(np.angle(frf["model"][band])), "C1")
        ax[1].set_ylabel("phase [deg]")
        ax[2].semilogx(f[band], frf["coherence"][band], "k")
        ax[2].set_ylabel("coherence")
        ax[2].set_xlabel("frequency [Hz]")
        fig.suptitle(f"current to gap: {r.label}")
        fig.tight_layout()
        p = out / "frequency_response.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        written.append(p)
    return written
