"""The paper's own identification methods (Section 3.4), applied to a closed-loop record.

- Settled segments: stretches where the reference is constant and the loop has settled; there
  the integrator holds the equilibrium input, so each segment gives one equilibrium point
  ``(x, u)`` (position from Eq. 12/13 inverted, D/A voltage from Eq. 1).
- Two-point interpolation (Sec. 3.4.2): Eq. 11 at rest, ``m_k·g = k_f·u²/(x_0 − x)²``, is linear
  in ``x`` as ``u = (x_0 − x)·sqrt(m_k·g/k_f)``; two points give ``x_0`` and ``k_f``.
- Least squares (Eq. 14): minimise ``Σ (k_f·u_k²/(x_0 − x_k)² − m_k·g)²`` over ``x_0, k_f``.
- Simplex (Sec. 3.4.3): Nelder-Mead on ``k_FV`` against the measured closed-loop response.
``k_c = k_f / k_i²`` (plant.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from ..plant.formulas import positions
from ..records.record import Record
from .replay import replay

#: The paper's values (Sec. 3.4.2, 3.4.3).
PAPER = {
    "two_point": {"x_0": 0.0095, "k_f": 0.71214e-6, "k_c": 7.91e-6},
    "least_squares": {"x_0": 0.0083, "k_f": 0.609e-6, "k_c": 6.9e-6},
    "simplex": {"k_FV": 0.03},
}


@dataclass
class Segment:
    """A settled stretch of a record: sample range, mean reading y [MU] and input u [MU]."""

    start: int
    stop: int
    y: float
    u: float


def settled_segments(rec: Record, *, min_length: float = 0.6, settle: float = 0.4,
                     tolerance: float = 0.01) -> list[Segment]:
    """Stretches of constant reference, from ``settle`` s after the change to the next change,
    at least ``min_length`` s long in all, where the mean reading is within ``tolerance`` MU
    of the reference (the integrator has converged)."""
    change = np.nonzero(np.abs(np.diff(rec.w)) > 1e-9)[0] + 1
    edges = np.concatenate([[0], change, [rec.n]])
    skip = int(round(settle / rec.ts))
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        if (b - a) * rec.ts < min_length:
            continue
        s = a + skip if a > 0 else a
        if b - s < 50:
            continue
        y, u = float(np.mean(rec.y[s:b])), float(np.mean(rec.u[s:b]))
        if abs(y - rec.w[a]) <= tolerance and rec.u_min < u < rec.u_max:
            out.append(Segment(int(s), int(b), y, u))
    return out


def quasi_static_points(rec: Record, *, window: float = 0.2, n_bins: int = 20) -> list[Segment]:
    """For slowly varying references (the paper's slow sine, Sec. 3.4.2): window means of y and
    u where the reference moves slowly, binned by level."""
    k = max(1, int(round(window / rec.ts)))
    m = rec.n // k
    y = rec.y[: m * k].reshape(m, k).mean(axis=1)
    u = rec.u[: m * k].reshape(m, k).mean(axis=1)
    w = rec.w[: m * k].reshape(m, k)
    slow = np.ptp(w, axis=1) < 0.03
    if slow.sum() < 2:
        return []
    edges = np.linspace(y[slow].min(), y[slow].max() + 1e-12, n_bins + 1)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = slow & (y >= lo) & (y < hi)
        if sel.any():
            out.append(Segment(-1, -1, float(y[sel].mean()), float(u[sel].mean())))
    return out


def equilibrium_points(rec: Record, params: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Positions x [m] (Eq. 12/13 inverted) and D/A voltages [V] (Eq. 1) of the settled segments."""
    seg = settled_segments(rec)
    if len(seg) < 2:
        seg = quasi_static_points(rec)
    if len(seg) < 2:
        raise ValueError(f"{rec.path}: fewer than two settled segments or quasi-static levels: "
                         "the paper's methods need equilibrium points at two positions at least")
    y = np.array([s.y for s in seg])
    u = np.array([s.u for s in seg])

    return positions(params, y), params["k_DA"] * u + params["u_0"]   # Eq. 12/13 inverted, Eq. 1


def two_point(x: np.ndarray, u_v: np.ndarray, m_k: float, g: float) -> dict[str, float]:
    """Two-point interpolation (Sec. 3.4.2) through the two most distant equilibrium points."""
    a, b = int(np.argmin(x)), int(np.argmax(x))
    slope = (u_v[a] - u_v[b]) / (x[b] - x[a])           # sqrt(m_k g / k_f)
    if slope <= 0:
        raise ValueError("equilibrium input does not fall with height: the two-point method does not apply")
    return {"x_0": float(x[a] + u_v[a] / slope), "k_f": float(m_k * g / slope**2)}


def least_squares_eq14(x: np.ndarray, u_v: np.ndarray, m_k: float, g: float) -> dict[str, float]:
    """The LQ fit of Eq. 14: ``k_f`` in closed form for each ``x_0``, ``x_0`` by a bounded search."""
    mg = m_k * g

    def kf_and_cost(x0: float) -> tuple[float, float]:
        q = u_v**2 / (x0 - x) ** 2
        kf = mg * q.sum() / (q * q).sum()
        return kf, float(np.sum((kf * q - mg) ** 2))

    lo = float(x.max()) + 2e-4
    r = minimize_scalar(lambda x0: kf_and_cost(x0)[1], bounds=(lo, lo + 0.03), method="bounded",
                        options={"xatol": 1e-9})
    kf, cost = kf_and_cost(r.x)
    return {"x_0": float(r.x), "k_f": float(kf), "cost": cost}


def simplex_kfv(rec: Record, params: dict[str, float], *, k_fv0: float = 0.03) -> dict[str, float]:
    """Nelder-Mead on ``k_FV`` (Sec. 3.4.3): the closed-loop replay of the record (fast path) against
    the measured reading, least squares of ``y`` [MU]."""
    def cost(z: np.ndarray) -> float:
        sim = replay(rec, {**params, "k_FV": abs(float(z[0]))})
        return float(np.mean((rec.y - sim["y"]) ** 2))

    r = minimize(cost, [k_fv0], method="Nelder-Mead", options={"xatol": 1e-5, "fatol": 1e-14})
    return {"k_FV": abs(float(r.x[0])), "rms_y": float(np.sqrt(r.fun))}


def identify(rec: Record, params: dict[str, float], *, with_simplex: bool = True) -> dict:
    """All three methods on a record; ``params`` supplies the fixed values (k_DA, k_i, m_k, g, sensor)."""
    x, u_v = equilibrium_points(rec, params)
    m_k, g, k_i = params["m_k"], params["g"], params["k_i"]
    tp = two_point(x, u_v, m_k, g)
    lq = least_squares_eq14(x, u_v, m_k, g)
    out = {
        "points": {"x": x.tolist(), "u_V": u_v.tolist()},
        "two_point": {**tp, "k_c": tp["k_f"] / k_i**2},
        "least_squares": {"x_0": lq["x_0"], "k_f": lq["k_f"], "k_c": lq["k_f"] / k_i**2},
    }
    if with_simplex:
        base = {**params, "x_0": lq["x_0"], "k_c": lq["k_f"] / k_i**2}
        out["simplex"] = simplex_kfv(rec, base)
    return out
