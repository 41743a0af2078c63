"""The rig emulator and synthetic records (the data the diagnosis is tested on)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglev_cosim.records.record import read_record
from maglev_cosim.records.emulator import LSB, RigConfig, position_to_mu, reference, simulate_rig
from maglev_cosim.records.synth import parse_effect_spec, synth_record


def quiet(**kw) -> RigConfig:
    return RigConfig(sigma_y=0.0, sigma_F_rel=0.0, quantise=False).with_values(**kw)


def test_settled_start_stays_settled():
    cfg = quiet()
    w = np.full(1000, float(position_to_mu(cfg, 3.2e-3)))
    sim = simulate_rig(w, cfg, noise=False)
    assert np.max(np.abs(sim["x"] - 3.2e-3)) < 1e-9
    assert np.max(np.abs(sim["u"] - sim["u"][0])) < 1e-9


def test_step_settles_on_the_reference():
    cfg = quiet()
    w0 = float(position_to_mu(cfg, 3.2e-3))
    w = np.where(np.arange(2000) < 100, w0, w0 + 0.05)
    sim = simulate_rig(w, cfg, noise=False)
    assert sim["y"][-1] == pytest.approx(w0 + 0.05, abs=1e-3)   # the integrator zero at -1.5 is slow
    assert np.all(np.abs(sim["y"][1600:] - (w0 + 0.05)) < 2e-3)


def test_records_are_quantised_to_12_bits(tmp_path):
    rec = read_record(synth_record(tmp_path / "r.csv", effects={}, duration=3.0, seed=1))
    for sig in (rec.u, rec.y):
        assert np.max(np.abs(sig / LSB - np.round(sig / LSB))) < 1e-6 / LSB * 2
    truth = json.loads((tmp_path / "r.csv.truth.json").read_text())
    assert truth["effects"] == {} and "effect" not in " ".join(rec.meta)


def _run(**kw):
    cfg = quiet(**kw)
    w = reference("square", 4.0, seed=0)
    return simulate_rig(w, cfg, noise=False)


def test_each_effect_changes_the_response_as_it_should():
    base = _run()
    delayed = _run(T_d=2.5e-3)
    # a delay costs phase margin: the step at 1.5 s overshoots more (measured 0.104 vs 0.066 MU)
    w = reference("square", 4.0, seed=0)
    over = lambda sim: sim["y"][1500:2400].max() - w[1600]  # noqa: E731
    assert over(delayed) > 1.3 * over(base)
    sat = _run(i_max=0.8)
    assert sat["i"].max() <= 0.8 + 1e-12 and base["i"].max() > 0.8
    pick = _run(A_d=0.01, f_d=37.0)
    f = np.fft.rfftfreq(4000, 1e-3)
    spec = np.abs(np.fft.rfft(pick["u"] - base["u"]))
    assert abs(f[np.argmax(spec[f > 5]) + np.sum(f <= 5)] - 37.0) < 0.5
    nonlin = _run(k_x2=-2e4)
    # the loop regulates the reading: the true positions differ where the sensor bends
    assert np.max(np.abs(nonlin["x"] - base["x"])) > 2e-5
    lag = _run(T_a=3e-3)
    assert np.max(np.abs(lag["y"] - base["y"])) > 1e-3
    exponent = _run(n_F=2.4)
    assert np.max(np.abs(exponent["u"] - base["u"])) > 1e-3


def test_effect_specs():
    assert parse_effect_spec("delay:T_d=0.004") == ("delay", {"T_d": 0.004})
    assert parse_effect_spec("periodic_disturbance:A_d=0.01,f_d=50") == \
        ("periodic_disturbance", {"A_d": 0.01, "f_d": 50.0})
    with pytest.raises(ValueError, match="unknown effect 'lag'"):
        parse_effect_spec("lag:T=1")
    with pytest.raises(ValueError, match="no parameter 'T_a'"):
        parse_effect_spec("delay:T_a=1")
    with pytest.raises(ValueError, match="not a number"):
        parse_effect_spec("delay:T_d=abc")


def test_square_and_sine_references_take_a_period():
    w = reference("square", 1.2, 1e-3, period=0.6)
    steps = np.flatnonzero(np.diff(w)) + 1
    assert list(steps) == [300, 600, 900]
    assert np.array_equal(reference("square", 6.0, 1e-3), reference("square", 6.0, 1e-3, period=3.0))
    s = reference("sine", 2.0, 1e-3, period=1.0)
    assert abs(s[250] - s[750]) > 0.01 and s[0] == pytest.approx(s[1000])
    for kind, period in (("steps", 0.6), ("square", 0.0), ("sine", -1.0)):
        with pytest.raises(ValueError, match="period"):
            reference(kind, 1.0, 1e-3, period=period)


def test_the_truth_sidecar_says_how_often_the_current_limit_acts(tmp_path):
    """The benchmark plants a limit by the share of samples it acts in (scripts/diagnosis_matrix.py):
    the sidecar gives that share and the current's percentiles, for both emulators' records."""
    free = json.loads((synth_record(tmp_path / "a.csv", duration=3.0, seed=2, reference="square",
                                    period=0.6).parent / "a.csv.truth.json").read_text())
    assert free["i_limited_share"] == 0.0
    pct = free["current_percentiles"]
    assert len(pct) == 101 and pct == sorted(pct) and 0.3 < pct[50] < 1.0
    i_max = 0.5 * (pct[99] + pct[100])           # below the transients' peaks only
    bitten = json.loads((synth_record(tmp_path / "b.csv", duration=3.0, seed=2, reference="square", period=0.6,
                                      effects={"current_saturation": {"i_max": i_max}}).parent
                         / "b.csv.truth.json").read_text())
    assert 0.0 < bitten["i_limited_share"] < 0.2
    assert max(bitten["current_percentiles"]) <= i_max + 1e-12
