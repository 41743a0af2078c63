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
- The levitador benchmark's sessions (``sesiones_kan_pinn/``), and any text record that declares its
  columns (``docs/bringing-your-rig.md``): a Latin-1 or UTF-8 ``#`` header of ``key: value`` lines,
  one of them ``Columnas: t y y_obs dy_obs i u yd`` (any order, any subset holding ``t`` and ``y``),
  then tab-separated rows: time [s], measured position [m], the observer's position and velocity
  (kept, never used), coil current [A], coil voltage [V], position reference [m].

The format is told from the content, never the file name (:func:`sniff`).

Both rigs record the gap below the magnet (growing downward): :class:`maglev_cosim.rigs.Rig`
maps it onto the plant. Non-uniform time is an error unless ``resample=True``. Every error is a
:class:`maglev_cosim.records.record.RecordError` naming the file and where (line and column in a text
file; the variable and row of a ``.mat`` file, with line and column 0).
"""

from __future__ import annotations

import math
import re
import struct
import unicodedata
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import scipy.io

from .record import RecordError

#: Largest relative deviation of a time step from the median step still called uniform.
UNIFORM_TOL = 1e-3
INTECO_ROWS = {"t": 0, "reference": 1, "position": 2, "velocity": 3, "current": 4, "current_2": 5,
               "control": 6, "control_2": 7, "z_hat": 8, "v_hat": 9, "i_hat": 10, "drive": 12, "drive_2": 13}
#: The ``logouts`` rows a record cannot be read without: the rest (the other coil, the estimator's
#: copies, the reference) are left out with a warning where they are not finite.
INTECO_NEEDED = ("t", "position", "current", "drive")
#: A current below ``coil_off`` of its 99th percentile for this long [s] means the coil is off.
COIL_OFF_MIN = 0.1
LEVITADOR_COLUMNS = ("t", "reference", "position", "current_reference", "current", "voltage")


@dataclass
class Measured:
    """A measured closed-loop record of a real rig, in SI units.

    ``position`` and ``reference`` [m] are in the rig's own convention (both shipped rigs: the gap
    below the magnet). ``drive`` is the actuator signal applied to the coil, in ``drive_unit``
    (``"1"``: PWM duty; ``"V"``: volts; ``""``: a text record that does not say). ``current`` [A] is
    the measured coil current."""

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
    dropped: list[str] = []     # the rows read without (logouts)
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
            if name in INTECO_NEEDED:
                _check_signal(path, f"logouts row {r} ({name})", sig[name], lambda k: (0, 0))
            elif not np.all(np.isfinite(sig[name])):
                # a row the diagnosis does not need (the other coil, the estimator's copies, the
                # reference): read without it rather than refuse the record
                dropped.append(f"row {r} ({name}) is not a finite number at sample "
                               f"{int(np.flatnonzero(~np.isfinite(sig[name]))[0])}")
                sig[name] = None
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
    if dropped:
        m.warnings.append("read without " + "; ".join(dropped) + ": the diagnosis does not need "
                          + ("them" if len(dropped) > 1 else "it"))
    z_hat = m.extra.get("z_hat")
    if z_hat is not None and np.array_equal(m.position, z_hat):
        # step/PID_* of the shared data: what the PID saw was logged in place of the sensor
        m.metadata["position_source"] = "estimate"
        m.warnings.append("the gap (logouts row 2) equals the Kalman filter's gap (row 8) sample for sample: "
                          "this record holds the filter's estimate, not the sensor's reading, so its 'sensor "
                          "noise' is the filter's and its position lags the ball by the filter's dynamics")
    return m


def _norm(name: str) -> str:
    """A metadata key or column name compared loosely: lower case, accents dropped, blanks trimmed."""
    folded = unicodedata.normalize("NFKD", name.strip().lower())
    return "".join(c for c in folded if not unicodedata.combining(c))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _decode(path: Path) -> tuple[str, str, str | None]:
    """The file's text and its encoding, taken from the bytes: UTF-8 (a byte-order mark dropped)
    when it decodes, else Latin-1 (ISO-8859-1, which every byte string is), with a note saying where
    the first byte that is not UTF-8 sits and whether only ``#`` header lines hold such bytes."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RecordError(path, 0, 0, f"cannot be read: {exc.strerror or exc}") from None
    if b"\x00" in data:
        k = data.index(b"\x00")
        raise RecordError(path, data.count(b"\n", 0, k) + 1, k - data.rfind(b"\n", 0, k),
                          "a NUL byte: a binary file, not a text record")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        return data.decode("utf-8"), "utf-8", None
    except UnicodeDecodeError as exc:
        text = data.decode("latin-1")
        line = data.count(b"\n", 0, exc.start) + 1
        where = [raw for raw in text.splitlines() if any(ord(c) > 127 for c in raw)]
        header_only = all(raw.lstrip().startswith("#") for raw in where)
        return text, "latin-1", (f"not UTF-8 (byte 0x{data[exc.start]:02x} on line {line}): read as Latin-1 "
                                 "(ISO-8859-1)" + ("; only '#' header lines hold non-ASCII characters, the "
                                                   "numbers are unaffected" if header_only else ""))


