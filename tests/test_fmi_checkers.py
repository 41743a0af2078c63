"""Every FMU the project writes, through two importers that are not fmpy: the Modelica Association's
reference importer ``fmusim`` (Reference-FMUs v0.0.39: FMI 2.0 and 3.0) and the FMU Compliance
Checker ``fmuCheck`` (2.0.4, FMI Library 2.0.3: FMI 1.0 and 2.0 only, so not the 3.0 plant).

The FMU kinds: the plant (FMI 2.0 and 3.0), the controller (``maglev_pid.fmu``, ``maglev_pid3.fmu``), a rig's plant
(``maglev-cosim fmu --rig inteco-mls2em``) and a calibrated plant (``maglev_calibrated.fmu``, made
the way the diagnosis makes it). For each:

- validation: ``fmuCheck`` (FMI 2.0 kinds) exits 0 and its summary counts 0 errors; its own
  simulation of the input below agrees with fmpy's; ``fmusim`` runs the default experiment with
  every FMI call returning OK;
- agreement: ``fmusim`` and ``fmpy.simulate_fmu`` drive the FMU with the same piecewise-constant
  input (the plant: the input that holds the ball at rest mid-travel, from the package's formulas,
  then a small doublet; the controller: its measured input ``y``), the same start values and
  communication step, and every output agrees to 1e-9.

The prebuilt tools (x86_64 Linux) live in ``$MAGLEV_FMI_CHECKERS``, else in
``<repo>/../shared/tools/fmi-checkers``, else ``/work/shared/tools/fmi-checkers``; without them the
tests skip, naming the folders looked at. Under 4 s in all.
"""

from __future__ import annotations

import os
import platform
import re
import subprocess
import sys
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu

import maglev_cosim
from conftest import REPO
from maglev_cosim._resources import pid_fmu_path
from maglev_cosim.plant.formulas import point

H = 1e-3            # communication step [s] of every run here (the FMUs' default experiment step)
N = 200             # steps of the input-driven runs
TOL = 1e-9          # max |fmusim - fmpy| of every output
FMUSIM, FMUCHECK = "fmusim", "fmuCheck.linux64"


def _tools() -> Path:
    """``$MAGLEV_FMI_CHECKERS``, else ``../shared/tools/fmi-checkers`` beside the clone, else (as for
    the real records, tests/real_data.py) the development machine's ``/work/shared/tools/fmi-checkers``."""
    env = os.environ.get("MAGLEV_FMI_CHECKERS")
    looked = [Path(env)] if env else [REPO.parent / "shared" / "tools" / "fmi-checkers",
                                      Path("/work/shared/tools/fmi-checkers")]
    found = [d for d in looked if all(os.access(d / n, os.X_OK) for n in (FMUSIM, FMUCHECK))]
    if not found:
        pytest.skip(f"FMI checkers not found: no executable {FMUSIM} and {FMUCHECK} in "
                    f"{' or '.join(map(str, dict.fromkeys(looked)))} (set $MAGLEV_FMI_CHECKERS to their folder)")
    d = found[0]
    if sys.platform != "linux" or platform.machine() != "x86_64":
        pytest.skip(f"the FMI checkers in {d} are x86_64 Linux binaries; this is {sys.platform} {platform.machine()}")
    return d


@pytest.fixture(scope="module")
def tools() -> Path:
    return _tools()


# --- the FMU kinds --------------------------------------------------------------------------------

@dataclass
class Kind:
    fmu: Path
    fmi_version: int
    inputs: dict[str, np.ndarray]                # the inputs the runs drive: the value over each step [k*H, (k+1)*H)
    start: dict[str, float] = field(default_factory=dict)


