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
    assert checks["the emulator's own computation delay found as a delay"] == "1 of 2 (50.0 %)"
    text = dm.family_section({"null": null, "power": [], "checks": [{"criterion": c, "records": 2, "measured": m,
                                                                      "target": "—"} for c, m in checks.items()]},
                             "ivp")
    assert "seed 1: explained (delay: T_d = 0.340 ± 0.030 ms, the emulator's own 0.30 ms)" in text
    assert "not as a false positive" in text
