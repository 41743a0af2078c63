"""One loader for every record format: :func:`load` reads a CE152 record (CSV in machine units with
its controller, ``docs/record-format.md``), an Inteco results ``.mat``, a levitador text record or
any text record that declares its columns in SI units (``docs/bringing-your-rig.md``), and returns
one type, :class:`Recording`, which is what the diagnosis takes.

The format is told from the content (:func:`maglev_cosim.records.measured.sniff`), never the name;
the rig says which kind of record is expected: none (or ``ce152``) a CE152 record, any other rig a
real rig's record. A record that does not fit its rig is refused in one line that says what the file
is and which ``--rig`` it likely needs (:class:`WrongRig`); bad data inside a record is refused by the
format's reader as ``FILE:LINE:COLUMN: what is wrong`` (:class:`~maglev_cosim.records.record.RecordError`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..rigs import SHIPPED, Rig, load_rig
from .measured import MEASURED_FORMATS, Measured, read_measured, sniff
from .record import Record, read_record

#: How each format is named in a refusal.
FORMAT_WORDS = {"inteco-mat": "an Inteco MATLAB results file", "levitador": "a levitador benchmark text record",
                "columns": "a text record that declares its columns"}


class WrongRig(ValueError):
    """A record whose format does not fit the rig it was given (a CE152 record with a real rig, a
    real rig's record with none); ``str()`` names the file, what it is and the rig it likely needs."""


@dataclass
class Recording:
    """A record of any format, as the diagnosis takes it: exactly one of ``ce152`` (a CE152 record,
    machine units, its declared controller) and ``measured`` (a real rig's record, SI units, optional
    current and actuator signal) is set; ``rig`` is the rig it was recorded on (None: the paper's
    CE152, the record's own controller)."""

    path: Path
    format: str                      #: ``ce152``, ``inteco-mat``, ``levitador`` or ``columns``
    ce152: Record | None = None
    measured: Measured | None = None
    rig: Rig | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def kind(self) -> str:
        """``"ce152"`` (replayed in closed loop with its declared controller) or ``"rig"`` (a real
        rig's record, predicted from its measured actuator signal)."""
        return "ce152" if self.ce152 is not None else "rig"

    @property
    def label(self) -> str:
        return self.measured.label if self.measured is not None else self.path.stem

    @property
    def ts(self) -> float:
        """Sample time [s]."""
        return self.ce152.ts if self.ce152 is not None else self.measured.ts

    @property
    def n(self) -> int:
        """Number of samples."""
        return self.ce152.n if self.ce152 is not None else self.measured.n

    @property
    def duration(self) -> float:
        """Length [s]."""
        return self.ce152.duration if self.ce152 is not None else self.measured.duration


def _rig(rig: Rig | str | None) -> Rig | None:
    """The rig of a real record, or None for the CE152 (``None`` or ``"ce152"``)."""
    if isinstance(rig, Rig):
        return None if rig.name == "ce152" else rig
    return None if rig in (None, "ce152") else load_rig(rig)


def is_measured(path: str | Path) -> bool:
    """A real rig's published record (an Inteco .mat, a levitador text, a text record that declares
    its columns) rather than the CE152 record format; told from the content."""
    fmt = sniff(path)
    return fmt in MEASURED_FORMATS or (fmt is None and Path(path).suffix.lower() == ".mat")


def likely_rig(path: str | Path) -> str:
    """``"; likely --rig NAME (...)"`` when exactly one shipped real rig fits the record's sample time
    and travel (most positions between its stops), else ``""``. A record that cannot be read gets
    ``""``: its error comes when it is read."""
    try:
        m = read_measured(path)
    except Exception:  # the read error itself is reported where the record is used
        return ""
    fits = []
    for name in SHIPPED:
        if name == "ce152":
            continue
        rig = load_rig(name)
        lo, hi = rig.stops
        inside = float(np.mean((m.position >= lo - 1e-3) & (m.position <= hi + 1e-3)))
        if abs(m.ts - rig.ts) <= 1e-3 * rig.ts and inside > 0.9:
            fits.append(rig)
    if len(fits) != 1:
        return ""
    rig = fits[0]
    return (f"; likely --rig {rig.name} (its {rig.ts * 1e3:g} ms sample time and its travel "
            f"{rig.stops[0] * 1e3:g}-{rig.stops[1] * 1e3:g} mm fit the record)")


def check_rig(path: str | Path, rig: Rig | str | None) -> None:
    """Refuses (:class:`WrongRig`) a record whose format does not fit ``rig``: a CE152-format record
    given a real rig, a real rig's record given none or the CE152."""
    name = rig.name if isinstance(rig, Rig) else rig
    real = _rig(rig)
    fmt = sniff(path)
    if fmt == "ce152" and real is not None:
        raise WrongRig(f"{path} is a CE152-format record (docs/record-format.md: '# key: value' metadata, then "
                       f"the header t,w,u,y in machine units), not a record of a real rig: --rig {name} does not "
                       "fit it; diagnose it without --rig")
    if real is None and is_measured(path):
        what = FORMAT_WORDS.get(fmt, "a real rig's record")
        if name is None:
            raise WrongRig(f"{path} is {what}, a real rig's record: name its rig with --rig (inteco-mls2em, "
                           f"levitador, or a rig file, docs/rigs.md){likely_rig(path)}")
        raise WrongRig(f"{path} is {what}, not a CE152-format record: --rig {name} does not fit it{likely_rig(path)}")


def load(path: str | Path, rig: Rig | str | None = None, *, resample: bool = False,
         require: Sequence[str] = ("drive",), plausibility: str = "refuse") -> Recording:
    """Reads a record of any format (module docstring).

    Parameters
    ----------
    path : str or Path
        The record file.
    rig : Rig, str or None
        The rig it was recorded on: a :class:`~maglev_cosim.rigs.Rig`, a shipped rig's name or a
        rig file; None or ``"ce152"``: a CE152 record.
    resample : bool
        A real record with non-uniform time is interpolated onto a uniform grid instead of refused.
    require : sequence of str
        The signals a real record must hold besides time and position (``"drive"``: the actuator
        signal the prediction is driven by; ``"reference"``: a declared controller's input;
        ``"current"``); refused on the header otherwise.
    plausibility : {"refuse", "warn", "off"}
        What a CE152 record that looks physically implausible gets (:func:`~.record.read_record`).
    """
    check_rig(path, rig)
    real = _rig(rig)
    p = Path(path)
    if real is None:
        rec = read_record(p, plausibility=plausibility)
        return Recording(p, "ce152", ce152=rec, warnings=list(rec.warnings))
    m = read_measured(p, resample=resample, require=require)
    return Recording(p, m.fmt, measured=m, rig=real, warnings=list(m.warnings))


def load_all(paths: Sequence[str | Path], rig: Rig | str | None = None, **kw) -> list[Recording]:
    """:func:`load` of every path, every one checked before any is used; the rig is loaded once."""
    real = _rig(rig)
    return [load(p, real if real is not None else rig, **kw) for p in paths]
