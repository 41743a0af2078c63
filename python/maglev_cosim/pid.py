"""The paper's discrete PID (Eq. 20–25) on MU signals.

Continuous design (Eq. 20–22): zeros at −200 and −1.5, gain K = 2, so
``K_p = 2, K_d = 0.01, K_i = 2.97``. Discretised with ``s = (z − 1)/(T_s·z)`` (Eq. 23, a
backward difference although the paper calls it ZOH):

    H_c(z) = K_p + K_i·T_s·z/(z − 1) + K_d·(z − 1)/(T_s·z)          (Eq. 24, 25)

i.e. ``e[k] = w[k] − y[k]``, ``I[k] = I[k−1] + K_i·T_s·e[k]``,
``u[k] = clip(K_p·e[k] + I[k] + K_d·(e[k] − e[k−1])/T_s, u_min, u_max)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import control


@dataclass(frozen=True)
class PIDConfig:
    """Controller settings: sample time ``ts`` [s], gains (``ki`` [1/s], ``kd`` [s]), output limits
    [MU] (default [0, 1]: the rig's output stays between 0 and 4.5 V in Fig. 21), conditional
    integration anti-windup and a derivative filter time constant ``tf`` [s] (both off by default)."""

    ts: float = 1e-3
    kp: float = 2.0
    ki: float = 2.97
    kd: float = 0.01
    u_min: float = 0.0
    u_max: float = 1.0
    anti_windup: bool = False
    tf: float = 0.0


class DiscretePID:
    """The PID of Eq. 24/25 as a difference equation; :meth:`step` is one sample."""

    def __init__(self, cfg: PIDConfig | None = None) -> None:
        self.cfg = cfg or PIDConfig()
        self.reset(0.0)

    def reset(self, u_hold: float, e_prev: float = 0.0) -> None:
        """The loop settled: zero error gives output ``u_hold`` [MU] (integrator preloaded)."""
        self.integral = float(u_hold)
        self.e_prev = float(e_prev)
        self.d_prev = 0.0

    def step(self, w: float, y: float) -> float:
        """Controller output u[k] [MU] from reference w[k] and reading y[k] [MU]."""
        c = self.cfg
        e = w - y
        integral = self.integral + c.ki * c.ts * e
        if c.tf > 0:
            d = (c.tf * self.d_prev + c.kd * (e - self.e_prev)) / (c.tf + c.ts)
        else:
            d = c.kd * (e - self.e_prev) / c.ts
        v = c.kp * e + integral + d
        u = c.u_min if v < c.u_min else (c.u_max if v > c.u_max else v)
        if c.anti_windup and u != v and (v - u) * e > 0:
            integral = self.integral          # conditional integration: do not wind further
        self.integral = integral
        self.e_prev = e
        self.d_prev = d
        return u


def pid_tf(cfg: PIDConfig | None = None) -> control.TransferFunction:
    """Eq. 25 as a discrete transfer function (dt = ts), from e to u (no limits):
    ``(K_p·z(z−1) + K_i·T_s·z² + K_d/T_s·(z−1)²) / (z(z−1))``."""
    c = cfg or PIDConfig()
    num = [c.kp + c.ki * c.ts + c.kd / c.ts, -c.kp - 2 * c.kd / c.ts, c.kd / c.ts]
    return control.tf(num, [1.0, -1.0, 0.0], c.ts)


def pid_continuous_tf(kp: float = 2.0, ki: float = 2.97, kd: float = 0.01) -> control.TransferFunction:
    """The continuous PID of Eq. 20–22, ``(K_d s² + K_p s + K_i)/s``."""
    return control.tf([kd, kp, ki], [1.0, 0.0])
