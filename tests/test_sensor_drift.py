"""The effect sensor_drift (docs/model.md, item 7): the sensor's offset creeping at r_y [V/s]. Planted in
a synthetic record by the rig emulator, found by the diagnosis with its rate; the C plant agrees with the
reference (tests/test_cosim.py takes the catalogue's example by itself)."""

from __future__ import annotations

import pytest

from maglev_cosim.diagnosis import pipeline
from maglev_cosim.records.record import read_record
from maglev_cosim.records.synth import synth_record


@pytest.mark.slow   # the quick tier's 2-minute budget: a diagnosis, 2-3 s
def test_a_drifting_sensor_is_found_and_its_rate_recovered(tmp_path):
    path = synth_record(tmp_path / "drift.csv", effects={"sensor_drift": {"r_y": 0.01}}, duration=8.0, seed=5)
    d = pipeline.run(read_record(path), effects=["delay", "force_lag", "sensor_drift"])
    assert d.selected == ["sensor_drift"], [(c["effect"], c["held_out_gain"]) for c in d.candidates]
    assert d.parameters["r_y"] == pytest.approx(0.01, rel=0.2)
    assert d.to_json()["verdict"] == "explained"


@pytest.mark.slow   # the quick tier's 2-minute budget: a diagnosis, 2-3 s
def test_no_drift_is_not_found(tmp_path):
    path = synth_record(tmp_path / "none.csv", duration=8.0, seed=5)
    d = pipeline.run(read_record(path), effects=["sensor_drift"])
    assert d.selected == []
