"""The diagnosis's shortcuts give the numbers of the long way (issue 22, item 7): replays side by
side in threads, a fit's Jacobian columns on threads, a limit's scan evaluated a grid at a time,
and a candidate's fit to convergence from its screen's starts (the tests time nothing: the bench does)."""

from __future__ import annotations

import numpy as np
import pytest

from maglev_cosim.diagnosis import pipeline, problem
from maglev_cosim.diagnosis.effects import BASELINE, CATALOGUE, profile_scan
from maglev_cosim.diagnosis.problem import Problem, fit, thread_map
from maglev_cosim.diagnosis.replay import baseline_params, replay
from maglev_cosim.records.record import read_record
from maglev_cosim.records.synth import synth_record


@pytest.fixture(scope="module")
def prob(tmp_path_factory):
    path = synth_record(tmp_path_factory.mktemp("speed") / "d.csv", effects={"delay": {"T_d": 0.002}},
                        reference="steps", duration=3.0, seed=3)
    rec = read_record(path)
    return Problem(rec, baseline_params(), 1e-3, 1e-2, np.arange(rec.n) % 1000 < 500)


def test_thread_map_keeps_order():
    assert thread_map(lambda v: v * v, range(7)) == [v * v for v in range(7)]
    assert thread_map(str, []) == []


def test_profile_scan_by_batches_equals_one_by_one():
    """The grids evaluated a list at a time: the same points, costs and result as one by one."""
    cliff = lambda v: 1444.0 if v < 0.7605 else (v - 0.761) ** 2 * 1e3 + 0.2     # noqa: E731
    known = {v: cliff(v) for v in (0.58, 0.66, 0.75, 0.82, 0.93, 1.01)}
    one, batched, calls = [], [], []
    a = profile_scan(known, lambda v: one.append(v) or cliff(v), 1.3)
    b = profile_scan(known, lambda v: batched.append(v) or cliff(v), 1.3,
                     lambda vs: calls.append(len(vs)) or [cliff(v) for v in vs])
    assert a == b and len(calls) == 2 and max(calls) > 1 and len(batched) < len(one)


def test_threaded_jacobian_fit_equals_serial(prob, monkeypatch):
    """The fit with its Jacobian's columns on threads ends where the one-by-one fit ends, bit for bit."""
    eff = CATALOGUE["delay"]
    start = {**prob.base, "T_d": 1.5e-3}
    z0 = [BASELINE.to_coords(start), [1.5e-3]]
    threaded = fit(prob, [BASELINE, eff], z0, max_nfev=6)
    monkeypatch.setattr(problem, "THREADS", 1)
    serial = fit(prob, [BASELINE, eff], z0, max_nfev=6)
    assert threaded.values == serial.values and threaded.cost == serial.cost and threaded.nfev == serial.nfev


def test_fit_from_screen_starts_equals_fit_from_scratch(prob):
    """A candidate's fit to convergence from its screen's prepared starts is the fit from scratch."""
    current = {p: prob.base[p] for p in BASELINE.params}
    screen = pipeline.fit_candidate(prob, current, "force_lag", pipeline.SCREEN_NFEV)
    again = pipeline.fit_candidate(prob, current, "force_lag", 20, screen["prepared"])
    fresh = pipeline.fit_candidate(prob, current, "force_lag", 20)
    assert again["values"] == fresh["values"] and again["fit_cost"] == fresh["fit_cost"]


def test_converged_screen_is_the_fit_to_convergence(prob):
    """A candidate whose fits all ended by a tolerance within the screen's evaluations is the fit to
    convergence: the search takes it instead of fitting it again."""
    current = {p: prob.base[p] for p in BASELINE.params}
    screen = pipeline.fit_candidate(prob, current, "delay", 30)
    if not screen["converged"]:
        pytest.skip("the screen did not converge on this record")
    full = pipeline.fit_candidate(prob, current, "delay", pipeline.FULL_NFEV, screen["prepared"])
    assert full["converged"] and full["values"] == screen["values"] and full["nfev"] == screen["nfev"]


def test_fit_substep_policy():
    """The fits' RK4 substep: 1 ms, a sixth of a force lag, half an amplifier lag, never below
    0.25 ms nor below the plant's own ``solver_step``."""
    step = problem.fit_solver_step
    assert step({"solver_step": 1e-4, "T_F": 0.0, "T_a": 0.0}) == problem.FIT_SOLVER_STEP_MAX == 1e-3
    assert step({"solver_step": 1e-4, "T_F": 3e-3, "T_a": 0.0}) == pytest.approx(5e-4)
    assert step({"solver_step": 1e-4, "T_F": 0.0, "T_a": 1e-3}) == pytest.approx(5e-4)
    assert step({"solver_step": 1e-4, "T_F": 5e-4, "T_a": 3e-4}) == problem.FIT_SOLVER_STEP == 2.5e-4
    assert step({"solver_step": 2e-3}) == 2e-3
    assert problem.on_fit_steps({"solver_step": 1e-4, "T_F": 3e-3})["solver_step"] == pytest.approx(5e-4)


