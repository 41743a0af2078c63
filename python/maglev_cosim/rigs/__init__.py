"""Rig descriptions: a rig's physics in SI units, read from a TOML file, mapped onto the C plant.

A rig file (``docs/rigs.md`` has the full schema) states the ball's mass and gravity, the position
convention of the rig's records (``height``: growing upward towards the coil, as in the paper;
``gap``: the distance below the magnet, growing downward) and the stops; the coil drive (a current
amplifier with gain, lag and limit, or a voltage drive with resistance, inductance ``L(x, i)`` and
the input-to-voltage map with its floor); the force law (the paper's ``k_c·i²/(x_0 − x)²``, Eq. 8, or
the exponential ``K·e^(−gap/decay)·i²`` Inteco publishes); the sensor (linear, quadratic, or a
position the rig's own software already computed, with its calibration table) and the converters;
and the sample time. ``[sources]`` names where each value comes from.

Shipped: ``ce152`` (the paper's Section 3, the default everywhere; it maps exactly onto
:data:`maglev_cosim.plant.params.PARAMETER_SETS` ``"section3"``), ``inteco-mls2em`` and ``levitador``
(from the identification data of the shared real records). The equations stay in C: a rig is only
a set of plant parameters (:attr:`Rig.params`) and the maps between the record's signals and the
plant's (positions, actuator input, reading).

Every error is a :class:`RigError` naming the file and the key, and says what is wrong.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..plant.formulas import point, positions, readings
from ..plant.params import PlantParams

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

#: Rig names shipped with the package.
SHIPPED = ("ce152", "inteco-mls2em", "levitador")
#: Head-room of a ``position`` sensor's scale over the largest |x| between the stops.
POSITION_HEADROOM = 1.25


class RigError(ValueError):
    """A rig file that cannot be used; ``str()`` is ``FILE: key 'KEY': what is wrong``."""

    def __init__(self, path: str | Path, key: str, message: str) -> None:
        self.path, self.key, self.message = str(path), key, message
        where = f"key '{key}': " if key else ""
        super().__init__(f"{path}: {where}{message}")


@dataclass(frozen=True)
class Rig:
    """A rig: its plant parameters and the maps between its records' signals and the plant's.

    The plant's position ``x`` [m] always grows towards the coil; a ``gap`` rig's record position
    ``z`` maps to ``x = −z`` (the magnet face at ``x = 0``)."""

    name: str
    path: Path
    description: str
    ts: float                       #: sample time [s]
    convention: str                 #: ``"height"`` or ``"gap"``
    stops: tuple[float, float]      #: the stops in the record's convention [m], ascending
    drive: str                      #: ``"current"`` or ``"voltage"``
    input_unit: str                 #: what the record's actuator column holds: ``MU``, ``duty`` or ``V``
    input_range: tuple[float, float]
    sensor: str                     #: ``linear``, ``quadratic`` or ``position``
    params: PlantParams             #: the plant's parameters (x_start: the ball on its lower rest)
    position_scale: float = 1.0     #: for a ``position`` sensor: metres per MU of the plant's reading
    resolution: float | None = None  #: the record position's quantisation step [m], when stated
    #: the sensor noise [m] the filter's disturbance model starts from (the calibration fits it),
    #: when stated; else the quantisation step
    sensor_noise: float | None = None
    sensor_table: tuple[np.ndarray, np.ndarray] | None = None  #: (volts, position [m]) calibration
    sources: dict[str, str] = field(default_factory=dict)

    # --- positions
    def to_x(self, position):
        """The plant's ``x`` [m] for record positions [m] (array or float)."""
        return -np.asarray(position, dtype=float) if self.convention == "gap" else np.asarray(position, dtype=float)

    def from_x(self, x):
        """Record positions [m] for the plant's ``x`` [m]."""
        return self.to_x(x)  # the map is its own inverse

    # --- actuator
    def input_to_mu(self, drive):
        """The plant's input ``u`` [MU] for the record's actuator values (``input_unit``)."""
        d = np.asarray(drive, dtype=float)
        return d / self.params.k_DA if self.input_unit == "V" else d

    # --- reading
    def reading(self, position):
        """The plant's noise-free reading ``y`` [MU] for record positions [m] (a ``position`` sensor:
        ``x / position_scale``; otherwise Eq. 12, 13 with the rig's sensor)."""
        x = np.atleast_1d(self.to_x(position))
        return readings(self.params, x.ravel()).reshape(x.shape)

    def position_for_reading(self, y):
        """Record positions [m] for plant readings ``y`` [MU] (the sensor's inverse, Eq. 12, 13)."""
        return self.from_x(positions(self.params, y))

    def equilibrium_current(self, position: float) -> float:
        """The current [A] holding the ball at rest at a record position [m]."""
        return point(self.params, float(self.to_x(position))).i


