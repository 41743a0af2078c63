"""A second emulator of the CE152 in closed loop, written from the paper alone (issue 22, item 5).

It shares no code with the model the diagnosis fits: nothing here imports the C plant, its
cffi face (``fast``, ``replay``), the pure-Python reference, the loop or the first emulator
(``emulator``). It takes from :mod:`maglev_cosim.plant.params` only parameter values, by name, and writes
records with :func:`maglev_cosim.records.record.write_record` (I/O).
What it shares with the model is the paper's equations (``../shared/design/plant.md``: Eq. 1, 2,
8, 12, 13 and the PID of Eq. 24/25) and the parameter values; everything else is its own:

- **integrator**: :func:`scipy.integrate.solve_ivp` (``LSODA`` by default, ``rtol`` 1e-8) over
  each stretch in which the D/A value the plant sees is constant, on the state ``[x, v]`` plus the
  coil current ``i`` when the amplifier lags (``T_a``) and the force ``F`` when it lags the static
  law (``T_F``); the stops are terminal events, the contact perfectly inelastic (the ball keeps
  ``v = 0`` on the stop until the net force, random force included, pulls it off: a second event);
- **controller timing**: the reading ``y[k]`` is taken at ``t_k``, but the PID's output reaches the
  D/A only at ``t_k + pid_offset·ts`` (the computation takes time; default 0.3 of the sample), and
  the plant sees it ``T_d`` later still (effect ``delay``): every output is queued with the instant
  it reaches the coil, so any ``pid_offset·ts + T_d`` works, a whole number of samples or not;
- **controller form**: the paper's PID by default, or, with the settings ``pid_derivative``
  (``measurement``: the derivative of the reading alone, no kick at a reference step) and ``pid_tf``
  (a first-order filter of the derivative [s]), another implementation of the same gains; the
  record declares the gains alone, as a simulator that never heard of those settings would;
- **noise**: coloured sensor noise, a continuous first-order low-passed Gaussian (Ornstein-Uhlenbeck)
  process of RMS ``sigma_y`` [MU] and corner ``f_y`` [Hz] sampled at ``t_k`` (``f_y = inf``: white);
  a random force on the ball, another such process (RMS ``sigma_F_rel`` of the weight, time
  constant ``tau_F_noise``) plus an optional slow drift (``F_drift_rel``, ``tau_drift``), drawn at
  the sample instants and linearly interpolated between them, so the force is continuous;
- **converters**: the A/D reading and the D/A value are integer codes of a ``bits``-bit converter
  over ±1 MU (12 bits: steps of 1/2048 MU), two's complement: the codes run from −2^(bits−1) to
  2^(bits−1) − 1, so the D/A's largest value is 1 − 1/2048 MU, not 1 MU; the PID computes with the
  quantised reading, and the record's ``u`` is the D/A value;
- **effects**, each in its own words: amplifier lag ``T_a`` (Eq. 2), force lag ``T_F`` (the force on
  the ball follows the static law of Eq. 8 through a first-order lag), transport delay ``T_d``,
  sensor nonlinearity ``k_x2`` (a parabola through Table 3's calibration points 0 and ``x_cal``),
  current limit ``i_max`` (any value > 0: the amplifier's command is clipped to it), sensor pickup
  ``A_d·sin(2π f_d t + phi_d)`` [V] on the sensor voltage, Coulomb friction ``F_c·tanh(v/v_c)`` with
  ``v_c`` = 1 mm/s by default (``--effect coulomb_friction:F_c=...,v_c=...``), and the viscous damping ``k_FV`` of Eq. 8 (a plant parameter).

:func:`simulate` runs the loop and returns its signals; :func:`synth_record` writes a record with the
arguments of :func:`maglev_cosim.records.synth.synth_record` (``maglev-cosim synth --emulator ivp``).
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from ..plant.params import EFFECT_PARAMS, PARAMETER_SETS
from .emulation import DISTURBANCE_KEYS, checked_settings, current_truth, emulated_effects, reference_positions
from .record import write_record

#: The paper's values (Section 3, LQ fit), taken by name; ``T_a`` is an effect here (off by default).
_PAPER = PARAMETER_SETS["section3"]

#: Plant parameters a record may override (SI units), as :data:`maglev_cosim.records.synth.PLANT_PARAMS` and the stops.
PLANT_PARAMS = ("k_DA", "u_0", "k_i", "m_k", "g", "k_c", "x_0", "k_FV", "k_x", "y_0", "k_AD", "y_MU0",
                "x_min", "x_max", "x_cal")


#: Settings of this emulator alone (``synth_record(settings=...)``, ``--setting NAME=VALUE``).
SETTINGS = ("pid_offset", "f_y", "method", "rtol", "pid_tf", "pid_derivative")
#: ... of which these are words, not numbers.
WORD_SETTINGS = ("method", "pid_derivative")


def _typed(name: str, value) -> float | str:
    """A setting's value as the emulator takes it: a word (:data:`WORD_SETTINGS`) or a number."""
    return str(value).strip() if name in WORD_SETTINGS else float(value)


