"""The cffi fast path: the same C plant the FMU compiles (``c/maglev_plant.c``) with the
closed-loop replay of ``c/maglev_replay.c``, a whole record in one C call (the entry points that
take a controller are in :mod:`maglev_cosim.loop.fast_loop`).

CMake builds the two into a plain shared library (``libmaglev_fast.so``, with -O3 and the strict
warning flags) that ``pip install .`` puts into the package; it is loaded here with cffi in ABI
mode (``ffi.dlopen``), its declarations read from the installed ``maglev_replay.h``, so nothing is
compiled at run time. ``python -m maglev_cosim.plant.fast`` prints the library's path.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Mapping, Sequence
from types import SimpleNamespace
from typing import Protocol

import cffi
import numpy as np

from .._resources import ResourceError, c_dir, fast_library_path


class StartValues(Protocol):
    """Parameter values as FMU start values by name: a :class:`maglev_cosim.plant.params.PlantParams`
    (named so by its method, as :mod:`maglev_cosim.plant.params` itself checks its values here)."""

    def to_start_values(self) -> dict[str, float]: ...


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


def param_effects() -> dict[str, str]:
    """``name: effect`` for every FMU parameter, from the C variable table's ``effect`` column: the
    effect of the diagnosis's catalogue the parameter belongs to, ``""`` for the baseline plant."""
    m = _lib()
    return {n: m.ffi.string(m.lib.maglev_replay_param_effect(k)).decode() for k, n in enumerate(param_names())}


def effect_params() -> dict[str, tuple[str, ...]]:
    """``effect: (parameter, ...)`` in the C table's order: which parameters make which effect. The
    one declaration of an effect's parameters; everything else (:mod:`maglev_cosim.plant.params`,
    the catalogue, synth, the emulators) derives its lists from it."""
    out: dict[str, tuple[str, ...]] = {}
    for name, effect in param_effects().items():
        if effect:
            out[effect] = out.get(effect, ()) + (name,)
    return out


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


def param_vector(params: StartValues | Mapping[str, float] | np.ndarray | None) -> np.ndarray:
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


def _filter(m: SimpleNamespace, q_force: float, f_force: float, r_sensor: float, horizon: int, stride: int,
            current_input: bool = False, f_sensor: float = 0.0, r_coloured: float = 0.0, offset: int = 0,
            coil_free: bool = False):
    """The C filter settings (``MaglevFilter``, ``c/maglev_replay.h``) of both prediction entry points.
    ``f_sensor`` [Hz], ``r_coloured`` [MU]: corner and RMS of the coloured part of the sensor noise
    (``f_sensor`` 0: white only). ``coil_free``: without a measured current, the coil current runs
    free of the reading's updates (the coil model alone, along the tracked position)."""
    return m.ffi.new("MaglevFilter *", {"q_force": float(q_force), "f_force": float(f_force),
                                        "r_sensor": float(r_sensor), "horizon": int(horizon), "stride": int(stride),
                                        "current_input": int(bool(current_input)), "f_sensor": float(f_sensor),
                                        "r_coloured": float(r_coloured), "offset": int(offset),
                                        "coil_free": int(bool(coil_free))})


def _measured_inputs(y: np.ndarray, u: np.ndarray, current: np.ndarray | None
                     ) -> tuple[list[np.ndarray], int, np.ndarray | None]:
    """``y``, ``u`` and the optional ``current`` as contiguous float arrays of one length ``n``."""
    arrays = [np.ascontiguousarray(a, dtype=float) for a in (y, u)]
    n = len(arrays[0])
    cur = None if current is None else np.ascontiguousarray(current, dtype=float)
    if len(arrays[1]) != n or (cur is not None and len(cur) != n):
        raise ValueError("y, u and the current must have the same length")
    return arrays, n, cur


def _correction(m: SimpleNamespace, correction: Mapping | None):
    """The located correction at the mechanics as a ``MaglevCorrection *`` (``NULL``: none)."""
    if correction is None or int(correction["n_x"]) <= 0:
        return m.ffi.NULL
    coef = [float(v) for v in correction["coef"]]
    return m.ffi.new("MaglevCorrection *", {"n_x": int(correction["n_x"]), "x_c": float(correction["x_c"]),
                                            "x_s": float(correction["x_s"]), "v_s": float(correction["v_s"]),
                                            "v_c": float(correction["v_c"]), "coef": coef + [0.0] * (12 - len(coef))})


