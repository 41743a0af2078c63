"""The cffi fast path: the same C plant the FMU compiles (``c/maglev_plant.c``) with the
closed-loop replay of ``c/maglev_replay.c``, a whole record in one C call.

CMake builds the two into a plain shared library (``libmaglev_fast.so``, with -O3 and the strict
warning flags) that ``pip install .`` puts into the package; it is loaded here with cffi in ABI
mode (``ffi.dlopen``), its declarations read from the installed ``maglev_replay.h``, so nothing is
compiled at run time. ``python -m maglev_cosim.fast`` prints the library's path.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Mapping
from types import SimpleNamespace
from typing import TYPE_CHECKING

import numpy as np

from ._resources import ResourceError, c_dir, fast_library_path

if TYPE_CHECKING:
    from .controllers import Controller
    from .params import PlantParams
    from .pid import PID


def _cdef() -> str:
    """The declarations of c/maglev_replay.h, for cffi (preprocessor lines and comments removed)."""
    text = (c_dir() / "maglev_replay.h").read_text()
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))


_mod: SimpleNamespace | None = None


def _lib() -> SimpleNamespace:
    """``ffi`` and ``lib`` of the loaded fast-path library (loaded once per process)."""
    global _mod
    if _mod is None:
        import cffi

        ffi = cffi.FFI()
        ffi.cdef(_cdef())
        _mod = SimpleNamespace(ffi=ffi, lib=ffi.dlopen(str(fast_library_path())))
    return _mod


def param_names() -> list[str]:
    """FMU parameter names in the C order (value-reference order)."""
    m = _lib()
    return [m.ffi.string(m.lib.maglev_replay_param_name(k)).decode() for k in range(m.lib.maglev_replay_nparams())]


def param_table() -> dict[str, tuple[float, float, float, str]]:
    """``name: (default, min, max, unit)`` for every FMU parameter, from the C variable table."""
    m = _lib()
    return {n: (float(m.lib.maglev_replay_param_default(k)), float(m.lib.maglev_replay_param_min(k)),
                float(m.lib.maglev_replay_param_max(k)), m.ffi.string(m.lib.maglev_replay_param_unit(k)).decode())
            for k, n in enumerate(param_names())}


def default_params() -> dict[str, float]:
    """The C defaults (the FMU's start values, Section 3)."""
    return dict(_defaults())


_default_cache: dict[str, float] | None = None


def _defaults() -> dict[str, float]:
    """The C defaults, read once (every replay needs them)."""
    global _default_cache
    if _default_cache is None:
        m = _lib()
        _default_cache = {n: float(m.lib.maglev_replay_param_default(k)) for k, n in enumerate(param_names())}
    return _default_cache


_index_cache: dict[str, int] | None = None


def param_index() -> dict[str, int]:
    """Each FMU parameter's index in a parameter vector (:func:`param_vector`)."""
    global _index_cache
    if _index_cache is None:
        _index_cache = {n: k for k, n in enumerate(_defaults())}
    return _index_cache


def param_vector(params: PlantParams | Mapping[str, float] | np.ndarray | None) -> np.ndarray:
    """All FMU parameter values in the C order, ``params`` over the C defaults, checked by the C
    rules (``ValueError`` naming the variable otherwise). A vector (from this function) passes as
    it is, checked again: the replays of a fit build it once and hand it down."""
    return _param_vector(_as_mapping(params))


def _param_vector(params: Mapping[str, float] | np.ndarray | None) -> np.ndarray:
    """The values in C order (over the defaults), checked by the C rules."""
    defaults = _defaults()
    if isinstance(params, np.ndarray):
        if params.shape != (len(defaults),):
            raise ValueError(f"a parameter vector holds {len(defaults)} values, not {params.shape}")
        return _checked(np.array(params, dtype=float))
    if params:
        unknown = sorted(set(params) - set(defaults))
        if unknown:
            raise ValueError(f"unknown parameter(s): {', '.join(unknown)}")
        defaults = {**defaults, **{k: float(v) for k, v in params.items()}}
    return _checked(np.fromiter(defaults.values(), dtype=float, count=len(defaults)))


def _checked(vec: np.ndarray) -> np.ndarray:
    m = _lib()
    msg = m.ffi.new("char[256]")
    if m.lib.maglev_replay_check_params(m.ffi.cast("double *", m.ffi.from_buffer(vec)), msg, 256) != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return vec


def check_params(params: Mapping[str, float] | None) -> None:
    """Raises ``ValueError`` (one line naming the variable) unless ``params``, applied over the C
    defaults, is a parameter set the FMU accepts: each value in its range and the relations."""
    _param_vector(params)


def equilibrium_input(p: Mapping[str, float]) -> float:
    """D/A input [MU] holding the ball at rest at ``x_start`` (Eq. 8 at rest, Eq. 1, 5)."""
    from .formulas import point

    return point(p, p["x_start"]).u


def _controller(m: SimpleNamespace, controller):
    """Any controller (:data:`maglev_cosim.controllers.Controller`) as a C ``MaglevController``."""
    from .controllers import c_settings
    from .pid import PID

    return m.ffi.new("MaglevController *", c_settings(controller or PID()))


def closed_loop(params: PlantParams | Mapping[str, float] | None, w: np.ndarray, *,
                pid: Controller | None = None, u_hold: float | None = None, du: np.ndarray | None = None,
                dF: np.ndarray | None = None, dy: np.ndarray | None = None, y_step: float = 0.0,
                u_step: float = 0.0) -> dict[str, np.ndarray]:
    """The closed loop (plant + controller) over reference ``w`` [MU] in one C call: the low
    level of :func:`maglev_cosim.loop.simulate` (``backend="fast"``), which most callers want.

    ``params``: a :class:`PlantParams` or FMU parameter values over the C defaults, the start
    state included. ``pid``: the controller, any :data:`maglev_cosim.controllers.Controller`
    (default: the paper's PID, Eq. 24/25). ``u_hold`` [MU]: the settled
    input before t = 0 (default: the equilibrium input at ``x_start``). ``du`` [MU], ``dF`` [N],
    ``dy`` [MU]: signals injected at the actuator (added to the controller's output on its way to
    the plant), on the ball (a force held over each sample) and at the sensor (added to the
    reading), each of the length of ``w`` or None. ``y_step``, ``u_step`` [MU]: the A/D and D/A
    steps to which the reading and the controller's output are rounded (0: no rounding). Returns arrays ``t`` [s], ``w``, ``u`` (the
    controller's output), ``y`` [MU], ``x`` [m], ``v`` [m/s], ``i`` [A]."""
    from .pid import PID

    m = _lib()
    pv = _param_vector(_as_mapping(params))
    pid = pid or PID()
    w = np.ascontiguousarray(w, dtype=float)
    n = len(w)
    if u_hold is None:
        u_hold = equilibrium_input(dict(zip(_defaults(), pv)))
    out = {k: np.empty(n) for k in ("u", "y", "x", "v", "i")}
    cpid = _controller(m, pid)
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


def _filter(m: SimpleNamespace, q_force: float, f_force: float, r_sensor: float, horizon: int, stride: int,
            current_input: bool = False):
    """The C filter settings (``MaglevFilter``, ``c/maglev_replay.h``) of both prediction entry points."""
    return m.ffi.new("MaglevFilter *", {"q_force": float(q_force), "f_force": float(f_force),
                                        "r_sensor": float(r_sensor), "horizon": int(horizon), "stride": int(stride),
                                        "current_input": int(bool(current_input))})


def predict(params: PlantParams | Mapping[str, float] | None, pid: Controller, w: np.ndarray, y: np.ndarray,
            u: np.ndarray, u_hold: float, *, q_force: float, f_force: float, r_sensor: float, horizon: int,
            stride: int = 1) -> dict[str, np.ndarray]:
    """The prediction-error replay in one C call (``maglev_replay_predict``, ``c/maglev_replay.h``):
    an extended Kalman filter on the plant, driven by the measured ``u`` and corrected by the
    measured ``y`` [MU], predicting the closed loop ``horizon`` samples ahead from every
    ``stride``-th sample. ``q_force`` [N] and ``f_force`` [Hz]: RMS and corner of the random force
    on the ball; ``r_sensor`` [MU]: RMS of the sensor noise. Returns arrays ``y_pred``, ``u_pred``
    (NaN where no prediction ends), ``innov`` and ``innov_var`` (one-step innovations [MU] and
    their variances [MU²])."""
    m = _lib()
    pv = _param_vector(_as_mapping(params))
    arrays = [np.ascontiguousarray(a, dtype=float) for a in (w, y, u)]
    n = len(arrays[0])
    if any(len(a) != n for a in arrays):
        raise ValueError("w, y and u must have the same length")
    out = {k: np.empty(n) for k in ("y_pred", "u_pred", "innov", "innov_var")}
    filt = _filter(m, q_force, f_force, r_sensor, horizon, stride)
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    rc = m.lib.maglev_replay_predict(ptr(pv), _controller(m, pid), filt,
                                     *(ptr(a) for a in arrays), n, float(u_hold),
                                     *(ptr(out[k]) for k in ("y_pred", "u_pred", "innov", "innov_var")), msg, 256)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return out


def predict_measured(params: PlantParams | Mapping[str, float] | None, y: np.ndarray, u: np.ndarray, *, ts: float,
                     q_force: float, f_force: float, r_sensor: float, horizon: int, stride: int = 1,
                     current: np.ndarray | None = None, r_current: float = 0.0,
                     current_input: bool = False, correction: Mapping | None = None) -> dict[str, np.ndarray]:
    """The prediction-error replay of a record whose controller is unknown, in one C call
    (``maglev_replay_predict_measured``): the filter follows the measured reading ``y`` [MU] (and
    the measured coil ``current`` [A], white noise of RMS ``r_current``, when given) and predicts
    ``horizon`` samples ahead driven by the measured input ``u`` [MU], or with ``current_input`` by
    the measured ``current`` over the horizon (the actuator signal then only moves it within each
    sample). Returns ``y_pred`` [MU],
    ``i_pred`` [A] (NaN where no prediction ends), ``innov`` [MU], ``innov_var`` [MU²], and ``d``, ``d_sd``
    [N]: the filtered random force on the ball and its standard deviation at every sample.
    ``correction``: a located correction at the mechanics (``MaglevCorrection``: ``n_x``, ``x_c``,
    ``x_s``, ``v_s``, ``v_c``, ``coef``), a force that is a function of position and velocity, in the
    filter's model and its predictions (``maglev_replay_predict_corrected``)."""
    m = _lib()
    pv = _param_vector(_as_mapping(params))
    arrays = [np.ascontiguousarray(a, dtype=float) for a in (y, u)]
    n = len(arrays[0])
    cur = None if current is None else np.ascontiguousarray(current, dtype=float)
    if len(arrays[1]) != n or (cur is not None and len(cur) != n):
        raise ValueError("y, u and the current must have the same length")
    out = {k: np.empty(n) for k in ("y_pred", "i_pred", "innov", "innov_var", "d", "d_sd")}
    filt = _filter(m, q_force, f_force, r_sensor, horizon, stride, current_input)
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    if correction is not None and int(correction["n_x"]) > 0:
        coef = [float(v) for v in correction["coef"]]
        corr = m.ffi.new("MaglevCorrection *", {"n_x": int(correction["n_x"]), "x_c": float(correction["x_c"]),
                                                 "x_s": float(correction["x_s"]), "v_s": float(correction["v_s"]),
                                                 "v_c": float(correction["v_c"]), "coef": coef + [0.0] * (12 - len(coef))})
        call = lambda *args: m.lib.maglev_replay_predict_corrected(args[0], args[1], corr, *args[2:])  # noqa: E731
    else:
        call = m.lib.maglev_replay_predict_measured
    rc = call(ptr(pv), filt, float(ts), *(ptr(a) for a in arrays),
              m.ffi.NULL if cur is None else ptr(cur), float(r_current), n,
              *(ptr(out[k]) for k in ("y_pred", "i_pred", "innov", "innov_var", "d", "d_sd")), msg, 256)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return out


def pid_only(pid: PID, w: np.ndarray, y: np.ndarray, u_hold: float) -> np.ndarray:
    """The C PID alone over given ``w`` and ``y`` [MU], settled at ``u_hold`` [MU]: its outputs [MU]."""
    return control(pid, w, y, None, u_hold)


def control(controller: Controller, w: np.ndarray, y: np.ndarray, current: np.ndarray | None, u_hold: float,
            x0: tuple[float, float, float] | None = None) -> np.ndarray:
    """Any controller alone (``maglev_replay_control``) over given reference ``w`` and reading ``y``
    [MU] and coil ``current`` [A] (a cascade or a state feedback needs it), settled at ``u_hold``
    [MU] with the plant at ``x0`` = (position [m], velocity [m/s], current [A]): its outputs [MU]."""
    m = _lib()
    w = np.ascontiguousarray(w, dtype=float)
    y = np.ascontiguousarray(y, dtype=float)
    cur = None if current is None else np.ascontiguousarray(current, dtype=float)
    if len(y) != len(w) or (cur is not None and len(cur) != len(w)):
        raise ValueError("w, y and the current must have the same length")
    u = np.empty(len(w))
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    x0a = None if x0 is None else np.ascontiguousarray(x0, dtype=float)
    if m.lib.maglev_replay_control(_controller(m, controller), ptr(w), ptr(y), m.ffi.NULL if cur is None else ptr(cur),
                                   len(w), float(u_hold), m.ffi.NULL if x0a is None else ptr(x0a), ptr(u), msg,
                                   256) != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return u


def _as_mapping(params) -> Mapping[str, float] | None:
    return params.to_start_values() if hasattr(params, "to_start_values") else params


def open_loop(params: PlantParams | Mapping[str, float] | None, u: np.ndarray, *,
              ts: float = 1e-3) -> dict[str, np.ndarray]:
    """The plant driven by input ``u`` [MU] (``u[0]`` also before t = 0); ``y[k]`` read at ``t_k``."""
    m = _lib()
    pv = _param_vector(_as_mapping(params))
    u = np.ascontiguousarray(u, dtype=float)
    n = len(u)
    out = {k: np.empty(n) for k in ("y", "x", "v", "i")}
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    rc = m.lib.maglev_replay_open_loop(ptr(pv), ptr(u), n, ts, *(ptr(out[k]) for k in ("y", "x", "v", "i")),
                                       msg, 256)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return {"t": np.arange(n) * ts, "u": u, **out}


if __name__ == "__main__":
    try:
        _lib()
        print(fast_library_path())
    except ResourceError as exc:
        print(f"maglev_cosim.fast: {exc}", file=sys.stderr)
        raise SystemExit(2)
