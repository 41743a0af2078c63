"""The closed loop, once: plant + controller against a reference, on any of three backends.

:func:`simulate` is the one closed-loop simulator of the toolkit. The loop runs at the
controller's sample time ``ts``: at ``t_k`` the plant's reading ``y[k]`` is taken, the controller
computes ``u[k]``, which the D/A holds over ``[t_k, t_k + ts)``. The loop starts settled at rest at
``x_op``: the equilibrium current (limited to ``i_max``), and the controller's integrator holding
the equilibrium input.

Backends (``backend=``):

- ``"fast"``: the C plant and the C controller in one call through cffi (``c/maglev_replay.c``);
- ``"fmu"``: the FMU through fmpy, the controller in Python (what any FMI importer sees);
- ``"reference"``: the independent pure-Python plant (:mod:`maglev_cosim.plant.reference`).

All three return a :class:`LoopResponse`: python-control's ``TimeResponseData`` with the
reference ``w`` as input, ``y`` and ``u`` as outputs and ``x``, ``v``, ``i`` as states.
"""

from __future__ import annotations

import csv
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..plant.fast import param_index
from ..plant.params import PlantParams, as_params
from ..plant.reference import ReferencePlant
from . import fast_loop
from .fast_loop import settled_start_vector
from .controllers import Controller, c_settings, start as start_controller
from .fmu import FmuPlant
from .pid import PID

BACKENDS = ("fast", "fmu", "reference")
REFERENCES = ("step", "square", "sine")
#: The paper's operating point (Section 4) [m].
X_OP = 0.0032


class _Response:
    """A closed-loop time response sampled at ``t_k = k·ts`` (``LoopResponse``: these methods on
    python-control's ``TimeResponseData``, the class made when first used, :func:`__getattr__`).

    Signals by name, ``r["w"]`` and so on: input ``w`` reference [MU]; outputs ``y`` A/D reading
    [MU] and ``u`` controller output held over the next sample [MU]; states ``x`` position [m],
    ``v`` velocity [m/s], ``i`` coil current [A]; ``t`` [s]. The same arrays are python-control's
    ``.time``, ``.inputs``, ``.outputs`` and ``.states`` (named too: ``r.outputs["y"]``); ``.y``,
    ``.x``, ``.u`` keep python-control's meaning (all outputs, all states, all inputs).
    """

    def __init__(self, t: np.ndarray, w: np.ndarray, u: np.ndarray, y: np.ndarray, x: np.ndarray,
                 v: np.ndarray, i: np.ndarray, *, params: PlantParams, controller: Controller, backend: str,
                 x_op: float) -> None:
        super().__init__(np.asarray(t, float), np.vstack([y, u]), states=np.vstack([x, v, i]),
                         inputs=np.asarray(w, float), output_labels=["y", "u"], state_labels=["x", "v", "i"],
                         input_labels=["w"], title=f"CE152 closed loop ({backend})", sysname="maglev",
                         plot_inputs=True)
        self.params, self.controller, self.backend, self.x_op = params, controller, backend, float(x_op)

    def __getitem__(self, key):
        """A signal by name: ``r["y"]``, ``r["u"]``, ``r["w"]``, ``r["x"]``, ``r["v"]``, ``r["i"]``,
        ``r["t"]``; integer indices keep python-control's legacy meaning (``t, y = response``)."""
        if isinstance(key, str):
            if key in ("t", "time"):
                return self.time
            for labels, data in ((self.output_labels, self.outputs), (self.state_labels, self.states),
                                 (self.input_labels, np.atleast_2d(self.inputs))):
                if key in labels:
                    return data[labels.index(key)]
            raise KeyError(f"no signal {key!r}: the response has t, w, y, u, x, v, i")
        return super().__getitem__(key)

    def signals(self) -> dict[str, np.ndarray]:
        """``t, w, u, y, x, v, i`` by name."""
        return {k: self[k] for k in ("t", "w", "u", "y", "x", "v", "i")}

    def to_csv(self, path: str | Path, *, controller_file: str | None = None) -> Path:
        """Writes the response in the record format (docs/record-format.md): the controller as
        ``# key: value`` metadata, then ``t,w,u,y,x,v,i``. A cascade or state feedback is declared
        by the controller file it was read from, ``controller_file`` (a path relative to the
        record's folder, or a shipped controller's name)."""
        path = Path(path)
        c, sig = self.controller, self.signals()
        if not isinstance(c, PID) and controller_file is None:
            raise ValueError(f"a {type(c).__name__} is declared in a record by its controller file: pass "
                             "controller_file")
        with path.open("w", newline="") as fh:
            meta = [("ts", c.ts)] + ([("controller", controller_file)] if controller_file else [])
            if isinstance(c, PID) and controller_file is None:
                meta += [("controller", "pid"), ("kp", c.kp), ("ki", c.ki), ("kd", c.kd), ("u_min", c.u_min),
                         ("u_max", c.u_max)]
                meta += [("tf", c.tf), ("anti_windup", c.anti_windup)] if c.tf or c.anti_windup != "none" else []
                meta += [("derivative", c.derivative)] if c.derivative != "error" else []
            for k, v in meta:
                fh.write(f"# {k}: {v}\n")
            wr = csv.writer(fh)
            wr.writerow(["t", "w", "u", "y", "x", "v", "i"])
            for row in zip(*(sig[k] for k in ("t", "w", "u", "y", "x", "v", "i"))):
                wr.writerow([f"{row[0]:.6f}", *(f"{v:.17g}" for v in row[1:])])
        return path



