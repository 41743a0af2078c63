"""The controllers of the closed loop: the paper's PID, a cascade of position and current loops, and
state feedback with an observer; declared in a controller file (TOML) or built in Python.

One controller type for the loop layer, :data:`Controller`: each reads, at ``t_k``, the reference
``w`` [MU], the plant's reading ``y`` [MU] and the coil current ``i`` [A], and gives the D/A input
``u`` [MU] held over the next sample. The equations live once in C (``MaglevController`` in
``c/maglev_replay.h``, the fast path and the prediction-error replay); the Python classes here run
the same equations for the FMU and reference backends, and ``tests/test_controllers.py``
cross-checks the two.

- :class:`~maglev_cosim.loop.pid.PID`: the paper's discrete PID (Eq. 24/25), derivative filter and
  anti-windup (conditional integration or clamping).
- :class:`Cascade`: a position PID giving the current reference [A], and a current PID (usually a
  PI) giving ``u`` from the current error, as voltage-driven rigs run them.
- :class:`StateFeedback`: ``u = u_eq + k_w·(w − y_eq) − K·x̂ − k_int·q`` on an observer's estimate
  ``x̂`` of the deviation of (position, velocity, current) from an operating point, with an optional
  integral ``q`` of the reading error (LQI). :func:`design_state_feedback` designs one with
  python-control (``dlqr``, ``dlqe``) on the plant's discrete linearisation (:func:`discrete_plant`,
  from the C plant itself, so it holds for every rig's physics).

A controller file states the gains in the record's own signals (the rig's position convention
[m], current [A], actuator unit) or in the plant's (MU); :func:`load_controller` maps them onto the
plant (docs/controllers.md has the schema). Errors name the file and the key.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Union

import numpy as np

from ..plant import fast
from ..plant.formulas import point
from ..plant.params import as_params
from ..rigs import RigError, _Doc, load_rig
from .pid import ANTI_WINDUP, DERIVATIVE, DiscretePID, PID

if TYPE_CHECKING:   # python-control (and the matplotlib.pyplot it loads: half a second) is imported where it is
    import control  # used: a diagnosis needs none of it

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

#: Controller files shipped with the package (``maglev_cosim/rigs/controllers/``).
SHIPPED = ("levitador-cascade", "inteco-lqi")
KINDS = ("pid", "cascade", "state-feedback")


@dataclass(frozen=True)
class Cascade:
    """A position loop and a current loop (``MaglevController`` kind 1 in C).

    Parameters
    ----------
    outer : PID
        The position loop on the reading error ``w − y`` [MU]; its output is the current reference
        [A], its limits the reference's range [A].
    inner : PID
        The current loop on ``r − i`` [A]; its output is ``u`` [MU]. Same sample time as ``outer``.

    Examples
    --------
    >>> c = Cascade(PID(kp=3.0, ki=4.5, kd=0.015, u_max=1.5), PID(kp=2.0, ki=400.0, kd=0.0))
    >>> c.ts
    0.001
    """

    outer: PID
    inner: PID

    def __post_init__(self) -> None:
        if abs(self.outer.ts - self.inner.ts) > 1e-15:
            raise ValueError(f"Cascade: both loops run at one sample time, got {self.outer.ts} s and {self.inner.ts} s")

    @property
    def ts(self) -> float:
        """Sample time [s]."""
        return self.outer.ts

    @property
    def u_min(self) -> float:
        """Output limit [MU]."""
        return self.inner.u_min

    @property
    def u_max(self) -> float:
        """Output limit [MU]."""
        return self.inner.u_max

    def start(self, u_hold: float, x0: tuple[float, float, float] = (0.0, 0.0, 0.0), w0: float = 0.0,
              y0: float | None = None) -> RunningCascade:
        """Running, settled: the position loop holds the current ``x0[2]`` [A] at the first reference
        ``w0`` and reading ``y0`` [MU] (None: ``w0``), the current loop ``u_hold`` [MU]."""
        return RunningCascade(self, u_hold, x0, w0, y0)

    def c_settings(self) -> dict[str, Any]:
        """The settings as C's ``MaglevController`` holds them."""
        return {"kind": 1, "pid": self.outer.c_settings(), "inner": self.inner.c_settings()}


class RunningCascade:
    """A running :class:`Cascade`: :meth:`step` is one sample."""

    def __init__(self, cfg: Cascade, u_hold: float, x0, w0: float = 0.0, y0: float | None = None) -> None:
        self.cfg = cfg
        self.outer, self.inner = cfg.outer.start(float(x0[2]), w0, y0), cfg.inner.start(u_hold, float(x0[2]))

    def step(self, w: float, y: float, i: float = math.nan) -> float:
        """``u[k]`` [MU] from the reference ``w`` [MU], reading ``y`` [MU] and current ``i`` [A]."""
        return self.inner.step(self.outer.step(w, y), i)


@dataclass(frozen=True)
class StateFeedback:
    """State feedback with an observer, on deviations from an operating point (``MaglevController``
    kind 2 in C). States (position [m], velocity [m/s], current [A]) in the plant's convention
    (position growing towards the coil); measurements (reading [MU], current [A]).

    Each sample: ``e = (y − y_eq, i − i_eq) − C·x̂``, ``x̂ += L·e``;
    ``u = clip(u_eq + k_w·(w − y_eq) − K·x̂ − k_int·q, u_min, u_max)``; ``q += ts·(w − y)`` (held
    while ``u`` saturates and ``q`` would push it further, when ``anti_windup`` is
    ``"conditional"``); ``x̂ = Φ·x̂ + Γ·(u − u_eq)``.

    Parameters
    ----------
    ts : float
        Sample time [s].
    K : array (3,)
        State gain [MU/m, MU·s/m, MU/A].
    Phi, Gam, C, L : arrays (3, 3), (3,), (2, 3), (3, 2)
        The observer's model (discrete, ``ts``) and gain (a current estimator).
    x_eq : array (3,)
        Operating point [m, m/s, A]; ``u_eq`` [MU], ``y_eq`` [MU], ``i_eq`` [A] the matching input,
        reading and current.
    k_w : float
        Reference gain [MU/MU] (LQR tracking; 0 with integral action).
    k_int : float
        Integral gain [1/s] on ``q`` (LQI; 0: none).
    u_min, u_max : float
        Output limits [MU].
    anti_windup : {"none", "conditional"}
    """

    ts: float
    K: np.ndarray
    Phi: np.ndarray
    Gam: np.ndarray
    C: np.ndarray
    L: np.ndarray
    x_eq: np.ndarray
    u_eq: float
    y_eq: float
    i_eq: float
    k_w: float = 0.0
    k_int: float = 0.0
    u_min: float = 0.0
    u_max: float = 1.0
    anti_windup: str = "conditional"
    design: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        shapes = {"K": (3,), "Phi": (3, 3), "Gam": (3,), "C": (2, 3), "L": (3, 2), "x_eq": (3,)}
        for name, shape in shapes.items():
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise ValueError(f"StateFeedback: {name} must be finite with shape {shape}, got {a.shape}")
            object.__setattr__(self, name, a)
        scalars = (self.ts, self.u_eq, self.y_eq, self.i_eq, self.k_w, self.k_int, self.u_min, self.u_max)
        if not all(math.isfinite(float(v)) for v in scalars) or self.ts <= 0 or not self.u_min < self.u_max:
            raise ValueError("StateFeedback: needs ts > 0 s, finite operating point and gains, u_min < u_max")
        if self.anti_windup not in ("none", "conditional"):
            raise ValueError(f"StateFeedback: anti_windup must be none or conditional, got {self.anti_windup!r}")

    def replace(self, **changes) -> StateFeedback:
        """A copy with some settings changed."""
        return replace(self, **changes)

    def start(self, u_hold: float, x0: tuple[float, float, float] = (0.0, 0.0, 0.0), w0: float = 0.0,
              y0: float | None = None) -> RunningStateFeedback:
        """Running, settled: the observer at the plant's state ``x0`` [m, m/s, A], the integral where
        ``u = u_hold`` [MU] for reference ``w0`` [MU]. ``y0``, the first reading, changes nothing: the
        plant's state holds it (C ``ctl_start`` reads no ``from_reading`` for kind 2)."""
        return RunningStateFeedback(self, u_hold, x0, w0)

    def c_settings(self) -> dict[str, Any]:
        """The settings as C's ``MaglevController`` holds them."""
        pid = {"ts": self.ts, "kp": 0.0, "ki": 0.0, "kd": 0.0, "u_min": self.u_min, "u_max": self.u_max, "tf": 0.0,
               "anti_windup": 1 if self.anti_windup == "conditional" else 0}
        return {"kind": 2, "pid": pid, "Phi": self.Phi.tolist(), "Gam": self.Gam.tolist(), "C": self.C.tolist(),
                "L": self.L.tolist(), "K": self.K.tolist(), "k_w": self.k_w, "k_int": self.k_int,
                "x_eq": self.x_eq.tolist(), "u_eq": self.u_eq, "y_eq": self.y_eq, "i_eq": self.i_eq}


