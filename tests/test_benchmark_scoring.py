"""The acceptance benchmark's scoring (scripts/diagnosis_matrix.py): a delay the independent emulator
puts in by itself (its PID's output a fraction of a sample late) is a finding about its records, not
a false positive; the project emulator puts in none."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import diagnosis_matrix as dm  # noqa: E402


def _record_with_truth(tmp_path: Path, truth: dict) -> Path:
    path = tmp_path / "rec.csv"
    path.write_text("t,w,y,u\n")
    Path(str(path) + ".truth.json").write_text(json.dumps(truth))
    return path


def test_the_independent_emulators_own_delay_is_read_from_its_settings(tmp_path):
    path = _record_with_truth(tmp_path, {"emulator": "ivp", "settings": {"pid_offset": 0.3}})
    assert dm._own_delay(path, 1e-3) == pytest.approx(3e-4)
    assert dm._own_delay(_record_with_truth(tmp_path, {"effects": {}}), 1e-3) == 0.0


def test_a_delay_at_the_emulators_own_value_has_its_row_and_is_no_false_positive():
    null = [{"seed": 1, "selected": ["delay"], "verdict": "explained", "own_delay_s": 3e-4, "own_delay_found": True,
             "estimates": {"T_d": 3.4e-4}, "sigma": {"T_d": 3e-5}},
            {"seed": 2, "selected": [], "verdict": "no effect", "own_delay_s": 3e-4, "own_delay_found": False,
             "estimates": {}, "sigma": {}}]
    assert dm.false_positives(null) == 0
    assert dm.false_positives([{**null[0], "own_delay_found": False}, null[1]]) == 1   # a delay at another value
    checks = {c["criterion"]: c["measured"] for c in dm._checks({"null": null, "power": []}, 2,
                                                                 dm.false_positives(null), 0, 0)}
    assert checks["false positives"] == "0 of 2 (0.0 %)"
    assert checks["the emulator's own computation delay found (as a delay or a lag)"] == "1 of 2 (50.0 %)"
    text = dm.family_section({"null": null, "power": [], "checks": [{"criterion": c, "records": 2, "measured": m,
                                                                      "target": "—"} for c, m in checks.items()]},
                             "ivp")
    assert "seed 1: explained (delay: T_d = 0.340 ± 0.030 ms, the emulator's own 0.30 ms)" in text
    assert "not as a false positive" in text


def test_explained_is_judged_against_the_true_models_error(tmp_path):
    """The benchmark's measure of 'explained': the final model's 20 ms error of y over that of the
    emulator's own plant (baseline, planted effect) on the record. On a record with a 2.5 ms delay,
    the true model's error is below the baseline's (the model without the delay), and the checks
    count an 'explained' row beyond 1.2x of it, whatever the twin says."""
    from maglev_cosim.records.record import read_record
    from maglev_cosim.records.synth import synth_record

    path = synth_record(tmp_path / "d.csv", duration=6.0, seed=3, effects={"delay": {"T_d": 0.0025}})
    rec = read_record(path)
    true = dm.true_prediction_y(rec, path, {"delay": {"T_d": 0.0025}})
    without = dm.true_prediction_y(rec, path, {})
    assert 0 < true < 0.8 * without
    row = {"case": "delay", "effect": "delay", "seed": 3, "planted": {"T_d": 0.0025}, "selected": ["delay"],
           "verdict": "explained", "after_over_true_prediction_y": 1.3, "after_over_null_prediction_y": 1.0,
           "estimates": {"T_d": 0.0025}, "i_limited_share": 0.0}
    checks = {c["criterion"]: c["measured"] for c in dm._checks({"null": [], "power": [row]}, 0, 0, 1, 1)}
    assert checks["'explained' beyond 1.2× the true model's error"] == "1"
    assert checks["'explained' beyond 1.2× the no-effect twin's error"] == "0"


def test_a_delay_beside_the_planted_effect_at_the_emulators_own_value_is_no_spurious_second_effect():
    base = {"case": "current limit 2 %", "effect": "current_saturation", "seed": 1, "planted": {"i_max": 0.7},
            "verdict": "explained", "after_over_true_prediction_y": 1.0, "after_over_null_prediction_y": 1.0,
            "estimates": {"i_max": 0.7}, "i_limited_share": 0.02, "own_delay_s": 3e-4}
    own = {**base, "selected": ["current_saturation", "delay"], "estimates_all": {"i_max": 0.7, "T_d": 3.3e-4},
           "sigma_all": {"T_d": 2e-5}}
    other = {**base, "selected": ["current_saturation", "force_lag"], "estimates_all": {"i_max": 0.7, "T_F": 1e-3}}
    far = {**own, "estimates_all": {"i_max": 0.7, "T_d": 1.2e-3}}
    project = {**own, "own_delay_s": 0.0}
    wrong = {**base, "selected": ["delay"], "estimates_all": {"T_d": 2e-3}}      # a miss, not a second effect
    assert dm.extra_effects(own) == [] and dm.extra_effects(other) == ["force_lag"]
    assert dm.extra_effects(far) == ["delay"] and dm.extra_effects(project) == ["delay"]
    lag = {**base, "selected": ["current_saturation", "force_lag"], "estimates_all": {"i_max": 0.7, "T_F": 2.9e-4}}
    assert dm.extra_effects(lag) == []                       # a 0.29 ms lag is the 0.3 ms delay's twin
    assert dm.extra_effects(wrong) == []
    checks = {c["criterion"]: c["measured"] for c in dm._checks({"null": [], "power": [own, other, far, project, wrong]},
                                                                 0, 0, 0, 0)}
    assert checks["spurious second effect"] == "3 of 5 (60.0 %)"


def test_a_short_lag_at_the_emulators_own_delay_is_that_delay_and_a_long_one_is_not():
    """A first-order lag of T and a delay of T have the same phase to 1 % below 1/(6T): a force or
    amplifier lag found alone at the emulator's own delay is that delay, under its twin's name."""
    assert dm.own_delay_effect(["force_lag"], {"T_F": 2.94e-4}, {}, 3e-4) == "force_lag"
    assert dm.own_delay_effect(["amplifier_lag"], {"T_a": 3.1e-4}, {"T_a": 1e-5}, 3e-4) == "amplifier_lag"
    assert dm.own_delay_effect(["force_lag"], {"T_F": 2e-3}, {"T_F": 1e-4}, 3e-4) is None
    assert dm.own_delay_effect(["sensor_nonlinearity"], {"k_x2": 3e-4}, {}, 3e-4) is None
    assert dm.own_delay_effect(["force_lag"], {"T_F": 3e-4}, {}, 0.0) is None     # the project emulator has none
