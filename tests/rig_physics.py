"""Two other rigs' physics in plant coordinates, and the open-loop run the C plant and the
pure-Python reference are compared on (tests/test_cosim.py, tests/test_eddy_lag.py)."""

from __future__ import annotations

import numpy as np

from maglev_cosim.plant import fast
from maglev_cosim.plant.formulas import point
from maglev_cosim.plant.params import get_params
from maglev_cosim.plant.reference import ReferencePlant

# x grows toward the coil; the rig files in maglev_cosim/rigs map their gap conventions onto this:
# Inteco's exponential force law with a voltage-driven coil L(x, i) and a PWM floor, and the
# levitador's Eq. 8 law with L = L_0 + L_g/gap.
INTECO = dict(k_c=0.0, k_e=3.2, z_e=6.3e-3, x_0=0.0, x_n=-0.03, x_min=-0.0218, x_max=0.0, m_k=0.06054, k_FV=0.0,
              R_c=4.17, L_0=0.0654, L_x=0.0404, z_L=6.3e-3, L_i=0.0329, a_i=5.3, b_i=1.04, V_min=0.043,
              k_DA=11.658, u_0=-0.5608, i_max=3.0, k_x=1.0, y_0=0.0, k_AD=40.0, x_start=-0.012)
RIG_PHYSICS = {
    "exponential law, voltage drive, L(x, i)": INTECO,
    "Eq. 8 law, voltage drive, inverse-gap L": dict(
        k_c=9.1e-6, x_0=0.0052, x_n=0.0, x_min=-0.03, x_max=0.0, m_k=0.018, k_FV=0.0, R_c=2.72,
        L_0=0.0363, L_g=1.82e-5, k_DA=12.0, i_max=5.0, k_x=1.0, y_0=0.0, k_AD=30.0, x_start=-0.01),
}


def open_loop_pair(physics: dict, extra: dict | None = None) -> tuple[dict, dict]:
    """The plant from rest at its equilibrium, a 2 % input wobble, 0.3 s (the open-loop plant is
    unstable: the ball lifts or drops, through free flight and onto a stop): the C plant's and the
    reference's x [m], i [A], F [N], y [MU] per sample."""
    base = get_params("baseline").replace(**physics, **(extra or {}))
    p = base.replace(i_start=point(base, base.x_start).i)
    u = point(base, base.x_start).u * (1 + 0.02 * np.sin(np.arange(300) * 0.03))
    c = fast.open_loop(p.to_start_values(), u)
    ref = ReferencePlant(p)
    ref.reset(u[0])
    r: dict[str, list] = {"x": [], "i": [], "F": [], "y": []}
    for k in range(len(u)):
        o = ref.outputs()
        for n in r:
            r[n].append(o[n])
        ref.set_input(u[k])
        ref.step(1e-3)
    return c, {n: np.array(v) for n, v in r.items()}
