"""The diagnosis as stages, each with one responsibility:

1. :func:`calibrate`: replay the record on the baseline (Section 3, ``T_a = 0``) and calibrate
   its free parameters (:data:`~.effects.BASELINE`): the "before" model;
2. :func:`search`: rounds of candidate fits on the fit blocks, judged on the held-out blocks
   (:mod:`.acceptance`); the best accepted effect joins the model and the search repeats;
3. :func:`refit`: the final model refitted on the whole record, with uncertainties: "after";
4. :func:`summarise`: what is left unexplained, and where a choice was weak.

:func:`run` runs them in order and returns a :class:`Diagnosis`: the CE152 path of the one entry
point, :func:`maglev_cosim.diagnosis.diagnose`, which writes the figures, report and calibrated FMU
and returns the typed :class:`~.result.DiagnosisResult`.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from multiprocessing import get_context

import numpy as np
from threadpoolctl import threadpool_limits

from ..records.record import Record
from .acceptance import ALPHA, CRITERION, MIN_GAIN, accept, fit_blocks
from .effects import BASELINE, CATALOGUE, DEFAULT_EFFECTS, Effect, twin_warnings
from .identify import equilibrium_points, least_squares_eq14
from .jacobian import gauss_newton_step, parameter_columns
from .metrics import chi2_quantile, nrmse_fit
from .problem import (FIT_TOL, Fit, Parameterization, Problem, cost_on, fit, on_fit_steps, one_thread, remember,
                      residuals, stacked, thread_map)
from .replay import HORIZON_S, baseline_params, estimate_noise, predict
from .controller_form import identified
from .residual import analyse_residual, effective_samples, noise_floor
from .result import Json
from .verdict import Verdict, conclude, on_bounds

MAX_EFFECTS = 3

Say = Callable[[str], None]


@dataclass
class Diagnosis:
    """Everything the diagnosis found; :meth:`to_json` gives the ``diagnosis.json`` content."""

    record: str
    before: dict[str, float]
    after: dict[str, float]
    selected: list[str]
    parameters: dict[str, float]
    uncertainties: dict[str, float]
    candidates: list[dict]
    calibrated_baseline: dict[str, float]
    residual_before: dict
    residual_after: dict
    noise: dict[str, float]
    rounds: list[dict]
    elapsed: float
    sims: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    unexplained: dict = field(default_factory=dict)
    record_warnings: list[str] = field(default_factory=list)
    verdict: Verdict | None = None
    fit_mode: str = "free run"       # which errors the fits minimised: "free run" or "prediction"
    #: The record as diagnosed: with its PID's form as the record showed it (:mod:`.controller_form`).
    diagnosed: Record | None = field(default=None, repr=False)

    @property
    def warnings(self) -> list[str]:
        """Everything the reader of the report should know first: the record's plausibility, the
        verdict's findings, weak choices."""
        out = list(self.record_warnings) + (list(self.verdict.warnings) if self.verdict else [])
        out += [f"in round {a['round']} {a['rival']} explains nearly as much as {a['chosen']}: the record does not "
                "separate the two well" for a in self.unexplained.get("ambiguous", [])]
        for chosen, rivals in self.alternatives.items():
            for r in rivals:
                out.append(f"{chosen} or {r['effect']}: indistinguishable on this record (held-out costs "
                           f"{r['held_out_cost_chosen']:.4g} and {r['held_out_cost_rival']:.4g}, LR {r['lr_statistic']:.1f} "
                           f"where {r['threshold']:.1f} would tell them apart); {chosen} was kept for its lower cost")
        return out

    @property
    def alternatives(self) -> dict[str, list[dict]]:
        """Each selected effect's rivals that the held-out blocks do not tell from it (:func:`distinct`)."""
        out: dict[str, list[dict]] = {}
        for c in self.candidates:
            if not c.get("selected"):
                continue
            for r in self.candidates:
                t = r.get("against_chosen")
                if r["round"] == c["round"] and r is not c and t and not t["distinct"]:
                    out.setdefault(c["effect"], []).append(
                        {"effect": r["effect"], "lr_statistic": t["lr_statistic"], "threshold": t["threshold"],
                         "held_out_cost_chosen": c["held_out_cost_after"],
                         "held_out_cost_rival": r["held_out_cost_after"]})
        return out

    def to_json(self) -> Json:
        head = {"verdict": self.verdict.verdict, "fit": self.verdict.fit, "fit_before": self.verdict.fit_before,
                "warnings": self.warnings} if self.verdict else {}
        return {
            **head,
            "record": self.record,
            "fit_mode": self.fit_mode,
            "record_warnings": self.record_warnings,
            "before": self.before,
            "after": self.after,
            "selected": self.selected,
            "alternatives": self.alternatives,
            "parameters": self.parameters,
            "uncertainties": self.uncertainties,
            "candidates": self.candidates,
            "calibrated": list(BASELINE.params),
            "calibrated_baseline": self.calibrated_baseline,
            "criterion": CRITERION,
            "rounds": self.rounds,
            "residual_before": self.residual_before,
            "residual_after": self.residual_after,
            "noise_floor": self.noise,
            "unexplained": self.unexplained,
            "elapsed_s": self.elapsed,
            **({"noise_model": self.verdict.noise.to_json(), "noise_model_before": self.verdict.noise_before.to_json(),
                "innovations_predictable_share": self.verdict.predictable_share,
                "location_evidence": self.verdict.location_evidence,
                "noise_floor_rule": self.verdict.noise_floor} if self.verdict else {}),
        }


def rms(rec: Record, sim: Mapping[str, np.ndarray]) -> dict[str, float]:
    """RMS of measured minus simulated y and u [MU]."""
    return {"rms_y": float(np.sqrt(np.mean((rec.y - sim["y"]) ** 2))),
            "rms_u": float(np.sqrt(np.mean((rec.u - sim["u"]) ** 2)))}


#: Free-run fit of y [%] of the final model below which the search is done again on the k-step
#: prediction (prediction mode).
FREE_RUN_MIN_FIT = 90.0


# ----------------------------------------------------------------------------- 0. where to start

def static_start(rec: Record, base: dict[str, float], say: Say) -> dict[str, float]:
    """Starting values of k_c and x_0 from the paper's least-squares fit of Eq. 14 on the record's
    settled segments (Sec. 3.4.2), when it has them and they lie inside the calibration bounds."""
    try:
        x, u_v = equilibrium_points(rec, base)
        lq = least_squares_eq14(x, u_v, base["m_k"], base["g"])
    except ValueError:
        return {}
    k_c = lq["k_f"] / base["k_i"] ** 2
    bounds = {c.name: (c.lo, c.hi) for c in BASELINE.coords}
    if not (bounds["k_c"][0] < k_c < bounds["k_c"][1] and bounds["x_0"][0] < lq["x_0"] < bounds["x_0"][1]):
        return {}
    say(f"starting from the Eq. 14 least-squares fit: k_c = {k_c:.4g} N.m2/A2, x_0 = {lq['x_0'] * 1e3:.3f} mm")
    return {"k_c": k_c, "x_0": lq["x_0"]}


# ----------------------------------------------------------------------------- 1. calibrate

@dataclass
class Calibration:
    prob: Problem                    # weighted by the calibrated baseline's residual, fit blocks
    values: dict[str, float]         # the calibrated baseline parameters
    raw: dict[str, np.ndarray]       # replay of the uncalibrated baseline
    sim: dict[str, np.ndarray]       # replay of the calibrated baseline


def calibrate(rec: Record, base: dict[str, float], fit_mask: np.ndarray, say: Say) -> Calibration:
    """Replays the baseline as it is, calibrates :data:`BASELINE` on the fit blocks, and weighs
    the y and u errors by the calibrated baseline's RMS."""
    say("replaying the record on the baseline model (Section 3, T_a = 0)")
    prob = Problem(rec, base, 1.0, 1.0, fit_mask)
    sim0 = prob.free_run({})
    raw = rms(rec, sim0)
    say(f"calibrating {', '.join(BASELINE.params)} (raw replay error: rms_y {raw['rms_y']:.5f} MU, "
        f"rms_u {raw['rms_u']:.5f} MU)")
    prob = Problem(rec, base, max(raw["rms_y"], 1e-6), max(raw["rms_u"], 1e-6), fit_mask)
    cal = fit(prob, [BASELINE], [BASELINE.to_coords(base)])
    sim = prob.free_run(cal.values)
    before = rms(rec, sim)
    say(f"calibrated baseline: rms_y {before['rms_y']:.5f} MU, rms_u {before['rms_u']:.5f} MU")
    prob = Problem(rec, base, max(before["rms_y"], 1e-6), max(before["rms_u"], 1e-6), fit_mask)
    return Calibration(prob, dict(cal.values), sim0, sim)


def calibrate_by_prediction(rec: Record, base: dict[str, float], fit_mask: np.ndarray, free: Calibration,
                            say: Say, found: Mapping[str, float] | None = None) -> Calibration:
    """The calibration again, on the k-step prediction of a filter that follows the measured past
    (prediction mode): for records whose free run cannot follow them even with the effects found
    (a loop that rings near instability, a disturbance that drives it). The disturbance model is
    estimated on ``found`` (the free-run search's final model, effects included) when given: the
    calibrated baseline's would carry what the effects explain as random force, and that inflated
    force lets a twin effect (a delay for an amplifier lag) predict as well as the true one."""
    say(f"estimating the disturbances, then calibrating on the {HORIZON_S * 1e3:.0f} ms prediction")
    noise = estimate_noise(rec, {**base, **(found if found is not None else free.values)})
    pprob = _weighted(Problem(rec, base, 1.0, 1.0, fit_mask, noise=noise), free.values)
    cal = fit(pprob, [BASELINE], [BASELINE.to_coords({**base, **free.values})])
    pprob = _weighted(pprob, cal.values)
    say(f"calibrated baseline (prediction mode): k-step rms_y {pprob.sigma_y:.5f} MU, rms_u {pprob.sigma_u:.5f} MU")
    return Calibration(pprob, dict(cal.values), free.raw, pprob.free_run(cal.values))


def _kstep_problem(whole: Problem, values: Mapping[str, float]) -> Problem:
    """``whole`` judged by the k-step prediction through the disturbances estimated for ``values``
    on the fits' substeps, as the verdict estimates them (the same estimate, kept), weighted by the
    errors ``values`` leave (:func:`_weighted`)."""
    return _weighted(replace(whole, noise=whole.disturbances(values, fit_steps=True)), values)


def _weighted(prob: Problem, values: Mapping[str, float]) -> Problem:
    """``prob`` weighted by the RMS of the errors ``values`` leave on the compared samples."""
    sim, ok = prob.simulate(values), prob.compared()
    sy = float(np.sqrt(np.mean((prob.rec.y - sim["y"])[ok] ** 2)))
    su = float(np.sqrt(np.mean((prob.rec.u - sim["u"])[ok] ** 2)))
    return replace(prob, sigma_y=max(sy, 1e-6), sigma_u=max(su, 1e-6))


# ----------------------------------------------------------------------------- 2. search

#: The least-squares tolerances (``ftol`` and ``xtol``) of a candidate's fits, screens and fits to
#: convergence alike: a fit ends when an iteration lowers the cost by less than this share, or moves
#: the scaled coordinates by less (the model's own fits: 1e-6). A candidate's fit serves its
#: judgement, not its final values: the effect chosen is fitted again with the model, and the final
#: model on the whole record. At 1e-6, most of a candidate's evaluations bought the last thousandths
#: of its cost: on the bench's 12 s record with one delay, the current limit took 37 evaluations (26
#: at 1e-4) and the force exponent 22 (16), to end where they end at 1e-4 within their uncertainty;
#: the lags' screens converge within their 4 evaluations at 1e-4. The fits that decide something
#: are fitted again to 1e-6 (:data:`REFINE`). (docs/diagnosis.md, "Candidate fits to 1e-4".)
CANDIDATE_TOL = 1e-4