class RunningStateFeedback:
    """A running :class:`StateFeedback`: :meth:`step` is one sample (the C equations, in numpy)."""

    def __init__(self, cfg: StateFeedback, u_hold: float, x0, w0: float) -> None:
        self.cfg = cfg
        self.xh = np.asarray(x0, dtype=float) - cfg.x_eq
        self.q = 0.0
        if cfg.k_int != 0:
            self.q = (self._raw(w0) - u_hold) / cfg.k_int

    def _raw(self, w: float) -> float:
        c = self.cfg
        return c.u_eq + c.k_w * (w - c.y_eq) - float(c.K @ self.xh) - c.k_int * self.q

    def step(self, w: float, y: float, i: float = math.nan) -> float:
        """``u[k]`` [MU] from the reference ``w`` [MU], reading ``y`` [MU] and current ``i`` [A]."""
        c = self.cfg
        e = np.array([y - c.y_eq, i - c.i_eq]) - c.C @ self.xh
        self.xh = self.xh + c.L @ e
        raw = self._raw(w)
        u = min(max(raw, c.u_min), c.u_max)
        dq = c.ts * (w - y)
        if not (c.anti_windup == "conditional" and u != raw and (raw - u) * (-c.k_int * dq) > 0):
            self.q += dq
        self.xh = c.Phi @ self.xh + c.Gam * (u - c.u_eq)
        return u


#: The loop layer's one controller type.
Controller = Union[PID, Cascade, StateFeedback]


def start(controller: Controller, u_hold: float, x0=(0.0, 0.0, 0.0), w0: float = 0.0, y0: float | None = None):
    """A running controller, settled (see each type's ``start``) at the first reference ``w0`` and
    reading ``y0`` [MU] (None: ``w0``): ``.step(w, y, i)`` gives ``u`` [MU]."""
    if isinstance(controller, PID):
        return _RunningPID(controller, u_hold, w0, y0)
    return controller.start(u_hold, x0, w0, y0)


class _RunningPID(DiscretePID):
    def step(self, w: float, y: float, i: float = math.nan) -> float:  # the current is not used
        return super().step(w, y)


def c_settings(controller: Controller) -> dict[str, Any]:
    """Any controller as C's ``MaglevController``."""
    if isinstance(controller, PID):
        return {"kind": 0, "pid": controller.c_settings()}
    if isinstance(controller, (Cascade, StateFeedback)):
        return controller.c_settings()
    raise TypeError(f"not a controller: {type(controller).__name__} (PID, Cascade or StateFeedback)")


def needs_current(controller: Controller) -> bool:
    """Whether the controller reads the coil current."""
    return not isinstance(controller, PID)


# --------------------------------------------------------------------------- design