if TYPE_CHECKING:
    import control

    class LoopResponse(_Response, control.TimeResponseData):
        """What :func:`__getattr__` makes (for the type checkers)."""


_made: dict[str, type] = {}
_making = threading.Lock()


def __getattr__(name: str) -> type:
    """``LoopResponse``: python-control's ``TimeResponseData`` with :class:`_Response`'s methods, made
    on first use. Its base is why: importing python-control loads matplotlib.pyplot too, half a second
    that a diagnosis, which never simulates through here, need not pay at its start."""
    if name != "LoopResponse":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    with _making:
        if name not in _made:
            import control

            _made[name] = type("LoopResponse", (_Response, control.TimeResponseData),
                               {"__module__": __name__, "__qualname__": "LoopResponse", "__doc__": _Response.__doc__})
        return _made[name]


def reference_signal(kind: str, duration: float, ts: float = 1e-3, *, base: float, amplitude: float,
                     t_step: float = 0.1, period: float = 3.0) -> np.ndarray:
    """A position reference ``w`` [MU] lasting ``duration`` [s], sampled at ``ts`` [s].

    ``step``: ``base`` until ``t_step`` [s], then ``base + amplitude``. ``square``: period
    ``period`` [s] (3 s, as in Section 5), ``base`` for the first half period, then
    ``base + amplitude``. ``sine``: ``base + amplitude·sin(2π t / period)``.
    """
    n = int(round(duration / ts))
    if n < 1:
        raise ValueError(f"duration {duration} s holds no sample at ts = {ts} s")
    t = np.arange(n) * ts
    if kind == "step":
        return np.where(t >= t_step - 1e-12, base + amplitude, base)
    if kind == "square":
        phase = np.floor(t / (period / 2) + 1e-9).astype(int) % 2
        return base + amplitude * phase
    if kind == "sine":
        return base + amplitude * np.sin(2 * np.pi * t / period)
    raise ValueError(f"unknown reference {kind!r}: choose one of {', '.join(REFERENCES)}")


def settled_start(p: PlantParams, x_op: float) -> tuple[PlantParams, float]:
    """The plant at rest at ``x_op`` [m] with the equilibrium current (limited to ``i_max``), and
    the D/A input [MU] that holds it there."""
    start, u_hold = settled_start_vector(p, x_op)
    return p.replace(x_start=x_op, v_start=0.0, i_start=start[param_index()["i_start"]]), u_hold