def fit_candidate(prob: Problem, current: dict[str, float], effect_name: str, max_nfev: int = 60,
                  prepared: Mapping | None = None, one_base: bool = False, tol: float | None = None) -> dict:
    """Fits one effect together with the recalibrated baseline on the fit blocks (the baseline held
    for an effect that does not take it, :attr:`~.effects.Effect.with_baseline`); effects
    selected in earlier rounds stay in the model (in ``current``) while this one is fitted.
    ``max_nfev``: the least-squares evaluations allowed (a screen takes :data:`SCREEN_NFEV`).
    ``prepared``: the ``prepared`` entry of this candidate's screen on the same problem and
    ``current`` (its scored starts and the prefit of the chosen one), which the fit to convergence
    takes instead of computing them again: the same numbers. ``one_base``: an effect the baseline
    can absorb is fitted from the model as it stands only, not also from where the calibration
    started (:data:`IDLE_ONE_BASE`). ``tol``: the fits' tolerance (default :data:`CANDIDATE_TOL`)."""
    t0 = time.process_time()
    eff = CATALOGUE[effect_name]
    origin = {p: prob.base[p] for p in BASELINE.params}     # where the calibration started from
    prob = prob.with_base(current)

    def best_start(cur: dict[str, float]) -> tuple[float, list[float], dict[str, float]]:
        # the best start with the baseline held: of the effect's starts, and of its scan from their costs

        def evaluate(z: Sequence[float]) -> tuple[list[float], float, dict[str, float]]:
            vals = eff.start_values(list(z), prob, cur)
            return list(z), float(np.mean(residuals(prob, vals) ** 2)), vals

        # the starts are independent replays: side by side (thread_map keeps their order)
        scored = thread_map(evaluate, eff.starts(prob, cur))

        def cost(z: Sequence[float]) -> float:
            scored.append(evaluate(z))
            return scored[-1][1]

        def costs(zs: list[list[float]]) -> list[float]:
            got = thread_map(evaluate, zs)
            scored.extend(got)
            return [c for _, c, _ in got]

        eff.scan([(z, c) for z, c, _ in scored], cost, costs)
        c, z, vals = min(((c, z, vals) for z, c, vals in scored), key=lambda t: t[0])
        return c, z, vals

    prefits: dict[int, list[float]] = dict(prepared["prefit"]) if prepared else {}

    def fit_from(cur: dict[str, float], start: tuple[float, list[float], dict[str, float]], key: int | None = None):
        _, best, best_vals = start
        if key is not None and key in prefits:
            best = list(prefits[key])
        else:
            best = eff.prefit(prob, cur, list(best))
            if key is not None:
                prefits[key] = list(best)
        # the start's values besides the fitted coordinates (say the force exponent's pivot) stay
        parts, z0 = ([BASELINE, eff], [BASELINE.to_coords(best_vals), best]) if eff.with_baseline else ([eff], [best])
        # what the effect trades against in the model as it stands is freed beside it (a lag's twin)
        extra = eff.joint(cur)
        parts, z0 = [*parts, *extra], [*z0, *(p.to_coords(best_vals) for p in extra)]
        f = fit(prob.with_base(best_vals), parts, z0, max_nfev=max_nfev, tol=CANDIDATE_TOL if tol is None else tol)
        return {**cur, **best_vals, **f.values}, f

    # An effect the baseline can absorb (a D/A offset that shifted to mimic a current limit) may
    # have no start from the calibrated values that reaches it: its starts are placed from where the
    # calibration started too, and the fit goes from the better of the two.
    bases = [current]
    if eff.absorbed_by and not one_base and any(current[p] != origin[p] for p in BASELINE.params):
        bases.append({**current, **origin})
    # (a screen from one base prepared the first start only: the others are placed here)
    starts = list(prepared["starts"])[:len(bases)] if prepared else []
    starts += [best_start(b) for b in bases[len(starts):]]
    k = min(range(len(bases)), key=lambda j: starts[j][0])
    spare = None
    if len(starts) > 1:
        # An effect the baseline can absorb ends off from the better start on every record without
        # it, and is then fitted from the other base: the two fits side by side (the second is
        # spent in vain only where the effect is there).
        (values, f), spare = thread_map(lambda j: fit_from(bases[j], starts[j], j), [k, 1 - k])
    else:
        values, f = fit_from(bases[k], starts[k], k)
    nfev, retried, converged = f.nfev, k > 0, f.converged
    if (eff.is_off(values) and eff.absorbed_by and not one_base) or on_bounds(values)[0]:
        # From the chosen start the effect ended off, or the baseline on a bound: retried from the
        # other baseline (where the calibration started, the effect's starts placed anew).
        other = {**current, **origin} if k == 0 else current
        again, f2 = spare if spare is not None else fit_from(other, best_start(other))
        nfev, converged = nfev + f2.nfev, converged and f2.converged
        if f2.cost < f.cost or (on_bounds(values)[0] and not on_bounds(again)[0]):
            values, f, retried = again, f2, k == 0
    # converged: every fit ended by a tolerance within max_nfev, so that any larger max_nfev ends the
    # same (the same iterations): a screen that converged is the fit to convergence
    return {"effect": effect_name, "values": values, "fit_cost": f.cost, "nfev": nfev, "retried": retried,
            "converged": converged, "cpu_s": time.process_time() - t0, "joint": _joint(eff, current, values),
            "prepared": {"starts": starts, "prefit": prefits}, "simulated": prob.simulated(values)}


#: Whether the candidates whose fit to convergence reaches :data:`SCREEN_SHARE` of their threshold
#: are fitted again to :func:`~.problem.fit`'s 1e-6 (from their screen's starts) before they are
#: judged for the round's choice: the fits that decide something (an acceptance, a choice between
#: rivals whose fits differ by little) are made as before :data:`CANDIDATE_TOL`. Without it, on the
#: project emulator's force lag of benchmark seed 6100, the delay (its twin) was chosen.
REFINE = True
#: The tolerance of those fits (:data:`REFINE`): the model's own (:data:`~.problem.FIT_TOL`).
REFINE_TOL = FIT_TOL


#: A candidate whose fit at :data:`CANDIDATE_TOL` reaches :data:`SCREEN_SHARE` of its threshold is
#: fitted again to :data:`REFINE_TOL` only where that can change the round's choice
#: (:func:`within_reach`): where it was accepted, or where its held-out cost is within this factor
#: of the best accepted candidate's (refined) or its held-out gain at least that one's divided by
#: it. A candidate rejected at :data:`CANDIDATE_TOL` far behind the round's best is never chosen,
#: never a rival the record cannot tell from the chosen one, never "ambiguous" (a rival within 80 %
#: of the chosen one's gain, :func:`summarise`): its refit changed nothing but its own line of the
#: table. On the bench's 12 s record with one delay, the refit of a pickup at the loop's resonance
#: (16.9 Hz; LR 14.9 for 16.3 at 1e-4, -5.0 at 1e-6; held-out gain 5.0 % against the delay's 93.0 %)
#: took 213 of the diagnosis's 1303 closed-loop replays and was the first round's last job.
REFINE_REACH = 2.0


def within_reach(entry: Mapping, best: Mapping | None) -> bool:
    """Whether refitting a candidate (its judged ``entry`` at :data:`CANDIDATE_TOL`) to
    :data:`REFINE_TOL` could change the round's choice, given the ``best`` accepted candidate
    (None: none accepted, every refit could): :data:`REFINE_REACH`."""
    if best is None or entry["accepted"]:
        return True
    return (entry["held_out_cost_after"] <= REFINE_REACH * best["held_out_cost_after"]
            or entry["held_out_gain"] >= best["held_out_gain"] / REFINE_REACH)


def _joint(eff: Effect, current: Mapping[str, float], values: Mapping[str, float]) -> dict[str, float]:
    """The values of what ``eff``'s fit freed beside it (:meth:`~.effects.Effect.joint`) where they moved."""
    return {p: float(values[p]) for e in eff.joint(current) for p in e.params if values[p] != current[p]}


def _worker(args: tuple) -> dict:
    return fit_candidate(*args)


#: The screen: every candidate is first fitted with at most this many least-squares evaluations
#: (besides its Jacobians). Measured on 13 records of the emulator with and without each effect,
#: four evaluations reach the held-out likelihood ratio of the converged fit to within a few per
#: cent for every effect that is there, and stay below it where there is none; so only a
#: candidate whose screened ratio reaches :data:`SCREEN_SHARE` of its threshold is fitted to
#: convergence and judged again. The converged fits of the effects that are not there (up to 116
#: evaluations for a force exponent or a limit that never bites) made two thirds of a diagnosis.
#: An effect the baseline can absorb (:attr:`~.effects.Effect.absorbed_by`) is always fitted to
#: convergence: a limit active in 1 % of the samples screened at a held-out ratio of -14.8 and
#: converged at +221. So is a screen that stopped short of convergence yet already meets the
#: acceptance's minimum gain (:data:`~.acceptance.MIN_GAIN`): its ratio is a poor guide where the
#: held-out residual it leaves is slow and so has few effective samples (a force exponent of 3,
#: seed 3200: screened at n_F 2.21, a held-out gain of 14.9 % and a ratio of 3.4 for 13.8 from 21
#: effective samples; converged at n_F 3.00, 36.4 % and 653, where a sensor bend had been chosen).
SCREEN_NFEV = 4
SCREEN_SHARE = 0.5
FULL_NFEV = 60


def to_convergence(screened: Mapping[str, float], converged: bool) -> bool:
    """Whether a screened candidate (its judged entry: ``lr_statistic``, ``threshold``,
    ``held_out_gain``) is fitted to convergence: a screen whose ratio reaches :data:`SCREEN_SHARE`
    of its threshold, or one that stopped short of convergence and already meets the acceptance's
    minimum gain. (An effect the baseline can absorb is not screened in the first round, nor later
    where it was at work: :func:`at_work`.)"""
    return (screened["lr_statistic"] >= SCREEN_SHARE * screened["threshold"]
            or (not converged and screened["held_out_gain"] >= MIN_GAIN))


#: An effect the baseline can absorb is fitted to convergence again in a later round only where its
#: latest fit to convergence found it at work: not off, and lowering the held-out cost by at
#: least this share of the acceptance's minimum gain. (Elsewhere it is screened like the others,
#: from the model as it stands (:data:`IDLE_ONE_BASE`), and fitted to convergence from both bases
#: by :func:`to_convergence`.) On the benchmark's 12 s
#: record with one delay, the second round's two fits to convergence of an idle force exponent and
#: current limit took 1.9 s of the diagnosis's 8.6 s on one core.
AT_WORK_SHARE = 0.25


#: Whether an effect the baseline can absorb that its latest fit to convergence found idle
#: (:func:`at_work`) is screened in a later round from the model as it stands only. Its fit to
#: convergence was made from both bases, the model as it stood and where the calibration started
#: (for a limit the calibration's D/A offset absorbed), and found nothing there; the screen's second
#: scan from that start cost as much as the first (the limit's profile scan, 148 replays in each later
#: round on the bench's 12 s records). A screen that passes goes on to the fit to convergence from both.
IDLE_ONE_BASE = True


def at_work(effect: str, entry: Mapping, values: Mapping[str, float]) -> bool:
    """Whether a candidate's fit to convergence (its judged ``entry`` and fitted ``values``) found
    its effect at work: on, and lowering the held-out cost by :data:`AT_WORK_SHARE` of
    :data:`~.acceptance.MIN_GAIN` or more."""
    return not CATALOGUE[effect].is_off(values) and entry["held_out_gain"] >= AT_WORK_SHARE * MIN_GAIN


def turned_off(prob: Problem, effect: str, values: Mapping[str, float]) -> dict[str, float]:
    """``values`` with the parameters of ``effect`` at the problem's base, where every effect is off
    (the other values as they are: a candidate's own fit with the effect turned off)."""
    return {**values, **{p: prob.base[p] for p in CATALOGUE[effect].params}}


def _lr(r: np.ndarray, cost_before: float) -> tuple[float, float, float]:
    """The cost of a weighted residual ``r`` (y errors, then u errors), its effective samples (the
    fewer of its two halves') and the likelihood-ratio statistic ``N_eff·ln(J_before/J)``."""
    half = len(r) // 2
    n_eff = min(effective_samples(r[:half]), effective_samples(r[half:]))
    j = float(np.mean(r ** 2))
    return j, n_eff, (n_eff * math.log(cost_before / j) if j > 0 and cost_before > 0 else math.inf)


