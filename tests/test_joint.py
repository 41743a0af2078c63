"""Several CE152 records calibrated together and judged on another (maglev_cosim.diagnosis.joint):
``maglev-cosim calibrate A.csv B.csv --validate C.csv``."""

from __future__ import annotations

import json
import zipfile

import pytest

from maglev_cosim.diagnosis.result import SHARED_KEYS


@pytest.mark.slow
def test_two_records_calibrated_together_find_the_delay_and_judge_a_third(tmp_path):
    from maglev_cosim.cli import main
    from maglev_cosim.records.synth import synth_record

    # the records of docs/diagnosis.md's example ("Several records calibrated together")
    paths = [synth_record(tmp_path / f"j{k}.csv", effects={"delay": {"T_d": 0.002}}, duration=8.0, seed=20 + k,
                          reference="square" if k == 2 else "steps") for k in (1, 2, 3)]
    out = tmp_path / "joint"
    assert main(["calibrate", str(paths[0]), str(paths[1]), "--validate", str(paths[2]), "--out", str(out)]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert set(SHARED_KEYS) <= set(d)
    assert d["selected"] == ["delay"] and d["verdict"] == "explained"
    t_d, sigma = d["parameters"]["T_d"], d["uncertainties"]["T_d"]
    assert abs(t_d - 0.002) < max(3 * sigma, 0.05 * 0.002) and 0 < sigma < 2e-4
    assert [r["role"] for r in d["records"]] == ["calibration", "calibration", "validation"]
    val = d["records"][2]
    assert val["fit_after"]["y"] > val["fit_before"]["y"] + 2      # the delay helps the record no fit saw
    assert set(d["comparison"]) == {"calibration", "validation"}
    assert d["comparison"]["validation"]["50 ms"]["model"] > d["comparison"]["validation"]["50 ms"]["black_box"]
    own = d["own_calibrations"]
    assert [c["record"] for c in own] == ["j1.csv", "j2.csv"] and all(c["selected"] == ["delay"] for c in own)
    assert min(c["parameters"]["T_d"] for c in own) - sigma < t_d < max(c["parameters"]["T_d"] for c in own) + sigma
    with zipfile.ZipFile(out / "maglev_calibrated.fmu") as z:
        cal = json.loads(z.read("resources/calibration.json"))
    assert [r["file"] for r in cal["records"]] == ["j1.csv", "j2.csv"] and all(len(r["sha256"]) == 64
                                                                                for r in cal["records"])
    assert (out / "report.html").is_file() and "j3.csv" in (out / "report.md").read_text()


@pytest.mark.slow
def test_an_effect_one_record_alone_selects_is_judged_on_the_held_out_blocks_of_all(tmp_path):
    """6 s records: the square-wave record's own search adds a sensor nonlinearity the other does
    not. The joint model takes it only if it passes the search's held-out test on all records at
    once, and the warnings say which way it went and by how much."""
    from maglev_cosim.diagnosis import diagnose
    from maglev_cosim.records.load import load
    from maglev_cosim.records.synth import synth_record

    paths = [synth_record(tmp_path / f"j{k}.csv", effects={"delay": {"T_d": 0.002}}, duration=6.0, seed=20 + k,
                          reference="square" if k == 2 else "steps") for k in (1, 2)]
    res = diagnose([load(p) for p in paths], workers=1)
    own = res.extra["own_calibrations"]
    contested = sorted({e for c in own for e in c["selected"]} - set.intersection(*(set(c["selected"]) for c in own)))
    assert contested, "the case needs an effect one record alone selects"
    for e in contested:
        note = [w for w in res.warnings if w.startswith(f"{e}: selected by 1 of 2 records alone")]
        assert len(note) == 1 and "held-out blocks of all of them its cost change is" in note[0]
        assert (e in res.selected) == note[0].endswith("in the joint model")
    assert "delay" in res.selected and [r["role"] for r in res.extra["records"]] == ["calibration", "calibration"]
    assert res.extra["records"][0]["verdict"] is not None      # no validation record: the calibration ones judged
