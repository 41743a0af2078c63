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

import hashlib
import importlib
import json
import math
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares, minimize_scalar
from threadpoolctl import threadpool_limits

# Imported inside functions, on purpose: matplotlib (heavy, only the plots) and scipy.signal (0.7 s
# with the scipy.stats it loads, only the figures' spectra): both loaded on the background thread
# while the first stages run (_load_matplotlib).
from .._html import write_html
from ..loop import fast_loop
from ..loop.controllers import Cascade, needs_current
from ..loop.fmu import ensure_fmu
from ..plant import fast
from ..plant.calibrated_fmu import calibrated_fmu
from ..plant.fast import param_table
from ..plant.formulas import forces, point
from ..plant.params import PlantParams
from ..records.measured import Measured, Segment, levitation_segments
from ..records.record import RecordError
from ..rigs import Rig
from . import blackbox as bb
from . import reaction
from .effects import CATALOGUE, force_law
from .memo import Memo
from .jacobian import difference_jacobian, gauss_newton_gain
from .metrics import fit_ceiling, nrmse_fit, white_noise_rms
from .neldermead import nelder_mead
from .problem import Coord
from .result import (CalibratedFmu, Comparison, Fit, HorizonSkill, LocationEvidence, PredictionFit, RecordRef, Residual,
                     finite)
from .rig_result import (ClosedLoopFigures, ControllerCheck, EffectTrial, RigCalibration, RigCoilCalibration,
                         RigComparison, RigCorrection, RigDrift, RigFigures, RigForceBalance, RigHorizon, RigRecordResult,
                         RigRun, RigSearch, RigSegment, RigValidationSegment)

#: Prediction horizons of the position figures [s].
HORIZONS_S = (0.005, 0.020, 0.050)
#: Samples at a segment's start the figures skip while the filter settles [s].
SETTLE_S = 0.5
#: Parameters :func:`calibrate` fits, by drive type (multiplicative factors on the rig's values).
CALIBRATED = {"voltage": ("k_e", "z_e", "R_c", "k_DA", "u_0"), "current": ("k_c", "x_0", "k_i", "T_a")}
#: The coil's parameters, by drive type: fitted on the current from the actuator signal alone
#: (:func:`calibrate_coil`), on the calibration records (but ``kappa_R``: :data:`COIL_FIT`) and again
#: on every segment (their drift between runs, and the resistance's warming during each).
COIL = {"voltage": ("R_c", "k_DA", "u_0", "kappa_R"), "current": ("k_i",)}
#: Bounds of the coil resistance's drift ``kappa_R`` [1/s] (``R_c·(1 + kappa_R·t)``, t from the segment's
#: start: the winding warming during the run) that :func:`calibrate_coil` searches: ±1 %/s, a copper
#: winding warming or cooling by 2.5 K a second, far beyond a levitating coil's few watts. On the nine
#: shared Inteco records each segment's own fit found +0.045 to +0.11 %/s (every one of them warming).
COIL_DRIFT_BOUNDS = (-0.01, 0.01)
#: The coil stage on the calibration records fits these, :data:`COIL` (but ``kappa_R``) and the drive's transport
#: delay ``T_d`` (the duty a real-time controller computes at one sample reaches the coil about a
#: sample later: computation, output, the PWM period). The delay is the hardware's and software's,
#: the same in every run, so each segment's own coil keeps it (on the nine shared Inteco records
#: the current from the duty fits 89.4 % median without it, 91.2 % with 1.5 ms; every record gains).
#: The resistance's drift ``kappa_R`` is left to each segment's own coil: it is the run's own warming,
#: from the temperature the winding starts at, and one value shared by the calibration records (whose
#: resistances differ by several per cent between runs) took 0.145 %/s, above every segment's own
#: (0.048 to 0.109 %/s), standing in for those differences.
COIL_FIT = {d: (*(n for n in names if n != "kappa_R"), "T_d") for d, names in COIL.items()}
#: Bounds of the coil stage's delay [s] (its start: 1 ms, one sample of a 1 kHz rig).
COIL_DELAY_BOUNDS = (0.0, 0.01)
def mechanics_names(params: PlantParams) -> tuple[str, ...]:
    """The force law's two constants (exponential law ``k_e, z_e`` or inverse square ``k_c, x_0``):
    what :func:`calibrate` fits on the gap's prediction errors before the effect search."""
    return ("k_e", "z_e") if params.k_e > 0 else ("k_c", "x_0")


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
    reference: np.ndarray | None = None  #: the reference as the plant's reading [MU] (None: the record has none)
    #: whether the position is a state estimator's output logged in place of the sensor's reading
    #: (the reader's ``metadata["position_source"]``): judged, not calibrated on (:func:`information`)
    estimate: bool = False


