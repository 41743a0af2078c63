"""The installed package: what it carries, where it finds it, and (slow) that a wheel built from the
repository installs into a fresh virtual environment and works from outside the clone."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

import maglev_cosim
from maglev_cosim import _resources
from maglev_cosim.loop.fmu import FmuError, ensure_fmu

STALE = "the installed package is older than the repository: run bash scripts/setup.sh"


def test_the_tests_import_the_installed_package(repo):
    here = Path(maglev_cosim.__file__).resolve()
    assert not here.is_relative_to(repo / "python"), f"maglev_cosim imported from the source tree: {here}"
    assert here.parent / "_data" == _resources.DATA


def test_installed_c_sources_and_model_description_are_the_repository_ones(repo):
    c = _resources.c_dir()
    ours = sorted(p.name for p in (repo / "c").iterdir() if p.suffix in (".c", ".h"))
    assert sorted(p.name for p in c.iterdir()) == ours, STALE
    for name in ours:
        assert (c / name).read_bytes() == (repo / "c" / name).read_bytes(), f"{name}: {STALE}"
    assert _resources.model_description_path().read_bytes() == (repo / "modelDescription.xml").read_bytes(), STALE
    assert _resources.model_description_path(3).read_bytes() == (repo / "modelDescription3.xml").read_bytes(), STALE


# Every FMU: one set of FMI entry points, the one glue, one model (docs/fmu.md, "One glue, two models").
GLUE = ("maglev_fmi_common.c", "maglev_fmi_common.h")
PLANT_MODEL = ("maglev_plant_fmu.c", "maglev_plant.c", "maglev_plant.h")
PID_MODEL = ("maglev_pid_fmu.c", "maglev_pid_fmu.h", "maglev_replay.c", "maglev_replay.h", "maglev_plant.c",
             "maglev_plant.h")
INSTALLED_FMUS = {
    "plant-fmi2": (lambda: maglev_cosim.fmu_path(), "modelDescription.xml", ("maglev_fmu.c", *GLUE, *PLANT_MODEL)),
    "plant-fmi3": (lambda: maglev_cosim.fmu_path(fmi_version=3), "modelDescription3.xml",
                   ("maglev_fmi3.c", *GLUE, *PLANT_MODEL)),
    "pid-fmi2": (lambda: _resources.pid_fmu_path(), "modelDescription_pid.xml", ("maglev_fmu.c", *GLUE, *PID_MODEL)),
    "pid-fmi3": (lambda: _resources.pid_fmu_path(fmi_version=3), "modelDescription_pid3.xml",
                 ("maglev_fmi3.c", *GLUE, *PID_MODEL)),
}


@pytest.mark.parametrize("key", INSTALLED_FMUS)
def test_installed_fmu_carries_the_repository_model_description_and_sources(repo, key):
    path, xml, files = INSTALLED_FMUS[key]
    with zipfile.ZipFile(path()) as z:
        assert z.read("modelDescription.xml") == (repo / xml).read_bytes(), STALE
        sources = {n.removeprefix("sources/") for n in z.namelist() if n.startswith("sources/") and n[-1] != "/"}
        assert sources - {"buildDescription.xml"} == set(files), f"{path().name}: {STALE}"
        for name in files:
            assert z.read(f"sources/{name}") == (repo / "c" / name).read_bytes(), f"{name}: {STALE}"


def test_pid_fmu_path_api():
    assert _resources.pid_fmu_path().name == "maglev_pid.fmu"
    assert _resources.pid_fmu_path(fmi_version=3).name == "maglev_pid3.fmu"
    with pytest.raises(ValueError, match="fmi_version"):
        _resources.pid_fmu_path(fmi_version=1)


def test_fast_library_is_installed_and_loads():
    from maglev_cosim.plant import fast

    assert _resources.fast_library_path().is_file()
    assert "k_c" in fast.param_names()


def test_maglev_fmu_overrides_the_installed_fmu(tmp_path, monkeypatch):
    installed = maglev_cosim.fmu_path()
    other = tmp_path / "other.fmu"
    other.write_bytes(installed.read_bytes())
    monkeypatch.setenv("MAGLEV_FMU", str(other))
    assert maglev_cosim.fmu_path() == other
    assert ensure_fmu(None) == other
    monkeypatch.setenv("MAGLEV_FMU", str(tmp_path / "missing.fmu"))
    with pytest.raises(FileNotFoundError, match="MAGLEV_FMU"):
        maglev_cosim.fmu_path()
    with pytest.raises(FmuError, match="missing.fmu"):
        ensure_fmu(None)
    monkeypatch.setenv("MAGLEV_FMU3", str(other))
    assert maglev_cosim.fmu_path(fmi_version=3) == other and ensure_fmu(None, fmi_version=3) == other


# ----------------------------------------------------------------------------- the wheel (slow)

WHEEL_MEMBERS = [
    "maglev_cosim/__init__.py",
    "maglev_cosim/_resources.py",
    "maglev_cosim/cli.py",
    "maglev_cosim/_data/maglev.fmu",
    "maglev_cosim/_data/maglev3.fmu",
    "maglev_cosim/_data/maglev_pid.fmu",
    "maglev_cosim/_data/maglev_pid3.fmu",
    "maglev_cosim/_data/c/maglev_pid_fmu.c",
    "maglev_cosim/_data/c/maglev_pid_fmu.h",
    "maglev_cosim/_data/modelDescription.xml",
    "maglev_cosim/_data/modelDescription3.xml",
    "maglev_cosim/_data/libmaglev_fast.so",
    "maglev_cosim/_data/c/maglev_fmu.c",
    "maglev_cosim/_data/c/maglev_fmi3.c",
    "maglev_cosim/_data/c/maglev_fmi_common.c",
    "maglev_cosim/_data/c/maglev_plant_fmu.c",
    "maglev_cosim/_data/c/maglev_plant.c",
    "maglev_cosim/_data/c/maglev_plant.h",
    "maglev_cosim/_data/c/maglev_replay.c",
    "maglev_cosim/_data/c/maglev_replay.h",
]


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 300) -> subprocess.CompletedProcess:
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} exited {r.returncode}:\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
    return r


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="checks the Linux file names")
def test_wheel_installs_into_a_fresh_venv_and_runs_outside_the_clone(repo, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("MAGLEV_FMU", "MAGLEV_FMU3", "PYTHONPATH", "PYTHONHOME")}

    # 1. the wheel, built from the repository as pip builds it (isolated, scikit-build-core + CMake)
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "pip", "wheel", str(repo), "--no-deps", "--quiet", "-w", str(dist)], tmp_path, env,
         timeout=900)
    wheels = list(dist.glob("maglev_cosim-*.whl"))
    assert len(wheels) == 1, wheels
    wheel = wheels[0]
    assert wheel.name.startswith(f"maglev_cosim-{maglev_cosim.__version__}-py3-none-linux_")
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = [m for m in WHEEL_MEMBERS if m not in names]
    assert not missing, f"not in {wheel.name}: {missing}"
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)
    with zipfile.ZipFile(wheel) as z:
        (tmp_path / "maglev.fmu").write_bytes(z.read("maglev_cosim/_data/maglev.fmu"))
    fmu_names = set(zipfile.ZipFile(tmp_path / "maglev.fmu").namelist())
    assert {"modelDescription.xml", "binaries/linux64/maglev.so", "sources/maglev_fmu.c",
            "sources/maglev_plant.c", "sources/maglev_plant.h"} <= fmu_names

    # 2. a fresh venv with only the wheel installed; the dependencies (numpy, scipy, fmpy, ...) come from
    #    this environment's site-packages through a .pth file, whose folder goes after the venv's own
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], tmp_path, env)
    py = venv / "bin" / "python"
    site = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path,
                     env).stdout.strip())
    _run([str(py), "-m", "pip", "install", "--no-deps", "--no-index", "--quiet", "--disable-pip-version-check",
          str(wheel)], tmp_path, env)
    # after the install: with this environment's maglev-cosim visible, pip would see it as installed already
    (site / "_maglev_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")

    # 3. from a folder outside the clone, with the new venv's interpreter and command
    work = tmp_path / "work"
    work.mkdir()
    r = _run([str(py), "-c", "import maglev_cosim; print(maglev_cosim.__file__); print(maglev_cosim.fmu_path())"],
             work, env)
    module, fmu = (Path(line) for line in r.stdout.split())
    assert module.is_relative_to(site), f"maglev_cosim imported from {module}, not the new venv"
    assert fmu == site / "maglev_cosim" / "_data" / "maglev.fmu" and fmu.is_file()

    cli = str(venv / "bin" / "maglev-cosim")
    _run([cli, "--help"], work, env)
    _run([cli, "step", "--duration", "0.5", "--out", "step"], work, env)
    assert all((work / "step" / f).stat().st_size > 0 for f in ("step.csv", "step.png", "step.json"))
    _run([cli, "linearize", "--params", "eq18", "--json", "lin.json", "--plots", "lin"], work, env)
    assert (work / "lin.json").stat().st_size > 0
    assert {p.name for p in (work / "lin").glob("*.png")} == {"root_locus.png", "closed_loop_bode.png"}
    _run([cli, "synth", "--out", "rec.csv", "--duration", "3", "--effect", "delay:T_d=0.0025"], work, env)
    assert (work / "rec.csv").is_file()
    _run([cli, "diagnose", "rec.csv", "--out", "diag", "--effects", "delay"], work, env)
    assert json.loads((work / "diag" / "diagnosis.json").read_text())["selected"] == ["delay"]
    for f in ("diagnosis.json", "report.md", "maglev_calibrated.fmu"):
        assert (work / "diag" / f).stat().st_size > 0, f
    # nothing was compiled at run time
    assert not list((site / "maglev_cosim").rglob("*.o"))
