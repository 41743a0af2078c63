"""Where a residual no catalogue effect explains enters the loop: generic corrections.

At each of the three places a model error can enter the loop, a generic correction of the final
model is fitted to its free-run residual and judged on the held-out blocks, as the catalogue's
effects are (issue 7, item 5):

- ``actuator``: a correction of the coil current, injected at the D/A input [MU]: a function of
  the controller's output u, or a filter of the current i [A] (through the amplifier's gain);
- ``mechanics``: a force on the ball [N], a function of the ball's position x and of the force the
  model applies;
- ``sensor``: a correction added to the reading [MU], a function of the position x and of the
  model's reading.

Each correction has two forms: a *static nonlinearity*, a smooth cubic spline of the local signal
(``scipy.interpolate.BSpline``, knots at the signal's quantiles on the fit blocks), and a *low-order linear
filter*, ``sum_l a_l*(s[k-l] - s[k])`` over a few lags ``l`` of the local signal ``s`` (a lag,
a delay or a lead all have this form to first order); at the mechanics the filter also has a term
in the ball's velocity (damping). Each basis signal is injected into the model's closed loop
(:func:`maglev_cosim.diagnosis.replay.replay_injected`, the C plant) to get its effect on y and u, so the
loop's feedback is accounted for exactly to first order; the coefficients are then a ridge
least-squares fit of the residual (y and u, each over its noise level) on the fit blocks. The
held-out gain is the share of the held-out residual energy the correction removes.

The location that removes most is reported with the fitted shape (the spline's curve over the
signal's range, or the filter's frequency response), so that an engineer can recognise the
physics: a curve with a ripple at the sensor, a saturating curve at the actuator.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import BSpline

from ..records.record import Record
from .replay import replay, replay_injected

LOCATIONS = ("actuator", "mechanics", "sensor")
#: Interior knots of the splines (cubic: knots + 4 coefficients).
KNOTS = 8
#: Lags [samples] of the filters.
LAGS = (1, 2, 4, 8)
#: Share of the held-out residual energy a correction must remove for its location to count.
MIN_GAIN = 0.05
#: A location whose best correction removes at least this share of the winner's is a rival.
RIVAL_SHARE = 0.8
#: Ridge weight, relative to the mean diagonal of the normal equations.
RIDGE = 1e-6
#: Weight of a spline's second-difference penalty, relative to the same.
SMOOTH = 1e-2
#: Velocity [m/s] over which the mechanics' sign-of-velocity term ``tanh(v/V_SIGN)`` turns.
V_SIGN = 1e-3
#: The mechanics' force of the gap and the velocity, as a sum of these terms (each over its RMS on
#: the record): what it is, as a function of x - mean(x) and v.
MECHANICS_TERMS = ("v", "tanh(v/v_s)", "x", "x*v")
#: The actuator's current correction of the current and its rate. The input enters through the
#: current: in the model the current is the input through the amplifier's law (affine where it does
#: not clip), so that terms in u beside terms in i are collinear, and such a fit extrapolates
#: wildly to the held-out blocks (held-out gains of -30 % to -270 % measured with u, u^2 added).
ACTUATOR_TERMS = ("i", "i^2", "di/dt", "i*di/dt")


@dataclass
class Correction:
    """One generic correction fitted at one location."""

    location: str
    form: str                        # "static" or "filter"
    signal: str                      # the local signal it is a function of
    unit: str                        # unit of the correction
    held_out_gain: float             # share of the held-out residual energy removed
    fit_gain: float                  # same on the fit blocks
    coefficients: list[float]
    shape: dict = field(default_factory=dict)   # curve (static) or frequency response (filter)

    def to_json(self) -> dict:
        return {"location": self.location, "form": self.form, "signal": self.signal, "unit": self.unit,
                "held_out_gain": self.held_out_gain, "fit_gain": self.fit_gain,
                "coefficients": self.coefficients, "shape": self.shape}


def _spline_basis(s: np.ndarray, knots: int = KNOTS, at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Cubic B-spline basis of signal ``s`` (columns), knots at the quantiles of ``s[at]`` (the
    fit blocks: every basis function then has data to be fitted on); and the knot vector."""
    inner = np.quantile(s if at is None else s[at], np.linspace(0.0, 1.0, knots + 2))
    inner = np.unique(inner)
    if len(inner) < 2:
        return np.zeros((len(s), 0)), inner
    t = np.concatenate([[inner[0]] * 3, inner, [inner[-1]] * 3])
    B = BSpline.design_matrix(np.clip(s, inner[0], inner[-1]), t, 3).toarray()
    return B, t


def _lagged(s: np.ndarray, lags=LAGS) -> np.ndarray:
    """Columns s[k-l] - s[k] (the first samples repeat s[0])."""
    cols = []
    for lag in lags:
        prev = np.concatenate([np.full(lag, s[0]), s[:-lag]])
        cols.append(prev - s)
    return np.column_stack(cols)


