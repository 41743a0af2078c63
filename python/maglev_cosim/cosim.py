"""Closed-loop co-simulation: the plant FMU driven through fmpy by the paper's discrete PID.

The loop runs at the controller's sample time ``ts``: at ``t_k`` the FMU's ``y`` is read,
the PID (Eq. 24/25) computes ``u[k]``, which is set on the FMU and held over
``[t_k, t_k + ts)`` by one ``fmi2DoStep``. The loop starts settled at rest at a chosen
position, with the PID's integrator preloaded to the equilibrium input.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .fmu import FmuPlant
from .linear import operating_point
from .params import PlantParams, get_params
from .pid import DiscretePID, PIDConfig

REFERENCES = ("step", "square", "sine")


def resolve_params(params: PlantParams | str | Mapping[str, float] | None) -> PlantParams:
    """A :class:`PlantParams` from a set name, a mapping of overrides of the Section 3 set, or itself."""
    if params is None:
        return get_params("section3")
    if isinstance(params, str):
        return get_params(params)
    if isinstance(params, PlantParams):
        return params
    return get_params("section3").replace(**dict(params))


def reference_signal(kind: str, n: int, ts: float, *, base: float, amplitude: float,
                     t_step: float = 0.1, period: float = 3.0) -> np.ndarray:
    """A position reference ``w`` [MU] of ``n`` samples at ``ts`` [s].

    ``step``: ``base`` until ``t_step``, then ``base + amplitude``. ``square``: period ``period``
    (3 s, as in Section 5), ``base`` for the first half period, then ``base + amplitude``.
    ``sine``: ``base + amplitude·sin(2π t / period)``.
    """
    t = np.arange(n) * ts
    if kind == "step":
        return np.where(t >= t_step - 1e-12, base + amplitude, base)
    if kind == "square":
        phase = np.floor(t / (period / 2) + 1e-9).astype(int) % 2
        return base + amplitude * phase
    if kind == "sine":
        return base + amplitude * np.sin(2 * np.pi * t / period)
    raise ValueError(f"unknown reference {kind!r}: choose one of {', '.join(REFERENCES)}")


@dataclass
class ClosedLoopResult:
    """A closed-loop time response; arrays sampled at ``t_k = k·ts``.

    ``w`` reference [MU], ``u`` controller output held over the next sample [MU], ``y`` A/D
    reading [MU], ``x`` position [m], ``v`` velocity [m/s], ``i`` current [A].
    """

    t: np.ndarray
    w: np.ndarray
    u: np.ndarray
    y: np.ndarray
    x: np.ndarray
    v: np.ndarray
    i: np.ndarray
    params: PlantParams
    pid: PIDConfig
    x_op: float
    meta: dict = field(default_factory=dict)

    def to_csv(self, path: str | Path) -> Path:
        """Writes the response in the record format (``# key: value`` metadata, then ``t,w,u,y,x,v,i``)."""
        path = Path(path)
        with path.open("w", newline="") as fh:
            for k, v in (("ts", self.pid.ts), ("controller", "pid"), ("kp", self.pid.kp), ("ki", self.pid.ki),
                         ("kd", self.pid.kd), ("u_min", self.pid.u_min), ("u_max", self.pid.u_max)):
                fh.write(f"# {k}: {v}\n")
            wr = csv.writer(fh)
            wr.writerow(["t", "w", "u", "y", "x", "v", "i"])
            for row in zip(self.t, self.w, self.u, self.y, self.x, self.v, self.i):
                wr.writerow([f"{row[0]:.6f}", *(f"{v:.17g}" for v in row[1:])])
        return path


def simulate_closed_loop(w: np.ndarray, *, params: PlantParams | str | Mapping[str, float] | None = None,
                         x_op: float = 0.0032, pid: PIDConfig | None = None,
                         fmu: str | Path | None = None) -> ClosedLoopResult:
    """Runs the FMU in closed loop with the discrete PID (Eq. 24/25) against reference ``w`` [MU].

    The plant starts at rest at ``x_op`` [m] with the equilibrium current, and the PID's
    integrator holds the equilibrium input (the loop is settled before ``t = 0``).
    ``params``: a set name (``"section3"``, ``"eq18"``, ``"baseline"``), overrides of the
    Section 3 set, or a :class:`PlantParams`.
    """
    p = resolve_params(params)
    pid = pid or PIDConfig()
    w = np.asarray(w, dtype=float)
    if w.ndim != 1 or len(w) == 0 or not np.all(np.isfinite(w)):
        raise ValueError("reference w must be a non-empty 1-D array of finite values [MU]")
    op = operating_point(p, x_op)
    start = p.replace(x_start=x_op, v_start=0.0, i_start=op.i).to_start_values()
    start["u"] = op.u_MU
    n = len(w)
    u = np.empty(n)
    y = np.empty(n)
    x = np.empty(n)
    v = np.empty(n)
    i = np.empty(n)
    ctl = DiscretePID(pid)
    ctl.reset(op.u_MU)
    ts = pid.ts
    with FmuPlant(start, fmu=fmu) as plant:
        outputs, set_input, step, pid_step = plant.outputs, plant.set_input, plant.step, ctl.step
        for k in range(n):
            yk, x[k], v[k], i[k] = outputs()
            y[k] = yk
            uk = pid_step(w[k], yk)
            u[k] = uk
            set_input(uk)
            step(ts)
    return ClosedLoopResult(np.arange(n) * ts, w, u, y, x, v, i, p, pid, x_op)
