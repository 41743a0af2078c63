"""The FMI 3.0 co-simulation FMU (maglev3.fmu): same plant, same variables, same guards as the 2.0 one,
checked through fmpy's FMI 3 support. fmusim (Reference-FMUs), the reference importer, runs it in
tests/test_fmi_checkers.py (with every other FMU the project writes) and agrees with fmpy there."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave
from fmpy.validation import validate_fmu

import maglev_cosim
from maglev_cosim.loop.fmu import FmuError, FmuPlant
from maglev_cosim.loop.simulate import reference_signal, simulate
from maglev_cosim.plant.model_description import GUID
from maglev_cosim.plant.params import get_params

X = 0.0032


@pytest.fixture(scope="module")
def fmu3() -> Path:
    return maglev_cosim.fmu_path(fmi_version=3)


def test_fmu_path_api(fmu3):
    assert maglev_cosim.fmu_path().name == "maglev.fmu"          # the 2.0 API unchanged
    assert maglev_cosim.fmu_path(fmi_version=2) == maglev_cosim.fmu_path()
    assert fmu3.name == "maglev3.fmu" and fmu3.is_file()
    with pytest.raises(ValueError, match="fmi_version"):
        maglev_cosim.fmu_path(fmi_version=4)


def test_fmpy_validate_finds_no_problem(fmu3):
    assert validate_fmu(str(fmu3)) == []


def test_same_variables_units_ranges_and_token_as_the_2_0_fmu(fmu3, fmu_path):
    m3, m2 = read_model_description(str(fmu3)), read_model_description(str(fmu_path))
    assert m3.fmiVersion == "3.0" and m3.instantiationToken == GUID == m2.guid
    assert m3.coSimulation.canGetAndSetFMUstate and m3.coSimulation.canSerializeFMUstate  # fmpy names both versions so

    def row(v):
        return (v.name, v.valueReference, v.causality, v.variability, v.start, v.min, v.max, v.nominal,
                v.unit, v.displayUnit, v.description)

    vars3 = [v for v in m3.modelVariables if v.causality != "independent"]
    assert [row(v) for v in vars3] == [row(v) for v in m2.modelVariables]
    (time,) = [v for v in m3.modelVariables if v.causality == "independent"]
    assert time.name == "time" and time.valueReference == len(vars3)


def test_archive_holds_the_fmi3_binary_and_buildable_sources(fmu3):
    names = set(zipfile.ZipFile(fmu3).namelist())
    assert {"modelDescription.xml", "binaries/x86_64-linux/maglev.so", "sources/buildDescription.xml"} <= names
    bd = zipfile.ZipFile(fmu3).read("sources/buildDescription.xml").decode()
    for f in ("maglev_fmi3.c", "maglev_fmi_common.c", "maglev_plant_fmu.c", "maglev_plant.c"):
        assert f'name="{f}"' in bd and f"sources/{f}" in names
    assert {"sources/maglev_plant.h", "sources/maglev_fmi_common.h"} <= names


def test_default_experiment_matches_the_2_0_fmu(fmu3, fmu_path):
    kw = dict(start_values={"u": 0.7}, stop_time=0.3, output_interval=1e-3, output=["y", "x", "v", "i"])
    a, b = simulate_fmu(str(fmu3), **kw), simulate_fmu(str(fmu_path), **kw)
    assert a["x"].max() == pytest.approx(6.3e-3)                   # lifted to the upper stop
    for name in ("y", "x", "v", "i"):
        assert np.array_equal(a[name], b[name]), name


def test_bad_values_are_refused_naming_the_variable(fmu3):
    with pytest.raises(FmuError, match="fmi3SetFloat64: variable m_k: must be in"):
        FmuPlant({"m_k": -1.0}, fmu=fmu3)
    with pytest.raises(FmuError, match="variable u: value nan is not finite"):
        FmuPlant({"u": float("nan")}, fmu=fmu3)
    with pytest.raises(FmuError, match="x_max"):
        FmuPlant({"x_max": 9e-3}, fmu=fmu3)                         # relation checked at initialisation
    with FmuPlant(fmu=fmu3) as plant:
        with pytest.raises(FmuError, match="fixed parameter"):
            plant.set({"k_c": 1e-5})
        with pytest.raises(FmuError, match="communicationStepSize"):
            plant.step(-1e-3)


def test_state_save_restore_and_serialization_through_fmpy(fmu3):
    md = read_model_description(str(fmu3))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU3Slave(guid=md.instantiationToken, unzipDirectory=extract(str(fmu3)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="s")
    fmu.instantiate(logMessage=lambda *a: None)
    try:
        fmu.setFloat64([vr["u"]], [0.75])
        fmu.enterInitializationMode(startTime=0.0)
        fmu.exitInitializationMode()
        for k in range(40):
            fmu.doStep(k * 1e-3, 1e-3)
        state = fmu.getFMUState()
        blob = bytes(fmu.serializeFMUState(state))
        out = [vr[n] for n in ("y", "x", "v", "i", "time")]

        def run_on():
            for k in range(40, 120):
                fmu.doStep(k * 1e-3, 1e-3)
            return fmu.getFloat64(out)

        first = run_on()
        fmu.setFMUState(state)
        assert run_on() == first
        restored = fmu.deserializeFMUState(blob)
        fmu.setFMUState(restored)
        assert fmu.getFloat64([vr["time"]]) == [pytest.approx(0.04)]
        assert run_on() == first
        assert first[1] > 0.0 and first[4] == pytest.approx(0.12)  # the ball moved; time is the FMU's
        bad = bytearray(blob)
        bad[len(bad) // 2] ^= 0x10
        with pytest.raises(FMICallException):
            fmu.deserializeFMUState(bytes(bad))
        fmu.freeFMUState(state)
        fmu.freeFMUState(restored)
    finally:
        fmu.terminate()
        fmu.freeInstance()


def test_closed_loop_pid_step_matches_the_2_0_fmu_to_1e12(fmu3, fmu_path):
    """The paper's PID (Eq. 24/25) at 1 kHz, 0.05 MU step from 3.2 mm over 2 s, through fmpy on both FMUs
    (loop.simulate's FMU backend; FmuPlant picks FMU2Slave or FMU3Slave). Measured: identical (0.0)."""
    from maglev_cosim.plant.linear import operating_point

    p = get_params("section3")
    w = reference_signal("step", 2.0, 1e-3, base=operating_point(p, X).y_MU, amplitude=0.05, t_step=0.0)
    a = simulate(p, w, backend="fmu", fmu=fmu3)
    b = simulate(p, w, backend="fmu", fmu=fmu_path)
    for name in ("y", "u", "x", "v", "i"):
        assert np.max(np.abs(a[name] - b[name])) <= 1e-12, name
    assert a["y"].max() > operating_point(p, X).y_MU + 0.05   # it moved (overshoot), not two constants


def _fmutool() -> Path | None:
    exe = Path(sys.executable).parent / "fmutool"
    return exe if exe.exists() else (Path(shutil.which("fmutool")) if shutil.which("fmutool") else None)


@pytest.mark.slow
@pytest.mark.parametrize("which", [2, 3])
def test_fmu_manipulation_toolbox_checker_passes(which, tmp_path):
    """fmutool -check (fmu-manipulation-toolbox, PyPI, in the test extra) on both FMUs; a broken copy
    (a start value outside its max) shows the checker does look."""
    exe = _fmutool()
    if exe is None:
        pytest.skip("fmu-manipulation-toolbox is not installed (pip install '.[test]' installs it)")
    fmu = maglev_cosim.fmu_path(fmi_version=which)

    def check(path):
        r = subprocess.run([str(exe), "-input", str(path), "-check"], capture_output=True, text=True, timeout=120)
        return r.returncode, r.stdout + r.stderr

    rc, out = check(fmu)
    assert rc == 0 and f"compliant with FMI-{which}.0" in out and f"No semantic error against the FMI-{which}" in out, out
    broken = tmp_path / fmu.name
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(broken, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'name="k_DA"', b'name="k_DA" bogusAttribute="1"', 1)
            zout.writestr(item, data)
    rc, out = check(broken)
    assert f"compliant with FMI-{which}.0" not in out, out

