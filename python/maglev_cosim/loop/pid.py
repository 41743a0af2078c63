"""The paper's discrete PID (Eq. 20–25) on MU signals.

Continuous design (Eq. 20–22): zeros at −200 and −1.5, gain K = 2, so
``K_p = 2, K_d = 0.01, K_i = 2.97``. Discretised with ``s = (z − 1)/(T_s·z)`` (Eq. 23, a
backward difference although the paper calls it ZOH):

    H_c(z) = K_p + K_i·T_s·z/(z − 1) + K_d·(z − 1)/(T_s·z)          (Eq. 24, 25)

i.e. ``e[k] = w[k] − y[k]``, ``I[k] = I[k−1] + K_i·T_s·e[k]``,
``u[k] = clip(K_p·e[k] + I[k] + K_d·(e[k] − e[k−1])/T_s, u_min, u_max)``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

if TYPE_CHECKING:   # python-control (and the matplotlib.pyplot it loads: half a second) is imported where it is
    import control  # used: a diagnosis needs none of it

ANTI_WINDUP = ("none", "conditional", "clamping", "band")
#: What the derivative term differentiates: the error (Eq. 24) or the reading alone (no kick of
#: the output at a reference step; C ``d_on_y``).
DERIVATIVE = ("error", "measurement")


@dataclass(frozen=True)
class PID:
    """The paper's discrete PID (Eq. 24/25), with the usual extensions of real rigs.

    Parameters
    ----------
    ts : float
        Sample time [s] (Sec. 4.6: 1 ms).
    kp, ki, kd : float
        Gains: ``kp`` [MU/MU], ``ki`` [1/s], ``kd`` [s] (Eq. 22: 2, 2.97, 0.01).
    u_min, u_max : float
        Output limits [MU] (default [0, 1]: the rig's output stays between 0 and 4.5 V in Fig. 21).
    tf : float
        Derivative filter time constant [s] (0: the paper's unfiltered difference).
    anti_windup : {"none", "conditional", "clamping", "band"}
        ``conditional``: the integrator holds while the output saturates and the error pushes
        further into the limit; ``clamping``: the integrator stays within [u_min, u_max];
        ``band`` (as microcontroller firmware often has it): the integrator integrates only while
        its last value lies strictly inside ``(i_lo, i_hi)``, and is otherwise pulled back to
        ``clip(I, backoff·i_lo, backoff·i_hi)``.
    i_lo, i_hi : float
        The band [MU] (``anti_windup="band"``).
    backoff : float
        Where the band pulls the integrator back to, as a fraction of its limits (0, 1].
    derivative : {"error", "measurement"}
        ``error``: the paper's derivative of ``e = w - y`` (Eq. 24); ``measurement``: of ``-y``
        alone, as many PIDs compute it to spare the output a kick at each reference step.

    Examples
    --------
    >>> pid = PID()
    >>> state = pid.start(u_hold=0.37)      # settled: zero error gives the holding input
    >>> round(state.step(w=0.40, y=0.39), 6)   # 0.37 + kp*e + ki*ts*e + kd*e/ts with e = 0.01
    0.49003
    """

    ts: float = 1e-3
    kp: float = 2.0
    ki: float = 2.97
    kd: float = 0.01
    u_min: float = 0.0
    u_max: float = 1.0
    tf: float = 0.0
    anti_windup: str = "none"
    i_lo: float = 0.0
    i_hi: float = 0.0
    backoff: float = 1.0
    derivative: str = "error"

    def __post_init__(self) -> None:
        vals = (self.ts, self.kp, self.ki, self.kd, self.u_min, self.u_max, self.tf, self.i_lo, self.i_hi, self.backoff)
        if not all(isinstance(v, (int, float)) and v == v and abs(v) != float("inf") for v in vals):
            raise ValueError(f"PID: every setting must be a finite number, got {self}")
        if self.ts <= 0 or self.tf < 0 or not self.u_min < self.u_max:
            raise ValueError(f"PID: needs ts > 0 s, tf >= 0 s and u_min < u_max, got ts = {self.ts}, "
                             f"tf = {self.tf}, limits [{self.u_min}, {self.u_max}] MU")
        if self.anti_windup not in ANTI_WINDUP:
            raise ValueError(f"PID: anti_windup must be one of {', '.join(ANTI_WINDUP)}, got {self.anti_windup!r}")
        if self.derivative not in DERIVATIVE:
            raise ValueError(f"PID: derivative must be one of {', '.join(DERIVATIVE)}, got {self.derivative!r}")
        if self.anti_windup == "band" and not (self.i_lo < self.i_hi and 0 < self.backoff <= 1):
            raise ValueError(f"PID: the band needs i_lo < i_hi and 0 < backoff <= 1, got [{self.i_lo}, {self.i_hi}], "
                             f"backoff {self.backoff}")

    def replace(self, **changes) -> PID:
        """A copy with some settings changed."""
        return replace(self, **changes)

    def start(self, u_hold: float = 0.0, w0: float = 0.0, y0: float | None = None) -> DiscretePID:
        """A running controller, settled (:meth:`DiscretePID.reset`): output ``u_hold`` [MU] at the
        first reference ``w0`` and first reading ``y0`` [MU] (None: ``w0``)."""
        return DiscretePID(self, u_hold, w0, y0)

    def c_settings(self) -> dict[str, float | int]:
        """The settings as the C replay's ``MaglevPid`` holds them."""
        return {"ts": self.ts, "kp": self.kp, "ki": self.ki, "kd": self.kd, "u_min": self.u_min,
                "u_max": self.u_max, "tf": self.tf, "anti_windup": ANTI_WINDUP.index(self.anti_windup),
                "i_lo": self.i_lo, "i_hi": self.i_hi, "backoff": self.backoff,
                "d_on_y": DERIVATIVE.index(self.derivative)}

    def tf_discrete(self) -> control.TransferFunction:
        """Eq. 25 from e to u (no limits, no filter): see :func:`pid_tf`."""
        return pid_tf(self)


class DiscretePID:
    """A running :class:`PID`: :meth:`step` is one sample of the difference equation. The C replay
    (``c/maglev_replay.c``) has the same equation; ``tests/test_pid.py`` cross-checks the two."""

    def __init__(self, cfg: PID | None = None, u_hold: float = 0.0, w0: float = 0.0, y0: float | None = None) -> None:
        self.cfg = cfg or PID()
        self.reset(u_hold, w0=w0, y0=y0)

    def reset(self, u_hold: float, w0: float = 0.0, y0: float | None = None) -> None:
        """The loop settled, at rest before the first sample with the reading at ``y0`` [MU] (None:
        at the first reference ``w0`` [MU]): the error stood at ``e0 = w0 − y0`` and the output held
        ``u_hold`` [MU], so the integrator is ``u_hold − kp·e0`` and the derivative's last argument
        ``e0`` (``−y0`` with ``derivative="measurement"``): no kick at the first sample. The C
        replay's settled start (``ctl_start`` in ``c/maglev_replay.c``) is the same."""
        y0 = float(w0) if y0 is None else float(y0)
        e0 = float(w0) - y0
        self.integral = float(u_hold) - self.cfg.kp * e0
        self.e_prev = -y0 if self.cfg.derivative == "measurement" else e0
        self.d_prev = 0.0

    def step(self, w: float, y: float) -> float:
        """Controller output u[k] [MU] from reference w[k] and reading y[k] [MU]."""
        c = self.cfg
        e = w - y
        integral = self.integral + c.ki * c.ts * e
        if c.anti_windup == "band" and not c.i_lo < self.integral < c.i_hi:
            integral = min(max(self.integral, c.backoff * c.i_lo), c.backoff * c.i_hi)
        de = -y if c.derivative == "measurement" else e     # the derivative's argument
        if c.tf > 0:
            d = (c.tf * self.d_prev + c.kd * (de - self.e_prev)) / (c.tf + c.ts)
        else:
            d = c.kd * (de - self.e_prev) / c.ts
        v = c.kp * e + integral + d
        u = c.u_min if v < c.u_min else (c.u_max if v > c.u_max else v)
        if c.anti_windup == "conditional" and u != v and (v - u) * e > 0:
            integral = self.integral          # do not wind further into the limit
        elif c.anti_windup == "clamping":
            integral = c.u_min if integral < c.u_min else (c.u_max if integral > c.u_max else integral)
        self.integral = integral
        self.e_prev = de
        self.d_prev = d
        return u


def pid_tf(cfg: PID | None = None) -> control.TransferFunction:
    """Eq. 25 as a discrete transfer function (dt = ts), from e to u (no limits):
    ``(K_p·z(z−1) + K_i·T_s·z² + K_d/T_s·(z−1)²) / (z(z−1))``."""
    import control

    c = cfg or PID()
    num = [c.kp + c.ki * c.ts + c.kd / c.ts, -c.kp - 2 * c.kd / c.ts, c.kd / c.ts]
    return control.tf(num, [1.0, -1.0, 0.0], c.ts)


def pid_continuous_tf(kp: float = 2.0, ki: float = 2.97, kd: float = 0.01) -> control.TransferFunction:
    """The continuous PID of Eq. 20–22, ``(K_d s² + K_p s + K_i)/s``."""
    import control

    return control.tf([kd, kp, ki], [1.0, 0.0])