def parse_settings(specs) -> dict[str, float | str]:
    """``NAME=VALUE`` texts (``--setting``) as settings of :func:`synth_record`. Raises
    ``ValueError`` naming the text that is not ``NAME=VALUE`` or whose number is not one
    (``inf`` is one: ``f_y = inf`` is white sensor noise); the names are checked by
    :func:`synth_record`."""
    out: dict[str, float | str] = {}
    for spec in specs:
        if "=" not in spec:
            raise ValueError(f"--setting {spec!r}: expected NAME=VALUE")
        k, v = (x.strip() for x in spec.split("=", 1))
        try:
            out[k] = _typed(k, v)
        except ValueError:
            raise ValueError(f"--setting {spec!r}: {v!r} is not a number") from None
    return out


@dataclass(frozen=True)
class IvpConfig:
    """The emulated rig: plant (SI units), effects, controller timing, noise, converters, numerics."""

    # plant: the paper's Section 3 values (Eq. 1, 2, 8, 12, 13)
    k_DA: float = _PAPER.k_DA
    u_0: float = _PAPER.u_0
    k_i: float = _PAPER.k_i
    m_k: float = _PAPER.m_k
    g: float = _PAPER.g
    k_c: float = _PAPER.k_c
    x_0: float = _PAPER.x_0
    k_FV: float = _PAPER.k_FV          # viscous damping [N·s/m] (Eq. 8)
    k_x: float = _PAPER.k_x
    y_0: float = _PAPER.y_0
    k_AD: float = _PAPER.k_AD
    y_MU0: float = _PAPER.y_MU0
    x_min: float = _PAPER.x_min
    x_max: float = _PAPER.x_max
    x_cal: float = _PAPER.x_cal
    # effects (off by default)
    T_a: float = 0.0                   # amplifier_lag [s] (Eq. 2; 0: Eq. 5)
    T_F: float = 0.0                   # force_lag [s]
    T_d: float = 0.0                   # delay [s]
    k_x2: float = 0.0                  # sensor_nonlinearity [V/m²]
    i_max: float = _PAPER.i_max        # current_saturation [A] when lowered
    A_d: float = 0.0                   # periodic_disturbance [V]
    f_d: float = 50.0                  # [Hz]
    phi_d: float = 0.0                 # [rad]
    F_c: float = 0.0                   # coulomb_friction [N]
    v_c: float = 1e-3                  # its smoothing velocity [m/s]
    # the controller's timing: its output reaches the D/A pid_offset·ts after the reading
    pid_offset: float = 0.3
    # the controller's form: the derivative of the error or of the reading ("measurement"), filtered
    # with time constant pid_tf [s] (0: the paper's plain difference)
    pid_derivative: str = "error"
    pid_tf: float = 0.0
    # noise
    sigma_y: float = 2e-4              # sensor noise RMS [MU]
    f_y: float = 100.0                 # its corner [Hz] (inf: white)
    sigma_F_rel: float = 3e-3          # random force RMS / weight
    tau_F_noise: float = 0.02          # its time constant [s] (0: independent values at each sample)
    F_drift_rel: float = 0.0           # slow force drift RMS / weight
    tau_drift: float = 3.0             # its time constant [s]
    # converters
    bits: int = 12
    quantise: bool = True
    # numerics
    method: str = "LSODA"
    rtol: float = 1e-8
    seed: int = 0

    def with_values(self, **kw) -> IvpConfig:
        """A copy with some values changed; unknown names raise ``ValueError``."""
        names = {f.name for f in fields(self)}
        bad = sorted(set(kw) - names)
        if bad:
            raise ValueError(f"unknown emulator setting(s): {', '.join(bad)}")
        return replace(self, **kw)

    def check(self) -> None:
        """Raises ``ValueError`` naming the first setting the emulator cannot run with."""
        c = self
        for f in fields(c):
            v = getattr(c, f.name)
            if isinstance(v, float) and math.isnan(v):
                raise ValueError(f"emulator setting {f.name} is NaN")
        rules = [
            ("m_k", c.m_k > 0), ("k_c", c.k_c > 0), ("k_i", c.k_i > 0), ("g", c.g > 0), ("k_DA", c.k_DA != 0),
            ("k_x", c.k_x != 0), ("k_AD", c.k_AD != 0), ("k_FV", c.k_FV >= 0),
            ("x_max", c.x_min < c.x_max < c.x_0), ("T_a", c.T_a >= 0), ("T_F", c.T_F >= 0),
            ("T_d", 0 <= c.T_d <= 1.0), ("i_max", c.i_max > 0), ("F_c", c.F_c >= 0), ("v_c", c.v_c > 0),
            ("f_d", c.f_d >= 0), ("pid_offset", 0 <= c.pid_offset <= 1), ("sigma_y", c.sigma_y >= 0),
            ("f_y", c.f_y > 0), ("sigma_F_rel", c.sigma_F_rel >= 0), ("tau_F_noise", c.tau_F_noise >= 0),
            ("F_drift_rel", c.F_drift_rel >= 0), ("tau_drift", c.tau_drift > 0),
            ("bits", 4 <= int(c.bits) <= 24), ("rtol", 0 < c.rtol <= 1e-3), ("pid_tf", 0 <= c.pid_tf <= 1.0),
            ("pid_derivative", c.pid_derivative in ("error", "measurement")),
        ]
        for name, ok in rules:
            if not ok:
                raise ValueError(f"emulator setting {name} = {getattr(c, name)!r} is out of range")
        if not all(math.isfinite(getattr(c, n)) for n in ("k_c", "x_0", "m_k", "T_a", "T_F", "T_d", "i_max", "F_c")):
            raise ValueError("emulator: plant values must be finite")


