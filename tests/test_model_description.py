"""modelDescription.xml against the C side: value references, names, starts, GUID, archive."""

from __future__ import annotations

import re
import zipfile

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from maglev_cosim.fmu import FmuPlant
from maglev_cosim.model_description import GUID, generate, read_table

REQUIRED_PARAMETERS = ["k_DA", "u_0", "k_i", "T_a", "m_k", "g", "k_c", "x_0", "k_FV", "k_x", "y_0", "k_AD",
                       "y_MU0", "x_min", "x_max", "i_max", "x_start", "v_start", "i_start"]


def test_committed_xml_is_what_the_c_table_generates(repo, fmu_binary):
    committed = (repo / "modelDescription.xml").read_text()
    generated = generate(read_table(fmu_binary))
    assert committed == generated, (
        "modelDescription.xml differs from the C variable table: run "
        f"python -m maglev_cosim.model_description {fmu_binary} {repo / 'modelDescription.xml'}")


def test_value_references_follow_the_c_enum(repo):
    header = (repo / "c" / "maglev_plant.h").read_text()
    enum = re.search(r"typedef enum \{(.*?)\} MaglevVR;", header, re.S).group(1)
    names = re.findall(r"\bVR_(\w+)", enum)
    md = read_model_description(str(repo / "modelDescription.xml"))
    assert [(v.name, v.valueReference) for v in md.modelVariables] == [(n, k) for k, n in enumerate(names)]


def test_guid_is_the_same_everywhere(repo):
    md = read_model_description(str(repo / "modelDescription.xml"))
    assert md.guid == GUID
    for src in ("c/maglev_fmu.c", "tests/c/test_fmu.c"):
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
    assert sorted(listed) == ["maglev_fmu.c", "maglev_plant.c"]
    for f in listed:
        assert f"sources/{f}" in names
    assert "sources/maglev_plant.h" in names


def test_runtime_start_values_match_the_xml(fmu_path):
    md = read_model_description(str(fmu_path))
    params = [v for v in md.modelVariables if v.causality in ("parameter", "input")]
    with FmuPlant(fmu=fmu_path) as plant:
        got = plant.get([v.name for v in params])
    assert got == [float(v.start) for v in params]
