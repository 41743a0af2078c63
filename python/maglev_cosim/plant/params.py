"""The paper's parameter sets, with units and where each value comes from.

Named sets (:data:`PARAMETER_SETS`):

- ``section3``: the identified values of Section 3 (LQ fit of Sec. 3.4.2) — the FMU's defaults;
- ``eq18``: the reading the linearised matrices of Eq. 18 imply: ``T_a`` = 3 ms
  (−1/T_a = −333.3 s⁻¹, B = k_i·k_DA/T_a = 500) and ``k_FV`` = 2.4·m_k ≈ 0.0202 N·s/m;
- ``baseline``: the paper's simulation model, Section 3 with ``T_a`` neglected (Eq. 5).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import field, fields, make_dataclass, replace
from typing import TYPE_CHECKING

from .fast import check_params, effect_params, param_effects, param_table


class _PlantParamsMethods:
    """The methods of :class:`PlantParams` (its fields come from the C variable table)."""

    __slots__ = ()

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


def _make_plant_params() -> type:
    """:class:`PlantParams`, a frozen dataclass with one float field per row of the C variable table
    (``c/maglev_plant.c``), in its order, defaulting to its start value: a parameter (or an effect's)
    is declared once, in C, and appears here by itself."""
    table, effects = param_table(), param_effects()
    cls = make_dataclass("PlantParams", [(n, float, field(default=row[0])) for n, row in table.items()],
                         bases=(_PlantParamsMethods,), frozen=True)
    cls.__module__ = __name__      # pickles by this module's name (make_dataclass's module= is Python 3.12+)
    lines = [f"- ``{n}`` [{row[3]}]" + (f" (effect ``{effects[n]}``)" if effects[n] else "")
             for n, row in table.items()]
    cls.__doc__ = ("Plant parameters, named as the FMU's variables (SI units; MU = machine units), with the "
                   "C variable table's defaults (Section 3):\n\n" + "\n".join(lines))
    return cls


if TYPE_CHECKING:
    PlantParams = _PlantParamsMethods
else:
    PlantParams = _make_plant_params()


#: Where each baseline value comes from; an effect's parameters say their effect (from the C table).
_BASELINE_SOURCES: dict[str, str] = {
    "k_DA": "Sec. 3.1, Table 2 (Eq. 1)", "u_0": "Sec. 3.1 (Eq. 1)", "k_i": "Sec. 3.2 (Eq. 2)",
    "T_a": "Sec. 3.2 (Eq. 2); Eq. 18 implies 3 ms", "m_k": "Sec. 3.4.1 (Eq. 8)", "g": "standard gravity",
    "k_c": "Sec. 3.4.2, LQ fit (Eq. 14)", "x_0": "Sec. 3.4.2, LQ fit (Eq. 14)",
    "k_FV": "Sec. 3.4.3 simplex fit; Eq. 18 implies 0.020", "k_x": "Sec. 3.3, Table 3 (Eq. 12)",
    "y_0": "Table 3: 0.0125 V at x = 0 (never stated in the text)", "k_AD": "Sec. 3.1, Table 1 (Eq. 13)",
    "y_MU0": "Sec. 3.1 (Eq. 13)", "x_min": "lower mechanical stop (not in the paper)",
    "x_max": "upper mechanical stop, end of the sensor's calibrated range (Sec. 3.3)",
    "i_max": "k_i·k_DA·1 MU (D/A range)", "x_start": "initial state", "v_start": "initial state",
    "i_start": "initial state", "x_cal": "Table 3, second calibration point",
    "x_n": "the paper's operating point (Sec. 4)",
    "k_e": "other rigs' exponential force law (off)",
    "z_e": "other rigs' exponential force law", "R_c": "other rigs' voltage drive (off: Eq. 2)",
    "L_0": "voltage drive", "L_x": "voltage drive", "z_L": "voltage drive", "L_g": "voltage drive", "L_i": "voltage drive",
    "a_i": "voltage drive", "b_i": "voltage drive", "V_min": "voltage drive", "solver_step": "numerics",
}
SOURCES: dict[str, str] = {n: _BASELINE_SOURCES.get(n) or f"effect {e}" for n, e in param_effects().items()}

#: Effect name -> its parameters, from the C variable table (:func:`maglev_cosim.plant.fast.effect_params`):
#: names, for the emulators, which take nothing else of the model.
EFFECT_PARAMS: dict[str, tuple[str, ...]] = effect_params()

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
