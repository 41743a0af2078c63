"""Shared fixtures. The tests run against the *installed* package (``scripts/setup.sh`` installs it
with ``pip install .``; ``python/`` is not on ``sys.path``): its FMU is ``maglev_cosim.fmu_path()``
(or ``$MAGLEV_FMU``). Tests that compare with the repository's own files use :func:`repo`."""

from __future__ import annotations

import re
import sys
import zipfile
from pathlib import Path

import pytest

import maglev_cosim

REPO = Path(__file__).resolve().parents[1]
#: The suffix of this platform's FMU binaries: an FMU carries several (linux64 and win64).
HOST_SUFFIX = {"win32": ".dll", "darwin": ".dylib"}.get(sys.platform, ".so")


def host_binary(z: zipfile.ZipFile, model_identifier: str) -> str:
    """The name in an FMU archive of this platform's binary of ``model_identifier``."""
    names = [n for n in z.namelist() if n.startswith("binaries/") and n.endswith("/" + model_identifier + HOST_SUFFIX)]
    assert len(names) == 1, f"expected one {model_identifier}{HOST_SUFFIX} in {z.filename}, found {names}"
    return names[0]


def fmi_functions(prefix: str) -> set[str]:
    """The functions the FMI header declares (fmpy's copy of the standard's headers), ``prefix``
    ``fmi2`` or ``fmi3``."""
    import fmpy
    header = Path(fmpy.__file__).parent / "c-code" / f"{prefix}Functions.h"
    names = set(re.findall(rf"^#define ({prefix}\w+)\s+{prefix}FullName\(", header.read_text(), re.M))
    assert len(names) > 40, f"{header}: found only {len(names)} function names"
    return names


@pytest.fixture(scope="session")
def fmu_path() -> Path:
    return maglev_cosim.fmu_path()


@pytest.fixture(scope="session")
def fmu_binary(fmu_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The FMU's shared library, extracted from the archive."""
    with zipfile.ZipFile(fmu_path) as z:
        return Path(z.extract(host_binary(z, "maglev"), tmp_path_factory.mktemp("fmu_binary")))


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO
