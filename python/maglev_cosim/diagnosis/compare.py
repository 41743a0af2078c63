"""The model, the black box and the naive predictors side by side, per horizon, on a CE152 record.

A MATLAB user judges a grey-box model against ``arx`` / ``n4sid`` models fitted on the same data
(``compare`` with a prediction horizon). This stage does it for every CE152 diagnosis, with the
predictors of :mod:`.blackbox` and the same figure, the skill against "stays put"
(:func:`~.blackbox.skill`), at 5, 20 and 50 ms:

- **model (closed loop)**: the final model and the record's declared controller. A Kalman filter on
  the C plant follows the measured past; from each sample the plant and the controller run on
  their own predicted readings, driven by the recorded reference alone
  (``maglev_replay_predict_closed``);
- **model (measured input)**: the same filter, its predictions driven by the recorded actuator
  signal ``u`` up to the predicted instant: the predictor of a record whose controller is unknown
  (a real rig's, :mod:`.real_rig`);
- **black box**: one ridge regression per horizon on the last 30 ms of reading differences and on
  ``u`` and ``u²`` up to the predicted instant (:mod:`.blackbox`), fitted on the record's fit
  blocks only; and the same regression with ``u`` only up to the prediction's start
  (``black_box_past``);
- **constant velocity**.

The figures count on the held-out blocks (the ones no fit saw, :func:`~.acceptance.fit_blocks`),
predictions that start and end inside one, from the filter's first 0.5 s on.

Why two model predictors: in a closed loop the actuator signal up to the predicted instant holds
the controller's reaction to everything that moved the ball meanwhile (the random force, the
sensor noise it read). A predictor fed that signal reads part of the answer off it; the physics
driven by it cannot, because it runs the unstable plant forward from an uncertain state. So even
the true model, driven by ``u``, trails this black box at 50 ms (docs/diagnosis.md, "Model against
black box"), and the closed-loop prediction, which sees no measurement after its start, is the
model's own figure wherever the controller is known.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from ..loop import fast_loop
from ..plant import fast
from ..records.measured import true_runs
from ..records.record import Record
from . import blackbox as bb
from .acceptance import fit_blocks
from .problem import on_fit_steps
from .replay import NoiseModel, _settled_at_first_reading, record_controller
from .result import Comparison, HorizonSkill, Json, SegmentFigures

#: Horizons of the comparison [s].
HORIZONS_S = (0.005, 0.020, 0.050)
#: Samples at the record's start the figures skip while the filter settles [s].
SETTLE_S = 0.5
#: A prediction from every STRIDE-th sample (the skills are ratios of norms over thousands of them).
STRIDE = 2
#: Who is compared, in the tables' order.
WHO = ("model", "model_measured_input", "black_box", "black_box_past", "constant_velocity")


@dataclass
class RecordComparison:
    """The skills against "stays put" per role (``fit blocks``, ``held-out blocks``), horizon and
    predictor (:data:`WHO`), and the black box's ridge weights."""

    skills: dict[str, dict[str, dict[str, float]]]
    horizons_s: tuple[float, ...]
    samples: dict[str, int]
    black_box_missing: dict[str, str] = field(default_factory=dict)   #: horizon -> why no black box

    def comparisons(self) -> list[Comparison]:
        """As the typed result's :class:`~.result.Comparison` (model = the closed loop), per role."""
        return [Comparison(role, 1, {h: HorizonSkill(*(v[w] for w in HorizonSkill.WHO for _ in (0, 1)))
                                     for h, v in per_h.items()})
                for role, per_h in self.skills.items()]

    def segments(self, label: str) -> list[SegmentFigures]:
        return [SegmentFigures(label, role, None, {h: v["model"] for h, v in per_h.items()})
                for role, per_h in self.skills.items()]

    def to_json(self) -> Json:
        return {"horizons_s": list(self.horizons_s), "stride": STRIDE, "samples": self.samples,
                "skill_vs_stays_put": self.skills, "black_box_missing": self.black_box_missing}

    def table(self) -> list[str]:
        """Markdown: one row per role and horizon."""
        lines = ["| blocks | horizon | model (closed loop) | model (driven by u) | black box | black box, u up to the "
                 "start | constant velocity |", "|---|---|---|---|---|---|---|"]
        for role, per_h in self.skills.items():
            for h, v in per_h.items():
                lines.append(f"| {role} | {h} | " + " | ".join(_cell(v[w]) for w in WHO) + " |")
        for h, why in self.black_box_missing.items():
            lines += ["", f"No black box at {h}: {why}."]
        return lines


