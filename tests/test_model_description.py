"""modelDescription.xml against the C side: value references, names, starts, GUID, archive."""

from __future__ import annotations

import math
import re
import subprocess
import sys
import zipfile

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

import maglev_cosim
from maglev_cosim import _resources
from maglev_cosim.loop.fmu import FmuPlant
from maglev_cosim.plant.model_description import (GENERATION_DATE, GUID, UNITS, generate, nominal, read_table,
                                                  unit_info, variable_names)

REQUIRED_PARAMETERS = ["k_DA", "u_0", "k_i", "T_a", "m_k", "g", "k_c", "x_0", "k_FV", "k_x", "y_0", "k_AD",
                       "y_MU0", "x_min", "x_max", "i_max", "x_start", "v_start", "i_start"]


def test_committed_xml_is_what_the_c_table_generates(repo, fmu_binary):
    committed = (repo / "modelDescription.xml").read_text()
    generated = generate(read_table(fmu_binary))
    assert committed == generated, (
        "modelDescription.xml differs from the C variable table: run python -m maglev_cosim.plant.model_description "
        f"{fmu_binary} {repo / 'modelDescription.xml'}")


def test_fmi3_description_is_generated_by_the_build_from_the_c_table(repo, fmu_binary):
    """modelDescription3.xml is not committed: the build writes build/modelDescription3.xml from the C table
    (CMakeLists.txt), and the FMI 3.0 FMU and the installed package carry that file."""
    assert not (repo / "modelDescription3.xml").exists(), "modelDescription3.xml is generated into build/, not committed"
    generated = generate(read_table(fmu_binary), fmi_version=3)
    built = repo / "build" / "modelDescription3.xml"
    assert built.exists(), f"{built} is missing: run scripts/setup.sh (the CMake build in build/)"
    assert built.read_text() == generated
    assert _resources.model_description_path(3).read_text() == generated
    with zipfile.ZipFile(maglev_cosim.fmu_path(fmi_version=3)) as z:
        assert z.read("modelDescription.xml").decode() == generated
    with zipfile.ZipFile(repo / "build" / "maglev3.fmu") as z:
        assert z.read("modelDescription.xml").decode() == generated


def test_the_table_of_every_variable_is_generated_from_the_c_table(repo, fmu_binary, tmp_path):
    """docs/fmu.md's table of every variable is build/fmu_variables.md, written by the build: it is what
    scripts/fmu_variables.py prints from a model description generated from the C table here, one row per
    row of the C table; docs/fmu.md holds no copy and points to it."""
    table = read_table(fmu_binary)
    xml = tmp_path / "modelDescription.xml"
    xml.write_text(generate(table))
    r = subprocess.run([sys.executable, str(repo / "scripts" / "fmu_variables.py"), str(xml)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    built = repo / "build" / "fmu_variables.md"
    assert built.exists(), f"{built} is missing: run scripts/setup.sh (the CMake build in build/)"
    assert built.read_text() == r.stdout
    rows = [line for line in r.stdout.splitlines()[2:]]
    assert [re.match(r"\| `(\w+)` \|", line).group(1) for line in rows] == [v.name for v in table]
    fmu_md = (repo / "docs" / "fmu.md").read_text()
    assert "build/fmu_variables.md" in fmu_md
    assert not any(f"| `{v.name}` | {v.causality} |" in fmu_md for v in table), "docs/fmu.md: a hand copy of the table"


def test_generation_date_is_fixed_not_the_clock(repo):
    """Regenerating must not make the drift test flaky: the date is a constant (module docstring)."""
    md = read_model_description(str(repo / "modelDescription.xml"))
    assert md.generationDateAndTime == GENERATION_DATE
    assert md.generationTool == "maglev-cosim"


def test_xml_ranges_are_the_c_table_ones(repo, fmu_binary):
    """Every variable the C code gives a finite range carries it as min/max, and nothing else does."""
    table = {v.name: v for v in read_table(fmu_binary)}
    md = read_model_description(str(repo / "modelDescription.xml"))
    ranged = 0
    for mv in md.modelVariables:
        v = table[mv.name]
        want_min = repr(v.min) if math.isfinite(v.min) else None
        want_max = repr(v.max) if math.isfinite(v.max) else None
        assert (mv.min, mv.max) == (want_min, want_max), mv.name
        ranged += want_min is not None
    assert ranged >= 40  # every parameter and the A/D output y


def _instantiated(fmu_path, log):
    """A bare FMI 2.0 instance in the instantiated state (parameters checked one at a time)."""
    from fmpy import calloc, extract, free
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

    md = read_model_description(str(fmu_path))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu_path)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="ranges")
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: log.append(msg.decode()))
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    slave._keep = cb
    slave.instantiate(callbacks=cb)
    return md, slave


def test_a_value_outside_min_max_is_exactly_what_the_c_code_refuses(fmu_path):
    """For every settable variable: min and max themselves and the doubles just inside are accepted by
    fmi2SetReal, the doubles just outside are refused (Error, naming the variable). A variable
    without a range accepts any finite value."""
    from fmpy.fmi1 import FMICallException

    log: list[str] = []
    md, slave = _instantiated(fmu_path, log)
    checked = 0
    try:
        for mv in md.modelVariables:
            if mv.causality not in ("parameter", "input"):
                continue
            lo = float(mv.min) if mv.min is not None else -math.inf
            hi = float(mv.max) if mv.max is not None else math.inf
            inside = [x for x in (lo, math.nextafter(lo, hi), hi, math.nextafter(hi, lo)) if math.isfinite(x)]
            outside = [x for x in (math.nextafter(lo, -math.inf), math.nextafter(hi, math.inf)) if math.isfinite(x)]
            if not inside:
                inside = [-1e300, 1e300]
            for x in inside:
                if mv.name == "T_F" and 0 < x < 1e-6:
                    continue  # T_F: 0 (off) or >= 1e-6 s inside its range; the description says so
                slave.setReal([mv.valueReference], [x])
            for x in outside:
                with pytest.raises(FMICallException):
                    slave.setReal([mv.valueReference], [x])
                assert f"variable {mv.name}:" in log[-1], log[-1]
            checked += bool(outside)
            slave.setReal([mv.valueReference], [float(mv.start)])
    finally:
        slave.freeInstance()
    assert checked >= 40


