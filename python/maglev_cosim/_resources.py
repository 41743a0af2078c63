"""Where the installed package keeps its non-Python files: the one place that knows the layout.

``pip install .`` (scikit-build-core running CMakeLists.txt) puts them into ``maglev_cosim/_data/``:

- ``maglev.fmu``: the plant FMU, FMI 2.0 (``binaries/<platform>/maglev.so`` and ``sources/`` inside);
- ``maglev3.fmu``: the same plant as an FMI 3.0 co-simulation FMU;
- ``maglev_pid.fmu``: the controller FMU (the PID of ``c/maglev_pid_fmu.c`` behind the same FMI glue);
- ``maglev_pid3.fmu``: the same controller as an FMI 3.0 co-simulation FMU;
- ``modelDescription.xml``, ``modelDescription3.xml``: the plant FMUs' model descriptions;
- ``c/``: the C sources and headers (the FMI entry points ``maglev_fmu.c`` and ``maglev_fmi3.c``, the glue
  ``maglev_fmi_common.[ch]``, the models ``maglev_plant_fmu.c`` and ``maglev_pid_fmu.[ch]``,
  ``maglev_plant.[ch]``, ``maglev_replay.[ch]``);
- ``libmaglev_fast.so`` (``.dylib``, ``maglev_fast.dll``): plant + closed-loop replay, the fast path.

``$MAGLEV_FMU`` (``$MAGLEV_FMU3`` for FMI 3.0), when set, names the FMU to use instead of the installed one.
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


_FMU_FILES = {2: ("MAGLEV_FMU", "maglev.fmu", "modelDescription.xml"),
              3: ("MAGLEV_FMU3", "maglev3.fmu", "modelDescription3.xml")}


def _version(fmi_version: int) -> tuple[str, str, str]:
    if fmi_version not in _FMU_FILES:
        raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    return _FMU_FILES[fmi_version]


def fmu_path(fmi_version: int = 2) -> Path:
    """The plant FMU: ``$MAGLEV_FMU`` if set, else the installed ``maglev_cosim/_data/maglev.fmu``;
    with ``fmi_version=3``, ``$MAGLEV_FMU3`` or the installed FMI 3.0 ``maglev3.fmu``."""
    var, name, _ = _version(fmi_version)
    env = os.environ.get(var)
    if env:
        return _need(Path(env), f"the FMU named by ${var}")
    return _need(DATA / name, f"the installed FMI {fmi_version}.0 FMU")


_PID_FMU_FILES = {2: "maglev_pid.fmu", 3: "maglev_pid3.fmu"}


def pid_fmu_path(fmi_version: int = 2) -> Path:
    """The controller FMU (the paper's PID with a step reference): ``maglev_cosim/_data/maglev_pid.fmu``;
    with ``fmi_version=3``, the FMI 3.0 ``maglev_pid3.fmu``."""
    _version(fmi_version)
    return _need(DATA / _PID_FMU_FILES[fmi_version], f"the installed FMI {fmi_version}.0 controller FMU")


def model_description_path(fmi_version: int = 2) -> Path:
    """The installed ``modelDescription.xml`` (``modelDescription3.xml`` for FMI 3.0): the one inside
    the FMU, as a plain file."""
    name = _version(fmi_version)[2]
    return _need(DATA / name, f"the installed {name}")


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