#: The text format that declares its columns (the levitador benchmark's sessions, and the format of
#: ``docs/bringing-your-rig.md``): the names (case-insensitive) that a header may give each signal.
COLUMN_ROLES = {
    "t": ("t", "time"),                              # [s]
    "position": ("y", "position", "gap"),            # [m], the rig file's convention
    "current": ("i", "current"),                     # [A]
    "drive": ("u", "drive", "voltage", "duty"),      # the rig file's drive.input.unit
    "reference": ("yd", "reference"),                # [m]
}
#: Further columns kept in :attr:`Measured.extra` under these names; any other column is ignored
#: with a warning. ``y_obs``/``dy_obs`` are the levitador's observer estimates: kept, never used.
EXTRA_COLUMNS = {"y_obs": "y_obs", "dy_obs": "dy_obs", "velocity": "velocity", "ied": "current_reference",
                 "current_reference": "current_reference"}
#: What a record must hold to be read at all; ``require=`` asks for more (``diagnose --rig``: the drive).
REQUIRED_ROLES = ("t", "position")
ROLE_WORDS = {"t": "the time [s]", "position": "the measured position [m]", "current": "the coil current [A]",
              "drive": "the actuator signal (coil voltage or duty)", "reference": "the position reference [m]"}
#: Metadata keys (case and accents ignored) that declare the columns, the sample time, the sample count.
COLUMNS_KEYS = ("columns", "columnas")
TS_KEYS = ("ts", "sample_time")
SAMPLES_KEYS = ("samples", "muestras")
#: The formats of real rigs' records that :func:`sniff` tells apart (it also knows ``"ce152"``).
MEASURED_FORMATS = ("inteco-mat", "levitador", "columns")
CE152_REFUSAL = ("a CE152-format record (docs/record-format.md: '# key: value' metadata, then the header t,w,u,y "
                 "in machine units), not a real rig's record: read it with maglev_cosim.records.record.read_record "
                 "(maglev-cosim diagnose without --rig)")


def _sniff(path: Path) -> tuple[str | None, int]:
    """(format, line of the header or first data line); see :func:`sniff`."""
    try:
        with path.open("rb") as fh:
            head = fh.read(1 << 16)
    except OSError:
        return None, 0
    if head.startswith(b"MATLAB") or head.startswith(b"\x89HDF") or _mat4(head):
        return "inteco-mat", 0
    if b"\x00" in head:
        return None, 0
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        text = head.decode("latin-1")
    lines = text.splitlines()
    for ln, raw in enumerate(lines[:-1] if len(head) == 1 << 16 else lines, 1):
        s = raw.strip()
        if not s:
            continue
        if s.startswith("#"):
            if ":" in s and _norm(s[1:].split(":", 1)[0]) in COLUMNS_KEYS:
                return "columns", ln
            continue
        if "," in s:  # a comma-separated header without a '# Columns:' line: the CE152 record format
            return ("ce152" if not any(_is_number(c) for c in s.split(",")) else None), ln
        fields = _fields(s, None)
        if _is_header(fields):
            return "columns", ln
        if len(fields) == len(LEVITADOR_COLUMNS) and "," not in s and all(_is_number(f) for _, f in fields):
            return "levitador", ln
        return None, ln
    return None, 0


