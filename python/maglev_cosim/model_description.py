"""``modelDescription.xml`` from the C variable table, so the two cannot drift apart.

The C plant (``c/maglev_plant.c``) owns the variable table ``maglev_variables``: names,
value references (the ``MaglevVR`` enum order), causality, start values, units and
descriptions. :func:`generate` renders ``modelDescription.xml`` from that table as read
out of the compiled FMU binary (the declarations come from the installed ``maglev_plant.h``);
``tests/test_model_description.py`` fails when the committed file differs from what the binary
says. Regenerate, from the repository root after ``scripts/setup.sh``, with
``python -m maglev_cosim.model_description build/fmu/binaries/linux64/maglev.so modelDescription.xml``.
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import cffi

from ._resources import c_dir

GUID = "{6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0001}"
MODEL_IDENTIFIER = "maglev"
SOURCE_FILES = ("maglev_fmu.c", "maglev_plant.c")


# SI base-unit exponents of every unit the table uses.
_UNITS: dict[str, dict[str, float]] = {
    "MU": {},
    "1": {},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "s": {"s": 1},
    "kg": {"kg": 1},
    "A": {"A": 1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "V/MU": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "MU/V": {"kg": -1, "m": -2, "s": 3, "A": 1},
    "A/V": {"kg": -1, "m": -2, "s": 3, "A": 2},
    "V/m": {"kg": 1, "m": 1, "s": -3, "A": -1},
    "V/m2": {"kg": 1, "s": -3, "A": -1},
    "N.m2/A2": {"kg": 1, "m": 3, "s": -2, "A": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "Hz": {"s": -1},
    "rad": {"rad": 1},
    "N/A2": {"kg": 1, "m": 1, "s": -2, "A": -2},
    "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2},
    "1/A": {"A": -1},
    "H.m": {"kg": 1, "m": 3, "s": -2, "A": -2},
}

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


def read_table(library: str | Path) -> list[Variable]:
    """Reads ``maglev_variables`` out of a compiled plant/FMU shared library."""
    ffi = cffi.FFI()
    header = (c_dir() / "maglev_plant.h").read_text()
    for name in ("MaglevCausality", "MaglevVariable"):     # the C declarations, as the header has them
        decl = re.search(r"typedef (?:enum|struct) \{[^}]*\} " + name + ";", header)
        if decl is None:
            raise RuntimeError(f"c/maglev_plant.h: {name} not found")
        ffi.cdef(decl.group(0))
    enum = re.search(r"typedef enum \{(.*?)\} MaglevVR;", header, re.S)
    if enum is None:
        raise RuntimeError("c/maglev_plant.h: MaglevVR enum not found")
    names = re.findall(r"\b(VR_\w+|MAGLEV_NVARS)\b", enum.group(1))
    nvars = names.index("MAGLEV_NVARS")
    ffi.cdef(f"extern const MaglevVariable maglev_variables[{nvars}];")
    lib = ffi.dlopen(str(library))
    rows = []
    for vr in range(nvars):
        v = lib.maglev_variables[vr]
        name = ffi.string(v.name).decode()
        if "VR_" + name != names[vr]:
            raise RuntimeError(f"C table row {vr} is {name!r} but the enum says {names[vr]}")
        rows.append(Variable(vr, name, CAUSALITY[v.causality], float(v.start),
                             ffi.string(v.unit).decode(), ffi.string(v.description).decode()))
    return rows


def _num(x: float) -> str:
    return repr(float(x))


def generate(variables: list[Variable]) -> str:
    """The text of ``modelDescription.xml`` for a variable table."""
    units = sorted({v.unit for v in variables})
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<fmiModelDescription',
        '  fmiVersion="2.0"',
        '  modelName="CE152 magnetic levitation"',
        f'  guid="{GUID}"',
        '  description="Humusoft CE152 magnetic levitation plant: D/A (Eq. 1), amplifier (Eq. 2), '
        'ball and coil (Eq. 8), sensor (Eq. 12), A/D (Eq. 13), with mechanical stops and converter limits"',
        '  generationTool="maglev-cosim"',
        '  version="0.1.0"',
        '  variableNamingConvention="flat"',
        '  numberOfEventIndicators="0">',
        '  <CoSimulation',
        f'    modelIdentifier="{MODEL_IDENTIFIER}"',
        '    canHandleVariableCommunicationStepSize="true"',
        '    canGetAndSetFMUstate="true"',
        '    canSerializeFMUstate="true"',
        '    canNotUseMemoryManagementFunctions="false"',
        '    canInterpolateInputs="false"',
        '    maxOutputDerivativeOrder="0">',
        '    <SourceFiles>',
        *[f'      <File name="{f}"/>' for f in SOURCE_FILES],
        '    </SourceFiles>',
        '  </CoSimulation>',
        '  <UnitDefinitions>',
    ]
    for u in units:
        base = _UNITS[u]
        attrs = "".join(f' {k}="{int(e)}"' for k, e in base.items())
        out.append(f'    <Unit name="{u}"><BaseUnit{attrs}/></Unit>')
    out += [
        '  </UnitDefinitions>',
        '  <LogCategories>',
        '    <Category name="logStatusError" description="Errors: rejected values and calls"/>',
        '    <Category name="logCalls" description="FMI calls"/>',
        '    <Category name="logAll" description="Everything"/>',
        '  </LogCategories>',
        '  <DefaultExperiment startTime="0.0" stopTime="3.0" stepSize="0.001"/>',
        '  <ModelVariables>',
    ]
    for v in variables:
        out.append(f'    <!-- index {v.value_reference + 1} -->')
        head = (f'    <ScalarVariable name="{v.name}" valueReference="{v.value_reference}" '
                f'description={quoteattr(v.description)}')
        if v.causality == "input":
            out.append(f'{head} causality="input" variability="continuous">')
            out.append(f'      <Real unit="{v.unit}" start="{_num(v.start)}"/>')
        elif v.causality == "output":
            out.append(f'{head} causality="output" variability="continuous" initial="calculated">')
            out.append(f'      <Real unit="{v.unit}"/>')
        else:
            out.append(f'{head} causality="parameter" variability="fixed" initial="exact">')
            out.append(f'      <Real unit="{v.unit}" start="{_num(v.start)}"/>')
        out.append('    </ScalarVariable>')
    out += ['  </ModelVariables>', '  <ModelStructure>', '    <Outputs>']
    # i and F follow the input at once when T_a = 0 (Eq. 5): they may depend on u.
    feedthrough = {"i", "F"}
    outputs = [v for v in variables if v.causality == "output"]
    for v in outputs:
        dep = "" if v.name in feedthrough else ' dependencies=""'
        out.append(f'      <Unknown index="{v.value_reference + 1}"{dep}/>')
    out += ['    </Outputs>', '    <InitialUnknowns>']
    for v in outputs:
        out.append(f'      <Unknown index="{v.value_reference + 1}"/>')
    out += ['    </InitialUnknowns>', '  </ModelStructure>', '</fmiModelDescription>', '']
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) not in (1, 2):
        print("usage: python -m maglev_cosim.model_description PATH/TO/maglev.so [OUT.xml]\n"
              "writes OUT.xml (default: modelDescription.xml in the current folder)", file=sys.stderr)
        return 2
    target = Path(args[1] if len(args) == 2 else "modelDescription.xml")
    target.write_text(generate(read_table(args[0])))
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
