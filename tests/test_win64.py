"""The Windows binaries (docs/fmu.md, "Windows binaries"): the FMUs carry ``maglev.dll`` cross-compiled with
mingw-w64 (``binaries/win64`` for FMI 2.0, ``binaries/x86_64-windows`` for FMI 3.0). Checked here:

- every DLL exports exactly the FMI functions its standard's header declares and imports only Windows'
  own DLLs (no mingw runtime): needs only ``x86_64-w64-mingw32-objdump``, so this is the check that is
  left when wine cannot run;
- with wine: the small importer ``tests/c/fmi_importer.c``, cross-compiled, runs the closed-loop step
  against ``maglev.dll`` under wine, and its Linux build against ``maglev.so``; the trajectories must
  agree to 1e-12 (FMI 2.0, FMI 3.0, with the PID FMU of the same version as controller, and a rig FMU
  whose start values and GUID come from its resources/ folder). The Linux run itself is checked against loop.simulate.

Skips, with the reason, when the cross compiler or wine is absent (scripts/setup.sh installs both
when it runs as root with apt-get)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import maglev_cosim
from conftest import fmi_functions
from maglev_cosim._resources import pid_fmu_path
from maglev_cosim.loop.simulate import reference_signal, simulate
from maglev_cosim.loop.loop_fmu import STOP, loop_settings

REPO = Path(__file__).resolve().parents[1]
BUILD = REPO / "build"
WIN64 = BUILD / "win64"  # the CMake build's win64 sub-build (CMakeLists.txt, MAGLEV_WIN64)
TOL = 1e-12
OBJDUMP = shutil.which("x86_64-w64-mingw32-objdump")
# Debian's wine64 package installs its loader at /usr/lib/wine/wine64, not on PATH
WINE = shutil.which("wine64") or next((w for w in ("/usr/lib/wine/wine64",) if os.access(w, os.X_OK)), None)

needs_mingw = pytest.mark.skipif(OBJDUMP is None or not sys.platform.startswith("linux"),
                                 reason="no mingw-w64 (x86_64-w64-mingw32-objdump): the FMUs carry no Windows binaries")
FALLBACK = "the Windows binaries are checked by their export tables only (test_dll_exports_exactly_the_fmi_functions)"
needs_wine = pytest.mark.skipif(WINE is None, reason=f"wine64 is not installed: {FALLBACK}")

FMUS = {"fmi2": (lambda: maglev_cosim.fmu_path(), "binaries/win64/maglev.dll", "fmi2"),
        "fmi3": (lambda: maglev_cosim.fmu_path(fmi_version=3), "binaries/x86_64-windows/maglev.dll", "fmi3"),
        "pid": (pid_fmu_path, "binaries/win64/maglev_pid.dll", "fmi2"),
        "pid3": (lambda: pid_fmu_path(fmi_version=3), "binaries/x86_64-windows/maglev_pid.dll", "fmi3")}


def pe_table(dll: Path) -> tuple[set[str], set[str]]:
    """(exported names, imported DLL names) of a PE file, from objdump -p."""
    text = subprocess.run([OBJDUMP, "-p", str(dll)], capture_output=True, text=True, check=True).stdout
    imports = set(re.findall(r"^\s*DLL Name: (\S+)", text, re.M))
    m = re.search(r"\[Ordinal/Name Pointer\] Table\n(.*?)(?:\n\s*\n|\Z)", text, re.S)
    assert m, f"{dll}: no export table"
    exports = set(re.findall(r"^\s*\[\s*\d+\]\s+(\S+)\s*$", m.group(1), re.M))
    return exports, imports


@pytest.fixture(scope="module")
def extracted(tmp_path_factory) -> dict[str, Path]:
    """The installed FMUs (plant 2.0, 3.0, PID 2.0, 3.0), extracted."""
    out = {}
    for key, (path, dll, _) in FMUS.items():
        d = tmp_path_factory.mktemp(key)
        with zipfile.ZipFile(path()) as z:
            z.extractall(d)
        out[key] = d
    return out


@needs_mingw
@pytest.mark.parametrize("key", FMUS)
def test_fmus_carry_the_windows_binary_next_to_the_linux_one(key):
    path, dll, _ = FMUS[key]
    with zipfile.ZipFile(path()) as z:
        names = set(z.namelist())
    linux = dll.replace("win64", "linux64").replace("x86_64-windows", "x86_64-linux").replace(".dll", ".so")
    assert {dll, linux} <= names, f"{path()}: expected {dll} and {linux}, has {sorted(n for n in names if 'bin' in n)}"


@needs_mingw
@pytest.mark.parametrize("key", FMUS)
def test_dll_exports_exactly_the_fmi_functions(key, extracted):
    """The export table holds the standard's functions and nothing else; the DLL needs no mingw runtime DLL
    (libgcc is linked statically): only KERNEL32 and the C runtime Windows has."""
    _, dll, prefix = FMUS[key]
    exports, imports = pe_table(extracted[key] / dll)
    want = fmi_functions(prefix)
    assert exports == want, f"{dll}: missing {sorted(want - exports)}, extra {sorted(exports - want)}"
    system = {"kernel32.dll", "msvcrt.dll", "ucrtbase.dll"}
    assert imports and all(i.lower() in system or i.lower().startswith("api-ms-win-crt-") for i in imports), imports


def _run(cmd: list[str], cwd: Path) -> np.ndarray:
    env = {**os.environ, "WINEPREFIX": str(BUILD / "wine"), "WINEDEBUG": "-all"}
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd, timeout=300)
    assert r.returncode == 0, f"{cmd[:3]} failed ({r.returncode}): {r.stderr[-2000:]}"
    lines = r.stdout.splitlines()
    assert lines[0].split() == ["t", "w", "y", "u", "x", "v", "i"], lines[:1]
    return np.array([[float(v) for v in ln.split()] for ln in lines[1:]])


def importer_runs(fmu_dir: Path, stop: float, args: list[str], *, windows_path: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The importer's trajectory: (Linux build on maglev.so, Windows build under wine on maglev.dll)."""
    linux_exe, win_exe = BUILD / "fmi_importer", WIN64 / "fmi_importer.exe"
    for exe in (linux_exe, win_exe):
        if not exe.exists():
            pytest.fail(f"{exe} is missing: run scripts/setup.sh (the CMake build in build/)")
    (BUILD / "wine").mkdir(exist_ok=True)
    # under wine a Unix path works as is (drive Z: is /); a Windows program gets Z:\... from a real importer
    win_dir = "Z:" + str(fmu_dir).replace("/", "\\") if windows_path else str(fmu_dir)
    lin = _run([str(linux_exe), str(fmu_dir), repr(stop), *args], fmu_dir)
    win = _run([WINE, str(win_exe), win_dir, repr(stop), *args], fmu_dir)
    return lin, win


