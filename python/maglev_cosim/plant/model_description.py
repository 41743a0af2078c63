"""Model descriptions (FMI 2.0 and 3.0) from the C variable table, so the two cannot drift apart.

The C plant (``c/maglev_plant.c``) owns the variable table ``maglev_variables``, made from the list
``MAGLEV_VARIABLES`` at its top: names, value references (the list's order, which is the ``MaglevVR``
enum's), causality, start values, the ``[min, max]`` range ``maglev_check_value`` enforces, units,
descriptions and effects. :func:`read_table` reads that table out of the compiled FMU binary (the
declarations come from the C sources, :func:`variable_names`) and :func:`generate` renders it, with an
:class:`Identity` (model name, identifier, GUID / instantiationToken, description), as
``modelDescription.xml`` for FMI 2.0 or 3.0. Any FMU whose C table has the ``MaglevVariable`` layout can
use it (``read_table(lib, table=..., names=...)``).

What the generator adds to the table, from the unit alone (:data:`UNITS`): the SI base units, a
``TypeDefinitions`` entry per unit (its quantity), a ``displayUnit`` where people think in mm, mA
or ms, and a ``nominal`` where the values are far from 1 (the start value's power of ten, or the
unit's typical magnitude when the start is 0). ``min``/``max`` are the C table's own columns, so a
value outside them is exactly what ``fmi2SetReal`` refuses (``tests/test_model_description.py``).

``generationDateAndTime`` is :data:`GENERATION_DATE`, a constant, so that regenerating never
changes the committed files; ``python -m maglev_cosim.plant.model_description`` uses
``$SOURCE_DATE_EPOCH`` instead when it is set (reproducible-builds convention), and the drift test
then fails until the constant is updated to match, on purpose.

``tests/test_model_description.py`` fails when the committed ``modelDescription.xml`` differs from what
the binary says. Regenerate, from the repository root after ``scripts/setup.sh``, with
``python -m maglev_cosim.plant.model_description build/fmu/binaries/linux64/maglev.so modelDescription.xml``.
The FMI 3.0 one is not committed: the build writes ``build/modelDescription3.xml`` with
``... --fmi 3 --c c/ <the plant library> build/modelDescription3.xml`` (CMakeLists.txt); the controller
FMU's with ``... --pid build/maglev_pid.so modelDescription_pid.xml`` and
``... --pid --fmi 3 build/maglev_pid.so modelDescription_pid3.xml``.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import cffi

from .._resources import c_dir

GUID = "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"
MODEL_IDENTIFIER = "maglev"
#: The FMI 2.0 plant FMU's C files (<SourceFiles>): the FMI 2.0 entry points, the glue, the plant as its model.
SOURCE_FILES = ("maglev_fmu.c", "maglev_fmi_common.c", "maglev_plant_fmu.c", "maglev_plant.c")
#: generationDateAndTime of the committed descriptions (see the module docstring).
GENERATION_DATE = "2026-11-25T00:00:00Z"


@dataclass(frozen=True)
class UnitInfo:
    base: dict[str, int]
    quantity: str                                # the TypeDefinitions entry's name and quantity
    display: tuple[str, float] | None = None     # (name, factor): value_display = factor * value
    magnitude: float | None = None               # typical size, for the nominal of a zero start


# SI base-unit exponents, quantity and display unit of every unit the table uses.
UNITS: dict[str, UnitInfo] = {
    "MU": UnitInfo({}, "ConverterValue"),
    "1": UnitInfo({}, "Dimensionless"),
    "m": UnitInfo({"m": 1}, "Length", ("mm", 1e3), 1e-3),   # the rig is a few mm tall
    "m/s": UnitInfo({"m": 1, "s": -1}, "Velocity"),
    "m/s2": UnitInfo({"m": 1, "s": -2}, "Acceleration"),
    "s": UnitInfo({"s": 1}, "Time", ("ms", 1e3)),
    "kg": UnitInfo({"kg": 1}, "Mass", ("g", 1e3)),
    "A": UnitInfo({"A": 1}, "Current", ("mA", 1e3)),
    "N": UnitInfo({"kg": 1, "m": 1, "s": -2}, "Force"),
    "V": UnitInfo({"kg": 1, "m": 2, "s": -3, "A": -1}, "Voltage"),
    "V/MU": UnitInfo({"kg": 1, "m": 2, "s": -3, "A": -1}, "DAConverterGain"),
    "MU/V": UnitInfo({"kg": -1, "m": -2, "s": 3, "A": 1}, "ADConverterGain"),
    "A/V": UnitInfo({"kg": -1, "m": -2, "s": 3, "A": 2}, "Transconductance"),
    "V/m": UnitInfo({"kg": 1, "m": 1, "s": -3, "A": -1}, "SensorGain"),
    "V/m2": UnitInfo({"kg": 1, "s": -3, "A": -1}, "SensorCurvature"),
    "N.m2/A2": UnitInfo({"kg": 1, "m": 3, "s": -2, "A": -2}, "CoilConstant"),
    "N.s/m": UnitInfo({"kg": 1, "s": -1}, "DampingCoefficient"),
    "Hz": UnitInfo({"s": -1}, "Frequency"),
    "1/s": UnitInfo({"s": -1}, "Rate"),         # the PID's integral gain
    "rad": UnitInfo({"rad": 1}, "Angle", ("deg", 180 / math.pi)),
    "N/A2": UnitInfo({"kg": 1, "m": 1, "s": -2, "A": -2}, "ForceCurrentGain"),
    "Ohm": UnitInfo({"kg": 1, "m": 2, "s": -3, "A": -2}, "Resistance"),
    "H": UnitInfo({"kg": 1, "m": 2, "s": -2, "A": -2}, "Inductance", ("mH", 1e3)),
    "1/A": UnitInfo({"A": -1}, "InverseCurrent"),
    "H.m": UnitInfo({"kg": 1, "m": 3, "s": -2, "A": -2}, "InductanceLength"),
}



def unit_info(unit: str) -> UnitInfo:
    """:data:`UNITS`' entry of ``unit``, or for a unit it lacks (a new parameter's ``V/s``), one
    derived from its parts: a product of known units with integer powers, ``.`` between them and one
    ``/`` (``N.m2/A2``), its quantity named after the unit (``Unit_V_per_s``). So a table row may
    bring its own unit; a display unit or a typical magnitude needs an entry in :data:`UNITS`."""
    if unit in UNITS:
        return UNITS[unit]
    base: dict[str, int] = {}
    for sign, part in zip((1, -1), unit.split("/", 1) if "/" in unit else (unit,)):
        for factor in part.split("."):
            m = re.fullmatch(r"([A-Za-z]+)(-?\d*)", factor)
            if factor == "1":
                continue
            if m is None or m.group(1) not in UNITS:
                raise ValueError(f"unit {unit!r}: {factor!r} is not a known unit ({', '.join(UNITS)})")
            power = sign * int(m.group(2) or 1)
            for k, e in UNITS[m.group(1)].base.items():
                base[k] = base.get(k, 0) + power * e
    name = "Unit_" + unit.replace("/", "_per_").replace(".", "_")
    return UnitInfo({k: e for k, e in base.items() if e}, name)


CAUSALITY = {0: "input", 1: "output", 2: "parameter"}


@dataclass(frozen=True)
class Variable:
    """One row of the C variable table."""

    value_reference: int
    name: str
    causality: str
    start: float
    unit: str
    description: str
    min: float = -math.inf
    max: float = math.inf
    effect: str = ""        # the catalogue effect a parameter belongs to ("": the baseline plant)

    @property
    def described(self) -> str:
        """The description a model description carries: the table's, and the effect the parameter
        belongs to (the C table's ``effect`` column), so that a tool's user sees which parameters
        switch which effect on."""
        if not self.effect:
            return self.description
        if self.description.endswith(")"):     # "... (0 = off)" -> "... (0 = off; effect delay)"
            return f"{self.description[:-1]}; effect {self.effect})"
        return f"{self.description} (effect {self.effect})"


@dataclass(frozen=True)
class Identity:
    """What a model description says besides its variables."""

    model_name: str
    model_identifier: str
    token: str                                   # FMI 2.0 guid, FMI 3.0 instantiationToken
    description: str
    version: str = "0.1.0"
    source_files: tuple[str, ...] = ()           # FMI 2.0 <SourceFiles> (3.0 has buildDescription.xml)
    default_experiment: tuple[float, float, float] | None = (0.0, 3.0, 0.001)  # start, stop, step
    feedthrough: frozenset[str] = field(default_factory=frozenset)  # outputs the inputs reach at once
    generation_date: str = GENERATION_DATE


def plant_identity(fmi_version: int = 2) -> Identity:
    """The CE152 plant FMU's identity."""
    return Identity(
        model_name="CE152 magnetic levitation",
        model_identifier=MODEL_IDENTIFIER,
        token=GUID,
        description="Humusoft CE152 magnetic levitation plant: D/A (Eq. 1), amplifier (Eq. 2), "
                    "ball and coil (Eq. 8), sensor (Eq. 12), A/D (Eq. 13), with mechanical stops and converter limits",
        source_files=SOURCE_FILES if fmi_version == 2 else (),
        # i and F follow the input at once when T_a = 0 (Eq. 5): they may depend on u.
        feedthrough=frozenset({"i", "F"}),
    )


#: The controller FMU (c/maglev_pid_fmu.[ch], build/maglev_pid.fmu and build/maglev_pid3.fmu): the same
#: FMI entry points and glue as the plant's, with the PID as the model.
PID_GUID = "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0101}"
PID_MODEL_IDENTIFIER = "maglev_pid"
PID_SOURCE_FILES = ("maglev_fmu.c", "maglev_fmi_common.c", "maglev_pid_fmu.c", "maglev_replay.c", "maglev_plant.c")


def pid_identity(fmi_version: int = 2) -> Identity:
    """The controller FMU's identity (FMI 2.0 or 3.0; one token for both, as the plant has). Its output
    u changes only in the step, when the controller samples its inputs: no output depends on an input
    at the same instant."""
    return Identity(
        model_name="CE152 discrete PID with step reference",
        model_identifier=PID_MODEL_IDENTIFIER,
        token=PID_GUID,
        description="The paper's discrete PID (Eq. 24/25) of the CE152 magnetic levitation loop, with output "
                    "limits, derivative filter, anti-windup and a step reference w0 -> w1 at t_step (plus the input "
                    f"w_in); samples y at t0 + k*ts in fmi{fmi_version}DoStep and holds u until the next sample",
        source_files=PID_SOURCE_FILES if fmi_version == 2 else (),
    )


def read_pid_table(library: str | Path, header: str | Path | None = None, *,
                   c: str | Path | None = None) -> list[Variable]:
    """The controller FMU's variable table, out of its compiled binary (``c``: the folder of the C
    sources, by default the installed ones)."""
    header = Path(header) if header else Path(c or c_dir()) / "maglev_pid_fmu.h"
    body = re.search(r"typedef enum \{(.*?)\} MaglevPidVR;", header.read_text(), re.S)
    if body is None:
        raise RuntimeError(f"{header}: MaglevPidVR enum not found")
    names = re.findall(r"\bPID_(\w+)\b", body.group(1))
    return read_table(library, c=c, table="maglev_pid_variables", names=names)


def variable_names(c: str | Path | None = None) -> list[str]:
    """The plant's variable names in value-reference order: the rows of the list ``MAGLEV_VARIABLES``
    at the top of ``c/maglev_plant.c``, from which ``maglev_plant.h`` makes the ``MaglevVR`` enum."""
    source = Path(c or c_dir()) / "maglev_plant.c"
    body = re.search(r"#define MAGLEV_VARIABLES\(X\) \\\n(.*?)\n#endif", source.read_text(), re.S)
    if body is None:
        raise RuntimeError(f"{source}: the list MAGLEV_VARIABLES not found")
    return re.findall(r"^\s*X\((\w+),", body.group(1), re.M)


def read_table(library: str | Path, *, c: str | Path | None = None, table: str = "maglev_variables",
               names: list[str] | None = None) -> list[Variable]:
    """Reads a ``MaglevVariable`` table (by default the plant's, whose names are :func:`variable_names`)
    out of a compiled shared library; ``c`` is the folder of the C sources (the installed ones by
    default). Each row must carry the name the enum gives its value reference."""
    ffi = cffi.FFI()
    plant_header = (Path(c or c_dir()) / "maglev_plant.h").read_text()
    for name in ("MaglevCausality", "MaglevVariable"):     # the C declarations, as the header has them
        decl = re.search(r"typedef (?:enum|struct) \{[^}]*\} " + name + ";", plant_header)
        if decl is None:
            raise RuntimeError(f"c/maglev_plant.h: {name} not found")
        ffi.cdef(decl.group(0))
    names = variable_names(c) if names is None else names
    nvars = len(names)
    ffi.cdef(f"extern const MaglevVariable {table}[{nvars}];")
    lib = ffi.dlopen(str(library))
    rows = []
    for vr in range(nvars):
        v = getattr(lib, table)[vr]
        name = ffi.string(v.name).decode()
        if name != names[vr]:
            raise RuntimeError(f"C table row {vr} is {name!r} but the enum says {names[vr]!r}")
        rows.append(Variable(vr, name, CAUSALITY[v.causality], float(v.start), ffi.string(v.unit).decode(),
                             ffi.string(v.description).decode(), float(v.min), float(v.max),
                             ffi.string(v.effect).decode()))
    return rows


def _num(x: float) -> str:
    return repr(float(x))


def nominal(v: Variable) -> float | None:
    """A power of ten near the variable's size when that is far from 1 (None otherwise)."""
    size = abs(v.start) if v.start != 0 and v.causality != "output" else unit_info(v.unit).magnitude
    if not size:
        return None
    p = round(math.log10(size))
    return 10.0 ** p if abs(p) >= 2 else None


def _real_attrs(v: Variable, *, with_start: bool) -> str:
    u = unit_info(v.unit)
    a = f'declaredType="{u.quantity}" unit="{v.unit}"'
    if u.display:
        a += f' displayUnit="{u.display[0]}"'
    if with_start:
        a += f' start="{_num(v.start)}"'
    if math.isfinite(v.min):
        a += f' min="{_num(v.min)}"'
    if math.isfinite(v.max):
        a += f' max="{_num(v.max)}"'
    nom = nominal(v)
    if nom is not None:
        a += f' nominal="{_num(nom)}"'
    return a


def _units(variables: list[Variable]) -> list[str]:
    out = ['  <UnitDefinitions>']
    for name in sorted({v.unit for v in variables}):
        u = unit_info(name)
        attrs = "".join(f' {k}="{int(e)}"' for k, e in u.base.items())
        disp = f'<DisplayUnit name="{u.display[0]}" factor="{_num(u.display[1])}"/>' if u.display else ""
        out.append(f'    <Unit name="{name}"><BaseUnit{attrs}/>{disp}</Unit>')
    out.append('  </UnitDefinitions>')
    return out


def _types(variables: list[Variable], fmi_version: int) -> list[str]:
    out = ['  <TypeDefinitions>']
    for name in sorted({v.unit for v in variables}, key=lambda n: unit_info(n).quantity):
        u = unit_info(name)
        disp = f' displayUnit="{u.display[0]}"' if u.display else ""
        attrs = f'quantity="{u.quantity}" unit="{name}"{disp}'
        if fmi_version == 2:
            out.append(f'    <SimpleType name="{u.quantity}"><Real {attrs}/></SimpleType>')
        else:
            out.append(f'    <Float64Type name="{u.quantity}" {attrs}/>')
    out.append('  </TypeDefinitions>')
    return out


_LOG_CATEGORIES = [
    '  <LogCategories>',
    '    <Category name="logStatusError" description="Errors: rejected values and calls"/>',
    '    <Category name="logCalls" description="FMI calls"/>',
    '    <Category name="logAll" description="Everything"/>',
    '  </LogCategories>',
]


def _default_experiment(ident: Identity) -> list[str]:
    if ident.default_experiment is None:
        return []
    start, stop, step = ident.default_experiment
    return [f'  <DefaultExperiment startTime="{_num(start)}" stopTime="{_num(stop)}" stepSize="{_num(step)}"/>']


def _header(ident: Identity, fmi_version: int) -> list[str]:
    token = 'guid' if fmi_version == 2 else 'instantiationToken'
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<fmiModelDescription',
        f'  fmiVersion="{fmi_version}.0"',
        f'  modelName={quoteattr(ident.model_name)}',
        f'  {token}="{ident.token}"',
        f'  description={quoteattr(ident.description)}',
        '  generationTool="maglev-cosim"',
        f'  generationDateAndTime="{ident.generation_date}"',
        f'  version="{ident.version}"',
        '  variableNamingConvention="flat"',
    ]
    if fmi_version == 2:
        out.append('  numberOfEventIndicators="0">')
    else:
        out[-1] += '>'
    return out


