"""Measured records from real rigs, read as their authors publish them (no hand conversion).

- Inteco MLS2EM results (``results/<profile>/<controller> - KF.mat``): the variable ``logouts``, one
  row per signal, at 1 kHz. Rows (0-based; checked against the authors' ``results/plot_results.m``
  and ``functions/load_data.m``, and against the data): 0 time [s], 1 reference gap [m], 2 gap [m],
  3 velocity [m/s], 4 and 5 the coil currents [A], 6 and 7 the controllers' PWM duties, 8–10 the
  Kalman filter's gap, velocity and current, 12 and 13 the duties applied to the coils. Rows 6 and 12
  differ only in the PID records, and there the coil current follows row 12 (the current model fits
  it 80–87 % against 42–64 % for row 6): the applied duty is the plant's input.
- The levitador benchmark (``datos_levitador.txt``): whitespace-separated columns t [s], reference
  gap [m], gap [m], current reference [A], current [A], coil voltage [V] at 100 Hz (the column
  order of its authors' code, ``levitador_benchmark.py``).

Both rigs record the gap below the magnet (growing downward): :class:`maglev_cosim.rigs.Rig`
maps it onto the plant. Non-uniform time is an error unless ``resample=True``. Every error is a
:class:`maglev_cosim.record.RecordError` naming the file and where (line and column in a text
file; the variable and row of a ``.mat`` file, with line and column 0).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from .record import RecordError

#: Largest relative deviation of a time step from the median step still called uniform.
UNIFORM_TOL = 1e-3
INTECO_ROWS = {"t": 0, "reference": 1, "position": 2, "velocity": 3, "current": 4, "current_2": 5,
               "control": 6, "control_2": 7, "z_hat": 8, "v_hat": 9, "i_hat": 10, "drive": 12, "drive_2": 13}
#: A current below ``coil_off`` of its 99th percentile for this long [s] means the coil is off.
COIL_OFF_MIN = 0.1
LEVITADOR_COLUMNS = ("t", "reference", "position", "current_reference", "current", "voltage")


@dataclass
class Measured:
    """A measured closed-loop record of a real rig, in SI units.

    ``position`` and ``reference`` [m] are in the rig's own convention (both shipped rigs: the gap
    below the magnet). ``drive`` is the actuator signal applied to the coil, in ``drive_unit``
    (``"1"``: PWM duty; ``"V"``: volts). ``current`` [A] is the measured coil current."""

    path: Path
    fmt: str
    t: np.ndarray
    position: np.ndarray
    reference: np.ndarray | None
    current: np.ndarray | None
    drive: np.ndarray | None
    drive_unit: str
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.t)

    @property
    def ts(self) -> float:
        """Sample time [s]."""
        return float(self.t[1] - self.t[0]) if self.n > 1 else math.nan

    @property
    def duration(self) -> float:
        """Length [s]."""
        return float(self.t[-1] - self.t[0]) if self.n else 0.0

    @property
    def label(self) -> str:
        """A short name: the file's stem and, for Inteco, its profile folder."""
        prof = self.metadata.get("profile")
        return f"{prof}/{self.path.stem}" if prof else self.path.stem

    def slice(self, i0: int, i1: int) -> Measured:
        """Samples ``[i0, i1)``, every signal cut alike."""
        cut = lambda a: None if a is None else a[i0:i1].copy()  # noqa: E731
        return replace(self, t=cut(self.t), position=cut(self.position), reference=cut(self.reference),
                       current=cut(self.current), drive=cut(self.drive),
                       extra={k: cut(v) for k, v in self.extra.items()}, warnings=list(self.warnings))


