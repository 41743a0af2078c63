"""The declared PID's implementation, read off the record before anything is fitted.

A CE152 record declares its PID by its gains (metadata ``kp``, ``ki``, ``kd``, and ``tf`` where
the derivative is filtered). The same gains run in another implementation make another loop: a
derivative filter of 1 ms, which the metadata did not declare, made a record of the independent
emulator without any effect end ``explained`` by an amplifier lag, because every replay ran the
paper's unfiltered difference (Eq. 24) where the rig had run the filtered one.

The record holds the reference, the reading and the controller's output, so the controller is
identified from them alone, with no plant in the way: the declared PID is run on the recorded
``w`` and ``y`` (:func:`maglev_cosim.loop.fast_loop.control`) and its output compared with the
recorded ``u`` on the samples where neither is at a limit. The integrator's start is unknown (it
enters as a constant while no limit acts), so it is estimated (the mean difference) and the PID run
again from it. What remains is the misfit: on an honest record, the D/A's and the file's rounding.

The candidates are the declared PID with its derivative taken of the error (Eq. 24) or of the
reading alone (no kick at a reference step), each with its derivative filter's time constant
``tf`` free (a bounded scalar search over its logarithm, :data:`TF_BOUNDS_S`, and the declared
value). The best is adopted, and the whole diagnosis replays it, only when its misfit RMS is at most
:data:`ADOPT_RATIO` of the declared form's and the fall is significant (:data:`ADOPT_STAT`); the
record then carries a warning that says so, with both figures. A PID whose derivative acts on the
reading, declared as the paper's, made a record of that emulator without any effect end
``explained`` by a current saturation (the replays kicked the output at every reference step).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize_scalar

from ..loop import fast_loop
from ..loop.pid import DERIVATIVE, PID
from ..records.record import Record
from ..records.settled import from_settled
from .replay import record_controller
from .residual import check_controller

#: The derivative filter's time constant [s] is searched within these bounds (and 0, the
#: unfiltered difference): from a hundredth of the usual 1 ms sample to 50 ms, beyond which a
#: "derivative" no longer acts within the loop's bandwidth (about 30 Hz).
TF_BOUNDS_S = (1e-5, 0.05)
#: Another form is adopted only when it leaves at most this share of the declared form's misfit
#: RMS: a form that halves the misfit explains three quarters of its variance. A smaller gain is
#: left to the declared form, which the record's metadata states.
ADOPT_RATIO = 0.5
#: ... and when the fall is significant: N·ln(σ²_declared/σ²_form) above the χ²(1) quantile at
#: 1 − 0.001 (one parameter more), N the samples compared.
ADOPT_STAT = 10.83
#: The first samples are left out of the comparison: the PID's memory starts settled (zero error
#: before the record), which the record's first samples need not be.
SKIP = 2


@dataclass
class ControllerForm:
    """What the record says of its PID's implementation.

    Attributes
    ----------
    declared_rms : float
        Misfit RMS [MU] of the declared PID's output against the recorded u (integrator start
        estimated), over ``samples`` samples.
    rms : float
        Misfit RMS [MU] of the best candidate form.
    samples : int
        Samples compared (neither output at a limit).
    tf_declared, tf : float
        The derivative filter's time constant [s] declared and of the best form.
    derivative_declared, derivative : {"error", "measurement"}
        What the derivative differentiates, declared and in the best form.
    adopted : bool
        Whether the best form replaces the declared one in the diagnosis.
    """

    declared_rms: float
    rms: float
    samples: int
    tf_declared: float
    tf: float
    derivative_declared: str
    derivative: str
    adopted: bool


def misfit(rec: Record, pid: PID) -> tuple[float, int]:
    """RMS [MU] of the recorded u minus ``pid`` run on the recorded w and y, over the samples where
    neither is at a limit, with the integrator's start estimated (the mean difference there, and the
    PID run again from it); and the number of those samples (0: none, the RMS is inf)."""
    u_hold = float(rec.u[0])
    d = ok = None
    for _ in range(2):
        u_pid = fast_loop.control(pid, rec.w, rec.y, None, u_hold, y_before=rec.y_before)
        ok = (u_pid > pid.u_min) & (u_pid < pid.u_max) & (rec.u > pid.u_min) & (rec.u < pid.u_max)
        ok[:SKIP] = False
        if not ok.any():
            return float("inf"), 0
        d = rec.u - u_pid
        u_hold += float(np.mean(d[ok]))
    e = d[ok] - np.mean(d[ok])
    return float(np.sqrt(np.mean(e ** 2))), int(ok.sum())


def identify(rec: Record) -> ControllerForm | None:
    """The declared PID against the best of its candidate forms (module docstring); None when the
    record declares no PID of its metadata (a controller file) or one without a derivative term."""
    if rec.controller is not None or rec.kd == 0.0:
        return None
    pid = record_controller(rec)
    s0, n = misfit(rec, pid)
    if n == 0:
        return None
    lo, hi = np.log(TF_BOUNDS_S)
    best = (s0, pid)
    for derivative in (pid.derivative, *(d for d in DERIVATIVE if d != pid.derivative)):
        form = replace(pid, derivative=derivative)
        if derivative != pid.derivative:
            best = min(best, (misfit(rec, form)[0], form), key=lambda b: b[0])
        res = minimize_scalar(lambda lt: misfit(rec, replace(form, tf=float(np.exp(lt))))[0], bounds=(lo, hi),
                              method="bounded", options={"xatol": 0.01})
        best = min(best, (float(res.fun), replace(form, tf=float(np.exp(res.x)))), key=lambda b: b[0])
    s1, chosen = best
    gain = n * np.log(s0 ** 2 / s1 ** 2) if s1 > 0 else float("inf")
    adopted = bool(s1 <= ADOPT_RATIO * s0 and gain > ADOPT_STAT)
    return ControllerForm(s0, s1, n, pid.tf, chosen.tf, pid.derivative, chosen.derivative, adopted)


def identified(rec: Record, say=None) -> tuple[Record, ControllerForm | None]:
    """``rec`` as the diagnosis reads it: from where its loop is settled
    (:func:`~maglev_cosim.records.settled.from_settled`, with a warning where that is not its first
    sample), checked (:func:`~.residual.check_controller`: a u its controller did not make fails
    at once), and with the identified form of its PID where :func:`identify` adopts one: the record
    with that ``tf`` and a warning naming both misfits. Returns the record and the form."""
    rec, cut = from_settled(rec)
    if cut and say:
        say(cut)
    check_controller(rec)
    form = identify(rec)
    if form is None or not form.adopted:
        return rec, form
    text = (f"the recorded u is not what the declared PID ({_form_text(form.derivative_declared, form.tf_declared)}) "
            f"makes of the recorded w and y: misfit RMS {form.declared_rms:.3g} MU over {form.samples} samples; "
            f"with {_form_text(form.derivative, form.tf)} it is {form.rms:.3g} MU, and the diagnosis replays that "
            "PID (declare it in the record's metadata, 'derivative' and 'tf', to silence this)")
    if say:
        say(text)
    return replace(rec, tf=form.tf, derivative=form.derivative, warnings=[*rec.warnings, text]), form


def _form_text(derivative: str, tf: float) -> str:
    what = "the derivative of the error" if derivative == "error" else "the derivative of the reading alone"
    return f"{what}, " + (f"filtered with tf = {tf * 1e3:.3g} ms" if tf > 0 else "unfiltered")