def _mat4(head: bytes) -> bool:
    """A MATLAB level-4 file (no text header: the Inteco results are one): its first matrix header,
    five int32 (type MOPT, rows, columns, imaginary flag, name length), then a NUL-ended name."""
    if len(head) < 21:
        return False
    for order in "<>":
        mopt, rows, cols, imag, namlen = struct.unpack(order + "5i", head[:20])
        m, o, p, t = mopt // 1000, mopt // 100 % 10, mopt // 10 % 10, mopt % 10
        name = head[20:20 + namlen]
        if (0 <= mopt <= 4052 and m <= 4 and o == 0 and p <= 5 and t <= 2 and rows >= 0 and cols >= 0
                and imag in (0, 1) and 1 < namlen <= 64 and len(name) == namlen and name.endswith(b"\0")
                and re.fullmatch(rb"[A-Za-z][A-Za-z0-9_]*", name[:-1])):
            return True
    return False


def sniff(path: str | Path) -> str | None:
    """A record file's format, from its content (never its name): ``"inteco-mat"`` (a MATLAB file:
    level 4, as the Inteco results are, 5 or 7.3),
    ``"levitador"`` (the benchmark's first text format: six numeric columns, no header),
    ``"columns"`` (a text file that declares its columns: a ``# Columns:`` or ``# Columnas:`` line,
    or a first line of blank- or tab-separated names with a time column), ``"ce152"`` (the record
    format of ``docs/record-format.md``: a comma-separated header, ``t,w,u,y``, without a
    ``# Columns:`` line), or None (none of these, or unreadable)."""
    return _sniff(Path(path))[0]


def _fields(raw: str, delim: str | None) -> list[tuple[int, str]]:
    """The fields of a line as (0-based character position of their first non-blank, text):
    split on runs of blanks and tabs (``delim`` None) or on ``delim``."""
    if delim is None:
        return [(mt.start(), mt.group()) for mt in re.finditer(r"\S+", raw)]
    out, pos = [], 0
    for cell in raw.split(delim):
        out.append((pos + len(cell) - len(cell.lstrip()), cell.strip()))
        pos += len(cell) + 1
    return out


def _is_header(fields: list[tuple[int, str]]) -> bool:
    """A line of column names: no field is a number, and one names the time."""
    return bool(fields) and not any(_is_number(f) for _, f in fields) and \
        any(_norm(f) in COLUMN_ROLES["t"] for _, f in fields)


def _seconds(text: str) -> float | None:
    """A time such as ``0.01``, ``0.01s``, ``0.01 s`` or ``10 ms`` in seconds (None: not one)."""
    m = re.fullmatch(r"\s*([-+0-9.eE]+)\s*(s|ms)?\s*", text)
    if not m or not _is_number(m.group(1)):
        return None
    return float(m.group(1)) * (1e-3 if m.group(2) == "ms" else 1.0)


