"""Jacobians for ``scipy.optimize.least_squares`` whose columns are replays run side by side.

:func:`difference_jacobian` gives ``(fun, jac)``: ``jac`` is scipy's forward-difference Jacobian
(``approx_derivative`` with ``method="2-point"``, :func:`steps`) with its columns
evaluated by ``map_fn`` (the replays release the GIL, so threads use the cores). With ``refresh`` > 1
the differences are taken at the first point ``least_squares`` asks for and at every
``refresh``-th after it; at the points between, Broyden's rank-one update of the last Jacobian from
the last two points asked (``least_squares`` asks at its accepted points, whose residuals it has just
evaluated) replaces them at no replay. The update is the least change, in the coordinates divided by
``scale`` (``least_squares``'s ``x_scale``), that maps the step onto the change of the residuals
(Dennis and Schnabel, *Numerical Methods for Unconstrained Optimization*, 1983, section 8.1).
``jac.differences(z)`` is the difference Jacobian at ``z`` whatever ``refresh`` says: standard errors
need it at the solution. :func:`parameter_columns` differentiates a function of named parameter values
at their typical sizes (the CE152 standard errors and the k-step screen)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence

import numpy as np

Residuals = Callable[[np.ndarray], np.ndarray]

#: scipy's fallback relative step for forward differences, sqrt of the machine epsilon.
_EPS_2POINT = float(np.finfo(float).eps) ** 0.5


def steps(z: np.ndarray, lo: np.ndarray, hi: np.ndarray, rel_step: float, unit_floor: bool = False) -> np.ndarray:
    """The forward-difference steps of scipy's ``approx_derivative(method="2-point", rel_step=...)``:
    ``rel_step·|z|`` with the sign of ``z`` (``+`` at 0), or ``sqrt(eps)·max(1, |z|)`` where that step
    vanishes in ``z + h``; reversed where it would leave the bounds and fits on the other side, else
    as far as the farther bound. ``unit_floor``: ``rel_step·max(1, |z|)`` instead (a coordinate near 0
    still moves by ``rel_step``)."""
    sign = (z >= 0).astype(float) * 2 - 1
    if unit_floor:
        h = rel_step * sign * np.maximum(1.0, np.abs(z))
    else:
        h = rel_step * sign * np.abs(z)
        h = np.where((z + h) - z == 0, _EPS_2POINT * sign * np.maximum(1.0, np.abs(z)), h)
    lower, upper = z - lo, hi - z
    violated = (z + h < lo) | (z + h > hi)
    fitting = np.abs(h) <= np.maximum(lower, upper)
    h = np.where(violated & fitting, -h, h)
    h = np.where((upper >= lower) & ~fitting, upper, h)
    return np.where((upper < lower) & ~fitting, -lower, h)


def difference_jacobian(fun: Residuals, lo: np.ndarray, hi: np.ndarray, rel_step: float, *,
                        map_fn: Callable[[Callable, Iterable], Sequence] = lambda f, xs: [f(x) for x in xs],
                        refresh: int = 1, scale: np.ndarray | float | None = None,
                        unit_floor: bool = False) -> tuple[Residuals, Callable]:
    """``(fun, jac)`` for ``least_squares(fun, z0, jac=jac, bounds=(lo, hi))`` (module docstring).

    Parameters
    ----------
    fun : callable
        The residuals of the coordinates ``z`` (a 1-D array).
    lo, hi : ndarray
        The bounds of ``z``.
    rel_step : float
        The difference step relative to ``|z|`` (``least_squares``'s ``diff_step``), or to
        ``max(1, |z|)`` with ``unit_floor``.
    map_fn : callable
        ``map_fn(f, items)``: ``[f(x) for x in items]`` in order, side by side where it can.
    refresh : int
        Differences at the first call and every ``refresh``-th after it; Broyden's update between.
    scale : ndarray or float, optional
        The coordinates' scale (``least_squares``'s ``x_scale``) in which the update is the least.
    unit_floor : bool
        The step relative to ``max(1, |z|)`` instead of ``|z|`` (:func:`steps`).

    Returns
    -------
    fun : callable
        ``fun`` remembering its last point (``jac`` at that point needs no replay for it).
    jac : callable
        The Jacobian; ``jac.differences(z)`` the difference one whatever ``refresh`` says.
    """
    last: dict[bytes, np.ndarray] = {}
    memo: dict = {"calls": 0}
    s2 = np.ones(len(lo)) if scale is None else np.broadcast_to(np.asarray(scale, float) ** 2, (len(lo),))

    def f(z: np.ndarray) -> np.ndarray:
        v = fun(z)
        last.clear()
        last[z.tobytes()] = v
        return v

    def at(z: np.ndarray) -> np.ndarray:
        f0 = last.get(z.tobytes())
        return f(z) if f0 is None else f0

    def differences(z: np.ndarray) -> np.ndarray:
        f0 = at(z)
        h = steps(z, lo, hi, rel_step, unit_floor)

        def column(k: int) -> np.ndarray:
            zk = z.copy()
            zk[k] = z[k] + h[k]
            return (fun(zk) - f0) / ((z[k] + h[k]) - z[k])

        return np.stack(list(map_fn(column, range(len(z)))), axis=1)

    def jac(z: np.ndarray) -> np.ndarray:
        f0 = at(z)
        k = memo["calls"]
        memo["calls"] += 1
        J = memo.get("J")
        dz = z - memo["z"] if J is not None else None
        if refresh > 1 and k % refresh and dz is not None and np.any(dz != 0):
            w = dz / s2
            J = J + np.outer(f0 - memo["f"] - J @ dz, w) / float(dz @ w)
        else:
            J = differences(z)
        memo.update(z=z.copy(), f=f0, J=J)
        return J

    jac.differences = differences
    return f, jac


def gauss_newton_step(J: np.ndarray, f: np.ndarray, z: np.ndarray, lo: np.ndarray,
                      hi: np.ndarray) -> tuple[np.ndarray, float]:
    """The Gauss-Newton step of ``J`` from ``z`` (the linearised residuals ``f + J·step`` at their
    least squares), with the coordinates whose step would cross a bound held where they are, and
    the fall of the cost ½|f|² it promises."""
    free = np.ones(len(z), bool)
    for _ in range(len(z) + 1):
        step = np.zeros(len(z))
        if free.any():
            step[free] = np.linalg.lstsq(J[:, free], -f, rcond=None)[0]
        out = free & ((z + step < lo) | (z + step > hi))
        if not out.any():
            break
        free &= ~out
    return step, float(0.5 * (f @ f) - 0.5 * np.sum((f + J @ step) ** 2))


def gauss_newton_gain(J: np.ndarray, f: np.ndarray, z: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """The fall of the cost ½|f|² that the Gauss-Newton step of ``J`` promises from ``z``
    (:func:`gauss_newton_step`). Near 0 at a fit's optimum; a fit that stopped short (an
    approximate Jacobian) leaves more."""
    return gauss_newton_step(J, f, z, lo, hi)[1]


def parameter_columns(fun: Callable[[dict[str, float]], np.ndarray], values: Mapping[str, float],
                      scales: Mapping[str, float], f0: np.ndarray, *, rel: float = 1e-4,
                      map_fn: Callable[[Callable, Iterable], Sequence] = lambda f, xs: [f(x) for x in xs],
                      ) -> np.ndarray:
    """The forward-difference Jacobian of ``fun`` (residuals of named parameter ``values``; ``f0`` at
    ``values``) over the parameters of ``scales``: a step of ``rel`` times each one's scale (its typical
    size), each column per unit of that scale, the columns side by side with ``map_fn`` (one call of
    ``fun`` each)."""
    def column(name: str) -> np.ndarray:
        h = rel * scales[name]
        return (fun({**values, name: values[name] + h}) - f0) / (h / scales[name])

    return np.column_stack(list(map_fn(column, list(scales))))
