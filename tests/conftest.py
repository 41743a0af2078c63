"""Shared fixtures: the FMU is built once (CMake) if the set-up has not built it yet."""

from __future__ import annotations

from pathlib import Path

import pytest

from maglev_cosim.fmu import REPO, build_fmu, default_fmu_path


@pytest.fixture(scope="session")
def fmu_path() -> Path:
    p = default_fmu_path()
    return p if p.is_file() else build_fmu(p.parent)


@pytest.fixture(scope="session")
def fmu_binary(fmu_path: Path) -> Path:
    libs = list((fmu_path.parent / "fmu" / "binaries").glob("*/maglev.*"))
    assert libs, f"no FMU binary next to {fmu_path}"
    return libs[0]


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO
