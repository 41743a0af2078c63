"""What a diagnosis returns, for every record: :class:`DiagnosisResult` and its parts, typed.

:meth:`DiagnosisResult.to_json` is the content of ``diagnosis.json`` (``docs/diagnosis-json.md``):
the keys every diagnosis writes (:data:`SHARED_KEYS`) from the typed fields, then the keys of the
record's path (a CE152 record's, a real rig's) as that path's stages found them (:attr:`~DiagnosisResult.extra`).
:func:`from_ce152` and :func:`from_rig` build it from each path's stage results.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..plant.fast import param_table

#: A JSON object, as ``json.dumps`` takes it.
Json = dict[str, Any]

#: The keys every ``diagnosis.json`` holds, a CE152 record's or a real rig's (docs/diagnosis-json.md).
SHARED_KEYS = ("verdict", "fit", "fit_before", "warnings", "selected", "parameters", "uncertainties", "before",
               "after", "location_evidence", "calibrated_fmu", "written")


def _num(v: Any) -> float | None:
    """A float, or None for a missing or non-finite figure."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


@dataclass
class Parameter:
    """One parameter of the final model [SI], by its FMU variable name, with its ±1σ where fitted."""

    name: str
    value: float | None
    sigma: float | None = None
    unit: str | None = None

    def __str__(self) -> str:
        sd = f" ± {self.sigma:.2g}" if self.sigma is not None and math.isfinite(self.sigma) else ""
        return f"{self.name} = {self.value:.6g}{sd}" + (f" {self.unit}" if self.unit else "")


@dataclass
class FreeRunFit:
    """NRMSE fit % of the model run free in closed loop with the record's controller."""

    y: float
    u: float

    def to_json(self) -> Json:
        return {"y": self.y, "u": self.u}


@dataclass
class PredictionFit:
    """NRMSE fit % of the position reading ``y`` and of the actuator's signal (the controller output
    ``u`` of a CE152 record, the coil ``current`` of a real rig) predicted ``horizon_s`` ahead."""

    horizon_s: float
    y: float | None
    second: float | None
    second_name: str = "u"          #: ``u`` or ``current``

    def to_json(self) -> Json:
        return {"horizon_s": self.horizon_s, "y": self.y, self.second_name: self.second}


@dataclass
class Fit:
    """How well a model follows the record: free run (None: an unknown controller, never run free)
    and k-step prediction."""

    free_run: FreeRunFit | None
    prediction: PredictionFit

    def to_json(self) -> Json:
        return {"free_run": self.free_run.to_json() if self.free_run else None, "prediction": self.prediction.to_json()}

    @classmethod
    def from_json(cls, d: dict | None) -> Fit | None:
        if not d:
            return None
        fr, pr = d.get("free_run"), d["prediction"]
        second = "current" if "current" in pr else "u"
        return cls(FreeRunFit(fr["y"], fr["u"]) if fr else None,
                   PredictionFit(pr["horizon_s"], pr.get("y"), pr.get(second), second))


@dataclass
class Residual:
    """RMS of a model's error on the record: ``rms_y`` [MU] (CE152: free run, with ``rms_u``; a real
    rig: the prediction ``horizon_s`` ahead)."""

    rms_y: float | None
    rms_u: float | None = None
    horizon_s: float | None = None

    def to_json(self) -> Json:
        out: dict = {"rms_y": self.rms_y}
        if self.rms_u is not None:
            out["rms_u"] = self.rms_u
        if self.horizon_s is not None:
            out["horizon_s"] = self.horizon_s
        return out

    @classmethod
    def from_json(cls, d: dict | None) -> Residual | None:
        return None if d is None else cls(d.get("rms_y"), d.get("rms_u"), d.get("horizon_s"))


@dataclass
class LocationEvidence:
    """The best evidence for a missing effect at one place in the loop (sensor, actuator,
    mechanics): the catalogue's effect there and its held-out cost change (negative: better), and
    the path's further figures as it found them (the generic correction, the state correction)."""

    location: str
    effect: str | None
    held_out_cost_change: float | None
    figures: dict = field(default_factory=dict)

    def to_json(self) -> Json:
        return {**self.figures, "effect": self.effect, "held_out_cost_change": self.held_out_cost_change}

    @classmethod
    def from_json(cls, loc: str, d: dict) -> LocationEvidence:
        change = d.get("held_out_cost_change")
        if change is None and d.get("held_out_gain") is not None:
            change = -float(d["held_out_gain"])
        return cls(loc, d.get("effect"), change,
                   {k: v for k, v in d.items() if k not in ("effect", "held_out_cost_change")})


