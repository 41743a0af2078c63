"""The one entry point: :func:`diagnose` runs the stages (calibrate, effect search, verdict, location,
figures, report, calibrated FMU) on any record and returns a :class:`~.result.DiagnosisResult`.

It dispatches inside to the stage implementations of each record's path:

- a CE152 record (machine units, the controller declared in the record): the closed-loop replay
  and free run with that controller, the whole catalogue, the noise-floor verdict rules and the
  location of what is left (:func:`.pipeline.run`; report :mod:`.ce152_report`);
- a real rig's record (SI units, its rig file, the controller unknown or declared beside it): the
  prediction driven by the measured actuator signal, the calibration over every record given, the
  effects of the rig's drive, the comparison with a black box fitted on the same records and the
  validation records (:func:`.real_rig.run`).

``calibrate A B --validate C`` is this function over several records.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from threadpoolctl import threadpool_limits

from ..loop.fmu import ensure_fmu
from ..records.load import Recording, load
from ..records.measured import Measured
from ..records.record import Record
from ..rigs import Rig, load_rig
from . import joint, pipeline, real_rig
from .controller_form import identified
from .ce152_report import write_calibrated_fmu, write_report
from .compare import black_box_predictions, compare
from .result import CalibratedFmu, DiagnosisResult, RecordRef, from_ce152, from_rig

Say = Callable[[str], None]
Records = Recording | Record | Measured | str | os.PathLike


def _recording(r: Records, rig: Rig | None) -> Recording:
    """Any accepted form of a record as a :class:`Recording` (a path is read with :func:`load`)."""
    if isinstance(r, Recording):
        return r
    if isinstance(r, Record):
        return Recording(Path(r.path), "ce152", ce152=r, warnings=list(r.warnings))
    if isinstance(r, Measured):
        if rig is None:
            raise ValueError(f"{r.path}: a real rig's record needs its rig (rig=...)")
        return Recording(r.path, r.fmt, measured=r, rig=rig, warnings=list(r.warnings))
    return load(r, rig)


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def diagnose(record_or_records: Records | Sequence[Records], *, rig: Rig | str | os.PathLike | None = None,
             validate: Sequence[Records] = (), effects: Sequence[str] | bool | None = None,
             out: str | os.PathLike | None = None, progress: Say | None = None, workers: int | None = None,
             fmu: str | os.PathLike | None = None, controller=None, per_record: bool | None = None,
             start: dict[str, float] | None = None, json_name: str = "diagnosis.json") -> DiagnosisResult:
    """Diagnoses one record, or calibrates on several and judges on ``validate``.

    Parameters
    ----------
    record_or_records : Recording, Record, Measured, path, or a sequence of them
        The record(s) (:func:`maglev_cosim.records.load.load` reads a path). One CE152 record is
        diagnosed on its own; several (or one with ``validate``) are calibrated together
        (:mod:`.joint`), as a real rig's records always are.
    rig : Rig or str, optional
        The rig of real records (a shipped name or a rig file); default: the records' own.
    validate : sequence
        Records the calibration is judged on and not fitted to.
    effects : sequence of str, or bool, optional
        CE152: the catalogue entries to try (default :data:`~.effects.DEFAULT_EFFECTS`). A real rig
        tries the effects its drive can take (:func:`~.real_rig.rig_candidates`: the catalogue entries
        that apply to its drive and force law), unless ``effects`` is False or empty; a list of names
        is refused for it.
    out : path, optional
        Where ``diagnosis.json`` (``json_name``), ``report.md``, ``report.html``, the plots and
        ``maglev_calibrated.fmu`` go; None: nothing is kept (a real rig's stages write into a
        temporary folder, removed).
    progress : callable, optional
        Called with a line of text at each step.
    workers : int, optional
        CE152: processes for the candidate fits (default 2, or 1 on a one-core machine).
    fmu : path, optional
        The plant FMU the CE152 calibrated FMU is made from (default: the installed one).
    controller : optional
        A real rig's declared controller (:func:`maglev_cosim.loop.controllers.load_controller`),
        checked against each record and replayed in closed loop.
    per_record : bool, optional
        A real rig: each record's own force gain too (default: with more than one record).
    start : mapping, optional
        CE152: starting values of the calibrated parameters.
    """
    many = isinstance(record_or_records, (list, tuple))
    given = list(record_or_records) if many else [record_or_records]
    if not given:
        raise ValueError("no record to diagnose")
    if isinstance(rig, (str, os.PathLike)):
        rig = None if str(rig) == "ce152" else load_rig(rig)
    the_rig = rig if rig is not None and rig.name != "ce152" else None
    recs = [_recording(r, the_rig) for r in given]
    held = [_recording(r, the_rig) for r in validate]
    kinds = {r.kind for r in [*recs, *held]}
    if len(kinds) > 1:
        raise ValueError("CE152 records and real rigs' records cannot be diagnosed together")
    if recs[0].kind == "ce152":
        if len(recs) > 1 or held:
            return _ce152_joint(recs, held, effects=effects, out=out, progress=progress, workers=workers, fmu=fmu,
                                json_name=json_name)
        return _ce152(recs[0], effects=effects, out=out, progress=progress, workers=workers, fmu=fmu, start=start,
                      json_name=json_name)
    return _rig(recs, held, rig=the_rig or recs[0].rig, effects=effects, out=out, progress=progress,
                controller=controller, per_record=len(recs) > 1 if per_record is None else per_record,
                json_name=json_name)


def _ce152(r: Recording, *, effects, out, progress, workers, fmu, start, json_name: str) -> DiagnosisResult:
    say = progress or (lambda s: None)
    names = None if effects is None or effects is True else ([] if effects is False else list(effects))
    fmu_in = ensure_fmu(fmu) if out is not None else None       # a missing FMU fails before the diagnosis
    rec = r.ce152
    say(f"diagnosing {rec.path}: {rec.n} samples, {rec.duration:.2f} s")
    # The black boxes need no model: they are fitted on a thread of their own once the search has
    # ended (no worker is forked after it), beside the verdict's estimates, which leave a core idle
    # part of the time. One BLAS thread for both, as each stage asks for itself.
    with threadpool_limits(limits=1), ThreadPoolExecutor(max_workers=1) as side:
        boxes: list[Future] = []
        d = pipeline.run(rec, effects=names, workers=workers, progress=progress, start=start,
                         searched=lambda read: boxes.append(side.submit(black_box_predictions, read)))
        rec = d.diagnosed   # from where its loop is settled, with its PID's form as it showed it (controller_form)
        cmp = None
        if d.verdict is not None:
            say("comparing the final model's predictions with the black box and the naive predictors (5, 20, 50 ms)")
            cmp = compare(rec, d.parameters, d.verdict.noise, black_box=boxes[-1].result() if boxes else None)
    if out is None:
        return from_ce152(d, None, [], cmp)
    out = Path(out)
    # no calibrated FMU of a calibration that failed: its parameters are not a model of the rig
    failed = d.verdict is not None and d.verdict.verdict == "calibration failed"
    fmu_out = None if failed else out / "maglev_calibrated.fmu"
    written = write_report(rec, d, out, fmu_out=fmu_out, fmu_refused=failed, comparison=cmp)
    written = [out / json_name, *written, *([fmu_out] if fmu_out else [])]
    cal = CalibratedFmu(str(fmu_out), [RecordRef(Path(rec.path).name, _sha256(Path(rec.path)))]) if fmu_out else None
    result = from_ce152(d, cal, written, cmp)
    (out / json_name).write_text(json.dumps(result.to_json(), indent=2, allow_nan=False) + "\n")
    if fmu_out is not None:
        write_calibrated_fmu(rec, d, fmu_in, fmu_out, out)      # its documentation holds diagnosis.json
    return result


def _ce152_joint(recs: list[Recording], held: list[Recording], *, effects, out, progress, workers, fmu,
                 json_name: str) -> DiagnosisResult:
    names = None if effects is None or effects is True else ([] if effects is False else list(effects))
    fmu_in = ensure_fmu(fmu) if out is not None else None
    # each record with its PID's form as it showed it (controller_form): a calibration record's own
    # diagnosis reads it (pipeline.run), a validation record's is read here
    judged = [identified(r.ce152, progress)[0] for r in held]
    j = joint.run([r.ce152 for r in recs], judged, effects=names, workers=workers, progress=progress)
    train = [d.diagnosed for d in j.each]
    if out is None:
        return joint.result(j, train, judged)
    return joint.write(j, train, judged, Path(out), fmu_in, json_name)


def _rig(recs: list[Recording], held: list[Recording], *, rig: Rig, effects, out, progress, controller,
         per_record: bool, json_name: str) -> DiagnosisResult:
    if effects not in (None, True, False) and list(effects):
        raise ValueError("a real rig tries the effects its drive can take (maglev_cosim.diagnosis.real_rig.rig_candidates), "
                         "all or none: effects= is True or False for it (--effects names the CE152 catalogue's)")
    use_effects = effects is not False and not (effects is not None and effects is not True and not list(effects))
    for r in [*recs, *held]:
        if r.rig is not None and rig is not None and r.rig.path != rig.path:
            raise ValueError(f"{r.path}: read for rig {r.rig.name}, diagnosed with rig {rig.name}")
    tmp = tempfile.TemporaryDirectory(prefix="maglev-diagnose-") if out is None else None
    try:
        where = Path(tmp.name if tmp else out)
        res = real_rig.run(rig, [r.measured for r in recs], where, validate=[r.measured for r in held],
                           per_record=per_record, progress=progress, json_name=json_name, controller=controller,
                           effects=use_effects)
        result = from_rig(res)
        if tmp is None:
            (where / json_name).write_text(json.dumps(result.to_json(), indent=2, allow_nan=False) + "\n")
        else:
            result.written, result.calibrated_fmu = [], None
        return result
    finally:
        if tmp is not None:
            tmp.cleanup()
