"""Where a closed-loop record's loop is settled, and the record from there on.

Every replay of a CE152 record starts the loop settled where the record began (``diagnosis/replay.py``,
:func:`standing_reading`): the ball at rest, the current at equilibrium, the controller's output
holding it. A record cut from a running loop need not start so: cut 2 ms after a reference step of the project emulator
(seed 7701), its first 0.4 s hold the ball flying and the D/A at its limits. The declared PID run
from a settled start on such a record fits its u at -359 % (the record was refused as one whose
controller is not the declared one), and with that check skipped the diagnosis of a record without
any effect took 14.7 s and ended ``explained`` by a 0.08 ms amplifier lag, fitted to the start's
transient.

A user's record, or another simulator's, may start anywhere. So the diagnosis reads it from the first
window where the loop is as quiet as in the record's own settled stretches (:func:`settled_from`)
and says so in a warning (:func:`from_settled`).

The measure of motion is scale-free: each window's standard deviation of ``y`` and of ``u`` (a
trend, a ringing and the noise alike), against the same figure over the record's reference windows:
the last window of each rest of the reference that starts :data:`SETTLE_S` after its change, with
``u`` within its limits, where the loop is most settled. The loop is settled from the first window
that is quiet, and stays quiet for :data:`QUIET_WINDOWS` windows, with ``u`` within its limits and
the reference still. A record without enough reference windows (a reference that never rests) is
read whole.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .record import Record

#: Window over which the motion is measured [s]: several periods of the loop's ringing (about
#: 30 Hz) and of mains pickup.
WINDOW_S = 0.1
#: A window starts a reference window this long after a reference change [s]: the step response of
#: the paper's loop has settled within it (Sec. 4).
SETTLE_S = 0.5
#: A window is quiet when its standard deviations of y and u are within this factor of the
#: reference windows' 90th percentiles. On 40 records of the two emulators that start settled (seeds
#: 7710-7729, no effect, an amplifier lag, a current limit or friction, each with its disturbance) the
#: first four windows reach at most 1.17 times it. At 2.5, the project emulator's no-effect record of
#: seed 7801, cut 2 ms after a step, was read from 50 ms on (0.00154 MU against 0.0006 MU later) and
#: ended `unexplained: sensor`; read from 350 ms on, `no effect`.
QUIET_FACTOR = 1.5
#: The loop is settled where this many windows in a row (starts half a window apart) are quiet.
QUIET_WINDOWS = 4
#: The time over which the readings are averaged for the level the loop stood at when the record
#: began [s] (:func:`standing_reading`): whole periods of 50 and 60 Hz mains pickup, which a shorter
#: mean does not cancel (10 ms, half a period of 50 Hz, put the project emulator's record with a
#: 50 Hz pickup of 0.008 V, seed 5, 0.65 mMU off its reference and the pickup's amplitude 5.6 % low),
#: and short against a creeping integrator (0.01 MU/s after a step: 0.5 mMU in 50 ms).
STANDING_S = 0.1
#: A window cut at the first reference step is judged only with at least this many samples.
MIN_PART = 20
#: At least this many reference windows for the comparison; fewer, and the record is read whole.
MIN_REFERENCE_WINDOWS = 3
#: The search for a settled start ends after this share of the record; a record not settled by then
#: is read whole (with a warning).
MAX_SHARE = 0.3


def _windows(x: np.ndarray, starts: np.ndarray, n: int) -> np.ndarray:
    """The windows of ``n`` samples of ``x`` that begin at ``starts``, one per row."""
    return np.lib.stride_tricks.sliding_window_view(x, n)[starts]


def _quiet_until_first_step(rec: Record, n: int, step: int, first: int, lim_y: float, lim_u: float) -> bool:
    """Whether the record's start is quiet up to its first reference step at sample ``first``, when
    that step comes within the windows :func:`settled_from` asks to be quiet (a record that begins
    settled and steps 50 ms later starts settled: the step's response is no motion of the start).
    Each window is cut at the step; one of fewer than :data:`MIN_PART` samples is not judged."""
    if first >= (QUIET_WINDOWS - 1) * step + n:
        return False            # no step within them: the windows themselves said it
    parts = [(a, min(a + n, first)) for a in range(0, QUIET_WINDOWS * step, step) if min(a + n, first) - a >= MIN_PART]
    if not parts:
        return True             # the reference steps at once: the start is read as settled at the old level
    return all(np.std(rec.y[a:b]) <= lim_y and np.std(rec.u[a:b]) <= lim_u
               and bool(np.all((rec.u[a:b] > rec.u_min) & (rec.u[a:b] < rec.u_max))) for a, b in parts)


def settled_from(rec: Record) -> tuple[int, str | None]:
    """The first sample from which ``rec``'s loop is settled (module docstring), and why the record
    is read from there: ``(0, None)`` when it starts settled or when it cannot tell (no reference
    windows); ``(0, text)`` when no window in the first :data:`MAX_SHARE` of the record is quiet."""
    n = max(20, int(round(WINDOW_S / rec.ts)))
    if rec.n < 4 * n:
        return 0, None
    step = max(1, n // 2)
    starts = np.arange(0, rec.n - n + 1, step)
    ty, tu = _windows(rec.y, starts, n).std(axis=1), _windows(rec.u, starts, n).std(axis=1)
    changes = np.concatenate([[0], np.nonzero(np.abs(np.diff(rec.w)) > 1e-12)[0] + 1])
    rest = np.searchsorted(changes, starts, side="right") - 1       # the rest of the reference each window begins in
    last_change = changes[rest]
    next_change = np.concatenate([changes[1:], [rec.n]])[rest]
    u_win = _windows(rec.u, starts, n)
    inside = np.all((u_win > rec.u_min) & (u_win < rec.u_max), axis=1)
    settled = np.round(SETTLE_S / rec.ts)
    # each rest of the reference's last window, where its loop is most settled (a lightly damped loop
    # still rings 0.5 s after a step: the project emulator's 3 ms amplifier lag, seed 7701)
    last = (starts + n <= next_change) & (starts + n + step > next_change)
    reference = (starts - last_change >= settled) & (last_change > 0) & last & inside
    if reference.sum() < MIN_REFERENCE_WINDOWS:
        return 0, None
    lim_y = QUIET_FACTOR * float(np.percentile(ty[reference], 90))
    lim_u = QUIET_FACTOR * float(np.percentile(tu[reference], 90))
    quiet = (ty <= lim_y) & (tu <= lim_u) & inside & (starts + n <= next_change)
    # quiet from each window on for QUIET_WINDOWS windows (the last ones of the record: as far as it goes)
    held = np.array([bool(quiet[j:j + QUIET_WINDOWS].all()) for j in range(len(quiet))])
    if held[0] or _quiet_until_first_step(rec, n, step, int(changes[1]) if len(changes) > 1 else rec.n, lim_y, lim_u):
        return 0, None
    within = np.nonzero(held & (starts <= MAX_SHARE * rec.n))[0]
    if not len(within):
        return 0, (f"the record does not start settled: its first {WINDOW_S * 1e3:.0f} ms move "
                   f"(standard deviation of y {ty[0]:.3g} MU, of u {tu[0]:.3g} MU, against {lim_y:.3g} and {lim_u:.3g} in its settled "
                   f"stretches{'' if inside[0] else ', u at a limit'}), and no window of its first "
                   f"{MAX_SHARE * 100:.0f} % is quiet: it is read whole, and every replay's settled start is off at first")
    k = int(starts[within[0]])
    return k, (f"the record does not start settled: its first {WINDOW_S * 1e3:.0f} ms move (standard deviation of y {ty[0]:.3g} MU, "
               f"of u {tu[0]:.3g} MU, against {lim_y:.3g} and {lim_u:.3g} in its settled stretches"
               f"{'' if inside[0] else ', u at a limit'}); the diagnosis reads it from t = {rec.t[k]:.3f} s "
               f"(sample {k}), where the loop is first as quiet as in those stretches")


def standing_reading(y: np.ndarray, ts: float) -> float:
    """The reading [MU] at which the loop stood where readings ``y`` [MU] (``ts`` [s] apart) begin: their
    mean over the first :data:`STANDING_S` (sensor noise and mains pickup averaged). A record read from
    a settled point (:func:`from_settled`) keeps it as ``Record.y_before``: every replay starts there,
    with the error ``w[0]`` less it standing (:func:`maglev_cosim.loop.fast_loop.closed_loop`)."""
    return float(np.mean(y[:max(1, int(round(STANDING_S / ts)))]))


def from_settled(rec: Record) -> tuple[Record, str | None]:
    """``rec`` from where its loop is settled (:func:`settled_from`), with a warning that says so,
    and that warning (None: the record unchanged)."""
    k, text = settled_from(rec)
    if text is None or (k == 0 and text in rec.warnings):     # read before: said once
        return rec, None
    if k == 0:
        return replace(rec, warnings=[*rec.warnings, text]), text
    return replace(rec, t=rec.t[k:], w=rec.w[k:], u=rec.u[k:], y=rec.y[k:], y_before=standing_reading(rec.y[k:], rec.ts),
                   extra={name: v[k:] for name, v in rec.extra.items()}, warnings=[*rec.warnings, text]), text
