"""Writes one section of docs/benchmarks.md: every benchmark script measures, then replaces its own
section (found by its heading) with the figures, the command that printed them, the date and the
machine. Nothing in docs/benchmarks.md is edited by hand; a script that is run again replaces its
section. Used by the scripts beside it (``import benchdoc``: scripts/ is on ``sys.path`` when a
script in it runs)."""

from __future__ import annotations

import datetime
import os
import platform
import re
import shlex
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "benchmarks.md"
HEAD = ("# Benchmarks and measured figures\n\n"
        "Every section below is written by the script it names, with the command, the date, the machine "
        "and the wall time of the run that measured it; running the script again replaces its section. "
        "The tests check bounds, not these numbers, and time nothing.\n")


def machine() -> str:
    """This machine in one line: cores, CPU model, Python."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores, {cpu}, Python {platform.python_version()}"


def command_line() -> str:
    """The command that runs this script as it was run (relative to the repository)."""
    script = Path(sys.argv[0]).resolve()
    try:
        script = script.relative_to(ROOT)
    except ValueError:
        pass
    return " ".join([".venv/bin/python", shlex.quote(str(script)), *map(shlex.quote, sys.argv[1:])])


def reference_seconds(repeat: int = 3) -> float:
    """A fixed workload no code of the project touches, timed here (best of ``repeat``) [s]: 2·10^6
    multiply-adds in a pure-Python loop. Two machines that report the same CPU model (virtual
    machines do) may differ by half in speed; a section's figures scale roughly with this one, so
    sections measured on different machines can be compared."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        acc = 0
        for k in range(2_000_000):
            acc += k * k
        best = min(best, time.perf_counter() - t0)
    return best


def stamp(wall_s: float, command: str | None = None) -> str:
    """The provenance line a section starts with."""
    try:
        load = f"; 1-minute load average {os.getloadavg()[0]:.1f} at the end (the run counts about 1)"
    except OSError:
        load = ""
    return (f"Written by `{command or command_line()}` on {datetime.date.today().isoformat()} ({machine()}; "
            f"machine reference {1e3 * reference_seconds():.0f} ms, `benchdoc.reference_seconds`); "
            f"wall time {wall_s:.0f} s{load}.")


def replace_section(text: str, doc: Path = DOC) -> str:
    """Replaces the section of ``doc`` whose heading is ``text``'s first line (or appends it) with
    ``text``; returns it."""
    heading = text.splitlines()[0]
    old = doc.read_text() if doc.exists() else HEAD
    pat = re.compile(rf"^{re.escape(heading)}\n.*?(?=^## |\Z)", re.S | re.M)
    text = text.strip("\n") + "\n"
    new = pat.sub(lambda _: text + "\n", old, count=1) if pat.search(old) else old.rstrip("\n") + "\n\n" + text
    doc.write_text(new.rstrip("\n") + "\n")
    return text


def publish(text: str, write: bool = True, doc: Path = DOC) -> None:
    """Prints a section (from :func:`section`) and, with ``write``, puts it into ``doc``
    (:func:`replace_section`)."""
    print(text)
    if write:
        replace_section(text, doc)
        print(f"wrote the section of {doc}")


def section(title: str, body: str, wall_s: float, *, command: str | None = None) -> str:
    """The section ``## title``: the stamp, then ``body``."""
    return f"## {title}\n\n{stamp(wall_s, command)}\n\n{body.strip()}\n"


def write_section(title: str, body: str, wall_s: float, *, command: str | None = None, doc: Path = DOC) -> str:
    """Replaces the section ``## title`` of ``doc`` (or appends it) with the stamp and ``body``;
    returns the section's text."""
    return replace_section(section(title, body, wall_s, command=command), doc)


def table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)