def predict_measured(params: StartValues | Mapping[str, float] | None, y: np.ndarray, u: np.ndarray, *, ts: float,
                     q_force: float, f_force: float, r_sensor: float, horizon: int, stride: int = 1,
                     current: np.ndarray | None = None, r_current: float = 0.0,
                     current_input: bool = False, correction: Mapping | None = None, f_sensor: float = 0.0,
                     r_coloured: float = 0.0, offset: int = 0, coil_free: bool = False) -> dict[str, np.ndarray]:
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
    filter's model and its predictions (``maglev_replay_predict_corrected``). ``f_sensor`` [Hz],
    ``r_coloured`` [MU]: the coloured part of the sensor noise beside the white ``r_sensor`` (0: none).
    ``offset``: the predictions start at the samples ``k`` with ``k % stride == offset``. ``coil_free``
    (without ``current``): the coil current is never corrected from the reading (its covariance with
    the other states dropped), so ``i_pred`` is the coil model's free run from ``u`` along the tracked
    position: the current "from the actuator signal alone"."""
    m = _lib()
    pv = _param_vector(_as_mapping(params))
    arrays, n, cur = _measured_inputs(y, u, current)
    out = {k: np.empty(n) for k in ("y_pred", "i_pred", "innov", "innov_var", "d", "d_sd")}
    filt = _filter(m, q_force, f_force, r_sensor, horizon, stride, current_input, f_sensor, r_coloured, offset,
                   coil_free)
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    # (the corrected entry point with NULL is the measured one: maglev_replay.c)
    rc = m.lib.maglev_replay_predict_corrected(ptr(pv), filt, _correction(m, correction), float(ts),
                                               *(ptr(a) for a in arrays), m.ffi.NULL if cur is None else ptr(cur),
                                               float(r_current), n,
                                               *(ptr(out[k]) for k in ("y_pred", "i_pred", "innov", "innov_var", "d",
                                                                       "d_sd")), msg, 256)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return out


#: The filter of the measured-input replays linearises the plant every this many samples, counted
#: from a replay's first (``JAC_EVERY`` in ``c/maglev_replay.c``): a replay of a record's later part
#: that starts on that grid linearises where a replay of the whole record does.
JAC_EVERY = 10

#: The most horizons one call of :func:`predict_horizons` takes (``MAGLEV_MAX_HORIZONS`` in
#: ``c/maglev_replay.h``; the C code refuses more with a message).
MAX_HORIZONS = 64


def predict_horizons(params: StartValues | Mapping[str, float] | None, y: np.ndarray, u: np.ndarray, *, ts: float,
                     q_force: float, f_force: float, r_sensor: float, horizons: Sequence[int], stride: int = 1,
                     current: np.ndarray | None = None, r_current: float = 0.0,
                     correction: Mapping | None = None, f_sensor: float = 0.0,
                     r_coloured: float = 0.0, starts: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """:func:`predict_measured` at several ``horizons`` [samples] in one pass
    (``maglev_replay_predict_horizons``): the filter runs once and each prediction's trajectory to
    the longest horizon is read at every one, so the result equals one call per horizon at the
    cost of the longest alone. ``y_pred`` and ``i_pred`` have one row per horizon; ``innov``,
    ``innov_var``, ``d``, ``d_sd`` as in :func:`predict_measured`. ``starts``: ``n`` flags, predictions
    only from the samples flagged (``maglev_replay_predict_masked``; NaN elsewhere)."""
    m = _lib()
    pv = _param_vector(_as_mapping(params))
    arrays, n, cur = _measured_inputs(y, u, current)
    hs = [int(h) for h in horizons]
    out = {k: np.empty((len(hs), n)) for k in ("y_pred", "i_pred")}
    out.update({k: np.empty(n) for k in ("innov", "innov_var", "d", "d_sd")})
    filt = _filter(m, q_force, f_force, r_sensor, max(hs, default=0), stride, False, f_sensor, r_coloured)
    msg = m.ffi.new("char[256]")
    ptr = lambda a: m.ffi.cast("double *", m.ffi.from_buffer(a))  # noqa: E731
    head = (ptr(pv), filt, _correction(m, correction), float(ts), *(ptr(a) for a in arrays),
            m.ffi.NULL if cur is None else ptr(cur), float(r_current), n, len(hs), m.ffi.new("int[]", hs))
    tail = (*(ptr(out[k]) for k in ("y_pred", "i_pred", "innov", "innov_var", "d", "d_sd")), msg, 256)
    if starts is None:
        rc = m.lib.maglev_replay_predict_horizons(*head, *tail)
    else:
        flags = np.ascontiguousarray(starts, dtype=np.uint8)
        if flags.shape != (n,):
            raise ValueError(f"starts must hold {n} flags, not {flags.shape}")
        rc = m.lib.maglev_replay_predict_masked(*head, m.ffi.cast("unsigned char *", m.ffi.from_buffer(flags)), *tail)
    if rc != 0:
        raise ValueError(m.ffi.string(msg).decode())
    return out


def _as_mapping(params) -> Mapping[str, float] | None:
    return params.to_start_values() if hasattr(params, "to_start_values") else params


def open_loop(params: StartValues | Mapping[str, float] | None, u: np.ndarray, *,
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
        print(f"maglev_cosim.plant.fast: {exc}", file=sys.stderr)
        raise SystemExit(2)
