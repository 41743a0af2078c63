"""Runs the diagnosis on synthetic records and prints tables: the fixed matrix, and the
acceptance benchmark over the disturbance family (false-positive rate and power).

    .venv/bin/python scripts/diagnosis_matrix.py [--seed N] [--json FILE]          # the matrix (~2 min)
    .venv/bin/python scripts/diagnosis_matrix.py --family 50 [--power 5] [--seed N]  # the benchmark
    ... --emulator ivp    # either, on records of the independent emulator (maglev_cosim.records.emulator_ivp)

The matrix: each row the record's undeclared effect (from the rig emulator), what the diagnosis
selected, the estimates, and the RMS errors before and after.

The benchmark (``--family N``): N records with no effect, each with its own draw from the
disturbance family (``maglev_cosim.records.synth.FAMILY``: white or coloured force noise with corners
5 to 50 Hz at 0.1 to 1 % of the weight, a drifting force offset, sensor noise 1e-4 to 1.5e-3 MU,
10- to 14-bit converters, stable PID gains other than the paper's); the false-positive rate is
the share of them where any effect is selected. Then (``--power M``) each catalogue effect at
the matrix's magnitude on M of those draws: the power is the share where the planted effect is
selected, and "after / null" divides the after-error by what the same rig and seed leave without
the effect, by the free run and by the 20 ms prediction (which a loop near instability, whose
free run cannot follow the noise-driven ringing, is judged by). Then (``--limits L``,
``--friction F``, default as many as ``--power``) the kinds issue 22 adds: a current limit acting
in 1-60 % of the samples and Coulomb friction of 1-10 % of the weight (over 0.1-2 mm/s), drawn per record. The
checks of issue 22's done-when list close the run: false positives, power, spurious second
effects, `explained` beyond 1.2x the no-effect twin's error, friction and limits found.

``--write-docs`` writes the table into its section of docs/benchmarks.md (scripts/benchdoc.py),
one section per emulator for the matrix and for the benchmark.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections.abc import Sequence
from functools import partial
from pathlib import Path

import numpy as np

import benchdoc

from maglev_cosim.diagnosis import CATALOGUE, pipeline
from maglev_cosim.diagnosis.effects import DEFAULT_EFFECTS, TWINS
from maglev_cosim.diagnosis.replay import baseline_params, estimate_noise, predict
from maglev_cosim.plant.params import get_params
from maglev_cosim.records import emulator_ivp
from maglev_cosim.records.record import read_record
from maglev_cosim.records.synth import draw_disturbance, synth_record

#: The record writer: the rig emulator's, or with ``--emulator ivp`` the independent emulator's
#: (``maglev_cosim.records.emulator_ivp.synth_record``, same arguments; docs/diagnosis.md, "The independent emulator").
SYNTH = synth_record

#: With ``--cut``, each record begins this many samples after its first reference step at or after
#: :data:`CUT_AFTER_S` [s], re-timed from 0: a logger started while the ball flies
#: (maglev_cosim/records/settled.py), as records cut from a running loop come.
CUT_SAMPLES = 2
CUT_AFTER_S = 1.0


def cut_while_flying(synth, path: Path, **kw) -> Path:
    """``synth``'s record at ``path``, rewritten to begin :data:`CUT_SAMPLES` after its first reference
    step at or after :data:`CUT_AFTER_S` (its truth file, beside it, is the whole record's)."""
    out = synth(path, **kw)
    lines = out.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    cols = lines[head].split(",")
    it, iw = cols.index("t"), cols.index("w")
    rows = [line.split(",") for line in lines[head + 1:]]
    t = np.array([float(r[it]) for r in rows])
    w = np.array([float(r[iw]) for r in rows])
    steps = np.nonzero(np.diff(w) != 0)[0] + 1
    k = int(steps[t[steps] >= CUT_AFTER_S][0]) + CUT_SAMPLES
    digits = len(rows[0][it].split(".")[1]) if "." in rows[0][it] else 0
    for r in rows[k:]:
        r[it] = f"{float(r[it]) - t[k]:.{digits}f}"
    out.write_text("\n".join([*lines[:head + 1], *(",".join(r) for r in rows[k:])]) + "\n")
    return out


#: The catalogue cases of the power benchmark: each default entry at its example magnitude (the matrix's,
#: diagnosis/effects.py), but friction, which the family draws per record (``--friction``).
POWER_CASES: dict[str, dict] = {name: {name: dict(CATALOGUE[name].example)} for name in DEFAULT_EFFECTS
                                if name != "coulomb_friction"}

#: The kinds issue 22 adds to the family, drawn per record (log-uniform, from the record's seed):
#: a current limit acting in 1 to 60 % of the samples, bisected between the median and the peak of
#: the current of the same draw without the limit (:func:`_limit_for_share`); Coulomb friction of 1
#: to 10 % of the ball's weight, smoothed over 0.1 to 2 mm/s (the diagnosis fits the smoothing speed
#: ``v_c`` with the friction).
LIMIT_SHARE = (0.01, 0.60)
WEIGHT = get_params("section3").m_k * get_params("section3").g     #: the ball's weight [N]
FRICTION_SHARE = (0.01, 0.10)
FRICTION_SPEED = (1e-4, 2e-3)     #: [m/s]
#: The done-when figures of issue 22 that the benchmark checks (docs/diagnosis.md, "The acceptance benchmark").
TARGETS = {"the emulator's own computation delay found (as a delay or a lag)": "—", "false positives": "≤ 2 %", "power": "≥ 95 %", "spurious second effect": "≤ 2 %",
           "'explained' beyond 1.2× the true model's error": "0", "'explained' beyond 1.2× the no-effect twin's error": "–", "friction ≥ 2 % of the weight": "100 %",
           "current limit found, i_max within 5 %": "100 % (active in 1–60 % of the samples)"}


def _log_uniform(seed: int, salt: int, lo: float, hi: float) -> float:
    return float(np.exp(np.random.default_rng([seed, salt]).uniform(np.log(lo), np.log(hi))))


def _truth(path: Path) -> dict:
    return json.loads(Path(str(path) + ".truth.json").read_text())


def _limit_for_share(path: Path, seed: int, dist: dict, target: float, lo: float, hi: float, tries: int = 10,
                     within: tuple[float, float] | None = LIMIT_SHARE) -> tuple[float, float]:
    """The current limit i_max [A] at which the draw's record has the amplifier at its limit in about
    ``target`` of the samples, and the share it has there: bisection between ``lo`` and ``hi`` (the
    median and the largest current of the same draw without the limit), stopping within 0.8-1.25x of
    the target or after ``tries`` records. The share is not a quantile of the unlimited current: a limit near the current that
    holds the ball lets it fall, and the loop then sits on the limit. The share jumps there (from a
    few per cent to 75-90 % on seeds 6600), so many targets cannot be met; the limit returned is the
    one nearest the target among those whose share lies ``within`` (default :data:`LIMIT_SHARE`, the
    limits issue 22 asks about), the nearest of all only where none does (or ``within`` is None).
    Until 2026-11-28 it was the nearest of all, with 6 tries (``tries=6, within=None``): on seeds
    6600, 3 of 4 limits per emulator sat on the far side of the jump, and the criterion had 1 and 0
    records."""
    best, best_in = (hi, 0.0), None

    def off(share: float) -> float:
        return abs(np.log(max(share, 1e-4) / target))

    for _ in range(tries):
        i_max = 0.5 * (lo + hi)
        share = _truth(SYNTH(path, seed=seed, disturbance=dist,
                             effects={"current_saturation": {"i_max": i_max}}))["i_limited_share"]
        if off(share) < off(best[1]):
            best = (i_max, share)
        if within and within[0] <= share <= within[1] and (best_in is None or off(share) < off(best_in[1])):
            best_in = (i_max, share)
        if 0.8 * target <= share <= 1.25 * target:
            break
        lo, hi = (i_max, hi) if share > target else (lo, i_max)
    return best_in or best


def _label(name: str, values: dict[str, float]) -> str:
    """A matrix row's name: the effect and its planted values."""
    return f"{name} " + ", ".join(f"{k}={v:g}" for k, v in values.items())


#: Rows that try other entries than the default (DEFAULT_EFFECTS): each opt-in entry beside the default
#: ones, with its twin left out (docs/diagnosis.md), and the two lags with every entry tried.
TRIED: dict[str, list[str]] = {
    **{_label(name, e.example): [n for n in CATALOGUE if (n in DEFAULT_EFFECTS or n == name)
                                 and frozenset({n, name}) not in TWINS]
       for name, e in CATALOGUE.items() if name not in DEFAULT_EFFECTS},
    "sensor lag, all tried": list(CATALOGUE),
    "force lag, all tried": list(CATALOGUE),
}

CASES: list[tuple[str, dict]] = [
    ("none", {}),
    ("parameters only", {"params": {"k_c": 7.6e-6, "x_0": 0.0088, "k_FV": 0.02}}),
    # every catalogue entry at its example magnitude (diagnosis/effects.py)
    *((_label(name, e.example), {"effects": {name: dict(e.example)}}) for name, e in CATALOGUE.items()),
    ("sensor lag, all tried", {"effects": {"sensor_lag": {"T_y": 0.002}}}),
    ("force lag, all tried", {"effects": {"force_lag": {"T_F": 0.002}}}),
    ("delay 2ms + 50Hz", {"effects": {"delay": {"T_d": 0.002},
                                      "periodic_disturbance": {"A_d": 0.008, "f_d": 50.0, "phi_d": 0.0}}}),
    ("OUTSIDE slew 20A/s", {"effects": {"slew_rate": {"di_max": 20.0}}}),
    ("OUTSIDE ripple 20mV/0.5mm", {"effects": {"sensor_ripple": {"A_r": 0.02, "lambda_r": 5e-4}}}),
    ("square: delay 2ms", {"effects": {"delay": {"T_d": 0.002}}, "reference": "square"}),
    # a limit that bites for tens of ms after each step up: active in 2.6 % and 10 % of the samples
    ("square 0.6s: none", {"reference": "square", "period": 0.6}),
    ("square 0.6s: i_max=0.69", {"effects": {"current_saturation": {"i_max": 0.69}}, "reference": "square",
                                 "period": 0.6}),
    ("square 0.6s: i_max=0.66", {"effects": {"current_saturation": {"i_max": 0.66}}, "reference": "square",
                                 "period": 0.6}),
    ("sine: pickup 60Hz", {"effects": {"periodic_disturbance": {"A_d": 0.004, "f_d": 60.0, "phi_d": -2.0}},
                           "reference": "sine"}),
    ("gains 2.5/4/0.008: delay", {"effects": {"delay": {"T_d": 0.0015}}, "kp": 2.5, "ki": 4.0, "kd": 0.008}),
    ("gains 2.5/4/0.008: none", {"kp": 2.5, "ki": 4.0, "kd": 0.008}),
]


def _describe(dist: dict) -> str:
    colour = "white" if dist["tau_F_noise"] == 0 else f"{1 / (2 * 3.14159265 * dist['tau_F_noise']):.0f}Hz"
    return (f"sy={dist['sigma_y']:.1e} F={100 * dist['sigma_F_rel']:.2f}%/{colour} "
            f"drift={100 * dist['F_drift_rel']:.2f}% {dist['bits']}b "
            f"pid={dist.get('kp', 2):.2f}/{dist.get('ki', 2.97):.2f}/{dist.get('kd', 0.01):.4f}")


#: The effects the benchmark's diagnoses try (None: the default catalogue; ``--also`` adds to it).
FAMILY_EFFECTS: list[str] | None = None


EMULATOR_NAMES = {"rig": "the project's emulator (`maglev_cosim.records.emulator`)",
                  "ivp": "the independent emulator (`maglev_cosim.records.emulator_ivp`, written from the paper)"}


#: A delay found on a no-effect record is the emulator's own computation delay (below) when it lies
#: within 3 sigma of it, or within this share of it.
OWN_DELAY_TOL = 0.3


def _own_delay(path: Path, ts: float) -> float:
    """The delay a record's emulator puts in by itself [s]: the independent emulator's PID output
    reaches the D/A ``pid_offset`` of a sample late (its truth sidecar's settings); 0 for the
    project emulator. A ``delay`` found at that value on a no-effect record is a finding about the
    record, not a false positive, and the benchmark counts it apart."""
    return float(_truth(path).get("settings", {}).get("pid_offset", 0.0)) * ts


def true_prediction_y(rec, path: Path, planted: dict[str, dict[str, float]]) -> float:
    """The true model's 20 ms prediction error of y [MU] on a record: the emulator's plant (the
    baseline parameters, the planted effects, the emulator's own computation delay) under the
    disturbance model the diagnosis estimates for it, through the predictor the verdict uses
    (``replay.predict``). Issue 22's measure of "explained": the final model's error within 1.2x of it."""
    values = {**baseline_params(), **{p: v for e in planted.values() for p, v in e.items()}}
    own = _own_delay(path, rec.ts)
    if own > 0:
        values["T_d"] = values.get("T_d", 0.0) + own
    pr = predict(rec, values, estimate_noise(rec, values))
    ok = np.isfinite(pr["y_pred"])
    return float(np.sqrt(np.mean((rec.y[ok] - pr["y_pred"][ok]) ** 2)))


def is_own_delay(t_d: float, sigma: float, own: float) -> bool:
    """A delay found at the emulator's own computation delay ``own`` [s] (within 3 sigma, or
    :data:`OWN_DELAY_TOL` of it): a finding about the record, whether alone or beside a planted effect."""
    return bool(own > 0 and abs(t_d - own) <= max(3 * (sigma or 0.0), OWN_DELAY_TOL * own))


#: The effects that stand for the emulator's own delay when found at its value: a first-order lag of
#: T shifts the phase by atan(wT), a delay of T by wT, the same to within 1 % below w = 1/(6T) (about
#: 500 Hz for 0.3 ms, far above the loop's band), so at that size a lag in the force or the amplifier
#: and a delay are the same finding.
OWN_DELAY_TWINS = {"delay": "T_d", "force_lag": "T_F", "amplifier_lag": "T_a"}


def own_delay_effect(selected: Sequence[str], estimates: dict, sigma: dict, own: float) -> str | None:
    """The selected effect that is the emulator's own computation delay ``own`` [s]
    (:data:`OWN_DELAY_TWINS`, its time within :func:`is_own_delay` of it), or None."""
    for e in selected:
        p = OWN_DELAY_TWINS.get(e)
        if p and estimates.get(p) is not None and is_own_delay(estimates[p], (sigma or {}).get(p) or 0.0, own):
            return e
    return None


def extra_effects(row: dict) -> list[str]:
    """A spurious second effect: the effects beyond the first that a record with one planted effect
    ended with, the emulator's own delay (:func:`is_own_delay`) not counted; empty when it ended
    with one effect or none (a wrong single effect is a miss of the power count, not a second one)."""
    own = row.get("own_delay_s", 0.0)
    kept = [e for e in row["selected"]
            if e == row["effect"] or own_delay_effect([e], row.get("estimates_all", {}), row.get("sigma_all", {}), own) is None]
    if len(kept) < 2:
        return []
    return [e for e in kept if e != row["effect"]] if row["effect"] in kept else kept[1:]


def false_positives(null: list[dict]) -> int:
    """No-effect records where the diagnosis selected something other than the emulator's own delay."""
    return sum(bool(r["selected"]) and not r.get("own_delay_found", False) for r in null)


def family(n_null: int, n_power: int, seed0: int, tmp: Path, n_limit: int = 0, n_friction: int = 0) -> dict:
    """The acceptance benchmark: false positives on no-effect records, power on catalogue effects."""
    out: dict = {"null": [], "power": []}
    after_null: dict[int, dict[str, float]] = {}
    print(f"\nNo-effect records over the disturbance family ({n_null}):")
    print(f"{'seed':>6}  {'disturbance':<62}{'selected':<28}{'after y/u [MU]':<22}{'s':>5}")
    for k in range(n_null):
        seed = seed0 + k
        dist = draw_disturbance(seed)
        path = SYNTH(tmp / f"n{k}.csv", seed=seed, disturbance=dist)
        rec = read_record(path, plausibility="warn")
        t0 = time.perf_counter()
        d = pipeline.run(rec, effects=FAMILY_EFFECTS)
        dt = time.perf_counter() - t0
        after_null[seed] = {"free_run": d.after["rms_u"], "prediction": d.verdict.after.prediction_rms["u"],
                            "prediction_y": d.verdict.after.prediction_rms["y"],
                            "current_percentiles": _truth(path)["current_percentiles"]}
        est = {p: d.parameters[p] for e in d.selected for p in CATALOGUE[e].params}
        own = _own_delay(path, rec.ts)
        own_found = bool(len(d.selected) == 1 and own_delay_effect(d.selected, est, d.uncertainties, own))
        print(f"{seed:>6}  {_describe(dist):<62}{','.join(d.selected) or '-':<28}"
              f"{d.after['rms_y']:.5f}/{d.after['rms_u']:.5f}   {dt:5.1f}  {d.verdict.verdict} "
              f"(share {100 * d.verdict.predictable_share['after']:.1f} %)"
              + (f"; {d.selected[0]} {1e3 * est[OWN_DELAY_TWINS[d.selected[0]]]:.3f} ms: the emulator's own "
                 f"{1e3 * own:.2f} ms" if own_found else ""),
              flush=True)
        out["null"].append({"seed": seed, "disturbance": dist, "selected": d.selected, "after": d.after,
                            "seconds": dt, "warnings": rec.warnings, "verdict": d.verdict.verdict,
                            "predictable_share": d.verdict.predictable_share["after"], "estimates": est,
                            "sigma": {p: d.uncertainties.get(p) for p in est}, "own_delay_s": own,
                            "own_delay_found": own_found})
    fp = false_positives(out["null"])
    if n_power:
        print(f"\nCatalogue effects on the first {n_power} draws:")
        print(f"{'effect':<22}{'seed':>6}  {'selected':<40}{'after/null u: free run':>23}{'20 ms ahead':>12}{'s':>6}")
    cases = [(name, seed0 + k, planted) for name, planted in POWER_CASES.items() for k in range(n_power)]
    for k in range(n_limit):
        seed = seed0 + k
        share = _log_uniform(seed, 2201, *LIMIT_SHARE)
        pct = after_null[seed]["current_percentiles"]
        # the row names the share the record has (the draw's target may lie beyond the share's jump)
        i_max, got = _limit_for_share(tmp / "limit.csv", seed, draw_disturbance(seed), share, pct[50], pct[100])
        cases.append((f"current limit {100 * got:.0f} % (drawn {100 * share:.0f} %)", seed,
                      {"current_saturation": {"i_max": i_max}}))
    for k in range(n_friction):
        seed = seed0 + k
        frac = _log_uniform(seed, 2202, *FRICTION_SHARE)
        v_c = _log_uniform(seed, 2203, *FRICTION_SPEED)
        cases.append((f"friction {100 * frac:.1f} % of the weight over {1e3 * v_c:.2f} mm/s", seed,
                      {"coulomb_friction": {"F_c": frac * WEIGHT, "v_c": v_c}}))
    for name, seed, planted in cases:
        dist = draw_disturbance(seed)
        path = SYNTH(tmp / "p.csv", seed=seed, disturbance=dist, effects=planted)
        rec = read_record(path, plausibility="warn")
        t0 = time.perf_counter()
        d = pipeline.run(rec, effects=FAMILY_EFFECTS)
        dt = time.perf_counter() - t0
        null = after_null.get(seed)
        ratio = d.after["rms_u"] / null["free_run"] if null else float("nan")
        ratio_k = d.verdict.after.prediction_rms["u"] / null["prediction"] if null else float("nan")
        ratio_y = d.verdict.after.prediction_rms["y"] / null["prediction_y"] if null else float("nan")
        # the true model on the record as the diagnosis read it (a cut record: from its settled start;
        # on the whole cut record its predictions from the flying start dominated the RMS, 0.01 times)
        ratio_true = d.verdict.after.prediction_rms["y"] / true_prediction_y(d.diagnosed or rec, path, planted)
        effect = next(iter(planted))
        row = {"case": name, "effect": effect, "seed": seed, "planted": planted[effect], "selected": d.selected,
               "after_over_null": ratio, "after_over_null_prediction": ratio_k,
               "after_over_null_prediction_y": ratio_y, "after_over_true_prediction_y": ratio_true, "seconds": dt, "verdict": d.verdict.verdict,
               "fit_mode": d.fit_mode, "estimates": {p: d.parameters.get(p) for p in planted[effect]},
               "estimates_all": {p: d.parameters.get(p) for e in d.selected for p in CATALOGUE[e].params},
               "sigma_all": {p: d.uncertainties.get(p) for e in d.selected for p in CATALOGUE[e].params},
               "own_delay_s": _own_delay(path, rec.ts),
               "i_limited_share": _truth(path)["i_limited_share"],
               "alternatives": {e: [a["effect"] for a in alts] for e, alts in d.alternatives.items()}}
        print(f"{name:<22}{seed:>6}  {_selected(row):<40}{ratio:>23.2f}{ratio_k:>12.2f}{dt:>6.1f}  "
              f"{d.verdict.verdict}", flush=True)
        out["power"].append(row)
    # a current limit the record's current hardly reaches (the PID of the emulator's setting
    # pid_derivative=measurement spares the output the kicks at the steps that reach the matrix's
    # limit: 5 samples of 12000 at seed 7200) is no effect of the record: it is shown, and left out
    # of the power
    catalogue_rows = [r for r in out["power"] if r["case"] in POWER_CASES and not _never_acts(r)]
    hits = sum(r["selected"][:1] == [r["effect"]] for r in catalogue_rows)
    explained = sum(r["verdict"] == "explained" for r in catalogue_rows)
    out["checks"] = _checks(out, n_null, fp, hits, len(catalogue_rows))
    print("\n| benchmark | records | rate |\n|---|---|---|")
    wrong = sum(r["verdict"] != "no effect" for r in out["null"])
    print(f"| no-effect records whose verdict is not 'no effect' | {n_null} | {100 * wrong / max(n_null, 1):.1f} % |")
    if catalogue_rows:
        print(f"| catalogue records with the verdict 'explained' | {len(catalogue_rows)} | "
              f"{100 * explained / len(catalogue_rows):.1f} % |")
    for c in out["checks"]:
        print(f"| {c['criterion']} | {c['records']} | {c['measured']} (target {c['target']}) |")
    out["false_positive_rate"] = fp / max(n_null, 1)
    out["power_rate"] = hits / len(catalogue_rows) if catalogue_rows else None
    return out


#: A planted current limit the current exceeds in fewer samples than this share (12 samples of a 12 s
#: record; a tenth of issue 22's lowest share of interest, 1 %) is not an effect of the record.
MIN_ACTING_SHARE = 1e-3


def _never_acts(row: dict) -> bool:
    """A planted current limit that the record's current hardly exceeds (:data:`MIN_ACTING_SHARE`)."""
    return row["effect"] == "current_saturation" and row["i_limited_share"] < MIN_ACTING_SHARE


def _selected(row: dict) -> str:
    """The effects selected, each with the rivals the held-out blocks did not tell from it
    (``pipeline.distinct``): "delay (or force_lag)"."""
    alts = row.get("alternatives", {})
    return ", ".join(e + (f" (or {' or '.join(alts[e])})" if alts.get(e) else "") for e in row["selected"]) or "—"


def _share(k: int, n: int) -> str:
    return f"{k} of {n} ({100 * k / n:.1f} %)" if n else "no records"


def _checks(out: dict, n_null: int, fp: int, hits: int, n_catalogue: int) -> list[dict]:
    """The done-when figures of issue 22 over the benchmark's rows. 'The true model's error' is the
    20 ms prediction error of y of the emulator's own plant on the record (:func:`true_prediction_y`);
    the no-effect twin's (the final model's error on the record of the same draw without the
    effect) is shown beside it."""
    power = out["power"]
    single = power                      # every record of the benchmark has one effect planted
    spurious = [r for r in single if extra_effects(r)]
    loose = [r for r in power if r["verdict"] == "explained" and r["after_over_true_prediction_y"] > 1.2]
    loose_twin = [r for r in power if r["verdict"] == "explained" and r["after_over_null_prediction_y"] > 1.2]
    friction = [r for r in power if r["effect"] == "coulomb_friction" and r["planted"]["F_c"] >= 0.02 * WEIGHT]
    fr_ok = [r for r in friction if "coulomb_friction" in r["selected"] or r["verdict"] == "unexplained: mechanics"]
    # issue 22's criterion is over limits active in 1-60 % of the samples: a drawn limit whose record
    # holds the current at it far longer (the ball fell, and the loop sits on the limit), or less than
    # 1 % of the samples (the placement's bisection stops after a few tries), is shown apart
    drawn = [r for r in power if r["effect"] == "current_saturation" and r["case"] != r["effect"]]
    limits = [r for r in drawn if LIMIT_SHARE[0] <= r["i_limited_share"] <= LIMIT_SHARE[1]]
    beyond = [r for r in drawn if r not in limits]

    def found(rs: list[dict]) -> list[dict]:
        return [r for r in rs if "current_saturation" in r["selected"] and r["estimates"].get("i_max")
                and abs(r["estimates"]["i_max"] / r["planted"]["i_max"] - 1) <= 0.05]
    lim_ok = found(limits)
    own = [r for r in out["null"] if r.get("own_delay_s", 0) > 0]
    rows = [("false positives", n_null, _share(fp, n_null))]
    if own:
        rows.append(("the emulator's own computation delay found (as a delay or a lag)", len(own),
                     _share(sum(r["own_delay_found"] for r in own), len(own))))
    rows += [
             ("power", n_catalogue, _share(hits, n_catalogue)),
             ("spurious second effect", len(single), _share(len(spurious), len(single))),
             ("'explained' beyond 1.2× the true model's error", len(power), str(len(loose))),
             ("'explained' beyond 1.2× the no-effect twin's error", len(power), str(len(loose_twin))),
             ("friction ≥ 2 % of the weight", len(friction), _share(len(fr_ok), len(friction))),
             ("current limit found, i_max within 5 %", len(limits), _share(len(lim_ok), len(limits)))]
    idle = [r for r in power if r["case"] in POWER_CASES and _never_acts(r)]
    if idle:
        rows.append((f"a catalogue current limit the current exceeds in under {100 * MIN_ACTING_SHARE:g} % of the samples "
                     "(left out of the power)",
                     len(idle), ", ".join(r["case"] for r in idle)))
    if beyond:
        rows.append((f"current limit active in under {100 * LIMIT_SHARE[0]:.0f} % or over {100 * LIMIT_SHARE[1]:.0f} % "
                     "of the samples (outside the criterion), found", len(beyond), _share(len(found(beyond)), len(beyond))))
    return [{"criterion": c, "records": n, "measured": m, "target": TARGETS.get(c, "–")} for c, n, m in rows]


def family_section(res: dict, emulator: str, cut: bool = False) -> str:
    """The benchmark's section of docs/benchmarks.md (``cut``: of records cut while the ball flies, ``--cut``)."""
    body = [f"Records of {EMULATOR_NAMES[emulator]}: {len(res['null'])} without an effect (the disturbance family), "
            "then on the first draws each catalogue effect at the matrix's magnitude, a current limit acting in "
            f"{100 * LIMIT_SHARE[0]:.0f}–{100 * LIMIT_SHARE[1]:.0f} % of the samples and Coulomb friction of "
            f"{100 * FRICTION_SHARE[0]:.0f}–{100 * FRICTION_SHARE[1]:.0f} % of the weight smoothed over "
            f"{1e3 * FRICTION_SPEED[0]:.1f}–{1e3 * FRICTION_SPEED[1]:.0f} mm/s. The default catalogue "
            "is tried. 'The true model' is the emulator's own plant (the baseline parameters, the planted effect and "
            "the emulator's own computation delay) predicting the record through the verdict's predictor under the "
            "disturbance model estimated for it; 'the no-effect twin' is the record of the same draw without the "
            "effect, whose final 20 ms prediction error of y is shown beside."
            + (" The independent emulator applies its PID's output a fraction of a sample late (`pid_offset`), a "
               "real delay of its records: a `delay`, or a force or amplifier lag (a lag that short is a delay's twin), "
               f"found alone on a no-effect record within 3σ (or {100 * OWN_DELAY_TOL:.0f} %) of it is counted on its "
               "own row, not as a false positive."
               if any(r.get("own_delay_s", 0) > 0 for r in res["null"]) else "")
            + (f" Each record begins {CUT_SAMPLES} samples after its first reference step after {CUT_AFTER_S:g} s, "
               "re-timed from 0 (`--cut`: a logger started while the ball flies); the diagnosis reads it from where "
               "its loop is first settled (`records/settled.py`), the truth is the whole record's." if cut else ""), "",
            benchdoc.table(["criterion", "records", "measured", "target"],
                           [[c["criterion"], c["records"], c["measured"], c["target"]] for c in res["checks"]]),
            "", "Records with an effect. *selected*: an effect followed by \"(or X)\" was chosen over X, which the "
            "held-out blocks did not tell from it (`pipeline.distinct`: the likelihood ratio between the two below "
            "the acceptance test's threshold); the power counts the effect chosen alone.", "",
            benchdoc.table(["case", "seed", "planted", "limit active", "selected", "estimate", "verdict",
                            "y 20 ms / true model", "y 20 ms / twin"],
                           [[r["case"], r["seed"], ", ".join(f"{k} = {v:.4g}" for k, v in r["planted"].items()),
                             f"{100 * r['i_limited_share']:.1f} %", _selected(r),
                             ", ".join(f"{k} = {v:.4g}" for k, v in r["estimates"].items() if v is not None) or "—",
                             r["verdict"], f"{r.get('after_over_true_prediction_y', float('nan')):.2f}",
                             f"{r['after_over_null_prediction_y']:.2f}"] for r in res["power"]])]
    wrong = [r for r in res["null"] if r["selected"] or r["verdict"] != "no effect"]

    def what(r: dict) -> str:
        found = ", ".join(r["selected"])
        if r.get("own_delay_found"):
            p = OWN_DELAY_TWINS[r["selected"][0]]
            found += (f": {p} = {1e3 * r['estimates'][p]:.3f} ± {1e3 * (r['sigma'].get(p) or 0):.3f} ms, the "
                      f"emulator's own {1e3 * r['own_delay_s']:.2f} ms")
        return f" ({found})" if r["selected"] else ""

    body += ["", "No-effect records whose verdict is not `no effect`: "
             + ("none." if not wrong else "; ".join(f"seed {r['seed']}: {r['verdict']}{what(r)}" for r in wrong) + ".")]
    return "\n".join(body)


def matrix_section(rows: list[dict], seed: int, emulator: str) -> str:
    """The matrix's section of docs/benchmarks.md."""
    head = (f"Records of {EMULATOR_NAMES[emulator]}, seed {seed}, one per row: the effect planted, what the "
            "diagnosis selected, its estimates, the RMS errors of y and u before and after (free run), the final "
            "model's 20 ms prediction error, u's error over what the sensor noise alone makes, the verdict and "
            "the time. *tried* rows offer the catalogue entries that are not in the default; *OUTSIDE* rows plant "
            "an effect the catalogue lacks. What the rows show: [diagnosis.md](diagnosis.md#known-limits).")
    table = benchdoc.table(
        ["record", "selected", "estimates", "before y / u [MU]", "after y / u [MU]", "20 ms ahead y / u [MU]",
         "after u / noise", "verdict", "s"],
        [[r["record"], ", ".join(r["selected"]) or "—",
          ", ".join(f"{k} = {v:.4g}" for k, v in r["estimates"].items() if k != "phi_d") or "—",
          f"{r['before']['rms_y']:.5f} / {r['before']['rms_u']:.5f}", f"{r['after']['rms_y']:.5f} / {r['after']['rms_u']:.5f}",
          f"{r['after_prediction']['y']:.5f} / {r['after_prediction']['u']:.5f}", f"{r['after_u_over_noise']:.2f}",
          r["verdict"], f"{r['seconds']:.1f}"] for r in rows])
    return head + "\n\n" + table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=5, help="seed of the matrix; first seed of the benchmark")
    ap.add_argument("--json", default=None, help="write the rows to this JSON file")
    ap.add_argument("--family", type=int, default=0, metavar="N",
                    help="run the acceptance benchmark on N no-effect records instead of the matrix")
    ap.add_argument("--power", type=int, default=5, metavar="M",
                    help="with --family: each catalogue effect on the first M draws (default 5)")
    ap.add_argument("--emulator", choices=["rig", "ivp"], default="rig",
                    help="the records' emulator: rig (default) or ivp, the independent one written from the paper "
                         "(the matrix then skips the rows with effects it does not have)")
    ap.add_argument("--setting", action="append", default=[], metavar="NAME=VALUE",
                    help="with --emulator ivp: one of its settings (emulator_ivp.SETTINGS: pid_offset, f_y, method, rtol, "
                         "pid_tf, pid_derivative), repeatable")
    ap.add_argument("--limits", type=int, default=None, metavar="L",
                    help="with --family: a current limit on the first L draws (default: as --power)")
    ap.add_argument("--friction", type=int, default=None, metavar="F",
                    help="with --family: Coulomb friction on the first F draws (default: as --power)")
    ap.add_argument("--write-docs", action="store_true",
                    help="write the table into its section of docs/benchmarks.md (scripts/benchdoc.py)")
    ap.add_argument("--cut", action="store_true",
                    help=f"begin every record {CUT_SAMPLES} samples after its first reference step after {CUT_AFTER_S:g} s "
                         "(a record cut from a running loop, the ball flying)")
    ap.add_argument("--also", action="append", default=[], metavar="EFFECT",
                    help="with --family: an opt-in catalogue effect tried beside the default ones, to measure "
                         "what putting it in the default catalogue would do (repeatable)")
    a = ap.parse_args()
    t_start = time.perf_counter()
    global SYNTH, FAMILY_EFFECTS, POWER_CASES
    if a.also:
        FAMILY_EFFECTS = [*DEFAULT_EFFECTS, *(e for e in a.also if e not in DEFAULT_EFFECTS)]
    supported = None
    if a.setting and a.emulator != "ivp":
        ap.error("--setting belongs to --emulator ivp")
    if a.emulator == "ivp":
        try:
            settings = emulator_ivp.parse_settings(a.setting)
        except ValueError as e:
            ap.error(str(e))
        SYNTH, supported = partial(emulator_ivp.synth_record, settings=settings), set(emulator_ivp.EFFECTS)
        POWER_CASES = {k: v for k, v in POWER_CASES.items() if set(v) <= supported}
    if a.cut:
        SYNTH = partial(cut_while_flying, SYNTH)
    if a.family:
        with tempfile.TemporaryDirectory() as tmp:
            n_extra = [min(a.power if v is None else v, a.family) for v in (a.limits, a.friction)]
            res = family(a.family, min(a.power, a.family), a.seed, Path(tmp), *n_extra)
        if a.json:
            Path(a.json).write_text(json.dumps(res, indent=2, default=float))
        if a.write_docs:
            title = f"Acceptance benchmark: {'independent emulator' if a.emulator == 'ivp' else 'project emulator'}"
            if a.setting:     # a run with the independent emulator's own settings has a section of its own
                title += " (" + ", ".join(a.setting) + ")"
            if a.cut:
                title += f" (records cut {CUT_SAMPLES} samples after a reference step)"
            benchdoc.write_section(title, family_section(res, a.emulator, a.cut), time.perf_counter() - t_start)
            print(f"wrote the section '{title}' of {benchdoc.DOC}")
        return
    rows = []
    print(f"{'record':<26}{'selected':<38}{'estimates':<46}{'before y/u [MU]':<20}{'after y/u [MU]':<20}"
          f"{'20 ms ahead y/u':<20}{'after u/noise':>14}{'s':>6}  verdict")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, kw) in enumerate(CASES):
            if supported is not None and not set(kw.get("effects", {})) <= supported:
                print(f"{name:<26}(skipped: the {a.emulator} emulator has no {', '.join(set(kw['effects']) - supported)})")
                continue
            path = SYNTH(Path(tmp) / f"r{k}.csv", seed=a.seed, **kw)
            rec = read_record(path)
            t0 = time.perf_counter()
            d = pipeline.run(rec, effects=TRIED.get(name))
            dt = time.perf_counter() - t0
            est = {p: d.parameters[p] for e in d.selected for p in CATALOGUE[e].params}
            over = d.after["rms_u"] / d.noise["rms_u_from_sensor_noise"]
            k_rms = d.verdict.after.prediction_rms
            est_s = ", ".join(f"{p}={v:.4g}" for p, v in est.items() if p != "phi_d")
            print(f"{name:<26}{','.join(d.selected) or '-':<38}{est_s:<46}"
                  f"{d.before['rms_y']:.5f}/{d.before['rms_u']:.5f}   {d.after['rms_y']:.5f}/{d.after['rms_u']:.5f}"
                  f"   {k_rms['y']:.5f}/{k_rms['u']:.5f}   {over:11.2f}  {dt:5.1f}  {d.verdict.verdict}", flush=True)
            rows.append({"record": name, "truth": kw, "selected": d.selected, "estimates": est,
                         "before": d.before, "after": d.after, "after_prediction": k_rms,
                         "after_u_over_noise": over, "seconds": dt,
                         "verdict": d.verdict.verdict, "note": d.unexplained["note"]})
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2))
    if a.write_docs:
        title = f"Diagnosis matrix: {'independent emulator' if a.emulator == 'ivp' else 'project emulator'}"
        benchdoc.write_section(title, matrix_section(rows, a.seed, a.emulator), time.perf_counter() - t_start)
        print(f"wrote the section '{title}' of {benchdoc.DOC}")


if __name__ == "__main__":
    main()
