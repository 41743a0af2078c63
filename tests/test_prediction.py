"""The prediction-error replay (issue 7 item 1): the extended Kalman filter on the C plant, its
k-step predictions, the disturbance estimate, and the innovations' predictable share."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from maglev_cosim.loop import fast_loop
from maglev_cosim.diagnosis.verdict import converter_step, on_bounds, own_share, predictable_share
from maglev_cosim.loop.simulate import settled_start
from maglev_cosim.plant.params import get_params
from maglev_cosim.loop.pid import PID
from maglev_cosim.records.record import Record, read_record
from maglev_cosim.diagnosis.replay import (NOISE_RESTARTS, RESTART_MAXFEV, NoiseModel, _scaled_nll, baseline_params,
                                           estimate_noise, innovation_nll, minimize_restarted, predict)
from maglev_cosim.records.emulator import LSB
from maglev_cosim.records.synth import synth_record

NOISE = NoiseModel(q_force=2.5e-4, f_force=8.0, r_sensor=2.5e-4)


def _clean_record(params: dict[str, float], n: int = 3000) -> Record:
    """A noise-free record of the C plant itself: the filter's model is exact."""
    p = get_params("baseline").replace(**{k: v for k, v in params.items() if k != "x_start"})
    start, u_hold = settled_start(p, 0.0032)
    w = np.full(n, 0.0)
    sim0 = fast_loop.closed_loop(start, np.zeros(1), pid=PID(), u_hold=u_hold)
    w[:] = sim0["y"][0]
    w[n // 3:] += 0.04
    w[2 * n // 3:] -= 0.07
    sim = fast_loop.closed_loop(start, w, pid=PID(), u_hold=u_hold)
    t = np.arange(n) * 1e-3
    return Record("clean", t, w, sim["u"], sim["y"], 1e-3, 2.0, 2.97, 0.01, 0.0, 1.0)


@pytest.mark.parametrize("extra", [{}, {"T_a": 3e-3}, {"T_d": 2.5e-3, "T_F": 1e-3}, {"T_y": 2e-3},
                                   {"beta_F": 0.6, "T_F2": 0.015, "T_F": 1e-3}])
def test_predictions_of_an_exact_model_are_exact(extra):
    """With the plant's own noise-free record the k-step predictions equal the record: the
    filter's bookkeeping (sample order, PID state, delay line, lags) matches the free run."""
    params = {**baseline_params(), **extra}
    rec = _clean_record(params)
    out = predict(rec, params, NOISE, horizon_s=0.02, stride=7)
    ok = np.isfinite(out["y_pred"])
    assert ok.sum() == len(range(0, rec.n - 20, 7))
    assert np.max(np.abs(out["y_pred"][ok] - rec.y[ok])) < 1e-6
    assert np.max(np.abs(out["u_pred"][ok] - rec.u[ok])) < 1e-5
    assert np.nanmax(np.abs(out["innov"][1:])) < 1e-6


def test_a_wrong_model_predicts_worse_and_leaves_predictable_innovations():
    params = baseline_params()
    rec = _clean_record({**params, "T_d": 3e-3})
    good = predict(rec, {**params, "T_d": 3e-3}, NOISE)
    bad = predict(rec, params, NOISE)
    ok = np.isfinite(good["y_pred"])
    err = lambda o: float(np.sqrt(np.mean((o["y_pred"][ok] - rec.y[ok]) ** 2)))  # noqa: E731
    assert err(bad) > 100 * max(err(good), 1e-9)


def test_noise_levels_are_recovered_from_an_emulator_record(tmp_path):
    """The rig emulator's disturbances (written apart from the C plant): white sensor noise of
    2e-4 MU plus 12-bit quantisation, a random force of 0.3 % of the weight through a 20 ms lag.
    Measured: r 2.46e-4 MU (truth 2.45e-4), q 2.5e-4 N (truth 2.47e-4) on 12 s records."""
    rec = read_record(synth_record(tmp_path / "r.csv", duration=6.0, seed=11))
    nm = estimate_noise(rec, baseline_params())
    r_true = math.sqrt(2e-4**2 + LSB**2 / 12)
    q_true = 3e-3 * 8.4e-3 * 9.81
    assert nm.r_sensor == pytest.approx(r_true, rel=0.1)
    assert nm.q_force == pytest.approx(q_true, rel=0.35)
    assert 1.0 < nm.f_force < 100.0      # the corner (truth 8 Hz) is only weakly identified by 6 s


def test_the_likelihood_concentrated_on_the_ratios_is_the_likelihood_at_the_best_common_scale(tmp_path):
    """Every noise level scaled alike leaves the filter's innovations as they are and scales their
    variances: _scaled_nll's closed-form factor c gives the mean ``log s + e²/s`` of the levels
    scaled by √c (the start covariance's fixed part is forgotten within the skipped samples), and
    any other factor gives more."""
    rec = read_record(synth_record(tmp_path / "r.csv", duration=3.0, seed=5))
    p = baseline_params()
    unit = NoiseModel(q_force=1e-4, f_force=12.0, r_sensor=1e-3)
    cost, c = _scaled_nll(predict(rec, p, unit, horizon_s=0.0))
    scaled = lambda k: NoiseModel(unit.q_force * math.sqrt(k), unit.f_force, unit.r_sensor * math.sqrt(k))  # noqa: E731
    assert 0.01 < c < 0.5                   # the unit levels' sensor noise is 4 times the record's
    assert innovation_nll(rec, p, scaled(c)) == pytest.approx(cost, abs=1e-6)
    for k in (0.7 * c, 1.4 * c):
        assert innovation_nll(rec, p, scaled(k)) > cost + 1e-3
    # held within a range: the cost there is the mean at the range's end
    lo_cost, lo_c = _scaled_nll(predict(rec, p, unit, horizon_s=0.0), c_range=(2 * c, 10 * c))
    assert lo_c == pytest.approx(2 * c) and lo_cost == pytest.approx(innovation_nll(rec, p, scaled(2 * c)), abs=1e-6)


def test_the_disturbance_estimate_ends_at_the_likelihood_s_maximum(tmp_path):
    """The concentrated search's estimate (q, f, r) is a maximum of the likelihood over all three
    levels: none of them moved by 10 % either way lowers the mean ``log s + e²/s``; and on a record
    with a 50 Hz pickup the baseline lacks, whose likelihood has a plateau where the sensor noise
    takes the pickup, it ends on the deeper one where a random force does (the search from the
    usual start without the grid ended on the plateau: a mean of -12.3 against -14.4)."""
    p = baseline_params()
    pickup = {"periodic_disturbance": {"A_d": 0.008, "f_d": 50.0, "phi_d": 0.0}}
    for name, effects in (("plain", {}), ("pickup", pickup)):
        rec = read_record(synth_record(tmp_path / f"{name}.csv", effects=effects, duration=4.0, seed=11))
        nm = estimate_noise(rec, p, coloured=False)
        best = innovation_nll(rec, p, nm)
        for field in ("q_force", "f_force", "r_sensor"):
            for k in (0.9, 1.1):
                moved = NoiseModel(**{**nm.__dict__, field: getattr(nm, field) * k})
                assert innovation_nll(rec, p, moved) > best - 1e-4, (name, field, k)
        if name == "pickup":
            sensor_takes_it = NoiseModel(q_force=2e-4, f_force=4.5, r_sensor=1.2e-3)
            assert best < innovation_nll(rec, p, sensor_takes_it) - 1.0
            assert nm.q_force > 10 * 3e-3 * 8.4e-3 * 9.81      # the force took the pickup


def test_a_disturbance_estimate_is_kept_for_the_same_record_and_model(tmp_path, monkeypatch):
    """estimate_noise keeps its last estimates: the same record and arguments give the same estimate
    without a new search; another model, another record (even with the same samples), another
    argument, or an ``info`` dict that asks for the figures search again."""
    from maglev_cosim.diagnosis import replay as rp
    from maglev_cosim.diagnosis.memo import Memo
    rec = _clean_record(baseline_params(), n=1500)
    calls = []
    real = rp._estimate_noise

    def counted(*a, **kw):
        calls.append(1)
        return real(*a, **kw)

    monkeypatch.setattr(rp, "_estimate_noise", counted)
    monkeypatch.setattr(rp, "_ESTIMATES", Memo(rp.ESTIMATES_KEPT))
    p = baseline_params()
    first = estimate_noise(rec, p)
    assert estimate_noise(rec, dict(p)) is first and len(calls) == 1
    estimate_noise(rec, {**p, "k_FV": 0.031})
    estimate_noise(Record(**{f: getattr(rec, f) for f in rec.__dataclass_fields__}), p)
    estimate_noise(rec, p, coloured=False)
    info: dict = {}
    estimate_noise(rec, p, info=info)
    assert len(calls) == 5 and info


def test_predictable_share_sees_a_missing_delay(tmp_path):
    rec = read_record(synth_record(tmp_path / "r.csv", duration=6.0, seed=12, effects={"delay": {"T_d": 0.0025}}))
    base = baseline_params()
    shares = {}
    for label, vals in (("without", base), ("with", {**base, "T_d": 0.0025})):
        out = predict(rec, vals, estimate_noise(rec, vals), horizon_s=0.0)
        shares[label] = predictable_share(out["innov"], rec.u)
    assert shares["with"] < 0.01 < 0.1 < shares["without"], shares


def test_white_innovations_have_no_predictable_share():
    rng = np.random.default_rng(0)
    assert predictable_share(rng.standard_normal(20000), rng.standard_normal(20000)) < 0.003


@pytest.mark.parametrize("bad", [{"q_force": 0.0}, {"r_sensor": math.nan}, {"f_force": -1.0}])
def test_bad_filter_settings_are_refused_in_one_line(bad):
    rec = _clean_record(baseline_params(), n=500)
    nm = NoiseModel(**{**NOISE.__dict__, **bad})
    with pytest.raises(ValueError) as err:
        predict(rec, baseline_params(), nm)
    assert "invalid filter settings" in str(err.value) and "\n" not in str(err.value)


def test_bounds_that_are_search_limits_fail_the_calibration_physical_ones_do_not():
    base = baseline_params()
    search, physical = on_bounds({**base, "x_0": 6.8e-3, "k_FV": 0.0})
    assert [s.split(" =")[0] for s in search] == ["x_0"]
    assert [s.split(" =")[0] for s in physical] == ["k_FV"]
    assert on_bounds(base) == ([], [])


def test_every_catalogue_effect_says_where_it_acts():
    from maglev_cosim.diagnosis.effects import CATALOGUE

    assert {e.location for e in CATALOGUE.values()} == {"actuator", "mechanics", "sensor"}
    assert all(e.location in ("actuator", "mechanics", "sensor") for e in CATALOGUE.values())


@pytest.mark.parametrize("u_dz", [0.2, 0.5, 1.5])
def test_an_amplifier_dead_zone_is_the_d_a_offset_so_it_is_opt_in(tmp_path, u_dz):
    """The amplifier cannot reverse the current: a dead zone of half-width u_dz around 0 V replays
    as the D/A offset u_0 lowered by u_dz (to rounding; bit-identical at u_0 = 0), which every fit calibrates. A record
    cannot show it, so the default catalogue does not try it."""
    from maglev_cosim.diagnosis.effects import DEFAULT_EFFECTS
    from maglev_cosim.diagnosis.replay import replay

    rec = read_record(synth_record(tmp_path / "r.csv", duration=3.0, seed=2))
    base = baseline_params()
    zone = replay(rec, {**base, "u_dz": u_dz})
    offset = replay(rec, {**base, "u_0": base["u_0"] - u_dz})
    assert np.ptp(zone["u"]) > 0.05 and np.min(zone["i"]) < 0.5 * np.max(zone["i"])   # the loop moves
    assert np.max(np.abs(zone["y"] - offset["y"])) <= 1e-12 and np.max(np.abs(zone["u"] - offset["u"])) <= 1e-12
    assert "amplifier_dead_zone" not in DEFAULT_EFFECTS


def test_the_converter_step_is_found_through_print_rounding():
    """A 10-bit and a 12-bit grid printed to 6 decimals, with gaps of up to 200 steps, give their
    steps; a value half a step off halves it; a signal on no grid, or with a value off it, gives 0."""
    rng = np.random.default_rng(3)
    for bits in (10, 12):
        q = 2.0 / 2**bits
        levels = np.concatenate([np.arange(800, 1000), [1200, 1400]]) * q - 0.5
        v = np.round(rng.choice(levels, 5000), 6)
        assert converter_step(v) == pytest.approx(q, rel=1e-5)
        assert converter_step(np.append(v, v[0] + q / 2)) == pytest.approx(q / 2, rel=1e-5)   # a finer grid
        assert converter_step(np.append(v, v[0] + 0.37 * q)) == 0.0
    assert converter_step(rng.uniform(0.3, 0.6, 5000)) == 0.0
    assert converter_step(np.full(100, 0.4)) == 0.0


def test_a_model_s_own_records_carry_its_converters_rounding():
    """own_share: the C plant's closed loop with the model's own disturbances. On a record whose
    reading and input sit on a coarse 10-bit grid with little sensor noise, the exact model's own
    records leave several % of the innovations predictable (the rounding error is not white);
    on a 14-bit grid almost none. The y_step and u_step of the closed loop do round."""
    base = baseline_params()
    clean = _clean_record(base, n=6000)
    noise = NoiseModel(q_force=2.5e-4, f_force=8.0, r_sensor=5.7e-4)
    shares = {}
    for bits in (10, 14):
        q = 2.0 / 2**bits
        sim = fast_loop.closed_loop(get_params("baseline").replace(x_start=0.0032), clean.w, y_step=q, u_step=q)
        assert np.max(np.abs(sim["y"] / q - np.round(sim["y"] / q))) < 1e-9
        assert np.max(np.abs(sim["u"] / q - np.round(sim["u"] / q))) < 1e-9
        rec = Record("grid", clean.t, clean.w, sim["u"], sim["y"], 1e-3, 2.0, 2.97, 0.01, 0.0, 1.0)
        shares[bits] = own_share(rec, base, noise)
    assert shares[10] > 0.02 and shares[14] < 0.01, shares
    with pytest.raises(ValueError, match="y_step"):
        fast_loop.closed_loop(None, clean.w[:10], y_step=-1e-3)


def _noisy_record(f_sensor: float, n: int = 6000, seed: int = 3) -> Record:
    """A record of the C plant's own loop with a random force (2.5e-4 N RMS, 8 Hz), 12-bit
    converters and sensor noise of 1e-4 MU white plus 2e-4 MU either white (``f_sensor`` 0) or
    low-passed with a corner ``f_sensor`` [Hz], as the independent emulator makes it."""
    from scipy.signal import lfilter
    p = get_params("baseline")
    start, u_hold = settled_start(p, 0.0032)
    rng = np.random.default_rng(seed)
    w = np.full(n, fast_loop.closed_loop(start, np.zeros(1), pid=PID(), u_hold=u_hold)["y"][0])
    for k in range(n // 1000):
        w[k * 1000 + 500:(k + 1) * 1000] += 0.03
    a = math.exp(-2 * math.pi * 8.0 * 1e-3)
    dF = lfilter([math.sqrt(1 - a * a)], [1, -a], rng.standard_normal(n)) * 2.5e-4
    dy = rng.standard_normal(n) * 1e-4
    if f_sensor:
        b = math.exp(-2 * math.pi * f_sensor * 1e-3)
        dy += lfilter([math.sqrt(1 - b * b)], [1, -b], rng.standard_normal(n)) * 2e-4
    else:
        dy += rng.standard_normal(n) * 2e-4
    sim = fast_loop.closed_loop(start, w, pid=PID(), u_hold=u_hold, dF=dF, dy=dy, y_step=LSB, u_step=LSB)
    return Record("noisy", np.arange(n) * 1e-3, w, sim["u"], sim["y"], 1e-3, 2.0, 2.97, 0.01, 0.0, 1.0)


def test_coloured_sensor_noise_is_found_and_white_noise_stays_white():
    """The coloured sensor-noise state (issue 22): on a record whose sensor noise is low-passed at
    100 Hz the estimate finds the corner and the coloured RMS, passing the held-out criterion, and
    leaves white innovations; on the same record with white sensor noise the model stays white.
    The random force is the record's too (2.5e-4 N RMS with an 8 Hz corner), not the near-white force
    the white fit took for the coloured noise's share of the innovations, from where the five levels'
    search did not come back without its second start (replay._coloured_choice; before it: 0.96 mN
    at 531 Hz). Measured (6 s records): corner 104 Hz, coloured 1.91e-4 MU for 2e-4, white 1.74e-4 MU
    for 1.73e-4 (1e-4 and the 12-bit rounding), random force 0.27 mN at 13.6 Hz."""
    info: dict = {}
    rec = _noisy_record(100.0)
    nm = estimate_noise(rec, baseline_params(), info=info)
    assert info["coloured_accepted"], info
    assert 60.0 < nm.f_sensor < 160.0, nm
    assert nm.r_coloured == pytest.approx(2e-4, rel=0.25)
    assert nm.r_sensor == pytest.approx(math.sqrt(1e-4 ** 2 + LSB ** 2 / 12), rel=0.25)
    assert nm.q_force == pytest.approx(2.5e-4, rel=0.25) and nm.f_force < 30.0, nm
    assert nm.to_json()["f_sensor_Hz"] == nm.f_sensor
    white = NoiseModel(nm.q_force, nm.f_force, nm.sensor_rms)
    shares = [predictable_share(predict(rec, baseline_params(), m, horizon_s=0.0)["innov"], rec.u) for m in (white, nm)]
    assert shares[1] < 0.01 < shares[0], shares
    # held for another model (the calibrated baseline's estimate in the verdict): the coloured part stays
    held = estimate_noise(_noisy_record(100.0, n=2000), {**baseline_params(), "k_FV": 0.01}, sensor=nm)
    assert (held.f_sensor, held.r_coloured) == (nm.f_sensor, nm.r_coloured)

    info = {}
    nm = estimate_noise(_noisy_record(0.0), baseline_params(), info=info)
    assert not info["coloured_accepted"] and nm.f_sensor == 0.0 and nm.r_coloured == 0.0, (nm, info)
    assert nm.to_json()["f_sensor_Hz"] == 0.0


def test_a_nelder_mead_that_stalls_on_a_flat_ridge_is_restarted():
    """replay.minimize_restarted: on a long, curved, flat valley (as the disturbance likelihood along
    the random force's RMS and corner), scipy's Nelder-Mead with the estimate's tolerances stops
    where its simplex has shrunk; started again from there it goes on down the valley, within its
    budget (80 evaluations, then at most 40 a restart). At a minimum a restart that gains nothing
    ends the search."""
    def valley(z):
        return 25.0 * (z[1] - 0.3 * z[0] ** 2) ** 2 + 1e-3 * (z[0] - 3.0) ** 2

    opts = {"xatol": 0.05, "fatol": 1e-4, "maxfev": 80}
    for z0 in ([-2.0, 1.0], [-3.0, 2.7]):
        once = minimize(valley, z0, method="Nelder-Mead", options=opts)
        again = minimize_restarted(valley, np.array(z0), maxfev=80)
        assert again.fun < once.fun - 1e-3, (once.fun, again.fun)
        assert again.nfev <= 80 + NOISE_RESTARTS * RESTART_MAXFEV

    def bowl(z):
        return float(np.sum((np.asarray(z) - 1.0) ** 2))

    start = np.array([1.5, 0.5])
    at_min = minimize_restarted(bowl, start, maxfev=80)
    single = minimize(bowl, start, method="Nelder-Mead", options=opts)
    restart = minimize(bowl, single.x, method="Nelder-Mead", options={**opts, "maxfev": RESTART_MAXFEV})
    assert single.fun - restart.fun <= 1e-4               # nothing to gain: one restart, then stop
    assert at_min.nfev == single.nfev + restart.nfev
    assert at_min.fun == min(single.fun, restart.fun)
