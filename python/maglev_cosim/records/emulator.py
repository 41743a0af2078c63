"""An emulator of the real rig in closed loop, for synthetic records.

Written apart from the C plant the diagnosis fits (no C, no shared code beyond parameter
defaults), with its own way of adding each effect, its own integrator (RK4 on ``[x, v, i, F]``
with the current as an ODE state and stops clamped at substep ends), and the measurement chain
a real rig has:

- sensor noise: white Gaussian on the A/D reading, σ = 2e-4 MU (1 mV on the sensor's 0–5 V,
  about 0.4 LSB of the 12-bit card);
- 12-bit converters: A/D reading and D/A value quantised to 1/2048 MU (the MF614 at ±5 V; the
  example record's 0.969727 and 0.389160 are multiples of 1/2048);
- a small random force on the ball: Gaussian, low-passed with a 20 ms time constant, RMS 0.3 %
  of the weight (air draught, vibration);
- the paper's PID with its output limits.

The disturbance family is wider than these defaults (``RigConfig`` fields, and
:func:`maglev_cosim.records.synth.draw_disturbance` draws from it): white force noise held per sample
(``tau_F_noise = 0``) or coloured at any corner, a slowly drifting force offset (``F_drift_rel``,
an Ornstein-Uhlenbeck process with time constant ``tau_drift``), any sensor noise level, and
converters of 10 to 16 bits (``bits``).

Effects the catalogue also has, written here in the emulator's own way: ``force_exponent``
(force law ``k_c'·i²/(x_0 − x)^n_F`` with ``k_c'`` keeping the 3.2 mm equilibrium),
``coulomb_friction`` (``F_c·tanh(v/v_c)``, ``v_c`` = 0.1 mm/s unless set), ``amplifier_dead_zone`` (no current while the
amplifier's input is within ``±u_dz`` volts), ``sensor_drift`` (the sensor voltage's offset
creeping by ``r_y·t``) and ``force_gain_drift`` (the magnet warming: its force scaled by
``1 + kappa_c·t``, taken at the middle of each substep).

An effect the catalogue deliberately lacks, for honesty tests: ``slew_rate``, an amplifier whose
current cannot change faster than ``di_max`` [A/s], at the actuator; and ``sensor_ripple``, a
spatially periodic sensor error ``A_r·sin(2π·x/lambda_r)`` [V] (an optical sensor's fringes), at the
sensor: no catalogue effect has a reading that wiggles with the position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from ..plant.params import EFFECT_PARAMS
from .emulation import emulated_effects, reference_positions

LSB = 1.0 / 2048.0       # [MU] the default 12-bit converter over ±1 MU (RigConfig.bits)


@dataclass(frozen=True)
class RigConfig:
    """The emulated rig: plant parameters (SI units), effects, measurement chain and seed."""

    k_DA: float = 5.0
    u_0: float = 0.0
    k_i: float = 0.3
    m_k: float = 8.4e-3
    g: float = 9.81
    k_c: float = 6.9e-6
    x_0: float = 8.3e-3
    k_FV: float = 0.03
    k_x: float = 612.3
    y_0: float = 0.0125
    k_AD: float = 0.2
    y_MU0: float = 0.0
    x_min: float = 0.0
    x_max: float = 6.3e-3
    i_max: float = 1.5          # current_saturation when lowered
    T_a: float = 0.0            # amplifier_lag (the baseline neglects it, Eq. 5)
    T_F: float = 0.0            # force_lag
    beta_F: float = 0.0         # eddy_lag: the share of the force behind a second, slower lag
    T_F2: float = 0.01          # eddy_lag: that lag's time constant [s]
    T_d: float = 0.0            # delay
    k_x2: float = 0.0           # sensor_nonlinearity
    x_cal: float = 6.3e-3
    A_d: float = 0.0            # periodic_disturbance
    f_d: float = 50.0
    phi_d: float = 0.0
    n_F: float = 2.0            # force_exponent
    F_c: float = 0.0            # coulomb_friction [N]
    v_c: float = 1e-4           # its smoothing speed [m/s]
    u_dz: float = 0.0           # amplifier_dead_zone [V]
    T_y: float = 0.0            # sensor_lag [s]: the sensor sees the position through a first-order lag
    r_y: float = 0.0            # sensor_drift [V/s]: the sensor's offset creeps while its electronics warm up
    kappa_c: float = 0.0        # force_gain_drift [1/s]: the magnet's force gain changes as coil and core warm
    di_max: float = 0.0         # slew_rate [A/s] (outside the catalogue; 0 = off)
    A_r: float = 0.0            # sensor_ripple [V] (outside the catalogue; 0 = off)
    lambda_r: float = 5e-4      # its spatial period [m]
    sigma_y: float = 2e-4       # [MU] sensor noise
    sigma_F_rel: float = 3e-3   # random force RMS / weight
    tau_F_noise: float = 0.02   # [s] low-pass of the random force
    F_drift_rel: float = 0.0    # RMS of a slowly drifting force offset / weight
    tau_drift: float = 3.0      # [s] time constant of the drift
    bits: int = 12              # converter resolution over +-1 MU
    quantise: bool = True
    seed: int = 0
    extra: dict = field(default_factory=dict)

    def with_values(self, **kw: float) -> RigConfig:
        names = {f.name for f in fields(self)}
        bad = sorted(set(kw) - names)
        if bad:
            raise ValueError(f"unknown rig parameter(s): {', '.join(bad)}")
        return replace(self, **kw)


#: The emulator's effects the catalogue deliberately lacks (honesty tests), with their parameters.
OUTSIDE_CATALOGUE: dict[str, tuple[str, ...]] = {"slew_rate": ("di_max",), "sensor_ripple": ("A_r", "lambda_r")}

#: Effect name -> its parameters (rig names = FMU names for the catalogue): the C table's effects this
#: emulator writes in its own way (those with a :class:`RigConfig` field), then :data:`OUTSIDE_CATALOGUE`.
EFFECTS: dict[str, tuple[str, ...]] = emulated_effects(EFFECT_PARAMS, (f.name for f in fields(RigConfig)),
                                                       OUTSIDE_CATALOGUE)


def position_to_mu(cfg: RigConfig, x: float | np.ndarray) -> float | np.ndarray:
    """Noise-free A/D reading [MU] at position x [m] (Eq. 12, 13 with the sensor nonlinearity)."""
    return cfg.k_AD * (cfg.k_x * x + cfg.y_0 + cfg.k_x2 * x * (x - cfg.x_cal)) + cfg.y_MU0


def _position_for(cfg: RigConfig, y: float) -> float:
    lo, hi = cfg.x_min, cfg.x_max
    for _ in range(200):                    # bisection: the reading grows with x on the travel
        mid = 0.5 * (lo + hi)
        if position_to_mu(cfg, mid) < y:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def reference(kind: str, duration: float, ts: float = 1e-3, seed: int = 0, cfg: RigConfig | None = None,
              period: float | None = None) -> np.ndarray:
    """A position reference [MU] of :func:`maglev_cosim.records.emulation.reference_positions` (``square``,
    ``sine``, ``steps``, ``chirp``; ``steps`` drawn with ``seed``), read by the nominal sensor. ``cfg`` is
    accepted for the callers' convenience and does not change it."""
    x = reference_positions(kind, duration, ts, np.random.default_rng(seed), period)
    base = RigConfig()          # the reference is defined on the nominal sensor
    return np.asarray(position_to_mu(base, x), dtype=float)