@pytest.mark.parametrize("effect", [{"force_lag": {"T_F": 5e-4}}, {"force_lag": {"T_F": 3e-3}},
                                    {"amplifier_lag": {"T_a": 3e-3}}, {"delay": {"T_d": 2.5e-3}},
                                    {"sensor_lag": {"T_y": 2e-3}}])
def test_fit_substeps_replay_the_plant_steps_loop(tmp_path, effect):
    """What the fits compare with the record moves by a few millionths of an MU against the plant's
    own 0.1 ms substeps (sensor noise ~2.5e-4 MU, u's noise response ~4e-3 MU), and the problem's
    replay runs on the policy's substep."""
    rec = read_record(synth_record(tmp_path / "r.csv", effects=effect, reference="steps", duration=3.0, seed=5))
    values = {**baseline_params(), **next(iter(effect.values()))}
    prob = Problem(rec, values, 1e-3, 1e-2, np.ones(rec.n, bool))
    fine = prob.free_run({})
    coarse = prob.simulate({})
    assert np.max(np.abs(coarse["y"] - fine["y"])) < 2e-6 and np.max(np.abs(coarse["u"] - fine["u"])) < 1e-5
    same = replay(rec, problem.on_fit_steps(values))
    assert np.array_equal(coarse["y"], same["y"]) and np.array_equal(coarse["u"], same["u"])


def test_streamed_search_is_the_one_worker_search(prob):
    """Screens judged as they end, with promising fits to convergence queued ahead of the waiting
    screens (two workers), give the table of the one-worker search, entry for entry."""
    current = {p: prob.base[p] for p in BASELINE.params}
    hold = ~prob.mask
    effects = ["amplifier_lag", "delay", "current_saturation", "periodic_disturbance"]
    two = pipeline.search(prob, dict(current), effects, hold, 2, lambda s: None)
    one = pipeline.search(prob, dict(current), effects, hold, 1, lambda s: None)
    assert two.selected == one.selected and two.values == one.values
    strip = lambda c: {k: v for k, v in c.items() if k != "cpu_s"}      # noqa: E731
    assert [strip(c) for c in two.candidates] == [strip(c) for c in one.candidates]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A 4 s record with a 2.5 ms delay, its calibrated problem and held-out blocks, as the search has them."""
    from maglev_cosim.diagnosis.acceptance import fit_blocks
    rec = read_record(synth_record(tmp_path_factory.mktemp("cal") / "d.csv", effects={"delay": {"T_d": 0.0025}},
                                   reference="square", period=0.6, duration=4.0, seed=5))
    fit_mask = fit_blocks(rec.t)
    cal = pipeline.calibrate(rec, baseline_params(), fit_mask, lambda s: None)
    return cal.prob, cal.values, ~fit_mask


@pytest.mark.parametrize("effect", ["delay", "current_saturation"])
def test_a_candidate_fitted_to_the_candidate_tolerance_is_judged_as_at_1e_6(calibrated, monkeypatch, effect):
    """A candidate's fits end at :data:`~maglev_cosim.diagnosis.pipeline.CANDIDATE_TOL` (1e-4): in no
    more evaluations than at the 1e-6 of the model's own fits, and judged alike: the held-out
    likelihood ratio within 1 % and the value within 2 % for the planted delay, accepted either
    way; a limit, which this record does not have, rejected either way."""
    from maglev_cosim.diagnosis.problem import cost_on
    prob, values, hold = calibrated
    current = {p: values[p] for p in BASELINE.params}
    hold_before, fit_before = cost_on(prob, current, hold), cost_on(prob, current, ~hold)
    got = {}
    for tol in (pipeline.CANDIDATE_TOL, 1e-6):
        monkeypatch.setattr(pipeline, "CANDIDATE_TOL", tol)
        res = pipeline.fit_candidate(prob, current, effect, pipeline.FULL_NFEV)
        entry, vals = pipeline.judge(prob, hold, hold_before, res, 1, fit_before)
        got[tol] = (res["nfev"], entry, vals)
    (n_a, e_a, v_a), (n_b, e_b, v_b) = got[1e-4], got[1e-6]
    assert n_a <= n_b
    assert e_a["accepted"] == e_b["accepted"] == (effect == "delay"), (e_a, e_b)
    if effect == "delay":
        assert abs(e_a["lr_statistic"] - e_b["lr_statistic"]) <= 0.01 * e_b["lr_statistic"]
        assert v_a["T_d"] == pytest.approx(v_b["T_d"], rel=0.02)
        assert v_a["T_d"] == pytest.approx(0.0025, rel=0.05)
    else:
        assert max(e_a["lr_statistic"], e_b["lr_statistic"]) < e_a["threshold"]


def test_an_idle_absorbed_effect_is_screened_from_one_base_and_fitted_to_convergence_from_both(calibrated):
    """A later round's screen of an absorbed effect found idle (``one_base``, pipeline.IDLE_ONE_BASE)
    scans and fits from the model as it stands only; a fit to convergence from that screen's starts
    places the other base's start itself and ends where the fit from scratch ends."""
    prob, values, _ = calibrated
    current = {p: values[p] for p in BASELINE.params}
    one = pipeline.fit_candidate(prob, current, "current_saturation", pipeline.SCREEN_NFEV, one_base=True)
    two = pipeline.fit_candidate(prob, current, "current_saturation", pipeline.SCREEN_NFEV)
    assert len(one["prepared"]["starts"]) == 1 and len(two["prepared"]["starts"]) == 2
    full = pipeline.fit_candidate(prob, current, "current_saturation", 20, one["prepared"])
    fresh = pipeline.fit_candidate(prob, current, "current_saturation", 20)
    assert full["values"] == fresh["values"] and full["fit_cost"] == fresh["fit_cost"]


