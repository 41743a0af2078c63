"""The real-rig path's stage results (:mod:`.real_rig`), typed: dataclasses whose ``to_json()`` is the
part of ``diagnosis.json`` (docs/diagnosis-json.md, "A real rig's keys besides") each stage writes.

- :class:`RigCalibration`: :func:`~.real_rig.calibrate` (the force law, the mechanics' terms and the
  filter's disturbance model on the gap predicted ahead);
- :class:`RigFigures` (with :class:`RigHorizon` per horizon and :class:`RigDrift`): :func:`~.real_rig.figures`
  of one segment;
- :class:`RigSearch` (with an :class:`EffectTrial` per candidate tried): :func:`~.real_rig.effect_search`;
- :class:`RigCorrection`: :func:`~.real_rig.correction_search` (the located correction at the mechanics);
- :class:`RigComparison`: :func:`~.real_rig.comparison` (model / black box / naive per role and horizon);
- :class:`RigCoilCalibration`: :func:`~.real_rig.calibrate_coil` (the coil on the current computed from the
  actuator signal);
- :class:`RigForceBalance`, :class:`ControllerCheck`, :class:`ClosedLoopFigures`: what a record says of the rig
  file and of a declared controller (:func:`~.real_rig.force_balance`, :func:`~.real_rig.controller_check`,
  :func:`~.real_rig.closed_loop_figures`);
- :class:`RigRun`: :func:`~.real_rig.run`, every stage of the path, with a :class:`RigRecordResult` per
  calibration record (its :class:`RigSegment` each) and a :class:`RigValidationSegment` per validation
  segment; :func:`~.result.from_rig` makes the :class:`~.result.DiagnosisResult` of it.

``to_json()`` gives the stage's keys and values as they are written (non-finite numbers kept: the
diagnosis's :func:`~.result.finite` makes them ``null``), in the file's order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .result import CalibratedFmu, Comparison, Fit, HorizonSkill, Json, LocationEvidence, Residual, from_rig


@dataclass
class RigCalibration:
    """What :func:`~.real_rig.calibrate` found: one parameter set for several segments, by the
    prediction-error method.

    Attributes
    ----------
    names : list of str
        The calibrated parameters (FMU variable names), in the fit's order.
    values : dict of str to float
        Their calibrated values [SI, each parameter's unit].
    rig_values : dict of str to float
        Their starting values (the rig file's, or those of the stage before) [SI].
    noise : dict
        The filter's disturbance model after the fit: ``q_force`` [N], ``f_force`` [Hz], ``r_sensor``
        [MU], ``r_current`` [A] (and the located ``correction`` when one was given).
    sigma : dict of str to float
        ±1σ of ``values`` from the Jacobian at the solution [SI] (a lower bound: the errors of
        overlapping horizons are correlated).
    horizons_s : list of float
        The prediction horizons whose errors were minimised [s].
    cost_before, cost_after : float
        The least-squares cost at the start and at the solution [1].
    evaluations : int
        Cost evaluations (replays of every segment).
    on_bounds : list of str
        Calibrated parameters that ended on a bound of their search.
    noise_on_bounds : list of str
        Disturbance-model terms that ended on a bound.
    """

    names: list[str]
    values: dict[str, float]
    rig_values: dict[str, float]
    noise: dict[str, Any]
    sigma: dict[str, float]
    horizons_s: list[float]
    cost_before: float
    cost_after: float
    evaluations: int
    on_bounds: list[str]
    noise_on_bounds: list[str]

    def to_json(self) -> Json:
        return {"names": list(self.names), "values": dict(self.values), "rig_values": dict(self.rig_values),
                "noise": dict(self.noise), "sigma": dict(self.sigma), "horizons_s": list(self.horizons_s),
                "cost_before": self.cost_before, "cost_after": self.cost_after, "evaluations": self.evaluations,
                "on_bounds": list(self.on_bounds), "noise_on_bounds": list(self.noise_on_bounds)}


@dataclass
class RigDrift:
    """The filtered random force on the ball as a drift (:func:`~.real_rig.drift`).

    Attributes
    ----------
    t_s : list of float
        The blocks' centres from the segment's start [s].
    force_pct_weight : list of float
        The force's mean over each block [% of the ball's weight].
    two_sigma_pct_weight : list of float
        Its ±2σ (the filter's own standard deviation) [% of the weight].
    change_pct_weight : float or None
        The change from the first to the last block [% of the weight] (None: fewer than two blocks).
    change_two_sigma : float or None
        The two blocks' combined 2σ [% of the weight].
    significant : bool or None
        Whether the change exceeds that 2σ (a finding).
    range_pct_weight : list of float or None
        The least and largest block mean [% of the weight].
    """

    t_s: list[float]
    force_pct_weight: list[float]
    two_sigma_pct_weight: list[float]
    change_pct_weight: float | None = None
    change_two_sigma: float | None = None
    significant: bool | None = None
    range_pct_weight: list[float] | None = None

    def to_json(self) -> Json:
        out: Json = {"t_s": list(self.t_s), "force_pct_weight": list(self.force_pct_weight),
                     "two_sigma_pct_weight": list(self.two_sigma_pct_weight)}
        if self.change_pct_weight is not None:
            out.update(change_pct_weight=self.change_pct_weight, change_two_sigma=self.change_two_sigma,
                       significant=self.significant, range_pct_weight=list(self.range_pct_weight or []))
        return out


@dataclass
class RigHorizon:
    """The gap of one segment predicted at one horizon (:func:`~.real_rig.figures`).

    Attributes
    ----------
    model : float
        NRMSE fit [%] of the model in closed loop with the identified controller (or driven by the
        actuator signal when none could be identified).
    stays_put : float
        NRMSE fit [%] of "stays put".
    model_measured_input : float
        NRMSE fit [%] of the model driven by the measured actuator signal.
    rms_y : float
        RMS error of the model's prediction of the reading [MU] (NaN: no prediction counted).
    rms_y_measured_input : float
        The same, driven by the measured actuator signal [MU].
    constant_velocity : float
        NRMSE fit [%] of "constant velocity".
    skill_vs_stays_put : float
        The model's skill against "stays put" [1] (> 0: better).
    skill : dict of str to float
        Skill against "stays put" [1] of each predictor: ``model``, ``model_measured_input``,
        ``constant_velocity``, and with a black box ``black_box``, ``black_box_past``,
        ``model_on_position``.
    black_box : float or None
        NRMSE fit [%] of the black box on the record's position (None: no black box).
    """

    model: float
    stays_put: float
    model_measured_input: float
    rms_y: float
    rms_y_measured_input: float
    constant_velocity: float
    skill_vs_stays_put: float
    skill: dict[str, float]
    black_box: float | None = None

    def to_json(self) -> Json:
        out: Json = {"model": self.model, "stays_put": self.stays_put, "model_measured_input": self.model_measured_input,
                     "rms_y": self.rms_y, "rms_y_measured_input": self.rms_y_measured_input,
                     "constant_velocity": self.constant_velocity, "skill_vs_stays_put": self.skill_vs_stays_put,
                     "skill": dict(self.skill)}
        if self.black_box is not None:
            out["black_box"] = self.black_box
        return out


@dataclass
class RigFigures:
    """The fit figures of one segment (:func:`~.real_rig.figures`).

    Attributes
    ----------
    label : str
        The segment (record label and its time span).
    samples : int
        Its samples.
    duration_s : float
        Its duration [s].
    position : dict of str to RigHorizon
        The gap predicted ahead, by horizon (``"5 ms"``, ``"20 ms"``, ``"50 ms"``).
    identified_controller : dict
        The controller identified from the segment (:meth:`~.reaction.ReactionPrediction.to_json`), or
        ``{"missing": why}``.
    drift : RigDrift or None
        The filtered random force's drift through the segment.
    current : dict of str to float or None
        NRMSE fit [%] of the coil current from the actuator signal alone (``from_actuator``) and
        predicted ahead (by horizon); the white noise of its residual [A] (``noise_A``,
        :func:`~.metrics.white_noise_rms`: the measured current's own noise, or a bound on it) and the fit
        that noise alone allows [%] (``noise_ceiling``, :func:`~.metrics.fit_ceiling`); None without a
        measured current.
    """

    label: str
    samples: int
    duration_s: float
    position: dict[str, RigHorizon]
    identified_controller: dict[str, Any]
    drift: RigDrift | None
    current: dict[str, float] | None

    def to_json(self) -> Json:
        out: Json = {"label": self.label, "samples": self.samples, "duration_s": self.duration_s,
                     "position": {h: p.to_json() for h, p in self.position.items()},
                     "identified_controller": self.identified_controller}
        if self.drift is not None:
            out["drift"] = self.drift.to_json()
        out["current"] = None if self.current is None else dict(self.current)
        return out


@dataclass
class EffectTrial:
    """One candidate of the effect search tried in one round (:func:`~.real_rig.effect_search`).

    Attributes
    ----------
    round : int
        The greedy round (from 1).
    effect : str
        The effect (``a+b`` for a pair fitted jointly).
    parameter : str
        Its parameters, comma-separated.
    value : float
        The first parameter's fitted value [SI].
    values : dict of str to float
        Every value it sets: its parameters' and those it computes from the records [SI].
    location : str
        Where in the loop it acts (``+``-joined for a pair).
    held_out_gain : float
        The share of the held-out prediction cost it removes, the one that counts [1] (> 0: better).
    held_out_gains : dict of str to float
        The same per signal (``y``: the gap, ``i``: the current) [1].
    effects : list of str or None
        A pair's effects (None for one effect).
    screened : str or None
        Why it was reported off without a fit (no start lowered the fit blocks' cost enough).
    start_fit_gain : float or None
        Its best start's gain on the fit blocks [1] (None for a pair).
    """

    round: int
    effect: str
    parameter: str
    value: float
    values: dict[str, float]
    location: str
    held_out_gain: float
    held_out_gains: dict[str, float]
    effects: list[str] | None = None
    screened: str | None = None
    start_fit_gain: float | None = None

    def to_json(self) -> Json:
        out: Json = {"round": self.round, "effect": self.effect, "parameter": self.parameter, "value": self.value,
                     "values": dict(self.values), "location": self.location, "held_out_gain": self.held_out_gain,
                     "held_out_gains": dict(self.held_out_gains)}
        if self.effects is not None:
            out["effects"] = list(self.effects)
        if self.screened is not None:
            out["screened"] = self.screened
        if self.start_fit_gain is not None:
            out["start_fit_gain"] = self.start_fit_gain
        return out


@dataclass
class RigSearch:
    """The catalogue's effects tried on the calibrated model (:func:`~.real_rig.effect_search`).

    Attributes
    ----------
    held_out_cost : dict of str to float
        The prediction cost on the odd (held-out) blocks of the model without an effect: ``y``, ``i``,
        ``total`` [1].
    block_s : float
        The blocks' length [s].
    min_gain : float
        The held-out gain an effect needs to be selected [1].
    offered : dict of str to (str or None)
        Every catalogue entry and extra: None where offered to the rig, else why not.
    skipped : list of str
        Offered, but not tried: the calibration fits a parameter of theirs.
    candidates : list of EffectTrial
        Every candidate tried, round by round.
    selected : list of str
        The selected effects, in order.
    parameters : dict of str to float
        The selected effects' fitted values [SI].
    computed : dict of str to float
        Values the selected effects computed from the records (the force exponent's pivot) [SI].
    last_round_empty : bool
        Whether the last round selected nothing.
    taken_off : dict of str to float
        Parameters of effects the search selected and the joint refit with the force law took to off,
        with the value the refit ended on [SI] (:func:`~.real_rig.refit_took_off`).
    """

    held_out_cost: dict[str, float]
    block_s: float
    min_gain: float
    offered: dict[str, str | None]
    skipped: list[str]
    candidates: list[EffectTrial] = field(default_factory=list)
    selected: list[str] = field(default_factory=list)
    parameters: dict[str, float] = field(default_factory=dict)
    computed: dict[str, float] = field(default_factory=dict)
    last_round_empty: bool = False
    taken_off: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> Json:
        return {"held_out_cost": dict(self.held_out_cost), "block_s": self.block_s, "min_gain": self.min_gain,
                "offered": dict(self.offered), "skipped": list(self.skipped),
                "candidates": [c.to_json() for c in self.candidates], "selected": list(self.selected),
                "parameters": dict(self.parameters), "computed": dict(self.computed),
                "last_round_empty": self.last_round_empty, "taken_off": dict(self.taken_off)}


@dataclass
class RigCorrection:
    """The located correction at the mechanics (:func:`~.real_rig.correction_search`): a force on
    the ball of gap and velocity, fitted and judged on the held-out blocks like an effect.

    Attributes
    ----------
    basis : dict
        The correction's basis (:func:`~.real_rig.correction_basis` without coefficients): ``n_x``,
        the position's centre ``x_c`` and half width ``x_s`` [m], the velocity scale ``v_s`` and the
        friction's smoothing ``v_c`` [m/s], ``p_mean`` (the position terms' mean).
    shapes : list of str
        The velocity shapes, in the order of each position term's coefficients.
    ridge : float
        The ridge weight kept (lowest held-out cost) [1].
    held_out_cost_without : float
        The held-out cost without a correction [1].
    held_out : dict
        The held-out cost ``by_ridge`` (per ridge weight) and ``by_shape`` (``all`` and each velocity
        shape alone) [1].
    held_out_gain : float
        The share of the held-out cost the correction removes [1] (> 0: better).
    held_out_gain_by_shape : dict of str to float
        The same for each shape alone [1].
    min_gain : float
        The held-out gain needed to use it [1].
    selected : bool
        Whether it is used in the model.
    correction : dict or None
        The correction ready for the model (basis and ``coef``), None when not selected.
    coef : list of float
        Its coefficients refitted on every block [N].
    sigma : list of float
        Their ±1σ [N] (a lower bound: overlapping horizons' errors are correlated).
    cost_before, cost_after : float
        The cost on every block before and after the refit [1].
    evaluations : int
        Replays made.
    summary : dict
        What it says in the record's convention (:func:`~.real_rig.correction_summary`).
    """

    basis: dict[str, Any]
    shapes: list[str]
    ridge: float
    held_out_cost_without: float
    held_out: dict[str, dict[str, float]]
    held_out_gain: float
    held_out_gain_by_shape: dict[str, float]
    min_gain: float
    selected: bool
    correction: dict[str, Any] | None
    coef: list[float]
    sigma: list[float]
    cost_before: float
    cost_after: float
    evaluations: int
    summary: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> Json:
        return {"basis": dict(self.basis), "shapes": list(self.shapes), "ridge": self.ridge,
                "held_out_cost_without": self.held_out_cost_without,
                "held_out": {k: dict(v) for k, v in self.held_out.items()}, "held_out_gain": self.held_out_gain,
                "held_out_gain_by_shape": dict(self.held_out_gain_by_shape), "min_gain": self.min_gain,
                "selected": self.selected, "correction": None if self.correction is None else dict(self.correction),
                "coef": list(self.coef), "sigma": list(self.sigma), "cost_before": self.cost_before,
                "cost_after": self.cost_after, "evaluations": self.evaluations, "summary": dict(self.summary)}


@dataclass
class RigComparison:
    """Median (and worst) skill against "stays put" of the model, the black boxes and "constant
    velocity", per role (``calibration``, ``validation``) and horizon (:func:`~.real_rig.comparison`).

    Attributes
    ----------
    roles : list of Comparison
        One per role with segments, in that order (skills [1]; NaN where no segment had one).
    """

    roles: list[Comparison] = field(default_factory=list)

    def get(self, role: str) -> Comparison | None:
        """The comparison over ``role``'s segments, or None."""
        return next((c for c in self.roles if c.role == role), None)

    def to_json(self) -> Json:
        return {c.role: c.to_json() for c in self.roles}

    @classmethod
    def from_json(cls, d: dict | None) -> RigComparison:
        """From :meth:`to_json` (or ``diagnosis.json``'s ``comparison``)."""
        return cls([Comparison(role, c["segments"],
                               {h: HorizonSkill(**{k: x.get(k) for w in HorizonSkill.WHO for k in (w, f"{w}_worst")})
                                for h, x in c.items() if h != "segments"})
                    for role, c in (d or {}).items()])



@dataclass
class RigForceBalance:
    """How much of the ball's weight a force law carries at a record's measured gap and current
    (:func:`~.real_rig.force_balance`), over the samples where the ball is off both stops.

    Attributes
    ----------
    p10, median, p90 : float
        Percentiles of the force over the weight, ``F/(m·g)`` [1].
    samples : int
        The levitating samples.
    consistent : bool
        Whether the median lies within :data:`~.real_rig.FORCE_BALANCE`.
    current_scale_for_weight : float
        The factor on the recorded current that would carry the weight [1] (NaN: none).
    ohm : dict or None
        A voltage drive: where the current settles, the median of the rig file's coil voltage over
        ``R·i`` (``median_V_over_Ri`` [1]) and its ``samples``; None otherwise.
    """

    p10: float
    median: float
    p90: float
    samples: int
    consistent: bool
    current_scale_for_weight: float
    ohm: dict[str, float] | None = None

    def to_json(self) -> Json:
        out: Json = {"p10": self.p10, "median": self.median, "p90": self.p90, "samples": self.samples,
                     "consistent": self.consistent, "current_scale_for_weight": self.current_scale_for_weight}
        if self.ohm is not None:
            out["ohm"] = dict(self.ohm)
        return out


@dataclass
class ControllerCheck:
    """A declared controller replayed alone on a record's measured signals (:func:`~.real_rig.controller_check`).

    Attributes
    ----------
    actuator_fit : float
        NRMSE fit [%] of the recorded actuator signal, from the better start.
    start : str
        That start: ``settled`` or ``rest``.
    fits_by_start : dict of str to float
        The fit [%] from each start.
    loops : dict of str to dict
        A cascade fed the recorded signals, loop by loop: ``fit`` [%] and the RMS error (``rms_A`` [A],
        ``rms_input_units`` [the actuator's unit]); empty otherwise.
    """

    actuator_fit: float
    start: str
    fits_by_start: dict[str, float]
    loops: dict[str, dict[str, float]] = field(default_factory=dict)

    def to_json(self) -> Json:
        return {"actuator_fit": self.actuator_fit, "start": self.start, "fits_by_start": dict(self.fits_by_start),
                "loops": {k: dict(v) for k, v in self.loops.items()}}


@dataclass
class ClosedLoopFigures:
    """A declared controller in closed loop with the model on one segment, by prediction
    (:func:`~.real_rig.closed_loop_figures`).

    Attributes
    ----------
    label : str
        The segment.
    horizon_s : float
        The prediction horizon [s].
    gap_fit : float
        NRMSE fit [%] of the gap's reading predicted ``horizon_s`` ahead.
    actuator_fit : float
        NRMSE fit [%] of the actuator signal predicted ``horizon_s`` ahead.
    """

    label: str
    horizon_s: float
    gap_fit: float
    actuator_fit: float

    def to_json(self) -> Json:
        return {"label": self.label, "horizon_s": self.horizon_s, "gap_fit": self.gap_fit,
                "actuator_fit": self.actuator_fit}


@dataclass
class RigCoilCalibration:
    """What :func:`~.real_rig.calibrate_coil` found: the coil's parameters that make the current computed
    from the actuator signal alone fit the measured current.

    Attributes
    ----------
    names : list of str
        The fitted parameters (FMU variable names).
    values : dict of str to float
        Their fitted values [SI].
    sigma : dict of str to float
        Their ±1σ [SI] (widened for the residual's correlation from sample to sample).
    fit : dict of str to float
        NRMSE fit [%] of the current from the actuator signal, per segment label.
    on_bounds : list of str
        Parameters that ended on a bound of their search.
    """

    names: list[str]
    values: dict[str, float]
    sigma: dict[str, float]
    fit: dict[str, float]
    on_bounds: list[str]

    def to_json(self) -> Json:
        return {"names": list(self.names), "values": dict(self.values), "sigma": dict(self.sigma),
                "fit": dict(self.fit), "on_bounds": list(self.on_bounds)}


@dataclass
class RigSegment:
    """One levitation segment of a calibration record (:func:`~.real_rig.run`).

    Attributes
    ----------
    label : str
        The segment.
    after : RigFigures
        Its figures with the calibrated model (its own coil and force gain).
    before : RigFigures or None
        Its figures with the rig file's values.
    own_coil : dict of str to float or None
        The coil fitted on this segment alone [SI] (and ``kappa_R_sigma``, ``force_gain_factor``
        where found); None without a calibration or a measured current.
    own_calibration : dict of str to float or None
        Its own coil and the force law's gain calibrated on it alone [SI] (several records only).
    frequency_response : dict or None
        The measured current-to-gap response against the model's on 1–20 Hz
        (:func:`~.real_rig.current_to_position`'s ``summary``); None without a measured current.
    """

    label: str
    after: RigFigures
    before: RigFigures | None = None
    own_coil: dict[str, float] | None = None
    own_calibration: dict[str, float] | None = None
    frequency_response: dict[str, Any] | None = None

    def to_json(self) -> Json:
        out: Json = {"label": self.label, "before": self.before.to_json() if self.before else None,
                     "after": self.after.to_json(), "own_coil": self.own_coil}
        if self.own_calibration is not None:
            out["own_calibration"] = self.own_calibration
        out["frequency_response"] = self.frequency_response
        return out


@dataclass
class RigValidationSegment:
    """One levitation segment of a validation record (not used to calibrate; :func:`~.real_rig.run`).

    Attributes
    ----------
    file : str
        The record's file.
    label : str
        The segment.
    after : RigFigures
        Its figures with the calibrated model (its own coil).
    warnings : list of str
        The record's warnings.
    force_balance_calibrated : RigForceBalance or None
        The share of the weight the calibrated force law carries at the record's gap and current.
    own_coil : dict of str to float or None
        The coil fitted on this segment alone [SI].
    before : RigFigures or None
        Its figures with the rig file's values.
    """

    file: str
    label: str
    after: RigFigures
    warnings: list[str]
    force_balance_calibrated: RigForceBalance | None = None
    own_coil: dict[str, float] | None = None
    before: RigFigures | None = None

    def to_json(self) -> Json:
        return {"file": self.file, "label": self.label, "before": self.before.to_json() if self.before else None,
                "after": self.after.to_json(), "warnings": list(self.warnings),
                "force_balance_calibrated": self.force_balance_calibrated.to_json() if self.force_balance_calibrated
                else None, "own_coil": self.own_coil}


@dataclass
class RigRecordResult:
    """One calibration record (:func:`~.real_rig.run`).

    Attributes
    ----------
    file : str
        Its file.
    label : str
        Its label.
    warnings : list of str
        The reader's warnings.
    segments : list of RigSegment
        Its levitation segments.
    force_balance : RigForceBalance or None
        The share of the weight the rig file's force law carries at the measured gap and current (None:
        no measured current, or no levitating samples).
    controller_check : ControllerCheck or None
        The declared controller replayed on the record; None without one.
    closed_loop : list of ClosedLoopFigures or None
        The declared controller in closed loop with the model, per segment; None without one.
    """

    file: str
    label: str
    warnings: list[str]
    segments: list[RigSegment] = field(default_factory=list)
    force_balance: RigForceBalance | None = None
    controller_check: ControllerCheck | None = None
    closed_loop: list[ClosedLoopFigures] | None = None

    def to_json(self) -> Json:
        out: Json = {"file": self.file, "label": self.label, "warnings": list(self.warnings),
                     "segments": [s.to_json() for s in self.segments],
                     "force_balance": self.force_balance.to_json() if self.force_balance else None}
        if self.controller_check is not None:
            out["controller_check"] = self.controller_check.to_json()
            out["closed_loop"] = [c.to_json() for c in self.closed_loop or []]
        return out


@dataclass
class RigRun:
    """Every stage of the real-rig path (:func:`~.real_rig.run`); :func:`~.result.from_rig` makes the
    :class:`~.result.DiagnosisResult` of it. Optional stages are None where they did not run.

    Attributes
    ----------
    rig, rig_file : str
        The rig's name and its rig file.
    fit_segments : int
        Segments with enough information to calibrate on (0: nothing calibrated; not in the JSON).
    records : list of RigRecordResult
        The calibration records.
    validation : list of RigValidationSegment
        The validation records' segments.
    horizons_s : list of float
        The figures' prediction horizons [s].
    coil_calibration : RigCoilCalibration or None
        The coil stage (None: no measured current).
    effects : RigSearch or None
        The effect search.
    second_force_lag : dict or None
        The second force lag's fit (``mode``, ``values``, ``sigma``, ``on_bounds``), when fitted.
    correction : RigCorrection or None
        The located correction at the mechanics.
    calibration : RigCalibration or None
        The last calibration of the force law, the mechanics and the disturbance model.
    disturbance_model : dict of str to float
        The filter's disturbance model: ``q_force`` [N], ``f_force`` [Hz], ``r_sensor`` [MU],
        ``r_current`` [A].
    black_box_error : str or None
        Why the black box could not be fitted.
    black_box : dict or None
        The black box's ridge weight, samples and features per horizon.
    comparison : RigComparison or None
        Model / black box / naive per role and horizon.
    controller : dict or None
        The declared controller (``name``, ``file``, ``type``).
    verdict : str
        The verdict.
    reasons : list of str
        Its reasons.
    coil_drift, spread : dict or None
        Each segment's own coil's, and each record's own force gain's, spread between them.
    parameters : dict of str to float
        The final model's calibrated parameters [SI].
    fit, fit_before : Fit or None
        NRMSE fit [%] of the gap and the current 20 ms ahead, after and before the calibration (median).
    warnings : list of str
        The records' warnings.
    selected : list of str
        The selected effects.
    uncertainties : dict of str to float
        ±1σ of the calibrated parameters [SI].
    before, after : Residual or None
        RMS of the 20 ms prediction error of the reading [MU], before and after.
    location_evidence : list of LocationEvidence
        The best held-out cost change per location among the effects tried.
    calibrated_fmu : CalibratedFmu or None
        The calibrated FMU written (None: nothing calibrated worth one).
    written : list of str
        The files written (``diagnosis.json`` named first, written by the caller).
    """

    rig: str
    rig_file: str
    fit_segments: int = 0
    records: list[RigRecordResult] = field(default_factory=list)
    validation: list[RigValidationSegment] = field(default_factory=list)
    horizons_s: list[float] = field(default_factory=list)
    coil_calibration: RigCoilCalibration | None = None
    effects: RigSearch | None = None
    second_force_lag: dict[str, Any] | None = None
    correction: RigCorrection | None = None
    calibration: RigCalibration | None = None
    disturbance_model: dict[str, float] = field(default_factory=dict)
    black_box_error: str | None = None
    black_box: dict[str, dict[str, float]] | None = None
    comparison: RigComparison | None = None
    controller: dict[str, str] | None = None
    verdict: str = ""
    reasons: list[str] = field(default_factory=list)
    coil_drift: dict[str, dict[str, float]] | None = None
    spread: dict[str, dict[str, float]] | None = None
    parameters: dict[str, float] = field(default_factory=dict)
    fit: Fit | None = None
    fit_before: Fit | None = None
    warnings: list[str] = field(default_factory=list)
    selected: list[str] = field(default_factory=list)
    uncertainties: dict[str, float] = field(default_factory=dict)
    before: Residual | None = None
    after: Residual | None = None
    location_evidence: list[LocationEvidence] = field(default_factory=list)
    calibrated_fmu: CalibratedFmu | None = None
    written: list[str] = field(default_factory=list)

    def own_keys(self) -> dict[str, Any]:
        """The path's own keys of ``diagnosis.json`` (those :class:`~.result.DiagnosisResult` does not
        type), in the file's order, each as its stage's typed result."""
        out: dict[str, Any] = {"rig": self.rig, "rig_file": self.rig_file, "records": self.records,
                               "validation": self.validation, "horizons_s": self.horizons_s}
        if self.fit_segments:
            out["coil_calibration"] = self.coil_calibration
        for key in ("effects", "second_force_lag", "correction"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        out["calibration"] = self.calibration
        out["disturbance_model"] = self.disturbance_model
        if self.black_box_error is not None:
            out["black_box_error"] = self.black_box_error
        if self.fit_segments:
            out["black_box"] = self.black_box
        for key in ("controller", "coil_drift", "spread"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        return out

    def to_json(self) -> Json:
        """``diagnosis.json`` of the run (:meth:`~.result.DiagnosisResult.to_json` of :func:`~.result.from_rig`)."""
        return from_rig(self).to_json()
