"""Issue 22's benchmark failures of seeds 2900 and 2501 on the project emulator, each a full
diagnosis (about 40 s): a 2 ms force lag chosen as its twin, the delay; a sensor bend of -3e4 and a
Coulomb friction of 1.8 % of the weight ended 'no effect' (the friction at 1.67 times the true
model's error); a 78 us delay accepted beside a current limit active 62 % of the samples. The
records are the benchmark's (scripts/diagnosis_matrix.py): the same draws, the same effects."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from maglev_cosim.diagnosis import pipeline
from maglev_cosim.records import emulator_ivp
from maglev_cosim.records.record import read_record
from maglev_cosim.records.synth import draw_disturbance, synth_record

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import diagnosis_matrix as dm  # noqa: E402

pytestmark = pytest.mark.slow


def _diagnose(tmp_path: Path, seed: int, planted: dict):
    path = dm.SYNTH(tmp_path / "p.csv", seed=seed, disturbance=draw_disturbance(seed), effects=planted)
    rec = read_record(path, plausibility="warn")
    return rec, path, pipeline.run(rec)


@pytest.mark.parametrize("effect", ["force_lag", "sensor_nonlinearity"])
def test_the_planted_effect_of_seed_2900_is_chosen_alone(tmp_path, effect):
    planted = {effect: dict(dm.CATALOGUE[effect].example)}
    _, _, d = _diagnose(tmp_path, 2900, planted)
    assert d.selected == [effect], (d.selected, d.alternatives)
    assert not d.alternatives, d.alternatives          # the innovations told the twins apart
    (p, v), = planted[effect].items()
    assert abs(d.parameters[p] / v - 1) <= dm.CATALOGUE[effect].tolerance[p], d.parameters[p]


def test_a_friction_of_1_8_percent_of_the_weight_is_not_called_no_effect(tmp_path):
    frac = dm._log_uniform(2900, 2202, *dm.FRICTION_SHARE)
    planted = {"coulomb_friction": {"F_c": frac * dm.WEIGHT}}
    rec, path, d = _diagnose(tmp_path, 2900, planted)
    assert d.verdict.verdict != "no effect"
    assert "coulomb_friction" in d.selected, d.selected
    assert d.verdict.after.prediction_rms["y"] < 1.2 * dm.true_prediction_y(rec, path, planted)


def _benchmark_limit(tmp_path: Path, seed: int) -> float:
    """The current limit the benchmark drew for ``seed`` (scripts/diagnosis_matrix.py) [A] until
    2026-11-28, when these cases were found: the nearest to the target share in 6 tries."""
    dist = draw_disturbance(seed)
    share = dm._log_uniform(seed, 2201, *dm.LIMIT_SHARE)
    pct = dm._truth(dm.SYNTH(tmp_path / "null.csv", seed=seed, disturbance=dist))["current_percentiles"]
    return dm._limit_for_share(tmp_path / "limit.csv", seed, dist, share, pct[50], pct[100], tries=6, within=None)[0]


def test_no_second_effect_beside_a_limit_active_62_percent(tmp_path):
    seed = 2501
    i_max = _benchmark_limit(tmp_path, seed)
    _, path, d = _diagnose(tmp_path, seed, {"current_saturation": {"i_max": i_max}})
    assert dm._truth(path)["i_limited_share"] > 0.5
    assert d.selected == ["current_saturation"], d.selected
    assert abs(d.parameters["i_max"] / i_max - 1) <= 0.05, (d.parameters["i_max"], i_max)


def test_a_limit_the_k_step_fit_would_take_off_stays_alone(tmp_path):
    # seed 5401 of benchmark seeds 5400: a limit active in 28 % of the samples, accepted at LR 1227,
    # which the k-step refit took to within 0.3 sigma of off; refitted without it, the search in
    # prediction mode took a Coulomb friction first and the limit 12 % high, `explained` at 3.0 times
    # the true model's 20 ms error. Judged at the free run's fit, it stayed, alone, but 9 % low (the
    # free run's i_max 0.620 A for 0.685): the k-step fit's 0.676 A was judged by the free run's
    # standard errors (sigma 3.0 A, from a free run that loses the ball at those values), and with the
    # disturbance estimates restarted (replay.minimize_restarted) the model left 1.23 times the true
    # model's error. Judged by the k-step's own standard errors, it stays, and the search in
    # prediction mode (the free run failing) finds the limit alone within 1 %.
    planted = {"current_saturation": {"i_max": _benchmark_limit(tmp_path, 5401)}}
    rec, path, d = _diagnose(tmp_path, 5401, planted)
    assert 0.2 < dm._truth(path)["i_limited_share"] < 0.4
    assert d.selected == ["current_saturation"], d.selected
    assert abs(d.parameters["i_max"] / planted["current_saturation"]["i_max"] - 1) <= 0.05, d.parameters["i_max"]
    assert d.verdict.verdict == "explained"
    assert d.verdict.after.prediction_rms["y"] < 1.2 * dm.true_prediction_y(rec, path, planted)


@pytest.mark.parametrize("emulator, seed, v_c", [("rig", 3101, 1e-4), ("ivp", 3100, 1e-3)])
def test_a_friction_and_its_smoothing_speed_are_recovered(tmp_path, emulator, seed, v_c):
    """The smoothing speed is fitted with the friction (Eq. 8's F_c·tanh(v/v_c), docs/model.md): on
    the independent emulator's 1 mm/s friction of 8.6 % of the weight, which ended `calibration
    failed` with the plant's smoothing held at 0.1 mm/s (docs/diagnosis.md, 'Known limits'), and on
    the project emulator's 0.1 mm/s at 2 %. Both found, within 25 % in F_c and a factor 1.5 in v_c."""
    synth = emulator_ivp.synth_record if emulator == "ivp" else dm.SYNTH
    F_c = (0.086 if emulator == "ivp" else 0.02) * dm.WEIGHT
    planted = {"coulomb_friction": {"F_c": F_c, "v_c": v_c}}
    path = synth(tmp_path / "p.csv", seed=seed, disturbance=draw_disturbance(seed), effects=planted)
    d = pipeline.run(read_record(path, plausibility="warn"))
    assert d.selected == ["coulomb_friction"], (d.selected, d.verdict.verdict)
    assert abs(d.parameters["F_c"] / F_c - 1) < dm.CATALOGUE["coulomb_friction"].tolerance["F_c"], d.parameters["F_c"]
    assert 1 / 1.5 < d.parameters["v_c"] / v_c < 1.5, d.parameters["v_c"]


def test_the_independent_emulators_force_lag_is_not_read_as_a_delay(tmp_path):
    """Seed 3100's 2 ms force lag on the independent emulator (sensor noise low-passed at 100 Hz):
    the twins are told apart by innovations with a coloured sensor noise where the record shows one
    (pipeline.by_innovations); with white sensor noise the delay had been chosen (LR -34.7)."""
    planted = {"force_lag": {"T_F": 0.002}}
    path = emulator_ivp.synth_record(tmp_path / "p.csv", seed=3100, disturbance=draw_disturbance(3100), effects=planted)
    d = pipeline.run(read_record(path, plausibility="warn"))
    assert "force_lag" in d.selected and "delay" not in d.selected, (d.selected, d.alternatives)


def test_a_force_exponent_absorbed_by_the_baseline_is_found(tmp_path):
    """Seed 3300's force exponent of 3, whose screen from the calibrated baseline (x_0 mimics it)
    ended at n_F 2.14 and a sensor bend was chosen: fitted to convergence beside a start from where
    the calibration started (ForceExponent.absorbed_by), it is found and told from the bend."""
    planted = {"force_exponent": dict(dm.CATALOGUE["force_exponent"].example)}
    _, _, d = _diagnose(tmp_path, 3300, planted)
    assert d.selected == ["force_exponent"], (d.selected, d.alternatives)
    assert abs(d.parameters["n_F"] / 3.0 - 1) <= dm.CATALOGUE["force_exponent"].tolerance["n_F"], d.parameters["n_F"]


def test_the_37_hz_pickup_of_seed_6300_is_explained_at_the_true_models_error(tmp_path):
    """Seed 6300's pickup: the final model's disturbance estimate stopped on the likelihood's flat
    ridge (a 17.5 Hz corner, 118 nats short of the 2.5 Hz one) and its 20 ms prediction left 1.21
    times the true model's error beside 'explained'. With the restarted search
    (replay.minimize_restarted): 1.17."""
    planted = {"periodic_disturbance": dict(dm.CATALOGUE["periodic_disturbance"].example)}
    rec, path, d = _diagnose(tmp_path, 6300, planted)
    assert d.selected == ["periodic_disturbance"], d.selected
    if d.verdict.verdict == "explained":
        assert d.verdict.after.prediction_rms["y"] < 1.2 * dm.true_prediction_y(rec, path, planted)


def test_a_record_whose_ball_mostly_rests_on_a_stop_is_not_explained(tmp_path):
    """A current limit of 0.6 A on a 6 s staircase of the rig emulator: the ball falls and rests on
    the lower stop in 88 % of the samples, so the reader refuses the record unless told. Read anyway,
    the limit is found (0.626 A), and the verdict is at most 'explained in part', with the reason."""
    path = synth_record(tmp_path / "r.csv", effects={"current_saturation": {"i_max": 0.6}}, duration=6.0, seed=3)
    d = pipeline.run(read_record(path, plausibility="warn"))
    assert d.verdict.verdict not in ("explained", "no effect"), d.verdict.verdict
    if d.verdict.verdict == "explained in part":
        assert any("the reader refuses unless told" in w for w in d.verdict.warnings)
