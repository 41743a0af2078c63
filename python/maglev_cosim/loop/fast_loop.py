"""The closed loop (plant + any controller) and the prediction-error replay in one C call each:
the half of the fast path (:mod:`maglev_cosim.plant.fast`, ``c/maglev_replay.h``) that takes a
controller (:data:`maglev_cosim.loop.controllers.Controller`), converted here to its C settings."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import SimpleNamespace

import numpy as np

from ..plant import fast, formulas
from ..plant.params import PlantParams
from .controllers import Controller, c_settings
from .pid import PID


def _controller(m: SimpleNamespace, controller, y_before: float | None = None):
    """Any controller (:data:`maglev_cosim.loop.controllers.Controller`) as a C ``MaglevController``,
    settled before t = 0 at zero error (``y_before`` None) or at the reading ``y_before`` [MU] with
    the error ``w[0] − y_before`` standing (``from_reading``, ``c/maglev_replay.h``)."""
    settings = c_settings(controller or PID())
    if y_before is not None:
        settings = {**settings, "from_reading": 1, "y_before": float(y_before)}
    return m.ffi.new("MaglevController *", settings)


def closed_loop(params: PlantParams | Mapping[str, float] | None, w: np.ndarray, *,
                pid: Controller | None = None, u_hold: float | None = None, du: np.ndarray | None = None,
                dF: np.ndarray | None = None, dy: np.ndarray | None = None, y_step: float = 0.0,
                u_step: float = 0.0, y_before: float | None = None) -> dict[str, np.ndarray]:
    """The closed loop (plant + controller) over reference ``w`` [MU] in one C call: the low
    level of :func:`maglev_cosim.loop.simulate.simulate` (``backend="fast"``), which most callers want.

    ``params``: a :class:`PlantParams` or FMU parameter values over the C defaults, the start
    state included. ``pid``: the controller, any :data:`maglev_cosim.loop.controllers.Controller`
    (default: the paper's PID, Eq. 24/25). ``u_hold`` [MU]: the settled
    input before t = 0 (default: the equilibrium input at ``x_start``). ``du`` [MU], ``dF`` [N],
    ``dy`` [MU]: signals injected at the actuator (added to the controller's output on its way to
    the plant), on the ball (a force held over each sample) and at the sensor (added to the
    reading), each of the length of ``w`` or None. ``y_step``, ``u_step`` [MU]: the A/D and D/A
    steps to which the reading and the controller's output are rounded (0: no rounding).
    ``y_before`` [MU]: the reading at which the loop stood before t = 0, its error ``w[0] − y_before``
    standing (a record cut from a running loop); None: at zero error (a reference step at t = 0 acts
    at the first sample). Returns arrays ``t`` [s], ``w``, ``u`` (the
    controller's output), ``y`` [MU], ``x`` [m], ``v`` [m/s], ``i`` [A]."""
    m = fast._lib()
    pv = fast._param_vector(fast._as_mapping(params))
    pid = pid or PID()
    w = np.ascontiguousarray(w, dtype=float)
    n = len(w)
    if u_hold is None:
        u_hold = formulas.equilibrium_input(dict(zip(fast._defaults(), pv)))
    out = {k: np.empty(n) for k in ("u", "y", "x", "v", "i")}
    cpid = _controller(m, pid, y_before)
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    inj = []
    for name, a in (("du", du), ("dF", dF), ("dy", dy)):
        if a is None:
            inj.append(m.ffi.NULL)
            continue
        a = np.ascontiguousarray(a, dtype=float)
        if a.shape != (n,):
            raise ValueError(f"{name} has shape {a.shape}, the reference has {n} samples")
        inj.append(ptr(a))
    rc = m.lib.maglev_replay_closed_loop_injected(ptr(pv), cpid, ptr(w), n, float(u_hold), *inj,
                                                  float(y_step), float(u_step),
                                                  *(ptr(out[k]) for k in ("u", "y", "x", "v", "i")), msg, 256)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return {"t": np.arange(n) * pid.ts, "w": w, **out}


def predict(params: PlantParams | Mapping[str, float] | None, pid: Controller, w: np.ndarray, y: np.ndarray,
            u: np.ndarray, u_hold: float, *, q_force: float, f_force: float, r_sensor: float, horizon: int,
            stride: int = 1, f_sensor: float = 0.0, r_coloured: float = 0.0,
            y_before: float | None = None) -> dict[str, np.ndarray]:
    """The prediction-error replay in one C call (``maglev_replay_predict``, ``c/maglev_replay.h``):
    an extended Kalman filter on the plant, driven by the measured ``u`` and corrected by the
    measured ``y`` [MU], predicting the closed loop ``horizon`` samples ahead from every
    ``stride``-th sample. ``q_force`` [N] and ``f_force`` [Hz]: RMS and corner of the random force
    on the ball; ``r_sensor`` [MU]: RMS of the white sensor noise; ``f_sensor`` [Hz], ``r_coloured``
    [MU]: corner and RMS of a coloured part beside it (``f_sensor`` 0: none); ``y_before``: the
    controller's start, as :func:`closed_loop`'s. Returns arrays ``y_pred``, ``u_pred``
    (NaN where no prediction ends), ``innov`` and ``innov_var`` (one-step innovations [MU] and
    their variances [MU²])."""
    m = fast._lib()
    pv = fast._param_vector(fast._as_mapping(params))
    arrays = [np.ascontiguousarray(a, dtype=float) for a in (w, y, u)]
    n = len(arrays[0])
    if any(len(a) != n for a in arrays):
        raise ValueError("w, y and u must have the same length")
    out = {k: np.empty(n) for k in ("y_pred", "u_pred", "innov", "innov_var")}
    filt = fast._filter(m, q_force, f_force, r_sensor, horizon, stride, False, f_sensor, r_coloured)
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    rc = m.lib.maglev_replay_predict(ptr(pv), _controller(m, pid, y_before), filt,
                                     *(ptr(a) for a in arrays), n, float(u_hold),
                                     *(ptr(out[k]) for k in ("y_pred", "u_pred", "innov", "innov_var")), msg, 256)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return out


def predict_closed(params: PlantParams | Mapping[str, float] | None, controller: Controller, w: np.ndarray,
                   y: np.ndarray, u: np.ndarray, u_hold: float, *, q_force: float, f_force: float, r_sensor: float,
                   horizons: Sequence[int], stride: int = 1, current: np.ndarray | None = None,
                   r_current: float = 0.0, f_sensor: float = 0.0, r_coloured: float = 0.0,
                   y_before: float | None = None) -> dict[str, np.ndarray]:
    """The closed loop predicted at several ``horizons`` [samples] in one C call
    (``maglev_replay_predict_closed``): the filter follows the measured reading ``y`` [MU] (and the
    measured coil ``current`` [A], white noise of RMS ``r_current``, when given), driven by the
    measured ``u``; from every ``stride``-th sample the plant and the ``controller`` run on their own
    predicted readings and current, driven by the reference ``w`` [MU] alone. Returns ``y_pred``,
    ``u_pred``, ``i_pred`` (one row per horizon; NaN where no prediction ends), ``innov``,
    ``innov_var``, ``d``, ``d_sd`` as :func:`maglev_cosim.plant.fast.predict_horizons`. ``y_before``:
    the controller's start, as :func:`closed_loop`'s."""
    m = fast._lib()
    pv = fast._param_vector(fast._as_mapping(params))
    (y, u), n, cur = fast._measured_inputs(y, u, current)
    w = np.ascontiguousarray(w, dtype=float)
    if len(w) != n:
        raise ValueError("w, y and u must have the same length")
    hs = [int(h) for h in horizons]
    out = {k: np.empty((len(hs), n)) for k in ("y_pred", "u_pred", "i_pred")}
    out.update({k: np.empty(n) for k in ("innov", "innov_var", "d", "d_sd")})
    filt = fast._filter(m, q_force, f_force, r_sensor, max(hs, default=0), stride, False, f_sensor, r_coloured)
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    rc = m.lib.maglev_replay_predict_closed(ptr(pv), _controller(m, controller, y_before), filt, ptr(w), ptr(y), ptr(u),
                                            m.ffi.NULL if cur is None else ptr(cur), float(r_current), n,
                                            float(u_hold), len(hs), m.ffi.new("int[]", hs),
                                            *(ptr(out[k]) for k in ("y_pred", "u_pred", "i_pred", "innov", "innov_var",
                                                                    "d", "d_sd")), msg, 256)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return out


def pid_only(pid: PID, w: np.ndarray, y: np.ndarray, u_hold: float) -> np.ndarray:
    """The C PID alone over given ``w`` and ``y`` [MU], settled at ``u_hold`` [MU]: its outputs [MU]."""
    return control(pid, w, y, None, u_hold)


def control(controller: Controller, w: np.ndarray, y: np.ndarray, current: np.ndarray | None, u_hold: float,
            x0: tuple[float, float, float] | None = None, y_before: float | None = None) -> np.ndarray:
    """Any controller alone (``maglev_replay_control``) over given reference ``w`` and reading ``y``
    [MU] and coil ``current`` [A] (a cascade or a state feedback needs it), settled at ``u_hold``
    [MU] with the plant at ``x0`` = (position [m], velocity [m/s], current [A]) (``y_before``: as
    :func:`closed_loop`'s): its outputs [MU]."""
    m = fast._lib()
    w = np.ascontiguousarray(w, dtype=float)
    y = np.ascontiguousarray(y, dtype=float)
    cur = None if current is None else np.ascontiguousarray(current, dtype=float)
    if len(y) != len(w) or (cur is not None and len(cur) != len(w)):
        raise ValueError("w, y and the current must have the same length")
    u = np.empty(len(w))
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    x0a = None if x0 is None else np.ascontiguousarray(x0, dtype=float)
    if m.lib.maglev_replay_control(_controller(m, controller, y_before), ptr(w), ptr(y), m.ffi.NULL if cur is None else ptr(cur),
                                   len(w), float(u_hold), m.ffi.NULL if x0a is None else ptr(x0a), ptr(u), msg,
                                   256) != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return u


def settled_start_vector(params: PlantParams | Mapping[str, float] | np.ndarray,
                         x_op: float) -> tuple[np.ndarray, float]:
    """:func:`maglev_cosim.loop.simulate.settled_start` on a parameter vector
    (:func:`maglev_cosim.plant.fast.param_vector`), for the replays of a fit: the start state set in
    a copy of the vector, and the hold input [MU]."""
    pv, k = fast.param_vector(params), fast.param_index()
    i = min(formulas.point(pv, x_op).i, pv[k["i_max"]])
    u_hold = formulas.point(pv, x_op, i).u
    pv[k["x_start"]], pv[k["v_start"]], pv[k["i_start"]] = x_op, 0.0, i
    return pv, u_hold