@dataclass
class HorizonSkill:
    """Median (and worst) skill against "stays put" at one horizon (> 0: better than standing
    still): the model in closed loop (``model``: with the declared controller, or with the one
    identified from the record, :mod:`.reaction`), the model driven by the measured actuator signal
    (``model_measured_input``), the black-box baseline, the same black box reading the actuator
    signal only up to the prediction's start (``black_box_past``), and "constant velocity"."""

    model: float | None
    model_worst: float | None
    model_measured_input: float | None
    model_measured_input_worst: float | None
    black_box: float | None
    black_box_worst: float | None
    black_box_past: float | None
    black_box_past_worst: float | None
    constant_velocity: float | None
    constant_velocity_worst: float | None

    WHO = ("model", "model_measured_input", "black_box", "black_box_past", "constant_velocity")

    def to_json(self) -> Json:
        return {k: getattr(self, k) for w in self.WHO for k in (w, f"{w}_worst")}


@dataclass
class Comparison:
    """The prediction comparison over the segments of one role (``calibration``, ``validation``)."""

    role: str
    segments: int
    horizons: dict[str, HorizonSkill]

    def to_json(self) -> Json:
        return {"segments": self.segments, **{h: s.to_json() for h, s in self.horizons.items()}}


@dataclass
class SegmentFigures:
    """One levitation segment of a real record: its role, the current's fit from the actuator signal
    [%] and the model's skill against "stays put" per horizon."""

    label: str
    role: str
    current_from_actuator: float | None
    skill: dict[str, float | None]


@dataclass
class RecordCheck:
    """What a real record says of the rig file and of a declared controller: the share of the weight
    the force law carries at the measured gap and current (median, 10 and 90 %), and the declared
    controller's fit of the actuator signal, per loop, and in closed loop 20 ms ahead."""

    label: str
    force_balance: tuple[float, float, float] | None = None
    controller: str | None = None
    actuator_fit: float | None = None
    loop_fits: dict[str, float] = field(default_factory=dict)
    closed_loop: list[tuple[float, float]] = field(default_factory=list)   #: (gap, actuator) fit % per segment


@dataclass
class RecordRef:
    """A record a calibration rests on: its file name and sha256."""

    file: str
    sha256: str | None = None

    def to_json(self) -> Json:
        return {"file": self.file, **({"sha256": self.sha256} if self.sha256 else {})}


@dataclass
class CalibratedFmu:
    """The calibrated FMU written beside the report, and the records its values come from."""

    file: str
    records: list[RecordRef]

    def to_json(self) -> Json:
        return {"file": self.file, "records": [r.to_json() for r in self.records]}


@dataclass
class DiagnosisResult:
    """Everything a diagnosis found, one type for every record (module docstring)."""

    kind: str                                   #: ``ce152`` or ``rig``
    verdict: str
    fit: Fit | None
    fit_before: Fit | None
    warnings: list[str]
    selected: list[str]
    parameters: dict[str, Parameter]
    before: Residual | None
    after: Residual | None
    location_evidence: list[LocationEvidence]
    calibrated_fmu: CalibratedFmu | None = None
    comparison: list[Comparison] = field(default_factory=list)
    segments: list[SegmentFigures] = field(default_factory=list)
    checks: list[RecordCheck] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    written: list[Path] = field(default_factory=list)
    #: The path's own keys of ``diagnosis.json`` (docs/diagnosis-json.md, "besides"), as its stages found them
    #: (a real rig's stage results typed, :mod:`.rig_result`: :func:`finite` writes their ``to_json``).
    extra: dict = field(default_factory=dict)
    #: The path's stage result (:class:`~.pipeline.Diagnosis` of a CE152 record), for its figures; not in the JSON.
    detail: Any = None

    @property
    def uncertainties(self) -> dict[str, float]:
        """±1σ of the fitted parameters, by name."""
        return {n: p.sigma for n, p in self.parameters.items() if p.sigma is not None}

    def to_json(self) -> Json:
        shared = {
            "verdict": self.verdict,
            "fit": self.fit.to_json() if self.fit else None,
            "fit_before": self.fit_before.to_json() if self.fit_before else None,
            "warnings": list(self.warnings),
            "selected": list(self.selected),
            "parameters": {n: p.value for n, p in self.parameters.items() if p.value is not None},
            "uncertainties": self.uncertainties,
            "before": self.before.to_json() if self.before else None,
            "after": self.after.to_json() if self.after else None,
            "location_evidence": {e.location: e.to_json() for e in self.location_evidence},
            "calibrated_fmu": self.calibrated_fmu.to_json() if self.calibrated_fmu else None,
            "written": [str(p) for p in self.written],
        }
        if self.comparison:
            shared["comparison"] = {c.role: c.to_json() for c in self.comparison}
        if self.reasons:
            shared["reasons"] = list(self.reasons)
        return finite({**shared, **{k: v for k, v in self.extra.items() if k not in shared}})