def test_nominal_and_display_units(fmu_binary):
    """nominal where values are far from 1, displayUnit for lengths, currents and times."""
    rows = {v.name: v for v in read_table(fmu_binary)}
    assert nominal(rows["k_c"]) == 1e-5 and nominal(rows["x_0"]) == 1e-2 and nominal(rows["x"]) == 1e-3
    assert nominal(rows["k_x"]) == 1e3 and nominal(rows["g"]) is None and nominal(rows["i_max"]) is None
    assert UNITS["m"].display == ("mm", 1e3) and UNITS["A"].display == ("mA", 1e3)
    assert UNITS["s"].display == ("ms", 1e3)


def test_value_references_follow_the_c_list(repo):
    """The value references are the rows of MAGLEV_VARIABLES (c/maglev_plant.c) in order, from which
    maglev_plant.h makes the enum; the first ones are the interface every importer has used."""
    names = variable_names(repo / "c")
    md = read_model_description(str(repo / "modelDescription.xml"))
    assert [(v.name, v.valueReference) for v in md.modelVariables] == [(n, k) for k, n in enumerate(names)]
    assert names[:6] == ["u", "y", "x", "v", "i", "k_DA"] and names[-2:] == ["solver_step", "F"]
    assert len(names) == len(set(names)) > 40


def test_guid_is_the_same_everywhere(repo):
    md = read_model_description(str(repo / "modelDescription.xml"))
    assert md.guid == GUID
    for src in ("c/maglev_plant_fmu.c", "tests/c/test_fmu.c", "tests/c/test_fmi3.c"):
        m = re.search(r'#define (?:MAGLEV_)?GUID "(\{[^"]+\})"', (repo / src).read_text())
        assert m and m.group(1) == GUID, src


def test_interface_names_units_and_causalities(repo):
    md = read_model_description(str(repo / "modelDescription.xml"))
    by = {v.name: v for v in md.modelVariables}
    assert by["u"].causality == "input" and by["u"].unit == "MU"
    for name, unit in (("y", "MU"), ("x", "m"), ("v", "m/s"), ("i", "A")):
        assert by[name].causality == "output" and by[name].unit == unit
    for name in REQUIRED_PARAMETERS:
        assert by[name].causality == "parameter", name
    assert all(v.description for v in md.modelVariables)
    assert {u.name for u in md.unitDefinitions} >= {v.unit for v in md.modelVariables}
    de = md.defaultExperiment
    assert (float(de.startTime), float(de.stopTime), float(de.stepSize)) == (0.0, 3.0, 0.001)
    cs = md.coSimulation
    assert cs.modelIdentifier == "maglev"
    assert cs.canHandleVariableCommunicationStepSize and cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    # Section 3 defaults (LQ fit), Sec. 3.1-3.4
    assert float(by["k_c"].start) == 6.9e-6 and float(by["x_0"].start) == 8.3e-3
    assert float(by["T_a"].start) == 0.3e-3 and float(by["k_FV"].start) == 0.03
    assert float(by["i_max"].start) == pytest.approx(0.3 * 5.0 * 1.0)
    assert float(by["x_max"].start) < float(by["x_0"].start)


def test_fmpy_validate_finds_no_problem(fmu_path):
    assert validate_fmu(str(fmu_path)) == []


def test_archive_holds_binary_and_listed_sources(fmu_path):
    md = read_model_description(str(fmu_path))
    names = set(zipfile.ZipFile(fmu_path).namelist())
    assert "modelDescription.xml" in names
    assert "binaries/linux64/maglev.so" in names
    listed = [f for bc in md.buildConfigurations for fs in bc.sourceFileSets for f in fs.sourceFiles]
    assert sorted(listed) == ["maglev_fmi_common.c", "maglev_fmu.c", "maglev_plant.c", "maglev_plant_fmu.c"]
    for f in listed:
        assert f"sources/{f}" in names
    assert {"sources/maglev_plant.h", "sources/maglev_fmi_common.h"} <= names


def test_runtime_start_values_match_the_xml(fmu_path):
    md = read_model_description(str(fmu_path))
    params = [v for v in md.modelVariables if v.causality in ("parameter", "input")]
    with FmuPlant(fmu=fmu_path) as plant:
        got = plant.get([v.name for v in params])
    assert got == [float(v.start) for v in params]


def test_a_unit_outside_the_list_is_derived_from_its_parts():
    """A new parameter's unit needs no entry: its SI exponents come from the units it is made of."""
    assert unit_info("N.m2/A2") is UNITS["N.m2/A2"]
    assert unit_info("N.m2/A3").base == {"kg": 1, "m": 3, "s": -2, "A": -3}
    assert unit_info("V/s").base == {"kg": 1, "m": 2, "s": -4, "A": -1}
    assert unit_info("V/s").quantity == "Unit_V_per_s"
    with pytest.raises(ValueError, match="not a known unit"):
        unit_info("furlong/s")