def _levitating(fmu: Path, fmi_version: int) -> Kind:
    """A plant FMU driven by the input that holds the ball at rest mid-travel (Eq. 8 at rest,
    Eq. 1, 5 or the rig's drive, through the package's formulas, on the FMU's own start values),
    then a 0.2 % doublet that sets it moving: the ball starts there at rest with the current."""
    md = read_model_description(str(fmu))
    p = {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter"}
    x = 0.5 * (p["x_min"] + p["x_max"])
    eq = point({**p, "x_start": x, "v_start": 0.0}, x)
    u = np.full(N, eq.u)
    u[N // 4:N // 4 + 10] *= 1.002
    u[N // 4 + 10:N // 4 + 20] *= 0.998
    return Kind(fmu, fmi_version, {"u": u}, {"x_start": x, "v_start": 0.0, "i_start": eq.i})


def _make(name: str, tmp: Path) -> Kind:
    if name == "plant-fmi2":
        return _levitating(maglev_cosim.fmu_path(), 2)
    if name == "plant-fmi3":
        return _levitating(maglev_cosim.fmu_path(fmi_version=3), 3)
    if name == "rig-inteco-mls2em":
        from maglev_cosim.cli import main

        out = tmp / "inteco.fmu"
        assert main(["fmu", "--rig", "inteco-mls2em", "--out", str(out)]) == 0
        return _levitating(out, 2)
    if name == "calibrated":
        from maglev_cosim.plant.calibrated_fmu import calibrated_fmu

        # what write_calibrated_fmu (the diagnosis) writes, without a diagnosis to run: calibrated
        # start values, its own GUID, model name and description, calibration.json, the report as documentation
        out = tmp / "maglev_calibrated.fmu"
        calibrated_fmu(maglev_cosim.fmu_path(), out, {"T_d": 0.003, "k_c": 7.1e-6, "x_0": 0.0081, "T_a": 4e-4},
                       model_name="CE152 magnetic levitation, calibrated on rec.csv",
                       description="calibrated on rec.csv", resources={"calibration.json": b"{}\n"},
                       documentation={"index.html": b"<html><body>report</body></html>\n", "report.md": b"# report\n"},
                       source_sha256="ab" * 32)
        return _levitating(out, 2)
    if name in ("pid", "pid-fmi3"):
        # the measured input y wandering about the reference (0.4 MU, 0.45 from 50 ms on, plus w_in:
        # 0, then 0.02 from 120 ms on), piecewise constant; the output stays within its limits [0, 1]
        t = np.arange(N) * H
        y = 0.42 + 0.02 * np.sin(2 * np.pi * 7 * t) + 0.002 * np.sign(np.sin(2 * np.pi * 23 * t))
        w_in = np.where(t >= 0.12, 0.02, 0.0)
        version = 3 if name == "pid-fmi3" else 2
        return Kind(pid_fmu_path(version), version, {"y": y, "w_in": w_in},
                    {"w0": 0.4, "w1": 0.45, "t_step": 0.05, "u_hold": 0.37})
    raise ValueError(name)


KINDS = ["plant-fmi2", "plant-fmi3", "pid", "pid-fmi3", "rig-inteco-mls2em", "calibrated"]
FMI2_KINDS = [k for k in KINDS if k not in ("plant-fmi3", "pid-fmi3")]


@pytest.fixture(scope="module")
def kinds(tools, tmp_path_factory) -> dict[str, Kind]:   # tools: no FMUs to make when they skip
    tmp = tmp_path_factory.mktemp("fmus")
    return {k: _make(k, tmp) for k in KINDS}


def _input_csv(kind: Kind, path: Path) -> Path:
    """The input as both importers read it: two rows per step, (k*H, u_k) and ((k+1)*H, u_k), so that
    the linear interpolation of fmusim (and fmpy, and fmuCheck) gives u_k over the whole step and the
    repeated times mark the steps as discontinuities, where both apply the value after the step."""
    rows = [",".join(f'"{n}"' for n in ["time", *kind.inputs])]
    for k in range(N):
        values = ",".join(repr(float(v[k])) for v in kind.inputs.values())
        rows += [f"{k * H!r},{values}", f"{(k + 1) * H!r},{values}"]
    path.write_text("\n".join(rows) + "\n")
    return path


def _signal(kind: Kind) -> np.ndarray:
    """The same input as fmpy's structured array."""
    sig = np.zeros(2 * N, dtype=[("time", float)] + [(n, float) for n in kind.inputs])
    sig["time"] = np.column_stack([np.arange(N), np.arange(1, N + 1)]).ravel() * H
    for n, v in kind.inputs.items():
        sig[n] = np.repeat(v, 2)
    return sig


def _read_csv(path: Path) -> np.ndarray:
    return np.genfromtxt(path, delimiter=",", names=True, deletechars="")


def _fmpy(kind: Kind, start: dict[str, float] | None = None) -> np.ndarray:
    return simulate_fmu(str(kind.fmu), start_values=kind.start if start is None else start, input=_signal(kind),
                        stop_time=N * H, output_interval=H)


def _max_diffs(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """max |a - b| of every column of ``b`` (fmpy's result: time and the outputs)."""
    assert len(a) == len(b), (len(a), len(b))
    missing = [n for n in b.dtype.names if n not in a.dtype.names]
    assert not missing, f"columns {missing} missing from {a.dtype.names}"
    return {n: float(np.max(np.abs(a[n] - b[n]))) for n in b.dtype.names}


# --- fmuCheck -------------------------------------------------------------------------------------

_SUMMARY = re.compile(r"FMU check summary:\s*FMU reported:\s*(\d+) warning\(s\) and error\(s\)\s*"
                      r"Checker reported:\s*(\d+) Warning\(s\)\s*(\d+) Error\(s\)\s*\Z")


@dataclass
class CheckReport:
    returncode: int
    fmu_reported: int           # warnings and errors the FMU logged
    warnings: int               # the checker's
    errors: int
    problems: list[str]         # the log's [WARNING], [ERROR] and [FATAL] lines, and the FMU's messages ([FMU])
    output: Path


def fmu_check(tools: Path, fmu: Path, tmp: Path, input_csv: Path | None = None) -> CheckReport:
    """``fmuCheck`` on ``fmu``: the XML checks and a co-simulation run at step H (over N steps, with
    ``input_csv`` when given), every step written; the counts from its summary's last lines. It exits
    0 whatever it found: only the summary tells."""
    out = tmp / f"{fmu.stem}.fmucheck.csv"
    unpack = tmp / "fmucheck_unpack"
    unpack.mkdir(exist_ok=True)
    cmd = [str(tools / FMUCHECK), "-h", repr(H), "-s", repr(N * H), "-n", "0", "-t", str(unpack), "-o", str(out)]
    r = subprocess.run(cmd + (["-i", str(input_csv)] if input_csv else []) + [str(fmu)],
                       capture_output=True, text=True, timeout=60)
    m = _SUMMARY.search(r.stderr) or _SUMMARY.search(r.stdout)      # its last lines (stderr, the log's stream)
    assert m, f"no summary in fmuCheck's output ({' '.join(cmd)}):\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
    problems = [line.strip() for line in (r.stdout + r.stderr).splitlines()
                if re.match(r"\s*\[(WARNING|ERROR|FATAL|FMU)\]", line)]
    return CheckReport(r.returncode, *map(int, m.groups()), problems, out)


@pytest.mark.parametrize("name", FMI2_KINDS)
def test_fmucheck_validates_the_fmu_and_its_run_agrees_with_fmpy(name, tools, kinds, tmp_path):
    kind = kinds[name]
    rep = fmu_check(tools, kind.fmu, tmp_path, _input_csv(kind, tmp_path / "in.csv"))
    assert rep.returncode == 0 and rep.errors == 0, (
        f"fmuCheck on {kind.fmu}: exit {rep.returncode}, {rep.errors} error(s), {rep.warnings} warning(s), "
        f"{rep.fmu_reported} reported by the FMU:\n" + "\n".join(rep.problems))
    fmu_errors = [p for p in rep.problems if re.search(r"FMU status:(Error|Fatal)", p)]
    assert not fmu_errors, f"fmuCheck on {kind.fmu}: the FMU logged errors:\n" + "\n".join(fmu_errors)
    if rep.warnings or rep.fmu_reported:
        warnings.warn(f"fmuCheck on {kind.fmu.name}: {rep.warnings} warning(s), {rep.fmu_reported} from the FMU: "
                      + "; ".join(rep.problems))
    # fmuCheck sets no start values: its run is from the FMU's own ones, and so is fmpy's here
    diffs = _max_diffs(_read_csv(rep.output), _fmpy(kind, start={}))
    assert max(diffs.values()) <= TOL, diffs


def test_fmucheck_summary_counts_an_error(tools, tmp_path):
    """The summary parser is not blind: an output declared initial="exact" without a start value
    (FMI 2.0 needs one) is an error fmuCheck counts, though it still exits 0."""
    fmu = maglev_cosim.fmu_path()
    broken = tmp_path / "broken.fmu"
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(broken, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'causality="output" variability="continuous" initial="calculated"',
                                    b'causality="output" variability="continuous" initial="exact"', 1)   # y
            zout.writestr(item, data)
    rep = fmu_check(tools, broken, tmp_path)
    assert rep.errors >= 1 and any("Start attribute is required" in p for p in rep.problems), rep


# --- fmusim ---------------------------------------------------------------------------------------

def _fmusim(tools: Path, kind: Kind, tmp: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [str(tools / FMUSIM), "--interface-type", "cs", *args]
    for name, value in kind.start.items():
        cmd += ["--start-value", name, repr(float(value))]
    return subprocess.run(cmd + [str(kind.fmu)], capture_output=True, text=True, timeout=60, cwd=tmp)


@pytest.mark.parametrize("name", KINDS)
def test_fmusim_runs_the_default_experiment_with_every_call_ok(name, tools, kinds, tmp_path):
    """fmusim (which also checks modelDescription.xml against the FMI schema) over the FMU's default
    experiment from the FMU's own start values, the FMI calls logged: each returns OK."""
    kind = kinds[name]
    calls, out = tmp_path / "calls.txt", tmp_path / "out.csv"
    cmd = [str(tools / FMUSIM), "--interface-type", "cs", "--log-fmi-calls", "--fmi-log-file", str(calls),
           "--output-file", str(out), str(kind.fmu)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    # the FMU's log messages go to stdout, fmusim's own to stderr: neither has any
    assert r.returncode == 0 and not (r.stdout + r.stderr).strip(), \
        f"{' '.join(cmd)}: exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    log = calls.read_text().splitlines()
    not_ok = [line for line in log if not line.endswith("-> OK")]
    assert len(log) > 3 * 1000 and not not_ok, not_ok[:10]
    do_step = "fmi3DoStep" if kind.fmi_version == 3 else "fmi2DoStep"
    assert sum(line.startswith(do_step) for line in log) == 3000        # 3 s at 1 ms
    assert len(_read_csv(out)) == 3001


@pytest.mark.parametrize("name", KINDS)
def test_fmusim_and_fmpy_agree_on_an_input_driven_run(name, tools, kinds, tmp_path):
    """The same input, start values and step through fmusim (--output-interval = the communication
    step) and fmpy.simulate_fmu: every output within 1e-9 at every communication point."""
    kind = kinds[name]
    out = tmp_path / "fmusim.csv"
    r = _fmusim(tools, kind, tmp_path, "--stop-time", repr(N * H), "--output-interval", repr(H),
                "--input-file", str(_input_csv(kind, tmp_path / "in.csv")), "--output-file", str(out))
    assert r.returncode == 0 and not (r.stdout + r.stderr).strip(), \
        f"fmusim: exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    a, b = _read_csv(out), _fmpy(kind)
    diffs = _max_diffs(a, b)
    assert max(diffs.values()) <= TOL, diffs
    if "u" in kind.inputs:      # the plant: the ball held at rest until the doublet, then moving
        x0 = kind.start["x_start"]
        assert np.max(np.abs(b["x"][:N // 4] - x0)) < 1e-9 and np.max(np.abs(b["x"] - x0)) > 1e-5, b["x"]
    else:                       # the controller: the reference steps, the output moves within its limits
        assert b["w"][0] == 0.4 and b["w"][-1] == pytest.approx(0.47), b["w"]
        assert 0 < b["u"][1:].min() and b["u"].max() < 1 and np.ptp(b["u"][N // 2:]) > 0.01, b["u"]