def _uniform(path: Path, t: np.ndarray, where, resample: bool, signals: dict[str, np.ndarray | None],
             quantum: float = 0.0):
    """Checks that ``t`` is uniform (to ``quantum`` [s], the precision a text file prints it with);
    with ``resample`` interpolates every signal onto a uniform grid."""
    if len(t) < 3:
        raise RecordError(path, *where(0), f"only {len(t)} samples")
    dt = np.diff(t)
    step = float(np.median(dt))
    if not step > 0:
        raise RecordError(path, *where(1), "time does not increase")
    bad = np.flatnonzero(np.abs(dt - step) > max(UNIFORM_TOL * step, 1.01 * quantum))
    if bad.size == 0:
        if quantum > 0:  # printed times are rounded: the grid is the uniform one they round
            t = t[0] + step * np.arange(len(t))
        return t, signals, None
    k = int(bad[0]) + 1
    if not resample:
        raise RecordError(path, *where(k), f"time is not uniform: step {dt[k - 1]:.6g} s at sample {k} against "
                          f"{step:.6g} s (pass resample=True / --resample to interpolate onto a uniform grid)")
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise RecordError(path, *where(k), "time goes backwards or repeats: cannot resample")
    grid = t[0] + step * np.arange(int(math.floor((t[-1] - t[0]) / step + 1e-9)) + 1)
    out = {name: None if a is None else np.interp(grid, t, a) for name, a in signals.items()}
    return grid, out, (f"time was not uniform ({bad.size} irregular steps); every signal was linearly "
                       f"interpolated onto a {step:.6g} s grid")


def _check_signal(path: Path, name: str, a: np.ndarray, where) -> None:
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise RecordError(path, *where(int(bad[0])), f"{name} is not a finite number at sample {int(bad[0])}")


def _check_gap(path: Path, a: np.ndarray, where, name: str = "position") -> None:
    if np.nanmax(np.abs(a)) > 0.5:
        k = int(np.nanargmax(np.abs(a)))
        raise RecordError(path, *where(k), f"{name} {a[k]:g} m is beyond 0.5 m: is it in mm rather than m?")
    if np.ptp(a) == 0:
        raise RecordError(path, *where(0), f"{name} never changes: no information to use")