#: Effect name -> its parameters (the names of the C table and of ``maglev-cosim diagnose --help``): the
#: table's effects this emulator writes in its own way, those whose parameters are :class:`IvpConfig` fields.
EFFECTS: dict[str, tuple[str, ...]] = emulated_effects(EFFECT_PARAMS, (f.name for f in fields(IvpConfig)))


# --------------------------------------------------------------------------- the signal chain

def reading_volts(c: IvpConfig, x: float | np.ndarray) -> float | np.ndarray:
    """The sensor's voltage without noise or pickup (Eq. 12 with the parabola ``k_x2·x·(x − x_cal)``)."""
    return c.k_x * x + c.y_0 + c.k_x2 * x * (x - c.x_cal)


def reading_mu(c: IvpConfig, x: float | np.ndarray) -> float | np.ndarray:
    """The A/D reading [MU] without noise, pickup or quantisation (Eq. 12, 13)."""
    return c.k_AD * reading_volts(c, x) + c.y_MU0


def position_reading(c: IvpConfig, y: float) -> float:
    """The position [m] whose noise-free reading is ``y`` [MU], on the travel (the root of Eq. 12's
    quadratic with the sensor nonlinearity), clipped to the stops."""
    volts = (y - c.y_MU0) / c.k_AD
    a, b, q = c.k_x2, c.k_x - c.k_x2 * c.x_cal, c.y_0 - volts
    if abs(a) < 1e-300 or abs(a * q) < 1e-12 * b * b:
        x = -q / b
    else:
        disc = max(b * b - 4 * a * q, 0.0)
        roots = [(-b + s * math.sqrt(disc)) / (2 * a) for s in (1.0, -1.0)]
        x = min(roots, key=lambda r: abs(r - 0.5 * (c.x_min + c.x_max)))
    for stop in (c.x_min, c.x_max):
        if abs(x - stop) < 1e-12:      # rounding of a reading taken on the stop
            x = stop
    return min(max(x, c.x_min), c.x_max)