def _effects(rec: Record, params: Mapping[str, float], base: Mapping[str, np.ndarray], where: str,
             columns: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """Effect on (y, u) of each column injected at ``where``, to first order (scaled by ``eps``)."""
    ny, nu = np.empty_like(columns), np.empty_like(columns)
    key = {"actuator": "du", "mechanics": "dF", "sensor": "dy"}[where]
    for j in range(columns.shape[1]):
        sim = replay_injected(rec, params, **{key: eps * columns[:, j]})
        ny[:, j] = (sim["y"] - base["y"]) / eps
        nu[:, j] = (sim["u"] - base["u"]) / eps
    return ny, nu


def _terms(names: tuple[str, ...], sig: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Columns of products of centred signals (``x``, ``u``, ``i``: minus their mean; ``v``,
    ``di/dt`` as they are; ``tanh(v/v_s)``), each divided by its RMS: returned with those RMS."""
    cols = []
    for name in names:
        col = np.ones_like(sig["v"])
        for f in name.split("*"):
            f, _, power = f.partition("^")
            col = col * sig[f] ** (int(power) if power else 1)
        cols.append(col - (np.mean(col) if "^" in name or "*" in name else 0.0))
    X = np.column_stack(cols)
    rms = np.maximum(np.sqrt(np.mean(X ** 2, axis=0)), 1e-300)
    return X / rms, rms


def _centred(base: Mapping[str, np.ndarray], ts: float) -> dict[str, np.ndarray]:
    """The signals the state corrections are functions of: the free run's gap, velocity, input,
    current and the current's rate (central differences), centred where a constant is a bias."""
    return {"x": base["x"] - np.mean(base["x"]), "v": base["v"], "tanh(v/v_s)": np.tanh(base["v"] / V_SIGN),
            "u": base["u"] - np.mean(base["u"]), "i": base["i"] - np.mean(base["i"]),
            "di/dt": np.gradient(base["i"], ts)}


def _state_shape(where: str, theta: np.ndarray, rms: np.ndarray, sig: Mapping[str, np.ndarray], mg: float) -> dict:
    """What a state correction is, in physical units: each term's coefficient, and its curve over
    the signal that matters. At the mechanics the force against the velocity at the mean gap, with
    the sign-of-velocity step (Coulomb friction shows as a step at v = 0) and the viscous slope; at
    the actuator the current correction against the current at zero rate."""
    names = MECHANICS_TERMS if where == "mechanics" else ACTUATOR_TERMS
    coef = {n: float(c / r) for n, c, r in zip(names, theta, rms)}
    if where == "mechanics":
        v = sig["v"]
        grid = np.linspace(np.quantile(v, 0.01), np.quantile(v, 0.99), 81)
        curve = coef["v"] * grid + coef["tanh(v/v_s)"] * np.tanh(grid / V_SIGN)
        # a force against the motion, -F_c*tanh(v/v_s) - b*v, is a friction: F_c > 0, b > 0
        return {"kind": "curve", "signal": "v", "x": grid.tolist(), "correction": curve.tolist(),
                "terms": list(names), "coefficients_si": coef, "v_s": V_SIGN,
                "step_at_zero_velocity_N": 2 * coef["tanh(v/v_s)"],
                "coulomb_force_N": -coef["tanh(v/v_s)"], "coulomb_share_of_weight": -coef["tanh(v/v_s)"] / mg,
                "damping_N_s_per_m": -coef["v"]}
    i = sig["i"]
    grid = np.linspace(np.quantile(i, 0.01), np.quantile(i, 0.99), 60)
    curve = coef.get("i", 0.0) * grid + coef.get("i^2", 0.0) * (grid ** 2 - np.mean(i ** 2))
    return {"kind": "curve", "signal": "i", "x": (grid + sig["i_mean"]).tolist(), "correction": curve.tolist(),
            "terms": list(names), "coefficients_si": coef, "rate_A_per_A_s": coef.get("di/dt", 0.0)}


def _ridge(A: np.ndarray, b: np.ndarray, smooth: bool) -> np.ndarray:
    """Penalised least squares: a small ridge, and for a spline a penalty on the second
    differences of its coefficients (a P-spline), so that the curve stays smooth where the fit
    blocks hold few samples."""
    G = A.T @ A
    scale = float(np.mean(np.diag(G))) if G.size else 0.0
    P = RIDGE * scale * np.eye(G.shape[0])
    if smooth and G.shape[0] > 2:
        D = np.diff(np.eye(G.shape[0]), 2, axis=0)
        P = P + SMOOTH * scale * (D.T @ D)
    return np.linalg.solve(G + P, A.T @ b)


def generic_corrections(rec: Record, params: Mapping[str, float], fit_mask: np.ndarray, *, scale_y: float,
                        scale_u: float, base: Mapping[str, np.ndarray] | None = None) -> list[Correction]:
    """Fits the generic corrections at every location and form (module docstring).

    Parameters
    ----------
    rec : Record
        The closed-loop record.
    params : mapping
        The final model's FMU parameter values [SI units].
    fit_mask : ndarray of bool
        Samples the coefficients are fitted on; the others judge them.
    scale_y, scale_u : float
        Noise levels of y and u [MU]: each residual is divided by its own.
    base : mapping, optional
        The final model's free run (default: replayed here).

    Returns
    -------
    list of Correction
        One per location and form, best held-out gain first.
    """
    base = base or replay(rec, params)
    r = np.concatenate([(rec.y - base["y"]) / scale_y, (rec.u - base["u"]) / scale_u])
    fit = np.concatenate([fit_mask, fit_mask])
    held = ~fit
    m_k, g, k_fv = params["m_k"], params["g"], params["k_FV"]
    ts = rec.ts
    v = base["v"]
    force = m_k * (np.gradient(v, ts) + g) + k_fv * v       # the force the model applies [N]
    mg = m_k * g
    amp = abs(params["k_i"] * params["k_DA"])              # [A/MU] the amplifier's gain (Eq. 1, 5)
    sig = {**_centred(base, ts), "i_mean": float(np.mean(base["i"]))}
    signals = {
        "actuator": [("static", "u", base["u"], "MU", 1e-3), ("filter", "i", base["i"], "A", 1e-3 * amp),
                     ("state", "i, di/dt", base["i"], "A", 1e-3 * amp)],
        "mechanics": [("static", "x", base["x"], "N", 1e-3 * mg), ("filter", "F", force, "N", 1e-3 * mg),
                      ("state", "x, v", base["v"], "N", 1e-3 * mg)],
        "sensor": [("static", "x", base["x"], "MU", 1e-3), ("filter", "y", base["y"], "MU", 1e-3)],
    }
    out: list[Correction] = []
    for where in LOCATIONS:
        for form, name, s, unit, eps in signals[where]:
            if form == "static":
                cols, knots = _spline_basis(s, at=fit_mask)
            elif form == "state":
                cols, term_rms = _terms(MECHANICS_TERMS if where == "mechanics" else ACTUATOR_TERMS, sig)
            else:
                cols = _lagged(s)
                if where == "mechanics":
                    cols = np.column_stack([cols, v / max(float(np.std(v)), 1e-12)])   # damping
            if cols.shape[1] == 0:
                continue
            inject = cols / amp if (where == "actuator" and form != "static") else cols   # a current as its input
            ny, nu = _effects(rec, params, base, where, inject, eps)
            A = np.vstack([ny / scale_y, nu / scale_u])
            theta = _ridge(A[fit], r[fit], smooth=form == "static")
            res = r - A @ theta
            gain = lambda mask: float(1.0 - np.sum(res[mask] ** 2) / max(np.sum(r[mask] ** 2), 1e-300))  # noqa: E731
            c = Correction(where, form, name, unit, gain(held), gain(fit), [float(x) for x in theta])
            if form == "static":
                grid = np.linspace(np.quantile(s, 0.01), np.quantile(s, 0.99), 60)
                curve = BSpline(knots, theta, 3)(np.clip(grid, knots[0], knots[-1]))
                c.shape = {"kind": "curve", "signal": name, "x": grid.tolist(),
                           "correction": (curve - np.mean(curve)).tolist()}
            elif form == "state":
                c.shape = _state_shape(where, theta, term_rms, sig, mg)
            else:
                a = theta[:len(LAGS)]
                f = np.logspace(-1, np.log10(0.5 / ts), 60)
                z = np.exp(-2j * np.pi * f * ts)
                H = 1.0 + sum(ak * (z ** lag - 1.0) for ak, lag in zip(a, LAGS))
                c.shape = {"kind": "frequency_response", "signal": name, "f_hz": f.tolist(),
                           "magnitude": np.abs(H).tolist(), "phase_deg": np.degrees(np.angle(H)).tolist()}
                if where == "mechanics":
                    c.shape["damping_coefficient"] = float(theta[-1] / max(float(np.std(v)), 1e-12))
            out.append(c)
    return sorted(out, key=lambda c: -c.held_out_gain)


def best_per_location(corrections: list[Correction]) -> dict[str, Correction]:
    """Each location's correction with the largest held-out gain."""
    best: dict[str, Correction] = {}
    for c in corrections:
        if c.location not in best or c.held_out_gain > best[c.location].held_out_gain:
            best[c.location] = c
    return best


def locate(corrections: list[Correction]) -> tuple[str, dict[str, dict], list[str]]:
    """The location whose best correction removes most of the held-out residual (at least
    :data:`MIN_GAIN`), else ``undetermined``; per location its best correction's figures; and the
    other locations whose best removes at least :data:`RIVAL_SHARE` of that (the record does not
    separate them: a lag of the current, of the force and of the reading are nearly the same
    transfer function from u to y, so filters at all three places often tie)."""
    best = {loc: {"form": c.form, "signal": c.signal, "held_out_gain": c.held_out_gain}
            for loc, c in best_per_location(corrections).items()}
    top = max(best.items(), key=lambda kv: kv[1]["held_out_gain"], default=None)
    if top is None or top[1]["held_out_gain"] < MIN_GAIN:
        return "undetermined", best, []
    rivals = [loc for loc, fig in best.items()
              if loc != top[0] and fig["held_out_gain"] >= RIVAL_SHARE * top[1]["held_out_gain"]]
    return top[0], best, rivals