def generate(variables: list[Variable], ident: Identity | None = None, fmi_version: int = 2) -> str:
    """The text of ``modelDescription.xml`` for a variable table (FMI 2.0 or 3.0)."""
    if fmi_version not in (2, 3):
        raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    ident = ident or plant_identity(fmi_version)
    return (_generate2 if fmi_version == 2 else _generate3)(variables, ident)


#: A variable's causality, variability and initial, the same in FMI 2.0 and 3.0.
_KIND = {"input": 'causality="input" variability="continuous"',
         "output": 'causality="output" variability="continuous" initial="calculated"',
         "parameter": 'causality="parameter" variability="fixed" initial="exact"'}


def _generate2(variables: list[Variable], ident: Identity) -> str:
    out = _header(ident, 2) + [
        '  <CoSimulation',
        f'    modelIdentifier="{ident.model_identifier}"',
        '    canHandleVariableCommunicationStepSize="true"',
        '    canGetAndSetFMUstate="true"',
        '    canSerializeFMUstate="true"',
        '    canNotUseMemoryManagementFunctions="false"',
        '    canInterpolateInputs="false"',
        '    maxOutputDerivativeOrder="0">',
    ]
    if ident.source_files:
        out += ['    <SourceFiles>', *[f'      <File name="{f}"/>' for f in ident.source_files], '    </SourceFiles>']
    out += ['  </CoSimulation>']
    out += _units(variables) + _types(variables, 2) + _LOG_CATEGORIES + _default_experiment(ident)
    out += ['  <ModelVariables>']
    for v in variables:
        out.append(f'    <!-- index {v.value_reference + 1} -->')
        head = (f'    <ScalarVariable name="{v.name}" valueReference="{v.value_reference}" '
                f'description={quoteattr(v.described)}')
        out.append(f'{head} {_KIND[v.causality]}>')
        out.append(f'      <Real {_real_attrs(v, with_start=v.causality != "output")}/>')
        out.append('    </ScalarVariable>')
    out += ['  </ModelVariables>', '  <ModelStructure>', '    <Outputs>']
    outputs = [v for v in variables if v.causality == "output"]
    for v in outputs:
        dep = "" if v.name in ident.feedthrough else ' dependencies=""'
        out.append(f'      <Unknown index="{v.value_reference + 1}"{dep}/>')
    out += ['    </Outputs>', '    <InitialUnknowns>']
    for v in outputs:
        out.append(f'      <Unknown index="{v.value_reference + 1}"/>')
    out += ['    </InitialUnknowns>', '  </ModelStructure>', '</fmiModelDescription>', '']
    return "\n".join(out)