def simulate_rig(w: np.ndarray, cfg: RigConfig, *, ts: float = 1e-3, kp: float = 2.0, ki: float = 2.97,
                 kd: float = 0.01, u_min: float = 0.0, u_max: float = 1.0, noise: bool = True) -> dict[str, np.ndarray]:
    """The rig in closed loop with the paper's PID against reference ``w`` [MU].

    Returns t [s], w, u (D/A value), y (A/D reading) [MU], the true x [m], v [m/s], i [A], and
    i_limited: 1 where the current the D/A value asks for exceeds the amplifier's limit i_max, else 0."""
    c = cfg
    rng = np.random.default_rng(c.seed)
    n = len(w)
    mg = c.m_k * c.g
    kc = c.k_c * (c.x_0 - 3.2e-3) ** (c.n_F - 2.0)
    expo = c.n_F

    def force(i: float, x: float) -> float:
        return kc * i * i / (c.x_0 - x) ** expo

    def demand(u_mu: float) -> float:     # the current the amplifier is asked for, before its limit
        volts = c.k_DA * min(max(u_mu, -1.0), 1.0) + c.u_0
        if c.u_dz > 0:
            volts = 0.0 if abs(volts) <= c.u_dz else volts - math.copysign(c.u_dz, volts)
        return c.k_i * volts

    def command(u_mu: float) -> float:
        return min(max(demand(u_mu), 0.0), c.i_max)

    # settled start at the first reference value
    x = _position_for(c, float(w[0]))
    i_eq = min(math.sqrt(mg * (c.x_0 - x) ** expo / kc), c.i_max)
    u_hold = (i_eq / c.k_i + (c.u_dz if i_eq > 0 else 0.0) - c.u_0) / c.k_DA
    v, i, F = 0.0, i_eq, force(i_eq, x)
    F2 = F                                   # the slow part of the force (eddy_lag), settled too
    xs = x                                   # the position the sensor sees (its lag T_y has settled)

    h_max = min(1e-4, c.T_a / 10 if c.T_a > 0 else 1.0, c.T_F / 4 if c.T_F > 0 else 1.0,
                c.T_F2 / 4 if c.beta_F > 0 else 1.0)
    nsub = max(1, int(math.ceil(ts / h_max - 1e-9)))
    lag_i, lag_F = c.T_a > 0, c.T_F > 0
    Ta, TF, kfv, m = c.T_a, c.T_F, c.k_FV, c.m_k
    beta, TF2 = c.beta_F, c.T_F2
    fc, vc = c.F_c, c.v_c

    def accel(xx: float, vv: float, ff: float, fr: float) -> float:
        a = (ff - kfv * vv + fr) / m - c.g
        if fc > 0:
            a -= fc * math.tanh(vv / vc) / m
        return a

    # random force: low-passed Gaussian, RMS sigma_F (tau_F_noise = 0: white, held over each sample),
    # plus a slowly drifting offset (Ornstein-Uhlenbeck), both drawn per sample
    sigma_F = c.sigma_F_rel * mg if noise else 0.0
    a_lp = math.exp(-ts / c.tau_F_noise) if c.tau_F_noise > 0 else 0.0
    sigma_D = c.F_drift_rel * mg if noise else 0.0
    a_dr = math.exp(-ts / c.tau_drift) if c.tau_drift > 0 else 0.0
    lsb = 2.0 / 2.0 ** c.bits
    noise_y = rng.standard_normal(n) * (c.sigma_y if noise else 0.0)
    noise_f = rng.standard_normal(n)
    noise_d = rng.standard_normal(n) if sigma_D > 0 else np.zeros(n)
    f_col = rng.standard_normal() * sigma_F      # both processes start in their stationary law
    f_dr = rng.standard_normal() * sigma_D if sigma_D > 0 else 0.0
    fr = f_col + f_dr

    m_delay = int(math.floor(c.T_d / ts + 1e-9))
    r_delay = c.T_d - m_delay * ts
    if r_delay < 1e-12:
        r_delay = 0.0
    dac = np.empty(n)
    out = {k: np.empty(n) for k in ("u", "y", "x", "v", "i", "i_limited")}
    integral, e_prev = u_hold, 0.0
    u_hold_q = round(u_hold / lsb) * lsb if c.quantise else u_hold

    def dac_at(j: int) -> float:
        return dac[j] if j >= 0 else u_hold_q

    def integrate(t0: float, span: float, u_val: float, steps: int) -> None:
        nonlocal x, v, i, F, xs, F2
        ic = command(u_val)
        if not lag_i and c.di_max <= 0:
            i = ic
        h = span / steps
        q_s = math.exp(-h / c.T_y) if c.T_y > 0 else 0.0
        for j in range(steps):
            if not lag_i and c.di_max > 0:     # slew-limited current
                i += min(max(ic - i, -c.di_max * h), c.di_max * h)
            # the warming magnet (force_gain_drift): its gain over this substep, held at the substep's middle
            warm = max(0.0, 1.0 + c.kappa_c * (t0 + (j + 0.5) * h)) if c.kappa_c else 1.0
            # derivatives of (x, v, i, F, F2)
            def d(xx: float, vv: float, ii: float, ff: float, f2: float) -> tuple[float, ...]:
                fs = warm * force(ii, xx)
                f_act = ff if lag_F else fs
                if beta > 0:   # eddy currents: a share beta of the force answers late, through TF2
                    f_act = (1.0 - beta) * f_act + beta * f2
                return (vv, accel(xx, vv, f_act, fr), (ic - ii) / Ta if lag_i else 0.0,
                        (fs - ff) / TF if lag_F else 0.0, (fs - f2) / TF2 if beta > 0 else 0.0)

            k1 = d(x, v, i, F, F2)
            k2 = d(x + h / 2 * k1[0], v + h / 2 * k1[1], i + h / 2 * k1[2], F + h / 2 * k1[3], F2 + h / 2 * k1[4])
            k3 = d(x + h / 2 * k2[0], v + h / 2 * k2[1], i + h / 2 * k2[2], F + h / 2 * k2[3], F2 + h / 2 * k2[4])
            k4 = d(x + h * k3[0], v + h * k3[1], i + h * k3[2], F + h * k3[3], F2 + h * k3[4])
            x += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            v += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            if lag_i:
                di = h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
                i += min(max(di, -c.di_max * h), c.di_max * h) if c.di_max > 0 else di
            if lag_F:
                F += h / 6 * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3])
            if beta > 0:
                F2 += h / 6 * (k1[4] + 2 * k2[4] + 2 * k3[4] + k4[4])
            # inelastic stops, clamped at the end of each substep
            if x >= c.x_max:
                x, v = c.x_max, min(v, 0.0)
            elif x <= c.x_min:
                x, v = c.x_min, max(v, 0.0)
            xs = x + (xs - x) * q_s     # the sensor's lag, x held at the substep's end

    two_pi_f = 2 * math.pi * c.f_d
    for k in range(n):
        t = k * ts
        yv = c.k_x * xs + c.y_0 + c.k_x2 * xs * (xs - c.x_cal) + c.A_d * math.sin(two_pi_f * t + c.phi_d)
        if c.r_y:   # the offset the sensor had at the start, crept on since
            yv += c.r_y * t
        if c.A_r:   # a spatially periodic error of the sensor (an optical sensor's fringes)
            yv += c.A_r * math.sin(2 * math.pi * x / c.lambda_r)
        y = c.k_AD * yv + c.y_MU0 + noise_y[k]
        y = min(max(y, -1.0), 1.0)
        if c.quantise:
            y = round(y / lsb) * lsb
        out["y"][k], out["x"][k], out["v"][k], out["i"][k] = y, x, v, i
        e = w[k] - y
        integ = integral + ki * ts * e
        u = kp * e + integ + kd * (e - e_prev) / ts
        u = min(max(u, u_min), u_max)
        integral, e_prev = integ, e
        if c.quantise:
            u = round(u / lsb) * lsb
        out["u"][k] = u
        dac[k] = u
        out["i_limited"][k] = 1.0 if demand(dac_at(k - m_delay)) > c.i_max else 0.0
        f_col = a_lp * f_col + math.sqrt(1 - a_lp * a_lp) * sigma_F * noise_f[k]
        f_dr = a_dr * f_dr + math.sqrt(1 - a_dr * a_dr) * sigma_D * noise_d[k]
        fr = f_col + f_dr
        # the delayed D/A value switches at t_k + r_delay inside this sample
        if r_delay > 0:
            n1 = max(1, int(round(nsub * r_delay / ts)))
            n2 = max(1, nsub - n1)
            integrate(t, r_delay, dac_at(k - m_delay - 1), n1)
            integrate(t + r_delay, ts - r_delay, dac_at(k - m_delay), n2)
        else:
            integrate(t, ts, dac_at(k - m_delay), nsub)
    return {"t": np.arange(n) * ts, "w": np.asarray(w, float), **out}
