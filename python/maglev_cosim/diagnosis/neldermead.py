"""Nelder-Mead with the points it may need evaluated side by side.

scipy's Nelder-Mead (``minimize(method="Nelder-Mead")``, not adaptive, no bounds) evaluates one point
at a time: the reflection, then, depending on its cost, the expansion or one of the two contractions.
A replay of a 15 s record costs 40-80 ms, and a fit of 30 evaluations left the second core idle.
:func:`nelder_mead` walks the same path, to the bit, but evaluates the reflection together with the
second point the step is likely to need (the kind the previous step needed), the starting simplex's
vertices together, and a shrink's vertices together. A guess the step does not need is thrown away
and not counted: the evaluations counted against ``maxfev``, the points accepted and the result are
scipy's (``tests/test_neldermead.py`` compares them).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

#: scipy's coefficients without ``adaptive``: reflection, expansion, contraction, shrink.
RHO, CHI, PSI, SIGMA = 1.0, 2.0, 0.5, 0.5


@dataclass
class NelderMeadResult:
    """``x``: the best vertex; ``fun``: its cost; ``nfev``: the evaluations scipy would count;
    ``evaluated``: all evaluations made (the guesses not needed included)."""

    x: np.ndarray
    fun: float
    nfev: int
    evaluated: int


def nelder_mead(fun: Callable[[np.ndarray], float], simplex: Sequence[Sequence[float]], *, maxfev: int,
                xatol: float = 1e-4, fatol: float = 1e-4,
                map_fn: Callable[[Callable, list], list] | None = None) -> NelderMeadResult:
    """Minimises ``fun`` from the ``initial_simplex`` ``simplex`` ((N+1) x N) as
    ``scipy.optimize.minimize(fun, simplex[0], method="Nelder-Mead", options={"maxfev": maxfev,
    "xatol": xatol, "fatol": fatol, "initial_simplex": simplex})`` does, with ``map_fn(f, points)``
    (``[f(p) for p in points]``, in order; default: that loop) evaluating the points it may need
    together. ``fun`` must be deterministic (the same point, the same cost)."""
    run = map_fn or (lambda f, xs: [f(x) for x in xs])
    sim = np.array(simplex, dtype=float)
    if sim.ndim != 2 or sim.shape[0] != sim.shape[1] + 1:
        raise ValueError("the simplex must be (N+1) x N")
    n = sim.shape[1]
    calls = [0, 0]   # counted as scipy counts, all made

    def evaluate(points: list[np.ndarray]) -> list[float]:
        calls[1] += len(points)
        return [float(v) for v in run(lambda p: fun(np.copy(p)), points)]

    fsim = np.full(n + 1, np.inf)
    first = min(n + 1, maxfev)
    fsim[:first] = evaluate([sim[k] for k in range(first)])
    calls[0] = first
    order = np.argsort(fsim)
    sim, fsim = sim[order], fsim[order]
    guess = "contract_in"
    while calls[0] < maxfev:
        if np.max(np.abs(sim[1:] - sim[0])) <= xatol and np.max(np.abs(fsim[0] - fsim[1:])) <= fatol:
            break
        xbar = np.add.reduce(sim[:-1], 0) / n
        xr = (1 + RHO) * xbar - RHO * sim[-1]
        second = {"expand": (1 + RHO * CHI) * xbar - RHO * CHI * sim[-1],
                  "contract_out": (1 + PSI * RHO) * xbar - PSI * RHO * sim[-1],
                  "contract_in": (1 - PSI) * xbar + PSI * sim[-1]}
        # the reflection and the guessed second point together, while scipy would make the second call
        both = calls[0] + 2 <= maxfev
        got = evaluate([xr, second[guess]] if both else [xr])
        fxr = got[0]
        calls[0] += 1
        known = {guess: got[1]} if both else {}

        def cost_of(kind: str) -> float | None:
            """The second point's cost, or None where scipy's call would exceed ``maxfev``."""
            if calls[0] >= maxfev:
                return None
            calls[0] += 1
            if kind not in known:
                known[kind] = evaluate([second[kind]])[0]
            return known[kind]

        shrink = False
        if fxr < fsim[0]:
            need = "expand"
            fxe = cost_of(need)
            if fxe is None:
                break
            if fxe < fxr:
                sim[-1], fsim[-1] = second[need], fxe
            else:
                sim[-1], fsim[-1] = xr, fxr
        elif fxr < fsim[-2]:
            need = None
            sim[-1], fsim[-1] = xr, fxr
        elif fxr < fsim[-1]:
            need = "contract_out"
            fxc = cost_of(need)
            if fxc is None:
                break
            if fxc <= fxr:
                sim[-1], fsim[-1] = second[need], fxc
            else:
                shrink = True
        else:
            need = "contract_in"
            fxcc = cost_of(need)
            if fxcc is None:
                break
            if fxcc < fsim[-1]:
                sim[-1], fsim[-1] = second[need], fxcc
            else:
                shrink = True
        if need is not None:
            guess = need
        if shrink:
            # scipy moves each vertex, then evaluates it, until a call would exceed maxfev: the
            # vertex whose call fails is moved but keeps its old cost
            allowed = max(0, min(n, maxfev - calls[0]))
            for j in range(1, n + 1):
                sim[j] = sim[0] + SIGMA * (sim[j] - sim[0])
                if j > allowed:
                    break
            if allowed:
                fsim[1: allowed + 1] = evaluate([sim[j] for j in range(1, allowed + 1)])
                calls[0] += allowed
        order = np.argsort(fsim)
        sim, fsim = sim[order], fsim[order]
    return NelderMeadResult(x=sim[0].copy(), fun=float(np.min(fsim)), nfev=calls[0], evaluated=calls[1])