def judge(prob: Problem, hold_mask: np.ndarray, hold_before: float, res: dict, rnd: int,
          fit_before: float | None = None) -> tuple[dict, dict]:
    """A fitted candidate judged on the held-out blocks: its table entry and its values. With
    ``fit_before`` (the cost of the model without it on the fit blocks), an effect accepted there
    must also pass the likelihood-ratio test on the blocks it was fitted on (:data:`FIT_SIDE_TEST`)."""
    vals = res["values"]
    r_hold = residuals(prob, vals, hold_mask)
    hold_after, n_eff, _ = _lr(r_hold, hold_before)    # cost_on's figure, from the same replay
    eff = CATALOGUE[res["effect"]]
    ok, stats = accept(hold_before, hold_after, n_eff, len(eff.params))
    if eff.is_off(vals):
        ok = False
        stats = {**stats, "off": True}
    if ok and OWN_OFF_TEST:
        # The candidate's fit moved the baseline too (from where the calibration started, for an
        # effect the baseline can absorb): the gain must be the effect's, so it is judged against its
        # own fit with the effect off as well, where that is the better model without it (as
        # by_innovations_alone does for the filter's likelihood). That model must be one the fit
        # blocks would have taken without the effect too: where it fits them worse than the model
        # the round started from, it is no rival (the candidate's fit moved the baseline only away
        # from where the baseline had absorbed the effect there; :data:`OWN_OFF_TEST`).
        off = turned_off(prob, res["effect"], vals)
        hold_off = cost_on(prob, off, hold_mask)
        fit_off = cost_on(prob, off, ~hold_mask) if fit_before is not None and hold_off < hold_before else None
        if fit_off is not None:
            stats = {**stats, "fit_cost_own_off": float(fit_off)}
        if hold_off < hold_before and (fit_off is None or fit_off <= fit_before):
            ok_off, stats_off = accept(hold_off, hold_after, n_eff, len(eff.params))
            stats = {**stats, "held_out_cost_own_off": float(hold_off), "own_off_lr_statistic":
                     float(stats_off.get("lr_statistic", math.nan))}
            if not ok_off:
                ok = False
                stats = {**stats, "own_off_rejected": True}
    if ok and fit_before is not None and FIT_SIDE_TEST:
        # The classical test on the fitted blocks: an effect that explains nothing of the blocks it
        # was fitted on is not credited with what the held-out blocks show (a free run that loses
        # the ball a few ms earlier in one held-out block: a limit active 62 % of the samples, whose
        # 78 us delay gained 22 % held out and 0.06 % on the fit blocks).
        fit_after, n_fit, lr_fit = _lr(residuals(prob, vals, ~hold_mask), fit_before)
        stats = {**stats, "fit_cost_before": float(fit_before), "fit_cost_after": fit_after,
                 "fit_lr_statistic": float(lr_fit), "fit_n_eff": float(n_fit)}
        fit_threshold = float(chi2_quantile(1 - FIT_SIDE_ALPHA, len(eff.params)))
        stats = {**stats, "fit_threshold": fit_threshold}
        if not lr_fit > fit_threshold:
            ok = False
            stats = {**stats, "fit_side_rejected": True}
    if ok:
        # the effect's own signature (a pickup steady through the record, no harmonic of the reference)
        steady, evidence = eff.consistent(prob, vals)
        if evidence:
            stats = {**stats, "consistency": evidence}
        if not steady:
            ok = False
            stats = {**stats, "inconsistent": True}
    errs = rms(prob.rec, prob.free_run(vals))
    if res.get("joint"):
        stats = {**stats, "joint": dict(res["joint"])}
    entry = {"effect": res["effect"], "round": rnd, "parameters": {p: vals[p] for p in eff.params}, **errs,
             "accepted": ok, "held_out_cost_before": hold_before, "held_out_cost_after": hold_after, **stats,
             "calibrated": {n: vals[n] for n in BASELINE.params}}
    return entry, vals


#: Whether :func:`judge` also asks the likelihood-ratio test of the fit blocks (given their cost
#: before): the classical in-sample test, which the held-out blocks then replicate.
FIT_SIDE_TEST = True
#: The level of that test on the fit blocks. The held-out test at 1 - ALPHA keeps the false positives
#: down; the fit blocks' test only asks that the effect act where it was fitted too (what the held-out
#: blocks replicate), so at a plainer level: a current limit active in five samples of a 12 s record
#: (project emulator, seed 3700, i_max 0.85 A) gained 59.8 % held out at LR 263 and reached LR 10.1
#: on the fit blocks, under the 10.8 of ALPHA; the amplifier lag that its transients made look right
#: (T_a 1.45 ms, none planted) was chosen instead. The spurious delay this test was made for read 0.2.
FIT_SIDE_ALPHA = 0.01
#: Whether :func:`judge` also tests a candidate against its own fit with the effect turned off, where
#: that model is better than the one without it: the gain of a candidate that only moved the
#: baseline, or the effects already selected, is not the effect's. Better means on the held-out blocks
#: and, since 2026-11-27, not worse on the fit blocks: on the independent emulator's record of a
#: 0.85 A limit active in 0.03 % of the samples (benchmark seeds 4500, seed 4500), the calibrated
#: baseline had absorbed the limit on the fit blocks (x_0 = 10.3 mm, u_0 = 0.67 V for 8.3 mm and 0).
#: The limit's fit moved them back (8.35 mm, 0.012 V) and lowered the held-out cost from 0.83 to
#: 0.62; its own-off model reached 0.65 held out, so the limit was rejected (LR 7.3 against it), but
#: that model cost 4.07 on the fit blocks, against the baseline's 1.15. A 1.7 ms amplifier lag was
#: chosen instead, and the final model (x_0 = 9.3 mm) was `explained` at 1.31 times the true model's
#: 20 ms error.
OWN_OFF_TEST = True


#: False-distinction probability of :func:`distinct`: the acceptance test's (``acceptance.ALPHA``),
#: so that the choice between two effects is held to the standard of the choice of one.
DISTINCT_ALPHA = ALPHA


def distinct(chosen: Mapping, rival: Mapping, alpha: float = DISTINCT_ALPHA) -> dict:
    """Whether the held-out blocks tell the chosen candidate from an accepted rival: the acceptance
    test's likelihood ratio between the two, ``N_eff·ln(J_rival/J_chosen)`` (``N_eff`` the chosen
    fit's effective held-out samples), against the chi-square quantile of one degree of freedom at
    ``1 - alpha``: the rival, judged as an effect added to the chosen one's model, would gain too
    little to be told from noise. Two effects of one transfer function from u to y (a delay and a
    force lag of a few ms) reach held-out costs a fraction of a per cent apart: the record does
    not tell which. (A Vuong test of the per-sample differences, tried first, called a 12 % cost
    difference indistinguishable: the differences concentrate in the few samples after each step.)"""
    j_c, j_r, n_eff = chosen["held_out_cost_after"], rival["held_out_cost_after"], chosen["n_eff"]
    stat = n_eff * math.log(j_r / j_c) if j_c > 0 and j_r > 0 else math.inf
    threshold = float(chi2_quantile(1 - alpha, 1))
    return {"lr_statistic": float(stat), "threshold": threshold, "distinct": bool(stat > threshold)}


#: Samples at the start of the record whose innovations :func:`by_innovations` leaves out (the
#: filter settling), as :func:`~.replay.innovation_nll` does.
INNOVATIONS_SKIP = 200


def by_innovations(prob: Problem, hold_mask: np.ndarray, chosen: Mapping[str, float], rival: Mapping[str, float],
                   alpha: float = DISTINCT_ALPHA) -> dict:
    """Two accepted candidates that the held-out free run does not tell apart (:func:`distinct`),
    compared by the likelihood of the filter's one-step innovations on the held-out blocks, each
    model with its own disturbances estimated by maximum likelihood (:func:`~.replay.estimate_noise`,
    white sensor noise: three levels each). The free run sees only what the reference excites; the
    innovations see how each model carries the record's own excitation (the PID's answer to the
    sensor noise, up to the Nyquist frequency), where a first-order lag attenuates and a delay does
    not. The statistic is the sum over the held-out samples of the difference of
    ``log s + e²/s`` (minus twice the log-likelihood), positive when the chosen one is the likelier,
    scaled by the effective share of samples of the two innovation sequences
    (:func:`~.residual.effective_samples`), against the chi-square quantile of one degree of freedom
    at ``1 - alpha``, as :func:`distinct`. On the project emulator's 2 ms force lag of seed 2900,
    whose held-out free run chose a delay (costs 0.6 % apart), it reads 32 for the force lag.

    Each model's sensor noise may have a coloured part (:func:`~.replay.estimate_noise`'s held-out
    choice): the twins differ above the loop's bandwidth, where a coloured sensor noise taken for
    white reads as a loop that answers its noise less, as a lag does. On the independent emulator's
    2 ms force lag of seed 3100 (sensor noise low-passed at 100 Hz), white sensor noise chose the
    delay (LR -34.7; -10.9 with that noise white); with the coloured choice, the force lag (+16.4),
    and on the project emulator's seed 2900 (white noise) still the force lag (+29.9)."""
    t_c, t_r = thread_map(lambda v: innovation_terms(prob, v, coloured=True), (chosen, rival))   # C, GIL released
    return innovations_test(t_c, t_r, hold_mask, 1, alpha)


