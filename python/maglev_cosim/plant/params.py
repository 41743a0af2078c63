"""The paper's parameter sets, with units and where each value comes from.

Named sets (:data:`PARAMETER_SETS`):

- ``section3``: the identified values of Section 3 (LQ fit of Sec. 3.4.2) — the FMU's defaults;
- ``eq18``: the reading the linearised matrices of Eq. 18 imply: ``T_a`` = 3 ms
  (−1/T_a = −333.3 s⁻¹, B = k_i·k_DA/T_a = 500) and ``k_FV`` = 2.4·m_k ≈ 0.0202 N·s/m;
- ``baseline``: the paper's simulation model, Section 3 with ``T_a`` neglected (Eq. 5).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace

from .fast import check_params


@dataclass(frozen=True)
class PlantParams:
    """Plant parameters, named as the FMU's variables (SI units; MU = machine units)."""

    k_DA: float = 5.0          #: D/A gain [V/MU], Eq. 1, Sec. 3.1 (Table 2)
    u_0: float = 0.0           #: D/A offset [V], Eq. 1, Sec. 3.1
    k_i: float = 0.3           #: amplifier gain [A/V], Eq. 2, Sec. 3.2
    T_a: float = 0.3e-3        #: amplifier time constant [s], Eq. 2, Sec. 3.2
    m_k: float = 8.4e-3        #: ball mass [kg], Eq. 8, Sec. 3.4.1
    g: float = 9.81            #: gravity [m/s²], Eq. 8
    k_c: float = 6.9e-6        #: coil constant [N·m²/A²], Eq. 8, Sec. 3.4.2 (LQ)
    x_0: float = 8.3e-3        #: coil offset [m], Eq. 8, Sec. 3.4.2 (LQ)
    k_FV: float = 0.03         #: damping [N·s/m], Eq. 8, Sec. 3.4.3
    k_x: float = 612.3         #: sensor gain [V/m], Eq. 12, Sec. 3.3
    y_0: float = 0.0125        #: sensor offset [V], Eq. 12, Table 3
    k_AD: float = 0.2          #: A/D gain [MU/V], Eq. 13, Sec. 3.1 (Table 1)
    y_MU0: float = 0.0         #: A/D offset [MU], Eq. 13, Sec. 3.1
    x_min: float = 0.0         #: lower stop [m]
    x_max: float = 6.3e-3      #: upper stop [m]
    i_max: float = 1.5         #: amplifier current limit [A] (k_i·k_DA·1 MU)
    x_start: float = 0.0       #: initial position [m]
    v_start: float = 0.0       #: initial velocity [m/s]
    i_start: float = 0.0       #: initial current [A]
    T_F: float = 0.0           #: force lag [s] (effect force_lag)
    T_d: float = 0.0           #: transport delay [s] (effect delay)
    k_x2: float = 0.0          #: sensor nonlinearity [V/m²] (effect sensor_nonlinearity)
    x_cal: float = 6.3e-3      #: second sensor calibration point [m], Table 3
    A_d: float = 0.0           #: sensor pickup amplitude [V] (effect periodic_disturbance)
    f_d: float = 50.0          #: sensor pickup frequency [Hz]
    phi_d: float = 0.0         #: sensor pickup phase [rad]
    F_c: float = 0.0           #: Coulomb friction force [N], F_c·tanh(v/0.1 mm/s) (effect coulomb_friction)
    n_F: float = 2.0           #: force-law exponent [-] (effect force_exponent; 2: Eq. 8)
    x_n: float = 3.2e-3        #: position [m] where the exponent leaves the force unchanged
    u_dz: float = 0.0          #: amplifier dead-zone half-width [V] (effect amplifier_dead_zone)
    k_e: float = 0.0           #: exponential force-law gain [N/A²], k_e·exp(−(x_0 − x)/z_e)·i² (other rigs; 0 = off)
    z_e: float = 5e-3          #: decay length of the exponential force law [m]
    R_c: float = 0.0           #: coil resistance [Ω]; > 0 selects a voltage drive (other rigs; 0 = Eq. 2)
    L_0: float = 0.1           #: coil inductance far from the ball [H] (voltage drive)
    L_x: float = 0.0           #: inductance the ball adds at x = x_0 [H]
    z_L: float = 5e-3          #: decay length of the ball's inductance [m]
    L_g: float = 0.0           #: inverse-gap inductance [H·m], L_g/(x_0 − x)
    L_i: float = 0.0           #: current dependence of the inductance [H], L_i·atan(a_i·i − b_i)
    a_i: float = 1.0           #: its current scale [1/A]
    b_i: float = 0.0           #: its offset [-]
    V_min: float = 0.0         #: lowest coil voltage of a voltage drive [V]
    T_y: float = 0.0           #: sensor lag [s]: the sensor sees the position through a first-order lag (effect sensor_lag)
    solver_step: float = 1e-4  #: largest internal RK4 step [s]

    def replace(self, **changes: float) -> PlantParams:
        """A copy with some values changed; unknown names raise ``ValueError``."""
        names = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise ValueError(f"unknown parameter(s): {', '.join(unknown)}")
        return replace(self, **{k: float(v) for k, v in changes.items()})

    def to_start_values(self) -> dict[str, float]:
        """FMU start values by variable name (for ``simulate_fmu(start_values=...)`` or ``setReal``)."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}

    def validate(self) -> None:
        """Raises ``ValueError`` (one line naming the variable) unless the FMU would accept these
        values: each in the range of the C variable table, and the relations between them. The
        rules live once, in C (``maglev_check_value``, ``maglev_check_params``)."""
        check_params(self.to_start_values())


SOURCES: dict[str, str] = {
    "k_DA": "Sec. 3.1, Table 2 (Eq. 1)", "u_0": "Sec. 3.1 (Eq. 1)", "k_i": "Sec. 3.2 (Eq. 2)",
    "T_a": "Sec. 3.2 (Eq. 2); Eq. 18 implies 3 ms", "m_k": "Sec. 3.4.1 (Eq. 8)", "g": "standard gravity",
    "k_c": "Sec. 3.4.2, LQ fit (Eq. 14)", "x_0": "Sec. 3.4.2, LQ fit (Eq. 14)",
    "k_FV": "Sec. 3.4.3 simplex fit; Eq. 18 implies 0.020", "k_x": "Sec. 3.3, Table 3 (Eq. 12)",
    "y_0": "Table 3: 0.0125 V at x = 0 (never stated in the text)", "k_AD": "Sec. 3.1, Table 1 (Eq. 13)",
    "y_MU0": "Sec. 3.1 (Eq. 13)", "x_min": "lower mechanical stop (not in the paper)",
    "x_max": "upper mechanical stop, end of the sensor's calibrated range (Sec. 3.3)",
    "i_max": "k_i·k_DA·1 MU (D/A range)", "x_start": "initial state", "v_start": "initial state",
    "i_start": "initial state", "T_F": "effect force_lag (off)", "T_d": "effect delay (off)",
    "k_x2": "effect sensor_nonlinearity (off)", "x_cal": "Table 3, second calibration point",
    "A_d": "effect periodic_disturbance (off)", "f_d": "effect periodic_disturbance",
    "phi_d": "effect periodic_disturbance", "F_c": "effect coulomb_friction (off)",
    "n_F": "effect force_exponent (2: Eq. 8)", "x_n": "the paper's operating point (Sec. 4)",
    "u_dz": "effect amplifier_dead_zone (off)", "k_e": "other rigs' exponential force law (off)",
    "z_e": "other rigs' exponential force law", "R_c": "other rigs' voltage drive (off: Eq. 2)",
    "L_0": "voltage drive", "L_x": "voltage drive", "z_L": "voltage drive", "L_g": "voltage drive", "L_i": "voltage drive",
    "a_i": "voltage drive", "b_i": "voltage drive", "V_min": "voltage drive", "T_y": "effect sensor_lag (off)", "solver_step": "numerics",
}

_SECTION3 = PlantParams()
PARAMETER_SETS: dict[str, PlantParams] = {
    "section3": _SECTION3,
    "eq18": _SECTION3.replace(T_a=3e-3, k_FV=2.4 * _SECTION3.m_k),
    "baseline": _SECTION3.replace(T_a=0.0),
}


def as_params(params: PlantParams | str | Mapping[str, float] | None) -> PlantParams:
    """A :class:`PlantParams` from itself, a set name, or FMU parameter values [SI units] over the
    Section 3 set (``None``: the Section 3 set)."""
    if params is None:
        return PARAMETER_SETS["section3"]
    if isinstance(params, PlantParams):
        return params
    if isinstance(params, str):
        return get_params(params)
    return PARAMETER_SETS["section3"].replace(**dict(params))


def get_params(name: str) -> PlantParams:
    """A named parameter set (``section3``, ``eq18``, ``baseline``)."""
    try:
        return PARAMETER_SETS[name]
    except KeyError:
        raise ValueError(f"unknown parameter set {name!r}: choose one of {', '.join(PARAMETER_SETS)}") from None


#: What each named set is, in a few words (plot titles and the demo's log say which set they show).
SET_DESCRIPTIONS: dict[str, str] = {
    "section3": "Section 3, the FMU's defaults",
    "eq18": "the reading of Eq. 18: T_a = 3 ms, k_FV = 2.4·m_k",
    "baseline": "Section 3 with T_a = 0, Eq. 5",
}


def set_label(params: PlantParams | str) -> str:
    """``"parameters 'eq18' (the reading of Eq. 18: ...)"`` for a named set (by name or by value),
    ``"parameters: custom"`` for any other values: what a plot title says about its plant."""
    name = params if isinstance(params, str) else next(
        (n for n, p in PARAMETER_SETS.items() if p == params), None)
    if name not in PARAMETER_SETS:
        return "parameters: custom"
    return f"parameters '{name}' ({SET_DESCRIPTIONS[name]})"