def settings_args() -> list[str]:
    """The loop's experiment (the SSP loop's: settled at 3.2 mm, step of 0.05 MU at 0.1 s) as name=value."""
    s = loop_settings()
    return [f"{k}={v!r}" for group in (s["plant"], s["pid"]) for k, v in group.items()]


def max_difference(lin: np.ndarray, win: np.ndarray) -> float:
    assert lin.shape == win.shape and lin.shape[0] > 0, (lin.shape, win.shape)
    return float(np.max(np.abs(lin - win)))


@pytest.fixture(scope="module")
def wine_runs() -> None:
    """Skips when wine is installed but cannot run a Windows program here (the importer without
    arguments prints its usage: no FMU involved)."""
    exe = WIN64 / "fmi_importer.exe"
    if not exe.exists():
        pytest.fail(f"{exe} is missing: run scripts/setup.sh (the CMake build in build/)")
    (BUILD / "wine").mkdir(exist_ok=True)
    env = {**os.environ, "WINEPREFIX": str(BUILD / "wine"), "WINEDEBUG": "-all"}
    try:
        r = subprocess.run([WINE, str(exe)], capture_output=True, text=True, env=env, timeout=300)
        ok, why = "fmi_importer: usage" in r.stderr, r.stderr.strip()[-300:]
    except (OSError, subprocess.TimeoutExpired) as e:
        ok, why = False, str(e)
    if not ok:
        pytest.skip(f"wine cannot run a Windows program here ({why}): {FALLBACK}")


@pytest.fixture(scope="module")
def linux_reference() -> np.ndarray:
    """loop.simulate on the installed FMU: w y u x v i, the check of the importer's Linux run."""
    s = loop_settings()
    w = reference_signal("step", STOP, base=s["pid"]["w0"], amplitude=s["pid"]["w1"] - s["pid"]["w0"])
    r = simulate("section3", w, backend="fmu")
    return np.column_stack([r[k] for k in ("w", "y", "u", "x", "v", "i")])


@needs_mingw
@needs_wine
@pytest.mark.slow   # wine takes 20 s: scripts/test.sh runs these in its Windows step
@pytest.mark.parametrize("case", ["fmi2", "fmi3", "fmi2+pid_fmu", "fmi3+pid3_fmu"])
def test_wine_closed_loop_matches_linux(case, wine_runs, extracted, linux_reference):
    """The closed-loop step, 1 s at the paper's 1 kHz: maglev.dll under wine against maglev.so."""
    args = settings_args()
    if "+" in case:     # the controller FMU of the same FMI version
        args = ["--pid-fmu", str(extracted["pid3" if case.startswith("fmi3") else "pid"]), *args]
    lin, win = importer_runs(extracted[case.split("+")[0]], STOP, args)
    diff = max_difference(lin, win)
    print(f"\n[win64] {case}: {len(lin)} samples, max |linux64 - win64 under wine| = {diff:.3g}")
    assert diff <= TOL, f"{case}: Windows and Linux differ by {diff:.3g} (> {TOL})"
    # the importer ran the loop loop.simulate runs (not a constant or a wrong loop)
    assert np.ptp(lin[:, 2]) > 0.04, "the reading did not follow the step"
    ref = np.max(np.abs(lin[:, 1:] - linux_reference))
    assert ref <= TOL, f"{case}: the importer's Linux run differs from loop.simulate by {ref:.3g}"


@needs_mingw
@needs_wine
@pytest.mark.slow   # wine takes 20 s: scripts/test.sh runs these in its Windows step
def test_wine_rig_fmu_reads_its_resources(tmp_path, wine_runs, extracted):
    """A rig FMU (its GUID in resources/guid.txt, its parameters in resources/start_values.txt), given to
    the DLL as a Windows resource URI (file:///Z:/...): instantiated, and the same run as on Linux."""
    fmu = tmp_path / "rig.fmu"
    subprocess.run([sys.executable, "-m", "maglev_cosim", "fmu", "--rig", "inteco-mls2em", "--out", str(fmu)],
                   check=True, capture_output=True)
    rig = tmp_path / "rig"
    with zipfile.ZipFile(fmu) as z:
        assert "binaries/win64/maglev.dll" in z.namelist()
        z.extractall(rig)
    lin, win = importer_runs(rig, 0.3, [], windows_path=True)
    diff = max_difference(lin, win)
    print(f"\n[win64] rig FMU: {len(lin)} samples, max |linux64 - win64 under wine| = {diff:.3g}")
    assert diff <= TOL
    nominal, _ = importer_runs(extracted["fmi2"], 0.3, [])
    assert np.max(np.abs(nominal - lin)) > 1e-3, "the rig's start values were not used"