def _read_text(path: str | Path, resample: bool, require: Sequence[str]) -> Measured:
    """Both text formats: the levitador's first (six columns, no header) and a declared-columns
    file (the levitador's sessions, ``docs/bringing-your-rig.md``); see :func:`read_levitador`."""
    path = Path(path)
    if not path.is_file():
        raise RecordError(path, 0, 0, "no such file" if not path.exists() else "is not a file")
    text, encoding, enc_note = _decode(path)
    lines = text.splitlines()
    meta: dict[str, str] = {}
    at: dict[str, tuple[int, int]] = {}  # normalised key -> (line, column of its value)
    titles: list[str] = []
    k = 0
    while k < len(lines) and (not lines[k].strip() or lines[k].lstrip().startswith("#")):
        raw = lines[k]
        body = raw.lstrip()[1:].strip() if raw.strip() else ""
        if ":" in body:
            key, value = (s.strip() for s in body.split(":", 1))
            c = raw.index(":") + 1
            while c < len(raw) and raw[c] in " \t":
                c += 1
            meta[key], at[_norm(key)] = value, (k + 1, c + 1)
        elif body:
            titles.append(body)
        k += 1
    declared = next((key for key in COLUMNS_KEYS if key in at), None)
    names: list[tuple[int, str]] | None = None   # (character position, name) in the header line
    delim: str | None = None
    if declared is not None:
        header_ln, col = at[declared]
        raw = lines[header_ln - 1]
        names = _fields(raw[col - 1:], "," if "," in raw[col - 1:] else None)
        names = [(p + col - 1, n) for p, n in names if n]
        first = next((j for j in range(k, len(lines))
                      if lines[j].strip() and not lines[j].lstrip().startswith("#")), None)
        delim = "," if first is not None and "," in lines[first] else None
        if first is not None and [n for _, n in _fields(lines[first], delim)] == [n for _, n in names]:
            k = first + 1   # the declared names once more, as a first line: a header, not data
    elif k < len(lines) and "," in lines[k] and not any(_is_number(c) for c in lines[k].split(",")):
        raise RecordError(path, k + 1, 1, CE152_REFUSAL)
    elif k < len(lines) and _is_header(_fields(lines[k], None)):
        header_ln = k + 1
        names = _fields(lines[k], None)
        k += 1
    if names is None:
        return _read_legacy(path, lines, k, text_meta=(meta, titles, encoding, enc_note), resample=resample)

    # the declared columns: each to its signal, once
    listed = " ".join(n for _, n in names)
    role_of: dict[str, int] = {}
    extra_of: dict[str, int] = {}
    unknown: list[str] = []
    for j, (pos, name) in enumerate(names):
        key = _norm(name)
        role = next((r for r, alts in COLUMN_ROLES.items() if key in alts), None)
        if role is None and key in EXTRA_COLUMNS:
            role = "extra:" + EXTRA_COLUMNS[key]
        if role is None:
            unknown.append(f"'{name}' (column {j + 1})")
            continue
        if any(_norm(other) == key for _, other in names[:j]):
            raise RecordError(path, header_ln, pos + 1, f"column '{name}' is declared twice ({listed})")
        target = extra_of if role.startswith("extra:") else role_of
        slot = role.split(":", 1)[-1]
        if slot in target:
            first = names[target[slot]][1]
            raise RecordError(path, header_ln, pos + 1, f"columns '{first}' and '{name}' both hold "
                              f"{ROLE_WORDS.get(slot, slot)}: keep one ({listed})")
        target[slot] = j
    missing = [r for r in (*REQUIRED_ROLES, *require) if r not in role_of]
    if missing:
        need = "; ".join(f"{ROLE_WORDS[r]} as {' or '.join(repr(a) for a in COLUMN_ROLES[r])}" for r in missing)
        why = "" if set(missing) <= set(REQUIRED_ROLES) else " (this command needs " + \
            ", ".join(ROLE_WORDS[r] for r in missing if r not in REQUIRED_ROLES) + ")"
        raise RecordError(path, header_ln, names[0][0] + 1 if names else 1,
                          f"the header declares no column for {need}{why}; declared: {listed}")

    # the rows
    ncol = len(names)
    used = {**{r: j for r, j in role_of.items()}, **{"extra:" + e: j for e, j in extra_of.items()}}
    cols: dict[str, list[float]] = {r: [] for r in used}
    rows: list[tuple[int, str]] = []
    decimals = 0
    for ln in range(k + 1, len(lines) + 1):
        raw = lines[ln - 1]
        if not raw.strip() or raw.lstrip().startswith("#"):
            continue
        parts = _fields(raw, delim)
        if len(parts) != ncol:
            col = parts[ncol][0] + 1 if len(parts) > ncol else len(raw) + 1
            raise RecordError(path, ln, col, f"{len(parts)} fields, the header (line {header_ln}) declares "
                              f"{ncol}: {listed}")
        for r, j in used.items():
            pos, cell = parts[j]
            label = f"column '{names[j][1]}'" + (f" ({r})" if not r.startswith("extra:") and r != names[j][1] else "")
            try:
                v = float(cell)
            except ValueError:
                raise RecordError(path, ln, pos + 1, f"{label}: {cell!r} is not a number") from None
            if not math.isfinite(v):
                raise RecordError(path, ln, pos + 1, f"{label}: {cell!r} is not finite")
            cols[r].append(v)
        rows.append((ln, raw))
        tt = parts[role_of["t"]][1]
        if "." in tt and "e" not in tt.lower():
            decimals = max(decimals, len(tt.split(".")[1]))
    if len(rows) < 3:
        raise RecordError(path, header_ln, 1, f"only {len(rows)} data lines after the header")

    def where_in(role: str):
        j = used[role]

        def where(i: int) -> tuple[int, int]:
            ln, raw = rows[min(i, len(rows) - 1)]
            return ln, _fields(raw, delim)[j][0] + 1
        return where

    sig = {r: np.asarray(v) for r, v in cols.items()}
    warnings = [enc_note] if enc_note else []
    _check_gap(path, sig["position"], where_in("position"), name=f"position (column '{names[role_of['position']][1]}')")
    if "reference" in sig and np.max(np.abs(sig["reference"])) > 0.5:
        i = int(np.argmax(np.abs(sig["reference"])))
        raise RecordError(path, *where_in("reference")(i), f"reference {sig['reference'][i]:g} m is beyond 0.5 m: "
                          "is it in mm rather than m?")
    quantum = 10.0 ** -decimals if decimals else 0.0
    ts_key = next((key for key in TS_KEYS if key in at), None)
    ts_declared = None
    if ts_key is not None:
        ts_ln, ts_col = at[ts_key]
        ts_text = lines[ts_ln - 1][ts_col - 1:].strip()
        ts_declared = _seconds(ts_text)
        if ts_declared is None or not ts_declared > 0:
            raise RecordError(path, ts_ln, ts_col, f"sample time {ts_text!r} is not a positive time (such as 0.01 "
                              "or 0.01s)")
    n_key = next((key for key in SAMPLES_KEYS if key in at), None)
    if n_key is not None:
        ln, col = at[n_key]
        value = lines[ln - 1][col - 1:].strip()
        if value.isdigit() and int(value) != len(rows):
            warnings.append(f"line {ln} says {value} samples, the file holds {len(rows)} data lines")
    if unknown:
        warnings.append(f"unknown column(s) {', '.join(unknown)} ignored (known: "
                        + ", ".join(a for alts in COLUMN_ROLES.values() for a in alts)
                        + ", " + ", ".join(EXTRA_COLUMNS) + ")")
    if "current" not in sig:
        warnings.append("no coil current column: the current's figures and the force balance are left out")
    t_raw = sig.pop("t")
    t, sig, note = _uniform(path, t_raw, where_in("t"), resample, sig, quantum=quantum)
    if ts_declared is not None:
        # uniform time: its mean step, to the print's rounding spread over the record; resampled
        # (gaps in the time): its median step, to the print's rounding
        n_raw = len(t_raw)
        step = float(np.median(np.diff(t_raw))) if note else float(t_raw[-1] - t_raw[0]) / (n_raw - 1)
        tol = max(UNIFORM_TOL * ts_declared, 1.01 * quantum if note else 2.02 * quantum / (n_raw - 1))
        if abs(step - ts_declared) > tol:
            raise RecordError(path, ts_ln, ts_col, f"sample time {ts_text} disagrees with the time column, which "
                              f"steps by {step:.6g} s" + ("" if note else f" on average over {n_raw} samples"))
        if not note:
            t = t_raw[0] + ts_declared * np.arange(n_raw)
    if note:
        warnings.append(note)
    metadata = {**meta, "format": "columns", "encoding": encoding, "columns": listed}
    if titles:
        metadata.setdefault("title", titles[0])
    # the drive's unit as the file states it (informational: the rig file's drive.input.unit counts)
    unit = meta.get("drive_unit") or ({"voltage": "V", "duty": "1"}.get(_norm(names[role_of["drive"]][1]), "")
                                      if "drive" in role_of else "")
    return Measured(path=path, fmt="columns", t=t, position=sig.pop("position"), reference=sig.pop("reference", None),
                    current=sig.pop("current", None), drive=sig.pop("drive", None), drive_unit=unit,
                    extra={r.split(":", 1)[1]: v for r, v in sig.items()}, metadata=metadata, warnings=warnings)


