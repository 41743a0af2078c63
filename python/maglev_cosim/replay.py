"""Replaying a record in closed loop on the C plant (cffi fast path).

The record's controller and reference drive the model; the loop starts settled at the first
reading ``y[0]``: the ball at rest where the model's sensor reads ``y[0]``, the current at
equilibrium there, ``e[−1] = 0`` and the integrator holding the equilibrium input.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from . import fast
from .record import Record

#: The diagnosis baseline: the paper's simulation model, Section 3 with T_a neglected (Eq. 5).
BASELINE_OVERRIDES = {"T_a": 0.0}


def baseline_params() -> dict[str, float]:
    """FMU parameter values of the diagnosis baseline (C defaults with ``T_a = 0``)."""
    return {**fast.default_params(), **BASELINE_OVERRIDES}


def position_for_reading(p: Mapping[str, float], y_mu: float) -> float:
    """The position x [m] at which the model's sensor (Eq. 12 with ``k_x2``, Eq. 13) reads ``y_mu``
    [MU] at t = 0, limited to the stops."""
    volts = (y_mu - p["y_MU0"]) / p["k_AD"] - p["y_0"] - p["A_d"] * math.sin(p["phi_d"])
    a, b = p["k_x2"], p["k_x"] - p["k_x2"] * p["x_cal"]
    if abs(a) < 1e-12 * abs(b) / max(abs(volts / b), 1e-12):
        x = volts / b
    else:
        disc = max(b * b + 4 * a * volts, 0.0)
        roots = ((-b + math.sqrt(disc)) / (2 * a), (-b - math.sqrt(disc)) / (2 * a))
        x = min(roots, key=lambda r: abs(r - volts / b))
    return min(max(x, p["x_min"]), p["x_max"])


def settled_start(p: Mapping[str, float], y0: float) -> tuple[dict[str, float], float]:
    """Start values (x_start, v_start, i_start) and the equilibrium input u_hold [MU] for a loop
    settled at reading ``y0``."""
    x = position_for_reading(p, y0)
    i = (p["x_0"] - x) * math.sqrt(p["m_k"] * p["g"] / p["k_c"])      # Eq. 8 at rest
    i = min(i, p["i_max"])
    u_hold = (i / p["k_i"] - p["u_0"]) / p["k_DA"]                      # Eq. 1, 5
    return {"x_start": x, "v_start": 0.0, "i_start": i}, u_hold


def replay(rec: Record, params: Mapping[str, float], *, w: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The record's closed loop simulated with ``params`` (complete FMU parameter values).

    Returns arrays t [s], w, u, y [MU], x [m], v [m/s], i [A]. Raises ``ValueError`` (one line
    naming the variable) for a parameter set the FMU would refuse."""
    fast.check_params(params)
    p = dict(params)
    start, u_hold = settled_start(p, float(rec.y[0]))
    p.update(start)
    return fast.closed_loop(p, rec.w if w is None else w, ts=rec.ts, kp=rec.kp, ki=rec.ki, kd=rec.kd,
                            u_min=rec.u_min, u_max=rec.u_max, u_hold=u_hold)