def innovation_terms(prob: Problem, values: Mapping[str, float],
                     coloured: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, ``log s + e²/s`` of the filter's one-step innovations ``e`` (variance ``s``) of a
    model with its disturbances estimated by maximum likelihood (white sensor noise, or with
    ``coloured`` a coloured part where the record shows one), and ``e/√s``."""
    full = prob.model(values)
    out = predict(prob.rec, full, estimate_noise(prob.rec, full, coloured=coloured), horizon_s=0.0)
    e, v = out["innov"], out["innov_var"]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.log(v) + e ** 2 / v, e / np.sqrt(v)


def innovations_test(chosen: tuple[np.ndarray, np.ndarray], rival: tuple[np.ndarray, np.ndarray],
                     hold_mask: np.ndarray, dof: int = 1, alpha: float = DISTINCT_ALPHA) -> dict:
    """The likelihood-ratio statistic of two models' innovations (:func:`innovation_terms`) on the
    held-out blocks, positive when ``chosen`` is the likelier, against the chi-square quantile of
    ``dof`` degrees of freedom at ``1 - alpha``."""
    (l_c, z_c), (l_r, z_r) = chosen, rival
    ok = np.isfinite(l_c) & np.isfinite(l_r) & np.asarray(hold_mask, bool)
    ok[:INNOVATIONS_SKIP] = False
    n = int(ok.sum())
    if n < 10:
        return {"lr_statistic": 0.0, "threshold": math.inf, "distinct": False, "samples": n, "criterion": "innovations"}
    share = min(effective_samples(z_c[ok]), effective_samples(z_r[ok])) / n
    stat = float(np.sum(l_r[ok] - l_c[ok])) * share
    threshold = float(chi2_quantile(1 - alpha, dof))
    return {"lr_statistic": stat, "threshold": threshold, "distinct": bool(abs(stat) > threshold),
            "samples": n, "effective_share": float(share), "criterion": "innovations"}


def by_innovations_alone(prob: Problem, hold_mask: np.ndarray, current: Mapping[str, float],
                         results: Mapping[str, tuple[dict, dict]], say: Say) -> None:
    """The first round's candidates fitted to convergence that the held-out free run rejected
    though they improved it (a held-out gain above 0), tested by the held-out likelihood of the
    filter's innovations against the model without them (:func:`innovation_terms`): an effect whose
    innovations are the likelier beyond the chi-square quantile of its parameter count at
    ``1 - ALPHA`` is accepted (``accepted_by``: ``innovations``). Tried only when no candidate passes
    the free-run test, and only for the first effect: a further one must pass against the model of
    the first refitted in full. The free run sees what the reference excites; a small deterministic
    effect (a Coulomb friction of 1.8 % of the weight, a sensor bend k_x2 = -3e4) hides there under
    the random force (free-run LR 10.4 and 7.1 against 10.8), and the filter, which follows the
    record's own disturbances, sees it (LR 209 and 62 on seed 2900's records; at most 11 for any
    candidate of the no-effect records of seeds 2000-2006, a pickup with a threshold of 16.3, and 2
    for a one-parameter one).

    The model without an effect is also the candidate's own fit with the effect turned off, and the
    test is the stricter of the two: a candidate refits the baseline too (from where the calibration
    started, for an effect the baseline can absorb), and what the filter credits must be the effect's,
    not that other calibration's. On a no-effect record (seed 3511) a current limit at 1.348 A, above
    every current the record's input asks for, passed at LR +49.8 against the calibrated baseline:
    the same replay with or without the limit, a baseline from the other start. Updates the entries
    in place.

    An effect the baseline can absorb (:attr:`~.effects.Effect.absorbed_by`: a current limit, a force
    exponent) is not tried (since 2026-11-27): it trades with the baseline's parameters, and the
    filter's likelihood credits such a pair with what the record's own disturbances leave in the
    innovations. On the project emulator's no-effect records of seeds 4501 (a drifting force of
    0.19 % of the weight) and 4607 (10-bit converters, 1.4e-3 MU of sensor noise), whose free runs
    it did not improve (held-out gains under 0.05 %), a force exponent passed at LR +39.7 and +51.7
    against 13.8 (n_F = 2.08 and 1.66), verdicts `explained in part` and `explained`.

    One it accepts must show the effect's own signature as well (:meth:`~.effects.Effect.consistent`,
    which :func:`judge` asks of what the free run accepts; since 2026-11-27): on a 4 s record of a
    0.69 A limit under a 0.6 s square (tests/test_verdict_rules.py), a pickup fitted on the 6th
    harmonic of the reference, rejected held out (LR 12.4 against 16.3), passed the innovations'
    test and was selected; the reference's comb rejects it."""
    todo = [(e, entry, vals) for e, (entry, vals) in results.items()
            if entry.get("stage") == "fit" and not entry["accepted"] and entry["held_out_gain"] > 0
            and not entry.get("off") and not entry.get("inconsistent") and not CATALOGUE[e].absorbed_by]
    if not todo:
        return
    own_off = [turned_off(prob, e, vals) for e, _, vals in todo]
    # the model without them, each candidate and each with its effect off, side by side (the filter
    # runs in C, the GIL released)
    base_terms, *terms = thread_map(lambda v: innovation_terms(prob, v), [current, *(t[2] for t in todo), *own_off])
    terms, off_terms = terms[:len(todo)], terms[len(todo):]
    for (e, entry, vals), t, t_off in zip(todo, terms, off_terms):
        test = min((innovations_test(t, null, hold_mask, len(CATALOGUE[e].params), ALPHA)
                    for null in (base_terms, t_off)), key=lambda r: r["lr_statistic"])
        entry["innovations"] = test
        if test["lr_statistic"] > test["threshold"]:
            # the effect's own signature holds here too (judge asks it of what the free run accepts):
            # a pickup the innovations credit must still be steady and no harmonic of the reference
            steady, evidence = CATALOGUE[e].consistent(prob, vals)
            if evidence:
                entry["consistency"] = evidence
            if steady:
                entry["accepted"], entry["accepted_by"] = True, "innovations"
            else:
                entry["inconsistent"] = True
        say(f"  {e} by the innovations' likelihood on the held-out blocks: LR {test['lr_statistic']:+.1f} vs "
            f"{test['threshold']:.1f} -> " + ("accepted" if entry["accepted"] else "rejected"))


def against_refitted(prob: Problem, hold_mask: np.ndarray, hold_before: float, selected: Sequence[str],
                     entry: dict, vals: dict[str, float], rnd: int,
                     fit_before: float | None = None) -> tuple[dict, dict, Fit]:
    """A further effect, accepted against the model of the ``selected`` effects as it stood, judged
    again against that model refitted in full (the baseline's and every selected effect's
    parameters) from where the candidate's fit ended, the candidate turned off; the candidate's
    model is refitted in full too (its fit held the selected effects' parameters). A candidate
    that only patches an under-fitted first effect (a friction that moved the calibration to
    where the current limit, freed, fits better) gains nothing against the refitted model. The
    reference is the lower of the two held-out costs: the model as it stood and refitted; on the
    fit blocks (:func:`judge`'s test there), the lower of ``fit_before`` and the refitted model's.
    Returns the new table entry, the candidate's values and the refitted model's fit."""
    eff = CATALOGUE[entry["effect"]]
    null_parts: list[Parameterization] = [BASELINE, *(CATALOGUE[e] for e in selected)]
    start = turned_off(prob, entry["effect"], vals)
    null = fit(prob.with_base(start), null_parts, [p.to_coords(start) for p in null_parts], max_nfev=FULL_NFEV)
    null = replace(null, values={**start, **null.values})
    alt_parts = [*null_parts, eff]
    alt = fit(prob.with_base(vals), alt_parts, [p.to_coords(vals) for p in alt_parts], max_nfev=FULL_NFEV)
    alt_vals = {**vals, **alt.values}
    hold_null = cost_on(prob, null.values, hold_mask)
    new, alt_vals = judge(prob, hold_mask, min(hold_before, hold_null), {"effect": entry["effect"],
                                                                         "values": alt_vals}, rnd,
                          fit_before=min(null.cost, math.inf if fit_before is None else fit_before))
    new.update(stage="against refitted", held_out_cost_as_it_stood=hold_before,
               held_out_cost_refitted=hold_null,
               first_refitted={p: null.values[p] for part in null_parts for p in part.params},
               as_it_stood={k: entry[k] for k in ("held_out_gain", "lr_statistic", "accepted")})
    return new, alt_vals, null


#: Whether the search's later rounds screen the candidates the baseline cannot absorb by their
#: gradient first (:func:`gradient_screen`).
GRADIENT_SCREEN = True
#: The gradient screen's step along each effect coordinate [its typical size, :attr:`Coord.scale`]: a
#: secant over a tenth of it (0.1 ms of a lag, 0.1 mN of friction, 1 mV of a pickup).
GRADIENT_STEP = 0.1
#: Share of the acceptance threshold the in-sample likelihood ratio that the Gauss-Newton step
#: promises must reach for the candidate to be screened by a short fit (:func:`gradient_screen`).
GRADIENT_SHARE = 0.25


def gradient_screen(prob: Problem, current: dict[str, float],
                    points: Mapping[str, Sequence[tuple[list[float], tuple[int, ...]]]], hold_mask: np.ndarray,
                    hold_before: float, fit_before: float, rnd: int) -> dict[str, tuple[dict, dict, float]]:
    """Candidates of a later round screened by one Gauss-Newton step from the model as it stands,
    the effect off: the columns of the baseline's parameters (shared by every candidate) and of
    each effect's coordinates at the ``points`` it names (:meth:`~.effects.Effect.gradient_points`),
    secants over :data:`GRADIENT_STEP` of their scales, one replay each. The step's fall of the
    cost on the fit blocks gives the in-sample likelihood ratio it promises (``N_eff·ln(J/J_GN)``,
    ``N_eff`` the effective samples of the residual as it stands); the step's values are judged on
    the held-out blocks as any screen (:func:`judge`). The baseline's columns are in every
    candidate's step, a pickup's too (whose fits hold the baseline): the promise can only grow by
    them, and a promise errs best on the side of fitting. For each effect: its best point's entry
    (``stage``: ``gradient screen``, ``gradient``: the promised ratio), values and promised ratio.

    A short fit (the screen) costs 40 to 150 replays per candidate, its starts placed over the
    effect's range; the round after an effect was added screened every other candidate so, and
    most of them found nothing. The promised ratio is a local, in-sample figure, optimistic for
    an effect that is absent; an effect that is there shows in it (the bench's 50 Hz pickup beside a
    delay: promised LR 1.2e3 against 16.3)."""
    r0 = residuals(prob, current)
    half = len(r0) // 2
    n_eff = min(effective_samples(r0[:half]), effective_samples(r0[half:]))
    j0 = float(np.mean(r0 ** 2))
    scales = BASELINE.uncertainty_scales()
    # every replay of the screen side by side: the baseline's columns, each point, each point's steps
    jobs: list[dict[str, float]] = []
    plan: dict[str, list[tuple[list[float], tuple[int, ...], int | None, list[int]]]] = {}
    for e, pts in points.items():
        eff = CATALOGUE[e]
        plan[e] = []
        for z, free in pts:
            at = eff.start_values(z, prob, current)
            k0 = None
            if any(at.get(p) != current.get(p) for p in (*eff.params, *BASELINE.params)):
                k0 = len(jobs)
                jobs.append(at)
            ks = []
            for k in free:
                zk = list(z)
                zk[k] += GRADIENT_STEP * eff.coords[k].scale
                ks.append(len(jobs))
                jobs.append(eff.start_values(zk, prob, current))
            plan[e].append((z, free, k0, ks))
    got = thread_map(lambda v: residuals(prob, v), jobs)
    J_b = parameter_columns(lambda v: residuals(prob, v), current, scales, r0, map_fn=thread_map)
    zb = np.array([current[c.name] / c.scale for c in BASELINE.coords])
    lob = np.array([c.lo / c.scale for c in BASELINE.coords])
    hib = np.array([c.hi / c.scale for c in BASELINE.coords])
    out: dict[str, tuple[dict, dict, float]] = {}
    for e, rows in plan.items():
        eff = CATALOGUE[e]
        best = None
        for z, free, k0, ks in rows:
            f = r0 if k0 is None else got[k0]
            J = np.column_stack([J_b, *((got[k] - f) / GRADIENT_STEP for k in ks)])
            ze = np.array([z[k] / eff.coords[k].scale for k in free])
            lo = np.concatenate([lob, [eff.coords[k].lo / eff.coords[k].scale for k in free]])
            hi = np.concatenate([hib, [eff.coords[k].hi / eff.coords[k].scale for k in free]])
            step, gain = gauss_newton_step(J, f, np.concatenate([zb, ze]), lo, hi)
            j1 = max(float(f @ f) - 2 * gain, 0.0) / len(f)
            lr = n_eff * math.log(j0 / j1) if j1 > 0 and j0 > 0 else math.inf
            if best is None or lr > best[0]:
                best = (lr, z, free, step)
        lr, z, free, step = best
        zn = list(z)
        for j, k in enumerate(free):
            zn[k] += step[len(zb) + j] * eff.coords[k].scale
        vals = eff.start_values(zn, prob, current)
        for j, c in enumerate(BASELINE.coords):
            vals[c.name] = float(np.clip(vals[c.name] + step[j] * c.scale, c.lo, c.hi))
        entry, vals = judge(prob, hold_mask, hold_before, {"effect": e, "values": vals,
                                                           "joint": _joint(eff, current, vals)}, rnd, fit_before)
        entry["stage"] = "gradient screen"
        entry["gradient"] = {"lr_promised": float(lr), "share": GRADIENT_SHARE, "n_eff": float(n_eff)}
        out[e] = (entry, vals, float(lr))
    return out


def _judged(entry: Mapping, stage: str) -> str:
    """One line of the search's progress: a candidate's fit and its judgement."""
    return (f"{entry['effect']} ({stage}): " + ", ".join(f"{p} = {v:.4g}" for p, v in entry["parameters"].items())
            + "".join(f" ({p} refitted to {v:.4g})" for p, v in entry.get("joint", {}).items())
            + f"; held-out cost change {-100 * entry['held_out_gain']:+.1f} % "
            + f"(LR {entry['lr_statistic']:.1f} vs {entry['threshold']:.1f}"
            + (f"; on the fit blocks {entry['fit_lr_statistic']:.1f}" if "fit_lr_statistic" in entry else "")
            + ") -> " + ("accepted" if entry["accepted"] else "rejected")
            + (f" ({entry['refined']['skipped']})" if "skipped" in entry.get("refined", {}) else ""))


