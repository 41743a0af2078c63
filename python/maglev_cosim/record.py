"""Closed-loop records from the rig: reading and writing the record format.

::

    # ts: 0.001
    # controller: pid
    # kp: 2.0
    # ki: 2.97
    # kd: 0.01
    # u_min: 0.0
    # u_max: 1.0
    t,w,u,y
    0.0000,0.440000,0.969727,0.389160

Lines starting with ``#`` before the header are ``key: value`` metadata (unknown keys are
kept). Then a header and one row per sample: ``t`` [s] uniform at ``ts``, ``w`` the position
reference [MU], ``u`` the controller output written to the D/A [MU], ``y`` the A/D reading [MU].
Columns may come in any order; extra columns are ignored. Every error names the file, the
line and the column (1-based) and says what is wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REQUIRED = ("t", "w", "u", "y")
#: PID defaults (the paper's Eq. 22 gains, Sec. 4.6 sampling) for metadata a record omits.
PID_DEFAULTS = {"ts": 1e-3, "kp": 2.0, "ki": 2.97, "kd": 0.01, "u_min": 0.0, "u_max": 1.0}
#: Fewest samples worth analysing: 2 s at 1 kHz.
MIN_SAMPLES = 2000
MIN_DURATION = 1.0


class RecordError(ValueError):
    """A record that cannot be used; ``str()`` is ``FILE:LINE:COLUMN: what is wrong``."""

    def __init__(self, path: str | Path, line: int, column: int, message: str) -> None:
        self.path, self.line, self.column, self.message = str(path), line, column, message
        super().__init__(f"{path}:{line}:{column}: {message}")


@dataclass
class Record:
    """A closed-loop record. Arrays are in SI units and MU; ``meta`` holds all metadata as read."""

    path: str
    t: np.ndarray
    w: np.ndarray
    u: np.ndarray
    y: np.ndarray
    ts: float
    kp: float
    ki: float
    kd: float
    u_min: float
    u_max: float
    meta: dict[str, str] = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        """Record length [s]."""
        return self.n * self.ts

    def pid_kwargs(self) -> dict[str, float]:
        """The record's controller as keyword arguments (ts, kp, ki, kd, u_min, u_max)."""
        return {k: getattr(self, k) for k in PID_DEFAULTS}


def _value_column(raw: str) -> int:
    """1-based column where a metadata value starts (after ':' and blanks)."""
    k = raw.index(":") + 1
    while k < len(raw) and raw[k] == " ":
        k += 1
    return k + 1