def discrete_plant(params, x_op: float, ts: float, *, i_op: float | None = None) -> control.StateSpace:
    """The plant's discrete linearisation at rest at ``x_op`` [m], sample time ``ts`` [s], by
    central differences of the C plant's own one-sample map (every rig's physics included).

    States ``x`` [m], ``v`` [m/s], ``i`` [A] (deviations); input ``u`` [MU] held over the sample;
    outputs ``y`` [MU] (the reading's slope) and ``i`` [A]. Returns a python-control
    ``StateSpace`` with ``dt = ts`` and named signals; ``.op`` holds the operating point
    (``x``, ``i``, ``u``, ``y``)."""
    import control

    p = as_params(params)
    pt = point(p, x_op) if i_op is None else point(p, x_op, i_op)
    s0 = np.array([x_op, 0.0, pt.i])
    deltas = np.array([1e-7, 1e-5, 1e-5 * max(1.0, abs(pt.i))])
    du = 1e-5

    if not p.x_min < x_op < p.x_max:
        raise ValueError(f"x_op = {x_op * 1e3:g} mm must lie strictly between the stops "
                         f"[{p.x_min * 1e3:g}, {p.x_max * 1e3:g}] mm")

    def one_step(s, u):
        r = fast.open_loop(p.replace(x_start=float(s[0]), v_start=float(s[1]), i_start=float(s[2])),
                           np.array([u, u]), ts=ts)
        return np.array([r["x"][1], r["v"][1], r["i"][1]])

    A = np.empty((3, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = deltas[j]
        A[:, j] = (one_step(s0 + e, pt.u) - one_step(s0 - e, pt.u)) / (2 * deltas[j])
    B = ((one_step(s0, pt.u + du) - one_step(s0, pt.u - du)) / (2 * du)).reshape(3, 1)
    C = np.array([[pt.dy_dx, 0.0, 0.0], [0.0, 0.0, 1.0]])
    sys_d = control.ss(A, B, C, np.zeros((2, 1)), ts, states=["x", "v", "i"], inputs=["u"], outputs=["y", "i"],
                       name="plant_d")
    sys_d.op = {"x": x_op, "i": pt.i, "u": pt.u, "y": pt.y}
    return sys_d


def design_state_feedback(params, x_op: float, ts: float, *, q: tuple[float, float, float],
                          r: float, qn: tuple[float, float] = (10.0, 10.0),
                          rn: tuple[float, float] = (1e-6, 1e-4), integral: float = 0.0,
                          u_min: float = 0.0, u_max: float = 1.0, measure_current: bool = True) -> StateFeedback:
    """An LQR (or LQI) with a Kalman observer, designed on :func:`discrete_plant` at ``x_op`` [m].

    Parameters
    ----------
    q : (3,) float
        State weights (position [1/m²], velocity [s²/m²], current [1/A²]), as in a continuous
        design (Bryson's rule); the discrete design uses ``q·ts`` and ``r·ts``.
    r : float
        Input weight [1/MU²].
    qn : (2,) float
        Process noise intensities on the velocity [(m/s²)²·s] and the current [(A/s)²·s].
    rn : (2,) float
        Measurement noise intensities of the reading [MU²·s] and the current [A²·s] (continuous;
        the discrete covariance is ``rn/ts``).
    integral : float
        Weight [1/(MU·s)²] of the integral of the reading error (LQI); 0: LQR with a reference gain
        ``k_w`` that gives zero static error on the linear model.
    u_min, u_max : float
        Output limits [MU].
    measure_current : bool
        Whether the observer uses the measured current.
    """
    import control

    p = as_params(params)
    plant = discrete_plant(p, x_op, ts)
    A, B, C = plant.A, plant.B, plant.C
    Q = np.diag(np.asarray(q, float)) * ts
    R = np.array([[float(r)]]) * ts
    k_int = 0.0
    k_w = 0.0
    if integral > 0:
        # augmented with q[k+1] = q[k] + ts·(w − y): the error integral enters with −C_y
        Aa = np.block([[A, np.zeros((3, 1))], [-ts * C[:1], np.ones((1, 1))]])
        Ba = np.vstack([B, [[0.0]]])
        Qa = np.diag([*np.diag(Q), integral * ts])
        Ka, _, _ = control.dlqr(Aa, Ba, Qa, R)
        # u = −K·x − Ka_q·q, and C's law has ... − k_int·q
        K, k_int = Ka[0, :3], float(Ka[0, 3])
    else:
        Kd, _, _ = control.dlqr(A, B, Q, R)
        K = Kd[0]
        # static gain from u to y of the loop u = −K x + k_w·w: choose k_w for unit gain
        Acl = A - B @ Kd
        g = float((C[:1] @ np.linalg.solve(np.eye(3) - Acl, B))[0, 0])
        k_w = 1.0 / g
    G = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]) * ts
    rows = [0, 1] if measure_current else [0]
    Cm = C[rows]
    QN = np.diag(np.asarray(qn, float)) / ts
    RN = np.diag(np.asarray(rn, float)[rows]) / ts
    # the current estimator's gain: L = P C' (C P C' + R)^-1 with P the predicted covariance
    _, P, _ = control.dlqe(A, G, Cm, QN, RN)
    P = np.asarray(P)
    Lm = P @ Cm.T @ np.linalg.inv(Cm @ P @ Cm.T + RN)
    L = np.zeros((3, 2))
    L[:, rows] = Lm
    op = plant.op
    return StateFeedback(ts=ts, K=np.asarray(K, float), Phi=A, Gam=B[:, 0], C=C, L=L,
                         x_eq=np.array([x_op, 0.0, op["i"]]), u_eq=op["u"], y_eq=op["y"], i_eq=op["i"], k_w=k_w,
                         k_int=k_int, u_min=u_min, u_max=u_max,
                         design={"x_op": x_op, "q": list(q), "r": r, "qn": list(qn), "rn": list(rn),
                                 "integral": integral, "measure_current": measure_current,
                                 "closed_loop_poles": [complex(z) for z in np.linalg.eigvals(A - np.outer(B[:, 0], K))]})


