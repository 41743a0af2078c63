"""Replaying a record in closed loop on the C plant (cffi fast path).

The record's controller and reference drive the model (:func:`maglev_cosim.loop.simulate`); the
loop starts settled at the first reading ``y[0]``: the ball at rest where the model's sensor
reads ``y[0]``, the current at equilibrium there, ``e[−1] = 0`` and the integrator holding the
equilibrium input.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import fast, formulas
from .loop import simulate
from .params import as_params, get_params
from .pid import PID
from .record import Record


def baseline_params() -> dict[str, float]:
    """FMU parameter values of the diagnosis baseline: the paper's simulation model, Section 3 with
    T_a neglected (Eq. 5), the ``baseline`` set of :mod:`maglev_cosim.params`."""
    return get_params("baseline").to_start_values()


def record_controller(rec: Record) -> PID:
    """The controller a record declares (its metadata; the paper's PID where it is silent)."""
    return PID(**rec.pid_kwargs())


def replay(rec: Record, params: Mapping[str, float], *, w: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The record's closed loop simulated with ``params`` (FMU parameter values), settled at the
    position where the model reads ``y[0]``, on the fast backend.

    Returns arrays t [s], w, u, y [MU], x [m], v [m/s], i [A]. Raises ``ValueError`` (one line
    naming the variable) for a parameter set the FMU would refuse."""
    fast.check_params(params)
    p = as_params(params)
    r = simulate(p, rec.w if w is None else w, controller=record_controller(rec), backend="fast",
                 x_op=formulas.position(p, float(rec.y[0])))
    return r.signals()
