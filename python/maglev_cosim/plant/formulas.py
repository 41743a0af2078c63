"""The plant's formulas besides the simulation, computed by the C plant so that they live once.

The equilibrium current (Eq. 8 at rest), the D/A input giving a current (Eq. 1, 5), the sensor
reading (Eq. 12, 13) and its inverse, and the force and sensor slopes of the linearisation
(Eq. 16, 17) are functions of ``c/maglev_plant.c``; this module calls them through the cffi
fast path. The independent cross-checks (``reference.py``, the rig emulator ``rig.py``) keep
their own code on purpose.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from . import fast

if TYPE_CHECKING:
    from .params import PlantParams


@dataclass(frozen=True)
class Point:
    """The plant at position ``x`` [m] with current ``i`` [A]: ``u`` the D/A input giving ``i``
    [MU], ``y`` the noise-free reading [MU] (both before the converters' limits), ``F`` the static
    force [N], ``dF_dx`` [N/m], ``dF_di`` [N/A] (Eq. 16, 17) and ``dy_dx`` the reading's slope [MU/m]."""

    x: float
    i: float
    u: float
    y: float
    F: float
    dF_dx: float
    dF_di: float
    dy_dx: float


def _call(fn_name: str, params, *args):
    m = fast._lib()
    pv = fast.param_vector(params)
    msg = m.ffi.new("char[256]")
    rc = getattr(m.lib, fn_name)(m.ffi.cast("double *", m.ffi.from_buffer(pv)), *args, msg, 256)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())


def point(params: PlantParams | Mapping[str, float] | np.ndarray | None, x: float, i: float | None = None) -> Point:
    """The plant's formulas at ``x`` [m] and current ``i`` [A] (default: the equilibrium current,
    Eq. 8 at rest). ``params``: a :class:`PlantParams`, FMU parameter values over the C defaults,
    or a parameter vector (:func:`maglev_cosim.plant.fast.param_vector`)."""
    m = fast._lib()
    out = m.ffi.new("MaglevPoint *")
    _call("maglev_replay_point", params, float(x), math.nan if i is None else float(i), out)
    return Point(*(float(getattr(out, f)) for f in Point.__dataclass_fields__))


def forces(params: PlantParams | Mapping[str, float] | np.ndarray | None, x, i) -> np.ndarray:
    """The static forces [N] at positions ``x`` [m] with currents ``i`` [A]: ``point(params, x, i).F`` for
    each (a current that is NaN: the equilibrium current), in one C call."""
    m = fast._lib()
    x, i = np.broadcast_arrays(np.atleast_1d(np.asarray(x, dtype=float)), np.atleast_1d(np.asarray(i, dtype=float)))
    x, i = np.ascontiguousarray(x), np.ascontiguousarray(i)
    out = np.empty_like(x)
    ptr = lambda v: m.ffi.cast("double *", m.ffi.from_buffer(v))  # noqa: E731
    _call("maglev_replay_forces", params, ptr(x), ptr(i), len(x), ptr(out))
    return out


def readings(params: PlantParams | Mapping[str, float] | np.ndarray | None, x, t: float = 0.0) -> np.ndarray:
    """The noise-free readings [MU] at positions ``x`` [m] and time ``t`` [s] (Eq. 12, 13): ``point(params,
    x).y`` for each, in one C call."""
    return _elementwise("maglev_replay_readings", params, x, t)


def positions(params: PlantParams | Mapping[str, float] | np.ndarray | None, y, t: float = 0.0) -> np.ndarray:
    """Positions [m] between the stops where the model reads ``y`` [MU] at time ``t`` [s] (Eq. 12,
    13 inverted, ``k_x2`` and the pickup included); readings beyond the travel give the nearest stop."""
    return _elementwise("maglev_replay_positions", params, y, t)


def _elementwise(entry: str, params, a, t: float) -> np.ndarray:
    """One C call of ``entry`` (readings from positions, or the inverse) over the array ``a``."""
    m = fast._lib()
    a = np.ascontiguousarray(np.atleast_1d(np.asarray(a, dtype=float)))
    out = np.empty_like(a)
    ptr = lambda v: m.ffi.cast("double *", m.ffi.from_buffer(v))  # noqa: E731
    _call(entry, params, ptr(a), len(a), float(t), ptr(out))
    return out


def position(params: PlantParams | Mapping[str, float] | np.ndarray | None, y: float, t: float = 0.0) -> float:
    """:func:`positions` for one reading."""
    return float(positions(params, [y], t)[0])


def equilibrium_input(p: Mapping[str, float]) -> float:
    """D/A input [MU] holding the ball at rest at ``x_start`` (Eq. 8 at rest, Eq. 1, 5)."""
    return point(p, p["x_start"]).u


__all__ = ["Point", "equilibrium_input", "forces", "point", "position", "positions"]