def simulate(params: PlantParams | str | Mapping[str, float] | None, w: np.ndarray, *,
             controller: Controller | None = None, backend: str = "fast", x_op: float | None = None,
             fmu: str | Path | None = None, y_before: float | None = None) -> LoopResponse:
    """The closed loop of plant and controller against reference ``w``.

    Parameters
    ----------
    params : PlantParams, str, mapping or None
        The plant: a :class:`PlantParams`, a named set (``"section3"``, ``"eq18"``,
        ``"baseline"``), or FMU parameter values [SI units] over the Section 3 set.
    w : array_like
        Reference [MU], one value per controller sample.
    controller : PID, Cascade or StateFeedback, optional
        The controller (:mod:`maglev_cosim.loop.controllers`; default: the paper's PID, Eq. 24/25, at
        1 kHz). A cascade or a state feedback also reads the plant's coil current.
    backend : {"fast", "fmu", "reference"}
        Which implementation of the plant runs the loop (module docstring).
    x_op : float, optional
        Settled start position [m] (default 3.2 mm, the paper's Section 4).
    fmu : path, optional
        The FMU for ``backend="fmu"`` (default: the installed or built ``maglev.fmu``); FMI 2.0 or
        3.0 (``maglev_cosim.fmu_path(fmi_version=3)``), whichever its model description says.
    y_before : float, optional
        The reading [MU] at which the loop stood before t = 0, the error ``w[0] − y_before``
        standing and the controller's output holding the plant (a record cut from a running loop,
        as the diagnosis replays one). Default: at zero error, so a reference that steps at t = 0
        acts at the first sample.

    Returns
    -------
    LoopResponse
        ``t`` [s], ``w``, ``y``, ``u`` [MU], ``x`` [m], ``v`` [m/s], ``i`` [A].

    Examples
    --------
    >>> from maglev_cosim.loop.simulate import simulate, reference_signal
    >>> w = reference_signal("step", 1.0, base=0.394, amplitude=0.05)
    >>> r = simulate("section3", w)
    >>> round(float(r["y"][-1]), 2)
    0.44
    """
    p = as_params(params)
    controller = controller or PID()
    c_settings(controller)  # a TypeError for anything else
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}: choose one of {', '.join(BACKENDS)}")
    w = np.asarray(w, dtype=float)
    if w.ndim != 1 or len(w) == 0 or not np.all(np.isfinite(w)):
        raise ValueError("reference w must be a non-empty 1-D array of finite values [MU]")
    x_op = X_OP if x_op is None else float(x_op)
    if not p.x_min <= x_op <= p.x_max:
        raise ValueError(f"x_op = {x_op * 1e3:g} mm lies outside the stops [{p.x_min * 1e3:g}, {p.x_max * 1e3:g}] mm")
    start, u_hold = settled_start(p, x_op)
    run = {"fast": _run_fast, "fmu": _run_fmu, "reference": _run_reference}[backend]
    sig = run(start, controller, w, u_hold, fmu, y_before)
    t = np.arange(len(w)) * controller.ts
    return __getattr__("LoopResponse")(t, w, sig["u"], sig["y"], sig["x"], sig["v"], sig["i"], params=p,
                        controller=controller, backend=backend, x_op=x_op)


def _run_fast(start: PlantParams, c: Controller, w: np.ndarray, u_hold: float, fmu,
              y_before: float | None) -> dict[str, np.ndarray]:
    return fast_loop.closed_loop(start, w, pid=c, u_hold=u_hold, y_before=y_before)


def _stepwise(plant_outputs, set_input, step, c: Controller, w: np.ndarray, u_hold: float,
              y_before: float | None) -> dict[str, np.ndarray]:
    """The loop with the controller in Python, for the plants stepped from Python."""
    n = len(w)
    out = {k: np.empty(n) for k in ("u", "y", "x", "v", "i")}
    _, x0, v0, i0 = plant_outputs()
    ctl = start_controller(c, u_hold, (x0, v0, i0), float(w[0]), y_before)
    for k in range(n):
        yk, out["x"][k], out["v"][k], out["i"][k] = plant_outputs()
        out["y"][k] = yk
        uk = ctl.step(w[k], yk, out["i"][k])
        out["u"][k] = uk
        set_input(uk)
        step(c.ts)
    return out


def _run_fmu(start: PlantParams, c: Controller, w: np.ndarray, u_hold: float, fmu,
             y_before: float | None) -> dict[str, np.ndarray]:
    with FmuPlant({**start.to_start_values(), "u": u_hold}, fmu=fmu) as plant:
        return _stepwise(plant.outputs, plant.set_input, plant.step, c, w, u_hold, y_before)


def _run_reference(start: PlantParams, c: Controller, w: np.ndarray, u_hold: float, fmu,
                   y_before: float | None) -> dict[str, np.ndarray]:
    plant = ReferencePlant(start)
    plant.reset(u_hold)

    def outputs() -> tuple[float, float, float, float]:
        o = plant.outputs()
        return o["y"], o["x"], o["v"], o["i"]

    return _stepwise(outputs, plant.set_input, plant.step, c, w, u_hold, y_before)