def read_inteco_mat(path: str | Path, *, coil: int = 1, resample: bool = False) -> Measured:
    """An Inteco MLS2EM results file (``logouts``, or the ``MLS2EMExpData`` struct that the authors'
    ``load_data.m`` also reads), coil 1 or 2.

    Raises
    ------
    RecordError
        Missing file, not a MATLAB file, no known variable, wrong shape, non-finite values,
        positions off by a unit, non-uniform time (unless ``resample``).
    """
    import scipy.io

    path = Path(path)
    if coil not in (1, 2):
        raise ValueError(f"coil must be 1 or 2, got {coil}")
    if not path.is_file():
        raise RecordError(path, 0, 0, "no such file" if not path.exists() else "is not a file")
    try:
        d = scipy.io.loadmat(path, squeeze_me=False, struct_as_record=False)
    except Exception as e:  # scipy raises several types for a file that is not MATLAB's
        raise RecordError(path, 0, 0, f"not a MATLAB .mat file scipy can read ({type(e).__name__}: {e})") from None
    meta = {"format": "inteco-mat", "coil": str(coil), "profile": path.parent.name,
            "controller": re.sub(r"\s*-\s*KF$", "", path.stem), "estimator": "KF" if path.stem.endswith("KF") else ""}
    if "logouts" in d:
        L = np.asarray(d["logouts"], dtype=float)
        if L.ndim != 2 or L.shape[0] < 14:
            raise RecordError(path, 0, 0, f"variable 'logouts' has shape {L.shape}, expected 14 rows (signals) "
                              "by N samples")
        where = lambda k: (0, 0)  # noqa: E731
        rows = dict(INTECO_ROWS)
        if coil == 2:
            rows.update(current=5, current_2=4, control=7, control_2=6, drive=13, drive_2=12)
        sig = {name: L[r].copy() for name, r in rows.items()}
        for name, r in rows.items():
            _check_signal(path, f"logouts row {r} ({name})", sig[name], lambda k: (0, 0))
    elif "MLS2EMExpData" in d:
        s = d["MLS2EMExpData"][0, 0]
        try:
            t = np.asarray(s.time, dtype=float).ravel()
            vals = [np.asarray(s.signals[0, k].values, dtype=float) for k in range(4)]
        except (AttributeError, IndexError, ValueError) as e:
            raise RecordError(path, 0, 0, f"variable 'MLS2EMExpData' lacks time or signals(1..4).values ({e})") from None
        col = lambda a, c: a[:, c] if a.ndim == 2 and a.shape[1] > c else a.ravel()  # noqa: E731
        sig = {"t": t, "position": vals[0].ravel(), "velocity": vals[1].ravel(), "current": col(vals[2], coil - 1),
               "drive": col(vals[3], coil - 1), "reference": None}
        for name, a in sig.items():
            if a is not None and len(a) != len(t):
                raise RecordError(path, 0, 0, f"MLS2EMExpData: {name} has {len(a)} samples, time has {len(t)}")
            if a is not None:
                _check_signal(path, f"MLS2EMExpData {name}", a, lambda k: (0, 0))
    else:
        names = ", ".join(k for k in d if not k.startswith("__")) or "none"
        raise RecordError(path, 0, 0, f"no variable 'logouts' or 'MLS2EMExpData' (found: {names})")
    where = lambda k: (0, 0)  # noqa: E731
    _check_gap(path, sig["position"], where)
    t = sig.pop("t")
    t, sig, note = _uniform(path, t, where, resample, sig)
    m = Measured(path=path, fmt="inteco-mat", t=t, position=sig.pop("position"), reference=sig.pop("reference"),
                 current=sig.pop("current"), drive=sig.pop("drive"), drive_unit="1",
                 extra={k: v for k, v in sig.items() if v is not None}, metadata=meta)
    if note:
        m.warnings.append(note)
    z_hat = m.extra.get("z_hat")
    if z_hat is not None and np.array_equal(m.position, z_hat):
        # step/PID_* of the shared data: what the PID saw was logged in place of the sensor
        m.warnings.append("the gap (logouts row 2) equals the Kalman filter's gap (row 8) sample for sample: "
                          "this record holds the filter's estimate, not the sensor's reading, so its 'sensor "
                          "noise' is the filter's and its position lags the ball by the filter's dynamics")
    return m