def _read_legacy(path: Path, lines: list[str], start: int, *, text_meta, resample: bool) -> Measured:
    """The levitador benchmark's first format: six whitespace-separated numeric columns per line,
    no header (t [s], reference [m], gap [m], current reference [A], current [A], voltage [V])."""
    meta, titles, encoding, enc_note = text_meta
    rows, where_rows, decimals = [], [], 0
    for ln in range(start + 1, len(lines) + 1):
        raw = lines[ln - 1]
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        parts = list(re.finditer(r"\S+", raw))
        if len(parts) != len(LEVITADOR_COLUMNS):
            col = parts[len(LEVITADOR_COLUMNS)].start() + 1 if len(parts) > len(LEVITADOR_COLUMNS) else len(raw) + 1
            raise RecordError(path, ln, col, f"{len(parts)} fields, expected {len(LEVITADOR_COLUMNS)} "
                              f"({', '.join(LEVITADOR_COLUMNS)}), or a header that declares the columns "
                              "('# Columns: t y i u yd', docs/bringing-your-rig.md)")
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
        where_rows.append(ln)
        tt = parts[0].group()
        if "." in tt and "e" not in tt.lower():
            decimals = max(decimals, len(tt.split(".")[1]))
    if len(rows) < 3:
        raise RecordError(path, 0, 0, f"only {len(rows)} data lines")
    a = np.asarray(rows)

    def where(k: int) -> tuple[int, int]:
        return where_rows[min(k, len(where_rows) - 1)], 1

    sig = {name: a[:, j] for j, name in enumerate(LEVITADOR_COLUMNS)}
    _check_gap(path, sig["position"], where)
    t = sig.pop("t")
    t, sig, note = _uniform(path, t, where, resample, sig, quantum=10.0 ** -decimals if decimals else 0.0)
    metadata = {**meta, "format": "levitador", "encoding": encoding, "controller": "position PID + PI current loop"}
    if titles:
        metadata.setdefault("title", titles[0])
    m = Measured(path=path, fmt="levitador", t=t, position=sig.pop("position"), reference=sig.pop("reference"),
                 current=sig.pop("current"), drive=sig.pop("voltage"), drive_unit="V",
                 extra={"current_reference": sig.pop("current_reference")}, metadata=metadata)
    m.warnings += [w for w in (enc_note, note) if w]
    return m