# --------------------------------------------------------------------------- controller files

class ControllerError(RigError):
    """A controller file that cannot be used; ``str()`` is ``FILE: key 'KEY': what is wrong`` (the
    form of :class:`maglev_cosim.rigs.RigError`)."""


def controller_path(name_or_path: str | Path) -> Path:
    """The file of a shipped controller by name, or ``name_or_path`` itself when it is a file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    if str(name_or_path) in SHIPPED:
        return Path(str(resources.files("maglev_cosim.rigs").joinpath("controllers", f"{name_or_path}.toml")))
    raise ControllerError(name_or_path, "", f"no such controller file, and not a shipped one ({', '.join(SHIPPED)})")


@dataclass(frozen=True)
class ControllerFile:
    """A controller read from a file: the controller on the plant's signals, and where it came from."""

    name: str
    path: Path
    description: str
    rig: str
    kind: str
    controller: Controller
    sources: dict[str, str]


def load_controller(name_or_path: str | Path, rig=None) -> ControllerFile:
    """Reads a controller file (``docs/controllers.md``) and maps it onto the plant of ``rig``.

    Parameters
    ----------
    name_or_path : str or Path
        A file, or a shipped controller's name (:data:`SHIPPED`).
    rig : Rig or str, optional
        The rig (default: the one the file names). A file whose gains act on the record's signals
        (``signals = "record"``) needs a rig with a ``position`` sensor (position linear in the
        reading) to map them.

    Raises
    ------
    ControllerError
        Missing, unknown or non-physical keys, or a file that names another rig; the message names
        the file and the key.
    """
    path = controller_path(name_or_path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ControllerError(path, "", "no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ControllerError(path, "", f"cannot be read ({type(e).__name__})") from None
    except tomllib.TOMLDecodeError as e:
        raise ControllerError(path, "", f"not valid TOML: {e}") from None
    d = _Doc(path, doc)
    try:
        name, description = d.text("name"), d.text("description", default="")
        rig_name = d.text("rig")
        if rig is None or isinstance(rig, (str, Path)):
            rig = load_rig(rig if rig is not None else rig_name)
        if rig.name != rig_name:
            raise d.error("rig", f"the file is for rig {rig_name!r}, not {rig.name!r}")
        kind = d.text("type", KINDS)
        ts = d.number("sample_time", "s", lo=1e-6, hi=1.0)
        signals = d.text("signals", ("record", "plant"), default="record")
        maps = _signal_maps(d, rig, signals)
        if kind == "pid":
            ctl: Controller = _pid(d, "position", ts, maps["y"], maps["u"])
        elif kind == "cascade":
            ctl = Cascade(_pid(d, "position", ts, maps["y"], 1.0), _pid(d, "current", ts, 1.0, maps["u"]))
        else:
            ctl = _state_feedback(d, rig, ts, maps)
        unknown = d.unknown_keys()
        if unknown:
            raise d.error(unknown[0], "unknown key (docs/controllers.md lists the keys)")
        sources = doc.get("sources", {})
        return ControllerFile(name=name, path=path, description=description,
                              rig=rig_name, kind=kind, controller=ctl,
                              sources={str(k): str(v) for k, v in sources.items()})
    except ControllerError:
        raise
    except RigError as e:
        raise ControllerError(e.path, e.key, e.message) from None


def _signal_maps(d, rig, signals: str) -> dict[str, float]:
    """Factors from the plant's signals to the file's: position per MU of reading (``y``), actuator
    unit per MU (``u``)."""
    if signals == "plant":
        return {"y": 1.0, "u": 1.0}
    if rig.sensor != "position":
        raise d.error("signals", f"rig {rig.name}'s reading is not linear in the position: state the gains on the "
                      "plant's signals (signals = \"plant\", MU)")
    y = -rig.position_scale if rig.convention == "gap" else rig.position_scale
    u = rig.params.k_DA if rig.input_unit == "V" else 1.0
    return {"y": y, "u": u}


def _pid(d, section: str, ts: float, c_in: float, c_out: float) -> PID:
    """A PID section of a file (gains on the file's signals) as a PID on the plant's: the error is
    ``c_in`` times the plant's, the output ``c_out`` times the plant's."""
    k = lambda name, unit: d.number(f"{section}.{name}", unit, default=0.0)  # noqa: E731
    lo, hi = d.pair(f"{section}.limits", "output units")
    aw = d.text(f"{section}.anti_windup", ANTI_WINDUP, default="none")
    g = c_in / c_out
    band: dict[str, float] = {}
    if aw == "band":
        b_lo, b_hi = d.pair(f"{section}.band", "output units")
        band = {"i_lo": b_lo / c_out, "i_hi": b_hi / c_out,
                "backoff": d.number(f"{section}.backoff", "1", lo=0.0, lo_open=True, hi=1.0, default=1.0)}
    return PID(**band, ts=ts, kp=k("kp", "output/error") * g, ki=k("ki", "output/(error s)") * g,
               kd=k("kd", "output s/error") * g, tf=d.number(f"{section}.tf", "s", lo=0.0, hi=10.0, default=0.0),
               u_min=lo / c_out, u_max=hi / c_out, anti_windup=aw,
               derivative=d.text(f"{section}.derivative", DERIVATIVE, default="error"))


def _state_feedback(d, rig, ts: float, maps: dict[str, float]) -> StateFeedback:
    method = d.text("design.method", ("lqr", "lqi"))
    op = d.number("design.operating_point", "m", lo=-0.5, hi=0.5)
    x_op = float(rig.to_x(op))
    q = d.array("design.q")
    if len(q) != 3 or np.any(q < 0):
        raise d.error("design.q", f"needs three weights >= 0 (position, velocity, current), got {q.tolist()}")
    r = d.number("design.r", "1/input^2", lo=0.0, lo_open=True)
    integral = d.number("design.integral", "1/(m s)^2", lo=0.0, lo_open=True) if method == "lqi" else 0.0
    qn = d.array("observer.qn")
    rn = d.array("observer.rn")
    if len(qn) != 2 or len(rn) != 2 or np.any(qn <= 0) or np.any(rn <= 0):
        raise d.error("observer", "qn and rn each need two intensities > 0")
    lo, hi = d.pair("limits", "input units")
    cy, cu = maps["y"], maps["u"]
    # weights and noise on the file's signals -> the plant's: the position itself is in metres either
    # way; the reading's noise and the integral of its error scale with cy, the input with cu
    try:
        return design_state_feedback(rig.params, x_op, ts, q=tuple(q), r=r * cu**2, qn=tuple(qn),
                                     rn=(rn[0] / cy**2, rn[1]), integral=integral * cy**2, u_min=lo / cu,
                                     u_max=hi / cu, measure_current=d.text("observer.current", ("yes", "no"),
                                                                           default="yes") == "yes")
    except (ValueError, np.linalg.LinAlgError) as e:
        raise d.error("design", f"the design failed: {e}") from None