@dataclass
class Search:
    selected: list[str]
    values: dict[str, float]         # baseline and effect values of the model after the search
    candidates: list[dict]
    rounds: list[dict]


def search(prob: Problem, current: dict[str, float], effects: Sequence[str], hold_mask: np.ndarray,
           workers: int, say: Say) -> Search:
    """Rounds of candidate fits; the best accepted effect joins the model each round."""
    selected: list[str] = []
    candidates: list[dict] = []
    rounds: list[dict] = []
    cpu: dict[str, float] = {}       # each candidate's CPU time in the last round
    last_fits: dict[str, tuple[dict, dict]] = {}   # each candidate's latest fit to convergence (entry, values)
    ctx = get_context("fork") if sys.platform.startswith("linux") else get_context()
    # One pool of one process per worker, so that a candidate's later fits go where its screen ran:
    # a fit to convergence, and a refit to the model's tolerance, retrace the path of the fit before
    # them, whose replays that process keeps (problem.SIMULATED_KEPT). Each process starts here, before
    # any thread of this search does.
    pools = [ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=one_thread)
             for _ in range(workers)] if workers > 1 else []
    for p in pools:
        p.submit(int).result()
    on_pool: dict[Future, int] = {}
    home: dict[str, int] = {}         # each candidate's process: where its last fit ran

    def run(fn, args) -> Future:
        """``fn(args)`` on a worker (the candidate's own where it is among the least busy), or at
        once here (one worker)."""
        if pools:
            busy = [sum(1 for f, j in on_pool.items() if j == k and not f.done()) for k in range(len(pools))]
            k = home.get(args[2], -1)
            if k < 0 or busy[k] > min(busy):
                k = busy.index(min(busy))
            fut = pools[k].submit(fn, args)
            on_pool[fut] = home[args[2]] = k
            return fut
        done: Future = Future()
        done.set_result(fn(args))
        return done

    def result(fut: Future) -> dict:
        """A fit's result, the replay of the values it ended at kept here for its judgement."""
        res = fut.result()
        on_pool.pop(fut, None)
        remember(*res.pop("simulated"))
        return res

    try:
        for rnd in range(1, MAX_EFFECTS + 1):
            remaining = [e for e in effects if e not in selected]
            if not remaining:
                break
            hold_before = cost_on(prob, current, hold_mask)
            fit_before = cost_on(prob, current, ~hold_mask)
            better_null: dict[str, float] | None = None
            say(f"round {rnd}: fitting {len(remaining)} candidate effect(s) on the fit blocks")
            # the costliest fits first, so that no core idles at the end of the round: as the last
            # round measured them, or in the first as many starts and parameters they have
            work = {e: cpu.get(e, len(CATALOGUE[e].starts(prob, current)) * len(CATALOGUE[e].params))
                    for e in remaining}
            order = sorted(remaining, key=lambda e: -work[e])
            results: dict[str, tuple[dict, dict]] = {}
            prepared: dict[str, Mapping] = {}     # each candidate's scored starts, from its screen
            converged: set[str] = set()           # candidates whose screen converged (fit() ended by a tolerance)
            # The effects the baseline can absorb are fitted to convergence whatever the screens find:
            # with a pool, those fits (the round's longest) go first, beside the screens, rather than
            # after them on one core while the other idles. Judged in the fit stage, in its order.
            # From the second round on, one that its latest fit to convergence found idle is
            # screened like the others (from the model as it stands: IDLE_ONE_BASE): what it could
            # absorb has not changed.
            full = {e for e in order if CATALOGUE[e].absorbed_by and (e not in last_fits or at_work(e, *last_fits[e]))}
            # Each screen is judged as it comes in, and a promising one is fitted to convergence next
            # (with its screen's starts: prepared[e]), ahead of the screens still waiting: the round's
            # longest fit no longer waits for the last screen. At most one job per worker is handed
            # out, so that a fit queued later can still go first; jobs that end together are judged
            # in the costliest-first order (with a single worker: all of them).
            # From the second round on, a candidate the baseline cannot absorb is screened by the
            # gradient first (:func:`gradient_screen`), and by a short fit only where that promises
            # enough; the short fits of the others go to the workers meanwhile.
            points = {}
            if rnd > 1 and GRADIENT_SCREEN:
                points = {e: CATALOGUE[e].gradient_points(prob, current) for e in order
                          if e not in full and not CATALOGUE[e].absorbed_by}
                points = {e: p for e, p in points.items() if p}
            todo = [("fit", e, FULL_NFEV, None) for e in order if e in full]
            todo += [("screen", e, SCREEN_NFEV, None) for e in order if e not in full and e not in points]
            n_screens = len(todo) - len(full)
            flying: dict[Future, tuple[str, str]] = {}
            fitted: dict[str, dict] = {}
            gradients: dict[str, dict] = {}       # the gradient screen's figures of those it passed on
            k = 0

            def launch() -> None:
                while todo and (not pools or len(flying) < workers):
                    kind, e, nfev, prep = todo.pop(0)
                    # an absorbed effect found idle before is screened from the model as it stands only
                    one = IDLE_ONE_BASE and kind == "screen" and e in last_fits and bool(CATALOGUE[e].absorbed_by)
                    flying[run(_worker, (prob, current, e, nfev, prep, one))] = (kind, e)

            if points:
                launch()
                for e, (entry, vals, lr) in gradient_screen(prob, current, points, hold_mask, hold_before,
                                                            fit_before, rnd).items():
                    passed = lr >= GRADIENT_SHARE * entry["threshold"] or to_convergence(entry, False)
                    say(f"  {e} (gradient screen): promised LR {lr:.1f} on the fit blocks vs "
                        f"{GRADIENT_SHARE * entry['threshold']:.1f}; one step: held-out cost change "
                        f"{-100 * entry['held_out_gain']:+.1f} % -> " + ("screened by a short fit" if passed else "rejected"))
                    if passed:
                        todo.append(("screen", e, SCREEN_NFEV, None))
                        n_screens += 1
                        gradients[e] = entry["gradient"]
                    else:
                        results[e] = (entry, vals)

            while todo or flying:
                launch()
                ended, _ = wait(list(flying), return_when=FIRST_COMPLETED)
                came = [(flying.pop(f), result(f)) for f in sorted(ended, key=lambda f: order.index(flying[f][1]))]
                launch()           # the workers go on while the screens that ended are judged here
                for (kind, e), res in came:
                    if kind == "fit":
                        fitted[e] = res
                        continue
                    prepared[e] = res.pop("prepared")
                    entry, vals = judge(prob, hold_mask, hold_before, res, rnd, fit_before)
                    entry["stage"] = "screen"
                    if e in gradients:
                        entry["gradient"] = gradients[e]
                    cpu[e] = res["cpu_s"]
                    results[e] = (entry, vals)
                    k += 1
                    say(f"  [{k}/{n_screens}] " + _judged(entry, "screen"))
                    # a screen whose fits converged within SCREEN_NFEV is its fit to convergence: not fitted again
                    if res["converged"]:
                        converged.add(e)
                    elif to_convergence(entry, False):
                        todo.insert(sum(t[0] == "fit" for t in todo), ("fit", e, FULL_NFEV, prepared[e]))
            # (the table in the costliest-first order, whichever screen ended first)
            results = {e: results[e] for e in order if e in results}
            # only the candidates the screen found promising are fitted to convergence, and those the
            # baseline can absorb (a limit mimicked by u_0): their screen starts from the calibrated
            # baseline that absorbed them, and only the full fit's retry from where the calibration
            # started can see them
            to_fit = [e for e in order if e in full or to_convergence(results[e][0], e in converged)]
            if to_fit:
                say(f"  fitting {len(to_fit)} of them to convergence: {', '.join(to_fit)}")
            for e in to_fit:
                if e in fitted:
                    res = fitted[e]
                    prepared[e] = res.pop("prepared")
                    entry, vals = judge(prob, hold_mask, hold_before, res, rnd, fit_before)
                    if e in gradients:
                        entry["gradient"] = gradients[e]
                    cpu[e] = res["cpu_s"]
                else:                         # its converged screen, judged alike
                    entry, vals = results[e]
                results[e] = ({**entry, "stage": "fit"}, vals)
            # the fits that decide something, fitted again to the model's own tolerance (REFINE)
            # (in waves: those within reach of the best accepted one first, then any that the refined
            # figures bring within reach; the others cannot change the round's choice: REFINE_REACH)
            near = [e for e in to_fit if REFINE and results[e][0]["lr_statistic"] >= SCREEN_SHARE * results[e][0]["threshold"]]
            refined: set[str] = set()

            def best_of(names) -> dict | None:
                return min((results[e][0] for e in names if results[e][0]["accepted"]),
                           key=lambda c: c["held_out_cost_after"], default=None)

            best = best_of(near)           # at 1e-4 first, then of the refitted figures
            while wave := [e for e in near if e not in refined and within_reach(results[e][0], best)]:
                again = {run(_worker, (prob, current, e, FULL_NFEV, prepared[e], False, REFINE_TOL)): e for e in wave}
                for fut in list(again):
                    e, res = again[fut], result(fut)
                    res.pop("prepared")
                    entry, vals = judge(prob, hold_mask, hold_before, res, rnd, fit_before)
                    old = results[e][0]
                    entry = {**entry, "stage": "fit", "refined": {"tol": REFINE_TOL, "lr_statistic_before":
                                                                    old["lr_statistic"]}}
                    if "gradient" in old:
                        entry["gradient"] = old["gradient"]
                    results[e] = (entry, vals)
                    refined.add(e)
                best = best_of(refined)
            for e in near:
                if e not in refined:
                    entry = results[e][0]
                    entry["refined"] = {"tol": None, "skipped": (
                        f"not refined: rejected at {CANDIDATE_TOL:g} with a held-out cost change of "
                        f"{-100 * entry['held_out_gain']:+.1f} % against {best['effect']}'s "
                        f"{-100 * best['held_out_gain']:+.1f} % (out of reach: REFINE_REACH)")}
            for k, e in enumerate(to_fit, 1):
                say(f"  [{k}/{len(to_fit)}] " + _judged(results[e][0], "fit"))
            # (a screen that passes the test is above SCREEN_SHARE: only converged fits are accepted)
            if not selected and not any(entry["accepted"] for entry, _ in results.values()):
                by_innovations_alone(prob, hold_mask, current, results, say)
            if selected:
                # a further effect is judged against the model of the effects already selected
                # refitted in full from where its fit ended, not against that model as it stood
                cur_cost = float(np.mean(residuals(prob, current) ** 2))
                for e, (entry, vals) in list(results.items()):
                    if not entry["accepted"]:
                        continue
                    new, new_vals, null = against_refitted(prob, hold_mask, hold_before, selected, entry, vals, rnd,
                                                      fit_before)
                    results[e] = (new, new_vals)
                    say(f"  {e} against {', '.join(selected)} refitted in full from where its fit ended: held-out "
                        f"cost change {-100 * new['held_out_gain']:+.1f} % (LR {new['lr_statistic']:.1f} vs "
                        f"{new['threshold']:.1f}"
                        + (f"; on the fit blocks {new['fit_lr_statistic']:.1f}" if "fit_lr_statistic" in new else "")
                        + ") -> " + ("accepted" if new["accepted"] else "rejected"))
                    if null.cost < cur_cost:
                        # the selected effects fit better from there: the next round (or the final
                        # refit) starts from the better fit, whatever becomes of the candidate
                        better_null, cur_cost = {**current, **null.values}, null.cost
            candidates += [entry for entry, _ in results.values()]
            last_fits.update({e: r for e, r in results.items() if r[0]["stage"] == "fit"})
            accepted = [r for r in results.values() if r[0]["accepted"]]
            rounds.append({"round": rnd, "held_out_cost_before": hold_before,
                           "accepted": [e["effect"] for e, _ in accepted]})
            if not accepted:
                if better_null is not None:
                    current = better_null
                break
            if any(e.get("accepted_by") == "innovations" for e, _ in accepted):
                entry, vals = max(accepted, key=lambda r: r[0]["innovations"]["lr_statistic"])
            else:
                entry, vals = min(accepted, key=lambda r: r[0]["held_out_cost_after"])
            # rivals the held-out free run does not tell from the chosen one: the likelihood of the
            # filter's innovations decides where it tells them apart (by_innovations)
            told: dict[str, dict] = {}
            for rival, r_vals in sorted(accepted, key=lambda r: r[0]["held_out_cost_after"]):
                if rival is entry or distinct(entry, rival)["distinct"]:
                    continue
                test = by_innovations(prob, hold_mask, vals, r_vals)
                say(f"  {entry['effect']} against {rival['effect']} by the innovations' likelihood on the held-out "
                    f"blocks: LR {test['lr_statistic']:+.1f} (beyond ±{test['threshold']:.1f} tells them apart)")
                if test["distinct"] and test["lr_statistic"] < 0:
                    # the rival is the likelier: it is chosen, and the two are told apart
                    told = {entry["effect"]: {**test, "lr_statistic": -test["lr_statistic"]}}
                    entry, vals = rival, r_vals
                elif test["distinct"]:
                    told[rival["effect"]] = test
            entry["selected"] = True
            for rival, _ in accepted:
                if rival is entry:
                    continue
                test = told.get(rival["effect"]) or distinct(entry, rival)
                rival["against_chosen"] = test
                if not test["distinct"]:
                    entry.setdefault("indistinguishable_from", []).append(rival["effect"])
                    say(f"  {entry['effect']} and {rival['effect']} fit the held-out blocks alike (LR "
                        f"{test['lr_statistic']:.1f}, at least {test['threshold']:.1f} to tell them apart): "
                        "the record does not tell which")
            selected.append(entry["effect"])
            # the model of the next round, fitted to convergence: else a candidate of the next round
            # is credited with what merely finishing this fit gains
            parts: list[Parameterization] = [BASELINE, *(CATALOGUE[e] for e in selected)]
            conv = fit(prob.with_base(vals), parts, [p.to_coords(vals) for p in parts], max_nfev=100)
            current = {**vals, **conv.values}
            say(f"round {rnd}: added {entry['effect']}")
    finally:
        for p in pools:
            p.shutdown()
    return Search(selected, current, candidates, rounds)