def read_levitador(path: str | Path, *, resample: bool = False, require: Sequence[str] = ()) -> Measured:
    """The levitador benchmark's text records, in either of its published formats (told apart by
    the content, never the name):

    - the first (``datos_levitador.txt``): six whitespace-separated numeric columns per line, no
      header: t [s], reference [m], gap [m], current reference [A], current [A], voltage [V];
    - the sessions (``sesiones_kan_pinn/``), and any text record that declares its columns: ``#``
      header lines ``key: value`` (kept in :attr:`Measured.metadata`), one of them ``Columnas:`` (or
      ``Columns:``) naming the columns in their order (or, instead, a first line of names separated
      by blanks or tabs), then one row per sample, its fields separated by tabs or blanks (or by
      commas, given the ``Columns:`` line: a comma-separated header alone is the CE152 format).
      Names (:data:`COLUMN_ROLES`): ``t`` time [s], ``y`` measured position [m], ``i`` coil current
      [A], ``u`` actuator signal, ``yd`` position reference [m]; ``y_obs``, ``dy_obs`` (an
      observer's estimates) and ``ied`` (current reference) are kept in :attr:`Measured.extra`,
      never used as the position; other columns are ignored with a warning. ``t`` and ``y`` are
      required, and whatever ``require`` names (``"current"``, ``"drive"``, ``"reference"``); a
      ``Ts:`` line must agree with the time column; a ``Muestras:``/``Samples:`` count that does
      not is a warning.

    The encoding comes from the bytes: UTF-8 when they decode, else Latin-1, said in the metadata
    (``encoding``) and, for Latin-1, in the warnings. Errors name the file, the line and the
    character column."""
    return _read_text(path, resample, require)


def read_measured(path: str | Path, *, resample: bool = False, require: Sequence[str] = ()) -> Measured:
    """A measured record in any published format, told apart by the content (:func:`sniff`):
    a MATLAB file → Inteco (:func:`read_inteco_mat`; a ``.mat`` name too, for its error message),
    text → :func:`read_levitador` (either format, or a declared-columns record). A record in the
    CE152 record format is refused on its header line: :func:`maglev_cosim.records.record.read_record`
    reads it."""
    p = Path(path)
    fmt = sniff(p)
    if fmt == "inteco-mat" or (fmt is None and p.suffix.lower() == ".mat"):
        return read_inteco_mat(p, resample=resample)
    return read_levitador(p, resample=resample, require=require)


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
        for a, b in true_runs(low):
            # a controller may cut the current for a few samples; off for longer, the ball falls
            if (b - a) * m.ts >= COIL_OFF_MIN:
                why[a:b][why[a:b] == ""] = "coil off"
    off = why != ""
    pad = int(round(margin / m.ts))
    if pad and off.any():
        widened = np.zeros_like(off)
        for a, b in true_runs(off):
            widened[max(a - pad, 0):min(b + pad, m.n)] = True
        off = widened
    excluded = [(a, b, " / ".join(sorted(set(why[a:b]) - {""}))) for a, b in true_runs(off)]
    segs = []
    for a, b in true_runs(~off):
        if (b - a) * m.ts >= min_duration:
            segs.append(Segment(a, b))
        else:
            excluded.append((a, b, "shorter than min_duration"))
    excluded.sort()
    return segs, excluded


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of every run of True."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))
