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
Columns may come in any order; extra columns are kept in :attr:`Record.extra`. Every error
names the file, the line and the character column (1-based) and says what is wrong. The full
specification, with the PID form and every metadata key, is ``docs/record-format.md``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..loop.controllers import ControllerError, load_controller
from ..loop.pid import ANTI_WINDUP as _ALL_ANTI_WINDUP
from ..loop.pid import DERIVATIVE
from ..plant.formulas import point
from ..plant.params import as_params

#: The anti-windup schemes a record's metadata can declare (a band needs its limits: a controller file).
ANTI_WINDUP = _ALL_ANTI_WINDUP[:3]

REQUIRED = ("t", "w", "u", "y")
#: PID defaults (the paper's Eq. 22 gains, Sec. 4.6 sampling) for metadata a record omits.
PID_DEFAULTS = {"ts": 1e-3, "kp": 2.0, "ki": 2.97, "kd": 0.01, "u_min": 0.0, "u_max": 1.0}
#: The metadata keys of the PID's form beside its gains (``docs/record-format.md``).
PID_FORM = ("tf", "anti_windup", "derivative")
#: Fewest samples and shortest record worth analysing, at any sample rate.
MIN_SAMPLES = 200
MIN_DURATION = 1.0
#: Plausibility thresholds (fractions of the record): above ``REFUSE`` a record is refused, above
#: ``WARN`` it is read with a warning in :attr:`Record.warnings` (the report and the JSON show them).
WARN = {"y_saturated": 0.01, "u_saturated": 0.10, "on_stop": 0.02}
REFUSE = {"y_saturated": 0.5, "u_saturated": 0.5, "on_stop": 0.5}
#: Shortest stretch counted as the ball resting on a stop [s].
STOP_RUN = 0.05


class RecordError(ValueError):
    """A record that cannot be used; ``str()`` is ``FILE:LINE:COLUMN: what is wrong``.

    ``line`` and ``column`` are 1-based; ``column`` counts characters (not bytes, not fields).
    Both are 0 when the file as a whole is at fault (missing, a directory, unreadable)."""

    def __init__(self, path: str | Path, line: int, column: int, message: str) -> None:
        self.path, self.line, self.column, self.message = str(path), line, column, message
        super().__init__(f"{path}:{line}:{column}: {message}")


@dataclass
class Record:
    """A closed-loop record. Arrays are in SI units and MU; ``meta`` holds all metadata as read.

    ``warnings`` lists what the plausibility checks found suspicious but not fatal."""

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
    warnings: list[str] = field(default_factory=list)
    tf: float = 0.0
    anti_windup: str = "none"
    derivative: str = "error"
    #: A controller declared by a controller file (metadata ``controller: FILE.toml``); None: the PID
    #: of the metadata. ``controller_file`` is where it came from.
    controller: Any = None
    controller_file: str | None = None
    #: Where the header is in the file: its line (1-based) and each column's character column, for
    #: errors found after reading that name the column (0 and empty when not read from a CSV file).
    header_line: int = 0
    header_columns: dict[str, int] = field(default_factory=dict)
    #: The reading [MU] at which the loop stood before the record began, its error ``w[0] − y_before``
    #: standing: set where the record was read from a settled point after a start that moved
    #: (:func:`maglev_cosim.records.settled.from_settled`), and every replay then starts there. None:
    #: the loop started settled at zero error where ``y[0]`` reads.
    y_before: float | None = None

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        """Record length [s]."""
        return self.n * self.ts

    def pid_kwargs(self) -> dict[str, float]:
        """The record's controller as keyword arguments (ts, kp, ki, kd, u_min, u_max, tf, anti_windup,
        derivative)."""
        return {k: getattr(self, k) for k in (*PID_DEFAULTS, *PID_FORM)}


def _controller_file(path: Path, lines: list[str], meta: dict[str, str], meta_line: dict[str, int]):
    """The controller file a record's metadata names (a path relative to the record's folder, or a
    shipped controller), read for the CE152 rig; its errors point at the metadata value."""
    value = meta["controller"].strip()
    line = meta_line["controller"]
    candidate = Path(value) if Path(value).is_absolute() else Path(path).parent / value
    try:
        return load_controller(candidate if candidate.exists() or value.endswith(".toml") else value, "ce152")
    except ControllerError as e:
        raise RecordError(path, line, _value_column(lines[line - 1]), f"controller '{value}': {e}") from None


