"""The real-rig path's model terms that need no shared record: the drift of the filtered random
force (real_rig.drift), the black box beside the model in the figures, the verdict against it."""

from __future__ import annotations

import numpy as np
import pytest

from maglev_cosim.plant import formulas
from maglev_cosim.loop import fast_loop
from maglev_cosim.diagnosis import real_rig
from maglev_cosim.loop.controllers import load_controller
from maglev_cosim.diagnosis import blackbox as bb
from maglev_cosim.records.measured import Segment
from maglev_cosim.rigs import load_rig


def _record(rig, force_pct: np.ndarray, seed: int) -> real_rig.RigRecord:
    """The Inteco model under the shipped LQI, the gap stepping between 10 and 8.5 mm every second,
    with a force ``force_pct`` [% of the weight] on the ball, read through 10 um of sensor noise
    and 5 mA of current noise."""
    p = rig.params
    n = len(force_pct)
    rng = np.random.default_rng(seed)
    gap_ref = np.where((np.arange(n) * 1e-3 // 1.0) % 2 == 0, 0.010, 0.0085)
    x0 = float(rig.to_x(0.010))
    i0 = rig.equilibrium_current(0.010)
    start = p.replace(x_start=x0, v_start=0.0, i_start=i0)
    r = fast_loop.closed_loop(start, rig.reading(gap_ref), pid=load_controller("inteco-lqi").controller,
                         u_hold=float(formulas.equilibrium_input(start.to_start_values())),
                         dF=force_pct / 100 * p.m_k * p.g)
    gap = rig.from_x(r["x"]) + rng.normal(0.0, 1e-5, n)
    return real_rig.RigRecord(label=f"model {seed}", ts=1e-3, y=np.asarray(rig.reading(gap)), u=np.asarray(r["u"]),
                            current=np.asarray(r["i"]) + rng.normal(0.0, 5e-3, n), position=gap, segment=Segment(0, n))


# the filter told the truth about the noise: 10 um of the 27.25 mm per MU reading, 5 mA of current
NOISE = {"q_force": 0.03 * 0.06054 * 9.81, "f_force": 0.05, "r_sensor": 1e-5 / 0.02725, "r_current": 5e-3}


@pytest.mark.parametrize("planted", [3.0, -2.0, 0.0])
def test_a_planted_drift_of_the_force_is_recovered_within_its_two_sigma(planted):
    """A force ramping by ``planted`` % of the weight over 8 s: the block means of the filtered
    random force change by the planted amount within their own 2σ; no drift, no finding."""
    rig = load_rig("inteco-mls2em")
    n = 8000
    force = np.linspace(0.0, planted, n)
    r = _record(rig, force, seed=int(10 + planted))
    o = real_rig.predict(rig, r, rig.params, 0.005, noise=NOISE)
    d = real_rig.drift(r, o["d"], o["d_sd"], rig.params.m_k * rig.params.g)
    t = np.asarray(d["t_s"])
    truth = np.interp(t, np.arange(n) * 1e-3, force)
    est, two_sigma = np.asarray(d["force_pct_weight"]), np.asarray(d["two_sigma_pct_weight"])
    assert len(t) == 7 and np.all(two_sigma > 0) and np.all(two_sigma < 2.0)
    assert np.all(np.abs(est - truth) <= two_sigma), (est, truth, two_sigma)
    assert abs(d["change_pct_weight"] - (truth[-1] - truth[0])) <= d["change_two_sigma"]
    assert d["significant"] == (planted != 0.0)


def test_the_figures_show_the_black_box_beside_the_model_and_the_verdict_heeds_it():
    rig = load_rig("inteco-mls2em")
    train = [_record(rig, np.zeros(6000), seed=s) for s in (1, 2)]
    test = _record(rig, np.zeros(6000), seed=3)
    boxes = {hs: bb.fit([bb.Series(r.position, r.current, r.ts) for r in train], hs) for hs in real_rig.HORIZONS_S}
    f = real_rig.figures(rig, test, rig.params, NOISE, boxes)
    for h in ("5 ms", "20 ms", "50 ms"):
        sk = f["position"][h]["skill"]
        assert set(sk) >= {"model", "black_box", "constant_velocity", "model_on_position"}
        # the exact model beats the naive predictor; the reading is linear in the gap here, so
        # the model's skill is the same on the reading and on the position
        assert sk["model"] > 0.2 and sk["model_on_position"] == pytest.approx(sk["model"], abs=1e-6)
    # with a disturbance model that says the truth (no force on the ball but a trace), the model
    # of the record's own plant beats the black box at every horizon: the filter and the
    # predictions through the unstable plant cost nothing the regression does not pay too
    exact = real_rig.figures(rig, test, rig.params, {**NOISE, "q_force": 1e-3, "f_force": 20.0}, boxes)
    for h, v in exact["position"].items():
        assert v["skill"]["model"] > v["skill"]["black_box"] + 0.05, (h, v["skill"])
    comp = real_rig.comparison([f], [f])
    assert comp["validation"]["20 ms"]["model"] == f["position"]["20 ms"]["skill"]["model"]
    # the rule: any horizon lost to the black box makes "explained" only "explained in part"
    won = {"segments": 1, "20 ms": {"model": 0.5, "black_box": 0.3}, "50 ms": {"model": 0.2, "black_box": 0.1}}
    lost = {"segments": 1, "20 ms": {"model": 0.5, "black_box": 0.3}, "50 ms": {"model": -0.1, "black_box": 0.4}}
    assert real_rig.judge_against_black_box("explained", {"validation": won})[0] == "explained"
    verdict, why = real_rig.judge_against_black_box("explained", {"calibration": won, "validation": lost})
    assert verdict == "explained in part" and "50 ms" in why[0] and "20 ms:" not in why[0]
    assert real_rig.judge_against_black_box("unexplained: mechanics", {"validation": lost})[0] == "unexplained: mechanics"