def _converter(bits: int):
    lsb = 2.0 / 2 ** bits
    lo, hi = -(2 ** (bits - 1)), 2 ** (bits - 1) - 1

    def code(v: float) -> float:      # nearest code, the converter's range limiting it
        return min(max(math.floor(v / lsb + 0.5), lo), hi) * lsb
    return code, lsb


def _ou(rng: np.random.Generator, n: int, sigma: float, tau: float, ts: float) -> np.ndarray:
    """``n`` samples, ``ts`` apart, of a stationary first-order low-passed Gaussian of RMS ``sigma``
    and time constant ``tau`` (exact discretisation; ``tau = 0``: independent values)."""
    xi = rng.standard_normal(n) * sigma     # drawn even when sigma = 0: a seed's other draws stay put
    if sigma == 0:
        return np.zeros(n)
    a = math.exp(-ts / tau) if tau > 0 else 0.0
    out = np.empty(n)
    out[0] = xi[0]
    b = math.sqrt(1.0 - a * a)
    for k in range(1, n):
        out[k] = a * out[k - 1] + b * xi[k]
    return out


def sensor_noise(n: int, sigma: float, corner_hz: float, ts: float, rng: np.random.Generator) -> np.ndarray:
    """The sensor's coloured noise at the ``n`` reading instants [MU]: a first-order low-passed
    Gaussian process (corner ``corner_hz``, ``inf``: white) of RMS ``sigma``."""
    tau = 0.0 if math.isinf(corner_hz) else 1.0 / (2 * math.pi * corner_hz)
    return _ou(rng, n, sigma, tau, ts)


# --------------------------------------------------------------------------- the closed loop