def _number(path: Path, line: int, col: int, name: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise RecordError(path, line, col, f"column '{name}': {text.strip()!r} is not a number") from None
    if not math.isfinite(v):
        raise RecordError(path, line, col, f"column '{name}': {text.strip()} is not a finite number")
    return v


def read_record(path: str | Path, *, min_samples: int = MIN_SAMPLES) -> Record:
    """Reads and checks a record; raises :class:`RecordError` naming file, line and column."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise RecordError(path, 0, 0, "file not found") from None
    except UnicodeDecodeError as exc:
        raise RecordError(path, 1, 1, f"not a text file ({exc.reason})") from None
    lines = text.splitlines()
    meta: dict[str, str] = {}
    meta_line: dict[str, int] = {}
    k = 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        body = lines[k][1:].strip()
        if body:
            if ":" not in body:
                raise RecordError(path, k + 1, 2, f"metadata line {body!r} is not 'key: value'")
            key, value = body.split(":", 1)
            meta[key.strip()] = value.strip()
            meta_line[key.strip()] = k + 1
        k += 1
    if k == len(lines):
        raise RecordError(path, k + 1, 1, "no header line: expected columns t,w,u,y")
    header_no = k + 1
    header = [h.strip() for h in lines[k].split(",")]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise RecordError(path, header_no, 1, f"header lacks column(s) {', '.join(missing)} "
                          f"(found: {', '.join(header)})")
    dup = sorted({h for h in header if header.count(h) > 1 and h in REQUIRED})
    if dup:
        raise RecordError(path, header_no, header.index(dup[0]) + 1, f"column '{dup[0]}' appears twice")
    idx = {c: header.index(c) for c in REQUIRED}

    params: dict[str, float] = {}
    for key, default in PID_DEFAULTS.items():
        if key in meta:
            line = meta_line[key]
            raw = lines[line - 1]
            params[key] = _number(path, line, _value_column(raw), key, meta[key])
        else:
            params[key] = default
    if meta.get("controller", "pid").lower() != "pid":
        line = meta_line["controller"]
        raise RecordError(path, line, _value_column(lines[line - 1]),
                          f"controller '{meta['controller']}' is not supported: only the paper's 'pid'")
    for key in ("ts",):
        if params[key] <= 0:
            line = meta_line[key]
            raise RecordError(path, line, _value_column(lines[line - 1]), f"{key} must be > 0, got {params[key]}")
    if params["u_min"] >= params["u_max"]:
        line = meta_line.get("u_max", meta_line.get("u_min", 1))
        raise RecordError(path, line, 1, f"u_min {params['u_min']} must be below u_max {params['u_max']}")

    rows: list[list[float]] = []
    line_of: list[int] = []
    ncol = len(header)
    extra_names = [h for h in header if h not in REQUIRED and h]
    for j in range(k + 1, len(lines)):
        raw = lines[j]
        if not raw.strip():
            continue
        if raw.startswith("#"):
            raise RecordError(path, j + 1, 1, "metadata ('#') is only allowed before the header")
        cells = raw.split(",")
        if len(cells) != ncol:
            raise RecordError(path, j + 1, min(len(cells), ncol) + 1,
                              f"{len(cells)} fields, the header has {ncol}")
        starts = np.cumsum([0] + [len(c) + 1 for c in cells[:-1]])
        row = []
        for c in REQUIRED:
            v = _number(path, j + 1, int(starts[idx[c]]) + 1, c, cells[idx[c]])
            if c != "t" and abs(v) > 1.0:
                raise RecordError(path, j + 1, int(starts[idx[c]]) + 1,
                                  f"column '{c}': {v} is outside the converter range of +-1 MU")
            row.append(v)
        for name in extra_names:
            try:
                row.append(float(cells[header.index(name)]))
            except ValueError:
                row.append(math.nan)
        rows.append(row)
        line_of.append(j + 1)
    if not rows:
        raise RecordError(path, header_no + 1, 1, "no data rows after the header")
    data = np.array(rows)
    t = data[:, 0]
    ts = params["ts"]
    tcol = idx["t"]

    def tcolumn(line: int) -> int:
        cells = lines[line - 1].split(",")
        return sum(len(c) + 1 for c in cells[:tcol]) + 1

    dt = np.diff(t)
    if len(dt):
        bad = np.nonzero(dt <= 0)[0]
        if len(bad):
            ln = line_of[bad[0] + 1]
            raise RecordError(path, ln, tcolumn(ln), f"time {t[bad[0] + 1]} does not increase "
                              f"(previous row has {t[bad[0]]})")
        step = float(np.median(dt))
        tol = max(1e-9, 1e-3 * ts, 0.5 * 10.0 ** -_decimals(lines, line_of, tcol))
        if "ts" in meta and abs(step - ts) > tol:
            ln = meta_line["ts"]
            raise RecordError(path, ln, _value_column(lines[ln - 1]),
                              f"ts {ts} disagrees with the time column, which steps by {step:.6g} s")
        if "ts" not in meta:
            ts = params["ts"] = step
        expected = t[0] + np.arange(len(t)) * ts
        off = np.nonzero(np.abs(t - expected) > tol)[0]
        if len(off):
            ln = line_of[off[0]]
            raise RecordError(path, ln, tcolumn(ln), f"time {t[off[0]]} is not on the uniform grid of "
                              f"ts = {ts} s (expected {expected[off[0]]:.6f})")
    if len(t) < min_samples or len(t) * ts < MIN_DURATION:
        raise RecordError(path, line_of[-1], 1, f"record too short to analyse: {len(t)} samples "
                          f"({len(t) * ts:.3g} s); at least {min_samples} samples and {MIN_DURATION} s needed")
    extra = {name: data[:, 4 + m] for m, name in enumerate(extra_names)}
    return Record(str(path), t, data[:, 1], data[:, 2], data[:, 3], ts, params["kp"], params["ki"],
                  params["kd"], params["u_min"], params["u_max"], meta, extra)


def _decimals(lines: list[str], line_of: list[int], col: int) -> int:
    """Decimals written in the time column (its rounding sets the grid tolerance)."""
    cell = lines[line_of[min(1, len(line_of) - 1)] - 1].split(",")[col].strip()
    return len(cell.split(".")[1]) if "." in cell and "e" not in cell.lower() else 9


def write_record(path: str | Path, t: np.ndarray, w: np.ndarray, u: np.ndarray, y: np.ndarray, *,
                 ts: float, kp: float, ki: float, kd: float, u_min: float, u_max: float,
                 meta: dict[str, str] | None = None, extra: dict[str, np.ndarray] | None = None) -> Path:
    """Writes a record in the format above (6 decimals for the signals, as the rig's logger)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    extra = extra or {}
    with path.open("w") as fh:
        for key, value in (("ts", ts), ("controller", "pid"), ("kp", kp), ("ki", ki), ("kd", kd),
                           ("u_min", u_min), ("u_max", u_max), *((meta or {}).items())):
            fh.write(f"# {key}: {value}\n")
        fh.write(",".join(["t", "w", "u", "y", *extra]) + "\n")
        cols = [np.asarray(c) for c in (w, u, y, *extra.values())]
        td = max(4, int(math.ceil(-math.log10(ts))) + 1)
        for k in range(len(t)):
            fh.write(f"{t[k]:.{td}f}," + ",".join(f"{c[k]:.6f}" for c in cols) + "\n")
    return path
