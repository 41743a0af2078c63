"""An independent pure-Python reference of the plant, to cross-check the C code.

Same equations and limits as docs/model.md, written apart from the C plant and integrated by a
different kind of method: scipy's ``solve_ivp`` (DOP853, tight tolerances) on the full state
``[x, v, i, F, x_s, F_2]`` (``x_s``: the position the sensor sees through its lag ``T_y``; ``F_2``:
the slow part of the force, effect ``eddy_lag``) between input breakpoints, with stop impacts and releases as terminal events.
Nothing here calls C. :func:`maglev_cosim.loop.simulate.simulate` runs it in closed loop
(``backend="reference"``).
"""

from __future__ import annotations

import math
from bisect import bisect_right

import numpy as np
from scipy.integrate import solve_ivp

from .params import PlantParams

RTOL = 1e-12
ATOL = np.array([1e-16, 1e-14, 1e-14, 1e-14, 1e-16, 1e-14])


class ReferencePlant:
    """The plant advanced by ``step(h)``; input held between calls (``set_input``)."""

    def __init__(self, params: PlantParams) -> None:
        params.validate()
        self.p = params
        self.reset(0.0)

    def reset(self, u0: float = 0.0) -> None:
        """Initial state from x_start, v_start, i_start; ``u0`` [MU] is also the input before t = 0."""
        p = self.p
        self.time = 0.0
        self.u = float(u0)
        self.hist_t: list[float] = [-math.inf]
        self.hist_u: list[float] = [self.u]
        self.volt = p.R_c > 0  # a voltage drive: the current is a state, the piece's input a voltage
        i = p.i_start if (p.T_a > 0 or self.volt) else self._command(self.u)
        F = self._force(i, p.x_start)
        self.z = np.array([p.x_start, p.v_start, i, F, p.x_start, F])
        self.mode = 0
        net = F - p.m_k * p.g
        if p.x_start >= p.x_max and (p.v_start > 0 or (p.v_start == 0 and net >= 0)):
            self.mode, self.z[1] = 1, 0.0
        elif p.x_start <= p.x_min and (p.v_start < 0 or (p.v_start == 0 and net <= 0)):
            self.mode, self.z[1] = -1, 0.0

    # --- the equations (Eq. 1, 2/5, 8, 12, 13)
    def _command(self, u_mu: float) -> float:
        """The current command (Eq. 2/5), or with a voltage drive the coil voltage."""
        p = self.p
        volts = p.k_DA * min(max(u_mu, -1.0), 1.0) + p.u_0
        volts = math.copysign(max(abs(volts) - p.u_dz, 0.0), volts)      # the amplifier's dead zone
        if p.R_c > 0:
            return max(volts, p.V_min)
        return min(max(p.k_i * volts, 0.0), p.i_max)

    def _coil(self, volts: float, i: float, x: float, v: float, t: float) -> float:
        """di/dt of a voltage drive at time ``t``: d(L(x, i)·i)/dt = V − R·i with the winding's
        resistance R = R_c·max(0, 1 + kappa_R·t) (warming during the run), held at 0 and i_max."""
        p = self.p
        resistance = p.R_c * max(0.0, 1.0 + p.kappa_R * t)
        dL_dx = p.L_x / p.z_L * math.exp(-(p.x_0 - x) / p.z_L)
        L = p.L_0 + p.L_x * math.exp(-(p.x_0 - x) / p.z_L) + p.L_i * math.atan(p.a_i * i - p.b_i)
        if p.L_g > 0:  # the inverse-gap form
            L += p.L_g / (p.x_0 - x)
            dL_dx += p.L_g / (p.x_0 - x) ** 2
        dL_di = p.L_i * p.a_i / (1.0 + (p.a_i * i - p.b_i) ** 2)
        rate = (volts - resistance * i - i * dL_dx * v) / (L + i * dL_di)
        return 0.0 if (i <= 0 and rate < 0) or (i >= p.i_max and rate > 0) else rate

    def _force(self, i: float, x: float, t: float = 0.0) -> float:
        """The static force law at time ``t``: Eq. 8 (and the exponential law), its gain drifting by
        the factor ``max(0, 1 + kappa_c·t)`` (effect force_gain_drift: the coil and magnet warming)."""
        p = self.p
        gap = p.x_0 - x
        heat = max(0.0, 1.0 + p.kappa_c * t)
        law_e = p.k_e * math.exp(-gap / p.z_e) * i * i  # the exponential law of other rigs
        if p.k_c == 0:  # the exponential law alone: the ball may touch the coil (gap 0)
            return heat * law_e
        return heat * (p.k_c * i * i / gap**2 * ((p.x_0 - p.x_n) / gap) ** (p.n_F - 2.0) + law_e)

    def _rhs(self, ic: float):
        p = self.p

        def f(t: float, z: np.ndarray) -> np.ndarray:
            x, v, i, F, xs, F2 = z
            dxs = (x - xs) / p.T_y if p.T_y > 0 else 0.0
            if self.volt:
                di = self._coil(ic, i, x, 0.0 if self.mode else v, t)
            else:
                di = (ic - i) / p.T_a if p.T_a > 0 else 0.0
            fs = self._force(i if (p.T_a > 0 or self.volt) else ic, x, t)
            dF = (fs - F) / p.T_F if p.T_F > 0 else 0.0
            # the second, slower lag of a share beta_F of the force (effect eddy_lag)
            dF2 = (fs - F2) / p.T_F2 if p.beta_F > 0 else 0.0
            force = self._felt(F if p.T_F > 0 else fs, F2)
            if self.mode:
                return np.array([0.0, 0.0, di, dF, dxs, dF2])
            friction = p.F_c * math.tanh(v / p.v_c) if p.F_c > 0 else 0.0
            return np.array([v, (force - p.k_FV * v - friction) / p.m_k - p.g, di, dF, dxs, dF2])

        return f

    def _felt(self, fast: float, F2: float) -> float:
        """The force the ball feels: the fast part (the force lag's output or the static force) and,
        with the effect eddy_lag, the share beta_F of the slow lag's output."""
        b = self.p.beta_F
        return (1.0 - b) * fast + b * F2 if b > 0 else fast

    def _net(self, z: np.ndarray, ic: float, t: float) -> float:
        p = self.p
        force = z[3] if p.T_F > 0 else self._force(z[2] if (p.T_a > 0 or self.volt) else ic, z[0], t)
        return self._felt(force, z[5]) - p.m_k * p.g

    def set_input(self, u: float) -> None:
        """The D/A input [MU] from now on."""
        if not math.isfinite(u):
            raise ValueError(f"variable u: value {u} is not finite")
        self.u = float(u)
        if self.hist_t[-1] >= self.time:
            self.hist_u[-1] = self.u
        elif self.hist_u[-1] != self.u:
            self.hist_t.append(self.time)
            self.hist_u.append(self.u)

    def _delayed(self, t: float) -> float:
        k = bisect_right(self.hist_t, t - self.p.T_d + 1e-12) - 1
        return self.hist_u[max(k, 0)]

    def step(self, h: float) -> None:
        """Advances ``h`` seconds."""
        if not h > 0:
            raise ValueError(f"step size {h} must be > 0")
        p = self.p
        t_end = self.time + h
        cuts = sorted({tc + p.T_d for tc in self.hist_t if self.time + 1e-12 < tc + p.T_d < t_end - 1e-12})
        for a, b in zip([self.time, *cuts], [*cuts, t_end]):
            self._piece(a, b, self._command(self._delayed(0.5 * (a + b))))
        self.time = t_end

    def _piece(self, t0: float, t1: float, ic: float) -> None:
        p = self.p
        if p.T_a <= 0 and not self.volt:
            self.z[2] = ic
            if p.T_F <= 0:
                self.z[3] = self._force(ic, self.z[0], t0)
        t = t0
        while t1 - t > 1e-15:
            if self.mode and self.mode * self._net(self.z, ic, t) < 0:
                # the net force jumped away from the stop at the piece's start (an algebraic
                # current or force): no sign change left for the release event to catch
                self.mode = 0
            if self.mode == 0:
                hit_top = lambda _t, z: z[0] - p.x_max  # noqa: E731
                hit_bottom = lambda _t, z: z[0] - p.x_min  # noqa: E731
                hit_top.terminal, hit_top.direction = True, 1
                hit_bottom.terminal, hit_bottom.direction = True, -1
                events = [hit_top, hit_bottom]
            else:
                sign = self.mode
                release = lambda t_, z: sign * self._net(z, ic, t_)  # noqa: E731
                release.terminal, release.direction = True, -1
                events = [release]
            sol = solve_ivp(self._rhs(ic), (t, t1), self.z, method="DOP853", rtol=RTOL, atol=ATOL,
                            events=events)
            self.z = sol.y[:, -1].copy()
            if sol.status == 1:
                t = float(sol.t[-1])
                if self.mode == 0:
                    top = len(sol.t_events[0]) > 0
                    self.z[0] = p.x_max if top else p.x_min
                    self.z[1] = 0.0
                    stop = 1 if top else -1
                    self.mode = stop if stop * self._net(self.z, ic, t) >= 0 else 0
                else:
                    self.mode = 0
            else:
                t = t1
        if p.T_a <= 0 and not self.volt:
            self.z[2] = ic

    def outputs(self) -> dict[str, float]:
        """y [MU] (Eq. 12, 13), x [m], v [m/s], i [A], F [N] now."""
        p = self.p
        x, v, i, F, xs, F2 = self.z
        xs = xs if p.T_y > 0 else x     # the sensor's lag (Eq. 12 reads x itself without it)
        if p.T_a <= 0 and not self.volt:
            i = self._command(self._delayed(self.time))
        force = self._felt(F if p.T_F > 0 else self._force(i, x, self.time), F2)
        yv = p.k_x * xs + p.y_0 + p.k_x2 * xs * (xs - p.x_cal) + p.A_d * math.sin(2 * math.pi * p.f_d * self.time + p.phi_d)
        yv += p.r_y * self.time         # the sensor's offset drifting since t = 0 (effect sensor_drift)
        y = min(max(p.k_AD * yv + p.y_MU0, -1.0), 1.0)
        return {"y": y, "x": float(x), "v": float(v), "i": float(i), "F": float(force)}
