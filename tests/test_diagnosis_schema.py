"""One schema for every diagnosis (docs/diagnosis-json.md): a CE152 record and a real rig's record
give the same kinds of files and the keys of real_rig.SHARED_KEYS in diagnosis.json."""

from __future__ import annotations

import json
import zipfile

import pytest

from real_data import REAL

INTECO = REAL / "inteco-mls2em" / "results"
need_real = pytest.mark.skipif(not INTECO.is_dir(), reason="shared real records not present")

FILES = ("diagnosis.json", "report.md", "report.html", "maglev_calibrated.fmu")


def _check(out):
    from maglev_cosim.diagnosis.real_rig import SHARED_KEYS

    for f in FILES:
        assert (out / f).is_file(), f
    d = json.loads((out / "diagnosis.json").read_text())
    missing = [k for k in SHARED_KEYS if k not in d]
    assert not missing, missing
    assert d["calibrated_fmu"]["file"].endswith("maglev_calibrated.fmu")
    assert set(d["fit"]) >= {"free_run", "prediction"} and "horizon_s" in d["fit"]["prediction"]
    with zipfile.ZipFile(out / "maglev_calibrated.fmu") as z:
        names = set(z.namelist())
    assert {"resources/calibration.json", "documentation/index.html", "modelDescription.xml"} <= names
    return d


@pytest.mark.slow
@need_real
def test_a_ce152_record_and_an_inteco_record_give_the_same_files_and_keys(tmp_path):
    from maglev_cosim.cli import main
    from maglev_cosim.records.synth import synth_record

    rec = synth_record(tmp_path / "rec.csv", effects={"delay": {"T_d": 0.003}}, reference="square", period=1.0,
                       duration=3.0, seed=2)
    assert main(["diagnose", str(rec), "--effects", "delay", "--out", str(tmp_path / "ce152")]) == 0
    ce = _check(tmp_path / "ce152")
    assert main(["diagnose", str(INTECO / "step" / "MPC - KF.mat"), "--rig", "inteco-mls2em",
                 "--out", str(tmp_path / "inteco")]) == 0
    rig = _check(tmp_path / "inteco")
    assert ce["selected"] == ["delay"]
    assert rig["fit"]["free_run"] is None and rig["fit"]["prediction"]["current"] is not None
    assert set(rig["comparison"]["calibration"]["50 ms"]) >= {"model", "black_box", "constant_velocity"}