def prepare(rig: Rig, m: Measured, *, min_duration: float = 1.0) -> list[RigRecord]:
    """The levitation segments of ``m`` (:func:`maglev_cosim.records.measured.levitation_segments`: off the
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
                             current=part.current, position=part.position, segment=s,
                             reference=None if part.reference is None else np.asarray(rig.reading(part.reference)),
                             estimate=m.metadata.get("position_source") == "estimate"))
    return out


def check_units(rig: Rig, m: Measured) -> None:
    """Refuses a record whose position contradicts the rig's stops by a unit factor: most samples
    outside the travel widened by half of it on each side (mm read as m: 1000x too large; or the
    other way round, a travel squeezed into a thousandth). Names the file and the column."""
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


#: The longest RK4 substep [s] of the replays (the plant's ``solver_step`` where it is longer; the
#: plant shortens it further where a force lag, a friction or the coil's time constant needs it). The
#: FMU's default of 0.1 ms is set for the CE152's fast dynamics. On the 1 kHz Inteco records, with the
#: rig file's values, 1 ms moves the gap predicted 5, 20 and 50 ms ahead by at most 1.4e-5 MU and the
#: current by at most 6.7e-5 A against 0.1 ms (step/MPC; multisteps_stairs/LQI: 2.4e-6 MU, 1.1e-6 A),
#: against a position step of 3.7e-4 MU, a 50 ms prediction error of 0.006 to 0.011 MU RMS and 10 mA
#: of current noise; 0.5 ms moved them by 5.1e-7 MU and 2.8e-6 A. A record's three predictions take
#: 0.33 s at 1 ms, 0.51 s at 0.5 ms and 1.9 s at 0.1 ms. The calibrated parameters and the calibrated
#: FMU keep the plant's own step.
REPLAY_SOLVER_STEP = 1e-3


def _start(rig: Rig, r: RigRecord, params: PlantParams) -> PlantParams:
    p = params
    x0 = float(np.clip(rig.to_x(r.position[0]), p.x_min, p.x_max))
    i0 = float(np.clip(r.current[0], 0.0, p.i_max)) if r.current is not None else p.i_start
    return p.replace(x_start=x0, v_start=0.0, i_start=i0, solver_step=max(p.solver_step, REPLAY_SOLVER_STEP))


def noise_defaults(rig: Rig, params: PlantParams) -> dict[str, float]:
    """The filter's disturbance model for a real rig: a random force of 1 % of the weight with a
    20 Hz corner, the rig file's sensor noise (``sensor.noise``; else the position's quantisation,
    else 10 µm), 10 mA on the current."""
    res = rig.sensor_noise or rig.resolution or 1e-5
    return {"q_force": 0.01 * params.m_k * params.g, "f_force": 20.0,
            "r_sensor": res / rig.position_scale if rig.sensor == "position" else 1e-3, "r_current": 0.01}


#: Replays :func:`predict` and :func:`predict_many` keep, most recent last (:func:`_cached`): the
#: stages ask for the same replay more than once (a cost on the even blocks and on the odd ones of
#: one parameter set, the start of a fit and its first step, a candidate's fitted value and its
#: held-out cost). About 1 MB each.
REPLAY_CACHE_SIZE = 64
_replays = Memo(REPLAY_CACHE_SIZE)


def _fingerprint(r: RigRecord) -> bytes:
    """A digest of the segment's signals (not its ``id``: a segment freed and another made at the same
    address must not find the first one's replays), kept on the segment beside the arrays it was taken
    of (taken again when one of them is replaced: every replay of a fit asks for it)."""
    arrays = (r.y, r.u, r.current, float(r.ts))
    memo = r.__dict__.get("_fingerprint")
    if memo is not None and all(a is b for a, b in zip(memo[0][:3], arrays[:3])) and memo[0][3] == arrays[3]:
        return memo[1]
    digest = _digest(r)
    r.__dict__["_fingerprint"] = (arrays, digest)
    return digest


def _digest(r: RigRecord) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    for a in (r.y, r.u, r.current):
        h.update(b"-" if a is None else np.ascontiguousarray(a, dtype=float).tobytes())
    h.update(repr(float(r.ts)).encode())
    return h.digest()


def _noise_key(nz: dict) -> tuple:
    return tuple(sorted((k, json.dumps(v, sort_keys=True) if isinstance(v, dict) else repr(v)) for k, v in nz.items()))


def _cached(key: tuple, compute):
    """``compute()``, or the result of the same ``key`` computed before (:data:`REPLAY_CACHE_SIZE`);
    its arrays are read-only (shared between callers)."""
    return _replays.get(key, compute, seal=_read_only)


def _read_only(out) -> None:
    for o in (out if isinstance(out, list) else [out]):
        for v in o.values():
            if isinstance(v, np.ndarray):
                v.flags.writeable = False


def predict(rig: Rig, r: RigRecord, params: PlantParams, horizon_s: float, *, use_current: bool = True,
            stride: int = 1, noise: dict[str, float] | None = None, offset: int = 0) -> dict[str, np.ndarray]:
    """``y_pred`` [MU] and ``i_pred`` [A] ``horizon_s`` ahead (NaN where no prediction ends), from the
    samples ``k`` with ``k % stride == offset``."""
    nz = noise or noise_defaults(rig, params)
    h = max(1, int(round(horizon_s / r.ts)))
    start = _start(rig, r, params)
    key = ("one", _fingerprint(r), fast.param_vector(start).tobytes(), _noise_key(nz), h, stride, offset, use_current)

    def one(part: RigRecord, p: PlantParams, flags=None) -> dict[str, np.ndarray]:
        return fast.predict_measured(
            _start(rig, part, p), part.y, part.u, ts=r.ts, q_force=nz["q_force"], f_force=nz["f_force"],
            r_sensor=nz["r_sensor"], horizon=h, stride=stride, current=part.current if use_current else None,
            r_current=nz["r_current"], correction=nz.get("correction"), offset=offset, coil_free=not use_current)

    return _cached(key, lambda: _in_chunks(r, params, h, stride, None, one))


def predict_many(rig: Rig, r: RigRecord, params: PlantParams, horizons_s: Sequence[float], *, stride: int = 1,
                 noise: dict[str, float] | None = None, starts: np.ndarray | None = None) -> list[dict[str, np.ndarray]]:
    """:func:`predict` at each of ``horizons_s`` in one pass of the filter (one trajectory to the
    longest horizon, read at each: the same predictions as one call per horizon, at the cost of the
    longest alone); one dict per horizon (``d``, ``d_sd``, ``innov`` shared). ``starts``: flags of the
    samples to predict from (besides the stride), None: all."""
    nz = noise or noise_defaults(rig, params)
    hs = [max(1, int(round(h / r.ts))) for h in horizons_s]
    start = _start(rig, r, params)

    def one(part: RigRecord, p: PlantParams, flags: np.ndarray | None) -> dict[str, np.ndarray]:
        return fast.predict_horizons(_start(rig, part, p), part.y, part.u, ts=r.ts, q_force=nz["q_force"],
                                     f_force=nz["f_force"], r_sensor=nz["r_sensor"], horizons=hs, stride=stride,
                                     current=part.current, r_current=nz["r_current"], correction=nz.get("correction"),
                                     starts=flags)

    def compute() -> list[dict[str, np.ndarray]]:
        o = _in_chunks(r, params, max(hs), stride, starts, one)
        rest = {k: v for k, v in o.items() if k not in ("y_pred", "i_pred")}
        return [{"y_pred": o["y_pred"][q], "i_pred": o["i_pred"][q], **rest} for q in range(len(hs))]

    flags = None if starts is None else hashlib.blake2b(np.packbits(np.asarray(starts, bool)).tobytes(),
                                                        digest_size=16).digest()
    key = ("many", _fingerprint(r), fast.param_vector(start).tobytes(), _noise_key(nz), tuple(hs), stride, flags)
    return _cached(key, compute)


#: A segment at least this long [s] is replayed as two chunks side by side on the machine's cores
#: (:func:`_in_chunks`): the filter's passes are sequential in time, and a single segment's fit
#: otherwise keeps one core of two busy between its Jacobians.
CHUNK_S = 8.0


def _in_chunks(r: RigRecord, params: PlantParams, h: int, stride: int, starts: np.ndarray | None, one
               ) -> dict[str, np.ndarray]:
    """``one(chunk, params, flags)`` (a filter pass: arrays with one value per sample, last axis) over
    ``r``, in two chunks on the machine's cores where ``r`` is at least :data:`CHUNK_S` long; the
    arrays put together. The second chunk's filter starts :data:`SETTLE_S` plus the horizon ``h``
    before the first sample it gives, on the grid of the stride and of the filter's linearisation
    (:data:`~maglev_cosim.plant.fast.JAC_EVERY`), and with the parameters of a plant whose
    clock starts there (:func:`shifted`): the filter forgets where it started within that time (on
    the shared Inteco records the predictions 20 and 50 ms ahead, the innovations and the random
    force agree with one pass over the segment to 1e-8 of their spread), so the figures are those of
    one pass in about half its wall time."""
    n = len(r.y)
    mid = n // 2
    grid = math.lcm(stride, fast.JAC_EVERY)
    c0 = max(0, (mid - int(round(SETTLE_S / r.ts)) - h) // grid * grid)
    later = shifted(params, c0 * r.ts) if n * r.ts >= CHUNK_S and (os.cpu_count() or 1) > 1 else None
    if later is None:
        return one(r, params, starts)

    def part(a: int, b: int) -> RigRecord:
        return RigRecord(label=r.label, ts=r.ts, y=r.y[a:b], u=r.u[a:b],
                         current=None if r.current is None else r.current[a:b], position=r.position[a:b],
                         segment=r.segment, reference=None if r.reference is None else r.reference[a:b])

    pieces = [(0, 0, part(0, mid), params), (c0, mid, part(c0, n), later)]
    got = _map(lambda pc: one(pc[2], pc[3], None if starts is None else starts[pc[0]:pc[0] + len(pc[2].y)]), pieces)
    out = {}
    for key in got[0]:
        a = np.empty(got[0][key].shape[:-1] + (n,))
        for (first, keep, piece, _), g in zip(pieces, got):
            a[..., keep:first + len(piece.y)] = g[key][..., keep - first:]
        out[key] = a
    return out


def shifted(params: PlantParams, t0: float) -> PlantParams | None:
    """The parameters of the same plant with its clock started ``t0`` [s] later: the terms that
    depend on the time since the start (a sensor's drift ``r_y``, the force gain's ``kappa_c``, the
    coil resistance's ``kappa_R``, a pickup's phase) rewritten so that at its time ``τ`` the plant is
    the original at ``t0 + τ``. None where no such parameters exist (a drift that has taken a gain
    to 0 by ``t0``, a value outside its range)."""
    p, ch = params, {}
    if p.r_y:
        ch["y_0"] = p.y_0 + p.r_y * t0
    if p.kappa_c:
        a = 1.0 + p.kappa_c * t0
        if not a > 0:
            return None
        ch.update(k_c=p.k_c * a, k_e=p.k_e * a, kappa_c=p.kappa_c / a)
    if p.kappa_R:
        a = 1.0 + p.kappa_R * t0
        if not a > 0:
            return None
        ch.update(R_c=p.R_c * a, kappa_R=p.kappa_R / a)
    if p.A_d:
        ch["phi_d"] = math.remainder(p.phi_d + 2 * math.pi * p.f_d * t0, 2 * math.pi)
    if not ch:
        return p
    try:
        out = p.replace(**ch)
        out.validate()
    except ValueError:
        return None
    return out


def trajectories(rig: Rig, r: RigRecord, params: PlantParams, horizon: int, *,
                 noise: dict[str, float] | None = None) -> tuple[np.ndarray, list[dict[str, np.ndarray]]]:
    """The filter's predictions driven by the measured actuator signal from every sample, to
    ``horizon`` samples ahead: ``traj[k, j]`` the reading predicted for ``k + j`` at ``k``
    (``traj[:, 0]`` the measured reading; NaN where none ends), and :func:`predict_many`'s dicts
    for ``j = 1..horizon`` (the same passes, :data:`~maglev_cosim.plant.fast.MAX_HORIZONS` a time)."""
    n = len(r.y)
    traj = np.full((n, horizon + 1), np.nan)
    traj[:, 0] = r.y
    outs: list[dict[str, np.ndarray]] = []
    for j0 in range(1, horizon + 1, fast.MAX_HORIZONS):
        js = range(j0, min(j0 + fast.MAX_HORIZONS, horizon + 1))
        outs += predict_many(rig, r, params, [j * r.ts for j in js], noise=noise)
    for j, o in enumerate(outs, start=1):
        traj[:n - j, j] = o["y_pred"][j:]
    return traj, outs


def _valid(n: int, h: int, ts: float) -> np.ndarray:
    k = np.arange(n)
    return k >= h + int(round(SETTLE_S / ts))


#: Blocks [s] over which the filtered random force is averaged to show its drift.
DRIFT_BLOCK_S = 1.0


def drift(r: RigRecord, d: np.ndarray, d_sd: np.ndarray, weight: float) -> RigDrift:
    """The filtered random force on the ball (``d`` [N], ``d_sd`` its standard deviation) as a
    drift: its mean over blocks of :data:`DRIFT_BLOCK_S` in % of the ball's ``weight`` [N], with
    ±2σ (the filter's own standard deviation, which the block mean does not shrink: the force is
    correlated across the block), and the change from the first to the last block, called a
    finding when it exceeds the two blocks' combined 2σ."""
    nb = max(1, int(round(DRIFT_BLOCK_S / r.ts)))
    skip = int(round(SETTLE_S / r.ts))
    t, mean, sd = [], [], []
    for a in range(skip, len(d) - nb // 2, nb):
        blk = slice(a, min(a + nb, len(d)))
        if np.all(np.isfinite(d[blk])):
            t.append(float((a + (blk.stop - a) / 2) * r.ts))
            mean.append(float(100 * np.mean(d[blk]) / weight))
            sd.append(float(100 * np.mean(d_sd[blk]) / weight))
    out = RigDrift(t_s=t, force_pct_weight=mean, two_sigma_pct_weight=[2 * v for v in sd])
    if len(mean) >= 2:
        change = mean[-1] - mean[0]
        band = 2 * float(np.hypot(sd[0], sd[-1]))
        out.change_pct_weight, out.change_two_sigma = change, band
        out.significant, out.range_pct_weight = bool(abs(change) > band), [min(mean), max(mean)]
    return out


def figures(rig: Rig, r: RigRecord, params: PlantParams, noise: dict[str, float] | None = None,
            black_box: dict[float, object] | None = None) -> RigFigures:
    """The fit figures of one segment (module docstring). ``black_box``: the fitted
    direct predictors per horizon (:func:`maglev_cosim.diagnosis.blackbox.fit`), shown beside the
    model and the naive predictors, all as skill against "stays put" over the same samples."""
    position: dict[str, RigHorizon] = {}
    drifted = None
    if r.current is not None:
        o = predict(rig, r, params, r.ts, use_current=False, noise=noise)
        ok = _valid(len(r.y), 1, r.ts) & np.isfinite(o["i_pred"])
        white = white_noise_rms(r.current[ok] - o["i_pred"][ok], r.ts)
        cur = {"from_actuator": nrmse_fit(r.current[ok], o["i_pred"][ok]), "noise_A": white,
               "noise_ceiling": fit_ceiling(r.current[ok], white)}
    else:
        cur = None
    series = bb.Series(r.position, r.current if r.current is not None else r.u, r.ts)
    lags = [_lag(r, hs) for hs in HORIZONS_S]
    traj, every = trajectories(rig, r, params, max(lags), noise=noise)
    outs = [every[h - 1] for h in lags]
    try:
        loop: reaction.ReactionPrediction | None = reaction.predict(r.y, r.u, r.reference, traj, lags, r.ts,
                                                                           current=r.current)
        identified = loop.to_json()
    except ValueError as e:     # too short to identify a controller: the model driven by the actuator signal
        loop = None
        identified = {"missing": str(e)}
    for q, (hs, o) in enumerate(zip(HORIZONS_S, outs)):
        h = lags[q]
        y = r.y
        y_loop = loop.y_pred[q] if loop is not None else o["y_pred"]
        # the skills count where both model predictions end: the closed loop's on the starts whose
        # window lies in one block of the cross-fitting (reaction.predict)
        ok = _valid(len(r.y), h + 10, r.ts) & np.isfinite(o["y_pred"]) & np.isfinite(y_loop)
        stay = bb.stays_put(y, h)
        cv = bb.constant_velocity(y, h, r.ts)
        entry = RigHorizon(model=nrmse_fit(y[ok], y_loop[ok]), stays_put=nrmse_fit(y[ok], stay[ok]),
                           model_measured_input=nrmse_fit(y[ok], o["y_pred"][ok]),
                           rms_y=float(np.sqrt(np.mean((y[ok] - y_loop[ok]) ** 2))) if ok.any() else float("nan"),
                           rms_y_measured_input=float(np.sqrt(np.mean((y[ok] - o["y_pred"][ok]) ** 2))) if ok.any()
                           else float("nan"),
                           constant_velocity=nrmse_fit(y[ok], cv[ok]),
                           skill_vs_stays_put=bb.skill(y, y_loop, stay, ok),
                           skill={"model": bb.skill(y, y_loop, stay, ok),
                                  "model_measured_input": bb.skill(y, o["y_pred"], stay, ok),
                                  "constant_velocity": bb.skill(y, cv, stay, ok)})
        if black_box and hs in black_box:
            # the black box predicts the record's position: both are compared there too
            yb = black_box[hs].predict(series)
            okb = ok & np.isfinite(yb)
            entry.black_box = nrmse_fit(r.position[okb], yb[okb])
            entry.skill["black_box"] = bb.skill(r.position, yb, bb.stays_put(r.position, h), okb)
            if ("past", hs) in black_box:
                yp = black_box[("past", hs)].predict(series)
                entry.skill["black_box_past"] = bb.skill(r.position, yp, bb.stays_put(r.position, h),
                                                         okb & np.isfinite(yp))
            entry.skill["model_on_position"] = bb.skill(r.position, _to_position(rig, y_loop),
                                                        bb.stays_put(r.position, h), okb)
        position[f"{hs * 1e3:g} ms"] = entry
        if cur is not None:
            cur[f"{hs * 1e3:g} ms"] = nrmse_fit(r.current[ok], o["i_pred"][ok])
        if hs == HORIZONS_S[0]:
            drifted = drift(r, o["d"], o["d_sd"], params.m_k * params.g)
    return RigFigures(label=r.label, samples=len(r.y), duration_s=len(r.y) * r.ts, position=position,
                      identified_controller=identified, drift=drifted, current=cur)


def _to_position(rig: Rig, y_pred: np.ndarray) -> np.ndarray:
    """Predicted readings [MU] as record positions [m] (the rig's sensor inverse; NaN stays NaN)."""
    out = np.full(len(y_pred), np.nan)
    ok = np.isfinite(y_pred)
    out[ok] = rig.position_for_reading(y_pred[ok])
    return out


def calibrate_coil(rig: Rig, records: Sequence[RigRecord], params: PlantParams, *,
                   names: Sequence[str] | None = None) -> tuple[PlantParams, RigCoilCalibration | None]:
    """The coil's parameters (default :data:`COIL` of the rig's drive) that make the current
    computed from the actuator signal alone (the filter never sees the measured current; the gap
    is tracked) fit the measured current: least squares on factors in [0.5, 2] (offsets ±1 V; the
    delay ``T_d`` within :data:`COIL_DELAY_BOUNDS`, the resistance's drift ``kappa_R`` within
    :data:`COIL_DRIFT_BOUNDS`). Returns the parameters and a :class:`~.rig_result.RigCoilCalibration` (``values``, ``sigma``: ±1σ from
    the Jacobian, widened for the residual's correlation from sample to sample (an AR(1) count of
    independent samples), ``fit`` % per record, ``on_bounds``); with no measured current, the
    parameters unchanged and ``None``."""
    names = tuple(names or COIL[rig.drive])
    use = [r for r in records if r.current is not None]
    if not use:
        return params, None
    base = np.array([getattr(params, n) for n in names])
    additive = np.array([n == "u_0" for n in names])
    # the delay in ms, absolute (from 0, which a factor could not leave)
    delay = np.array([n == "T_d" for n in names])
    # the resistance's drift in 1e-3/s, absolute (from 0 too)
    drift = np.array([n == "kappa_R" for n in names])
    absolute = delay | drift
    nz = noise_defaults(rig, params)

    def make(z: np.ndarray) -> PlantParams:
        vals = np.where(absolute, 1e-3 * z, np.where(additive, base + z, base * z))
        vals = np.where(delay & (vals < 1e-6), 0.0, vals)   # a delay under 1 µs is off
        return params.replace(**dict(zip(names, vals)))

    def currents(p: PlantParams, r: RigRecord) -> tuple[np.ndarray, np.ndarray]:
        o = predict(rig, r, p, r.ts, use_current=False, noise=nz)
        ok = _valid(len(r.y), 1, r.ts) & np.isfinite(o["i_pred"])
        return o["i_pred"][ok], r.current[ok]

    # the residuals take every third sample from the first one the figures count (_valid): the
    # predictions are made from those alone (offset), the filter still follows every sample
    first = {id(r): int(np.argmax(_valid(len(r.y), 1, r.ts))) for r in use}
    spread = {id(r): max(float(np.std(r.current[_valid(len(r.y), 1, r.ts)])), 1e-9) for r in use}

    def every_third(p: PlantParams, r: RigRecord) -> tuple[np.ndarray, np.ndarray]:
        o = predict(rig, r, p, r.ts, use_current=False, noise=nz, stride=3, offset=(first[id(r)] - 1) % 3)
        ok = _valid(len(r.y), 1, r.ts) & np.isfinite(o["i_pred"])
        return o["i_pred"][ok], r.current[ok]

    def resid(z: np.ndarray) -> np.ndarray:
        try:
            p = make(z)
            p.validate()
            parts = []
            for r, (ip, im) in zip(use, _map(lambda r: every_third(p, r), use)):
                parts.append((ip - im) / spread[id(r)] / np.sqrt(len(ip) * len(use)))
            return np.nan_to_num(np.concatenate(parts), nan=10.0, posinf=10.0, neginf=-10.0)
        except ValueError:
            return np.full(sum(len(r.y) // 3 + 1 for r in use), 10.0)

    lo = np.where(delay, 1e3 * COIL_DELAY_BOUNDS[0],
                  np.where(drift, 1e3 * COIL_DRIFT_BOUNDS[0], np.where(additive, -1.0, 0.5)))
    hi = np.where(delay, 1e3 * COIL_DELAY_BOUNDS[1],
                  np.where(drift, 1e3 * COIL_DRIFT_BOUNDS[1], np.where(additive, 1.0, 2.0)))
    z0 = np.where(delay, np.clip(1e3 * base, 1.0, None), np.where(drift, 1e3 * base, np.where(additive, 0.0, 1.0)))
    fun, jac = difference_jacobian(resid, lo, hi, 1e-4, map_fn=_map, unit_floor=True)
    sol = least_squares(fun, np.clip(z0, lo, hi), jac=jac, bounds=(lo, hi),
                        x_scale=np.where(delay, 0.5, 0.05), max_nfev=30)
    p = make(sol.x)
    return p, RigCoilCalibration(
        names=list(names), values={n: float(getattr(p, n)) for n in names},
        sigma=_coil_sigma(sol, names, base, additive, absolute),
        fit={r.label: nrmse_fit(*reversed(c)) for r, c in zip(use, _map(lambda r: currents(p, r), use))},
        on_bounds=[n for n, z, a, b in zip(names, sol.x, lo, hi) if min(z - a, b - z) < 1e-3 * (b - a)])


def _coil_sigma(sol, names: Sequence[str], base: np.ndarray, additive: np.ndarray, absolute: np.ndarray
                ) -> dict[str, float]:
    """±1σ of :func:`calibrate_coil`'s parameters in their own units: the Jacobian's covariance at the
    solution, scaled by the residual's variance and widened by ``sqrt((1 + ρ)/(1 − ρ))`` for its
    correlation ρ from one residual to the next (an AR(1) residual: fewer independent samples than
    rows; the current's model errors are slow beside its 1 kHz samples)."""
    e = np.asarray(sol.fun, float)
    n, k = len(e), len(sol.x)
    rho = float(np.clip(np.corrcoef(e[:-1], e[1:])[0, 1], 0.0, 0.99)) if n > 3 and np.std(e) > 0 else 0.0
    try:
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * (float(e @ e) / max(n - k, 1)) * (1 + rho) / (1 - rho)
        sz = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        sz = np.full(k, np.nan)
    # z: factors on the start (R_c, k_DA), volts (u_0), thousandths (T_d [ms], kappa_R [1e-3/s])
    return {nm: float(sz[j] * (1e-3 if absolute[j] else (1.0 if additive[j] else abs(base[j]))))
            for j, nm in enumerate(names)}


#: The filter's disturbance model, calibrated with the plant (log-factors on :func:`noise_defaults`):
#: the random force's RMS and corner (a low corner is a slowly drifting force: a gain that changes
#: during the run, or a force the mechanics lacks) and the sensor noise.
NOISE = ("q_force", "f_force", "r_sensor")
#: :func:`calibrate` stops when a step lowers the cost by less than this share of it (scipy's ``ftol``,
#: 1e-8 by default). Its parameters then lie within about ``sqrt(ftol·rows)`` of their ±1σ from the
#: optimum (the cost near it is quadratic, and 1σ raises it by about ``cost/rows``): with the 2000 to
#: 7000 rows of one to three 15 s records, under 0.1σ. The default's tail on the Inteco records took
#: five or six more iterations (each a Jacobian: one replay per parameter) that lowered the cost by
#: less than 1e-9 of it.
CAL_FTOL = 1e-6
#: :func:`calibrate` stops when the trust region's step is shorter than this share of the scaled
#: coordinates' norm (scipy's ``xtol``, 1e-8 by default). With the default, the fits of three of the
#: nine shared Inteco records ended in a run of refused steps after their last accepted one (each a
#: replay, the region cut to a quarter of the refused step each time); 1e-4 saves 14, 6 and 5 of
#: their diagnoses' calibration replays (105, 97 and 81).
#: At 1e-4 a step moves a factor (scale 0.1) by at most about 3e-4 of its value, and a log-factor of
#: the disturbance model by about 3e-3. Measured on those nine records: the same verdicts and effects;
#: seven with every number the same, two whose fits took another path, ending within 0.05σ of each
#: parameter (multisteps_stairs/PID_anti_windup: k_FV 3.9775 -> 3.9835 ± 0.135, the cost 1.4e-5 lower).
CAL_XTOL = 1e-4
#: Horizons [s] whose prediction errors :func:`calibrate` minimises: those the figures judge (the
#: long one is where an unstable plant's model errors show; the short ones keep the fast dynamics
#: and the filter on the readings). 20 and 50 ms until 2026-11-28. In a closed loop the actuator
#: signal after a prediction's start reacts to the disturbance the prediction cannot see, so the
#: disturbance model that predicts best 20 and 50 ms ahead driven by it need not be one that follows
#: the readings: on emulated Inteco records of the rig file's own model (the shipped LQI reading the
#: noisy gap, a random force of 0.4 % of the weight with a 1 Hz corner, 10 um of sensor noise;
#: three square-wave records calibrated, three sines judged) that calibration took a sensor noise
#: of 0.35 MU (9.5 mm; 10 um planted) and a random force of 7.7 N, selected a force lag and a
#: damping none of which was planted, and predicted the sines 5 ms ahead at a skill of -1.02 (black
#: box +0.39). With the 5 ms errors in the cost: no effect, k_e 3.217 and z_e 6.30 mm (3.206 and
#: 6.31 planted), and the model ahead of the black box at every horizon (+0.41/+0.76/+0.82 against
#: +0.39/+0.75/+0.76). On the shared Inteco records the validation medians moved by at most 0.01.
CAL_HORIZONS_S = HORIZONS_S
#: The calibration's Jacobian by differences (one replay per parameter, two at a time on the 2-core
#: machine) at its first point and every CAL_JAC_REFRESH-th accepted point after; Broyden's rank-one
#: update at those between (:func:`~.jacobian.difference_jacobian`). 1: differences at every point.
CAL_JAC_REFRESH = 3
#: :func:`calibrate` goes on with difference Jacobians at every point where, after its fit with
#: Broyden's updates, the Gauss-Newton step of the differences would still lower the cost by this
#: fraction of it (a hundred times ``CAL_FTOL``: the fit stopped short, not at a tolerance).
CAL_RESTART_GAIN = 1e-4


def calibrate(rig: Rig, records: Sequence[RigRecord], params: PlantParams | None = None, *,
              names: Sequence[str] | None = None, noise: dict[str, float] | None = None,
              horizons_s: Sequence[float] = CAL_HORIZONS_S, stride: int = 20, max_evaluations: int = 60,
              fit_noise: bool = True, parity: int | None = None, progress=None) -> tuple[PlantParams, RigCalibration]:
    """One parameter set for several segments, by the prediction-error method: least squares
    (scipy, trust-region reflective) on the prediction errors ``horizons_s`` ahead of the gap (each
    scaled by the error of "stays put" at that horizon, so every horizon counts alike) and of the
    coil current (scaled by its spread), over factors on the rig's values of ``names`` (default
    :data:`CALIBRATED`) bounded to [0.5, 2] (offsets: ±1 V; an effect parameter at 0 is searched
    on [0, its catalogue bound]) and log-factors of ±4 on the filter's disturbance model
    (:data:`NOISE`, starting from ``noise`` or :func:`noise_defaults`; held with ``fit_noise=False``).
    ``parity``: only the predictions that end in the even (0) or odd (1) blocks of
    :data:`EFFECT_BLOCK_S` count (the effect search's fit and held-out halves).

    Returns the calibrated parameters and a :class:`~.rig_result.RigCalibration`: ``values``,
    ``rig_values``, ``noise`` (the calibrated disturbance model), costs before and after, evaluations,
    ``on_bounds``."""
    p0 = params or rig.params
    names = tuple(names or CALIBRATED[rig.drive])
    nz0 = dict(noise or noise_defaults(rig, p0))
    base = np.array([getattr(p0, n) for n in names])
    additive = np.array([n in ("u_0", "x_0") for n in names])
    ranges = _effect_ranges(p0)
    # an effect parameter is searched over its catalogue range (not by factors of its start: a lag
    # found at 1 ms by the effect search may belong at 3 ms once the rest moves with it)
    absolute = np.array([n in ranges for n in names])
    effect_lo = np.array([ranges[n][0] if n in ranges else 0.0 for n in names])
    effect_hi = np.array([ranges[n][1] if n in ranges else 1.0 for n in names])
    # a parameter whose range starts at 0 (a lag, a damping, a share) is off there; a signed one (a
    # drift, a bend) is not
    offable = absolute & (effect_lo == 0.0)
    free = NOISE if fit_noise else ()
    lo = np.concatenate([np.where(additive, -1.0, np.where(absolute, effect_lo, 0.5)), np.full(len(free), -4.0)])
    hi = np.concatenate([np.where(additive, 1.0, np.where(absolute, effect_hi, 2.0)), np.full(len(free), 4.0)])
    # an effect parameter that is off starts inside its range (the middle of its catalogue grid):
    # on its lower bound the fit would start where a lag's switch-on makes the cost jump
    z0 = np.concatenate([np.where(additive, 0.0, np.where(absolute, [b if b != 0 else (ranges[n][2] if n in ranges else 0.0)
                                                                      for n, b in zip(names, base)], 1.0)),
                         np.zeros(len(free))])
    scale = np.concatenate([np.where(absolute, 0.1 * np.maximum(np.abs(effect_lo), effect_hi), 0.1),
                            np.ones(len(free))])
    evals = [0]

    def make(z: np.ndarray) -> tuple[PlantParams, dict[str, float]]:
        zp = z[: len(names)]
        # an effect parameter under 1e-4 of its range is off (a lag of 1e-10 s is refused, not small)
        vals = np.where(additive, base + zp * np.where([n == "x_0" for n in names], 1e-3, 1.0),
                        np.where(absolute, np.where(offable & (zp < 1e-4 * hi[: len(names)]), 0.0, zp), base * zp))
        nz = dict(nz0)
        nz.update({k: nz0[k] * float(np.exp(v)) for k, v in zip(free, z[len(names):])})
        return p0.replace(**dict(zip(names, vals))), nz

    # the naive predictor's error per record and horizon: the scale of the gap's errors
    naive = {(id(r), hs): max(float(np.sqrt(np.mean((r.y[_lag(r, hs):] - r.y[: -_lag(r, hs)]) ** 2))), 1e-9)
             for r in records for hs in horizons_s}
    size = sum(len(r.y) // stride + 1 for r in records) * (len(horizons_s) + 1)

    def resid(z: np.ndarray) -> np.ndarray:
        evals[0] += 1
        try:
            p, nz = make(z)
            p.validate()
        except ValueError:
            return np.full(size, 1e3)
        parts = []
        jobs = [(r, hs) for r in records for hs in horizons_s]
        try:
            done = dict(zip(((id(r), hs) for r, hs in jobs), _predict_all(rig, jobs, p, stride=stride, noise=nz)))
        except ValueError:
            return np.full(size, 1e3)
        for r in records:
            for j, hs in enumerate(horizons_s):
                h = _lag(r, hs)
                o = done[(id(r), hs)]
                ok = _valid(len(r.y), h, r.ts) & np.isfinite(o["y_pred"])
                if parity is not None:
                    ok &= _block_parity(r) == parity
                sel = np.flatnonzero(ok)[: len(r.y) // stride + 1]
                ey = np.zeros(len(r.y) // stride + 1)
                e = (r.y[sel] - o["y_pred"][sel]) / naive[(id(r), hs)]
                ey[: len(e)] = np.nan_to_num(e, nan=10.0, posinf=10.0, neginf=-10.0) / np.sqrt(max(len(e), 1))
                parts.append(ey)
                if j == 0:  # the current, once, at the first horizon
                    ei = np.zeros_like(ey)
                    if r.current is not None:
                        e = (r.current[sel] - o["i_pred"][sel]) / max(float(np.std(r.current[ok])), 1e-9)
                        ei[: len(e)] = np.nan_to_num(e, nan=10.0, posinf=10.0, neginf=-10.0) / np.sqrt(max(len(e), 1))
                    parts.append(ei)
        if progress:
            progress(evals[0])
        return np.concatenate(parts) / np.sqrt(len(records))

    r0 = resid(z0)
    refresh = CAL_JAC_REFRESH if len(z0) > 2 else 1
    fun, jac = difference_jacobian(resid, lo, hi, 1e-3, map_fn=_map, unit_floor=True, refresh=refresh, scale=scale)
    sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), x_scale=scale, max_nfev=max_evaluations, ftol=CAL_FTOL,
                        xtol=CAL_XTOL)
    if refresh > 1:
        # the standard errors below need differences, not Broyden's update; and where Broyden's
        # Jacobian stopped short of the optimum (the Gauss-Newton step of the differences, within the
        # bounds, would still gain CAL_RESTART_GAIN of the cost), the fit goes on with differences at
        # every point
        sol.jac = jac.differences(sol.x)
        if gauss_newton_gain(sol.jac, sol.fun, sol.x, lo, hi) > CAL_RESTART_GAIN * sol.cost:
            fun, jac = difference_jacobian(resid, lo, hi, 1e-3, map_fn=_map, unit_floor=True)
            sol = least_squares(fun, sol.x, jac=jac, bounds=(lo, hi), x_scale=scale, max_nfev=max_evaluations,
                                ftol=CAL_FTOL, xtol=CAL_XTOL)
    p, nz = make(sol.x)
    # ±1σ of the parameters from the Jacobian at the solution (white, independent prediction errors
    # assumed: the errors of overlapping horizons are correlated, so this is a lower bound)
    dof = max(len(sol.fun) - len(sol.x), 1)
    try:
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * (2 * sol.cost / dof)
        sz = np.sqrt(np.clip(np.diag(cov), 0, None))[: len(names)]
    except np.linalg.LinAlgError:
        sz = np.full(len(names), np.nan)
    sigma = {n: float(sz[j] * (np.where(n == "x_0", 1e-3, 1.0) if additive[j] else (1.0 if absolute[j] else base[j])))
             for j, n in enumerate(names)}
    at_bound = [n for n, z, a, b in zip((*names, *free), sol.x, lo, hi)
                if min(z - a, b - z) < 1e-3 * (b - a) and not (n in names and absolute[names.index(n)] and z - a < 1e-9)]
    on_bound = [n for n in at_bound if n in names]
    return p, RigCalibration(names=list(names), values={n: float(getattr(p, n)) for n in names},
                             rig_values={n: float(v) for n, v in zip(names, base)}, noise=nz, sigma=sigma,
                             horizons_s=list(horizons_s), cost_before=float(0.5 * r0 @ r0), cost_after=float(sol.cost),
                             evaluations=evals[0], on_bounds=on_bound,
                             noise_on_bounds=[n for n in at_bound if n in NOISE])


def _predict_all(rig: Rig, jobs: Sequence[tuple[RigRecord, float]], params: PlantParams, *, stride: int = 1,
                 noise: dict[str, float] | None = None, starts=None) -> list[dict[str, np.ndarray]]:
    """:func:`predict` for every (segment, horizon) of ``jobs``: each segment's horizons in one pass
    (:func:`predict_many`), the segments on the machine's cores (:func:`_map`). ``params``: one
    parameter set, or a function of the segment (each segment's own model). ``starts``: a function of
    the segment giving its flags of :func:`predict_many` (None: every start)."""
    order: dict[int, tuple[RigRecord, list[float]]] = {}
    for r, hs in jobs:
        order.setdefault(id(r), (r, []))[1].append(hs)
    groups = list(order.values())
    of = params if callable(params) else (lambda r: params)
    done = _map(lambda g: predict_many(rig, g[0], of(g[0]), g[1], stride=stride, noise=noise,
                                       starts=starts(g[0]) if starts else None), groups)
    got = {(id(g[0]), hs): o for g, outs in zip(groups, done) for hs, o in zip(g[1], outs)}
    return [got[(id(r), hs)] for r, hs in jobs]


class _Batch:
    """One :func:`_map` call's items: claimed one at a time by the threads that run them."""

    __slots__ = ("fn", "items", "results", "errors", "next", "left")

    def __init__(self, fn, items: list) -> None:
        self.fn, self.items = fn, items
        self.results: list = [None] * len(items)
        self.errors: list = [None] * len(items)
        self.next = 0               # the first item not claimed yet
        self.left = len(items)      # items not finished yet


#: The batches of :func:`_map` with items not claimed yet, newest (the most deeply nested) last, the
#: lock and condition that guard them, and the pool's threads (started when first needed).
_pending: list[_Batch] = []
_pool = threading.Condition()
_pool_threads: list[threading.Thread] = []


def _claim(prefer: _Batch | None) -> tuple[_Batch, int]:
    """An item not claimed yet (with :data:`_pool` held, ``_pending`` not empty): of ``prefer`` while
    it has one, else of the newest batch (a nested map's items before its caller's next ones)."""
    b = prefer if prefer is not None and prefer.next < len(prefer.items) else _pending[-1]
    k = b.next
    b.next += 1
    if b.next == len(b.items):
        _pending.remove(b)
    return b, k


def _run_item(b: _Batch, k: int) -> None:
    try:
        b.results[k] = b.fn(b.items[k])
    except BaseException as e:  # noqa: BLE001 - raised again by the batch's caller, in order
        b.errors[k] = e
    with _pool:
        b.left -= 1
        if b.left == 0:
            _pool.notify_all()


def _pool_worker() -> None:
    while True:
        with _pool:
            while not _pending:
                _pool.wait()
            b, k = _claim(None)
        _run_item(b, k)


def _reset_pool_in_child() -> None:
    """A forked child has none of the pool's threads (nor its parent's batches)."""
    global _pool
    _pending.clear()
    _pool_threads.clear()
    _pool = threading.Condition()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_reset_pool_in_child)


def _map(fn, items: Sequence) -> list:
    """``[fn(x) for x in items]`` on the machine's cores (threads: the C filter releases the GIL),
    in order; the same results as the loop, in less wall time where a core is free. One pool of
    threads, one fewer than the cores, shares the work with the callers: a caller runs its own items
    as long as any is left, and while the last ones run elsewhere it helps with those of the other
    maps (the newest first). A map inside an item of another (a Jacobian's columns, each a replay of
    several segments) thus spreads its items over the cores too, never more threads busy than cores:
    the cores stay busy to the end of the outer map instead of waiting on its longest item."""
    items = list(items)
    cores = os.cpu_count() or 1
    if cores < 2 or len(items) < 2:
        return [fn(x) for x in items]
    mine = _Batch(fn, items)
    with _pool:
        while len(_pool_threads) < cores - 1:
            t = threading.Thread(target=_pool_worker, name=f"real_rig-map-{len(_pool_threads)}", daemon=True)
            t.start()
            _pool_threads.append(t)
        _pending.append(mine)
        _pool.notify_all()
    while True:
        with _pool:
            if mine.next >= len(mine.items):
                while mine.left > 0 and not _pending:
                    _pool.wait()
                if mine.left == 0:
                    break
            b, k = _claim(mine)
        _run_item(b, k)
    for e in mine.errors:
        if e is not None:
            raise e
    return mine.results


def _block_parity(r: RigRecord) -> np.ndarray:
    """0 for the samples of the even blocks of :data:`EFFECT_BLOCK_S`, 1 for the odd ones."""
    return (np.arange(len(r.y)) // max(1, int(round(EFFECT_BLOCK_S / r.ts)))) % 2


def _lag(r: RigRecord, horizon_s: float) -> int:
    return max(1, int(round(horizon_s / r.ts)))


# ----------------------------------------------------------------------------- effects on real records

#: Real-rig effects beside the catalogue (:data:`~.effects.CATALOGUE`): (name, parameter, where it acts,
#: start grid, bounds, description). The viscous damping ``k_FV`` is a baseline parameter of the CE152's
#: diagnosis (calibrated on every record, :data:`~.effects.BASELINE`), but a real rig's file identifies
#: none (the Inteco's authors' model has no damping term), so here it is an effect like the catalogue's.
RIG_EXTRAS = (
    ("damping", "k_FV", "mechanics", (0.02, 0.1, 0.3, 1.0, 3.0), (0.0, 10.0),
     "a viscous damping k_FV*v on the moving ball (air, eddy currents in the ball)"),
)
#: Catalogue entries that the real-rig search leaves out although they apply to the rig's drive, with
#: the reason (:func:`rig_offer` reports them beside the drive's exclusions).
RIG_LEFT_OUT = {
    # measured by scripts/bench_rig.py (three Inteco calibration records, 2026-11-26): offered, it took
    # round 2 from force_lag by 0.6 % of held-out gain (0.239 against 0.233, after coulomb_friction), and
    # the joint refit drove it to beta_F = 0.95, its bound, with T_F2 = 3.0 ms: one force lag under
    # another name (with T_F off the two are twins), at 41 s of the run's 136 s (load 6.4) for that refit
    "eddy_lag": "with the fast lag T_F off it is a twin of force_lag (on the Inteco records it took force_lag's "
                "place at beta_F = 0.95, its bound); a second lag beside T_F is fitted by the calibration when "
                "asked (SECOND_FORCE_LAG_FIT)",
    # measured by scripts/bench_rig.py the same day, eddy_lag left out: offered, it was selected in round 1
    # (held-out gain 0.52 against the damping's 0.18; F_c = 21.6 mN, 3.6 % of the weight, v_c = 1.0 mm/s,
    # then force_lag), but on the six validation records the closed-loop model's median skill fell from
    # +0.34/+0.58/+0.50 to +0.32/+0.57/+0.50 (5/20/50 ms) and the model driven by the PWM duty alone from
    # +0.21/+0.28/-0.06 to +0.15/+0.24/-0.19 (worst segment -2.15 against -0.90); the friction's short
    # substeps made the joint refit take 44 s instead of 9 s (run 130 s at load 5.1 against 57 s at 3.6)
    "coulomb_friction": "on the Inteco records it won the calibration records' held-out blocks but lowered the "
                        "validation records' skill, at five times the refit's time (docs/rigs.md); the located "
                        "correction's friction shape measures the friction instead",
    "periodic_disturbance": "its starts are the spectral peaks of a closed-loop replay's residual "
                            "(PeriodicDisturbance.starts, a CE152 Problem), which the real-rig search does not "
                            "compute yet; its amplitude, phase and frequency have no grid of their own",
}
#: Effects that trade against each other (a damping, a force lag and a delay all slow the loop's
#: response), fitted jointly when no single effect passes a round: the only pairs tried, as every pair of
#: the catalogue would cost a joint fit each (tens of replays of every record).
RIG_PAIRS = (("force_lag", "delay"), ("force_lag", "damping"), ("delay", "damping"))
#: Evaluations of the prediction cost a joint fit may spend (Nelder-Mead): a pair of :data:`RIG_PAIRS`,
#: and one effect of several coordinates (from the best point of its start grid, which placed it already:
#: fewer, as every such entry of the catalogue takes them in each round).
JOINT_MAXFEV = 30
EFFECT_MAXFEV = 20
#: The second force lag (the catalogue's ``eddy_lag``): a share ``beta_F`` of the force behind a slower lag
#: ``T_F2``, as eddy currents in a solid core give it beside the fast lag ``T_F`` (their time constants
#: spread; one lag is a compromise between the fast and the slow ones). When :data:`SECOND_FORCE_LAG_FIT`
#: says so, its two parameters are fitted by :func:`calibrate` (:func:`run`) within these bounds (name:
#: (lower, upper, start)); a share fitted to 0 leaves it off. The effect search leaves it out
#: (:data:`RIG_LEFT_OUT`).
SECOND_FORCE_LAG = {"beta_F": (0.0, 0.95, 0.3), "T_F2": (1e-3, 0.1, 0.01)}
#: How :func:`run` fits the second force lag: None (not at all: the model of before), "joint" (with the
#: force law, the selected effects and the disturbance model, in their refit) or "after" (after that
#: refit, with the disturbance model, the rest held). Off by default: on the shared Inteco records
#: neither raised the validation records' skill (docs/rigs.md, the lift-off error's candidates).
SECOND_FORCE_LAG_FIT: str | None = None
#: Held-out blocks [s]: the effect is fitted on the even blocks' predictions, judged on the odd ones.
EFFECT_BLOCK_S = 1.0
#: Relative reduction of the held-out prediction cost an effect must bring to be selected.
MIN_EFFECT_GAIN = 0.10
#: Relative reduction of the fit blocks' cost the best point of an effect's start grid must bring for the
#: effect to be fitted further (and judged on the held-out blocks): the others are reported off. The fit
#: from the grid's best point then changed the gain (held out, against the start's on the fit blocks) by
#: 0.8 to 5.3 times on scripts/bench_rig.py's calibration records (force_lag 0.219 -> 0.175 and 0.019 ->
#: 0.038, damping 0.079 -> 0.175, sensor_drift 0.014 -> 0.043, force_gain_drift 0.0058 -> 0.031): from
#: under a fifth of :data:`MIN_EFFECT_GAIN` no start has been seen to reach it, and the fits of those
#: starts were half of the search's time.
REFINE_MIN_GAIN = MIN_EFFECT_GAIN / 5


@dataclass(frozen=True)
class RigCandidate:
    """One effect the real-rig search tries: its coordinates with their ranges on this rig, its start
    grid (in those coordinates) and the parameter values a point stands for (computed ones included)."""

    name: str
    location: str
    description: str
    coords: tuple[Coord, ...]
    grid: tuple[tuple[float, ...], ...]
    to_values: Callable[[Sequence[float]], dict[str, float]]

    @property
    def names(self) -> tuple[str, ...]:
        """The fitted coordinates' names (FMU parameters on every entry the search offers)."""
        return tuple(c.name for c in self.coords)


def rig_offer(drive: str, law: str) -> dict[str, str | None]:
    """Every catalogue entry and real-rig extra (:data:`RIG_EXTRAS`) for a rig of coil ``drive`` and force
    ``law`` (:data:`~.effects.DRIVES`, :data:`~.effects.FORCE_LAWS`): None where the effect search offers
    it, else the reason it does not (the entry's own, :meth:`~.effects.Effect.applies`, or
    :data:`RIG_LEFT_OUT`)."""
    out: dict[str, str | None] = {}
    for name, eff in CATALOGUE.items():
        why = eff.applies(drive, law)
        if why:
            what = f"a {drive} drive" if drive not in eff.drives else f"the {law} force law"
            out[name] = f"not for {what}: {why}"
        else:
            out[name] = RIG_LEFT_OUT.get(name)
    out.update({e[0]: None for e in RIG_EXTRAS})
    return out


def _values_of(params: PlantParams) -> dict[str, float]:
    return {f.name: float(getattr(params, f.name)) for f in fields(params)}


def rig_candidates(rig: Rig, records: Sequence[RigRecord], params: PlantParams, skip: Sequence[str] = ()
                   ) -> list[RigCandidate]:
    """The effects the search offers on this rig (:func:`rig_offer` of its drive and its force law),
    but those with a parameter in ``skip`` (the calibration fits it already): each with its
    coordinates' ranges and start grid from the catalogue entry, on this rig's sensor scale and records
    (:meth:`~.effects.Effect.rig_coords`, :meth:`~.effects.Effect.rig_grid`), and the parameters it
    computes from the records (:meth:`~.effects.Effect.rig_values`: the force exponent's pivot at the
    records' mean position, the sensor's gain and offset that keep a bend's reading there, the force
    gain that a drift keeps at the records' middle); the real-rig extras (:data:`RIG_EXTRAS`) with
    theirs."""
    values = _values_of(params)
    x = np.concatenate([np.asarray(rig.to_x(r.position), float) for r in records]) if records \
        else np.array([values["x_start"]])
    duration = float(np.mean([len(r.y) * r.ts for r in records])) if records else 0.0
    offer = rig_offer(rig.drive, force_law(values))
    out = []
    for name, why in offer.items():
        if why is not None:
            continue
        if name in CATALOGUE:
            eff = CATALOGUE[name]
            coords = eff.rig_coords(values)
            cand = RigCandidate(name, eff.location, eff.description, coords,
                                tuple(tuple(z) for z in eff.rig_grid(values, x)),
                                lambda z, eff=eff: eff.rig_values(z, values, x, duration))
        else:
            _, param, location, grid, (lo, hi), description = next(e for e in RIG_EXTRAS if e[0] == name)
            cand = RigCandidate(name, location, description, (Coord(param, 0.1 * (hi - lo), lo, hi),),
                                tuple((g,) for g in grid), lambda z, param=param: {param: float(z[0])})
        if not set(cand.names) & set(skip):
            out.append(cand)
    return out


def refit_took_off(search: RigSearch, cal: RigCalibration, ranges: dict[str, tuple[float, float, float]]
                   ) -> list[str]:
    """The selected effects whose every parameter the joint refit (``cal``) ended at or within 1e-3 of
    its range from the low end of a range that starts at 0 (off: a lag, a damping): removed from
    ``search`` (its selection and values, ``search.taken_off``) and from ``cal.on_bounds``, so that the
    verdict neither reads them as a calibration that failed nor lists an effect at 0 as found.
    Returns their names."""
    faded = []
    for e in list(search.selected):
        names = [n for n in _effect_params(e) if n in search.parameters]
        if names and all(n in ranges and ranges[n][0] == 0.0
                         and cal.values[n] < 1e-3 * (ranges[n][1] - ranges[n][0]) for n in names):
            faded.append(e)
    for e in faded:
        search.selected.remove(e)
        for n in _effect_params(e):
            if n in search.parameters:
                search.taken_off[n] = search.parameters.pop(n)
                cal.on_bounds = [b for b in cal.on_bounds if b != n]
                cal.values[n] = 0.0
    return faded


def _effect_params(effect: str) -> tuple[str, ...]:
    """The parameters of a catalogue entry or of a real-rig extra (:data:`RIG_EXTRAS`)."""
    extra = {name: (param,) for name, param, *_ in RIG_EXTRAS}
    return extra[effect] if effect in extra else CATALOGUE[effect].params


def _effect_ranges(params: PlantParams) -> dict[str, tuple[float, float, float]]:
    """Every effect parameter the search may select, as :func:`calibrate` refits it: (lower bound, upper
    bound, start where it is off) from its catalogue coordinates on this rig's scale (the real-rig extras
    and :data:`SECOND_FORCE_LAG` from theirs). A parameter that is off at 0 below its search range (a lag,
    whose smallest values are refused rather than small) is refitted from 0, where the refit's rule turns
    it off; it starts at the middle of its start grid."""
    values = _values_of(params)
    table = param_table()
    out: dict[str, tuple[float, float, float]] = {}
    for eff in CATALOGUE.values():
        grid = np.array(eff.rig_grid(values, np.array([values["x_start"]])), float)
        for k, c in enumerate(eff.rig_coords(values)):
            if c.name in table:
                lo = 0.0 if _off_at_zero(c) else c.lo
                out[c.name] = (lo, c.hi, float(grid[len(grid) // 2, k]) if len(grid) else 0.5 * (c.lo + c.hi))
    out.update({p: (lo, hi, grid[len(grid) // 2]) for _, p, _, grid, (lo, hi), _ in RIG_EXTRAS})
    out.update(SECOND_FORCE_LAG)
    return out


def _off_at_zero(c: Coord) -> bool:
    """Whether a coordinate is off at 0 below its search range: a time constant whose C table allows 0
    (off) while its search starts above it (under 50 µs a force lag is invisible at 1 kHz)."""
    table = param_table()
    return c.name in table and table[c.name][3] == "s" and c.lo > 0 and table[c.name][1] <= 0.0


def prediction_cost(rig: Rig, records: Sequence[RigRecord], params: PlantParams, *,
                    horizons_s: Sequence[float] = CAL_HORIZONS_S, stride: int = 10, parity: int | None = None,
                    noise: dict[str, float] | None = None) -> dict[str, float]:
    """Mean squares of the prediction errors of the gap's reading (``"y"``: ``horizons_s`` ahead,
    each horizon's errors scaled by those of "stays put", as :func:`calibrate` weighs them, the
    horizons averaged) and of the current (``"i"``, where measured, at the first horizon, scaled
    by its spread), and their mean (``"total"``), over the predictions that end in the even
    (``parity=0``) or odd (1) blocks of :data:`EFFECT_BLOCK_S`, or all (None). ``stride``: a prediction
    from every ``stride``-th sample (10: twice as many as :func:`calibrate` takes; with 20 the held-out
    gain of the force lag on the Inteco MPC step record moved from 0.059 to 0.095, near the 0.10 that
    selects it)."""
    sums = {"y": [0.0, 0], "i": [0.0, 0]}
    jobs = [(r, hs) for r in records for hs in horizons_s]
    starts = None if parity is None else (lambda r: _parity_starts(r, horizons_s, parity))
    for (r, hs), o in zip(jobs, _predict_all(rig, jobs, params, stride=stride, noise=noise, starts=starts)):
        h = _lag(r, hs)
        ok = _valid(len(r.y), h, r.ts) & np.isfinite(o["y_pred"])
        if parity is not None:
            ok &= _block_parity(r) == parity
        if not ok.any():
            continue
        naive = max(float(np.sqrt(np.mean((r.y[h:] - r.y[:-h]) ** 2))), 1e-9)
        parts = {"y": (r.y[ok] - o["y_pred"][ok]) / naive / np.sqrt(len(horizons_s))}
        if r.current is not None and hs == horizons_s[0]:
            parts["i"] = (r.current[ok] - o["i_pred"][ok]) / max(float(np.std(r.current[ok])), 1e-9)
        for name, e in parts.items():
            sums[name][0] += float(np.sum(np.nan_to_num(e, nan=10.0, posinf=10.0, neginf=-10.0) ** 2))
            sums[name][1] += len(e) / (len(horizons_s) if name == "y" else 1)
    out = {name: s / n if n else float("nan") for name, (s, n) in sums.items()}
    used = [v for v in out.values() if np.isfinite(v)]
    out["total"] = float(np.mean(used)) if used else float("inf")
    return out


def _parity_starts(r: RigRecord, horizons_s: Sequence[float], parity: int) -> np.ndarray:
    """Flags of the samples whose prediction ends, at one of ``horizons_s`` at least, on a sample that
    :func:`prediction_cost` reads for ``parity``: the others' predictions would be made for nothing
    (the cost is the same; half of the replay's predictions are skipped)."""
    n = len(r.y)
    out = np.zeros(n, bool)
    par = _block_parity(r)
    for hs in horizons_s:
        h = _lag(r, hs)
        end = np.arange(h, n)
        out[: n - h] |= _valid(n, h, r.ts)[end] & (par[end] == parity)
    return out


def _cost_of(rig: Rig, records: Sequence[RigRecord], params: PlantParams, parity: int | None,
             noise: dict[str, float] | None):
    """The prediction cost (``total``) of ``params`` with some values changed: inf where the plant
    refuses them."""
    def cost(values: dict[str, float]) -> float:
        try:
            p = params.replace(**values)
            p.validate()
        except ValueError:
            return float("inf")
        return prediction_cost(rig, records, p, parity=parity, noise=noise)["total"]

    return cost


#: The cost :func:`_fit_one` gives a value the plant refuses (far above any replay's: its errors are capped
#: at 10 of their scales).
REFUSED_COST = 1e30


def _fit_one(rig: Rig, records: Sequence[RigRecord], params: PlantParams, cand: RigCandidate,
             parity: int | None, noise: dict[str, float] | None = None,
             grid_costs: Sequence[float] | None = None) -> tuple[tuple[float, ...], float]:
    """The value of a one-coordinate effect that minimises the prediction cost (its grid, then a
    bounded scalar search between the best grid point's neighbours), the other parameters held:
    (coordinates, cost). ``grid_costs``: the grid's costs when known already."""
    c = cand.coords[0]
    at = _cost_of(rig, records, params, parity, noise)

    def cost(v: float) -> float:
        # a value the plant refuses (a bend that turns the sensor's slope over) costs a finite amount:
        # the bounded search's parabolic steps subtract costs, and inf - inf is no step
        out = at(cand.to_values([float(v)]))
        return out if np.isfinite(out) else REFUSED_COST

    grid = [g[0] for g in cand.grid]
    costs = list(grid_costs) if grid_costs is not None else _map(cost, grid)
    j = int(np.argmin(costs))
    lo = grid[j - 1] if j > 0 else c.lo
    hi = grid[j + 1] if j + 1 < len(grid) else c.hi
    res = minimize_scalar(cost, bounds=(max(lo, c.lo), min(hi, c.hi)), method="bounded",
                          options={"xatol": 1e-3 * (hi - lo), "maxiter": 12})
    return ((float(res.x),), float(res.fun)) if res.fun < costs[j] else ((float(grid[j]),), float(costs[j]))


def _fit_joint(rig: Rig, records: Sequence[RigRecord], params: PlantParams, cands: Sequence[RigCandidate],
               start: Sequence[Sequence[float]], *, parity: int | None, noise: dict[str, float] | None,
               maxfev: int = JOINT_MAXFEV) -> tuple[list[tuple[float, ...]], float]:
    """The coordinates of one or several effects fitted together (Nelder-Mead on the prediction cost
    of :func:`_fit_one`, scipy's path evaluated side by side: :func:`~.neldermead.nelder_mead`, in coordinates scaled by each catalogue range, from ``start``, one point per
    effect, at most ``maxfev`` evaluations): (coordinates per effect, cost)."""
    coords = [c for cand in cands for c in cand.coords]
    lo = np.array([c.lo for c in coords])
    span = np.array([c.hi - c.lo for c in coords])
    zero = np.array([_off_at_zero(c) for c in coords])
    cuts = np.cumsum([0] + [len(cand.coords) for cand in cands])
    at = _cost_of(rig, records, params, parity, noise)

    def split(z: np.ndarray) -> list[tuple[float, ...]]:
        v = np.clip(lo + z * span, lo, lo + span)
        # an effect at the bottom of its range is off (a lag below its minimum is refused, not small)
        v = np.where(v <= lo + 1e-4 * span, np.where(zero, 0.0, lo), v)
        return [tuple(float(x) for x in v[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]

    def cost(z: np.ndarray) -> float:
        vals: dict[str, float] = {}
        for cand, zc in zip(cands, split(z)):
            vals.update(cand.to_values(zc))
        return at(vals)

    z0 = np.clip((np.concatenate([np.asarray(s, float) for s in start]) - lo) / span, 0.0, 1.0)
    simplex = [z0] + [z0 + 0.05 * np.eye(len(z0))[k] for k in range(len(z0))]
    # scipy's Nelder-Mead path, with the points a step may need replayed side by side on the cores
    res = nelder_mead(cost, simplex, maxfev=maxfev, xatol=1e-3, fatol=1e-4, map_fn=_map)
    return split(res.x), float(res.fun)


def _gains(held: dict[str, float], base: dict[str, float]) -> tuple[float, dict[str, float]]:
    """The held-out gain per signal, and the one that counts: the better signal's, unless the other's
    cost rises by more than 1 % (then the worse one's)."""
    gains = {k: float(1 - held[k] / base[k]) for k in base if np.isfinite(base[k]) and base[k] > 0}
    worst = min(gains.values())
    return (max(gains.get("y", -np.inf), gains.get("i", -np.inf)) if worst > -0.01 else worst), gains


def effect_search(rig: Rig, records: Sequence[RigRecord], params: PlantParams, say=lambda s: None, *,
                  max_effects: int = 2, noise: dict[str, float] | None = None, skip: Sequence[str] = (),
                  refit_follows: bool = False) -> RigSearch:
    """The catalogue's effects that the rig's drive and force law can take (:func:`rig_candidates`: every
    entry of :data:`~.effects.CATALOGUE` that applies, and the real-rig extras) tried on its calibrated
    model, in greedy rounds: each effect not yet selected is fitted on the even held-out blocks and
    judged on the odd ones by the prediction cost (:func:`prediction_cost`: the gap 5, 20 and 50 ms ahead,
    the current 5 ms ahead) of the gap and of the current, each on its own (a mechanical effect shows
    in the gap, an actuator effect in the current, and either is diluted in their sum).

    Every effect's start grid is costed first (all of them side by side); an effect none of whose starts
    lowers the even blocks' cost by :data:`REFINE_MIN_GAIN` is reported off (its values those of the
    model, its held-out gains 0, ``start_fit_gain`` its best start's gain) without further search.
    The others are fitted from their best start (one coordinate: a bounded scalar search between the
    grid's neighbours; several: Nelder-Mead, :func:`_fit_joint`). The best one that lowers one signal's
    held-out cost by :data:`MIN_EFFECT_GAIN` without raising the other's by more than 1 % is selected,
    refitted on every block, and kept for the next round; at most ``max_effects``. When none passes,
    the pairs of :data:`RIG_PAIRS` are fitted jointly and judged the same way.

    A :class:`~.rig_result.RigSearch`: ``offered`` (every catalogue entry and extra: None where offered, else
    why not, by the rig's drive and force law), ``skipped`` (offered, but a parameter is fitted by the calibration),
    ``candidates`` (:class:`~.rig_result.EffectTrial`: round, effect, parameter(s), ``values``, location,
    held-out gain per signal),
    ``selected``, ``parameters`` (the selected effects' fitted values), ``computed`` (the values they
    computed from the records: the force exponent's pivot) and ``held_out_cost`` of the model without
    an effect. ``noise``: the filter's disturbance model (default :func:`noise_defaults`); ``skip``:
    parameters the calibration fits already (their effects are not tried again). ``refit_follows``: the
    caller refits the selected effects on every block with the rest (:func:`calibrate`), so the last
    round's selection keeps its values from the even blocks (its fit on every block would only be that
    refit's starting point: a Nelder-Mead of 30-40 replays, one or two at a time)."""
    cands = rig_candidates(rig, records, params, skip)
    offered = rig_offer(rig.drive, force_law(_values_of(params)))
    out = RigSearch(held_out_cost=prediction_cost(rig, records, params, parity=1, noise=noise), block_s=EFFECT_BLOCK_S,
                    min_gain=MIN_EFFECT_GAIN, offered=offered,
                    skipped=[n for n, why in offered.items() if why is None and n not in {c.name for c in cands}])
    current = params
    by_name = {c.name: c for c in cands}

    def record(rnd: int, members: Sequence[RigCandidate], z: Sequence[Sequence[float]], held: dict[str, float] | None,
               base: dict[str, float], screened: bool = False) -> EffectTrial:
        vals: dict[str, float] = {}
        for cand, zc in zip(members, z):
            vals.update(cand.to_values(zc))
        gain, gains = (0.0, {k: 0.0 for k in base if np.isfinite(base[k]) and base[k] > 0}) if held is None \
            else _gains(held, base)
        names = [n for cand in members for n in cand.names]
        locs = list(dict.fromkeys(cand.location for cand in members))
        return EffectTrial(round=rnd, effect="+".join(c.name for c in members), parameter=", ".join(names),
                           value=vals[names[0]], values=vals, location="+".join(locs), held_out_gain=float(gain),
                           held_out_gains=gains, effects=[c.name for c in members] if len(members) > 1 else None,
                           screened=(f"no start lowered the fit blocks' cost by {100 * REFINE_MIN_GAIN:g} %: "
                                     "reported off, not fitted further") if screened else None)

    for rnd in range(1, max_effects + 1):
        base = prediction_cost(rig, records, current, parity=1, noise=noise)
        fit_base = prediction_cost(rig, records, current, parity=0, noise=noise)["total"]
        todo = [c for c in cands if c.name not in out.selected]
        if not todo:
            break
        tries = ", ".join(f"{c.name} ({', '.join(c.names)})" for c in todo)
        say(f"round {rnd}: trying {tries} on the held-out blocks")
        at = _cost_of(rig, records, current, 0, noise)
        points = [(c, z) for c in todo for z in c.grid]
        flat = _map(lambda cz: at(cz[0].to_values(cz[1])), points)
        grid_costs = {c.name: [v for (cc, _), v in zip(points, flat) if cc is c] for c in todo}

        def candidate(c: RigCandidate) -> EffectTrial:
            costs = grid_costs[c.name]
            start_gain = float(1 - min(costs) / fit_base) if fit_base > 0 else 0.0
            if not start_gain >= REFINE_MIN_GAIN:
                off = tuple(float(getattr(current, n)) for n in c.names)
                trial = record(rnd, [c], [off], None, base, screened=True)
                trial.start_fit_gain = start_gain
                return trial
            if len(c.coords) == 1:
                z, _ = _fit_one(rig, records, current, c, parity=0, noise=noise, grid_costs=costs)
            else:
                (z,), _ = _fit_joint(rig, records, current, [c], [c.grid[int(np.argmin(costs))]], parity=0, noise=noise,
                                     maxfev=EFFECT_MAXFEV)
            held = prediction_cost(rig, records, current.replace(**c.to_values(z)), parity=1, noise=noise)
            trial = record(rnd, [c], [z], held, base)
            trial.start_fit_gain = start_gain
            return trial

        tried = _map(candidate, todo)
        out.candidates += tried
        best = max(tried, key=lambda c: c.held_out_gain, default=None)
        last = refit_follows and rnd == max_effects
        if best and best.held_out_gain >= MIN_EFFECT_GAIN:
            c = by_name[best.effect]
            if last:
                z = tuple(best.values[n] for n in c.names)
            elif len(c.coords) == 1:
                z, _ = _fit_one(rig, records, current, c, parity=None, noise=noise)
            else:
                (z,), _ = _fit_joint(rig, records, current, [c], [[best.values[n] for n in c.names]],
                                     parity=None, noise=noise, maxfev=EFFECT_MAXFEV)
            vals = c.to_values(z)
            current = current.replace(**vals)
            out.selected.append(c.name)
            out.parameters.update({n: vals[n] for n in c.names})
            out.computed.update({n: v for n, v in vals.items() if n not in c.names})
            continue
        # no effect alone: two that act together (a damping and a force lag trade against each
        # other) are fitted jointly on the even blocks and judged on the odd ones, as one candidate
        fitted_at = {t.effect: [t.values[n] for n in by_name[t.effect].names] for t in tried
                     if t.screened is None}
        pairs = []
        for na, nb in RIG_PAIRS:
            if na not in by_name or nb not in by_name or {na, nb} & set(out.selected):
                continue
            say(f"round {rnd}: trying {na} and {nb} together on the held-out blocks")
            members = [by_name[na], by_name[nb]]
            start = [fitted_at.get(m.name, m.grid[len(m.grid) // 2]) for m in members]
            z, _ = _fit_joint(rig, records, current, members, start, parity=0, noise=noise)
            vals = {k: v for m, zc in zip(members, z) for k, v in m.to_values(zc).items()}
            held = prediction_cost(rig, records, current.replace(**vals), parity=1, noise=noise)
            pairs.append(record(rnd, members, z, held, base))
        out.candidates += pairs
        best = max(pairs, key=lambda c: c.held_out_gain, default=None)
        if not best or best.held_out_gain < MIN_EFFECT_GAIN:
            out.last_round_empty = True
            break
        members = [by_name[n] for n in best.effects]
        z = [[best.values[n] for n in m.names] for m in members]
        if not last:
            z, _ = _fit_joint(rig, records, current, members, z, parity=None, noise=noise)
        for m, zc in zip(members, z):
            vals = m.to_values(zc)
            current = current.replace(**vals)
            out.parameters.update({n: vals[n] for n in m.names})
            out.computed.update({n: v for n, v in vals.items() if n not in m.names})
        out.selected += best.effects
    return out


# ----------------------------------------------------------------------------- located correction

#: The located correction at the mechanics (``MaglevCorrection``, ``c/maglev_replay.h``): a force on
#: the ball that is a function of position and velocity, ``Σ c[j,l]·P_j(ξ)·b_l(v)`` with ``P_j`` the
#: first :data:`CORRECTION_NX` Legendre polynomials of the standardised position ``ξ`` and
#: ``b = (1, v/v_s, tanh(v/v_c))``: a static force (a force law's error along the gap), a viscous force
#: (eddy currents, air) and a friction (Coulomb, smoothed), each varying with the gap. It is part of
#: the physics model (the filter and its predictions carry it like the random force) and is used
#: only where the catalogue explains too little (:func:`correction_search`).
CORRECTION_NX = 2
#: The shapes of the velocity basis, in the order of each position term's three coefficients.
CORRECTION_SHAPES = ("static", "viscous", "friction")
#: Ridge weights tried for the correction's coefficients (on the coefficients in units of
#: :data:`CORRECTION_SCALE` of the weight, relative to the prediction cost without a correction);
#: the one with the lowest held-out cost is used.
CORRECTION_RIDGE = (1e-2, 1e-1)
#: The coefficients' scale in the ridge penalty, as a fraction of the ball's weight.
CORRECTION_SCALE = 0.02
#: The forward-difference step of the correction's Jacobian, in units of that scale (1 ‰ of the weight).
CORRECTION_STEP = 0.05


def correction_basis(rig: Rig, records: Sequence[RigRecord], n_x: int = CORRECTION_NX) -> dict:
    """The correction's basis for these segments (no coefficients yet): the position's centre
    ``x_c`` (median) and half width ``x_s`` (half its 1-99 % span) in the plant's x, the velocity's
    scale ``v_s`` (its RMS) and the friction's smoothing ``v_c`` (the median speed): velocities from
    the position smoothed over 10 ms."""
    xs, vs = [], []
    for r in records:
        x = np.asarray(rig.to_x(r.position), float)
        k = max(1, int(round(0.010 / r.ts)))
        sm = np.convolve(x, np.ones(k) / k, "same")
        v = np.gradient(sm, r.ts)[k:-k]
        xs.append(x)
        vs.append(v)
    x, v = np.concatenate(xs), np.concatenate(vs)
    lo, hi = np.percentile(x, [1, 99])
    x_c, x_s = float(np.median(x)), float(max((hi - lo) / 2, 1e-4))
    xi = np.clip((x - x_c) / x_s, -1.5, 1.5)
    # the position terms' mean over the records' positions: the summary's weights (the positions
    # are often two or three levels of a reference, and their centre is where the ball seldom is)
    p_mean = [float(np.mean(np.polynomial.legendre.legval(xi, [0.0] * j + [1.0]))) for j in range(n_x)]
    return {"n_x": int(n_x), "x_c": x_c, "x_s": x_s,
            "v_s": float(max(np.sqrt(np.mean(v ** 2)), 1e-4)), "v_c": float(max(np.median(np.abs(v)), 1e-4)),
            "p_mean": p_mean, "coef": [0.0] * (3 * n_x)}


def correction_force(corr: dict, x: np.ndarray, v: np.ndarray, terms: Sequence[str] = CORRECTION_SHAPES) -> np.ndarray:
    """The correction's force [N] (along the plant's x) at positions ``x`` [m] and velocities ``v``
    [m/s], the same formula as ``maglev_correction_force`` (C); ``terms``: only these shapes."""
    x, v = np.broadcast_arrays(np.asarray(x, float), np.asarray(v, float))
    xi = np.clip((x - corr["x_c"]) / corr["x_s"], -1.5, 1.5)
    b = {"static": np.ones_like(v), "viscous": v / corr["v_s"], "friction": np.tanh(v / corr["v_c"])}
    out = np.zeros_like(x)
    for j in range(corr["n_x"]):
        pj = np.polynomial.legendre.legval(xi, [0.0] * j + [1.0])
        for l, shape in enumerate(CORRECTION_SHAPES):
            if shape in terms:
                out = out + corr["coef"][3 * j + l] * pj * b[shape]
    return out


def _errors(rig: Rig, records: Sequence[RigRecord], params: PlantParams, noise: dict, *,
            horizons_s: Sequence[float] = CAL_HORIZONS_S, stride: int = 20,
            own: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The gap's prediction errors ``horizons_s`` ahead as :func:`calibrate` weighs them (each
    horizon's scaled by "stays put"'s, each segment's by the root of its count), over a fixed set of
    predictions, and the parity of the block each ends in: (errors, parity). ``own``: each
    segment's own parameters by ``id`` (:func:`_own_coil`), where given."""
    jobs = [(r, hs) for r in records for hs in horizons_s]
    own = own or {}
    outs = _predict_all(rig, jobs, lambda r: own.get(id(r), params), stride=stride, noise=noise)
    errs, par = [], []
    for (r, hs), o in zip(jobs, outs):
        h = _lag(r, hs)
        k = np.arange(len(r.y))
        sel = np.flatnonzero(_valid(len(r.y), h, r.ts) & ((k - h) % stride == 0))
        naive = max(float(np.sqrt(np.mean((r.y[h:] - r.y[:-h]) ** 2))), 1e-9)
        e = (r.y[sel] - o["y_pred"][sel]) / naive
        errs.append(np.nan_to_num(e, nan=10.0, posinf=10.0, neginf=-10.0) / np.sqrt(max(len(sel), 1)))
        par.append(_block_parity(r)[sel])
    scale = 1.0 / np.sqrt(len(records) * len(horizons_s))
    return np.concatenate(errs) * scale, np.concatenate(par)


def _with_coef(noise: dict, corr: dict, coef: np.ndarray) -> dict:
    return {**noise, "correction": {**corr, "coef": [float(c) for c in coef]}}


def correction_search(rig: Rig, records: Sequence[RigRecord], params: PlantParams, noise: dict, say=lambda s: None, *,
                      n_x: int = CORRECTION_NX, stride: int = 20, ridge: Sequence[float] = CORRECTION_RIDGE,
                      min_gain: float | None = None, max_nfev: int = 3, own: dict | None = None) -> RigCorrection:
    """The located correction at the mechanics, fitted by the prediction cost of the calibration
    (the gap 5, 20 and 50 ms ahead, :func:`_errors`) and selected like an effect: its coefficients are
    fitted on the predictions that end in the even blocks (a ridge regression on the errors' Jacobian
    through the filter and the unstable plant, taken once at zero: the correction is a force linear
    in its coefficients), for each ridge weight of ``ridge``, and judged on the odd ones by replays. The ridge weight with the lowest held-out
    cost is kept; the correction is selected when its held-out cost change reaches ``min_gain``
    (default :data:`MIN_EFFECT_GAIN`), and refitted on every block (also when not selected: its
    shape is reported either way) by Gauss-Newton steps, at most ``max_nfev``, each with its own
    Jacobian. Each velocity shape alone (static + viscous, static + friction,
    the same at every gap) is fitted and judged the same way, to tell which one carries the
    correction. A :class:`~.rig_result.RigCorrection`: ``basis``, ``coef`` and ``sigma`` [N] (±1σ from the Jacobian, a lower
    bound: overlapping horizons' errors are correlated), ``ridge``, ``held_out`` (cost per ridge
    weight and per shape), ``held_out_gain`` (> 0: better), ``selected``, ``summary``
    (:func:`correction_summary`), and the correction ready for the model in ``correction`` (None when
    not selected). ``own``: each segment's own parameters by ``id`` (its coil and force gain,
    :func:`_own_coil`), as its figures use them."""
    min_gain = MIN_EFFECT_GAIN if min_gain is None else min_gain
    weight = params.m_k * params.g
    corr = correction_basis(rig, records, n_x)
    npar = 3 * n_x
    unit = CORRECTION_SCALE * weight    # the coefficients' scale [N]
    evals = [0]

    def errors(coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        evals[0] += 1
        return _errors(rig, records, params, _with_coef(noise, corr, coef), stride=stride, own=own)

    def jacobian(z0: np.ndarray, e0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The errors at ``z0`` (given, or one replay) and their Jacobian by forward differences
        (``npar`` replays): the correction is a force linear in its coefficients, so the errors are
        nearly linear in them and one Jacobian serves every fit below."""
        e0 = errors(z0 * unit)[0] if e0 is None else e0
        def column(k: int) -> np.ndarray:
            z = z0.copy()
            z[k] += CORRECTION_STEP
            return (errors(z * unit)[0] - e0) / CORRECTION_STEP

        return e0, np.stack(_map(column, range(npar)), axis=1)

    def fit(lin: tuple[np.ndarray, np.ndarray, np.ndarray], rows: np.ndarray, cols: Sequence[int], lam: float
            ) -> np.ndarray:
        """Coefficients (in units of the scale) that minimise the errors on ``rows`` plus the ridge
        penalty ``lam·|z|²``, only ``cols`` free: the Gauss-Newton step of the linearisation
        ``lin = (e0, J, z0)`` (errors ``e0 + J·(z − z0)``), a ridge regression."""
        e0, J, z0 = lin
        cols = list(cols)
        A, b = J[np.ix_(rows, cols)], e0[rows] - J[rows] @ z0
        z = np.zeros(npar)
        z[cols] = np.linalg.solve(A.T @ A + lam * np.eye(len(cols)), -A.T @ b)
        return z

    say(f"located correction at the mechanics: fitting {npar} coefficients ({n_x} position terms x static, "
        "viscous, friction) on the held-out blocks")
    e0, par = errors(np.zeros(npar))
    cost0 = {p: float(np.sum(e0[par == p] ** 2)) for p in (0, 1)}
    even = par == 0
    everything = list(range(npar))
    e0, J0 = jacobian(np.zeros(npar), e0)
    lin0 = (e0, J0, np.zeros(npar))

    def held(z: np.ndarray) -> float:
        e, p = errors(z * unit)
        return float(np.sum(e[p == 1] ** 2))

    per_ridge = {}
    for lam in ridge:
        z = fit(lin0, even, everything, lam * cost0[0])
        per_ridge[lam] = (held(z), z)
    lam = min(per_ridge, key=lambda k: per_ridge[k][0])
    best_cost, z_even = per_ridge[lam]
    # the velocity shapes alone (the first position term only: the same at every gap), each with
    # the static part: which one carries the correction
    shapes = {"static+viscous": (0, 1), "static+friction": (0, 2)}
    by_shape = {"all": best_cost}
    for name, cols in shapes.items():
        by_shape[name] = held(fit(lin0, even, cols, lam * cost0[0]))
    gain = 1.0 - best_cost / cost0[1] if cost0[1] > 0 else 0.0
    # refit on every block from the even blocks' solution (also when not selected: its shape is
    # reported either way)
    allrows = np.ones(len(e0), bool)
    cost_all = float(np.sum(e0 ** 2))
    lin = lin0
    for _ in range(max_nfev):     # Gauss-Newton on every block, the Jacobian taken again at each step
        z = fit(lin, allrows, everything, lam * cost_all)
        e_z, J_z = jacobian(z)
        step = np.max(np.abs(z - lin[2]))
        lin = (e_z, J_z, z)
        if step < 0.05 * max(float(np.max(np.abs(z))), 1.0):
            break
    e, Jz = lin[0], lin[1]
    dof = max(len(e) - npar, 1)
    A = Jz.T @ Jz
    Hinv = np.linalg.pinv(A + lam * cost_all * np.eye(npar))
    cov = Hinv @ A @ Hinv * (float(e @ e) / dof)
    coef = [float(c) for c in z * unit]
    selected = bool(gain >= min_gain)
    out = RigCorrection(basis={k: corr[k] for k in ("n_x", "x_c", "x_s", "v_s", "v_c", "p_mean")},
                        shapes=list(CORRECTION_SHAPES), ridge=float(lam), held_out_cost_without=cost0[1],
                        held_out={"by_ridge": {f"{k:g}": float(v[0]) for k, v in per_ridge.items()},
                                  "by_shape": {k: float(v) for k, v in by_shape.items()}},
                        held_out_gain=float(gain),
                        held_out_gain_by_shape={k: float(1 - v / cost0[1]) for k, v in by_shape.items()},
                        min_gain=float(min_gain), selected=selected,
                        correction={**corr, "coef": coef} if selected else None, coef=coef,
                        sigma=[float(s) for s in np.sqrt(np.clip(np.diag(cov), 0, None)) * unit],
                        cost_before=cost_all, cost_after=float(e @ e), evaluations=evals[0])
    out.summary = correction_summary(rig, out, params)
    return out


def correction_reason(co: RigCorrection) -> str:
    """The reasons' sentence on the located correction: used or not, and what its shape says."""
    s = co.summary
    head = (f"the located correction at the mechanics (a force of gap and velocity) {'is used' if co.selected else 'is not used'}: "
            f"held-out cost change {-100 * co.held_out_gain:+.1f} % (at most −{100 * co.min_gain:.0f} % needed)")
    return head + "; " + s.get("answer", "") + " (correction.png)"


def correction_plot(rig: Rig, co: RigCorrection, params: PlantParams, path: Path) -> Path:
    """correction.png: the fitted correction force [% of the weight] against the velocity at three
    gaps (the positions' 10th, 50th and 90th percentile of the basis span), and against the gap at
    three velocities, with the catalogue's damping beside it (the velocity force in all), in the
    record's convention (gap growing downward: a force opposing a downward motion is upward)."""
    b = co.basis
    corr = {**b, "coef": co.coef}
    w = params.m_k * params.g
    sign = -1.0 if rig.convention == "gap" else 1.0    # record coordinate = sign * x
    v = np.linspace(-3 * b["v_s"], 3 * b["v_s"], 241)
    fig, ax = _figure((11, 4.5), 1, 2)
    for j, xi in enumerate((-0.8, 0.0, 0.8)):
        x = b["x_c"] + xi * b["x_s"]
        pos = 1e3 * float(rig.from_x(np.array([x]))[0])
        f = correction_force(corr, x, v)
        # in the record's convention: velocity and force both flip with the axis
        ax[0].plot(sign * v * 1e3, sign * 100 * f / w, color=f"C{j}", lw=1.4, label=f"correction, {rig.convention} {pos:.2f} mm")
        ax[0].plot(sign * v * 1e3, sign * 100 * (f - params.k_FV * v) / w, color=f"C{j}", lw=0.9, ls="--",
                   label=f"with the catalogue's damping {params.k_FV:.3g} N·s/m")
    ax[0].axhline(0, color="0.6", lw=0.7)
    ax[0].axvline(0, color="0.6", lw=0.7)
    ax[0].set_xlabel(f"velocity of the {rig.convention} [mm/s]")
    ax[0].set_ylabel(f"force along the {rig.convention} [% of the weight]")
    ax[0].set_title("against the velocity", fontsize=10)
    ax[0].legend(fontsize=7)
    x = np.linspace(b["x_c"] - 1.2 * b["x_s"], b["x_c"] + 1.2 * b["x_s"], 121)
    pos = 1e3 * np.asarray(rig.from_x(x))
    for j, vv in enumerate((-b["v_s"], 0.0, b["v_s"])):
        f = correction_force(corr, x, np.full_like(x, vv))
        ax[1].plot(pos, sign * 100 * f / w, color=f"C{j + 3}", lw=1.4,
                   label=f"{rig.convention} velocity {sign * vv * 1e3:+.1f} mm/s")
    ax[1].axhline(0, color="0.6", lw=0.7)
    ax[1].axvspan(*sorted(1e3 * np.asarray(rig.from_x(np.array([b["x_c"] - b["x_s"], b["x_c"] + b["x_s"]])))),
                  color="C0", alpha=0.07)
    ax[1].set_xlabel(f"{rig.convention} [mm] (shaded: 1-99 % of the calibration positions)")
    ax[1].set_ylabel(f"force along the {rig.convention} [% of the weight]")
    ax[1].set_title("against the gap", fontsize=10)
    ax[1].legend(fontsize=7)
    fig.suptitle(f"located correction at the mechanics ({'used' if co.selected else 'not used'}: held-out cost change "
                 f"{-100 * co.held_out_gain:+.1f} %)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def correction_summary(rig: Rig, res: RigCorrection, params: PlantParams) -> dict:
    """What the fitted correction says, in the record's convention and the catalogue's terms,
    averaged over the records' positions: a static force [% of the weight], a viscous constant [N·s/m] and a
    friction force [N] (positive: opposing the motion), each with ±1σ, and how much of the held-out
    cost each velocity shape alone removes (the answer to "what is the damping")."""
    b, coef, sig = res.basis, np.asarray(res.coef), np.asarray(res.sigma)
    # averaged over the records' positions (the centre of the basis may lie between two levels)
    p_at0 = np.asarray(b["p_mean"])
    w = params.m_k * params.g

    def at_centre(l: int) -> tuple[float, float]:
        c = coef[l::3] @ p_at0
        s = float(np.sqrt(np.sum((sig[l::3] * p_at0) ** 2)))
        return float(c), s

    (c0, s0), (c1, s1), (c2, s2) = at_centre(0), at_centre(1), at_centre(2)
    # the plant's x grows upward; a force opposing the motion is -k·v
    out = {"static_pct_weight": 100 * c0 / w, "static_sigma_pct_weight": 100 * s0 / w,
           "viscous_N_s_per_m": -c1 / b["v_s"], "viscous_sigma": s1 / b["v_s"],
           "friction_N": -c2, "friction_sigma": s2, "weight_N": w, "k_FV": float(params.k_FV),
           "held_out_gain_by_shape": res.held_out_gain_by_shape}
    out["answer"] = damping_answer(out)
    return out


def damping_answer(s: dict) -> str:
    """What the velocity force of the mechanics is, from the correction's shapes alone (held-out
    cost change of the viscous and the friction parts, each with the static part) and its values
    averaged over the records' gaps (the catalogue's damping ``k_FV`` included)."""
    g = s["held_out_gain_by_shape"]
    visc = s["k_FV"] + s["viscous_N_s_per_m"]
    fr, fr_sd = s["friction_N"], s["friction_sigma"]
    gv, gf = g.get("static+viscous", g.get("viscous", 0.0)), g.get("static+friction", g.get("friction", 0.0))
    text = (f"velocity force in all, averaged over the records' gaps: {visc:.3g} N·s/m viscous (the catalogue's {s['k_FV']:.3g} plus "
            f"{s['viscous_N_s_per_m']:+.3g} ± {s['viscous_sigma']:.2g} from the correction) and a friction of "
            f"{1e3 * fr:+.3g} ± {1e3 * fr_sd:.2g} mN ({100 * fr / s['weight_N']:+.2f} % of the weight); held out, the "
            f"viscous shape alone changes the cost by {-100 * gv:+.1f} %, the friction shape alone by {-100 * gf:+.1f} %")
    if fr > 3 * fr_sd and gf >= MIN_EFFECT_GAIN and gf > gv + 0.02:
        text += (": the damping is mostly a friction (a force opposing the motion whose size barely grows with "
                 "the speed), not a force proportional to the velocity (eddy currents)")
    elif visc > 0 and gv >= MIN_EFFECT_GAIN and gv > gf + 0.02:
        text += ": the damping is mostly viscous (a force proportional to the velocity, as eddy currents give)"
    elif max(gv, gf) >= MIN_EFFECT_GAIN:
        text += ": the two shapes do about as well alone; the records do not tell them apart"
    else:
        text += (f": neither shape alone lowers the held-out cost by {100 * MIN_EFFECT_GAIN:.0f} %, so the records do "
                 "not tell what the velocity force is")
    return text


# ----------------------------------------------------------------------------- frequency response

def current_to_position(rig: Rig, r: RigRecord, params: PlantParams, *, seconds_per_segment: float = 2.0) -> dict:
    """The measured frequency response from coil current to position (Welch cross-spectra,
    ``G = P_iz / P_ii``, with the coherence) beside the model's, linearised at the segment's mean
    position: ``m·s²·x = dF/dx·x + dF/di·i`` (Eq. 16, 17), in the record's convention. In closed loop
    the estimate is biased where the coherence is low; the JSON gives both on 1–20 Hz."""
    if r.current is None:
        return {}
    from scipy import signal

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
    """Why a segment carries too little information to calibrate a model on (empty: enough)."""
    why = []
    if r.estimate:
        # the Inteco step/PID records: their "gap" lags the ball by the filter's dynamics, and a model
        # calibrated on it takes those for the ball's (calibrated on the four step records, validated on
        # the five stairs records, the two PID records in: the 50 ms skill +0.37 against the black box's
        # +0.44 and a damping on its bound; without them +0.47 against +0.44)
        why.append("the gap is the record's state estimate, logged in place of the sensor's reading: its "
                   "dynamics are the estimator's as well as the ball's, so the segment is judged, not calibrated on")
    if r.ts > 0.005:
        why.append(f"sampled every {r.ts * 1e3:g} ms: the 5 ms prediction is under one sample and the ball's "
                   "open-loop time constant (tens of ms) spans only a few samples")
    if rig.resolution:
        h = max(1, int(round(0.02 / r.ts)))
        moves = np.abs(r.position[h:] - r.position[:-h])
        if np.median(moves) < 2 * rig.resolution:
            why.append(f"the position moves less than two quantisation steps (2 × {rig.resolution * 1e3:g} mm) in "
                       f"20 ms on most samples (median {np.median(moves) * 1e3:.3f} mm)")
    return why


def conclude(rig: Rig, figs: list[RigFigures], info: list[list[str]], cal: RigCalibration | None
             ) -> tuple[str, list[str]]:
    """The verdict over the segments (``"explained"``, ``"unexplained: actuator"``, ``"unexplained:
    mechanics"``, ``"calibration failed"``, ``"too little information"``) and the reasons."""
    reasons: list[str] = []
    if not figs:
        return "calibration failed", ["no levitation segment of at least 1 s: nothing to calibrate on"]
    if all(info):
        reasons += sorted({w for ws in info for w in ws})
        cur = [f.current["from_actuator"] for f in figs if f.current]
        if cur:
            reasons.append(f"for what it is worth, the rig file's coil model fits the current from the actuator "
                           f"signal at {np.median(cur):.1f} % (median over segments){_ceiling_note(figs)}")
        return "too little information", reasons
    if cal and cal.on_bounds:
        return "calibration failed", [f"calibrated {', '.join(cal.on_bounds)} ended on a bound"]
    cur = [f.current["from_actuator"] for f in figs if f.current]
    skill = [f.position["20 ms"].skill_vs_stays_put for f in figs
             if np.isfinite(f.position["20 ms"].skill_vs_stays_put)]
    if not skill:
        return "too little information", ["the gap never moves within a segment"]
    if cur and np.median(cur) < MIN_CURRENT_FIT:
        reasons.append(f"the coil current from the actuator signal fits only {np.median(cur):.1f} % "
                       f"(median over segments; at least {MIN_CURRENT_FIT:g} % expected){_ceiling_note(figs)}")
        return "unexplained: actuator", reasons
    if np.median(skill) < MIN_SKILL:
        reasons.append(f"the current path is explained ({np.median(cur):.1f} % fit) but the gap 20 ms ahead "
                       f"is predicted with skill {np.median(skill):+.2f} against 'stays put' (median; "
                       f"{MIN_SKILL:g} needed): what the model lacks acts on the force or the mechanics")
        return "unexplained: mechanics", reasons
    return "explained", [f"current fit {np.median(cur):.1f} %{_ceiling_note(figs)}, skill at 20 ms "
                         f"{np.median(skill):+.2f}"]


def _ceiling_note(figs: Sequence[RigFigures]) -> str:
    """How far the measured current's own noise lets its fit go (:func:`~.metrics.fit_ceiling`, median
    over the segments with a current; an estimate, which a model at the noise floor may pass by a few
    tenths), as a parenthesis for the reasons; empty without a current."""
    cur = [f.current for f in figs if f.current and np.isfinite(f.current.get("noise_ceiling", np.nan))]
    if not cur:
        return ""
    return (f" (the measured current's own noise, {1e3 * np.median([c['noise_A'] for c in cur]):.1f} mA RMS white, "
            f"limits it to about {np.median([c['noise_ceiling'] for c in cur]):.1f} %)")


def comparison(calibration: Sequence[RigFigures], validation: Sequence[RigFigures]) -> RigComparison:
    """Median skill against "stays put" of the model, the black-box baseline and "constant
    velocity", per horizon, over the calibration and the validation segments (:func:`figures`)."""
    out = RigComparison()
    for role, figs in (("calibration", calibration), ("validation", validation)):
        if not figs:
            continue
        rows = {}
        for h in figs[0].position:
            row = {}
            for who in HorizonSkill.WHO:
                v = [f.position[h].skill.get(who, np.nan) for f in figs]
                v = [x for x in v if np.isfinite(x)]
                row[who] = float(np.median(v)) if v else float("nan")
                row[f"{who}_worst"] = float(min(v)) if v else float("nan")
            rows[h] = HorizonSkill(**row)
        out.roles.append(Comparison(role, len(figs), rows))
    return out


def comparison_table(comp: RigComparison) -> list[str]:
    """The Markdown table of :func:`comparison`: one row per role and horizon, the median skill
    (worst in brackets) of the model in closed loop and driven by the actuator signal, the black
    boxes and "constant velocity"."""
    lines = ["| records | horizon | model (closed loop, identified controller) | model (driven by the actuator signal) "
             "| black box | black box, actuator up to the start | constant velocity |", "|---|---|---|---|---|---|---|"]
    for c in comp.roles:
        for h, v in c.horizons.items():
            lines.append(f"| {c.role} ({c.segments}) | {h} | " + " | ".join(
                f"{getattr(v, w):+.2f} ({getattr(v, w + '_worst'):+.2f})" for w in HorizonSkill.WHO) + " |")
    return lines


def judge_against_black_box(verdict: str, comp: RigComparison) -> tuple[str, list[str]]:
    """A model that predicts the gap worse than the black-box baseline (median skill, on the
    validation segments when there are any, else the calibration ones) at some horizon does not
    explain the record: ``explained`` becomes ``explained in part``, and the reasons say where."""
    role = "validation" if comp.get("validation") is not None else "calibration"
    figs = comp.get(role)
    if not figs:
        return verdict, []
    lost = [(h, v) for h, v in figs.horizons.items() if np.isfinite(v.black_box) and not v.model > v.black_box]
    unjudged = [h for h, v in figs.horizons.items() if not np.isfinite(v.black_box)]
    if not lost:
        if unjudged:    # no black box there (none fitted, or no sample it predicts): no claim either way
            return verdict, [f"no black-box baseline to compare with at {', '.join(unjudged)} on the {role} "
                             "segments (none was fitted, or it predicts none of their samples): the model is "
                             "judged there against \"stays put\" alone"]
        return verdict, [f"the model beats the black-box baseline at every horizon on the {role} segments"]
    why = ", ".join(f"{h}: model {v.model:+.2f} against black box {v.black_box:+.2f}" for h, v in lost)
    reasons = [f"the model predicts the gap worse than the black-box baseline fitted on the same calibration "
               f"segments at {', '.join(h for h, _ in lost)} (median skill over {figs.segments} {role} "
               f"segment(s): {why}). The model's figure is its closed-loop prediction with the controller "
               "identified from the record (docs/diagnosis.md, \"A controller nobody states\"): either the model lacks "
               "something that acts on the gap's dynamics (the force or the mechanics), or the controller is not "
               "the linear one the identification assumes (gain scheduling, saturation, a state estimator of "
               "higher order), so that its reaction after the start is read only in part"]
    return ("explained in part" if verdict in ("explained", "no effect") else verdict), reasons


#: A rig's force law that carries less or more of the ball's weight than this (median over the
#: levitating samples, at the measured gap and current) contradicts the record.
FORCE_BALANCE = (0.7, 1.4)
#: A declared controller that fits the recorded actuator signal (as a whole, or every loop of a
#: cascade fed the recorded intermediate signals) below this [%] is not the one that ran.
MIN_CONTROLLER_FIT = 50.0


def force_balance(rig: Rig, m: Measured, params: PlantParams | None = None) -> RigForceBalance | None:
    """How much of the ball's weight the rig's force law carries at the record's measured gap and
    current, over the samples where the ball is off both stops (1 mm clear): the 10th, 50th and
    90th percentiles of ``F/(m·g)``. A ball that levitates for seconds is held, on average, by its
    weight: a median far from 1 is a force constant (or a current or position scale) that
    contradicts the record. ``None`` without a measured current or levitating samples."""
    p = params or rig.params
    if m.current is None:
        return None
    x = rig.to_x(m.position)
    lev = (x > p.x_min + 1e-3) & (x < p.x_max - 1e-3)
    if lev.sum() < 10:
        return None
    step = max(1, int(lev.sum() // 2000))
    ratio = forces(p, x[lev][::step], np.clip(m.current[lev][::step], 0, None)) / (p.m_k * p.g)
    q10, q50, q90 = np.percentile(ratio, [10, 50, 90])
    out = RigForceBalance(p10=float(q10), median=float(q50), p90=float(q90), samples=int(lev.sum()),
                          consistent=bool(FORCE_BALANCE[0] <= q50 <= FORCE_BALANCE[1]),
                          current_scale_for_weight=float(1 / np.sqrt(q50)) if q50 > 0 else float("nan"))
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
            out.ohm = {"median_V_over_Ri": float(ohm), "samples": int(still.sum())}
    return out


def controller_check(rig: Rig, m: Measured, ctl) -> ControllerCheck:
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
    if m.reference is None or m.drive is None:
        raise ValueError(f"{m.path}: checking a declared controller needs the recorded reference and actuator signal")
    if needs_current(ctl) and m.current is None:
        raise ValueError(f"{m.path}: the declared controller reads the coil current, which the record lacks")
    y, w = np.asarray(rig.reading(m.position)), np.asarray(rig.reading(m.reference))
    u_meas = np.asarray(rig.input_to_mu(m.drive))
    x = float(rig.to_x(m.position[0]))
    starts = {"settled": ((x, 0.0, float(m.current[0]) if m.current is not None else 0.0), float(u_meas[0])),
              "rest": ((x, 0.0, 0.0), 0.0)}
    fits = {name: nrmse_fit(u_meas, fast_loop.control(ctl, w, y, m.current, hold, x0))
            for name, (x0, hold) in starts.items()}
    start = max(fits, key=lambda k: fits[k] if np.isfinite(fits[k]) else -np.inf)
    out = ControllerCheck(actuator_fit=fits[start], start=start, fits_by_start=fits)
    r_meas = m.extra.get("current_reference")
    if isinstance(ctl, Cascade) and r_meas is not None:
        r = fast_loop.control(ctl.outer, w, y, None, float(r_meas[0]))
        ui = fast_loop.control(ctl.inner, r_meas, m.current, None, float(u_meas[0]))
        out.loops = {"position -> current reference": {"fit": nrmse_fit(r_meas, r),
                                                      "rms_A": float(np.sqrt(np.mean((r - r_meas) ** 2)))},
                     "current -> actuator": {"fit": nrmse_fit(u_meas, ui),
                                             "rms_input_units": float(np.sqrt(np.mean((ui - u_meas) ** 2)))
                                             * (rig.params.k_DA if rig.input_unit == "V" else 1.0)}}
    return out


def closed_loop_figures(rig: Rig, r: RigRecord, m: Measured, params: PlantParams, ctl, horizon_s: float = 0.020
                        ) -> ClosedLoopFigures:
    """The declared controller replayed in closed loop with the model, by prediction: the filter
    follows the segment, and from every sample the model and the controller run ``horizon_s``
    ahead on their own predicted readings and current. Fit % of the gap and of the actuator signal."""
    seg = m.slice(r.segment.start, r.segment.stop)
    if seg.reference is None:
        raise ValueError(f"{m.path}: a closed-loop replay needs the recorded reference")
    w = np.asarray(rig.reading(seg.reference))
    h = max(1, int(round(horizon_s / r.ts)))
    nz = noise_defaults(rig, params)
    o = fast_loop.predict(_start(rig, r, params), ctl, w, r.y, r.u, float(r.u[0]), q_force=nz["q_force"],
                     f_force=nz["f_force"], r_sensor=nz["r_sensor"], horizon=h)
    ok = _valid(len(r.y), h, r.ts) & np.isfinite(o["y_pred"]) & np.isfinite(o["u_pred"])
    return ClosedLoopFigures(label=r.label, horizon_s=horizon_s, gap_fit=nrmse_fit(r.y[ok], o["y_pred"][ok]),
                             actuator_fit=nrmse_fit(r.u[ok], o["u_pred"][ok]))


# ----------------------------------------------------------------------------- the commands

def run(rig: Rig, records: Sequence[Measured], out: str | Path, *, validate: Sequence[Measured] = (),
        per_record: bool = True, progress=None, json_name: str = "diagnosis.json", controller=None,
        effects: bool = True, second_force_lag: str | None = "default") -> RigRun:
    """The real-rig path's stages (:func:`maglev_cosim.diagnosis.diagnose` runs them): calibrates one
    parameter set on ``records`` (all their levitation segments), reports every record's figures
    before and after, each record's own calibration (the spread between records: drift is a
    finding), the fit on the ``validate`` records not used, the verdict, and writes ``report.md``,
    ``report.html``, the plots and the calibrated FMU into ``out``; the result (a
    :class:`~.rig_result.RigRun`) names ``json_name`` among the files, which the caller writes (from the typed
    result). Every record is
    cut into segments and checked before anything is written. ``controller``: a declared controller
    (:class:`maglev_cosim.loop.controllers.ControllerFile`), checked against each record and replayed
    in closed loop (:func:`controller_check`, :func:`closed_loop_figures`). ``effects``: try the
    catalogue's effects on the calibrated model (:func:`effect_search`); ``second_force_lag``: how the
    second force lag (:data:`SECOND_FORCE_LAG`) is fitted, None, "joint" or "after" (default
    :data:`SECOND_FORCE_LAG_FIT`)."""
    # One BLAS thread: the stages already spread their replays over the cores (:func:`_map`), and
    # OpenBLAS's own threads beside them only compete for the cores (on a busy 2-core machine a
    # controller's least squares of reaction.predict took 100 ms with two BLAS threads, 3 ms with one).
    # The thread beside the stages (the black box, the figures before calibration): what it has not
    # started when a stage fails is dropped.
    with threadpool_limits(limits=1), ThreadPoolExecutor(max_workers=1) as background:
        try:
            return _run(rig, records, out, validate=validate, per_record=per_record, progress=progress,
                        json_name=json_name, controller=controller, effects=effects,
                        second_force_lag=second_force_lag, background=background)
        finally:
            background.shutdown(wait=False, cancel_futures=True)


def _run(rig: Rig, records: Sequence[Measured], out: Path | str, *, validate: Sequence[Measured], per_record: bool,
         progress, json_name: str, controller, effects: bool, second_force_lag: str | None,
         background: ThreadPoolExecutor) -> RigRun:
    """:func:`run`'s stages (with one BLAS thread; ``background``: a thread for the work beside them)."""
    mode = SECOND_FORCE_LAG_FIT if second_force_lag == "default" else second_force_lag
    if mode not in (None, "joint", "after"):
        raise ValueError(f"second_force_lag: None, 'joint' or 'after', got {mode!r}")
    say = progress or (lambda msg: None)
    train = [(m, prepare(rig, m)) for m in records]
    held = [(m, prepare(rig, m)) for m in validate]
    segs = [r for _, rs in train for r in rs]
    out = Path(out)
    result = RigRun(rig=rig.name, rig_file=str(rig.path), horizons_s=list(HORIZONS_S))
    cal = None
    params = rig.params
    info = [information(rig, r) for r in segs]
    lacking = {id(r): why for r, why in zip(segs, info)}
    noise = noise_defaults(rig, params)
    fit_on = [r for r, why in zip(segs, info) if not why]
    result.fit_segments = len(fit_on)
    mech = mechanics_names(params)

    def fit_black_box() -> dict:
        series = [bb.Series(r.position, r.current if r.current is not None else r.u, r.ts) for r in fit_on]
        out = {hs: bb.fit(series, hs) for hs in HORIZONS_S}
        out.update({("past", hs): bb.fit(series, hs, future=False) for hs in HORIZONS_S})
        return out

    # the black box needs the records alone: it is fitted beside the calibration (numpy's products
    # release the GIL, and a single segment's fit leaves a core free)
    black_box_job = background.submit(fit_black_box) if fit_on else None
    background.submit(_load_matplotlib)   # the plots' library, loaded while the replays run
    # every segment's figures before calibration (the rig file's values) need nothing the stages
    # compute: queued behind the black box on the same thread, they fill a core the stages leave idle
    # (a sequential search, the Python between the replays); those not started when the figures'
    # stage comes are taken back into it (see there)
    every_seg = segs + [r for _, rs in held for r in rs]
    before_jobs = [background.submit(figures, rig, r, rig.params) for r in every_seg]
    if fit_on:
        # two stages, each on the signal its parameters act on: the coil on the current computed
        # from the actuator signal, then the force law, the mechanics' terms and the filter's
        # disturbance model on the gap predicted 5, 20 and 50 ms ahead
        say(f"calibrating the coil ({', '.join(COIL_FIT[rig.drive])}) on the current from the actuator signal")
        params, coil = calibrate_coil(rig, fit_on, params, names=COIL_FIT[rig.drive])
        result.coil_calibration = coil
        say(f"calibrating {', '.join(mech)} and the disturbance model on {len(fit_on)} segment(s)")
        params, cal = calibrate(rig, fit_on, params, names=mech)
        noise = cal.noise
        say(f"calibrated in {cal.evaluations} evaluations: cost {cal.cost_before:.4g} -> {cal.cost_after:.4g}")
    if cal is not None and effects:
        second = tuple(SECOND_FORCE_LAG) if mode else ()
        # the second force lag is the catalogue's eddy_lag: never tried by the effect search when the
        # calibration fits it (RIG_LEFT_OUT leaves it out of the search in any case, for now)
        search = result.effects = effect_search(rig, fit_on, params, say, noise=noise, skip=mech + ("T_d",) + second,
                                                refit_follows=True)
        chosen = list(search.parameters)
        params = params.replace(**search.parameters, **search.computed)
        joint = second if mode == "joint" else ()
        if chosen or joint:
            # the selected effects refitted together with the mechanics and the disturbance model:
            # an effect chosen with the others held may have taken the place of a parameter's error
            # (and "joint": the second force lag with them, sharing the force's time scale with T_F)
            say(f"refitting {', '.join(mech + tuple(chosen) + joint)} and the disturbance model together")
            params, cal = calibrate(rig, fit_on, params, names=mech + tuple(chosen) + joint, noise=noise)
            noise = cal.noise
            search.parameters = {n: cal.values[n] for n in chosen}
            faded = refit_took_off(search, cal, _effect_ranges(params))
            if faded:
                # an effect the joint refit took to its off end is no calibration that failed: the
                # model without it is the refit's (on multisteps_stairs/MPC alone, damping selected at
                # held-out -19 % and the joint refit ended at k_FV 0.0018 N·s/m, beside a force lag of
                # 0.45 ms): it leaves, at off
                params = params.replace(**{n: 0.0 for n in search.taken_off})
                say("the joint refit took " + ", ".join(faded) + " to off: " + ("they leave" if len(faded) > 1 else
                                                                                 "it leaves") + " the model")
        if mode == "after":
            say(f"fitting the second force lag ({', '.join(second)}) and the disturbance model, the rest held")
            params, cal = calibrate(rig, fit_on, params, names=second, noise=noise)
            noise = cal.noise
        if second:
            result.second_force_lag = {"mode": mode, "values": {n: cal.values[n] for n in second},
                                       "sigma": {n: cal.sigma[n] for n in second},
                                       "on_bounds": [n for n in cal.on_bounds if n in second]}
    # the model's parameters are final here (the correction below changes the filter's disturbance
    # model only): the linearised model's frequency response is drawn on the background thread while
    # the correction is fitted, instead of at the end beside the figures (half a second of plotting)
    out.mkdir(parents=True, exist_ok=True)
    plot_jobs = {}
    if segs:
        plot_jobs["frequency"] = background.submit(frequency_plot, rig, segs[0], params, out)
    own_models: dict = {}
    if cal is not None and effects:
        # where the catalogue explains too little: the located correction at the mechanics, a force
        # of gap and velocity, fitted and judged on the held-out blocks like an effect, on each
        # segment's own model (its coil and force gain) as its figures use it
        own_models = dict(zip(map(id, fit_on), _map(lambda r: _own_coil(rig, r, params, cal), fit_on)))
        say("trying the located correction at the mechanics (a force of gap and velocity) on the held-out blocks")
        co = result.correction = correction_search(rig, fit_on, params, noise, say,
                                                   own={k: v[0] for k, v in own_models.items()})
        if co.selected:
            noise = {**noise, "correction": co.correction}
    result.calibration = cal
    result.disturbance_model = {k: v for k, v in noise.items() if k != "correction"}
    black_box = {}
    if fit_on:
        say(f"fitting the black-box baseline (direct ridge predictors at {', '.join(f'{h * 1e3:g}' for h in HORIZONS_S)}"
            " ms) on the same segments")
        try:
            black_box = black_box_job.result()
        except ValueError as e:
            result.black_box_error = str(e)
        result.black_box = {f"{hs * 1e3:g} ms": {"ridge_alpha": p.alpha, "samples": p.samples,
                                                 "features": len(p.coef)}
                            for hs, p in black_box.items() if not isinstance(hs, tuple)}

    def calibration_segment(r: RigRecord) -> RigSegment:
        say(f"figures of {r.label}")
        pr, own = own_models.get(id(r)) or _own_coil(rig, r, params, cal)
        seg = RigSegment(label=r.label, after=figures(rig, r, pr, noise, black_box), own_coil=own)
        if per_record and cal and len(segs) > 1 and not lacking[id(r)]:
            # the force law's gain on this record alone (the rest held): its spread between
            # records is a finding, not noise
            gain = mech[0]
            _, own_info = calibrate(rig, [r], pr, names=(gain,), noise=noise, fit_noise=False, max_evaluations=15)
            seg.own_calibration = {**(own or {}), gain: own_info.values[gain]}
        frf = current_to_position(rig, r, params)
        seg.frequency_response = frf.get("summary")
        return seg

    def validation_segment(item: tuple[Measured, RigRecord, dict | None]) -> RigValidationSegment:
        m, r, fb = item
        say(f"validation figures of {r.label}")
        pr, own = _own_coil(rig, r, params, cal)
        return RigValidationSegment(file=str(m.path), label=r.label, after=figures(rig, r, pr, noise, black_box),
                                    warnings=m.warnings, force_balance_calibrated=fb, own_coil=own)

    def job(w: tuple[str, object]):
        kind, x = w
        if kind == "cal":
            return calibration_segment(x)
        if kind == "val":
            return validation_segment(x)
        return figures(rig, x, rig.params)   # "before"

    # every segment's figures (before and after calibration), own coil and own force gain are
    # independent of each other: they run side by side on the machine's cores (:func:`_map`), in one
    # list so that both keep busy; the figures before calibration the background thread has not
    # started yet join the list (the others it finishes meanwhile)
    held_items = [(m, r, fb) for m, rs in held for fb in [force_balance(rig, m, params)] for r in rs]
    taken = [f.cancel() for f in before_jobs]
    work = ([("cal", r) for r in segs] + [("val", it) for it in held_items]
            + [("before", r) for r, t in zip(every_seg, taken) if t])
    # the plots that need only the calibrated model are drawn on the background thread meanwhile
    # (matplotlib's Python beside the replays, which release the GIL; 2.8 s of plots at the end of a
    # 15 s record's diagnosis before), all on that one thread (matplotlib is not thread-safe)
    if segs:
        plot_jobs["prediction"] = background.submit(prediction_plot, rig, segs[0], params, out, noise, black_box)
    if result.correction is not None:
        plot_jobs["correction"] = background.submit(correction_plot, rig, result.correction, params,
                                                    out / "correction.png")
    done = _map(job, work)
    n_seg = len(every_seg)
    again = iter(done[n_seg:])
    for d, f, t in zip(done[:n_seg], before_jobs, taken):
        d.before = next(again) if t else f.result()
    cal_segs, result.validation = done[: len(segs)], done[len(segs): n_seg]
    figs_after = []
    k = 0
    for m, rs in train:
        entry = RigRecordResult(file=str(m.path), label=m.label, warnings=m.warnings, force_balance=force_balance(rig, m))
        if controller is not None:
            say(f"replaying the declared controller {controller.name} on {m.label}")
            entry.controller_check = controller_check(rig, m, controller.controller)
            entry.closed_loop = [closed_loop_figures(rig, r, m, params, controller.controller) for r in rs]
        for _ in rs:
            seg = cal_segs[k]
            k += 1
            entry.segments.append(seg)
            figs_after.append(seg.after)
        result.records.append(entry)
    verdict, reasons = conclude(rig, figs_after, info, cal)
    result.comparison = comparison(figs_after, [v.after for v in result.validation])
    verdict, more = judge_against_black_box(verdict, result.comparison)
    reasons += more
    if verdict == "explained" and not (result.effects and result.effects.selected):
        verdict = "no effect"   # the CE152 diagnosis's word: the calibrated model alone explains the record
    every = figs_after + [v.after for v in result.validation]
    drifting = [f for f in every if f.drift is not None and f.drift.significant]
    if drifting:
        reasons.append(f"the random force the filter estimates drifts during the run in {len(drifting)} of {len(every)} "
                       "segment(s), beyond its 2σ (change from the first to the last second, % of the weight): "
                       + "; ".join(f"{f.label} {f.drift.change_pct_weight:+.1f} ± "
                                   f"{f.drift.change_two_sigma:.1f}" for f in drifting)
                       + ": a force or a gain that changes during the run (drift.png)")
    heating = [(x.label, x.own_coil) for x in [*(s for e in result.records for s in e.segments), *result.validation]
               if (x.own_coil or {}).get("kappa_R_sigma")]
    if heating:
        found = [(lb, c) for lb, c in heating if abs(c["kappa_R"]) > 2 * c["kappa_R_sigma"]]
        reasons.append(f"the coil resistance changes during the run beyond its 2σ in {len(found)} of {len(heating)} "
                       "segment(s) (kappa_R, each segment's own coil, %/s ± 2σ; its model uses it only beyond 2σ): "
                       + "; ".join(f"{lb} {100 * c['kappa_R']:+.3f} ± {200 * c['kappa_R_sigma']:.3f}" for lb, c in heating)
                       + ": the winding warming (copper: +0.39 %/K) or cooling")
    held_skill = [v.after.position["20 ms"].skill_vs_stays_put for v in result.validation]
    held_skill = [k for k in held_skill if np.isfinite(k)]
    if held_skill and np.median(held_skill) < MIN_SKILL:
        reasons.append(f"the calibration does not carry over to the {len(held_skill)} validation segment(s): their gap "
                       f"20 ms ahead has median skill {np.median(held_skill):+.2f} against 'stays put' ({MIN_SKILL:g} "
                       f"needed; best {max(held_skill):+.2f}, worst {min(held_skill):+.2f}): the verdict holds for the "
                       "calibration records only")
        own = [fb.median for fb in (force_balance(rig, m, params) for m, _ in train) if fb]
        for v in result.validation:
            k = v.after.position["20 ms"].skill_vs_stays_put
            if not (np.isfinite(k) and k < MIN_SKILL):
                continue
            why = []
            fb = v.force_balance_calibrated
            if fb and own and not min(own) - 0.02 <= fb.median <= max(own) + 0.02:
                why.append(f"the calibrated force law carries {100 * fb.median:.0f} % of the weight here against "
                           f"{100 * min(own):.0f}-{100 * max(own):.0f} % on the calibration records (the force gain "
                           "differs between runs)")
            cur = v.after.current
            if cur and cur["from_actuator"] < MIN_CURRENT_FIT:
                why.append(f"its coil current from the actuator signal fits only {cur['from_actuator']:.1f} %")
            why += [w for w in v.warnings if "Kalman" in w]
            if why:
                reasons.append(f"{v.label} (skill {k:+.2f}): " + "; ".join(why))
    co = result.correction
    if co:
        reasons.append(correction_reason(co))
    ef = result.effects
    if ef:
        last = max(c.round for c in ef.candidates)
        tried = ", ".join(f"{c.effect} (off: no start gained {100 * REFINE_MIN_GAIN:g} %)" if c.screened is not None
                          else f"{c.effect} ({c.parameter} = {_values(c)}) {-100 * c.held_out_gain:+.1f} %"
                          for c in ef.candidates if c.round == last)
        if ef.selected:
            reasons.append(f"effects found: {', '.join(ef.selected)} ("
                           + ", ".join(f"{k} = {v:.4g}" for k, v in ef.parameters.items()) + ")")
        if ef.last_round_empty:   # the last round selected nothing
            reasons.append(("none of the remaining effects" if ef.selected else "no effect of the catalogue")
                           + f" explains enough on the held-out blocks: changes of the prediction cost (gap 5, 20 and 50 ms, current 5 ms ahead) "
                           f"{tried} (at most −{100 * MIN_EFFECT_GAIN:.0f} % needed)")
    for e in result.records:
        fb = e.force_balance
        if fb and not fb.consistent:
            reasons.append(f"{e.label}: the rig file's force law carries {100 * fb.median:.0f} % of the ball's "
                           f"weight at the recorded gap and current (median over {fb.samples} levitating samples; "
                           f"10-90 %: {100 * fb.p10:.0f}-{100 * fb.p90:.0f} %): its force constant, or the "
                           "record's current or position scale, contradicts the record"
                           + (f"; the current would have to be {fb.current_scale_for_weight:.2f}x the recorded "
                              "one to carry the weight" if np.isfinite(fb.current_scale_for_weight) else ""))
        ohm = fb.ohm if fb else None
        if ohm and not 0.7 <= ohm["median_V_over_Ri"] <= 1.4:
            both = (fb and not fb.consistent
                    and (ohm["median_V_over_Ri"] > 1) == (fb.current_scale_for_weight > 1))
            reasons.append(f"{e.label}: where the current settles, the rig file's coil voltage is "
                           f"{ohm['median_V_over_Ri']:.2f}x R times the recorded current (median over {ohm['samples']} "
                           "samples; Ohm's law wants 1)"
                           + (f"; both checks find the recorded current too {'small' if ohm['median_V_over_Ri'] > 1 else 'large'} "
                              f"for the rig file ({fb.current_scale_for_weight:.1f}x for the weight, "
                              f"{ohm['median_V_over_Ri']:.1f}x for Ohm's law): the record's current scale, or the rig "
                              "file's force constant and resistance, are wrong" if both else ""))
    if controller is not None:
        result.controller = {"name": controller.name, "file": str(controller.path), "type": controller.kind}
        for e in result.records:
            cc = e.controller_check
            loops = [v["fit"] for v in cc.loops.values()]
            best = max(cc.actuator_fit, min(loops) if loops else -np.inf)
            if best >= MIN_CONTROLLER_FIT:
                reasons.append(f"{e.label}: the declared controller {controller.name} reproduces the recorded "
                               f"actuator signal (fit {cc.actuator_fit:.1f} % from {cc.start}"
                               + "".join(f"; {k} {v['fit']:.1f} %" for k, v in cc.loops.items()) + ")")
            else:
                reasons.append(f"{e.label}: the declared controller {controller.name} does not reproduce the "
                               f"recorded actuator signal (fit {cc.actuator_fit:.1f} %, from rest or settled): the "
                               "declaration is not "
                               "the controller that ran; the figures above rest on the measured actuator signal "
                               "(the unknown-controller path) and do not depend on it")
    result.verdict, result.reasons = verdict, reasons
    own = [s.own_calibration for e in result.records for s in e.segments if s.own_calibration is not None]
    coils = [x.own_coil for x in [*(s for e in result.records for s in e.segments), *result.validation] if x.own_coil]
    if len(coils) > 1:
        result.coil_drift = _spread(coils)
    if len(own) > 1:
        result.spread = _spread(own)
    result.parameters = {**{n: float(getattr(params, n)) for n in (*COIL_FIT[rig.drive], *mech)},
                         **(result.effects.parameters if result.effects else {}),
                         **(result.second_force_lag or {}).get("values", {})}
    if segs:
        plot_jobs["drift"] = background.submit(drift_plot, [*figs_after, *(v.after for v in result.validation)], out)
    plots = [p for k in ("prediction", "drift", "frequency", "correction") if k in plot_jobs
             for p in [plot_jobs[k].result()] if p is not None]
    _shared_keys(result, train, held)
    written = [out / json_name, out / "report.md", out / "report.html", *plots]
    (out / "report.md").write_text(_markdown(result, plots))
    write_html(out / "report.md", out / "report.html")
    if verdict not in ("calibration failed", "too little information"):
        fmu_path = out / "maglev_calibrated.fmu"
        result.calibrated_fmu = _calibrated_rig_fmu(rig, result, params, train, out, fmu_path)
        written.insert(3, fmu_path)
    else:
        result.calibrated_fmu = None   # nothing calibrated worth an FMU: the verdict says why
    result.written = [str(p) for p in written]
    return result


def _shared_keys(result: RigRun, train, held) -> None:
    """Fills in the fields a real rig's result shares with the CE152 diagnosis (:data:`.result.SHARED_KEYS`),
    from its own figures: ``fit`` and ``fit_before`` the median NRMSE fit % of the gap reading
    (``y``) and of the current (``current``) predicted 20 ms ahead, beside ``free_run: None``
    (an unknown controller is never run free: the plant is open-loop unstable); ``before`` and
    ``after`` the RMS of the 20 ms prediction error of the reading [MU]; ``location_evidence``
    the best held-out cost change per location among the catalogue's effects."""
    segs = [s for e in result.records for s in e.segments]

    def fit(key: str) -> Fit:
        figs = [getattr(s, key) for s in segs]
        y = [f.position["20 ms"].model for f in figs]
        cur = [f.current["20 ms"] for f in figs if f.current]
        return Fit(None, PredictionFit(0.020, float(np.median(y)) if y else None,
                                       float(np.median(cur)) if cur else None, "current"))

    def rms(key: str) -> Residual:
        v = [getattr(s, key).position["20 ms"].rms_y for s in segs]
        v = [x for x in v if x is not None]
        return Residual(float(np.sqrt(np.mean(np.square(v)))) if v else None, horizon_s=0.020)

    evidence: dict[str, LocationEvidence] = {}
    search = result.effects
    for c in search.candidates if search else []:
        change = -c.held_out_gain
        if c.location not in evidence or change < evidence[c.location].held_out_cost_change:
            evidence[c.location] = LocationEvidence(c.location, c.effect, float(change))
    result.warnings = sorted({w for m, _ in [*train, *held] for w in m.warnings})
    result.fit, result.fit_before = (fit("after"), fit("before")) if segs else (None, None)
    result.selected = list(search.selected if search else [])
    result.uncertainties = result.calibration.sigma if result.calibration else {}
    result.before, result.after = (rms("before"), rms("after")) if segs else (None, None)
    result.location_evidence = list(evidence.values())


def _calibrated_rig_fmu(rig: Rig, result: RigRun, params: PlantParams, train, out: Path, path: Path) -> CalibratedFmu:
    """The rig's FMU with the calibrated parameters as start values, with its provenance in
    ``resources/calibration.json`` (records and their sha256, parameters with units and σ, the
    verdict, the comparison with the black box) and the report as ``documentation/``."""
    units = {n: u for n, (_, _, _, u) in fast.param_table().items()}
    sigma = result.uncertainties
    provenance = {
        "format": "maglev-cosim calibration 1",
        "rig": rig.name,
        "records": [{"file": Path(m.path).name, "sha256": hashlib.sha256(Path(m.path).read_bytes()).hexdigest()}
                    for m, _ in train],
        "verdict": result.verdict,
        "effects": result.selected,
        "parameters": {n: {"value": float(v), "unit": units.get(n), **({"sigma": sigma[n]} if n in sigma else {})}
                       for n, v in result.parameters.items()},
        "disturbance_model": result.disturbance_model,
        "comparison": result.comparison,
    }
    docs = {"index.html": (out / "report.html").read_bytes(), "report.md": (out / "report.md").read_bytes()}
    calibrated_fmu(ensure_fmu(None), path, params.to_start_values(),
                   resources={"rig.toml": rig.path.read_bytes(),
                              "calibration.json": (json.dumps(finite(provenance), indent=2) + "\n").encode()},
                   description=f"{rig.description}, calibrated on {', '.join(r['file'] for r in provenance['records'])} "
                               f"(maglev-cosim; verdict {result.verdict}; resources/calibration.json)",
                   model_name=f"{rig.name} magnetic levitation, calibrated", documentation=docs,
                   source_sha256=hashlib.sha256("".join(r["sha256"] for r in provenance["records"]).encode()).hexdigest())
    return CalibratedFmu(str(path), [RecordRef(r["file"], r.get("sha256")) for r in provenance["records"]])


def _spread(values: Sequence[dict]) -> dict:
    """Each parameter's least and largest value over the segments' ``values`` (their ``…_sigma`` left
    out) and its spread: relative to the mean (``(max − min)/|mean|``), or for an offset or a drift
    that may be near 0 (``u_0``, ``kappa_R``) the plain ``max − min``."""
    out = {}
    for n in values[0]:
        if n.endswith("_sigma"):
            continue
        v = [c[n] for c in values]
        out[n] = {"min": min(v), "max": max(v),
                  "relative": float(np.ptp(v)) if n in ("u_0", "kappa_R") else float(np.ptp(v) / abs(np.mean(v)))}
    return out


def _own_coil(rig: Rig, r: RigRecord, params: PlantParams, cal: RigCalibration | None
              ) -> tuple[PlantParams, dict[str, float] | None]:
    """The model of one segment with its own coil (:func:`calibrate_coil` on the segment alone: a
    resistance that differs between runs and warms during the run, ``kappa_R``, used only where its
    estimate lies beyond its 2σ of 0, a drive gain that differs between runs) and its own force gain
    (:func:`own_force_gain`: the force law's gain times the factor that makes it carry the ball's
    weight at the segment's measured gap and current) once the model is calibrated; the segment's
    values, or ``None``."""
    if cal is None or r.current is None:
        return params, None
    p, info = calibrate_coil(rig, [r], params)
    values = dict(info.values) if info else {}
    if "kappa_R" in values:   # the heating's drift is a finding: with its ±1σ
        sigma = float(info.sigma["kappa_R"])
        if not abs(values["kappa_R"]) > 2 * sigma:
            # within its 2σ of none: the segment's model goes without it (the rest refitted so), the
            # estimate is still reported
            p, info = calibrate_coil(rig, [r], params.replace(kappa_R=0.0),
                                     names=[n for n in COIL[rig.drive] if n != "kappa_R"])
            values = {**values, **info.values}
        values["kappa_R_sigma"] = sigma
    gain = mechanics_names(p)[0]
    factor = own_force_gain(rig, r, p)
    if np.isfinite(factor) and FORCE_BALANCE[0] <= 1 / factor <= FORCE_BALANCE[1]:
        p = p.replace(**{gain: getattr(p, gain) * factor})
        values[gain] = float(getattr(p, gain))
        values["force_gain_factor"] = float(factor)
    return p, values


def own_force_gain(rig: Rig, r: RigRecord, params: PlantParams) -> float:
    """The factor on the force law's gain that makes it carry the ball's weight on this segment:
    1 / the median of ``F(gap, i)/(m·g)`` over its samples at the measured gap and current (a
    levitating ball is held by its weight on average; the force gain drifts between runs by a few
    per cent, more than the filter's slow random force follows). NaN without a measured current."""
    if r.current is None:
        return float("nan")
    x = np.asarray(rig.to_x(r.position), float)
    i = np.clip(np.asarray(r.current, float), 0.0, None)
    step = max(1, len(x) // 2000)
    ratio = np.median(forces(params, x[::step], i[::step])) / (params.m_k * params.g)
    return float(1.0 / ratio) if ratio > 0 else float("nan")


def _values(c: EffectTrial) -> str:
    """A candidate's fitted value, or values (several coordinates, a pair of effects): those of its
    parameters (not the values it computed from them)."""
    return ", ".join(f"{c.values[n]:.4g}" for n in c.parameter.split(", "))


def _row(label: str, f: RigFigures) -> str:
    cur = f.current or {}
    cells = [label, f"{cur.get('from_actuator', float('nan')):.1f} ({cur.get('noise_ceiling', float('nan')):.1f})"]
    for h in ("5 ms", "20 ms", "50 ms"):
        p = f.position[h]
        bb = p.skill.get("black_box")
        cells.append(f"{p.model:.1f} / {p.stays_put:.1f} / {p.constant_velocity:.1f} "
                     f"({p.skill_vs_stays_put:+.2f}" + (f"; black box {bb:+.2f})" if bb is not None else ")"))
    cells.append(f"{cur.get('20 ms', float('nan')):.1f}")
    return "| " + " | ".join(cells) + " |"


def _markdown(res: RigRun, plots: list[Path]) -> str:
    head = ("| segment | current from actuator, fit % (the most its noise allows) | gap 5 ms: model / stays put / const. velocity (skill; black box's) "
            "| 20 ms | 50 ms | current 20 ms ahead, fit % |\n|---|---|---|---|---|---|")
    lines = [f"# Rig {res.rig}: measured records", "", f"**Verdict: {res.verdict}**", ""]
    lines += [f"- {r}" for r in res.reasons]
    lines += ["", "Fits are NRMSE fit % (MATLAB `compare`); the gap is predicted by the prediction-error replay "
              "in closed loop with a controller identified from the record (a linear map from the gap, the "
              "reference, the current and its own past to the actuator signal, fitted on the other half of the "
              "record's 1 s blocks; the measured actuator signal after each start is read as its reaction to the "
              "model's error: docs/diagnosis.md, 'A controller nobody states'), and driven by the measured "
              "actuator signal alone; skill = 1 − ‖error of the model‖/‖error of 'stays put'‖ (> 0: the model "
              "beats the naive predictor).", ""]
    comp = res.comparison
    if comp is not None and any(c.horizons for c in comp.roles):    # each horizon's row has the black box's figures
        lines += ["## The model against the black-box baseline", "",
                  "Median skill against 'stays put' (worst in brackets) of the gap predicted ahead: the model (the "
                  "physics with its effects and its disturbance model) in closed loop with the identified controller "
                  "and driven by the actuator signal alone, the black-box baseline (one ridge regression "
                  "per horizon on the last 30 ms of gap differences and the measured current and its square up to "
                  "the predicted instant, fitted by the tool on the same calibration segments), the same black box "
                  "with the current only up to the prediction's start, and 'constant velocity'. Higher is better; "
                  "> 0 beats 'stays put'.", "",
                  *comparison_table(comp)]
        lines.append("")
    cal = res.calibration
    if cal:
        units = {n: u for n, (_, _, _, u) in param_table().items()}
        lines += ["## Calibration", "", "| parameter | unit | rig file | calibrated |", "|---|---|---|---|"]
        lines += [f"| {n} | {units.get(n, '')} | {cal.rig_values[n]:.6g} | {cal.values[n]:.6g} |"
                  for n in cal.names]
        nz = cal.noise
        if nz:
            lines += ["", "The filter's disturbance model, calibrated with the plant: random force on the ball "
                      f"{nz['q_force'] * 1e3:.3g} mN RMS with a {nz['f_force']:.3g} Hz corner, sensor noise "
                      f"{nz['r_sensor']:.3g} MU RMS, current noise {nz['r_current'] * 1e3:.3g} mA RMS."]
        lines += ["", f"Cost {cal.cost_before:.4g} → {cal.cost_after:.4g} in {cal.evaluations} evaluations "
                  f"(prediction errors {', '.join(f'{h * 1e3:g}' for h in cal.horizons_s)} ms ahead)."]
        coil = res.coil_calibration
        if coil:
            lines += ["", "The coil was calibrated first, on the current computed from the actuator signal alone: "
                      + ", ".join(f"`{n}` = {v:.5g} {units.get(n, '')}" for n, v in coil.values.items()) + "."]
        rows = [(s.label, s.own_coil) for e in res.records for s in e.segments]
        rows += [(v.label, v.own_coil) for v in res.validation]
        rows = [(lb, c) for lb, c in rows if c]
        if rows:
            names = list(rows[0][1])
            lines += ["", "The coil of each segment on its own (the model of that segment uses it: a resistance that "
                      "follows heating, a drive gain that changes between runs):", "",
                      "| segment | " + " | ".join(f"{n} [{units.get(n, '')}]" for n in names) + " |",
                      "|---|" + "---|" * len(names)]
            lines += [f"| {lb} | " + " | ".join(f"{c[n]:.5g}" for n in names) + " |" for lb, c in rows]
        if res.spread:
            lines += ["", "Each record calibrated on its own (the spread between records):", "",
                      "| parameter | min | max | spread (max − min)/mean |", "|---|---|---|---|"]
            lines += [f"| {n} | {s['min']:.6g} | {s['max']:.6g} | "
                      + (f"{s['relative']:.3g} {units.get(n, '')} (max − min) |" if n in ("u_0", "kappa_R")
                         else f"{100 * s['relative']:.1f} % |") for n, s in res.spread.items()]
        lines.append("")
    ef = res.effects
    if ef:
        lines += ["## Effects of the catalogue on the calibrated model", "",
                  f"Each fitted on the even {ef.block_s:g} s blocks, judged on the odd ones: the change of the "
                  f"prediction cost of the gap 20 and 50 ms ahead and of the current 20 ms ahead (negative is better; at most −{100 * ef.min_gain:.0f} % to be selected).",
                  "", "| round | effect | acts on | parameter | fitted value | held-out cost change: gap / current |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {c.round} | {c.effect} | {c.location} | {c.parameter} | "
                  + (f"off (no start lowered the fit blocks' cost by {100 * REFINE_MIN_GAIN:g} %) | - / - |"
                     if c.screened is not None else
                     f"{_values(c)} | " + " / ".join(f"{-100 * c.held_out_gains[k]:+.1f} %" if k in c.held_out_gains
                                                     else "-" for k in ("y", "i")) + " |")
                  for c in ef.candidates]
        lines += ["", f"Selected: {', '.join(ef.selected) or 'none'}.", ""]
        # what the rig was not offered, and why (its drive and force law, or the real-rig search's own
        # exclusions), and what the calibration fitted instead
        missing = {n: why for n, why in ef.offered.items() if why is not None}
        if missing:
            lines += ["Not offered on this rig: " + "; ".join(f"{n} ({why})" for n, why in missing.items()) + ".", ""]
        if ef.skipped:
            lines += [f"Not tried, the calibration fits their parameters: {', '.join(ef.skipped)}.", ""]
    co = res.correction
    if co:
        s = co.summary
        lines += ["## The located correction at the mechanics", "",
                  f"A force on the ball that is a function of the gap and the velocity ({co.basis['n_x']} Legendre "
                  "terms in the gap, each times a static, a viscous (∝ v) and a friction (tanh(v/v_c)) part), in the "
                  "filter's model and its predictions; fitted by the prediction cost of the gap 20 and 50 ms ahead on "
                  f"the even {EFFECT_BLOCK_S:g} s blocks, judged on the odd ones (ridge weight {co.ridge:g}, chosen "
                  f"there). Held-out cost change {-100 * co.held_out_gain:+.1f} % (at most "
                  f"−{100 * co.min_gain:.0f} % to be used): {'used' if co.selected else 'not used'}.", "",
                  "| velocity shape fitted alone | held-out cost change |", "|---|---|"]
        lines += [f"| {k} | {-100 * v:+.1f} % |" for k, v in co.held_out_gain_by_shape.items()]
        lines += ["", f"Averaged over the records' gaps (positive: opposing the motion): static {s['static_pct_weight']:+.2f} ± "
                  f"{s['static_sigma_pct_weight']:.2f} % of the weight, viscous {s['viscous_N_s_per_m']:+.3g} ± "
                  f"{s['viscous_sigma']:.2g} N·s/m, friction {1e3 * s['friction_N']:+.3g} ± {1e3 * s['friction_sigma']:.2g} mN "
                  f"({100 * s['friction_N'] / s['weight_N']:+.2f} % of the weight); the catalogue's damping in the model "
                  f"is {s.get('k_FV', 0.0):.3g} N·s/m, so the velocity force in all is "
                  f"{s.get('k_FV', 0.0) + s['viscous_N_s_per_m']:.3g} N·s/m viscous and {1e3 * s['friction_N']:+.3g} mN of "
                  "friction. " + s.get("answer", ""), ""]
    for title, key in (("Before calibration (the rig file's values)", "before"), ("After calibration", "after")):
        lines += [f"## {title}", "", head]
        lines += [_row(s.label, getattr(s, key)) for e in res.records for s in e.segments]
        lines.append("")
    if res.validation:
        lines += ["## Validation on records not used for calibration", "", head]
        lines += [_row(v.label, v.after) for v in res.validation]
        lines.append("")
    fr = [s.frequency_response for e in res.records for s in e.segments if s.frequency_response]
    if fr:
        lines += ["## Current to gap: measured against the model (1–20 Hz)", "",
                  "| segment | mean coherence | gain measured/model | phase difference [deg] |", "|---|---|---|---|"]
        lines += [f"| {s.label} | {s.frequency_response['mean_coherence']:.2f} | "
                  f"{s.frequency_response['gain_ratio_measured_over_model']:.2f} | "
                  f"{s.frequency_response['phase_difference_deg']:+.0f} |"
                  for e in res.records for s in e.segments if s.frequency_response]
        lines.append("")
    fbs = [(e.label, e.force_balance) for e in res.records if e.force_balance]
    if fbs:
        lines += ["## Force balance: the share of the weight the force law carries at the measured gap and current",
                  "", "| record | 10 % | median | 90 % | levitating samples |", "|---|---|---|---|---|"]
        lines += [f"| {lab} | {100 * f.p10:.0f} % | {100 * f.median:.0f} % | {100 * f.p90:.0f} % | "
                  f"{f.samples} |" for lab, f in fbs]
        lines.append("")
    if res.controller:
        c = res.controller
        lines += [f"## The declared controller: {c['name']} ({c['type']})", "",
                  "Replayed alone on each record's measured signals, against the recorded actuator signal "
                  "(and loop by loop, when the record holds the current reference); then in closed loop with "
                  "the calibrated model, 20 ms ahead from every sample.", "",
                  "| record | actuator fit % | per loop | closed loop 20 ms: gap fit % / actuator fit % |",
                  "|---|---|---|---|"]
        for e in res.records:
            cc = e.controller_check
            loops = "; ".join(f"{k}: {v['fit']:.1f} %" for k, v in (cc.loops if cc else {}).items()) or "-"
            cl = ", ".join(f"{x.gap_fit:.1f} / {x.actuator_fit:.1f}" for x in e.closed_loop or []) or "-"
            lines.append(f"| {e.label} | {cc.actuator_fit if cc else float('nan'):.1f} | {loops} | {cl} |")
        lines.append("")
    lines += [f"![{p.stem}]({p.name})" for p in plots]
    return "\n".join(lines) + "\n"


#: The horizon [s] prediction.png shows.
PLOT_HORIZON_S = 0.020
#: Coherence below which the measured frequency response is drawn faded (not a measurement).
MIN_COHERENCE = 0.3
#: Width of each window of the prediction plot [s].
WINDOW_S = 0.8


def event_windows(r: RigRecord, y_pred: np.ndarray, h: int) -> list[tuple[str, int, int]]:
    """Two windows of the segment worth looking at: around its largest move of the position over
    ``h`` samples (a step of the reference, usually) and around the model's largest error ``h``
    ahead, outside the first window where the segment has room for both (a step is often where the
    model errs most: two windows of the same step showed nothing twice); (title, first sample, end
    sample)."""
    n = len(r.y)
    w = min(n, int(round(WINDOW_S / r.ts)))
    skip = min(n - w, int(round(SETTLE_S / r.ts)))
    move = np.zeros(n)
    move[h:] = np.abs(r.position[h:] - r.position[:-h])
    move[:skip] = 0
    err = np.abs(r.y - y_pred)
    err[~np.isfinite(err)] = 0
    err[:skip] = 0
    def window(k: int) -> int:
        return int(np.clip(k - w // 3, 0, n - w))

    k_move, k_err = int(np.argmax(move)), int(np.argmax(err))
    a = window(k_move)
    first = f"largest move (t = {k_move * r.ts:.2f} s)"
    if a <= k_err < a + w and n >= 4 * w:
        first = f"largest move and model error (t = {k_move * r.ts:.2f} s)"
        err[max(0, a - w):a + 2 * w] = 0      # the next largest, whose window then stays clear of the first
        k_err = int(np.argmax(err))
        second = f"largest model error elsewhere (t = {k_err * r.ts:.2f} s)"
    else:
        second = f"largest model error (t = {k_err * r.ts:.2f} s)"
    b = window(k_err)
    return [(first, a, a + w), (second, b, b + w)]


def _load_matplotlib() -> None:
    """Imports what the figures and the plots use (a second and a half of imports, done ahead)."""
    for name in ("scipy.signal", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        importlib.import_module(name)


def _figure(figsize: tuple[float, float], *grid: int, **kw):
    """A figure and its axes (``Figure.subplots(*grid, **kw)``) without pyplot: no global list of
    figures, so the plots can be drawn on the background thread while the stages run (``savefig``
    renders with Agg)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*grid, **kw)


def prediction_plot(rig: Rig, r: RigRecord, params: PlantParams, out: Path, noise: dict[str, float] | None = None,
                    black_box: dict | None = None) -> Path:
    """prediction.png: the gap :data:`PLOT_HORIZON_S` ahead (model, black box, "stays put") and the
    current from the actuator signal, in the windows of the record's events (:func:`event_windows`)."""
    hs = PLOT_HORIZON_S
    h = _lag(r, hs)
    o = predict(rig, r, params, hs, noise=noise)
    oc = predict(rig, r, params, r.ts, use_current=False, noise=noise)
    yb = (black_box[hs].predict(bb.Series(r.position, r.current if r.current is not None else r.u, r.ts))
          if black_box and hs in black_box else None)
    t = np.arange(len(r.y)) * r.ts
    wins = event_windows(r, o["y_pred"], h)
    fig, ax = _figure((11, 6.5), 2, len(wins), sharex="col", squeeze=False)
    for j, (title, k0, k1) in enumerate(wins):
        sl = slice(k0, k1)
        a = ax[0, j]
        a.plot(t[sl], 1e3 * r.position[sl], "k", lw=1.2, label="measured")
        a.plot(t[sl], 1e3 * _to_position(rig, o["y_pred"][sl]), "C1", lw=1, label=f"model, {hs * 1e3:g} ms ahead")
        if yb is not None:
            a.plot(t[sl], 1e3 * yb[sl], "C2", lw=1, ls="--", label=f"black box, {hs * 1e3:g} ms ahead")
        a.plot(t[sl], 1e3 * bb.stays_put(r.position, h)[sl], "0.6", lw=1, ls=":", label="stays put")
        a.set_title(title, fontsize=10)
        a.set_ylabel(f"position ({rig.convention}) [mm]")
        if r.current is not None:
            ax[1, j].plot(t[sl], r.current[sl], "k", lw=1, label="measured current")
            ax[1, j].plot(t[sl], oc["i_pred"][sl], "C0", lw=1, label="model from the actuator signal")
        ax[1, j].set_ylabel("coil current [A]")
        ax[1, j].set_xlabel("time in segment [s]")
    handles = [hd for a in (ax[0, 0], ax[1, 0]) for hd in a.get_legend_handles_labels()[0]]
    labels = [lb for a in (ax[0, 0], ax[1, 0]) for lb in a.get_legend_handles_labels()[1]]
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=9, frameon=False)
    fig.suptitle(f"{r.label}: the gap {hs * 1e3:g} ms ahead and the current (parameters: calibrated)")
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    p = out / "prediction.png"
    fig.savefig(p, dpi=110)
    return p


def drift_plot(figs: Sequence[RigFigures], out: Path) -> Path | None:
    """drift.png: the random force the filter estimates, per segment, in :data:`DRIFT_BLOCK_S` means
    with ±2σ (None: no segment has its trajectory)."""
    drifts = [(f.label, f.drift) for f in figs if f.drift is not None and f.drift.t_s]
    if drifts:
        fig, a = _figure((9, 4.5))
        for j, (label, d) in enumerate(drifts):
            tt, m, s2 = (np.asarray(v) for v in (d.t_s, d.force_pct_weight, d.two_sigma_pct_weight))
            a.plot(tt, m, color=f"C{j % 10}", lw=1.2, label=label)
            a.fill_between(tt, m - s2, m + s2, color=f"C{j % 10}", alpha=0.15)
        a.axhline(0, color="0.5", lw=0.8)
        a.set_xlabel("time in segment [s]")
        a.set_ylabel("random force on the ball [% of weight]")
        a.set_title(f"the force the filter estimates, {DRIFT_BLOCK_S:g} s means with ±2σ (positive: downward on the gap)",
                    fontsize=10)
        a.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
        fig.tight_layout()
        p = out / "drift.png"
        fig.savefig(p, dpi=110)
        return p
    return None


def frequency_plot(rig: Rig, r: RigRecord, params: PlantParams, out: Path) -> Path | None:
    """frequency_response.png: current to gap, measured (Welch; faded where the coherence is below
    :data:`MIN_COHERENCE`) and the model linearised, with the band the figures use (None: no response)."""
    frf = current_to_position(rig, r, params)
    if frf:
        f = frf["f_Hz"]
        band = (f > 0.3) & (f < 60)
        good = band & (frf["coherence"] >= MIN_COHERENCE)
        fig, ax = _figure((8, 7), 3, 1, sharex=True)
        meas_gain = np.abs(frf["measured"])
        meas_phase = np.degrees(np.angle(frf["measured"]))
        for a, mv, model in ((ax[0], meas_gain, np.abs(frf["model"])),
                             (ax[1], meas_phase, np.degrees(np.angle(frf["model"])))):
            a.plot(f[band], np.where(good[band], np.nan, mv[band]), color="0.75", lw=1,
                   label=f"measured, coherence < {MIN_COHERENCE:g} (not a measurement)")
            a.plot(f[band], np.where(good[band], mv[band], np.nan), "k", lw=1.2, label="measured (Welch)")
            a.plot(f[band], model[band], "C1", label="model, linearised")
        ax[0].set_xscale("log")
        ax[0].set_yscale("log")
        ax[0].set_ylabel("|gap/current| [m/A]")
        ax[1].set_ylabel("phase [deg]")
        ax[2].semilogx(f[band], frf["coherence"][band], "k")
        ax[2].axhline(MIN_COHERENCE, color="0.5", ls=":", lw=1)
        ax[2].set_ylabel("coherence")
        ax[2].set_xlabel("frequency [Hz]")
        lo, hi = frf["summary"]["band_Hz"]
        for a in ax:
            a.axvspan(lo, hi, color="C0", alpha=0.07)
        ax[0].legend(fontsize=8, loc="lower left")
        fig.suptitle(f"current to gap: {r.label}\n(shaded: the {lo:g}–{hi:g} Hz band of the figures)", fontsize=11)
        fig.tight_layout()
        p = out / "frequency_response.png"
        fig.savefig(p, dpi=110)
        return p
    return None
