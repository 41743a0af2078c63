"""The second force lag (effect ``eddy_lag``, issue 21 item 2): a share ``beta_F`` of the magnetic
force behind a slower lag ``T_F2``, a state of the C plant (``F2``) and of its filter. Written three
times (C, the pure-Python reference, the emulator), off by default, its values checked."""

from __future__ import annotations

import numpy as np
import pytest

from maglev_cosim.diagnosis.effects import CATALOGUE, DEFAULT_EFFECTS
from maglev_cosim.diagnosis.replay import baseline_params, estimate_noise, predict
from maglev_cosim.plant import fast
from maglev_cosim.plant.formulas import point
from maglev_cosim.plant.params import get_params
from maglev_cosim.records.record import read_record
from maglev_cosim.records.synth import synth_record
from rig_physics import INTECO, open_loop_pair

@pytest.mark.parametrize("extra", [{"beta_F": 0.6, "T_F2": 0.015}, {"beta_F": 0.6, "T_F2": 0.015, "T_F": 5e-3},
                                   {"beta_F": 0.3, "T_F2": 0.05, "T_F": 2e-3, "T_d": 1.5e-3}])
def test_the_two_lag_force_agrees_between_the_c_plant_and_the_reference(extra):
    """The voltage-driven Inteco plant with the second lag (and the first, and a delay), C against the
    reference written from docs/model.md: the ball travels through free flight and onto a stop."""
    c, r = open_loop_pair(INTECO, extra)
    none, _ = open_loop_pair(INTECO)
    assert np.ptp(c["x"]) > 2e-3                               # the ball travels
    assert np.max(np.abs(c["x"] - none["x"])) > 1e-4           # the lag acts
    assert np.max(np.abs(c["i"] - r["i"])) <= 1e-7             # [A]
    assert np.max(np.abs(c["x"] - r["x"])) <= 1e-8             # [m]


def test_off_by_default_and_bit_identical_whatever_its_time_constant():
    """beta_F = 0 (the default) is the plant without the effect, to the bit, whatever T_F2."""
    p = get_params("baseline").replace(**INTECO)
    op = point(p, p.x_start)
    p = p.replace(i_start=op.i)
    assert p.beta_F == 0.0
    u = op.u * (1 + 0.02 * np.sin(np.arange(200) * 0.03))
    a = fast.open_loop(p.to_start_values(), u)
    b = fast.open_loop(p.replace(T_F2=0.3).to_start_values(), u)
    for n in ("x", "v", "i", "y"):
        assert np.array_equal(a[n], b[n]), n
    assert "eddy_lag" in CATALOGUE and "eddy_lag" not in DEFAULT_EFFECTS      # opt-in
    assert CATALOGUE["eddy_lag"].params == ("beta_F", "T_F2")


@pytest.mark.parametrize("bad", [{"beta_F": -0.1}, {"beta_F": 1.2}, {"beta_F": float("nan")}, {"T_F2": 0.0},
                                 {"T_F2": 2.0}, {"T_F2": float("inf")}])
def test_bad_values_are_refused_naming_the_variable(bad):
    (name,) = bad
    p = get_params("baseline").replace(**bad)
    with pytest.raises(ValueError, match=f"variable {name}"):
        p.validate()
    with pytest.raises(ValueError, match=name):
        fast.open_loop(p.to_start_values(), np.full(10, 0.3))


def test_the_filter_with_the_second_lag_predicts_an_emulator_record_made_with_it_better(tmp_path):
    """A record of the rig emulator (written apart from the C plant) with a share 0.6 of the force
    behind 15 ms: the filter whose plant has the lag predicts it 50 ms ahead better than the one
    without, each with the noise it estimates on the record."""
    rec = read_record(synth_record(tmp_path / "r.csv", duration=6.0, seed=21,
                                   effects={"eddy_lag": {"beta_F": 0.6, "T_F2": 0.015}}))
    base = baseline_params()
    err = {}
    for label, vals in (("without", base), ("with", {**base, "beta_F": 0.6, "T_F2": 0.015})):
        out = predict(rec, vals, estimate_noise(rec, vals), horizon_s=0.05, stride=5)
        ok = np.isfinite(out["y_pred"])
        err[label] = float(np.sqrt(np.mean((out["y_pred"][ok] - rec.y[ok]) ** 2)))
    assert err["with"] < 0.8 * err["without"], err


def test_the_linearisation_has_the_slow_force_as_a_state_and_keeps_the_steady_gain():
    """linear.linearize: F2 is a state; at steady state the force is the static one, so the DC gain
    from u to y is the plant's without the lag (both are unstable, the gain of the transfer function)."""
    from maglev_cosim.plant.linear import linearize, transfer_function

    p = get_params("section3")
    for extra in ({}, {"T_F": 2e-3}):
        q = p.replace(**extra)
        sys2 = linearize(q.replace(beta_F=0.6, T_F2=0.015))
        assert sys2.nstates == linearize(q).nstates + 1
        g0 = float(np.real(transfer_function(q)(0)))
        g2 = float(np.real(transfer_function(q.replace(beta_F=0.6, T_F2=0.015))(0)))
        assert g2 == pytest.approx(g0, rel=1e-9)


def test_the_real_rig_calibration_recovers_a_planted_second_lag():
    """real_rig.calibrate fits beta_F and T_F2 (within :data:`real_rig.SECOND_FORCE_LAG`'s bounds) on a
    record of the Inteco model (the C plant in closed loop with the shipped LQI) made with them:
    measured 0.492 ± 0.005 and 20.03 ± 0.32 ms for 0.5 and 20 ms, in 21 evaluations."""
    import sys
    from pathlib import Path

    from maglev_cosim.diagnosis import real_rig
    from maglev_cosim.rigs import load_rig

    sys.path.insert(0, str(Path(__file__).parent))
    from test_rigfit import NOISE, _record

    rig = load_rig("inteco-mls2em")
    r = _record(rig, np.zeros(5000), seed=5, params=rig.params.replace(beta_F=0.5, T_F2=0.02), period=0.5)
    _, cal = real_rig.calibrate(rig, [r], rig.params, names=("beta_F", "T_F2"), noise=NOISE, fit_noise=False,
                                max_evaluations=20)
    assert cal.values["beta_F"] == pytest.approx(0.5, abs=0.03)
    assert cal.values["T_F2"] == pytest.approx(0.02, rel=0.05)
    assert 0 < cal.sigma["beta_F"] < 0.03 and not cal.on_bounds


def test_the_real_rig_run_refuses_an_unknown_fitting_mode(tmp_path):
    from maglev_cosim.diagnosis import real_rig
    from maglev_cosim.rigs import load_rig

    assert real_rig.SECOND_FORCE_LAG_FIT is None      # off by default (docs/rigs.md: measured, no gain)
    with pytest.raises(ValueError, match="second_force_lag"):
        real_rig.run(load_rig("inteco-mls2em"), [], tmp_path, second_force_lag="both")
