"""Equilibrium and Jacobian linearisation of the plant (Eq. 15–19) as python-control objects.

States ``[x, v, i]`` (Eq. 15), input ``u`` [MU], output ``y`` [MU]. With ``T_a = 0`` (Eq. 5) the
current is algebraic and the model has the two states ``[x, v]``; with a force lag ``T_F > 0``
the force ``F`` is a fourth state, and with the second force lag (``beta_F > 0``) its slow part ``F2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from . import formulas
from .params import PlantParams

if TYPE_CHECKING:   # python-control (and the matplotlib.pyplot it loads: half a second) is imported where it is
    import control  # used: a diagnosis needs none of it

#: Eq. 18 as printed (states x, v, i; input u_MU; output y_MU).
EQ18_A = np.array([[0.0, 1.0, 0.0], [3834.4, -2.4, 35.2], [0.0, 0.0, -333.3]])
EQ18_B = np.array([[0.0], [0.0], [500.0]])
EQ18_C = np.array([[122.4, 0.0, 0.0]])
EQ18_POLES = (60.73, -63.12, -333.3)     #: Eq. 19 denominator roots [1/s]
EQ19_GAIN = 2.154487e6                   #: Eq. 19 numerator
PAPER_OPERATING_POINT = (0.0032, 0.0, 0.5612)   #: [m, m/s, A], Section 4


@dataclass(frozen=True)
class OperatingPoint:
    """Equilibrium at rest: position x [m], velocity 0, current i [A], D/A input u_MU [MU],
    A/D reading y_MU [MU]."""

    x: float
    v: float
    i: float
    u_MU: float
    y_MU: float


def equilibrium_current(p: PlantParams, x: float) -> float:
    """Current [A] holding the ball at rest at ``x`` [m] (Eq. 8 with ẍ = ẋ = 0)."""
    return formulas.point(p, x).i


def operating_point(p: PlantParams, x: float) -> OperatingPoint:
    """The equilibrium at position ``x`` [m]: current, D/A input (Eq. 1, 5) and reading (Eq. 12, 13)."""
    pt = formulas.point(p, x)
    return OperatingPoint(x, 0.0, pt.i, pt.u, pt.y)


def linearize(p: PlantParams, x: float | None = None, i: float | None = None) -> control.StateSpace:
    """Jacobian linearisation (Eq. 16–17) at position ``x`` [m] (default 3.2 mm) and current ``i``
    [A] (default: the equilibrium current; the paper's Section 4 uses 0.5612 A).

    Returns
    -------
    control.StateSpace
        Named ``maglev``: input ``u`` [MU], output ``y`` [MU], states ``x`` [m], ``v`` [m/s] and,
        when their lags are on, ``i`` [A] (``T_a > 0``), ``F`` [N] (``T_F > 0``), ``F2`` [N] (the second
        force lag's slow part, ``beta_F > 0``) and ``x_s`` [m], the position the sensor sees (``T_y > 0``).
    """
    import control

    x = PAPER_OPERATING_POINT[0] if x is None else x
    pt = formulas.point(p, x, i)
    dfdx, dfdi, c_y = pt.dF_dx, pt.dF_di, pt.dy_dx     # Eq. 16, 17 and the sensor's slope
    kin = p.k_i * p.k_DA                        # [A/MU]
    lag_f = p.T_F > 0
    # the fast force's share: all of it, or 1 - beta_F beside the second lag's slow part (eddy_lag)
    fb = 1.0 - p.beta_F if p.beta_F > 0 else 1.0
    if p.T_a > 0:
        n = 4 if lag_f else 3
        A = np.zeros((n, n))
        B = np.zeros((n, 1))
        A[0, 1] = 1.0
        A[1, 1] = -p.k_FV / p.m_k
        A[2, 2] = -1.0 / p.T_a
        B[2, 0] = kin / p.T_a
        if lag_f:
            A[1, 3] = fb / p.m_k
            A[3, 0] = dfdx / p.T_F
            A[3, 2] = dfdi / p.T_F
            A[3, 3] = -1.0 / p.T_F
        else:
            A[1, 0] = fb * dfdx / p.m_k
            A[1, 2] = fb * dfdi / p.m_k
    else:
        n = 3 if lag_f else 2
        A = np.zeros((n, n))
        B = np.zeros((n, 1))
        A[0, 1] = 1.0
        A[1, 1] = -p.k_FV / p.m_k
        if lag_f:
            A[1, 2] = fb / p.m_k
            A[2, 0] = dfdx / p.T_F
            A[2, 2] = -1.0 / p.T_F
            B[2, 0] = dfdi * kin / p.T_F
        else:
            A[1, 0] = fb * dfdx / p.m_k
            B[1, 0] = fb * dfdi * kin / p.m_k
    states = ["x", "v"] + (["i"] if p.T_a > 0 else []) + (["F"] if lag_f else [])
    if p.beta_F > 0:   # the slow part F2' = (F_s - F2)/T_F2, a share beta_F of the force on the ball
        A = np.block([[A, np.zeros((n, 1))], [np.zeros((1, n + 1))]])
        B = np.vstack([B, [[0.0]]])
        A[1, n] = p.beta_F / p.m_k
        A[n, 0], A[n, n] = dfdx / p.T_F2, -1.0 / p.T_F2
        if p.T_a > 0:
            A[n, 2] = dfdi / p.T_F2
        else:
            B[n, 0] = dfdi * kin / p.T_F2
        n += 1
        states.append("F2")
    C = np.zeros((1, n))
    C[0, 0] = c_y
    if p.T_y > 0:   # the sensor's lag: x_s' = (x - x_s)/T_y, y reads x_s
        A = np.block([[A, np.zeros((n, 1))], [np.zeros((1, n + 1))]])
        A[n, 0], A[n, n] = 1.0 / p.T_y, -1.0 / p.T_y
        B = np.vstack([B, [[0.0]]])
        C = np.zeros((1, n + 1))
        C[0, n] = c_y
        states.append("x_s")
    return control.ss(A, B, C, np.zeros((1, 1)), states=states, inputs=["u"], outputs=["y"], name="maglev")


def transfer_function(p: PlantParams, x: float | None = None, i: float | None = None) -> control.TransferFunction:
    """H(s) = Y(s)/U(s) in MU/MU (Eq. 19); rounding residue of the conversion (coefficients below
    1e-12 of the largest) is removed, so the numerator is the constant of Eq. 19."""
    import control

    tf = control.ss2tf(linearize(p, x, i))
    num = np.asarray(tf.num[0][0], float)
    num = np.where(np.abs(num) < 1e-12 * np.max(np.abs(num)), 0.0, num)
    num = np.trim_zeros(num, "f")
    return control.tf(num, np.asarray(tf.den[0][0], float), inputs=["u"], outputs=["y"], name="H")