def read_levitador(path: str | Path, *, resample: bool = False) -> Measured:
    """The levitador benchmark's text format: six whitespace-separated numeric columns per line
    (t [s], reference [m], gap [m], current reference [A], current [A], voltage [V])."""
    path = Path(path)
    if not path.is_file():
        raise RecordError(path, 0, 0, "no such file" if not path.exists() else "is not a file")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        line = path.read_bytes()[: e.start].count(b"\n") + 1
        raise RecordError(path, line, 1, f"byte 0x{e.object[e.start]:02x} is not UTF-8 text") from None
    rows, lines, decimals = [], [], 0
    for ln, raw in enumerate(text.splitlines(), 1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        parts = list(re.finditer(r"\S+", raw))
        if len(parts) != len(LEVITADOR_COLUMNS):
            col = parts[len(LEVITADOR_COLUMNS)].start() + 1 if len(parts) > len(LEVITADOR_COLUMNS) else len(raw) + 1
            raise RecordError(path, ln, col, f"{len(parts)} fields, expected {len(LEVITADOR_COLUMNS)} "
                              f"({', '.join(LEVITADOR_COLUMNS)})")
        vals = []
        for name, mt in zip(LEVITADOR_COLUMNS, parts):
            try:
                v = float(mt.group())
            except ValueError:
                raise RecordError(path, ln, mt.start() + 1, f"{name}: {mt.group()!r} is not a number") from None
            if not math.isfinite(v):
                raise RecordError(path, ln, mt.start() + 1, f"{name}: {mt.group()!r} is not finite")
            vals.append(v)
        rows.append(vals)
        lines.append((ln, raw))
        tt = parts[0].group()
        if "." in tt and "e" not in tt.lower():
            decimals = max(decimals, len(tt.split(".")[1]))
    if len(rows) < 3:
        raise RecordError(path, 0, 0, f"only {len(rows)} data lines")
    a = np.asarray(rows)

    def where(k: int) -> tuple[int, int]:
        return lines[min(k, len(lines) - 1)][0], 1

    sig = {name: a[:, j] for j, name in enumerate(LEVITADOR_COLUMNS)}
    _check_gap(path, sig["position"], where)
    t = sig.pop("t")
    t, sig, note = _uniform(path, t, where, resample, sig, quantum=10.0 ** -decimals if decimals else 0.0)
    m = Measured(path=path, fmt="levitador", t=t, position=sig.pop("position"), reference=sig.pop("reference"),
                 current=sig.pop("current"), drive=sig.pop("voltage"), drive_unit="V",
                 extra={"current_reference": sig.pop("current_reference")},
                 metadata={"format": "levitador", "controller": "position PID + PI current loop"})
    if note:
        m.warnings.append(note)
    return m


def read_measured(path: str | Path, *, resample: bool = False) -> Measured:
    """A measured record in either published format, chosen by the file: ``.mat`` → Inteco,
    text with six numeric columns → levitador."""
    p = Path(path)
    if p.suffix.lower() == ".mat":
        return read_inteco_mat(p, resample=resample)
    return read_levitador(p, resample=resample)


@dataclass(frozen=True)
class Segment:
    """Samples ``[start, stop)`` of a record where the ball levitates."""

    start: int
    stop: int


def levitation_segments(m: Measured, stops: float | Sequence[float], *, tol: float = 5e-4,
                        margin: float = 0.1, min_duration: float = 1.0,
                        coil_off: float = 0.05) -> tuple[list[Segment], list[tuple[int, int, str]]]:
    """Splits a record into levitation segments.

    A sample is off when the ball is within ``tol`` [m] of one of the ``stops`` [m] (record
    convention: the rest it falls onto, and the magnet it can stick to), or when the coil is off:
    a measured current below ``coil_off`` times its 99th percentile for at least ``COIL_OFF_MIN``
    [s] (a ball cannot fall freely for longer and still levitate). Each off stretch is widened by
    ``margin`` [s] on both sides (the lift-off and the fall); what is left and lasts at least
    ``min_duration`` [s] is a segment.

    Returns
    -------
    segments : list of Segment
    excluded : list of (start, stop, reason)
        The stretches left out: ``"on a stop at G m"``, ``"coil off"`` or
        ``"shorter than min_duration"``.
    """
    stops = [float(stops)] if np.isscalar(stops) else [float(s) for s in stops]
    why = np.full(m.n, "", dtype=object)
    for s in stops:
        why[(why == "") & (np.abs(m.position - s) <= tol)] = f"on a stop at {s:g} m"
    if m.current is not None and coil_off > 0:
        top = float(np.percentile(np.abs(m.current), 99))
        low = np.abs(m.current) < coil_off * top
        for a, b in _runs(low):
            # a controller may cut the current for a few samples; off for longer, the ball falls
            if (b - a) * m.ts >= COIL_OFF_MIN:
                why[a:b][why[a:b] == ""] = "coil off"
    off = why != ""
    pad = int(round(margin / m.ts))
    if pad and off.any():
        widened = np.zeros_like(off)
        for a, b in _runs(off):
            widened[max(a - pad, 0):min(b + pad, m.n)] = True
        off = widened
    excluded = [(a, b, " / ".join(sorted(set(why[a:b]) - {""}))) for a, b in _runs(off)]
    segs = []
    for a, b in _runs(~off):
        if (b - a) * m.ts >= min_duration:
            segs.append(Segment(a, b))
        else:
            excluded.append((a, b, "shorter than min_duration"))
    excluded.sort()
    return segs, excluded


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of every run of True."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))
