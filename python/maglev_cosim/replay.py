"""Replaying a record in closed loop on the C plant (cffi fast path).

The record's controller and reference drive the model; the loop starts settled at the first
reading ``y[0]``: the ball at rest where the model's sensor reads ``y[0]``, the current at
equilibrium there, ``e[−1] = 0`` and the integrator holding the equilibrium input.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import fast, formulas
from .record import Record

#: The diagnosis baseline: the paper's simulation model, Section 3 with T_a neglected (Eq. 5).
BASELINE_OVERRIDES = {"T_a": 0.0}


def baseline_params() -> dict[str, float]:
    """FMU parameter values of the diagnosis baseline (C defaults with ``T_a = 0``)."""
    return {**fast.default_params(), **BASELINE_OVERRIDES}


def settled_start(p: Mapping[str, float], y0: float) -> tuple[dict[str, float], float]:
    """Start values (x_start, v_start, i_start) and the equilibrium input u_hold [MU] for a loop
    settled at reading ``y0`` [MU] (the position where the model reads ``y0`` at t = 0)."""
    x = formulas.position(p, y0)
    i = min(formulas.point(p, x).i, p["i_max"])
    u_hold = formulas.point(p, x, i).u
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