def _value_column(raw: str) -> int:
    """1-based column where a metadata value starts (after ':' and blanks)."""
    k = raw.index(":") + 1
    while k < len(raw) and raw[k] == " ":
        k += 1
    return k + 1


def _cell_column(raw: str, index: int) -> int:
    """1-based character column of field ``index`` of a comma-separated line (its first non-blank)."""
    cells = raw.split(",")
    col = sum(len(c) + 1 for c in cells[:index])
    cell = cells[index] if index < len(cells) else ""
    return col + (len(cell) - len(cell.lstrip())) + 1


def _number(path: Path, line: int, col: int, name: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise RecordError(path, line, col, f"column '{name}': {text.strip()!r} is not a number") from None
    if not math.isfinite(v):
        raise RecordError(path, line, col, f"column '{name}': {text.strip()} is not a finite number")
    return v


def _read_text(path: Path) -> str:
    """The file as text: UTF-8, an optional byte-order mark dropped; one-line errors otherwise."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise RecordError(path, 0, 0, "file not found") from None
    except IsADirectoryError:
        raise RecordError(path, 0, 0, "is a directory, not a record file") from None
    except PermissionError:
        raise RecordError(path, 0, 0, "cannot be read: permission denied") from None
    except OSError as exc:
        raise RecordError(path, 0, 0, f"cannot be read: {exc.strerror or exc}") from None
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        bad = exc.start
        line = data.count(b"\n", 0, bad) + 1
        begin = data.rfind(b"\n", 0, bad) + 1
        col = len(data[begin:bad].decode("utf-8", errors="replace")) + 1
        raise RecordError(path, line, col, f"byte 0x{data[bad]:02x} is not UTF-8 text ({exc.reason}); "
                          "records are UTF-8 (or ASCII) text") from None


def _check_row(path: Path, line: int, raw: str, ncol: int, idx: dict[str, int]) -> list[float]:
    """Parses one data row exactly as the fast path must, raising the precise error for it."""
    cells = raw.split(",")
    if len(cells) != ncol:
        col = len(raw) + 1 if len(cells) < ncol else _cell_column(raw, ncol)
        raise RecordError(path, line, col, f"{len(cells)} fields, the header has {ncol}")
    row = []
    for c in REQUIRED:
        col = _cell_column(raw, idx[c])
        v = _number(path, line, col, c, cells[idx[c]])
        if c != "t" and abs(v) > 1.0:
            raise RecordError(path, line, col, f"column '{c}': {v} is outside the converter range of +-1 MU")
        row.append(v)
    return row


def _parse_rows(path: Path, rows: list[str], line_of: np.ndarray, ncol: int, idx: dict[str, int]) -> np.ndarray:
    """The required columns as an (n, 4) array in REQUIRED order.

    numpy's C parser reads the rows; a row it rejects (or a value out of range) is parsed again by
    :func:`_check_row`, which words the error, so a bad last row of 10^6 is reported as fast."""
    counts = np.fromiter((r.count(",") for r in rows), dtype=np.int64, count=len(rows))
    bad = np.flatnonzero(counts != ncol - 1)
    first_bad = int(bad[0]) if len(bad) else len(rows)
    cols = [idx[c] for c in REQUIRED]
    try:
        data = np.loadtxt(rows[:first_bad], delimiter=",", usecols=cols, comments=None, dtype=float, ndmin=2)
    except ValueError as exc:
        m = re.search(r"at row (\d+)", str(exc))
        guess = int(m.group(1)) if m else 0
        for k in [*range(max(guess - 1, 0), min(guess + 2, first_bad)), *range(first_bad)]:
            _check_row(path, int(line_of[k]), rows[k], ncol, idx)
        raise RecordError(path, int(line_of[0]), 1, f"data rows cannot be read: {exc}") from None
    if first_bad < len(rows):
        _check_row(path, int(line_of[first_bad]), rows[first_bad], ncol, idx)
    data = data.reshape(len(rows), len(cols))
    bad_rows = np.flatnonzero(~np.isfinite(data).all(axis=1) | (np.abs(data[:, 1:]) > 1.0).any(axis=1))
    if len(bad_rows):
        k = int(bad_rows[0])
        _check_row(path, int(line_of[k]), rows[k], ncol, idx)
    return data


def _extra_column(rows: list[str], index: int) -> np.ndarray:
    """An extra column as floats, NaN where a cell is not a number (extra columns may hold text)."""
    try:
        return np.loadtxt(rows, delimiter=",", usecols=[index], comments=None, dtype=float, ndmin=1)
    except ValueError:
        out = np.full(len(rows), math.nan)
        for k, r in enumerate(rows):
            try:
                out[k] = float(r.split(",")[index])
            except ValueError:
                pass
        return out


def read_record(path: str | Path, *, min_samples: int = MIN_SAMPLES, plausibility: str = "refuse",
                params=None) -> Record:
    """Reads and checks a record.

    Parameters
    ----------
    path : str or Path
        The record file (format: ``docs/record-format.md``). UTF-8, with or without a byte-order mark.
    min_samples : int
        Fewest samples accepted (and at least :data:`MIN_DURATION` seconds).
    plausibility : {"refuse", "warn", "off"}
        What a physically implausible record gets (constant or saturated signals, a ball on a
        stop): refused with a :class:`RecordError` beyond :data:`REFUSE`, or only warnings.
    params : PlantParams or mapping, optional
        The plant whose stops are sought in ``y`` (default: the CE152 of Section 3).

    Returns
    -------
    Record
        With :attr:`Record.warnings` listing what looked suspicious.

    Raises
    ------
    RecordError
        Naming the file, the line and the character column of what is wrong.
    """
    path = Path(path)
    if plausibility not in ("refuse", "warn", "off"):
        raise ValueError(f"plausibility must be 'refuse', 'warn' or 'off', not {plausibility!r}")
    lines = _read_text(path).splitlines()
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
    header_raw = lines[k]
    header = [h.strip() for h in header_raw.split(",")]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise RecordError(path, header_no, 1, f"header lacks column(s) {', '.join(missing)} "
                          f"(found: {', '.join(header)})")
    for j, h in enumerate(header):
        if h and h in header[:j]:
            raise RecordError(path, header_no, _cell_column(header_raw, j), f"column '{h}' appears twice")
        if not h:
            raise RecordError(path, header_no, _cell_column(header_raw, j), f"column {j + 1} has no name")
    idx = {c: header.index(c) for c in REQUIRED}

    params_pid: dict[str, float] = {}
    for key, default in PID_DEFAULTS.items():
        if key in meta:
            line = meta_line[key]
            params_pid[key] = _number(path, line, _value_column(lines[line - 1]), key, meta[key])
        else:
            params_pid[key] = default
    declared = None
    if meta.get("controller", "pid").lower() != "pid":
        declared = _controller_file(path, lines, meta, meta_line)
        for key in (*PID_DEFAULTS, *PID_FORM):
            if key in meta and key != "ts":
                line = meta_line[key]
                raise RecordError(path, line, 1, f"{key}: the controller is declared by the file "
                                  f"'{meta['controller']}'; a PID setting here would contradict it")
        params_pid.update(kp=math.nan, ki=math.nan, kd=math.nan, u_min=declared.controller.u_min,
                          u_max=declared.controller.u_max)
        if "ts" in meta and abs(params_pid["ts"] - declared.controller.ts) > 1e-9 * declared.controller.ts:
            line = meta_line["ts"]
            raise RecordError(path, line, _value_column(lines[line - 1]), f"ts {params_pid['ts']} disagrees with "
                              f"the sample time {declared.controller.ts} of controller '{meta['controller']}'")
        params_pid["ts"] = declared.controller.ts
    if params_pid["ts"] <= 0:
        line = meta_line["ts"]
        raise RecordError(path, line, _value_column(lines[line - 1]), f"ts must be > 0, got {params_pid['ts']}")
    tf = 0.0
    if "tf" in meta:
        line = meta_line["tf"]
        tf = _number(path, line, _value_column(lines[line - 1]), "tf", meta["tf"])
        if tf < 0:
            raise RecordError(path, line, _value_column(lines[line - 1]), f"tf must be >= 0 s, got {tf}")
    anti_windup = meta.get("anti_windup", "none").lower()
    if anti_windup not in ANTI_WINDUP:
        line = meta_line["anti_windup"]
        raise RecordError(path, line, _value_column(lines[line - 1]), f"anti_windup '{meta['anti_windup']}' is "
                          f"not one of {', '.join(ANTI_WINDUP)}")
    derivative = meta.get("derivative", "error").lower()
    if derivative not in DERIVATIVE:
        line = meta_line["derivative"]
        raise RecordError(path, line, _value_column(lines[line - 1]), f"derivative '{meta['derivative']}' is "
                          f"not one of {', '.join(DERIVATIVE)}")
    if params_pid["u_min"] >= params_pid["u_max"]:
        line = meta_line.get("u_max", meta_line.get("u_min", 1))
        raise RecordError(path, line, 1, f"u_min {params_pid['u_min']} must be below u_max {params_pid['u_max']}")

    body = lines[k + 1:]
    keep = [j for j, r in enumerate(body) if r.strip()]
    rows = [body[j] for j in keep]
    line_of = np.asarray(keep, dtype=np.int64) + k + 2
    hashes = [j for j, r in enumerate(rows) if r.startswith("#")]
    if hashes:
        raise RecordError(path, int(line_of[hashes[0]]), 1, "metadata ('#') is only allowed before the header")
    if not rows:
        raise RecordError(path, header_no + 1, 1, "no data rows after the header")
    ncol = len(header)
    data = _parse_rows(path, rows, line_of, ncol, idx)
    t = data[:, 0]
    ts = params_pid["ts"]
    tcol = idx["t"]

    def tcolumn(line: int) -> int:
        return _cell_column(lines[line - 1], tcol)

    dt = np.diff(t)
    if len(dt):
        bad = np.nonzero(dt <= 0)[0]
        if len(bad):
            ln = int(line_of[bad[0] + 1])
            raise RecordError(path, ln, tcolumn(ln), f"time {t[bad[0] + 1]} does not increase "
                              f"(previous row has {t[bad[0]]})")
        step = float(np.median(dt))
        tol = max(1e-9, 1e-3 * ts, 0.5 * 10.0 ** -_decimals(rows, tcol))
        if ("ts" in meta or declared is not None) and abs(step - ts) > tol:
            ln = meta_line["ts" if "ts" in meta else "controller"]
            raise RecordError(path, ln, _value_column(lines[ln - 1]),
                              f"ts {ts} disagrees with the time column, which steps by {step:.6g} s")
        if "ts" not in meta and declared is None:
            ts = params_pid["ts"] = step
        expected = t[0] + np.arange(len(t)) * ts
        off = np.nonzero(np.abs(t - expected) > tol)[0]
        if len(off):
            ln = int(line_of[off[0]])
            raise RecordError(path, ln, tcolumn(ln), f"time {t[off[0]]} is not on the uniform grid of "
                              f"ts = {ts} s (expected {expected[off[0]]:.6f})")
    if len(t) < min_samples or len(t) * ts < MIN_DURATION:
        raise RecordError(path, int(line_of[-1]), 1, f"record too short to analyse: {len(t)} samples "
                          f"({len(t) * ts:.3g} s); at least {min_samples} samples and {MIN_DURATION} s needed")
    extra_names = [h for h in header if h not in REQUIRED]
    extra = {name: _extra_column(rows, header.index(name)) for name in extra_names}
    rec = Record(str(path), t, data[:, 1], data[:, 2], data[:, 3], ts, params_pid["kp"], params_pid["ki"],
                 params_pid["kd"], params_pid["u_min"], params_pid["u_max"], meta, extra, tf=tf,
                 anti_windup=anti_windup, derivative=derivative,
                 controller=None if declared is None else declared.controller,
                 controller_file=None if declared is None else str(declared.path), header_line=header_no,
                 header_columns={h: _cell_column(header_raw, j) for j, h in enumerate(header)})
    if plausibility != "off":
        for name, fraction, message in plausibility_findings(rec, params):
            if plausibility == "refuse" and refused(name, fraction):
                col = _cell_column(header_raw, idx["u" if name == "u_saturated" else "y"])
                raise RecordError(path, header_no, col, f"implausible record: {message}")
            rec.warnings.append(message)
    return rec


def stop_runs(rec: Record, params=None) -> list[tuple[str, int, int]]:
    """Stretches where the ball rests on a stop: ``(stop, first, last + 1)`` sample indices.

    A sample is on a stop when its reading is within a tolerance of the model's reading at
    ``x_min`` or ``x_max`` (Eq. 12, 13 through the C plant), while the reference asks for a
    position well away from it; only stretches of at least :data:`STOP_RUN` count."""
    tol = max(0.01, 4.0 * _noise_std(rec.y))
    runs: list[tuple[str, int, int]] = []
    lo, hi = (point(params, _stop(params, name)).y for name in ("x_min", "x_max"))
    min_len = max(2, int(round(STOP_RUN / rec.ts)))
    for name, y_stop in (("lower", lo), ("upper", hi)):
        on = (np.abs(rec.y - y_stop) <= tol) & (np.abs(rec.w - y_stop) > 3 * tol)
        edges = np.flatnonzero(np.diff(np.concatenate(([0], on.astype(np.int8), [0]))))
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a >= min_len:
                runs.append((name, int(a), int(b)))
    return sorted(runs, key=lambda r: r[1])


def _stop(params, name: str) -> float:
    return float(getattr(as_params(params), name))


def _noise_std(y: np.ndarray) -> float:
    """Robust noise level of a signal [its unit]: the MAD of its first differences over sqrt(2)."""
    d = np.diff(y)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0)) if len(d) else 0.0


def refused(name: str, fraction: float) -> bool:
    """Whether the reader refuses a record by default for the plausibility finding ``name`` over
    ``fraction`` of its samples (:data:`REFUSE`; a constant ``y`` always)."""
    return name == "constant" or fraction > REFUSE.get(name, 1.0)


def plausibility_findings(rec: Record, params=None) -> list[tuple[str, float, str]]:
    """What makes a record physically implausible: ``(check, fraction of samples, message)``.

    Checks, most fundamental first: a constant ``y`` (no position signal), the ball resting on
    a stop (:func:`stop_runs`), ``y`` pinned at the converter limit of +-1 MU, ``u`` pinned at its limits. Each is
    reported when its fraction exceeds :data:`WARN` (``constant`` always)."""
    out: list[tuple[str, float, str]] = []
    if np.ptp(rec.y) == 0.0:
        return [("constant", 1.0, f"y is constant at {rec.y[0]:g} MU over the whole record: no position signal")]
    runs = stop_runs(rec, params)
    on = sum(b - a for _, a, b in runs) / rec.n
    if on > WARN["on_stop"]:
        first = runs[0]
        out.append(("on_stop", on, f"the ball rests on a stop in {100 * on:.1f} % of the samples ({len(runs)} "
                    f"stretch(es), the first on the {first[0]} stop from t = {rec.t[first[1]]:.3f} s for "
                    f"{(first[2] - first[1]) * rec.ts:.3f} s)"))
    sat_y = float(np.mean(np.abs(rec.y) >= 0.999))
    if sat_y > WARN["y_saturated"]:
        out.append(("y_saturated", sat_y, f"y sits at the A/D limit of +-1 MU in {100 * sat_y:.1f} % of the "
                    "samples: the position left the sensor's range"))
    span = rec.u_max - rec.u_min
    sat_u = float(np.mean((rec.u <= rec.u_min + 1e-6 * span) | (rec.u >= rec.u_max - 1e-6 * span)))
    if sat_u > WARN["u_saturated"]:
        out.append(("u_saturated", sat_u, f"u sits at its limits ({rec.u_min:g} or {rec.u_max:g} MU) in "
                    f"{100 * sat_u:.1f} % of the samples: the loop was not in control there"))
    return out


def _decimals(rows: list[str], col: int) -> int:
    """Decimals written in the time column (its rounding sets the grid tolerance)."""
    cell = rows[min(1, len(rows) - 1)].split(",")[col].strip()
    return len(cell.split(".")[1]) if "." in cell and "e" not in cell.lower() else 9


def write_record(path: str | Path, t: np.ndarray, w: np.ndarray, u: np.ndarray, y: np.ndarray, *,
                 ts: float, kp: float, ki: float, kd: float, u_min: float, u_max: float,
                 meta: dict[str, str] | None = None, extra: dict[str, np.ndarray] | None = None,
                 tf: float = 0.0, anti_windup: str = "none", derivative: str = "error") -> Path:
    """Writes a record in the format of ``docs/record-format.md`` (6 decimals for the signals, as
    the rig's logger). ``tf``, ``anti_windup`` and ``derivative`` are written only when they differ
    from the paper's."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    extra = extra or {}
    with path.open("w") as fh:
        for key, value in (("ts", ts), ("controller", "pid"), ("kp", kp), ("ki", ki), ("kd", kd),
                           ("u_min", u_min), ("u_max", u_max),
                           *((("tf", tf),) if tf else ()),
                           *((("anti_windup", anti_windup),) if anti_windup != "none" else ()),
                           *((("derivative", derivative),) if derivative != "error" else ()),
                           *((meta or {}).items())):
            fh.write(f"# {key}: {value}\n")
        fh.write(",".join(["t", "w", "u", "y", *extra]) + "\n")
        cols = [np.asarray(c) for c in (w, u, y, *extra.values())]
        td = max(4, int(math.ceil(-math.log10(ts))) + 1)
        for k in range(len(t)):
            fh.write(f"{t[k]:.{td}f}," + ",".join(f"{c[k]:.6f}" for c in cols) + "\n")
    return path
