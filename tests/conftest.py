"""Shared fixtures. The tests run against the *installed* package (``scripts/setup.sh`` installs it
with ``pip install .``; ``python/`` is not on ``sys.path``): its FMU is ``maglev_cosim.fmu_path()``
(or ``$MAGLEV_FMU``). Tests that compare with the repository's own files use :func:`repo`."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest

import maglev_cosim

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def fmu_path() -> Path:
    return maglev_cosim.fmu_path()


@pytest.fixture(scope="session")
def fmu_binary(fmu_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The FMU's shared library, extracted from the archive."""
    with zipfile.ZipFile(fmu_path) as z:
        names = [n for n in z.namelist() if n.startswith("binaries/") and Path(n).stem == "maglev"]
        assert names, f"no binary in {fmu_path}"
        return Path(z.extract(names[0], tmp_path_factory.mktemp("fmu_binary")))


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO
