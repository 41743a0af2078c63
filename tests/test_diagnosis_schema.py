"""One engine and one schema for every diagnosis (docs/diagnosis-json.md): a CE152 record and a real
rig's record go through the same ``maglev_cosim.diagnosis.diagnose`` and give the same kinds of files,
the keys of ``result.SHARED_KEYS`` in diagnosis.json, and a typed ``DiagnosisResult`` whose
``to_json`` is that file."""

from __future__ import annotations

import json
import zipfile

import pytest

from real_data import REAL

INTECO = REAL / "inteco-mls2em" / "results"
need_real = pytest.mark.skipif(not INTECO.is_dir(), reason="shared real records not present")

FILES = ("diagnosis.json", "report.md", "report.html", "maglev_calibrated.fmu")


def _check(out):
    from maglev_cosim.diagnosis.result import SHARED_KEYS

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


@pytest.mark.slow
@need_real
def test_one_diagnose_takes_a_ce152_and_an_inteco_record_and_returns_one_typed_result(tmp_path):
    """The Python entry point: ``load`` reads both formats into one type, ``diagnose`` runs either
    and returns a DiagnosisResult whose ``to_json`` is the diagnosis.json it wrote."""
    from maglev_cosim.diagnosis import DiagnosisResult, diagnose
    from maglev_cosim.diagnosis.result import SHARED_KEYS, Fit, Parameter
    from maglev_cosim.records.load import load
    from maglev_cosim.records.synth import synth_record

    csv = synth_record(tmp_path / "rec.csv", effects={"delay": {"T_d": 0.003}}, reference="square", period=1.0,
                       duration=3.0, seed=2)
    results = {}
    for name, rec in (("ce152", load(csv)), ("inteco", load(INTECO / "step" / "MPC - KF.mat", "inteco-mls2em"))):
        res = diagnose(rec, effects=["delay"] if name == "ce152" else None, workers=1, out=tmp_path / name)
        assert isinstance(res, DiagnosisResult) and isinstance(res.fit, Fit)
        assert all(isinstance(p, Parameter) for p in res.parameters.values())
        d = _check(tmp_path / name)
        assert d == json.loads(json.dumps(res.to_json()))        # the file is the typed result's JSON
        assert {f.name for f in res.written} >= set(FILES)
        results[name] = (res, d)
    (ce, ce_json), (rig, rig_json) = results["ce152"], results["inteco"]
    assert set(ce_json) & set(rig_json) >= set(SHARED_KEYS)
    assert ce.kind == "ce152" and rig.kind == "rig"
    assert ce.fit.free_run is not None and rig.fit.free_run is None
    assert ce.parameters["T_d"].sigma is not None and ce.selected == ["delay"]
    assert [c.role for c in rig.comparison] == ["calibration"] and set(rig.comparison[0].horizons) == {"5 ms", "20 ms", "50 ms"}
    assert rig.segments and all(s.role == "calibration" for s in rig.segments)
    assert rig.calibrated_fmu is not None and rig.calibrated_fmu.records[0].sha256