def simulate(w: np.ndarray, cfg: IvpConfig | None = None, *, ts: float = 1e-3, kp: float = 2.0, ki: float = 2.97,
             kd: float = 0.01, u_min: float = 0.0, u_max: float = 1.0, noise: bool = True) -> dict[str, np.ndarray]:
    """The rig with the paper's discrete PID (Eq. 24/25) against reference ``w`` [MU].

    The loop starts settled where ``w[0]`` reads: the ball at rest there with its equilibrium
    current (limited to ``i_max``), the PID's integrator at the D/A value that holds it, the
    previous error 0. ``noise=False`` turns off the sensor noise and the random force (the
    converters' rounding stays unless ``cfg.quantise`` is False).

    Returns ``t`` [s], ``w``, ``u`` (D/A value), ``y`` (A/D reading) [MU], and at the reading
    instants the true ``x`` [m], ``v`` [m/s], ``i`` [A], ``F`` (magnetic force on the ball) [N],
    ``i_limited`` (1 where the amplifier is asked for more than ``i_max``, 0 elsewhere),
    ``contact`` (−1 on the lower stop, 1 on the upper, 0 in flight), ``F_random`` (the random
    force on the ball) [N] and ``y_noise`` (the sensor noise added to that reading) [MU]."""
    c = cfg or IvpConfig()
    c.check()
    w = np.asarray(w, dtype=float)
    n = len(w)
    if n < 2 or not np.all(np.isfinite(w)):
        raise ValueError("reference w must hold at least two finite values [MU]")
    if not (ts > 0 and u_min < u_max):
        raise ValueError(f"needs ts > 0 and u_min < u_max, got ts = {ts}, [{u_min}, {u_max}]")
    rng = np.random.default_rng(c.seed)
    weight = c.m_k * c.g
    ny = sensor_noise(n, c.sigma_y if noise else 0.0, c.f_y, ts, rng)
    # the random force at the n + 1 sample instants
    fr = _ou(rng, n + 1, c.sigma_F_rel * weight if noise else 0.0, c.tau_F_noise, ts) \
        + _ou(rng, n + 1, c.F_drift_rel * weight if noise else 0.0, c.tau_drift, ts)
    if c.quantise:
        dac, _ = _converter(int(c.bits))
        adc = dac
    else:
        def dac(v: float) -> float:
            return min(max(v, -1.0), 1.0)
        adc = dac

    lag_i, lag_F = c.T_a > 0, c.T_F > 0
    ix = 2                       # index of i in the state, then of F
    iF = 3 if lag_i else 2
    size = 2 + lag_i + lag_F
    atol = np.array([1e-12, 1e-10, 1e-9, 1e-11])[[0, 1, *([2] if lag_i else []), *([3] if lag_F else [])]]
    two_pi_fd = 2 * math.pi * c.f_d

    def amplifier(u_mu: float) -> float:
        """Eq. 1, then Eq. 2/5's static part: the current the amplifier is asked for, within [0, i_max]."""
        volts = c.k_DA * min(max(u_mu, -1.0), 1.0) + c.u_0
        return min(max(c.k_i * volts, 0.0), c.i_max)

    def static_force(i: float, x: float) -> float:
        gap = c.x_0 - x
        return c.k_c * (i / gap) ** 2          # Eq. 8

    # settled start where w[0] reads
    x_start = position_reading(c, float(w[0]))
    i_need = math.sqrt(weight / c.k_c) * (c.x_0 - x_start)
    i_hold = min(i_need, c.i_max)
    u_hold = (i_hold / c.k_i - c.u_0) / c.k_DA
    z = np.zeros(size)
    z[0] = x_start
    if lag_i:
        z[ix] = i_hold
    if lag_F:
        z[iF] = static_force(i_hold, x_start)
    tie = 1e-12 * weight            # a net force this small is rounding: it neither presses nor pulls
    contact = 0
    if x_start <= c.x_min and static_force(i_hold, x_start) + fr[0] - weight <= tie:
        contact = -1
    elif x_start >= c.x_max and static_force(i_hold, x_start) + fr[0] - weight >= -tie:
        contact = 1

    def magnetic(zz: np.ndarray, ic: float) -> tuple[float, float]:
        """(current, force on the ball) of state ``zz`` under command ``ic``."""
        i = zz[ix] if lag_i else ic
        force = zz[iF] if lag_F else static_force(i, zz[0])
        return i, force

    def advance(ta: float, tb: float, u_plant: float, k: float) -> None:
        """The plant from ``ta`` to ``tb`` with the D/A value ``u_plant`` at the coil; the random
        force interpolated over sample ``k``'s interval."""
        nonlocal z, contact
        ic = amplifier(u_plant)
        f0, slope = fr[k], (fr[k + 1] - fr[k]) / ts
        t0k = k * ts

        def push(t: float) -> float:
            return f0 + slope * (t - t0k)

        def rhs(t: float, s: np.ndarray) -> list[float]:
            x, v = s[0], s[1]
            i = s[ix] if lag_i else ic
            fs = c.k_c * (i / (c.x_0 - x)) ** 2
            force = s[iF] if lag_F else fs
            out = [0.0, 0.0] if contact else \
                [v, (force - c.k_FV * v - c.F_c * math.tanh(v / c.v_c) + push(t)) / c.m_k - c.g]
            if lag_i:
                out.append((ic - i) / c.T_a)
            if lag_F:
                out.append((fs - force) / c.T_F)
            return out

        def net(t: float, s: np.ndarray) -> float:
            return magnetic(s, ic)[1] + push(t) - weight

        t = ta
        events_here = 0
        while tb - t > 1e-13:
            if contact and contact * net(t, z) < -tie:
                contact = 0                        # pulled off the stop at once
            elif not contact:                      # on a stop and pressed into it: contact
                for side, stop in ((-1, c.x_min), (1, c.x_max)):
                    if side * (z[0] - stop) >= -1e-15 and side * z[1] >= 0 and side * net(t, z) >= -tie:
                        z[0], z[1], contact = stop, 0.0, side
            if contact:
                def release(tt, s, side=contact):
                    return side * net(tt, s) + tie
                release.terminal, release.direction = True, -1
                events = [release]
            else:
                def top(tt, s):
                    return s[0] - c.x_max
                def bottom(tt, s):
                    return s[0] - c.x_min
                top.terminal, top.direction = True, 1
                bottom.terminal, bottom.direction = True, -1
                events = [top, bottom]
            sol = solve_ivp(rhs, (t, tb), z, method=c.method, rtol=c.rtol, atol=atol, events=events)
            if not sol.success:
                raise RuntimeError(f"emulator_ivp: solve_ivp failed at t = {t:.6f} s: {sol.message}")
            z = sol.y[:, -1].copy()
            if sol.status == 1:                    # an event ended the stretch
                t = float(sol.t[-1])
                events_here += 1
                if events_here > 1000:
                    raise RuntimeError(f"emulator_ivp: the ball chatters on a stop at t = {t:.6f} s")
                if contact:
                    contact = 0                    # released
                else:
                    side = 1 if len(sol.t_events[0]) else -1
                    z[0] = c.x_max if side > 0 else c.x_min
                    z[1] = 0.0                     # inelastic: the ball stops on the stop
                    contact = side if side * net(t, z) >= -tie else 0
            else:
                t = tb

    out = {name: np.empty(n) for name in ("u", "y", "x", "v", "i", "F", "i_limited", "contact")}
    out["F_random"], out["y_noise"] = fr[:n].copy(), ny
    # the D/A values on their way to the coil: (instant they reach it, value)
    queue: deque[tuple[float, float]] = deque()
    u_coil = dac(u_hold)
    integral, d_term = u_hold, 0.0
    # the derivative's last argument: the loop was settled before the first reading, at zero error
    # (the paper's form) or at a reading the first one's (none yet: a zero derivative at the first sample)
    d_arg_prev: float | None = 0.0 if c.pid_derivative == "error" else None
    lag = c.pid_offset * ts + c.T_d
    for k in range(n):
        tk, tk1 = k * ts, (k + 1) * ts
        # the reading at t_k (Eq. 12, 13): sensor, pickup, noise, A/D
        volts = reading_volts(c, z[0]) + c.A_d * math.sin(two_pi_fd * tk + c.phi_d)
        y = adc(c.k_AD * volts + c.y_MU0 + ny[k])
        ic_now = amplifier(u_coil)
        i_now, f_now = magnetic(z, ic_now)
        out["y"][k], out["x"][k], out["v"][k], out["i"][k], out["F"][k] = y, z[0], z[1], i_now, f_now
        out["contact"][k] = contact
        unclipped = c.k_i * (c.k_DA * min(max(u_coil, -1.0), 1.0) + c.u_0)
        out["i_limited"][k] = 1.0 if unclipped > c.i_max else 0.0
        # the paper's PID (Eq. 24/25): backward-difference integral and derivative, the derivative of
        # the error or of the reading alone, filtered or not (pid_derivative, pid_tf)
        e = float(w[k]) - y
        integral += ki * ts * e
        d_arg = -y if c.pid_derivative == "measurement" else e
        diff = 0.0 if d_arg_prev is None else kd * (d_arg - d_arg_prev)
        d_term = (c.pid_tf * d_term + diff) / (c.pid_tf + ts)
        u = kp * e + integral + d_term
        u = min(max(u, u_min), u_max)
        d_arg_prev = d_arg
        u = dac(u)
        out["u"][k] = u
        queue.append((tk + lag, u))
        # the plant over [t_k, t_k+1]: the D/A value at the coil switches as the queue says
        t = tk
        while queue and queue[0][0] < tk1 - 1e-9 * ts:
            when, value = queue.popleft()
            if when > t + 1e-9 * ts:
                advance(t, when, u_coil, k)
                t = when
            u_coil = value
        advance(t, tk1, u_coil, k)
    return {"t": np.arange(n) * ts, "w": w, **out}


