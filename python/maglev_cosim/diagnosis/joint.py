"""Several CE152 records calibrated together, and judged on records no fit saw:
``maglev-cosim calibrate A.csv B.csv --validate C.csv``, the one engine over several records.

The stages, each the one-record engine's where it can be:

1. each calibration record is diagnosed on its own (:func:`.pipeline.run`: its calibration, the
   effect search on its held-out blocks, its verdict): which effects the rig shows;
2. the effects every record selected join one model, and one that only some selected joins it when
   it passes the search's held-out test on all records at once; the baseline's parameters and theirs are
   calibrated on all calibration records at once (least squares over every record's free-run
   residual, each record weighted by its own calibrated baseline's RMS, :func:`.problem.fit` over
   several problems); the baseline alone too (the "before" model), with ±1σ from the joint Jacobian;
3. every validation record (or, with none, every calibration record) is judged with that one model
   by the one-record verdict (:func:`.verdict.conclude`: the noise-floor rule, the location); the
   verdict is the worst of theirs;
4. on every record, the model against the black boxes fitted on the calibration records
   (:func:`.compare.compare`), median and worst per role and horizon.

A rig whose records disagree (a parameter that drifts between runs, an effect one record shows
and another does not) fits worse jointly than each record alone: the per-record values stand
beside the joint ones in the report, and the spread is a finding.
"""

from __future__ import annotations

import hashlib
import json
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._html import write_html
from ..plant.calibrated_fmu import calibrated_fmu, issued_guid
from ..plant.fast import param_table
from ..records.record import Record
from . import pipeline
from .acceptance import accept, fit_blocks
from .compare import HORIZONS_S, RecordComparison, compare, fit_boxes
from .effects import BASELINE, CATALOGUE
from .metrics import nrmse_fit
from .problem import Problem, fit, residuals
from .replay import estimate_noise, replay
from .residual import effective_samples, noise_floor
from .result import (CalibratedFmu, Comparison, DiagnosisResult, Fit, HorizonSkill, LocationEvidence, RecordRef,
                     Residual, SegmentFigures, _parameters, finite)
from .verdict import Verdict, conclude, on_bounds

Say = Callable[[str], None]

#: Verdicts from worst to best: the joint verdict is the worst of the judged records'.
SEVERITY = ("calibration failed", "unexplained", "explained in part", "explained", "no effect")


def _rank(verdict: str) -> int:
    return next((k for k, v in enumerate(SEVERITY) if verdict.startswith(v)), 0)


@dataclass
class Judged:
    """One record under the joint model: its role, verdict, free-run fits and comparison."""

    name: str
    role: str                       #: ``calibration`` or ``validation``
    verdict: Verdict | None
    fit_before: tuple[float, float]  #: free-run NRMSE fit [%] of y, u: the joint calibrated baseline
    fit_after: tuple[float, float]   #: the joint final model
    rms_before: tuple[float, float]  #: RMS of y, u [MU]: the joint calibrated baseline
    rms_after: tuple[float, float]   #: the joint final model
    comparison: RecordComparison


@dataclass
class JointDiagnosis:
    """What the joint calibration found (module docstring)."""

    each: list                       #: the calibration records' own diagnoses (:class:`.pipeline.Diagnosis`)
    selected: list[str]
    baseline: dict[str, float]       #: the joint calibrated baseline (all parameters)
    parameters: dict[str, float]     #: the joint final model (all parameters)
    uncertainties: dict[str, float]
    judged: list[Judged]
    verdict: str
    elapsed: float
    warnings: list[str] = field(default_factory=list)


def _median(values) -> float:
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(np.median(v)) if v else float("nan")


def _joint_fit(probs: list[Problem], parts, start: dict[str, float], say: Say) -> dict[str, float]:
    say(f"calibrating {', '.join(c.name for p in parts for c in p.coords)} on {len(probs)} records at once")
    return fit(probs, parts, [p.to_coords(start) for p in parts], max_nfev=40).values


