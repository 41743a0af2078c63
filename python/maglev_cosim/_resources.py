"""Where the installed package keeps its non-Python files: the one place that knows the layout.

``pip install .`` (scikit-build-core running CMakeLists.txt) puts them into ``maglev_cosim/_data/``:

- ``maglev.fmu``: the plant FMU (``binaries/<platform>/maglev.so`` and ``sources/`` inside);
- ``maglev_pid.fmu``: the controller FMU (``c/maglev_pid_fmu.c``);
- ``modelDescription.xml``: the FMU's model description;
- ``c/``: the C sources and headers (``maglev_plant.[ch]``, ``maglev_fmu.c``, ``maglev_replay.[ch]``);
- ``libmaglev_fast.so`` (``.dylib``, ``maglev_fast.dll``): plant + closed-loop replay, the fast path.

``$MAGLEV_FMU``, when set, names the FMU to use instead of the installed one.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DATA = Path(__file__).resolve().parent / "_data"


class ResourceError(FileNotFoundError):
    """A file the installed package should carry is missing (one-line message)."""


def _need(path: Path, what: str) -> Path:
    if not path.exists():
        hint = "" if DATA.is_dir() or not path.is_relative_to(DATA) else (
            f" ({DATA} is missing: install the package with `pip install .` rather than importing it "
            "from the source tree)")
        raise ResourceError(f"{what} not found at {path}{hint}")
    return path


def data_dir() -> Path:
    """``maglev_cosim/_data`` of the installed package."""
    return _need(DATA, "the package data folder")


def fmu_path() -> Path:
    """The plant FMU: ``$MAGLEV_FMU`` if set, else the installed ``maglev_cosim/_data/maglev.fmu``."""
    env = os.environ.get("MAGLEV_FMU")
    if env:
        return _need(Path(env), "the FMU named by $MAGLEV_FMU")
    return _need(DATA / "maglev.fmu", "the installed FMU")


def pid_fmu_path() -> Path:
    """The controller FMU (the paper's PID with a step reference): ``maglev_cosim/_data/maglev_pid.fmu``."""
    return _need(DATA / "maglev_pid.fmu", "the installed controller FMU")


def model_description_path() -> Path:
    """The installed ``modelDescription.xml`` (the one inside the FMU, as a plain file)."""
    return _need(DATA / "modelDescription.xml", "the installed modelDescription.xml")


def c_dir() -> Path:
    """The installed C sources and headers."""
    return _need(DATA / "c", "the installed C sources")


def fast_library_path() -> Path:
    """The fast-path shared library (plant + replay, ``c/maglev_replay.h`` is its interface)."""
    if sys.platform == "win32":
        name = "maglev_fast.dll"
    elif sys.platform == "darwin":
        name = "libmaglev_fast.dylib"
    else:
        name = "libmaglev_fast.so"
    return _need(DATA / name, "the fast-path library")