def _search_bound_params(values: Mapping[str, float]) -> list[str]:
    """Calibrated parameters within :data:`~.verdict.ON_BOUND` of a search bound (as
    :func:`~.verdict.on_bounds` names them, physical limits aside)."""
    text = on_bounds(values)[0]
    return [c.name for c in BASELINE.coords if any(t.startswith(f"{c.name} = ") for t in text)]


def retry_on_bounds(prob: Problem, found: Search, effects: Sequence[str], hold_mask: np.ndarray,
                    say: Say) -> Search | None:
    """A model whose calibrated parameter ends on a search bound (say the D/A offset ``u_0``
    that absorbed a current limit and ran to 1 V) is refitted from other starts before the
    calibration may be called failed: the baseline from where its calibration started, and the
    model's values with the parameters on a bound reset there; each with the selected effects
    alone, and with each other candidate effect present (its starts placed anew). Among the fits
    that leave every search bound, the selected effects alone are kept unless a candidate passes
    the acceptance test against them on the held-out blocks. None when nothing leaves the bounds."""
    names = _search_bound_params(found.values)
    if not names:
        return None
    say(f"the model's calibration ended on a bound ({', '.join(names)}): refitting from other starts, "
        "with each candidate effect present")
    origin = {p: prob.base[p] for p in BASELINE.params}
    starts = [{**found.values, **origin}, {**found.values, **{n: origin[n] for n in names}}]
    parts: list[Parameterization] = [BASELINE, *(CATALOGUE[e] for e in found.selected)]
    alone: dict | None = None
    for st in starts:
        f = fit(prob.with_base(st), parts, [p.to_coords(st) for p in parts], max_nfev=100)
        vals = {**st, **f.values}
        if not on_bounds(vals)[0]:
            hold = cost_on(prob, vals, hold_mask)
            if alone is None or hold < alone["hold"]:
                alone = {"values": vals, "hold": hold}
    hold_before = alone["hold"] if alone else cost_on(prob, found.values, hold_mask)
    best: tuple[dict, dict] | None = None
    for e in effects:
        if e in found.selected:
            continue
        for st in starts:
            res = fit_candidate(prob, st, e)
            if on_bounds(res["values"])[0]:
                continue
            entry, vals = judge(prob, hold_mask, hold_before, res, len(found.rounds) + 1)
            entry["retry"] = True
            say(f"  {e} from another start: {', '.join(f'{p} = {v:.4g}' for p, v in entry['parameters'].items())}; "
                f"held-out cost change {-100 * entry['held_out_gain']:+.1f} % -> "
                + ("accepted" if entry["accepted"] else "rejected"))
            found.candidates.append(entry)
            if entry["accepted"] and (best is None or entry["held_out_cost_after"] < best[0]["held_out_cost_after"]):
                best = (entry, vals)
    if best is not None:
        entry, vals = best
        entry["selected"] = True
        selected = [*found.selected, entry["effect"]]
        parts = [BASELINE, *(CATALOGUE[e] for e in selected)]
        conv = fit(prob.with_base(vals), parts, [p.to_coords(vals) for p in parts], max_nfev=100)
        say(f"added {entry['effect']}, whose fit leaves the calibration inside its bounds")
        found.rounds.append({"round": entry["round"], "held_out_cost_before": hold_before,
                             "accepted": [entry["effect"]], "retry": True})
        return Search(selected, {**vals, **conv.values}, found.candidates, found.rounds)
    if alone is not None:
        say("the selected effects, from another start, leave the calibration inside its bounds")
        return Search(list(found.selected), alone["values"], found.candidates, found.rounds)
    return None


# ----------------------------------------------------------------------------- 3. refit

