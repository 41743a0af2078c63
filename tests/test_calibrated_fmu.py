"""A calibrated FMU is a model of its own: its own GUID (which the unchanged binary accepts through
resources/guid.txt, and nothing else), its own model name and description, its start values, and
what it was calibrated from (resources/calibration.json, documentation/index.html)."""

from __future__ import annotations

import zipfile

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from maglev_cosim.plant.model_description import GUID
from maglev_cosim.plant.calibrated_fmu import calibrated_fmu, issued_guid

PARAMS = {"T_d": 0.003, "k_c": 7.1e-6, "x_0": 0.0081}


@pytest.fixture()
def calibrated(tmp_path, fmu_path):
    out = tmp_path / "cal.fmu"
    calibrated_fmu(fmu_path, out, PARAMS, model_name="CE152, calibrated on rec.csv", description="calibrated on rec.csv",
                   resources={"calibration.json": b"{}"}, documentation={"index.html": b"<html></html>"},
                   source_sha256="ab" * 32)
    return out


def _instantiate(fmu, tmp_path, guid):
    slave = FMU2Slave(guid=guid, unzipDirectory=extract(str(fmu), unzipdir=str(tmp_path / "x")),
                      modelIdentifier="maglev", instanceName="cal")
    try:
        slave.instantiate()
    except Exception as e:  # fmpy raises when fmi2Instantiate returns NULL
        return None, str(e)
    return slave, ""


def test_calibrated_fmu_has_its_own_identity_and_passes_fmpys_checks(calibrated):
    assert validate_fmu(str(calibrated)) == []
    md = read_model_description(str(calibrated))
    assert md.guid != GUID and md.guid == issued_guid(GUID, PARAMS, "ab" * 32)
    assert md.modelName == "CE152, calibrated on rec.csv" and md.description == "calibrated on rec.csv"
    assert md.coSimulation.modelIdentifier == "maglev"
    with zipfile.ZipFile(calibrated) as z:
        assert z.read("resources/guid.txt").decode().strip() == md.guid
        assert z.read("documentation/index.html") == b"<html></html>"
        assert z.read("resources/calibration.json") == b"{}"
    # deterministic, and a different calibration or record gives another GUID
    assert issued_guid(GUID, {**PARAMS, "T_d": 0.004}, "ab" * 32) != md.guid
    assert issued_guid(GUID, PARAMS, "cd" * 32) != md.guid


def test_calibrated_fmu_instantiates_with_its_guid_and_starts_from_the_calibrated_values(calibrated, tmp_path):
    md = read_model_description(str(calibrated))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave, err = _instantiate(calibrated, tmp_path, md.guid)
    assert slave is not None, err
    try:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        got = slave.getReal([vr[n] for n in PARAMS])
        assert got == [PARAMS[n] for n in PARAMS]
        assert {v.name: float(v.start) for v in md.modelVariables if v.name in PARAMS} == PARAMS
    finally:
        slave.freeInstance()


@pytest.mark.parametrize("which", ["nominal GUID", "tampered GUID"])
def test_a_guid_other_than_the_issued_one_is_refused(calibrated, tmp_path, which):
    md = read_model_description(str(calibrated))
    guid = GUID if which == "nominal GUID" else md.guid[:-2] + ("0}" if md.guid[-2] != "0" else "1}")
    slave, err = _instantiate(calibrated, tmp_path, guid)
    assert slave is None, f"{which} accepted"


def test_the_nominal_fmu_still_accepts_only_its_built_in_guid(fmu_path, tmp_path):
    slave, err = _instantiate(fmu_path, tmp_path, GUID)
    assert slave is not None, err
    slave.freeInstance()
    slave, _ = _instantiate(fmu_path, tmp_path, issued_guid(GUID, PARAMS))
    assert slave is None


def test_a_guid_file_without_a_guid_is_refused_naming_the_file(calibrated, tmp_path, capsys):
    bad = tmp_path / "bad.fmu"
    with zipfile.ZipFile(calibrated) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.infolist():
            data = b"not a guid\n" if item.filename == "resources/guid.txt" else zin.read(item.filename)
            zout.writestr(item, data)
    md = read_model_description(str(bad))
    from fmpy import simulate_fmu

    # fmpy's default logger prints the FMU's messages: a logger of our own would stay in fmpy's logger
    # proxy (one global) after this call, dangling, for every FMU instantiated later in the process
    capsys.readouterr()
    with pytest.raises(Exception):
        simulate_fmu(str(bad), stop_time=0.01, debug_logging=True)
    text = capsys.readouterr().out
    assert "resources/guid.txt" in text, text
    assert md.guid  # the description itself is intact: it is the resource that is refused