def test_the_candidates_that_decide_are_fitted_again_to_1e_6(calibrated):
    """The search's round: the candidates whose fit at the candidates' tolerance reaches half their
    threshold (the delay and its twin the force lag, both far above it) are fitted again to 1e-6 from
    their screen's starts, and judged on the values the fit from scratch at 1e-6 finds; a friction
    that this record does not have is judged at 1e-4 alone."""
    prob, values, hold = calibrated
    found = pipeline.search(prob, dict(values), ["delay", "force_lag", "coulomb_friction"], hold, 1, lambda s: None)
    first = {c["effect"]: c for c in found.candidates if c["round"] == 1}
    assert found.selected[0] in ("delay", "force_lag")
    for e in ("delay", "force_lag"):
        assert first[e]["refined"]["tol"] == pipeline.REFINE_TOL == 1e-6
        fresh = pipeline.fit_candidate(prob, {p: values[p] for p in BASELINE.params}, e, pipeline.FULL_NFEV,
                                       tol=1e-6)
        assert first[e]["parameters"] == {p: fresh["values"][p] for p in CATALOGUE[e].params}
    assert "refined" not in first["coulomb_friction"] and not first["coulomb_friction"]["accepted"]


def test_within_reach_rule():
    """A candidate rejected at the candidates' tolerance is refitted to 1e-6 only where that could
    change the round's choice (pipeline.REFINE_REACH): within twice the best accepted one's held-out
    cost, or at least half its held-out gain; an accepted one always, and every one when none is."""
    best = {"accepted": True, "held_out_cost_after": 0.07, "held_out_gain": 0.93}
    far = {"accepted": False, "held_out_cost_after": 0.96, "held_out_gain": 0.04}
    assert pipeline.REFINE_REACH == 2.0
    assert not pipeline.within_reach(far, best)
    assert pipeline.within_reach(far, None)
    assert pipeline.within_reach({**far, "accepted": True}, best)
    assert pipeline.within_reach({**far, "held_out_cost_after": 0.13}, best)          # 0.13 <= 2 x 0.07
    assert pipeline.within_reach({**far, "held_out_cost_after": 0.5, "held_out_gain": 0.5}, best)  # 0.5 >= 0.93/2
    assert not pipeline.within_reach({**far, "held_out_cost_after": 0.55, "held_out_gain": 0.45}, best)


@pytest.mark.slow   # the quick tier's 2-minute budget: two searches of a 4 s record, 2-3 s
def test_a_candidate_out_of_reach_is_not_refitted(calibrated, monkeypatch):
    """Every candidate fitted to convergence counts as near its threshold (SCREEN_SHARE far below 0):
    the friction this record lacks, rejected far behind the delay, is not refitted to 1e-6 and says
    so; with an unbounded reach it is, and rejected again. The delay, the selection and the model the
    round ends with are the same either way."""
    prob, values, hold = calibrated
    monkeypatch.setattr(pipeline, "SCREEN_SHARE", -1e9)

    def first_round():
        found = pipeline.search(prob, dict(values), ["delay", "coulomb_friction"], hold, 1, lambda s: None)
        return found, {c["effect"]: c for c in found.candidates if c["round"] == 1}

    found, first = first_round()
    skipped = first["coulomb_friction"]["refined"]
    assert skipped["tol"] is None and "out of reach" in skipped["skipped"] and not first["coulomb_friction"]["accepted"]
    assert first["delay"]["refined"]["tol"] == pipeline.REFINE_TOL and first["delay"]["accepted"]
    assert not pipeline.within_reach(first["coulomb_friction"], first["delay"])
    monkeypatch.setattr(pipeline, "REFINE_REACH", 1e9)
    found2, first2 = first_round()
    assert first2["coulomb_friction"]["refined"]["tol"] == pipeline.REFINE_TOL
    assert not first2["coulomb_friction"]["accepted"]
    assert found2.selected == found.selected and found2.values == found.values
    assert first2["delay"] == first["delay"]
