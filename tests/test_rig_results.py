"""The real-rig path's stage results are typed (maglev_cosim.diagnosis.rig_result): each stage of a
small run on records of the Inteco model (the C plant under the shipped LQI, tests/test_rigfit.py)
returns its dataclass, whose ``to_json()`` holds the keys, in the order, that ``diagnosis.json`` has
always had for that stage, and is strict JSON once made finite (``result.finite``, as the diagnosis
writes it)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from maglev_cosim.diagnosis import blackbox as bb
from maglev_cosim.diagnosis import real_rig
from maglev_cosim.diagnosis.result import DiagnosisResult, finite, from_rig
from maglev_cosim.diagnosis.rig_result import (ClosedLoopFigures, ControllerCheck, EffectTrial, RigCalibration,
                                               RigCoilCalibration, RigComparison, RigCorrection, RigDrift, RigFigures,
                                               RigForceBalance, RigHorizon, RigRecordResult, RigRun, RigSearch,
                                               RigSegment, RigValidationSegment)
from maglev_cosim.rigs import load_rig

from test_rigfit import NOISE, _record

HORIZONS = ["5 ms", "20 ms", "50 ms"]
HORIZON_KEYS = ["model", "stays_put", "model_measured_input", "rms_y", "rms_y_measured_input", "constant_velocity",
                "skill_vs_stays_put", "skill"]
DRIFT_KEYS = ["t_s", "force_pct_weight", "two_sigma_pct_weight"]
DRIFT_CHANGE_KEYS = ["change_pct_weight", "change_two_sigma", "significant", "range_pct_weight"]
SKILL_ROW = ["model", "model_worst", "model_measured_input", "model_measured_input_worst", "black_box", "black_box_worst",
             "black_box_past", "black_box_past_worst", "constant_velocity", "constant_velocity_worst"]
TRIAL_KEYS = ["round", "effect", "parameter", "value", "values", "location", "held_out_gain", "held_out_gains"]


@pytest.fixture(scope="module")
def stages():
    """Every typed stage once, on 4 s records (a few seconds in all)."""
    rig = load_rig("inteco-mls2em")
    train = _record(rig, np.zeros(4000), seed=31, period=0.5)
    test = _record(rig, np.zeros(4000), seed=32, period=0.5)
    series = [bb.Series(train.position, train.current, train.ts)]
    boxes = {hs: bb.fit(series, hs) for hs in real_rig.HORIZONS_S}
    boxes.update({("past", hs): bb.fit(series, hs, future=False) for hs in real_rig.HORIZONS_S})
    with_box = real_rig.figures(rig, test, rig.params, NOISE, boxes)
    without = real_rig.figures(rig, train, rig.params, NOISE)
    _, cal = real_rig.calibrate(rig, [train], rig.params, names=("k_e",), noise=NOISE, fit_noise=False,
                                max_evaluations=3)
    _, coil = real_rig.calibrate_coil(rig, [train], rig.params, names=("R_c",))
    search = real_rig.effect_search(rig, [train], rig.params, noise=NOISE, max_effects=1)
    co = real_rig.correction_search(rig, [train], rig.params, NOISE, max_nfev=1)
    comp = real_rig.comparison([without], [with_box])
    return {"figures": with_box, "figures_no_box": without, "calibration": cal, "search": search, "correction": co,
            "comparison": comp, "coil": coil}


def _strict(d) -> str:
    """``d`` as diagnosis.json holds it: made finite, dumped as strict JSON."""
    return json.dumps(finite(d), allow_nan=False, sort_keys=False)


def test_each_stage_returns_its_dataclass(stages):
    assert isinstance(stages["figures"], RigFigures) and isinstance(stages["figures"].drift, RigDrift)
    assert all(isinstance(p, RigHorizon) for p in stages["figures"].position.values())
    assert isinstance(stages["calibration"], RigCalibration)
    assert isinstance(stages["search"], RigSearch) and all(isinstance(c, EffectTrial) for c in stages["search"].candidates)
    assert isinstance(stages["correction"], RigCorrection)
    assert isinstance(stages["comparison"], RigComparison)
    assert isinstance(stages["coil"], RigCoilCalibration)


def test_the_coil_calibration_json_keeps_the_keys_of_diagnosis_json(stages):
    coil = stages["coil"]
    d = coil.to_json()
    assert list(d) == ["names", "values", "sigma", "fit", "on_bounds"]
    assert d["names"] == ["R_c"] and list(d["fit"]) == ["model 31"] and d["fit"]["model 31"] > 80
    assert d["values"]["R_c"] == coil.values["R_c"] and d["sigma"]["R_c"] > 0
    assert json.loads(_strict(coil)) == json.loads(_strict(d))


def test_the_figures_json_keeps_the_keys_of_diagnosis_json(stages):
    f, plain = stages["figures"], stages["figures_no_box"]
    d = f.to_json()
    assert list(d) == ["label", "samples", "duration_s", "position", "identified_controller", "drift", "current"]
    assert d["samples"] == 4000 and d["duration_s"] == pytest.approx(4.0) and d["label"] == "model 32"
    assert list(d["position"]) == HORIZONS and list(d["current"]) == ["from_actuator", "noise_A", "noise_ceiling", *HORIZONS]
    for h in HORIZONS:
        p = d["position"][h]
        # with a black box, its fit comes last and its skills beside the model's
        assert list(p) == [*HORIZON_KEYS, "black_box"]
        assert list(p["skill"]) == ["model", "model_measured_input", "constant_velocity", "black_box", "black_box_past",
                                    "model_on_position"]
        assert p["skill"]["model"] == f.position[h].skill["model"] and p["model"] == f.position[h].model
        assert list(plain.to_json()["position"][h]) == HORIZON_KEYS
        assert list(plain.to_json()["position"][h]["skill"]) == ["model", "model_measured_input", "constant_velocity"]
    # three blocks of 1 s after the filter settles: the change from the first to the last is judged
    assert list(d["drift"]) == DRIFT_KEYS + DRIFT_CHANGE_KEYS and len(d["drift"]["t_s"]) == 3
    assert d["drift"]["significant"] is f.drift.significant and isinstance(f.drift.significant, bool)
    assert d["identified_controller"] == f.identified_controller
    assert json.loads(_strict(f)) == json.loads(_strict(d))


def test_a_drift_of_one_block_and_a_figure_without_current_leave_their_keys_out():
    one = RigDrift(t_s=[1.0], force_pct_weight=[0.5], two_sigma_pct_weight=[0.2])
    assert list(one.to_json()) == DRIFT_KEYS
    h = RigHorizon(model=90.0, stays_put=80.0, model_measured_input=85.0, rms_y=float("nan"), rms_y_measured_input=0.1,
                   constant_velocity=70.0, skill_vs_stays_put=0.5, skill={"model": 0.5})
    f = RigFigures(label="x", samples=10, duration_s=0.01, position={"5 ms": h}, identified_controller={"missing": "short"},
                   drift=one, current=None)
    d = f.to_json()
    assert d["current"] is None and list(d["position"]["5 ms"]) == HORIZON_KEYS
    assert math.isnan(d["position"]["5 ms"]["rms_y"])
    with pytest.raises(ValueError):          # NaN is not strict JSON ...
        json.dumps(d, allow_nan=False)
    assert json.loads(_strict(d))["position"]["5 ms"]["rms_y"] is None     # ... but null once made finite


def test_the_calibration_json_keeps_the_keys_of_diagnosis_json(stages):
    cal = stages["calibration"]
    d = cal.to_json()
    assert list(d) == ["names", "values", "rig_values", "noise", "sigma", "horizons_s", "cost_before", "cost_after",
                       "evaluations", "on_bounds", "noise_on_bounds"]
    assert d["names"] == ["k_e"] and set(d["values"]) == set(d["rig_values"]) == set(d["sigma"]) == {"k_e"}
    assert set(d["noise"]) >= {"q_force", "f_force", "r_sensor", "r_current"}
    assert d["horizons_s"] == list(real_rig.CAL_HORIZONS_S) and d["cost_after"] <= d["cost_before"]
    assert d["evaluations"] == cal.evaluations > 0
    assert json.loads(_strict(cal)) == json.loads(_strict(d))


def test_the_effect_search_json_keeps_the_keys_of_diagnosis_json(stages):
    s = stages["search"]
    d = s.to_json()
    assert list(d) == ["held_out_cost", "block_s", "min_gain", "offered", "skipped", "candidates", "selected",
                       "parameters", "computed", "last_round_empty", "taken_off"]
    assert set(d["held_out_cost"]) == {"y", "i", "total"} and d["block_s"] == real_rig.EFFECT_BLOCK_S
    assert len(d["candidates"]) == len(s.candidates) > 0 and all(c["round"] == 1 for c in d["candidates"])
    for c, t in zip(d["candidates"], s.candidates):
        assert list(c)[: len(TRIAL_KEYS)] == TRIAL_KEYS and c["held_out_gain"] == t.held_out_gain
        rest = list(c)[len(TRIAL_KEYS):]
        if "+" in c["effect"]:      # a pair fitted jointly: its effects, no start
            assert rest == ["effects"] and c["effects"] == c["effect"].split("+")
        elif t.screened is not None:
            assert rest == ["screened", "start_fit_gain"]
        else:
            assert rest == ["start_fit_gain"]
    assert d["selected"] == s.selected and isinstance(d["last_round_empty"], bool)
    assert json.loads(_strict(s)) == json.loads(_strict(d))


def test_the_correction_json_keeps_the_keys_of_diagnosis_json(stages):
    co = stages["correction"]
    d = co.to_json()
    assert list(d) == ["basis", "shapes", "ridge", "held_out_cost_without", "held_out", "held_out_gain",
                       "held_out_gain_by_shape", "min_gain", "selected", "correction", "coef", "sigma", "cost_before",
                       "cost_after", "evaluations", "summary"]
    assert list(d["basis"]) == ["n_x", "x_c", "x_s", "v_s", "v_c", "p_mean"] and list(d["held_out"]) == ["by_ridge", "by_shape"]
    assert len(d["coef"]) == len(d["sigma"]) == 3 * real_rig.CORRECTION_NX
    # the correction for the model only when selected, with the refitted coefficients
    assert (d["correction"] is None) == (not co.selected)
    if co.selected:
        assert d["correction"]["coef"] == d["coef"]
    assert d["summary"]["answer"] == co.summary["answer"] and "viscous_N_s_per_m" in d["summary"]
    assert json.loads(_strict(co)) == json.loads(_strict(d))


def test_the_comparison_json_keeps_the_keys_of_diagnosis_json_and_reads_back(stages):
    comp, f = stages["comparison"], stages["figures"]
    d = comp.to_json()
    assert list(d) == ["calibration", "validation"]
    for role in d:
        assert list(d[role]) == ["segments", *HORIZONS] and d[role]["segments"] == 1
        assert all(list(d[role][h]) == SKILL_ROW for h in HORIZONS)
    # one segment: its median is its own skill; the calibration segment had no black box
    assert d["validation"]["20 ms"]["model"] == f.position["20 ms"].skill["model"]
    assert math.isnan(d["calibration"]["20 ms"]["black_box"])
    assert comp.get("validation").horizons["50 ms"].black_box == f.position["50 ms"].skill["black_box"]
    assert comp.get("nothing") is None
    back = RigComparison.from_json(d)
    assert _strict(back) == _strict(comp) and "NaN" not in _strict(comp)


def test_a_run_writes_its_typed_stages_in_the_order_of_diagnosis_json(stages):
    """from_rig keeps the typed stages in ``extra`` (RigRun.own_keys: the optional ones only where they ran,
    in the file's order); DiagnosisResult.to_json writes each as its to_json."""
    f, comp = stages["figures"], stages["comparison"]
    seg = RigSegment(label=f.label, after=f, before=stages["figures_no_box"], own_coil={"R_c": 10.0},
                     frequency_response=None)
    val = RigValidationSegment(file="v.mat", label="v", after=f, warnings=["w"], before=f,
                               force_balance_calibrated=RigForceBalance(0.9, 1.0, 1.1, 500, True, 1.0))
    fb = RigForceBalance(0.2, 0.25, 0.3, 1000, False, 2.0, ohm={"median_V_over_Ri": 2.1, "samples": 40})
    cc = ControllerCheck(actuator_fit=93.0, start="rest", fits_by_start={"settled": 80.0, "rest": 93.0},
                         loops={"current -> actuator": {"fit": 97.0, "rms_input_units": 0.05}})
    record = RigRecordResult(file="r.mat", label="r", warnings=[], segments=[seg], force_balance=fb, controller_check=cc,
                             closed_loop=[ClosedLoopFigures(label=f.label, horizon_s=0.02, gap_fit=95.0, actuator_fit=60.0)])
    run = RigRun(rig="inteco-mls2em", rig_file="inteco.toml", fit_segments=1, horizons_s=[0.005, 0.02, 0.05],
                 records=[record], validation=[val], controller={"name": "c", "file": "c.toml", "type": "cascade"},
                 coil_calibration=stages["coil"], effects=stages["search"], correction=stages["correction"],
                 calibration=stages["calibration"], disturbance_model={"q_force": 0.01}, black_box={},
                 comparison=comp, verdict="explained", reasons=["because"], parameters={"k_e": 1.0},
                 uncertainties={"k_e": 0.1}, written=["diagnosis.json"])
    assert list(run.own_keys()) == ["rig", "rig_file", "records", "validation", "horizons_s", "coil_calibration",
                                    "effects", "correction", "calibration", "disturbance_model", "black_box",
                                    "controller"]
    r = from_rig(run)
    assert isinstance(r, DiagnosisResult) and r.extra["effects"] is stages["search"]
    assert r.segments[0].skill["20 ms"] == f.position["20 ms"].skill_vs_stays_put and r.segments[1].role == "validation"
    assert [c.role for c in r.comparison] == ["calibration", "validation"] and r.parameters["k_e"].sigma == 0.1
    d = json.loads(json.dumps(r.to_json(), allow_nan=False))
    assert d == json.loads(json.dumps(run.to_json(), allow_nan=False))
    assert list(d["records"][0]) == ["file", "label", "warnings", "segments", "force_balance", "controller_check",
                                     "closed_loop"]
    assert list(d["records"][0]["force_balance"]) == ["p10", "median", "p90", "samples", "consistent",
                                                      "current_scale_for_weight", "ohm"]
    assert list(d["records"][0]["controller_check"]) == ["actuator_fit", "start", "fits_by_start", "loops"]
    assert d["records"][0]["closed_loop"] == [{"label": f.label, "horizon_s": 0.02, "gap_fit": 95.0, "actuator_fit": 60.0}]
    assert list(d["validation"][0]["force_balance_calibrated"]) == ["p10", "median", "p90", "samples", "consistent",
                                                                    "current_scale_for_weight"]
    # the checks, typed in the diagnosis's result too
    (check,) = r.checks
    assert check.force_balance == (0.25, 0.2, 0.3) and check.controller == "c" and check.actuator_fit == 93.0
    assert check.loop_fits == {"current -> actuator": 97.0} and check.closed_loop == [(95.0, 60.0)]
    assert list(d["records"][0]["segments"][0]) == ["label", "before", "after", "own_coil", "frequency_response"]
    assert d["records"][0]["segments"][0]["after"] == json.loads(_strict(f))
    assert list(d["validation"][0]) == ["file", "label", "before", "after", "warnings", "force_balance_calibrated",
                                        "own_coil"]
    for key in ("coil_calibration", "calibration", "effects", "correction", "comparison"):
        assert d[key] == json.loads(_strict(getattr(run, key))), key
    # nothing calibrated: no coil stage, no black box, the calibration null
    bare = RigRun(rig="x", rig_file="x.toml", verdict="too little information")
    assert list(bare.own_keys()) == ["rig", "rig_file", "records", "validation", "horizons_s", "calibration",
                                     "disturbance_model"]
    assert json.loads(json.dumps(bare.to_json(), allow_nan=False))["calibration"] is None


def test_the_prediction_plots_windows_show_two_places():
    # a step where the model also errs most: the second window goes to the next largest error
    # elsewhere, not to the same step again (step/MPC showed its one step twice)
    from types import SimpleNamespace

    import numpy as np

    from maglev_cosim.diagnosis.real_rig import WINDOW_S, event_windows

    ts, n = 1e-3, 15000
    pos = np.where(np.arange(n) < 5000, 0.010, 0.012)
    y = pos.copy()
    y_pred = y.copy()
    y_pred[5010] += 1e-3       # the largest error, at the step
    y_pred[11000] += 5e-4      # the next, ten seconds on
    r = SimpleNamespace(y=y, position=pos, ts=ts)
    (t1, a1, e1), (t2, a2, e2) = event_windows(r, y_pred, 20)
    assert t1.startswith("largest move and model error") and a1 <= 5000 < e1
    assert t2.startswith("largest model error elsewhere") and a2 <= 11000 < e2
    assert e1 - a1 == e2 - a2 == round(WINDOW_S / ts) and (e1 <= a2 or e2 <= a1)
    # where the largest error lies elsewhere, the two windows are the move's and the error's
    y_pred[5010] = y[5010]
    (t1, a1, _), (t2, a2, e2) = event_windows(r, y_pred, 20)
    assert t1.startswith("largest move (") and t2.startswith("largest model error (") and a2 <= 11000 < e2