def _held_out(probs: list[Problem], selected: Sequence[str], effect: str, start: dict[str, float],
              say: Say) -> tuple[bool, str]:
    """An effect some records selected and others did not, judged as the one-record search judges a
    candidate (:func:`.acceptance.accept`), on all records at once: the joint model with and without
    it fitted on every record's fit blocks, the costs compared on their held-out blocks (the
    effective samples summed over the records)."""
    fitm = [fit_blocks(p.rec.t) for p in probs]
    on_fit = [p.with_mask(m) for p, m in zip(probs, fitm)]
    parts = [BASELINE, *(CATALOGUE[e] for e in selected)]
    # only the model's own parameters: the problems' base holds every other effect off
    own = {c.name: start[c.name] for part in parts for c in part.coords}
    without = {**own, **_joint_fit(on_fit, parts, own, say)}
    s1 = {**without, **{c.name: start[c.name] for c in CATALOGUE[effect].coords}}
    with_it = {**s1, **_joint_fit(on_fit, [*parts, CATALOGUE[effect]], s1, say)}
    held_res = [[residuals(p, v, ~m) for p, m in zip(probs, fitm)] for v in (without, with_it)]
    cost = [float(np.mean(np.concatenate(r) ** 2)) for r in held_res]
    n_eff = sum(min(effective_samples(r[:len(r) // 2]), effective_samples(r[len(r) // 2:])) for r in held_res[1])
    ok, stats = accept(cost[0], cost[1], n_eff, len(CATALOGUE[effect].params))
    ok = ok and not CATALOGUE[effect].is_off(with_it)
    return ok, (f"its cost change is {-100 * stats['held_out_gain']:+.1f} % (LR {stats['lr_statistic']:.1f} against "
                f"{stats['threshold']:.1f})")


def run(recs: Sequence[Record], held: Sequence[Record], *, effects: Sequence[str] | None = None,
        workers: int | None = None, progress: Say | None = None) -> JointDiagnosis:
    """Calibrates one model on ``recs`` and judges it on ``held`` (module docstring).

    Parameters
    ----------
    recs : sequence of Record
        The calibration records (two or more, or one with validation records). Each is fitted as its
        own diagnosis read it (:attr:`.pipeline.Diagnosis.diagnosed`: with its PID's form).
    held : sequence of Record
        The validation records: judged, never fitted. Their PID's form is the caller's
        (:func:`.controller_form.identified`).
    effects : sequence of str, optional
        The catalogue entries each record's search tries (default :data:`~.effects.DEFAULT_EFFECTS`).
    workers : int, optional
        Processes for each record's candidate fits.
    progress : callable, optional
        Called with a line of text at each step.
    """
    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    each = []
    for k, rec in enumerate(recs, 1):
        say(f"[{k}/{len(recs)}] diagnosing {rec.path} on its own")
        each.append(pipeline.run(rec, effects=effects, workers=workers,
                                 progress=lambda s, k=k: say(f"[{k}/{len(recs)}] {s}")))
    # each record as its own diagnosis read it: with its PID's form as it showed it (controller_form)
    recs = [d.diagnosed if d.diagnosed is not None else r for r, d in zip(recs, each)]
    union = list(dict.fromkeys(e for d in each for e in d.selected))
    # every record weighted by its own calibrated baseline's error, so that each counts alike
    probs_base = [Problem(r, dict(d.calibrated_baseline), max(d.before["rms_y"], 1e-6), max(d.before["rms_u"], 1e-6),
                          np.ones(r.n, bool)) for r, d in zip(recs, each)]
    start = {c.name: _median(d.calibrated_baseline[c.name] for d in each) for c in BASELINE.coords}
    base_vals = _joint_fit(probs_base, [BASELINE], start, say)
    baseline = {**each[0].calibrated_baseline, **base_vals}
    start = dict(base_vals)
    for e in union:     # an effect's start: the records that found it
        for c in CATALOGUE[e].coords:
            start[c.name] = _median(d.parameters[c.name] for d in each if e in d.selected)
    # the effects' values of no record: off (the calibrated baseline's), until the joint model takes them
    probs = [Problem(r, {**dict(d.calibrated_baseline), **base_vals}, p.sigma_y, p.sigma_u, p.mask)
             for r, d, p in zip(recs, each, probs_base)]
    selected = [e for e in union if all(e in d.selected for d in each)]
    warnings: list[str] = []
    for e in (e for e in union if e not in selected):
        ok, note = _held_out(probs, selected, e, start, say)
        warnings.append(f"{e}: selected by {sum(e in d.selected for d in each)} of {len(each)} records alone; on the "
                        f"held-out blocks of all of them {note}: " + ("in the joint model" if ok else "left out"))
        if ok:
            selected.append(e)
    say(f"effects of the records: {', '.join(union) or 'none'}; the joint model's: {', '.join(selected) or 'none'}")
    parts = [BASELINE, *(CATALOGUE[e] for e in selected)]
    values = _joint_fit(probs, parts, start, say)
    dropped = [e for e in selected if CATALOGUE[e].is_off(values)]
    if dropped:
        say(f"the joint calibration turned {', '.join(dropped)} off: calibrating without it")
        selected = [e for e in selected if e not in dropped]
        off = {c.name: baseline[c.name] for e in dropped for c in CATALOGUE[e].coords}
        parts = [BASELINE, *(CATALOGUE[e] for e in selected)]
        probs = [Problem(p.rec, {**p.base, **off}, p.sigma_y, p.sigma_u, p.mask) for p in probs]
        values = _joint_fit(probs, parts, {**values, **off}, say)
    final = {**each[0].parameters, **{c.name: baseline[c.name] for e in CATALOGUE for c in CATALOGUE[e].coords
                                      if e not in selected and c.name in baseline}, **values}
    say("estimating the joint parameters' uncertainties")
    unc = pipeline.uncertainty(probs, final, {k: v for p in parts for k, v in p.uncertainty_scales().items()})

    boxes, _ = fit_boxes(recs)
    longest = max(range(len(recs)), key=lambda k: recs[k].n)
    noise_cal = estimate_noise(recs[longest], final)       # the validation records' filter: never fitted on them
    judged = []
    for role, group in (("calibration", recs), ("validation", held)):
        for rec in group:
            say(f"judging {rec.path} ({role}) with the joint model")
            sims = {"before": replay(rec, baseline), "after": replay(rec, final)}
            verdict = None
            if role == "validation" or not held:
                verdict = conclude(rec, baseline, final, sims, selected, [], say, fit_mask=fit_blocks(rec.t),
                                   noise_levels=noise_floor(rec))
            noise = estimate_noise(rec, final) if role == "calibration" else noise_cal
            b, a = (pipeline.rms(rec, sims[k]) for k in ("before", "after"))
            judged.append(Judged(
                Path(rec.path).name, role, verdict,
                (nrmse_fit(rec.y, sims["before"]["y"]), nrmse_fit(rec.u, sims["before"]["u"])),
                (nrmse_fit(rec.y, sims["after"]["y"]), nrmse_fit(rec.u, sims["after"]["u"])),
                (b["rms_y"], b["rms_u"]), (a["rms_y"], a["rms_u"]), compare(rec, final, noise, boxes=boxes)))
    search, physical = on_bounds(final)
    warnings += [f"{t} sits on its physical limit: the records do not resolve it" for t in physical]
    if search:
        verdict = "calibration failed"
        warnings.append("calibrated parameter(s) of the joint model on a bound of their range: " + "; ".join(search))
    else:
        verdict = min((j.verdict.verdict for j in judged if j.verdict is not None), key=_rank)
    for j in judged:
        warnings += [f"{j.name}: {w}" for w in (j.verdict.warnings if j.verdict else [])]
    return JointDiagnosis(each, selected, baseline, final, unc, judged, verdict, time.perf_counter() - t0, warnings)


# ----------------------------------------------------------------------------- the typed result

def _worst(values) -> float:
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(min(v)) if v else float("nan")


def _role_comparison(judged: Sequence[Judged], role: str) -> Comparison | None:
    """Median and worst skill per horizon and predictor over the records of ``role``."""
    group = [j for j in judged if j.role == role]
    if not group:
        return None
    horizons = {}
    for h in (f"{hs * 1e3:g} ms" for hs in HORIZONS_S):
        cells = []
        for w in HorizonSkill.WHO:
            v = [j.comparison.skills["record"][h][w] for j in group]
            cells += [_median(v), _worst(v)]
        horizons[h] = HorizonSkill(*cells)
    return Comparison(role, len(group), horizons)


def _fit_of(judged: Sequence[Judged], key: str) -> Fit | None:
    vs = [j.verdict for j in judged if j.verdict is not None]
    if not vs:
        return None
    def med(kind: str, sig: str):
        return _median(getattr(v, key)[kind].get(sig) for v in vs)
    pred = vs[0].fit["prediction"]
    return Fit.from_json({"free_run": {"y": med("free_run", "y"), "u": med("free_run", "u")},
                          "prediction": {"horizon_s": pred["horizon_s"], "y": med("prediction", "y"),
                                         "u": med("prediction", "u")}})


def result(j: JointDiagnosis, recs: Sequence[Record], held: Sequence[Record],
           written: Sequence[Path] = (), fmu: CalibratedFmu | None = None) -> DiagnosisResult:
    """The joint diagnosis as the one typed result every diagnosis returns."""
    judged = [x for x in j.judged if x.verdict is not None]
    worst = min(judged, key=lambda x: _rank(x.verdict.verdict)) if judged else None
    reasons = [f"{x.name} ({x.role}): " + (f"verdict {x.verdict.verdict}, " if x.verdict else "")
               + f"free-run fit y/u {x.fit_after[0]:.1f}/{x.fit_after[1]:.1f} % (joint baseline "
               f"{x.fit_before[0]:.1f}/{x.fit_before[1]:.1f} %)" for x in j.judged]
    comparison = [c for c in (_role_comparison(j.judged, r) for r in ("calibration", "validation")) if c]
    per_record = [{"record": x.name, "role": x.role, "verdict": x.verdict.verdict if x.verdict else None,
                   "fit_before": {"y": x.fit_before[0], "u": x.fit_before[1]},
                   "fit_after": {"y": x.fit_after[0], "u": x.fit_after[1]},
                   "rms_after": {"rms_y": x.rms_after[0], "rms_u": x.rms_after[1]},
                   "prediction_comparison": x.comparison.to_json()} for x in j.judged]
    own = [{"record": Path(d.record).name, "verdict": d.verdict.verdict if d.verdict else None,
            "selected": d.selected, "parameters": {p: d.parameters[p] for p in j.uncertainties}} for d in j.each]
    val = [x for x in j.judged if x.role == ("validation" if held else "calibration")]
    return DiagnosisResult(
        kind="ce152", verdict=j.verdict, fit=_fit_of(j.judged, "fit"), fit_before=_fit_of(j.judged, "fit_before"),
        warnings=list(j.warnings), selected=list(j.selected),
        parameters=_parameters({k: j.parameters[k] for k in j.uncertainties}, j.uncertainties),
        before=Residual.from_json({"rms_y": _median(x.rms_before[0] for x in val),
                                   "rms_u": _median(x.rms_before[1] for x in val)}),
        after=Residual.from_json({"rms_y": _median(x.rms_after[0] for x in val),
                                  "rms_u": _median(x.rms_after[1] for x in val)}),
        location_evidence=[LocationEvidence.from_json(k, e)
                           for k, e in (worst.verdict.location_evidence if worst else {}).items()],
        calibrated_fmu=fmu, comparison=comparison,
        segments=[SegmentFigures(x.name, x.role, None, {h: v["model"] for h, v in x.comparison.skills["record"].items()})
                  for x in j.judged],
        reasons=reasons, written=list(written),
        extra={"records": per_record, "own_calibrations": own, "calibrated_baseline": j.baseline,
               "elapsed_s": j.elapsed})


def _sha256(path: str) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def write(j: JointDiagnosis, recs: Sequence[Record], held: Sequence[Record], out: Path, fmu_in: Path | None,
          json_name: str = "diagnosis.json") -> DiagnosisResult:
    """``report.md``, ``report.html``, ``diagnosis.json`` and (unless the calibration failed) the
    calibrated FMU with every calibration record's name and sha256 as its provenance."""
    out.mkdir(parents=True, exist_ok=True)
    units = {n: row[3] for n, row in param_table().items()}
    res = result(j, recs, held)
    lines = [f"# Calibration on {len(recs)} CE152 records" + (f", validated on {len(held)}" if held else ""), "",
             f"**Verdict: {j.verdict}** (the worst of the judged records'). Effects of the joint model: "
             f"{', '.join(j.selected) or 'none'}.", ""]
    if j.warnings:
        lines += ["**Warnings**:", "", *(f"- {w}" for w in j.warnings), ""]
    lines += ["| record | role | verdict | fit y / u [%], joint baseline | fit y / u [%], joint model |",
              "|---|---|---|---|---|"]
    for x in j.judged:
        lines.append(f"| {x.name} | {x.role} | {x.verdict.verdict if x.verdict else '–'} | "
                     f"{x.fit_before[0]:.1f} / {x.fit_before[1]:.1f} | {x.fit_after[0]:.1f} / {x.fit_after[1]:.1f} |")
    lines += ["", "Free-run NRMSE fit (MATLAB's compare) of each record replayed with its own controller.", "",
              "## Parameters", "", "The joint model's (±1σ), and each calibration record's own:", "",
              "| parameter | joint | ± | " + " | ".join(Path(d.record).name for d in j.each) + " | unit |",
              "|---|---|---|" + "---|" * len(j.each) + "---|"]
    for p, s in j.uncertainties.items():
        lines.append(f"| {p} | {j.parameters[p]:.6g} | {s:.2g} | "
                     + " | ".join(f"{d.parameters[p]:.6g}" for d in j.each) + f" | {units.get(p, '')} |")
    lines += ["", "## Prediction: the model against the black box", "",
              "Skill against \"stays put\" of the reading predicted ahead, median (worst) over the records of each "
              "role: the model in closed loop with each record's controller, and the black box fitted on the "
              "calibration records (docs/diagnosis.md, \"Model against black box\").", "",
              "| records | horizon | model | black box | black box, u up to the start | constant velocity |",
              "|---|---|---|---|---|---|"]
    for c in res.comparison:
        for h, k in c.horizons.items():
            lines.append(f"| {c.role} ({c.segments}) | {h} | " + " | ".join(
                f"{getattr(k, w):+.2f} ({getattr(k, w + '_worst'):+.2f})" for w in HorizonSkill.WHO) + " |")
    lines.append("")
    md = out / "report.md"
    md.write_text("\n".join(lines) + "\n")
    html = write_html(md, out / "report.html")
    written = [out / json_name, md, html]
    fmu = None
    if j.verdict != "calibration failed" and fmu_in is not None:
        from lxml import etree   # fmpy's dependency, imported where it is used (as plant.calibrated_fmu does)

        refs = [RecordRef(Path(r.path).name, _sha256(r.path)) for r in recs]
        key = hashlib.sha256("".join(r.sha256 or "" for r in refs).encode()).hexdigest()
        params = {k: float(v) for k, v in j.parameters.items()}
        with zipfile.ZipFile(fmu_in) as z:
            guid = issued_guid(etree.fromstring(z.read("modelDescription.xml")).get("guid"), params, key)
        cal = {"format": "maglev-cosim calibration 1", "records": [r.to_json() for r in refs], "guid": guid,
               "effects": j.selected, "verdict": j.verdict,
               "parameters": {p: {"value": j.parameters[p], "sigma": s, "unit": units.get(p)}
                              for p, s in j.uncertainties.items()}}
        path = out / "maglev_calibrated.fmu"
        calibrated_fmu(fmu_in, path, params, model_name=f"CE152 magnetic levitation, calibrated on {len(recs)} records",
                       resources={"calibration.json": (json.dumps(finite(cal), indent=2) + "\n").encode()},
                       documentation={"index.html": html.read_bytes()}, source_sha256=key)
        fmu = CalibratedFmu(str(path), refs)
        written.append(path)
    res = result(j, recs, held, written, fmu)
    (out / json_name).write_text(json.dumps(res.to_json(), indent=2, allow_nan=False) + "\n")
    return res