def _generate3(variables: list[Variable], ident: Identity) -> str:
    # FMI 3.0 needs an independent variable: time, with the value reference after the table's.
    vr_time = len(variables)
    out = _header(ident, 3) + [
        '  <CoSimulation',
        f'    modelIdentifier="{ident.model_identifier}"',
        '    canHandleVariableCommunicationStepSize="true"',
        '    canGetAndSetFMUState="true"',
        '    canSerializeFMUState="true"',
        '    providesIntermediateUpdate="false"',
        '    hasEventMode="false"',
        '    canReturnEarlyAfterIntermediateUpdate="false"',
        '    maxOutputDerivativeOrder="0"/>',
    ]
    with_time = [*variables, Variable(vr_time, "time", "independent", 0.0, "s", "Simulation time")]  # its unit too
    out += _units(with_time) + _types(with_time, 3) + _LOG_CATEGORIES + _default_experiment(ident)
    out += ['  <ModelVariables>',
            f'    <Float64 name="time" valueReference="{vr_time}" causality="independent" '
            'variability="continuous" description="Simulation time" declaredType="Time" unit="s"/>']
    for v in variables:
        head = (f'    <Float64 name="{v.name}" valueReference="{v.value_reference}" '
                f'description={quoteattr(v.described)}')
        out.append(f'{head} {_KIND[v.causality]} {_real_attrs(v, with_start=v.causality != "output")}/>')
    out += ['  </ModelVariables>', '  <ModelStructure>']
    outputs = [v for v in variables if v.causality == "output"]
    for v in outputs:
        dep = "" if v.name in ident.feedthrough else ' dependencies=""'
        out.append(f'    <Output valueReference="{v.value_reference}"{dep}/>')
    for v in outputs:
        out.append(f'    <InitialUnknown valueReference="{v.value_reference}"/>')
    out += ['  </ModelStructure>', '</fmiModelDescription>', '']
    return "\n".join(out)


def _date_from_environment() -> str:
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if not epoch:
        return GENERATION_DATE
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(int(epoch)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m maglev_cosim.plant.model_description",
                                 description="Writes the model description of a compiled FMU binary's C variable table.")
    ap.add_argument("--pid", action="store_true", help="the controller FMU's table (maglev_pid.so)")
    ap.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default 2)")
    ap.add_argument("--c", metavar="DIR", help="the folder of the C sources (default: the installed ones); the "
                                                "build uses the repository's c/")
    ap.add_argument("library", help="PATH/TO/maglev.so (or maglev_pid.so)")
    ap.add_argument("out", nargs="?", default="modelDescription.xml", help="default: modelDescription.xml here")
    args = ap.parse_args(argv)
    ident = pid_identity(args.fmi) if args.pid else plant_identity(args.fmi)
    ident = Identity(**{**ident.__dict__, "generation_date": _date_from_environment()})
    table = read_pid_table(args.library, c=args.c) if args.pid else read_table(args.library, c=args.c)
    target = Path(args.out)
    target.write_text(generate(table, ident, args.fmi))
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