def rig_names() -> list[str]:
    """The rigs shipped with the package."""
    return list(SHIPPED)


def rig_path(name_or_path: str | Path) -> Path:
    """The file of a shipped rig by name, or ``name_or_path`` itself when it is a file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    if str(name_or_path) in SHIPPED:
        return Path(str(resources.files(__package__).joinpath(f"{name_or_path}.toml")))
    raise RigError(name_or_path, "", f"no such rig file, and not a shipped rig ({', '.join(SHIPPED)})")


def load_rig(name_or_path: str | Path = "ce152") -> Rig:
    """Reads and checks a rig file (or a shipped rig by name).

    Raises
    ------
    RigError
        The file is missing or not TOML (with its line and column), a key is missing, unknown, of the
        wrong type or non-physical, or the plant refuses the resulting parameters; the message names
        the file and the key.
    """
    path = rig_path(name_or_path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RigError(path, "", "no such file") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as e:
        raise RigError(path, "", f"cannot be read ({type(e).__name__})") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise RigError(path, "", f"not valid TOML: {e}") from None
    return _build(path, _Doc(path, doc))


class _Doc:
    """Typed access to a parsed TOML document; every complaint names the dotted key."""

    def __init__(self, path: Path, doc: dict[str, Any]) -> None:
        self.path, self.doc, self.used = path, doc, set()

    def _get(self, key: str) -> Any:
        node: Any = self.doc
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                return None
            node = node[part]
        self.used.add(key)
        return node

    def has(self, key: str) -> bool:
        return self._get(key) is not None

    def error(self, key: str, message: str) -> RigError:
        return RigError(self.path, key, message)

    def text(self, key: str, choices: tuple[str, ...] | None = None, default: str | None = None) -> str:
        v = self._get(key)
        if v is None:
            if default is not None:
                return default
            raise self.error(key, "missing" + (f" (one of {', '.join(choices)})" if choices else ""))
        if not isinstance(v, str):
            raise self.error(key, f"must be a string, got {v!r}")
        if choices and v not in choices:
            raise self.error(key, f"must be one of {', '.join(choices)}, got {v!r}")
        return v

    def number(self, key: str, unit: str, *, lo: float = -math.inf, hi: float = math.inf,
               lo_open: bool = False, default: float | None = None) -> float:
        v = self._get(key)
        if v is None:
            if default is not None:
                return default
            raise self.error(key, f"missing (a number in {unit})")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.error(key, f"must be a finite number in {unit}, got {v!r}")
        v = float(v)
        if (v <= lo if lo_open else v < lo) or v > hi:
            rng = f"{'>' if lo_open else '>='} {lo:g}" if math.isinf(hi) else f"in {'(' if lo_open else '['}{lo:g}, {hi:g}]"
            raise self.error(key, f"must be {rng} {unit}, got {v:g} (non-physical, or a unit slip?)")
        return v

    def pair(self, key: str, unit: str, default: tuple[float, float] | None = None) -> tuple[float, float]:
        v = self._get(key)
        if v is None:
            if default is not None:
                return default
            raise self.error(key, f"missing (two numbers in {unit}, ascending)")
        if (not isinstance(v, list) or len(v) != 2
                or not all(isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a) for a in v)
                or not v[0] < v[1]):
            raise self.error(key, f"must be two finite numbers in {unit}, ascending, got {v!r}")
        return float(v[0]), float(v[1])

    def array(self, key: str) -> np.ndarray:
        v = self._get(key)
        if (not isinstance(v, list) or len(v) < 2
                or not all(isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a) for a in v)):
            raise self.error(key, f"must be a list of at least two finite numbers, got {v!r}")
        return np.asarray(v, dtype=float)

    def unknown_keys(self) -> list[str]:
        found: list[str] = []

        def walk(node: dict[str, Any], prefix: str) -> None:
            for k, v in node.items():
                key = f"{prefix}{k}"
                if key == "sources":
                    continue
                if isinstance(v, dict):
                    walk(v, key + ".")
                elif key not in self.used:
                    found.append(key)

        walk(self.doc, "")
        return found


def _build(path: Path, d: _Doc) -> Rig:
    name = d.text("name")
    description = d.text("description", default="")
    ts = d.number("sample_time", "s", lo=1e-6, hi=1.0)
    conv = d.text("mechanics.position", ("height", "gap"))
    gap = conv == "gap"
    lo, hi = d.pair("mechanics.stops", "m")
    for k, v in (("mechanics.stops", lo), ("mechanics.stops", hi)):
        if abs(v) > 0.5:
            raise d.error(k, f"{v:g} m is not a stop of a levitation rig (more than 0.5 m): a unit slip?")
    x_min, x_max = (-hi, -lo) if gap else (lo, hi)
    p: dict[str, float] = {
        "m_k": d.number("mechanics.mass", "kg", lo=0.0, lo_open=True, hi=100.0),
        "g": d.number("mechanics.gravity", "m/s2", lo=0.0, lo_open=True, hi=100.0),
        "k_FV": d.number("mechanics.damping", "N s/m", lo=0.0, hi=1e3, default=0.0),
        "x_min": x_min, "x_max": x_max, "x_start": x_min, "v_start": 0.0, "i_start": 0.0,
    }
    # force law
    law = d.text("force.law", ("inverse-square", "exponential"))
    if law == "inverse-square":
        x0 = d.number("force.x_0", "m", lo=-0.5, hi=0.5)
        p.update(k_c=d.number("force.k_c", "N m2/A2", lo=0.0, lo_open=True, hi=1.0), x_0=-x0 if gap else x0)
    else:
        if gap:
            x0 = d.number("force.x_0", "m", lo=-0.5, hi=0.5, default=0.0)  # the gap is measured from the magnet
        else:
            x0 = d.number("force.x_0", "m", lo=-0.5, hi=0.5)
        p.update(k_c=0.0, k_e=d.number("force.K", "N/A2", lo=0.0, lo_open=True, hi=1e3),
                 z_e=d.number("force.decay", "m", lo=1e-6, hi=1.0), x_0=-x0 if gap else x0)
    if not p["x_max"] <= p["x_0"]:
        raise d.error("force.x_0", f"the magnet (x_0 = {x0:g} m) lies between the stops {lo:g}..{hi:g} m")
    if not PlantParams().x_n < p["x_0"]:  # n_F = 2: x_n unused, but it must lie below x_0
        p["x_n"] = p["x_min"] if p["x_min"] < p["x_0"] else p["x_0"] - 1e-3
    # drive
    drive = d.text("drive.type", ("current", "voltage"))
    p["i_max"] = d.number("drive.limit", "A", lo=0.0, lo_open=True, hi=1e3)
    unit = d.text("drive.input.unit", ("MU", "duty", "V"))
    gain = d.number("drive.input.gain", "V per input unit", lo=0.0, lo_open=True, hi=1e3)
    p.update(k_DA=gain, u_0=d.number("drive.input.offset", "V", lo=-100.0, hi=100.0, default=0.0))
    in_range = d.pair("drive.input.range", unit, default=(-1.0, 1.0) if unit == "MU" else None)
    mu_range = (in_range[0] / gain, in_range[1] / gain) if unit == "V" else in_range
    if mu_range[0] < -1 - 1e-9 or mu_range[1] > 1 + 1e-9:
        raise d.error("drive.input.range", f"maps to {mu_range[0]:g}..{mu_range[1]:g} MU, beyond the plant's "
                      "+-1 MU input: raise drive.input.gain (the full-scale voltage)")
    if drive == "current":
        p.update(k_i=d.number("drive.gain", "A/V", lo=0.0, lo_open=True, hi=1e3),
                 T_a=d.number("drive.lag", "s", lo=0.0, hi=1.0, default=0.0))
        if d.has("drive.input.floor"):
            raise d.error("drive.input.floor", "a floor voltage belongs to a voltage drive")
    else:
        p.update(R_c=d.number("drive.resistance", "ohm", lo=0.0, lo_open=True, hi=1e4), T_a=0.0,
                 V_min=d.number("drive.input.floor", "V", lo=-100.0, hi=100.0, default=0.0),
                 L_0=d.number("drive.inductance.L0", "H", lo=0.0, lo_open=True, hi=100.0),
                 L_x=d.number("drive.inductance.Lx", "H", lo=0.0, hi=100.0, default=0.0),
                 z_L=d.number("drive.inductance.decay", "m", lo=1e-6, hi=1.0, default=5e-3),
                 L_g=d.number("drive.inductance.Lg", "H m", lo=0.0, hi=10.0, default=0.0),
                 L_i=d.number("drive.inductance.Li", "H", lo=0.0, hi=100.0, default=0.0),
                 a_i=d.number("drive.inductance.a_i", "1/A", lo=0.0, hi=1e3, default=1.0),
                 b_i=d.number("drive.inductance.b_i", "1", lo=-1e3, hi=1e3, default=0.0))
        if p["L_i"] * math.pi / 2 >= p["L_0"]:
            raise d.error("drive.inductance.Li", f"Li*pi/2 = {p['L_i'] * math.pi / 2:g} H reaches L0 = {p['L_0']:g} H:"
                          " the inductance would turn negative")
    # sensor
    sensor = d.text("sensor.type", ("linear", "quadratic", "position"))
    scale, table, resolution = 1.0, None, None
    if d.has("sensor.resolution"):
        resolution = d.number("sensor.resolution", "m", lo=0.0, lo_open=True, hi=0.01)
    sensor_noise = d.number("sensor.noise", "m", lo=0.0, lo_open=True, hi=0.01) if d.has("sensor.noise") else None
    if d.has("sensor.table.volts") or d.has("sensor.table.position"):
        volts, pos = d.array("sensor.table.volts"), d.array("sensor.table.position")
        if len(volts) != len(pos):
            raise d.error("sensor.table.position", f"{len(pos)} positions for {len(volts)} voltages")
        if np.any(np.abs(pos) > 0.5):
            raise d.error("sensor.table.position", "positions beyond 0.5 m: a unit slip (mm given as m)?")
        table = (volts, pos)
    if sensor == "position":
        scale = POSITION_HEADROOM * max(abs(x_min), abs(x_max))
        p.update(k_x=1.0, y_0=0.0, k_x2=0.0, k_AD=1.0 / scale, y_MU0=0.0)
    else:
        if gap:
            raise d.error("sensor.type", "a linear or quadratic sensor is stated for the height convention; "
                          "for a gap record give type = \"position\"")
        p.update(k_x=d.number("sensor.gain", "V/m", lo=0.0, lo_open=True, hi=1e6),
                 y_0=d.number("sensor.offset", "V", lo=-100.0, hi=100.0, default=0.0),
                 k_AD=d.number("sensor.converter.gain", "MU/V", lo=0.0, lo_open=True, hi=1e3),
                 y_MU0=d.number("sensor.converter.offset", "MU", lo=-10.0, hi=10.0, default=0.0))
        if sensor == "quadratic":
            p["k_x2"] = d.number("sensor.quadratic", "V/m2", lo=-1e8, hi=1e8)
            p["x_cal"] = d.number("sensor.x_cal", "m", lo=1e-6, hi=1.0)
        d.pair("sensor.converter.range", "MU", default=(-1.0, 1.0))
        if d.has("sensor.converter.bits"):
            d.number("sensor.converter.bits", "bits", lo=1, hi=32)
        d.text("sensor.converter.unit", ("MU",), default="MU")
    if d.has("drive.input.bits"):
        d.number("drive.input.bits", "bits", lo=1, hi=32)
    unknown = d.unknown_keys()
    if unknown:
        raise d.error(unknown[0], "unknown key (a typing slip?); see docs/rigs.md for the schema")
    sources = d.doc.get("sources", {})
    if not isinstance(sources, dict) or not all(isinstance(v, str) for v in sources.values()):
        raise d.error("sources", "must be a table of strings")
    params = PlantParams().replace(**p)
    try:
        params.validate()
    except ValueError as e:
        raise RigError(path, "", f"the plant refuses the resulting parameters: {e}") from None
    return Rig(name=name, path=path, description=description, ts=ts, convention=conv, stops=(lo, hi),
               drive=drive, input_unit=unit, input_range=in_range, sensor=sensor, params=params,
               position_scale=scale, resolution=resolution, sensor_noise=sensor_noise, sensor_table=table,
               sources=dict(sources))