def uncertainty(prob: Problem | Sequence[Problem], values: Mapping[str, float],
                steps: Mapping[str, float]) -> dict[str, float]:
    """1-sigma standard errors of the parameters in ``steps`` (each with its typical size) from the
    Jacobian at the solution, inflated by N/N_eff for the residual's autocorrelation; several
    problems: records calibrated together (:func:`~.problem.stacked`)."""
    names = list(steps)
    x = np.array([values[n] for n in names])
    sc = np.array([steps[n] for n in names])
    # each record's y and u errors are autocorrelated differently: the inflation is the largest
    # N/N_eff among those pieces (one record: its y half and its u half)
    at = {**values, **dict(zip(names, x))}
    parts = [residuals(p, at) for p in ([prob] if isinstance(prob, Problem) else prob)]
    r0 = np.concatenate(parts)
    jac = parameter_columns(lambda v: stacked(prob, v), at, steps, r0, map_fn=thread_map)
    pieces = [half for r in parts for half in (r[:len(r) // 2], r[len(r) // 2:])]
    inflation = max(len(q) / max(effective_samples(q), 1.0) for q in pieces)
    s2 = float(np.sum(r0**2)) / max(len(r0) - len(names), 1)
    try:
        cov = np.linalg.pinv(jac.T @ jac) * s2 * inflation
    except np.linalg.LinAlgError:
        return {n: math.nan for n in names}
    return {n: float(math.sqrt(max(cov[k, k], 0.0)) * sc[k]) for k, n in enumerate(names)}


#: An effect whose refitted parameter lies within this many standard errors of switching it off
#: (:meth:`~.effects.Effect.distance_from_off`) leaves the model: the held-out blocks credited it
#: with a gain, but the whole record does not tell it from its absence. (Project emulator, seed
#: 4101: a current limit active in 75 % of the samples, found at i_max 0.754 A for 0.754, with a
#: sensor bend k_x2 = -851 ± 1915 V/m² beside it, the model at 0.99 times the true model's error.
#: Until 2026-11-27 the first effect was exempt, as it had passed against the baseline; on the
#: project emulator's no-effect record of seed 4501, with a drifting force of 0.19 % of the weight,
#: the innovations' test took a force exponent n_F = 2.080 ± 0.061, 1.3σ from Eq. 8's 2, and the
#: verdict was `explained in part`. 2σ until 2026-11-27, 3σ since, nearer the 1 - 0.001 level of the
#: held-out test (3.3σ for one parameter): on the project emulator's seed 4701 of benchmark seeds 4700,
#: a delay of 0.35 ± 0.13 ms (2.7σ) stayed beside a limit active in 76 % of the samples, where none
#: was planted. Over the benchmark blocks of seeds 4100-4700 no other selected effect lay between 2σ
#: and 4σ of off but the independent emulator's own 0.3 ms delay found as a force lag (3.2σ and 4.0σ).)
MIN_EFFECT_SIGMA = 3.0


def refit(prob: Problem, current: dict[str, float], selected: list[str], say: Say) -> tuple[dict, dict]:
    """The final model refitted on the whole record: its values and their uncertainties. An
    effect the refit turns off (:meth:`~.effects.Effect.is_off`) leaves the model (``selected``
    is updated in place) and the rest is refitted without it; so does an effect whose parameter
    lies within :data:`MIN_EFFECT_SIGMA` standard errors of off, and one that no longer acts (the
    model's free run without it is the same, sample for sample). Where the k-step fit that ends a
    free-run refit (:func:`_kstep_ridge`, :func:`_kstep_screened`) took an effect there and the free
    run's fit did not, the effect leaves where the free run refitted without it still follows ``y``
    by :data:`FREE_RUN_MIN_FIT` (:data:`KSTEP_OFF_LEAVES`); elsewhere the free run's values are kept.
    So does an effect the k-step fit took across off, to the other side from the free run's fit
    (:data:`KSTEP_CROSSING_LEAVES`)."""
    def without(effects: Sequence[str]) -> tuple[dict, dict]:
        nonlocal current
        for e in effects:
            selected.remove(e)
            current = turned_off(prob, e, current)
        return _refit(prob, current, selected, say)[:2]

    def off(values: dict) -> list[str]:
        return [e for e in selected if CATALOGUE[e].is_off(values)]

    def faint(values: dict, unc: dict) -> list[tuple[str, float]]:
        return [(e, z) for e in selected for z in [CATALOGUE[e].distance_from_off(values, unc)]
                if z is not None and z < MIN_EFFECT_SIGMA]

    def idle(values: dict) -> list[str]:
        # effects that no longer act: a limit the refit moved above every current the model's free
        # run reaches (the independent emulator's 2 ms force lag of seed 7200, its PID's derivative of
        # the reading: a current limit accepted at 0.870 A on held-out blocks, which the k-step refit
        # moved to 0.909 A, above the free run's peak, sigma 0: a second effect in name only)
        y = prob.free_run(values)["y"]
        return [e for e in selected if np.array_equal(prob.free_run(turned_off(prob, e, values))["y"], y)]

    def gone(values: dict, unc: dict) -> list[str]:
        return list(dict.fromkeys([*off(values), *(e for e, _ in faint(values, unc))]))

    def crossed(values: dict, free: dict | None) -> list[str]:
        # effects the k-step fit took to the other side of off from the free run's fit
        if free is None or not KSTEP_CROSSING_LEAVES:
            return []
        return [e for e in selected if any((float(free[p]) - o) * (float(values[p]) - o) < 0
                                           for p, o in CATALOGUE[e].off_values.items() if p in free and p in values)]

    values, unc, free = _refit(prob, current, selected, say)
    flipped = crossed(values, free)
    if flipped:
        say(f"the k-step fit took {', '.join(flipped)} to the other side of off from the free run's fit ("
            + ", ".join(f"{p} {free[p]:.4g} -> {values[p]:.4g}" for e in flipped for p in CATALOGUE[e].off_values)
            + "): the effect stands in for something else, and is judged as one the k-step fit took off")
    if free is not None and (gone(values, unc) or flipped):
        # the k-step fit polishes the effects the search found on held-out blocks; it does not remove
        # them. Where it took one to (or within noise of) off, the effect is judged at the free run's
        # fit instead. On the project emulator's current limit of seed 5401 (benchmark seeds 5400,
        # active in 28 % of the samples, accepted at LR 1227) the k-step fit, 20 % lower, left it
        # within 0.3σ of off; refitted without it, the free run fell to -10.8 % and the search in
        # prediction mode took a Coulomb friction first, then the limit 12 % high: `explained` at 3.0
        # times the true model's 20 ms error.
        unc_free = _uncertainties(prob, current, selected, free)
        if not gone(free, unc_free):
            dropped = list(dict.fromkeys([*gone(values, unc), *flipped]))
            kept = True
            if KSTEP_OFF_LEAVES and prob.noise is None:
                # Only where the free run needs them: refitted without them, a free run that still
                # follows the record (FREE_RUN_MIN_FIT) lets them go
                saved = (list(selected), current)
                v2, u2 = without(dropped)
                fit_y = nrmse_fit(prob.rec.y, prob.free_run(v2)["y"])
                if fit_y >= FREE_RUN_MIN_FIT:
                    say(f"the k-step fit left {', '.join(dropped)} off, within {MIN_EFFECT_SIGMA:g}σ of off or across it, and "
                        f"without {'them' if len(dropped) > 1 else 'it'} the free run still follows y by {fit_y:.1f} % "
                        f"(at least {FREE_RUN_MIN_FIT:.0f} %): {'they leave' if len(dropped) > 1 else 'it leaves'} the model")
                    values, unc, kept = v2, u2, False
                else:
                    selected[:], current = saved
                    say(f"without {', '.join(dropped)} the free run follows y by only {fit_y:.1f} %")
            if kept:
                say(f"the k-step fit left {', '.join(dropped)} off, within {MIN_EFFECT_SIGMA:g}σ of off or across it, "
                    "the free run's fit does not: the free run's values are kept")
                values, unc = free, unc_free
    dropped = off(values)
    if dropped:
        say(f"the refit turned {', '.join(dropped)} off: refitting without it")
        values, unc = without(dropped)
    dropped = idle(values)
    if dropped:
        say(f"the refit left {', '.join(dropped)} without action (the model's free run is the same without it): "
            "refitting without it")
        values, unc = without(dropped)
    # One at a time, the faintest first, each refit judged again: two effects that trade against each
    # other (a lag and its twin, split by the search) each stand within a few σ of off beside the
    # other, though the pair is far from it. On the emulator's slewing amplifier of test_diagnose
    # (seed 5) an amplifier lag and a force lag split from it stood at 2.4σ and 2.7σ; both left, and
    # the baseline refitted on the whole record followed u 0.04 % worse than the calibrated one.
    weak = faint(values, unc)
    while weak:
        e, z = min(weak, key=lambda t: t[1])
        say("the refit leaves " + ", ".join(f"{w} within {zw:.1f}σ of off" for w, zw in weak)
            + f" (at least {MIN_EFFECT_SIGMA:g}σ needed): refitting without {e}, the faintest")
        values, unc = without([e])
        weak = faint(values, unc)
    return values, unc


def _uncertainties(prob: Problem, current: dict[str, float], selected: Sequence[str], values: dict) -> dict:
    """The standard errors of the final model's ``values`` on the whole record (:func:`uncertainty`)."""
    parts: list[Parameterization] = [BASELINE, *(CATALOGUE[e] for e in selected)]
    whole = prob.with_base(current).with_mask(np.ones(prob.rec.n, bool))
    steps = {k: v for p in parts for k, v in p.uncertainty_scales().items()}
    return uncertainty(whole, values, steps)


def _refit(prob: Problem, current: dict[str, float], selected: Sequence[str], say: Say
           ) -> tuple[dict, dict, dict | None]:
    """The final model's values on the whole record and their uncertainties, and in free-run mode
    the free run's fit where the k-step fit then took other values (else None)."""
    say(f"refitting the final model ({', '.join(selected) or 'baseline only'}) on the whole record")
    whole = prob.with_base(current).with_mask(np.ones(prob.rec.n, bool))   # values besides the fitted ones stay
    parts: list[Parameterization] = [BASELINE, *(CATALOGUE[e] for e in selected)]
    final = fit(whole, parts, [p.to_coords(current) for p in parts], max_nfev=40)
    values = {**current, **final.values}
    if prob.noise is not None:
        # Prediction mode: polish by the prediction-error criterion proper (one-step errors, the
        # disturbances re-estimated for the model at hand): near instability the k-step fit leaves
        # the parameters a little off, and the loop's ringing magnifies such errors.
        say("polishing by the one-step prediction error (PEM), disturbances re-estimated")
        pem = replace(whole, noise=whole.disturbances(values), horizon_s=prob.rec.ts, stride=1)
        pem = _weighted(pem, values)
        final = fit(pem, parts, [p.to_coords(values) for p in parts], max_nfev=30)
        values = {**values, **final.values}
        # The verdict judges the k-step prediction through the final model's own disturbance
        # estimate: the refit ends on that criterion, the disturbances re-estimated for the polished
        # model (the k-step fit above used those of the free-run search's model). On the benchmark's
        # 3 ms amplifier lag of seed 2001, whose loop sits at its limits in 45 % of the samples, the
        # polished model (T_a 2.94 ms, u_0 9 mV) left 1.29 times the true model's 20 ms error; this
        # fit, 0.97 times (T_a 2.98 ms, u_0 6 mV). (In free-run mode a k-step end for every model was tried,
        # gated by a gain of 3 %, and left: it turned 3 of 12 no-effect records of seeds 3300 from
        # `no effect` to `unexplained`, a 7.4 % k-step gain of the baseline alone whose disturbance
        # estimate then fell to a 0.25 Hz corner, 2.0 times off the floor it implies. Now a model with
        # an absorbed effect gets it (_kstep_ridge), and any other where its Gauss-Newton step promises
        # much (_kstep_screened); either is taken only where it predicts better through its own
        # disturbance estimate.)
        say("refitting by the k-step prediction, the disturbances re-estimated for the polished model")
        kstep = _weighted(replace(whole, noise=whole.disturbances(values)), values)
        final = fit(kstep, parts, [p.to_coords(values) for p in parts], max_nfev=40)
        values = {**values, **final.values}
    free = None
    if prob.noise is None:
        free = values
        values = (_kstep_ridge if any(CATALOGUE[e].absorbed_by for e in selected) else _kstep_screened)(
            whole, parts, values, say)
    say("estimating parameter uncertainties")
    kept_free = free if free is not None and values != free else None
    if kept_free is not None and nrmse_fit(prob.rec.y, whole.free_run(values)["y"]) < FREE_RUN_MIN_FIT:
        # values the k-step fit took whose free run does not follow the record: the free run's
        # Jacobian there says nothing of them, and their standard errors are those of the criterion
        # they minimise (the k-step prediction through their own disturbance estimate). On the project
        # emulator's limit of seed 5401 (active in 28 % of the samples) the k-step fit found i_max
        # 0.676 A for 0.685 (the free run 0.620), and the free run at those values, which loses the
        # ball (fit -10.9 %), gave sigma(i_max) = 3.0 A: the limit was judged within 0.3 sigma of off
        # and the free run's 9 % low value kept. (Where the free run follows the record, its
        # standard errors stay: on the limit of seed 6501, benchmark seeds 6500, active in 74 % of the
        # samples, the k-step's own kept a spurious friction of 0.1 mN beside it, which the free
        # run's put within 3 sigma of off.) The model whose free run fails is searched again in
        # prediction mode (FREE_RUN_MIN_FIT), whose standard errors are the k-step's too.
        kstep = _kstep_problem(whole, values)
        return values, _uncertainties(kstep, current, selected, values), kept_free
    return values, _uncertainties(prob, current, selected, values), kept_free


#: Whether an effect that the k-step fit of a free-run refit takes to (or within 3σ of) off leaves
#: the model where the free run refitted without it still follows the record (:data:`FREE_RUN_MIN_FIT`).
KSTEP_OFF_LEAVES = True
#: Whether an effect that the k-step fit takes across off, to the other side from the free run's fit
#: (a signed parameter whose sign flips: a sensor bend, a force exponent's departure from 2, a
#: drift), is judged as one the k-step fit took off (:data:`KSTEP_OFF_LEAVES`). Two fits of one
#: model to one record that disagree on the sign of an effect do not find it; it stands in for
#: something else. On the independent emulator's 2 ms force lag of seed 6800 (benchmark seeds 6800;
#: no sensor bend planted, the emulator's own 0.3 ms delay beside the lag) the search took a bend
#: k_x2 = -1097 V/m² at held-out cost -14.6 %, which the k-step fit (taken, -21.9 %) turned to
#: +1181 ± 290: the bend stayed at 4σ from off, a spurious second effect.
KSTEP_CROSSING_LEAVES = True


#: The share by which the k-step prediction's cost must fall for :func:`_kstep_ridge` to take its
#: values: any fall (the k-step fit starts from the free run's values, so it never rises). The
#: prediction error, which follows the measured past, is the consistent criterion where a random force
#: acts in closed loop; the free run's ridge point is biased by it. Until 2026-11-27 the fit was taken
#: from a 10 % fall only. Seeds 4400 (limits only, 6 per emulator, 2026-11-27) and the misses of seeds
#: 4300 decided it: on the project emulator, limits of 0.664 A (active in 58 % of the samples) and 0.716 A
#: (46 %) that the free run had put at +5.2 % and +7.5 % (x_0 0.36 and 0.46 mm high, u_0 +0.12 and
#: +0.18 V) came to +0.2 % and +1.7 % by the k-step fit, which gained 6.3 % and 3.4 %; on the
#: independent emulator a 0.615 A limit (46 %), +5.1 %, came to +3.1 % (1.7 %). Of the nine limits
#: the free run had within 5 % none left it (at most +2.3 %); force exponents n_F = 3 (seeds
#: 4400-4402) came from 2.993 / 2.993 / 2.910 to 3.018 / 3.003 / 2.926. Not mended by it: the
#: independent emulator's 0.662 A limit active in 47 % of the samples (seed 4403), where the k-step
#: fit (a 13 % fall, taken by either rule) ends at +5.2 % with x_0 0.29 mm high and u_0 +0.11 V.
KSTEP_RIDGE_GAIN = 0.0


def _kstep_ridge(whole: Problem, parts: Sequence[Parameterization], values: dict[str, float], say: Say) -> dict:
    """A free-run model with an effect the baseline can absorb, fitted again on the k-step
    prediction (the disturbances estimated for it), and taken when that fit lowers the k-step cost
    by more than :data:`KSTEP_RIDGE_GAIN`, ends on no bound, and its values, through the disturbances
    estimated for them, still lower it (the verdict judges each model through its own estimate: on
    the project emulator's seed 4802 the fit's values took a 0.39 Hz random force, under which they
    predicted 20 ms ahead at 1.63 times the true model's error). Such an effect trades against the
    parameters that absorb it (a limit's force ``k_c·i_max²``): where the loop sits on the limit
    most of the time, the free run, which loses the ball for a few ms now and then, settles anywhere
    along that ridge, and the k-step prediction, which follows the measured past, tells the points
    of the ridge apart. On the
    project emulator's limit active 61 % of the samples (seed 3202), the free-run refit ended at
    i_max 0.707 A for 0.736 A, 1.64 times the true model's 20 ms error, with the verdict `explained`."""
    # the disturbances on the fits' substeps, as the verdict estimates them: the estimate of the model
    # this returns is then the verdict's own (kept, not made again)
    kstep = _kstep_problem(whole, values)
    before = float(np.mean(residuals(kstep, values) ** 2))
    f = fit(kstep, parts, [p.to_coords(values) for p in parts], max_nfev=40)
    gain = 1.0 - f.cost / before if before > 0 else 0.0
    new = {**values, **f.values}
    taken = gain > KSTEP_RIDGE_GAIN and not on_bounds(new)[0]
    why = "on a bound" if gain > KSTEP_RIDGE_GAIN else "no fall"
    own_gain = None
    if taken:
        # the verdict judges the model through the disturbances estimated for it: the fit is taken
        # only where its values, through their own estimate, still predict better than the free
        # run's through theirs
        own = replace(kstep, noise=whole.disturbances(new, fit_steps=True))
        own_gain = 1.0 - float(np.mean(residuals(own, new) ** 2)) / before if before > 0 else 0.0
        taken = own_gain > KSTEP_RIDGE_GAIN
        why = "worse through its own disturbance estimate"
    say(f"refitting by the k-step prediction: cost {-100 * gain:+.1f} %"
        + (f", {-100 * own_gain:+.1f} % through its own disturbance estimate" if own_gain is not None else "")
        + " -> " + ("taken" if taken else f"kept the free-run fit ({why})"))
    return new if taken else values


#: The fall of the k-step cost that the Gauss-Newton step of its Jacobian must promise for a free-run
#: model without an absorbed effect to be fitted again on the k-step prediction
#: (:func:`_kstep_screened`). A loop that an effect brings near its stability limit makes the free
#: run sensitive to small parameter errors, and the free-run fit may settle on parameters that
#: predict poorly: on the project emulator's seed 5000 (benchmark seeds 5000; a quiet record, sensor
#: noise 1.2e-4 MU) a 3 ms amplifier lag was found at 3.09 ms with x_0 0.06 mm low and k_FV 0.038 for
#: 0.03, `explained` at 4.6 times the true model's 20 ms error; the k-step fit lowered that cost by
#: 85 % (through its own disturbance estimate too). Models the free run fitted right promised 0.2 to
#: 11 % (seeds 4900 and 5000, the 12 s record of ``maglev-cosim bench``).
KSTEP_SCREEN_GAIN = 0.2


def _kstep_screened(whole: Problem, parts: Sequence[Parameterization], values: dict[str, float], say: Say) -> dict:
    """:func:`_kstep_ridge` for a free-run model without an absorbed effect, where the Gauss-Newton
    step of the k-step cost's Jacobian (differences over the fitted parameters at their uncertainty
    scales, the disturbances estimated for the model) promises a fall of at least
    :data:`KSTEP_SCREEN_GAIN`; else the free run's values."""
    # the disturbances on the fits' substeps, as the verdict estimates them (the same estimate, kept)
    kstep = _kstep_problem(whole, values)
    scales = {k: v for p in parts for k, v in p.uncertainty_scales().items()}
    r0 = residuals(kstep, values)
    jac = parameter_columns(lambda v: residuals(kstep, v), values, scales, r0, map_fn=thread_map)
    step = np.linalg.lstsq(jac, -r0, rcond=None)[0]
    promised = 1.0 - float(np.sum((r0 + jac @ step) ** 2)) / max(float(np.sum(r0 ** 2)), 1e-300)
    if promised < KSTEP_SCREEN_GAIN:
        say(f"the k-step prediction's Gauss-Newton step promises {100 * promised:.1f} % (a refit needs "
            f"{100 * KSTEP_SCREEN_GAIN:.0f} %): the free-run fit stays")
        return values
    say(f"the k-step prediction's Gauss-Newton step promises {100 * promised:.1f} %: the free run may have "
        "settled on biased parameters")
    return _kstep_ridge(whole, parts, values, say)


# ----------------------------------------------------------------------------- 4. summarise

def summarise(rec: Record, after: dict[str, float], residual_after: dict, noise: dict[str, float],
              candidates: list[dict], rounds: list[dict]) -> dict:
    """What the final model leaves: its residual over the noise floor, periodic peaks, and the
    rounds where a rival effect explained nearly as much as the chosen one."""
    ratio_u = after["rms_u"] / noise["rms_u_from_sensor_noise"] if noise["rms_u_from_sensor_noise"] > 0 else None
    out = {
        "rms_y_over_sensor_noise": after["rms_y"] / noise["sigma_y"] if noise["sigma_y"] > 0 else None,
        "rms_u_over_noise_response": ratio_u,
        "peaks_left_u": [p for p in residual_after["peaks_u"] if p["prominence"] > 30],
        "ambiguous": [],
        "note": "",
    }
    for rnd in rounds:
        acc = sorted((c for c in candidates if c["round"] == rnd["round"] and c["accepted"]),
                     key=lambda c: -c["held_out_gain"])
        if len(acc) > 1 and acc[1]["held_out_gain"] > 0.8 * acc[0]["held_out_gain"]:
            out["ambiguous"].append({"round": rnd["round"], "chosen": acc[0]["effect"], "rival": acc[1]["effect"],
                                     "gains": [acc[0]["held_out_gain"], acc[1]["held_out_gain"]]})
    notes = []
    if out["peaks_left_u"]:
        notes.append("narrow spectral peaks remain in the u residual: something periodic is still unexplained")
    if ratio_u is not None and ratio_u > 1.1:
        notes.append(f"the u residual is {ratio_u:.2f} times what sensor noise alone explains: the final model "
                     "still lacks something (an effect outside the catalogue, or disturbances the record does "
                     "not show)")
    elif ratio_u is not None:
        notes.append(f"the u residual is {ratio_u:.2f} times what sensor noise alone explains")
    for a in out["ambiguous"]:
        notes.append(f"in round {a['round']} {a['rival']} explains nearly as much as {a['chosen']} (held-out "
                     f"reductions {100 * a['gains'][0]:.1f} % and {100 * a['gains'][1]:.1f} %): the choice is weak, "
                     "and an effect outside the catalogue with the same signature cannot be excluded")
    out["note"] = "; ".join(notes)
    return out


# ----------------------------------------------------------------------------- the whole

def run(rec: Record, *, effects: Sequence[str] | None = None, workers: int | None = None,
        progress: Say | None = None, start: Mapping[str, float] | None = None,
        searched: Callable[[Record], None] | None = None) -> Diagnosis:
    """Runs the stages on a CE152 record (:func:`maglev_cosim.diagnosis.diagnose` is the entry point).

    Parameters
    ----------
    rec : Record
        The closed-loop record.
    effects : sequence of str, optional
        The catalogue entries to consider (default: :data:`~.effects.DEFAULT_EFFECTS`, the
        catalogue but for the opt-in ``sensor_lag`` and ``amplifier_dead_zone``).
    workers : int, optional
        Processes for the candidate fits (default: 2, or 1 on a one-core machine).
    progress : callable, optional
        Called with a line of text at each step.
    start : mapping, optional
        Starting values of the calibrated parameters (default: the Eq. 14 fit of the record's
        settled segments where it has them, else the Section 3 values).
    searched : callable, optional
        Called once the last search has ended, with the record as the diagnosis reads it
        (:attr:`Diagnosis.diagnosed`): no worker process is forked after it, so that the caller may
        start threads of its own there (the black boxes of :mod:`.compare`).
    """
    # One BLAS thread per process: the candidate fits already keep every core busy, and BLAS
    # threads inside scipy's least squares would only compete with them for the cores.
    with threadpool_limits(limits=1):
        return _diagnose(rec, effects, workers, progress, start, searched or (lambda r: None))


def _unless_on_bounds(prob: Problem, found: Search, final_values: dict, unc: dict, effects: Sequence[str],
                      fit_mask: np.ndarray, say: Say) -> tuple[Search, dict, dict]:
    """The final model, retried from other starts (:func:`retry_on_bounds`) when its calibration
    ended on a search bound; kept as it is when the retry leaves no bound either."""
    if not _search_bound_params(final_values):
        return found, final_values, unc
    again = retry_on_bounds(prob, replace(found, values={**found.values, **final_values}), effects, ~fit_mask, say)
    if again is None:
        return found, final_values, unc
    values, unc2 = refit(prob, again.values, again.selected, say)
    if _search_bound_params(values):
        return found, final_values, unc
    return again, values, unc2


def _diagnose(rec: Record, effects: Sequence[str] | None, workers: int | None, progress: Say | None,
              start: Mapping[str, float] | None, searched: Callable[[Record], None]) -> Diagnosis:
    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    effects = list(DEFAULT_EFFECTS) if effects is None else list(dict.fromkeys(effects))   # each tried once
    for e in effects:
        if e not in CATALOGUE:
            raise ValueError(f"unknown effect {e!r}: choose from {', '.join(CATALOGUE)}")
    workers = workers or min(2, os.cpu_count() or 1)
    # a record whose u its controller did not make (swapped columns) fails at once; a PID that ran in
    # another form than the declared one (its derivative's): every stage replays the form that ran
    rec, _ = identified(rec, say)
    base = baseline_params()
    base.update({k: float(v) for k, v in (static_start(rec, base, say) if start is None else start).items()})
    fit_mask = fit_blocks(rec.t)

    cal = calibrate(rec, base, fit_mask, say)
    found = search(cal.prob, dict(cal.values), effects, ~fit_mask, workers, say)
    # The calibrated baseline's disturbances, which the verdict compares with the final model's, are
    # estimated on a thread of their own while the final model is refitted: the estimate is a
    # Nelder-Mead search of one replay at a time, as is the final model's in the refit's k-step
    # screen, so the two take a core each (the verdict then finds both kept, replay.estimate_noise).
    # No worker process is forked while the thread runs: a search in prediction mode waits for it.
    with ThreadPoolExecutor(max_workers=1) as side:
        noise_before = side.submit(estimate_noise, rec, on_fit_steps({**base, **cal.values}), coloured=False)
        final_values, unc = refit(cal.prob, found.values, found.selected, say)
        found, final_values, unc = _unless_on_bounds(cal.prob, found, final_values, unc, effects, fit_mask, say)
        sim_after = cal.prob.free_run(final_values)
        fit_y = nrmse_fit(rec.y, sim_after["y"])
        if fit_y < FREE_RUN_MIN_FIT:
            noise_before.result()
    if fit_y < FREE_RUN_MIN_FIT:
        # Even with what the search found, the free run cannot follow the record: search again on
        # the k-step prediction error, which stays meaningful when the loop rings.
        say(f"the final model's free run follows y by only {fit_y:.1f} % (below {FREE_RUN_MIN_FIT:.0f} %): "
            "searching again in prediction mode")
        cal = calibrate_by_prediction(rec, base, fit_mask, cal, say, found=final_values)
        found = search(cal.prob, dict(cal.values), effects, ~fit_mask, workers, say)
        final_values, unc = refit(cal.prob, found.values, found.selected, say)
        found, final_values, unc = _unless_on_bounds(cal.prob, found, final_values, unc, effects, fit_mask, say)
        sim_after = cal.prob.free_run(final_values)
    searched(rec)
    before, after = rms(rec, cal.sim), rms(rec, sim_after)
    residual_after = analyse_residual(rec, sim_after)
    noise = noise_floor(rec)
    unexplained = summarise(rec, after, residual_after, noise, found.candidates, found.rounds)
    final = {**base, **final_values}
    verdict = conclude(rec, {**base, **cal.values}, final, {"before": cal.sim, "after": sim_after}, found.selected,
                       found.candidates, say, fit_mask=fit_mask, noise_levels=noise)
    verdict.warnings.extend(twin_warnings(found.selected, effects))
    say(f"verdict: {verdict.verdict}; fit y/u free run {verdict.fit['free_run']['y']:.1f}/"
        f"{verdict.fit['free_run']['u']:.1f} %, {HORIZON_S * 1e3:.0f} ms prediction "
        f"{verdict.fit['prediction']['y']:.1f}/{verdict.fit['prediction']['u']:.1f} %")
    elapsed = time.perf_counter() - t0
    say(f"done in {elapsed:.1f} s: before rms_y {before['rms_y']:.5f} rms_u {before['rms_u']:.5f}; "
        f"after rms_y {after['rms_y']:.5f} rms_u {after['rms_u']:.5f}; selected: {found.selected or 'none'}")
    return Diagnosis(rec.path, before, after, found.selected, {k: float(v) for k, v in {**base, **final_values}.items()},
                     unc, found.candidates, {**base, **cal.values}, analyse_residual(rec, cal.sim), residual_after,
                     noise, found.rounds, elapsed,
                     sims={"raw": cal.raw, "before": cal.sim, "after": sim_after}, unexplained=unexplained,
                     record_warnings=list(rec.warnings), verdict=verdict, fit_mode=cal.prob.mode, diagnosed=rec)
