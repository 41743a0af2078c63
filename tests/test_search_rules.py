"""The search's rules for a second effect and for a choice between rivals (issue 22, item 4, and the
force lag taken for its twin, the delay): a further effect is accepted only against the model of the
effects already selected refitted in full, and a rival the held-out blocks do not tell from the chosen
effect is listed beside it. Short records of the rig emulator, so the quick tier stays quick."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from maglev_cosim.diagnosis import pipeline, problem
from maglev_cosim.diagnosis.acceptance import fit_blocks
from maglev_cosim.diagnosis.effects import BASELINE, CATALOGUE
from maglev_cosim.diagnosis.problem import cost_on, fit
from maglev_cosim.diagnosis.replay import baseline_params
from maglev_cosim.plant.params import as_params
from maglev_cosim.records.record import read_record
from maglev_cosim.records.synth import synth_record

I_MAX = 0.66      # a limit that bites after each step up of a 0.6 s square (the matrix's row: 10 % of the samples)


def _limited(tmp_path, effects=None, i_max=I_MAX):
    """A 4 s record with the current limit (and ``effects``), its calibrated problem and the model
    with the limit fitted in full: what the search holds after its first round."""
    planted = {"current_saturation": {"i_max": i_max}, **(effects or {})}
    rec = read_record(synth_record(tmp_path / "rec.csv", seed=5, effects=planted, reference="square", period=0.6,
                                   duration=4.0), plausibility="warn")
    fit_mask = fit_blocks(rec.t)
    cal = pipeline.calibrate(rec, baseline_params(), fit_mask, lambda s: None)
    prob = cal.prob
    parts = [BASELINE, CATALOGUE["current_saturation"]]
    start = {**cal.values, "i_max": i_max * 1.05}
    first = fit(prob.with_base(start), parts, [p.to_coords(start) for p in parts], max_nfev=60)
    return rec, prob, ~fit_mask, {**start, **first.values}


@pytest.fixture(scope="module")
def limited(tmp_path_factory):
    """:func:`_limited` with the limit alone, shared by the tests that only read it."""
    return _limited(tmp_path_factory.mktemp("limited"))


def test_a_second_effect_that_only_patches_an_underfitted_first_one_is_rejected(limited, monkeypatch):
    """The first effect held where it under-fits (i_max 8 % high): a candidate whose fit also moved
    the limit to its right value, with a friction of 0.01 % of the weight, beats the model as it
    stood by far. It gains nothing against its own fit with the friction off (judge's own-off test),
    nor, without that test, against the model refitted in full from the candidate's values."""
    rec, prob, hold, first = limited
    assert not rec.warnings, rec.warnings
    assert abs(first["i_max"] / I_MAX - 1) < 0.03, first["i_max"]
    stood = {**first, "i_max": 1.08 * first["i_max"]}
    hold_before = cost_on(prob, stood, hold)
    patch = {**first, "F_c": 1e-4, "v_c": 1e-4}   # friction ~0: the gain is the limit's
    entry, vals = pipeline.judge(prob, hold, hold_before, {"effect": "coulomb_friction", "values": patch}, 2)
    assert not entry["accepted"] and entry["own_off_rejected"], entry
    assert entry["lr_statistic"] > entry["threshold"] > entry["own_off_lr_statistic"], entry
    monkeypatch.setattr(pipeline, "OWN_OFF_TEST", False)
    entry, vals = pipeline.judge(prob, hold, hold_before, {"effect": "coulomb_friction", "values": patch}, 2)
    assert entry["accepted"], entry                              # as it stood, the patch passes the test
    new, _, null = pipeline.against_refitted(prob, hold, hold_before, ["current_saturation"], entry, vals, 2)
    assert not new["accepted"], new
    assert new["held_out_cost_refitted"] < 0.5 * hold_before, new
    assert abs(null.values["i_max"] / I_MAX - 1) < 0.03, null.values["i_max"]


def test_a_true_second_effect_survives_the_refitted_first_one(tmp_path):
    """A limit of 0.72 A with a 2.5 ms delay (the limit active in 6 % of the samples): the delay fitted
    with the limit present is still accepted against the limit's model refitted in full."""
    rec, prob, hold, first = _limited(tmp_path, {"delay": {"T_d": 0.0025}}, i_max=0.72)
    assert not rec.warnings, rec.warnings            # the loop in control: the limit bites at the steps
    hold_before = cost_on(prob, first, hold)
    res = pipeline.fit_candidate(prob, first, "delay")
    entry, vals = pipeline.judge(prob, hold, hold_before, res, 2)
    assert entry["accepted"], entry
    new, vals, _ = pipeline.against_refitted(prob, hold, hold_before, ["current_saturation"], entry, vals, 2)
    assert new["accepted"], new
    assert abs(vals["T_d"] / 0.0025 - 1) < 0.15, vals["T_d"]


def test_two_rivals_a_fraction_of_a_per_cent_apart_are_indistinguishable():
    """The force lag of seed 2001 against its twin, the delay: held-out costs 0.2 % apart on some
    hundred effective samples cannot be told apart; 12 % apart (a delay against an amplifier lag on
    the same record) can, as can costs four times apart on thirty samples (a limit against friction)."""
    def cand(j, n_eff):
        return {"held_out_cost_after": j, "n_eff": n_eff}

    assert not pipeline.distinct(cand(0.498, 300.0), cand(0.499, 300.0))["distinct"]
    assert pipeline.distinct(cand(0.498, 300.0), cand(0.557, 300.0))["distinct"]
    assert pipeline.distinct(cand(0.0129, 27.0), cand(0.0507, 27.0))["distinct"]
    t = pipeline.distinct(cand(0.5, 100.0), cand(0.5 * np.exp(10.0 / 100.0), 100.0))     # LR 10 < 10.83
    assert not t["distinct"] and t["threshold"] == pytest.approx(10.83, abs=0.01), t


def test_the_diagnosis_lists_an_indistinguishable_rival_beside_the_chosen_effect():
    """Diagnosis.alternatives and its warning, from a round's candidates: the chosen effect's accepted
    rivals that :func:`pipeline.distinct` does not tell from it, and no others."""
    chosen = {"effect": "delay", "round": 1, "selected": True, "accepted": True, "held_out_cost_after": 0.498,
              "n_eff": 300.0}
    twin = {"effect": "force_lag", "round": 1, "accepted": True, "held_out_cost_after": 0.499, "n_eff": 300.0}
    other = {"effect": "amplifier_lag", "round": 1, "accepted": True, "held_out_cost_after": 0.557, "n_eff": 300.0}
    for r in (twin, other):
        r["against_chosen"] = pipeline.distinct(chosen, r)
    d = pipeline.Diagnosis("r.csv", {}, {}, ["delay"], {}, {}, [chosen, twin, other], {}, {}, {}, {}, [], 0.0)
    assert [a["effect"] for a in d.alternatives["delay"]] == ["force_lag"]
    assert any(w.startswith("delay or force_lag: indistinguishable on this record") for w in d.warnings), d.warnings


def test_the_prediction_mode_refit_ends_on_the_criterion_the_verdict_judges():
    """Issue 22's 'explained' beyond the true model's error: the 3 ms amplifier lag of seed 2001 (the
    loop at its limits a third of the time), refitted in prediction mode from the values the benchmark's
    diagnosis ended with (T_a 2.94 ms, u_0 9 mV). The refit ends on the 20 ms prediction through the
    disturbances estimated for its own values, the criterion of the verdict, so a further fit by that
    criterion gains under 1 %; ending on the one-step polish (PEM) left 7.9 % to gain on this record."""
    from dataclasses import replace

    from maglev_cosim.diagnosis.replay import estimate_noise
    from maglev_cosim.records.synth import draw_disturbance

    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        rec = read_record(synth_record(Path(tmp) / "rec.csv", seed=2001, disturbance=draw_disturbance(2001),
                                       effects={"amplifier_lag": {"T_a": 0.003}}, duration=6.0), plausibility="warn")
    base = baseline_params()
    start = {"k_c": 7.0118e-06, "x_0": 0.0083704, "k_FV": 0.028255, "u_0": 0.0092517, "T_a": 0.0029427}
    fit_mask = fit_blocks(rec.t)
    prob = pipeline._weighted(pipeline.Problem(rec, base, 1.0, 1.0, fit_mask,
                                               noise=estimate_noise(rec, {**base, **start})), start)
    vals, _, _ = pipeline._refit(prob, start, ["amplifier_lag"], lambda s: None)
    parts = [BASELINE, CATALOGUE["amplifier_lag"]]
    whole = prob.with_base(vals).with_mask(np.ones(rec.n, bool))
    kstep = pipeline._weighted(replace(whole, noise=estimate_noise(rec, {**base, **vals})), vals)
    cost = float(np.mean(pipeline.residuals(kstep, vals) ** 2))
    further = fit(kstep, parts, [p.to_coords(vals) for p in parts], max_nfev=40)
    assert 1 - further.cost / cost < 0.01, (cost, further.cost, vals)


def test_a_held_out_gain_without_a_gain_on_the_fit_blocks_is_not_accepted(limited, monkeypatch):
    """Issue 22's spurious second effect beside a long-active limit: the held-out free run of such a
    record turns on when the model loses the ball (one 0.8 s block made the 22 % a 78 us delay gained
    on seed 2501, which gained 0.06 % on the blocks it was fitted on). Here the limit's model as the
    candidate (a delay of 10 us) against a held-out cost before set twice as high: it passes the
    held-out test, and fails the same test on the fit blocks, where it gains nothing. (The own-off
    test, which would reject this made-up candidate first, is off here: the rule under test is the
    fit blocks'.)"""
    monkeypatch.setattr(pipeline, "OWN_OFF_TEST", False)
    rec, prob, hold, first = limited
    cand = {**first, "T_d": 5e-5}
    hold_before = 2.0 * cost_on(prob, first, hold)
    res = {"effect": "delay", "values": cand}
    alone, _ = pipeline.judge(prob, hold, hold_before, res, 2)
    assert alone["accepted"] and "fit_lr_statistic" not in alone, alone
    entry, _ = pipeline.judge(prob, hold, hold_before, res, 2, fit_before=cost_on(prob, first, ~hold))
    assert not entry["accepted"] and entry["fit_side_rejected"], entry
    assert entry["fit_lr_statistic"] < entry["fit_threshold"] < entry["threshold"] < entry["lr_statistic"], entry
    # the fit blocks' level is the plainer FIT_SIDE_ALPHA (1 % for one parameter: 6.63)
    assert entry["fit_threshold"] == pytest.approx(6.635, abs=0.01)
    # a fit-block cost before that the candidate does improve on passes
    entry, _ = pipeline.judge(prob, hold, hold_before, res, 2, fit_before=2.0 * cost_on(prob, first, ~hold))
    assert entry["accepted"] and entry["fit_lr_statistic"] > entry["fit_threshold"], entry


def test_the_innovations_test_reads_the_held_out_samples_and_their_dependence():
    """:func:`pipeline.innovations_test`: the sum over the held-out samples (after the filter's first
    200) of the difference of ``log s + e²/s``, positive when the first model is the likelier, scaled
    by the effective share of samples of the normalised innovations, against chi-square(dof)."""
    rng = np.random.default_rng(1)
    n = 4000
    hold = (np.arange(n) // 800) % 2 == 1
    z = rng.standard_normal(n)
    l_c = np.log(1.0) + z ** 2
    l_r = l_c + 0.01                         # the rival 0.01 less likely per sample
    t = pipeline.innovations_test((l_c, z), (l_r, z), hold, 1)
    assert t["samples"] == int(hold[200:].sum())
    assert t["lr_statistic"] == pytest.approx(0.01 * t["samples"] * t["effective_share"])
    assert t["effective_share"] > 0.8 and t["distinct"]
    assert pipeline.innovations_test((l_r, z), (l_c, z), hold, 1)["lr_statistic"] < 0
    # innovations that follow each other (a model that lacks something) count as fewer samples
    slow = np.convolve(z, np.ones(20) / np.sqrt(20), mode="same")
    t2 = pipeline.innovations_test((l_c, slow), (l_r, slow), hold, 1)
    assert t2["effective_share"] < 0.2 and t2["lr_statistic"] < t["lr_statistic"] / 5
    # two parameters: a larger threshold
    assert pipeline.innovations_test((l_c, z), (l_r, z), hold, 2)["threshold"] == pytest.approx(13.82, abs=0.01)


def test_a_screen_goes_to_convergence_by_its_ratio_or_its_gain():
    """pipeline.to_convergence: seed 3200's force exponent, screened short of convergence at a gain
    of 14.9 % but a ratio of 3.4 for 13.8 (21 effective samples), is fitted to convergence; the same
    screen converged, or one below the 3 % minimum gain, is not; half the threshold suffices alone."""
    exponent = {"lr_statistic": 3.4, "threshold": 13.8, "held_out_gain": 0.149}
    assert pipeline.to_convergence(exponent, converged=False)
    assert not pipeline.to_convergence(exponent, converged=True)
    small = {**exponent, "held_out_gain": 0.002}
    assert not pipeline.to_convergence(small, converged=False)
    assert pipeline.to_convergence({**small, "lr_statistic": 7.0}, converged=True)


def test_an_absorbable_effect_is_fitted_again_only_where_it_was_at_work():
    """pipeline.at_work: an effect the baseline can absorb is fitted to convergence again in a later
    round only where its latest fit to convergence found it on and lowering the held-out cost by a
    quarter of the 3 % minimum gain; a limit that never bites (i_max on its 1.5 A start), a force
    exponent left at 2, or one on that lowers nothing, are screened instead."""
    gain = pipeline.AT_WORK_SHARE * pipeline.MIN_GAIN
    assert pipeline.at_work("current_saturation", {"held_out_gain": 0.2}, {"i_max": 0.74})
    assert not pipeline.at_work("current_saturation", {"held_out_gain": 0.2}, {"i_max": 1.5})
    assert not pipeline.at_work("force_exponent", {"held_out_gain": 0.05}, {"n_F": 2.004})
    assert not pipeline.at_work("force_exponent", {"held_out_gain": 0.9 * gain}, {"n_F": 2.3})
    assert pipeline.at_work("force_exponent", {"held_out_gain": gain}, {"n_F": 2.3})


def test_the_innovations_credit_the_effect_not_the_candidates_other_calibration(limited):
    """pipeline.by_innovations_alone: a candidate is tested against the calibrated model without it
    and against its own fit with the effect turned off, whichever is the stricter. A friction of
    0.02 % of the weight on a well-calibrated baseline, beside a calibrated model whose D/A offset is
    5 % of the range off, is likelier than that model only through its calibration: rejected. The
    limit, an effect the baseline can absorb, is not tried, though it would pass against that model
    (the force exponents of the no-effect records of seeds 4501 and 4607 passed so)."""
    rec, prob, hold, first = limited
    current = {**first, "i_max": prob.base["i_max"], "u_0": first["u_0"] + 0.05}
    entries = {}
    for e, vals in (("coulomb_friction", {**first, "i_max": prob.base["i_max"], "F_c": 2e-5, "v_c": 1e-3}),
                    ("current_saturation", first)):
        entries[e] = ({"effect": e, "stage": "fit", "accepted": False, "held_out_gain": 0.01}, vals)
    assert not CATALOGUE["coulomb_friction"].is_off(entries["coulomb_friction"][1])
    pipeline.by_innovations_alone(prob, hold, current, entries, lambda s: None)
    friction, limit = entries["coulomb_friction"][0], entries["current_saturation"][0]
    assert not friction["accepted"] and abs(friction["innovations"]["lr_statistic"]) < 2.0, friction
    assert not limit["accepted"] and "innovations" not in limit, limit
    would = pipeline.innovations_test(pipeline.innovation_terms(prob, first), pipeline.innovation_terms(prob, current),
                                      hold, 1, pipeline.ALPHA)
    assert would["lr_statistic"] > would["threshold"], would
    # against the mis-calibrated model alone the friction would have passed: what the old test did
    off_base = pipeline.innovation_terms(prob, current)
    old = pipeline.innovations_test(pipeline.innovation_terms(prob, entries["coulomb_friction"][1]), off_base, hold, 2,
                                    pipeline.ALPHA)
    assert old["lr_statistic"] > old["threshold"], old


def test_a_free_run_fit_on_the_ridge_of_an_absorbed_effect_is_mended_by_the_k_step_fit(limited):
    """pipeline._kstep_ridge: the limit's model moved along its ridge (i_max 6 % low, k_c raised so
    that k_c*i_max^2 stays) is refitted on the k-step prediction, which brings i_max back within 2 %;
    from the converged model the k-step fit moves i_max by under 1 %."""
    rec, prob, hold, first = limited
    whole = prob.with_base(first).with_mask(np.ones(rec.n, bool))
    parts = [BASELINE, CATALOGUE["current_saturation"]]
    kept = pipeline._kstep_ridge(whole, parts, first, lambda s: None)
    assert abs(kept["i_max"] / first["i_max"] - 1) < 0.01, (kept["i_max"], first["i_max"])
    ridge = {**first, "i_max": 0.94 * first["i_max"], "k_c": first["k_c"] / 0.94 ** 2}
    said = []
    mended = pipeline._kstep_ridge(whole, parts, ridge, said.append)
    assert "taken" in said[-1], said
    assert abs(mended["i_max"] / I_MAX - 1) < 0.02, mended["i_max"]


def test_the_k_step_fit_is_kept_only_where_it_predicts_better_through_its_own_disturbance_estimate(limited, monkeypatch):
    """pipeline._kstep_ridge compares the models as the verdict does, each through the disturbances
    estimated for it: the free run's values through theirs against the k-step fit's through
    theirs. Where the estimate made for the k-step fit's values takes a slow random force (0.3 Hz,
    as the one-step likelihood did on the benchmark's seed 4802, whose final model then predicted
    20 ms ahead at 1.63 times the true model's error) under which its prediction is worse than the
    free run's, the free run's values stay, though the k-step fit lowered the cost through the free
    run's estimate."""
    rec, prob, hold, first = limited
    whole = prob.with_base(first).with_mask(np.ones(rec.n, bool))
    parts = [BASELINE, CATALOGUE["current_saturation"]]
    real = problem.estimate_noise

    def slow_for_the_fit(r, values, **kw):
        nz = real(r, values, **kw)
        return nz if values["i_max"] == first["i_max"] else dataclasses.replace(nz, f_force=0.3, q_force=3 * nz.q_force)

    monkeypatch.setattr(problem, "estimate_noise", slow_for_the_fit)
    said = []
    kept = pipeline._kstep_ridge(whole, parts, first, said.append)
    assert "kept the free-run fit (worse through its own disturbance estimate)" in said[-1], said
    assert float(said[-1].split("cost ")[1].split(" %")[0]) < 0, said      # the fit itself gained
    assert kept == first


def test_the_k_step_fit_estimates_the_disturbances_of_the_whole_model(limited, monkeypatch):
    """The values a fit holds are its fitted parameters alone; the disturbances are estimated for
    them over the problem's base (the baseline's T_a = 0), not over the C table's defaults (a
    0.3 ms amplifier lag the model does not have: on seed 5000's force exponent that model's
    estimate put the final model at 1.84 times the true model's 20 ms error, against 0.99)."""
    rec, prob, hold, first = limited
    assert "T_a" not in first and prob.base["T_a"] == 0.0
    whole = prob.with_base(first).with_mask(np.ones(rec.n, bool))
    seen = []
    real = problem.estimate_noise

    def spy(r, values, **kw):
        seen.append(as_params(values).T_a)
        return real(r, values, **kw)

    monkeypatch.setattr(problem, "estimate_noise", spy)
    pipeline._kstep_ridge(whole, [BASELINE, CATALOGUE["current_saturation"]], first, lambda s: None)
    assert seen and all(t == 0.0 for t in seen), seen


def test_a_free_run_fit_is_fitted_again_on_the_k_step_prediction_only_where_that_promises_much(limited):
    """pipeline._kstep_screened: the model the free run fitted right promises a fall of the k-step cost
    far below KSTEP_SCREEN_GAIN and stays as it is (no refit); the same model with its damping three
    times too large and its D/A offset 0.05 V off promises more, is fitted again on the k-step
    prediction and taken, which brings both back near the record's plant."""
    rec, prob, hold, first = limited
    whole = prob.with_base(first).with_mask(np.ones(rec.n, bool))
    parts = [BASELINE, CATALOGUE["current_saturation"]]
    said = []
    assert pipeline._kstep_screened(whole, parts, first, said.append) == first
    promised = float(said[-1].split("promises ")[1].split(" %")[0])
    assert promised < 100 * pipeline.KSTEP_SCREEN_GAIN / 4 and "stays" in said[-1], said
    biased = {**first, "k_FV": 3 * first["k_FV"], "u_0": first["u_0"] + 0.05}
    said = []
    mended = pipeline._kstep_screened(whole, parts, biased, said.append)
    assert "settled on biased parameters" in said[0] and "taken" in said[-1], said
    truth = baseline_params()     # the record's plant: no D/A offset, the paper's damping
    assert abs(mended["u_0"] - truth["u_0"]) < 0.02 and abs(mended["k_FV"] / truth["k_FV"] - 1) < 0.5, mended


def test_distance_from_off_in_standard_errors():
    """Each effect's distance from switching it off, in its standard errors: a bend from 0, a limit
    from the 1.5 A the D/A range implies, a lag from 0; None without a usable σ."""
    assert CATALOGUE["sensor_nonlinearity"].distance_from_off({"k_x2": -851.0}, {"k_x2": 1915.0}) == pytest.approx(0.444, abs=1e-3)
    assert CATALOGUE["current_saturation"].distance_from_off({"i_max": 0.754}, {"i_max": 0.003}) == pytest.approx(248.667, abs=1e-3)
    assert CATALOGUE["delay"].distance_from_off({"T_d": 3e-4}, {"T_d": 1e-4}) == pytest.approx(3.0)
    assert CATALOGUE["force_exponent"].distance_from_off({"n_F": 2.1}, {"n_F": 0.2}) == pytest.approx(0.5)
    assert CATALOGUE["delay"].distance_from_off({"T_d": 3e-4}, {"T_d": float("nan")}) is None
    assert CATALOGUE["delay"].distance_from_off({"T_d": 3e-4}, {}) is None
    assert all(e.off_values for e in CATALOGUE.values())


def _acting(values: dict) -> dict:
    """A fake free run on which every parameter acts: its y holds the values."""
    return {"y": np.array([float(v) for _, v in sorted(values.items())])}


def test_an_effect_that_no_longer_acts_leaves_the_final_model(monkeypatch):
    """The k-step refit moved a current limit above every current the model's free run reaches (the
    independent emulator's 2 ms force lag of seed 7200 with the PID's derivative of the reading: i_max
    0.870 A accepted on held-out blocks, 0.909 A after the refit, sigma 0): the free run without it is
    the same, and it leaves; a limit that bites stays."""
    calls = []

    def fake_refit(prob, current, selected, say):
        calls.append(list(selected))
        i_max = 0.909 if "current_saturation" in selected else current["i_max"]
        return {"T_F": 2.3e-3, "i_max": i_max}, {"T_F": 2e-5, "i_max": 0.0}, None

    monkeypatch.setattr(pipeline, "_refit", fake_refit)
    peak = 0.88
    prob = SimpleNamespace(base={"T_F": 5e-5, "i_max": 1.5},
                           free_run=lambda v: {"y": np.array([v["T_F"], min(peak, v["i_max"])])})
    said: list[str] = []
    selected = ["force_lag", "current_saturation"]
    values, _ = pipeline.refit(prob, {"T_F": 2e-3, "i_max": 0.87}, selected, said.append)
    assert selected == ["force_lag"] and values["i_max"] == 1.5 and calls[-1] == ["force_lag"]
    assert any("current_saturation without action" in m for m in said), said
    calls.clear()
    peak = 0.95                    # the model's current now reaches 0.909 A: the limit acts and stays
    selected = ["force_lag", "current_saturation"]
    pipeline.refit(prob, {"T_F": 2e-3, "i_max": 0.87}, selected, lambda s: None)
    assert selected == ["force_lag", "current_saturation"] and calls == [["force_lag", "current_saturation"]]


def test_a_faint_effect_leaves_the_final_model(monkeypatch):
    """The final refit drops an effect whose parameter lies within 3σ of off (the record does not
    tell it from its absence), the first one too (the force exponent 1.3σ from 2 that the
    innovations' test took on the drifting no-effect record of seed 4501), and refits without it;
    an effect beyond 3σ stays (a delay 2.7σ from 0 leaves since seed 4701 of benchmark seeds 4700)."""
    calls = []
    sigma = {"i_max": 0.003, "k_x2": 1915.0, "T_d": 5e-5}

    def fake_refit(prob, current, selected, say):
        calls.append(list(selected))
        values = {"i_max": current.get("i_max", 0.754), "k_x2": current.get("k_x2", -851.0), "T_d": 3e-4}
        return values, dict(sigma), None    # no k-step values apart from the free run's

    class Prob:
        base = {"k_x2": 0.0, "i_max": 1.5, "T_d": 0.0}
        free_run = staticmethod(_acting)

    monkeypatch.setattr(pipeline, "_refit", fake_refit)
    selected = ["current_saturation", "sensor_nonlinearity"]
    values, _ = pipeline.refit(Prob(), {"k_x2": -851.0}, selected, lambda s: None)
    assert selected == ["current_saturation"]            # the bend, 0.44σ from off, left; the limit, 249σ, stays
    assert calls == [["current_saturation", "sensor_nonlinearity"], ["current_saturation"]]
    assert values["k_x2"] == 0.0                          # refitted with the bend off
    calls.clear()
    said = []
    sigma["i_max"] = 0.5                                  # the limit now 1.5σ from off: it leaves, first or not
    selected = ["current_saturation", "delay"]            # the delay, 6σ, stays
    values, _ = pipeline.refit(Prob(), {}, selected, said.append)
    assert selected == ["delay"] and calls == [["current_saturation", "delay"], ["delay"]], (selected, calls)
    assert values["i_max"] == 1.5 and "current_saturation within 1.5σ of off" in said[0], (values, said)
    calls.clear()
    calls.clear()
    sigma["i_max"], sigma["T_d"] = 0.003, 3e-4 / 2.7      # a delay 2.7σ from 0 leaves beside a limit
    selected = ["current_saturation", "delay"]
    pipeline.refit(Prob(), {}, selected, lambda s: None)
    assert selected == ["current_saturation"], selected
    calls.clear()
    selected = ["sensor_nonlinearity"]                    # a lone faint effect leaves the baseline
    pipeline.refit(Prob(), {"k_x2": -851.0}, selected, lambda s: None)
    assert selected == [] and calls == [["sensor_nonlinearity"], []]

    # two that trade against each other (a lag and its twin): each stands within 3σ of off beside the
    # other; the faintest leaves first, and the other, refitted alone, stands far from off and stays
    def twin_refit(prob, current, selected, say):
        calls.append(list(selected))
        values = {"T_a": current.get("T_a", 2.4e-3), "T_F": current.get("T_F", 2.6e-3)}
        both = {"amplifier_lag", "force_lag"} <= set(selected)
        return values, ({"T_a": 1e-3, "T_F": 9.6e-4} if both else {"T_a": 1e-4, "T_F": 1e-4}), None

    monkeypatch.setattr(pipeline, "_refit", twin_refit)
    calls.clear()
    said.clear()
    selected = ["amplifier_lag", "force_lag"]
    values, _ = pipeline.refit(SimpleNamespace(base={"T_a": 0.0, "T_F": 5e-5}, free_run=_acting), {"T_a": 2.4e-3, "T_F": 2.6e-3},
                               selected, said.append)
    assert selected == ["force_lag"] and calls == [["amplifier_lag", "force_lag"], ["force_lag"]], (selected, calls)
    assert values["T_a"] == 0.0 and values["T_F"] == 2.6e-3
    assert "amplifier_lag within 2.4σ" in said[0] and "force_lag within 2.7σ" in said[0], said


def test_the_test_on_likelihoods_takes_their_difference_and_survives_huge_ones():
    # a filter that the record's model fits badly: mean NLLs of hundreds, whose exp overflows (seed
    # 5400 of the project emulator's current limits ended in a math domain error)
    from maglev_cosim.diagnosis.acceptance import accept, accept_nll

    ok, figs = accept_nll(812.0, 905.0, 3000, 2)
    assert not ok and figs["lr_statistic"] < 0 and figs["held_out_gain"] < 0
    ok, figs = accept_nll(905.0, 812.0, 3000, 2)
    assert ok and figs["lr_statistic"] == pytest.approx(3000 * 93.0)
    # where exp does not overflow, the same decision and figures as accept on the costs exp(NLL)
    for before, after in ((-7.31, -7.36), (-7.31, -7.3102), (2.0, 1.0)):
        ok_n, f_n = accept_nll(before, after, 5000, 2)
        ok_c, f_c = accept(np.exp(before), np.exp(after), 5000, 2)
        assert ok_n == ok_c
        assert f_n["lr_statistic"] == pytest.approx(f_c["lr_statistic"], rel=1e-9)
        assert f_n["held_out_gain"] == pytest.approx(f_c["held_out_gain"], rel=1e-9, abs=1e-12)
    assert not accept_nll(float("inf"), 1.0, 100, 2)[0] and not accept_nll(1.0, float("nan"), 100, 2)[0]
    # costs: an infinite or undefined cost after is a rejection
    assert not accept(1.0, float("inf"), 100, 2)[0] and not accept(1.0, float("nan"), 100, 2)[0]


def test_an_effect_the_k_step_fit_takes_off_leaves_only_where_the_free_run_does_without_it(monkeypatch):
    """The k-step fit that ends a free-run refit took the delay to off; the free run's own fit has it at
    2.5 ms, 25σ from off. The model refitted without it is kept where its free run still follows the
    record (:data:`~.pipeline.FREE_RUN_MIN_FIT`): the independent emulator's 3 ms amplifier lag of seed
    5700, whose slow force drift the free run had taken for a sensor bend and a current limit (free run
    97.5 % without them). Where the free run without it loses the record, the free run's values stay:
    the project emulator's current limit of seed 5401, accepted at LR 1227, left within 0.3σ of off by
    the k-step fit (free run -10.8 % without it)."""
    calls = []

    def fake_refit(prob, current, selected, say):
        calls.append(list(selected))
        if selected:   # the k-step fit took the delay off, the free run's fit had it at 2.5 ms
            return {"T_d": 1e-6}, {"T_d": 1e-4}, {"T_d": 2.5e-3}
        return {"T_d": 0.0}, {}, None

    monkeypatch.setattr(pipeline, "_refit", fake_refit)
    monkeypatch.setattr(pipeline, "_uncertainties", lambda prob, current, selected, values: {"T_d": 1e-4})
    y = np.sin(np.linspace(0.0, 20.0, 500))
    without = {"y": -y}                          # the free run without the delay: lost
    prob = SimpleNamespace(base={"T_d": 0.0}, noise=None, rec=SimpleNamespace(y=y),
                           free_run=lambda v: {"y": y} if v["T_d"] > 0 else without)

    def run() -> tuple[dict, list[str]]:
        calls.clear()
        selected = ["delay"]
        values, _ = pipeline.refit(prob, {"T_d": 2e-3}, selected, lambda s: None)
        return values, selected

    values, selected = run()
    assert values == {"T_d": 2.5e-3} and selected == ["delay"] and calls == [["delay"], []]
    without["y"] = y + 0.01 * np.cos(np.linspace(0.0, 20.0, 500))      # follows the record: it goes
    values, selected = run()
    assert values == {"T_d": 0.0} and selected == [] and calls == [["delay"], []]
    monkeypatch.setattr(pipeline, "KSTEP_OFF_LEAVES", False)             # the rule before stop 41: it stays
    values, selected = run()
    assert values == {"T_d": 2.5e-3} and selected == ["delay"] and calls == [["delay"]]

    # where the free run's fit leaves it within noise of off too, it goes as before
    monkeypatch.setattr(pipeline, "_uncertainties", lambda prob, current, selected, values: {"T_d": 1e-3})
    values, selected = run()
    assert selected == [] and calls == [["delay"], []]


def test_an_effect_the_k_step_fit_takes_across_off_is_judged_as_one_it_took_off(monkeypatch):
    """The free run's fit has a sensor bend at k_x2 = -1276 V/m², the k-step fit that ends the refit
    at +1181 ± 290 (4σ from off, so not faint): two fits of one model disagree on the bend's sign
    (the independent emulator's force lag of seed 6800, benchmark seeds 6800). It is judged as one
    the k-step fit took off: it leaves where the free run without it still follows the record."""
    calls = []

    def fake_refit(prob, current, selected, say):
        calls.append(list(selected))
        if selected:
            return {"k_x2": 1181.0}, {"k_x2": 290.0}, {"k_x2": -1276.0}
        return {"k_x2": 0.0}, {}, None

    monkeypatch.setattr(pipeline, "_refit", fake_refit)
    monkeypatch.setattr(pipeline, "_uncertainties", lambda prob, current, selected, values: {"k_x2": 290.0})
    y = np.sin(np.linspace(0.0, 20.0, 500))
    prob = SimpleNamespace(base={"k_x2": 0.0}, noise=None, rec=SimpleNamespace(y=y),
                           free_run=lambda v: {"y": y + 0.01 * np.cos(np.linspace(0.0, 20.0, 500)) + 1e-9 * v["k_x2"]})

    def run() -> tuple[dict, list[str], list[str]]:
        calls.clear()
        said: list[str] = []
        selected = ["sensor_nonlinearity"]
        values, _ = pipeline.refit(prob, {"k_x2": -1000.0}, selected, said.append)
        return values, selected, said

    values, selected, said = run()
    assert values == {"k_x2": 0.0} and selected == [] and calls == [["sensor_nonlinearity"], []]
    assert any("to the other side of off" in m and "k_x2 -1276 -> 1181" in m for m in said)
    monkeypatch.setattr(pipeline, "KSTEP_CROSSING_LEAVES", False)        # the rule before: it stays
    values, selected, said = run()
    assert values == {"k_x2": 1181.0} and selected == ["sensor_nonlinearity"] and calls == [["sensor_nonlinearity"]]
    # the same side of off: no crossing, the k-step fit's values stand
    monkeypatch.setattr(pipeline, "KSTEP_CROSSING_LEAVES", True)
    monkeypatch.setattr(pipeline, "_refit", lambda prob, current, selected, say:
                        ({"k_x2": 1181.0}, {"k_x2": 290.0}, {"k_x2": 1276.0}))
    values, selected, said = run()
    assert values == {"k_x2": 1181.0} and selected == ["sensor_nonlinearity"]


def test_the_gradient_screen_passes_a_second_effect_that_is_there_and_stops_those_that_are_not(tmp_path):
    """A later round's gradient screen (issue 22, item 7): one Gauss-Newton step from the limit's model,
    each effect off. The 2.5 ms delay planted beside the 0.72 A limit promises a likelihood ratio far
    beyond the acceptance threshold; from the model of both, the effects that are not there promise
    less than ``GRADIENT_SHARE`` of theirs and are not fitted. An effect the baseline can absorb (the limit,
    the force exponent) names no gradient point: it is always screened by a short fit."""
    rec, prob, hold, first = _limited(tmp_path, {"delay": {"T_d": 0.0025}}, i_max=0.72)

    def screened(model, names):
        points = {e: CATALOGUE[e].gradient_points(prob, model) for e in names}
        out = pipeline.gradient_screen(prob, model, points, hold, cost_on(prob, model, hold),
                                       cost_on(prob, model, ~hold), 2)
        return out, {e: out[e][2] for e in names}, {e: out[e][0]["threshold"] for e in names}

    out, lr, thr = screened(first, ["delay"])
    assert lr["delay"] > 5 * thr["delay"], lr
    entry, vals = out["delay"][:2]
    assert entry["stage"] == "gradient screen" and entry["gradient"]["lr_promised"] == lr["delay"]
    assert 0.001 < vals["T_d"] < 0.005, vals["T_d"]       # the one step goes the right way
    # the model of both, fitted in full (what the next round starts from): the others promise little
    parts = [BASELINE, CATALOGUE["current_saturation"], CATALOGUE["delay"]]
    start = {**first, "T_d": 0.002}
    both = {**start, **fit(prob.with_base(start), parts, [p.to_coords(start) for p in parts], max_nfev=60).values}
    # (a pickup is linearised at the residual's strongest spectral peak, here the loop's resonance near
    # 16 Hz that the random force excites: chosen as the largest of many, it promises 10 to 24 against
    # 16.3 on seeds 5 to 7, and goes on to the short fit, judged on the held-out blocks, as before)
    names = ["coulomb_friction", "sensor_nonlinearity", "force_lag", "amplifier_lag"]
    out, lr, thr = screened(both, names)
    for e in names:
        assert lr[e] < pipeline.GRADIENT_SHARE * thr[e], (e, lr[e], thr[e])
    for e in ("current_saturation", "force_exponent"):
        assert CATALOGUE[e].gradient_points(prob, first) is None


def test_a_pickup_is_fitted_with_the_baseline_held(limited):
    """A pickup moves the loop at its own frequency only, so its fit holds the baseline's parameters
    (``Effect.with_baseline``, issue 22 item 7): the candidate's values keep the model's baseline to
    the bit, and every other entry of the default catalogue refits it."""
    rec, prob, hold, first = limited
    res = pipeline.fit_candidate(prob, first, "periodic_disturbance", pipeline.SCREEN_NFEV)
    assert all(res["values"][p] == first[p] for p in BASELINE.params), res["values"]
    assert not CATALOGUE["periodic_disturbance"].with_baseline
    assert all(CATALOGUE[e].with_baseline for e in CATALOGUE if e != "periodic_disturbance")


def test_a_delay_beside_a_lag_that_took_it_in_is_split_off_by_freeing_its_twin(tmp_path, monkeypatch):
    """A lag and a delay turn the loop's phase alike within its band, so the amplifier lag fitted
    first takes the 2.5 ms delay beside its own 1 ms into itself (T_a 3.7 ms). From there a delay held
    against that lag gains nothing; fitted with its twin freed and started from the same total lag
    (``_TimeConstant.loop_twin``, ``start_values``, ``joint``) the short fit splits it and passes the
    acceptance test on both block sets. Its entry names the twin's refitted value."""
    planted = {"amplifier_lag": {"T_a": 0.001}, "delay": {"T_d": 0.0025}}
    rec = read_record(synth_record(tmp_path / "rec.csv", seed=5, effects=planted, reference="square", period=0.6,
                                   duration=4.0), plausibility="warn")
    fit_mask = fit_blocks(rec.t)
    prob = pipeline.calibrate(rec, baseline_params(), fit_mask, lambda s: None).prob
    hold = ~fit_mask
    lag = CATALOGUE["amplifier_lag"]
    start = {**prob.base, "T_a": 0.003}
    first = {**start, **fit(prob.with_base(start), [BASELINE, lag], [BASELINE.to_coords(start), [0.003]],
                            max_nfev=60).values}
    assert first["T_a"] > 0.0033, first["T_a"]            # the lag took the delay in
    delay = CATALOGUE["delay"]
    assert delay.loop_twin(first) is lag and CATALOGUE["force_lag"].loop_twin(first) is lag
    assert CATALOGUE["sensor_lag"].loop_twin(first) is None and delay.loop_twin(prob.base) is None
    moved = delay.start_values([0.001], prob, first)
    assert moved["T_d"] == 0.001 and moved["T_a"] == pytest.approx(first["T_a"] - 0.001)
    assert delay.start_values([0.01], prob, first)["T_a"] == lag.coords[0].lo     # not below its bound

    def screened() -> tuple[dict, dict]:
        res = pipeline.fit_candidate(prob, first, "delay", pipeline.SCREEN_NFEV)
        return pipeline.judge(prob, hold, cost_on(prob, first, hold), res, 2, cost_on(prob, first, ~hold))

    entry, vals = screened()
    assert entry["accepted"] and entry["fit_lr_statistic"] > entry["fit_threshold"], entry
    assert vals["T_d"] > 3e-4 and vals["T_a"] < first["T_a"] - 3e-4, (vals["T_d"], vals["T_a"])
    assert entry["joint"] == {"T_a": vals["T_a"]}
    # the same fit with the lag held where it stood: no gain
    monkeypatch.setattr(type(delay), "loop_twin", lambda self, current: None)
    entry, vals = screened()
    assert not entry["accepted"] and vals["T_a"] == first["T_a"] and "joint" not in entry, entry