def _cell(v: float) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{v:+.2f}"


def _runs(mask: np.ndarray) -> list[slice]:
    """The contiguous runs of True in ``mask``, as slices."""
    return [slice(a, b) for a, b in true_runs(mask)]


Boxes = dict  # horizon [s] -> (black box, black box reading u only up to the start), see fit_boxes


def fit_boxes(recs: Sequence[Record], horizons_s: tuple[float, ...] = HORIZONS_S) -> tuple[Boxes, dict[str, str]]:
    """Both black boxes per horizon, fitted on whole records (leave-one-record-out ridge weights),
    and why a horizon has none (records too short)."""
    boxes, notes = {}, {}
    with threadpool_limits(limits=1):
        for hs_s in horizons_s:
            train = [bb.Series(r.y, r.u, r.ts) for r in recs]
            try:
                boxes[hs_s] = (bb.fit(train, hs_s), bb.fit(train, hs_s, future=False))
            except ValueError as e:
                notes[f"{hs_s * 1e3:g} ms"] = str(e)
    return boxes, notes


@dataclass
class BlackBoxPredictions:
    """What the comparison needs of the black boxes (model-free, so computed while the diagnosis runs,
    :func:`black_box_predictions`): per horizon [s], the predictions of both (NaN where none) and why a
    horizon has none."""

    horizons_s: tuple[float, ...]
    predictions: dict[float, tuple[np.ndarray, np.ndarray]]
    missing: dict[str, str]


def black_box_predictions(rec: Record, horizons_s: tuple[float, ...] = HORIZONS_S, *,
                          boxes: Boxes | None = None) -> BlackBoxPredictions:
    """Both black boxes' predictions of ``rec`` per horizon: fitted on its fit blocks (or ``boxes``,
    fitted on other records, :func:`fit_boxes`), each predicting within each block from that block's
    own past only, as they were fitted; a record too short to fit one has none (NaN, and the reason).
    They need no model: :func:`maglev_cosim.diagnosis.diagnose` computes them beside the verdict (on a
    thread of its own, inside its own one-thread BLAS limit, so that this one's restores the same)."""
    with threadpool_limits(limits=1):      # as compare: small systems, which BLAS threads only slow down
        return _black_box_predictions(rec, horizons_s, boxes)


def _black_box_predictions(rec: Record, horizons_s: tuple[float, ...], boxes: Boxes | None) -> BlackBoxPredictions:
    fit = fit_blocks(rec.t) if boxes is None else np.ones(rec.n, bool)
    preds: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    notes: dict[str, str] = {}
    for hs_s in horizons_s:
        h = max(1, int(round(hs_s / rec.ts)))
        yb, yp = np.full(rec.n, np.nan), np.full(rec.n, np.nan)
        if boxes is None:
            try:
                train = [bb.Series(rec.y[s], rec.u[s], rec.ts) for s in _runs(fit)]
                pair = bb.fit(train, h * rec.ts), bb.fit(train, h * rec.ts, future=False)
            except ValueError as e:
                pair, notes[f"{hs_s * 1e3:g} ms"] = None, str(e)
        else:
            pair = boxes.get(hs_s)
        if pair is not None:
            for s in _runs(fit) + _runs(~fit):
                yb[s] = pair[0].predict(bb.Series(rec.y[s], rec.u[s], rec.ts))
                yp[s] = pair[1].predict(bb.Series(rec.y[s], rec.u[s], rec.ts))
        preds[hs_s] = (yb, yp)
    return BlackBoxPredictions(tuple(horizons_s), preds, notes)


def compare(rec: Record, params: Mapping[str, float], noise: NoiseModel,
            horizons_s: tuple[float, ...] = HORIZONS_S, *, boxes: Boxes | None = None,
            black_box: BlackBoxPredictions | None = None) -> RecordComparison:
    """The comparison of the module docstring for one CE152 record.

    Parameters
    ----------
    rec : Record
        The closed-loop record (its declared controller runs the closed-loop prediction).
    params : mapping
        The model's FMU parameter values [SI units].
    noise : NoiseModel
        The disturbances the filter assumes (the diagnosis's final estimate).
    horizons_s : tuple of float
        Prediction horizons [s].
    boxes : dict, optional
        Black boxes fitted on other records (:func:`fit_boxes`): the whole record is judged (one
        role, ``record``). Default: fitted on the record's fit blocks, judged on both kinds of block.
    black_box : BlackBoxPredictions, optional
        The black boxes' predictions, computed already (:func:`black_box_predictions` of the same
        record, horizons and ``boxes``).
    """
    # one BLAS thread: the black box's cross-validation solves hundreds of small systems, which
    # threads only slow down (and on a busy machine, by tens of times). The model's predictions run
    # on the fits' RK4 substeps, as the verdict's k-step figures do (problem.fit_solver_step: a few
    # thousandths of the noise from the plant's own 0.1 ms; the closed-loop predictions at three
    # horizons took 0.22 s of CPU at 0.1 ms on the bench's 12 s record)
    with threadpool_limits(limits=1):
        return _compare(rec, on_fit_steps(params), noise, horizons_s, boxes, black_box)