def finite(v):
    """JSON-safe: non-finite numbers become null (strict JSON has no NaN or Infinity); numpy
    scalars and arrays become Python numbers and lists; a typed result (a stage's dataclass with
    ``to_json``, :mod:`.rig_result`) becomes its JSON."""
    if hasattr(v, "to_json"):
        return finite(v.to_json())
    if isinstance(v, dict):
        return {k: finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [finite(x) for x in v]
    if isinstance(v, np.ndarray):
        return finite(v.tolist())
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


def _parameters(values: dict[str, float], sigma: dict[str, float]) -> dict[str, Parameter]:
    units = {n: row[3] for n, row in param_table().items()}
    names = list(dict.fromkeys([*values, *sigma]))
    return {n: Parameter(n, _num(values.get(n)), _num(sigma.get(n)), units.get(n)) for n in names}


# ----------------------------------------------------------------------------- from each path's stages

#: Keys of a CE152 diagnosis's JSON that the typed fields hold.
_CE152_TYPED = ("verdict", "fit", "fit_before", "warnings", "selected", "parameters", "uncertainties", "before",
                "after", "location_evidence")


def from_ce152(d, calibrated_fmu: CalibratedFmu | None, written: list[Path], comparison=None) -> DiagnosisResult:
    """The result of the CE152 path (:class:`~.pipeline.Diagnosis`: closed-loop replay with the
    record's declared controller, the catalogue, the verdict, the location), with the model / black
    box / naive ``comparison`` (:class:`~.compare.RecordComparison`) when there is one."""
    data = d.to_json()
    if comparison is not None:
        data["prediction_comparison"] = comparison.to_json()
    v = d.verdict
    return DiagnosisResult(
        kind="ce152", verdict=v.verdict if v else "calibration failed",
        fit=Fit.from_json(v.fit) if v else None, fit_before=Fit.from_json(v.fit_before) if v else None,
        warnings=list(d.warnings), selected=list(d.selected),
        parameters=_parameters(d.parameters, d.uncertainties),
        before=Residual.from_json(d.before), after=Residual.from_json(d.after),
        location_evidence=[LocationEvidence.from_json(k, e) for k, e in (v.location_evidence if v else {}).items()],
        calibrated_fmu=calibrated_fmu, written=list(written),
        comparison=comparison.comparisons() if comparison is not None else [],
        segments=comparison.segments(Path(d.record).name) if comparison is not None else [],
        extra={k: x for k, x in data.items() if k not in _CE152_TYPED}, detail=d)


def _skill(f) -> dict[str, float | None]:
    return {h: _num(p.skill_vs_stays_put) for h, p in f.position.items()}


def _current(f) -> float | None:
    return _num((f.current or {}).get("from_actuator"))


def from_rig(res, sigma: dict[str, float] | None = None) -> DiagnosisResult:
    """The result of the real-rig path (:func:`~.real_rig.run`, a :class:`~.rig_result.RigRun`: prediction
    driven by the measured actuator signal, calibration over several records, the black-box comparison).
    Its stages' typed results (:mod:`.rig_result`) are kept as they are in :attr:`DiagnosisResult.extra`
    (:meth:`~.rig_result.RigRun.own_keys`); ``sigma``: the parameters' ±1σ instead of the run's."""
    segments = [SegmentFigures(s.label, "calibration", _current(s.after), _skill(s.after))
                for e in res.records for s in e.segments]
    segments += [SegmentFigures(v.label, "validation", _current(v.after), _skill(v.after)) for v in res.validation]
    checks = []
    for e in res.records:
        fb, cc = e.force_balance, e.controller_check
        check = RecordCheck(e.label, (fb.median, fb.p10, fb.p90) if fb else None)
        if cc:
            check.controller = res.controller["name"]
            check.actuator_fit = cc.actuator_fit
            check.loop_fits = {k: x["fit"] for k, x in cc.loops.items()}
            check.closed_loop = [(x.gap_fit, x.actuator_fit) for x in e.closed_loop]
        checks.append(check)
    comparison = [Comparison(c.role, c.segments,
                             {h: HorizonSkill(*(_num(getattr(x, k)) for w in HorizonSkill.WHO for k in (w, f"{w}_worst")))
                              for h, x in c.horizons.items()})
                  for c in (res.comparison.roles if res.comparison is not None else [])]
    return DiagnosisResult(
        kind="rig", verdict=res.verdict, fit=res.fit, fit_before=res.fit_before, warnings=list(res.warnings),
        selected=list(res.selected),
        parameters=_parameters(res.parameters, res.uncertainties if sigma is None else sigma),
        before=res.before, after=res.after, location_evidence=list(res.location_evidence),
        calibrated_fmu=res.calibrated_fmu, comparison=comparison, segments=segments, checks=checks,
        reasons=list(res.reasons), written=[Path(p) for p in res.written], extra=res.own_keys())