# --------------------------------------------------------------------------- records

def _reference(kind: str, duration: float, ts: float, seed: int, period: float | None, c: IvpConfig) -> np.ndarray:
    """A position reference [MU]: the positions every synthetic record's reference follows
    (:func:`maglev_cosim.records.emulation.reference_positions`, a profile, not physics), turned into
    readings by this emulator's own nominal sensor; its ``steps`` are drawn from this emulator's own stream."""
    x = reference_positions(kind, duration, ts, np.random.default_rng([seed, 22]), period)
    nominal = IvpConfig()
    return np.asarray(reading_mu(nominal, x), dtype=float)


def _effects_text(effects: dict[str, dict[str, float]]) -> str:
    if not effects:
        return "none"
    return "; ".join(f"{name}(" + ", ".join(f"{k}={v:g}" for k, v in pv.items()) + ")" for name, pv in effects.items())


def synth_record(out: Path, *, effects: dict[str, dict[str, float]] | None = None, reference: str = "steps",
                 duration: float = 12.0, seed: int = 0, noise: bool = True, params: dict[str, float] | None = None,
                 ts: float = 1e-3, kp: float = 2.0, ki: float = 2.97, kd: float = 0.01, u_min: float = 0.0,
                 u_max: float = 1.0, disturbance: dict[str, float] | None = None, period: float | None = None,
                 settings: dict[str, float | str] | None = None) -> Path:
    """Simulates the rig with this emulator and writes a record at ``out`` (and ``out.truth.json``).

    The arguments are those of :func:`maglev_cosim.records.synth.synth_record`: ``effects`` by catalogue
    name (:data:`EFFECTS`), plant ``params`` (:data:`PLANT_PARAMS`, SI units), ``disturbance``
    (:data:`DISTURBANCE_KEYS` and the PID gains, e.g. from :func:`maglev_cosim.records.synth.draw_disturbance`:
    ``sigma_y`` is the coloured sensor noise's RMS here). ``noise=False``: no sensor noise, random
    force or quantisation. ``settings``: this emulator's own (:data:`SETTINGS`: ``pid_offset``,
    ``f_y``, ``method``, ``rtol``, ``pid_tf``, ``pid_derivative``; the friction's ``v_c`` is a parameter of its effect). The record's metadata name the emulator, the seed and
    the effects; the sidecar holds the whole configuration."""
    effects = {name: dict(pv) for name, pv in (effects or {}).items()}
    values, dist, (kp, ki, kd) = checked_settings(effects, params, disturbance, (kp, ki, kd), EFFECTS, PLANT_PARAMS)
    own = dict(settings or {})
    bad = sorted(set(own) - set(SETTINGS))
    if bad:
        raise ValueError(f"unknown emulator setting(s) {', '.join(bad)}: choose from {', '.join(SETTINGS)}")
    own = {k: _typed(k, v) for k, v in own.items()}
    cfg = IvpConfig().with_values(**{k: float(v) for k, v in (params or {}).items()}, **values, **dist, **own,
                                  seed=int(seed))
    if not noise:
        cfg = cfg.with_values(sigma_y=0.0, sigma_F_rel=0.0, F_drift_rel=0.0, quantise=False)
    w = _reference(reference, duration, ts, seed, period, cfg)
    sim = simulate(w, cfg, ts=ts, kp=kp, ki=ki, kd=kd, u_min=u_min, u_max=u_max, noise=noise)

    out = Path(out)
    write_record(out, sim["t"], sim["w"], sim["u"], sim["y"], ts=ts, kp=kp, ki=ki, kd=kd, u_min=u_min, u_max=u_max,
                 meta={"reference": reference, **({"period": str(period)} if period else {}), "seed": str(seed),
                       "source": "maglev-cosim synth --emulator ivp (maglev_cosim.records.emulator_ivp, written from the paper)",
                       "emulator": f"ivp (solve_ivp {cfg.method}, rtol {cfg.rtol:g})",
                       "effects": _effects_text(effects)})
    truth = {"emulator": "ivp", "effects": effects, "params": params or {}, "noise": noise, "seed": seed,
             "reference": reference, **({"period_s": period} if period else {}), "duration": duration,
             "pid": {"kp": kp, "ki": ki, "kd": kd, "u_min": u_min, "u_max": u_max},
             "disturbance": {k: getattr(cfg, k) for k in DISTURBANCE_KEYS},
             "settings": {k: getattr(cfg, k) for k in SETTINGS},
             "config": {k: v for k, v in asdict(cfg).items()},
             **current_truth(sim["i"], sim["i_limited"] > 0),
             "contact_share": float(np.mean(sim["contact"] != 0))}
    Path(str(out) + ".truth.json").write_text(json.dumps(truth, indent=2, default=float))
    return out