def _compare(rec: Record, params: Mapping[str, float], noise: NoiseModel,
             horizons_s: tuple[float, ...], boxes: Boxes | None,
             black_box: BlackBoxPredictions | None) -> RecordComparison:
    start, u_hold = _settled_at_first_reading(rec, params)
    hs = [max(1, int(round(h / rec.ts))) for h in horizons_s]
    kw = dict(q_force=noise.q_force, f_force=noise.f_force, r_sensor=noise.r_sensor, horizons=hs, stride=STRIDE,
              f_sensor=noise.f_sensor, r_coloured=noise.r_coloured)
    closed_kw = dict(kw, y_before=rec.y_before)
    # both predictions run in C, which cffi calls without the GIL: on two threads, while this one
    # fits the black boxes (their results are read where the skills are computed)
    with ThreadPoolExecutor(max_workers=2) as pool:
        jobs = (pool.submit(fast_loop.predict_closed, start, record_controller(rec), rec.w, rec.y, rec.u, u_hold, **closed_kw),
                pool.submit(fast.predict_horizons, start, rec.y, rec.u, ts=rec.ts, **kw))
        if black_box is None or tuple(black_box.horizons_s) != tuple(horizons_s):
            black_box = _black_box_predictions(rec, horizons_s, boxes)
        return _skills(rec, hs, horizons_s, boxes is not None, black_box, jobs)


def _skills(rec: Record, hs: list[int], horizons_s: tuple[float, ...], whole: bool, black_box: BlackBoxPredictions,
            jobs) -> RecordComparison:
    """:func:`_compare`'s figures; ``whole``: the record is judged as one (black boxes fitted on other
    records); ``jobs``: the futures of the closed-loop and the measured-input predictions."""
    closed: dict | None = None
    measured: dict | None = None
    fit = np.ones(rec.n, bool) if whole else fit_blocks(rec.t)
    roles = (("record", fit),) if whole else (("fit blocks", fit), ("held-out blocks", ~fit))
    k = np.arange(rec.n)
    skills: dict[str, dict[str, dict[str, float]]] = {role: {} for role, _ in roles}
    samples: dict[str, int] = {}
    for q, (h, hs_s) in enumerate(zip(hs, horizons_s)):
        yb, yp = black_box.predictions[hs_s]
        stay = bb.stays_put(rec.y, h)
        cv = bb.constant_velocity(rec.y, h, rec.ts)
        origin_same_block = np.zeros(rec.n, bool)       # (a horizon is far shorter than a block)
        origin_same_block[h:] = fit[h:] == fit[:-h]
        if closed is None or measured is None:
            closed, measured = jobs[0].result(), jobs[1].result()
        for role, blocks in roles:
            ok = (blocks & origin_same_block & (k >= h + int(round(SETTLE_S / rec.ts)))
                  & np.isfinite(closed["y_pred"][q]) & np.isfinite(measured["y_pred"][q]) & np.isfinite(cv)
                  & (np.isfinite(yb) | np.isnan(yb).all()))
            samples[role] = int(ok.sum())
            skills[role][f"{hs_s * 1e3:g} ms"] = {
                "model": bb.skill(rec.y, closed["y_pred"][q], stay, ok),
                "model_measured_input": bb.skill(rec.y, measured["y_pred"][q], stay, ok),
                "black_box": bb.skill(rec.y, yb, stay, ok) if np.isfinite(yb).any() else float("nan"),
                "black_box_past": bb.skill(rec.y, yp, stay, ok & np.isfinite(yp)) if np.isfinite(yp).any()
                else float("nan"),
                "constant_velocity": bb.skill(rec.y, cv, stay, ok)}
    return RecordComparison(skills, tuple(horizons_s), samples, dict(black_box.missing))
