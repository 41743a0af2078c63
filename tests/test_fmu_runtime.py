"""The FMU at run time through fmpy: experiments, sources, step-size independence, bad values,
several instances and saved state."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, simulate_fmu
from fmpy.fmi1 import FMICallException

import maglev_cosim
from conftest import fmi_functions, host_binary
from maglev_cosim._resources import pid_fmu_path
from maglev_cosim.loop.checks import comm_step_study, run_with_comm_step, staircase_input
from maglev_cosim.loop.fmu import FmuError, FmuPlant

X_OP = 0.0032


def equilibrium(x: float = X_OP) -> tuple[float, float]:
    """Eq. 8 at rest with the Section 3 values: current [A] and D/A input [MU] (Eq. 1, 5)."""
    i = (8.3e-3 - x) * np.sqrt(8.4e-3 * 9.81 / 6.9e-6)
    return i, i / (0.3 * 5.0)


def test_default_experiment_runs_in_fmpy(fmu_path):
    r = simulate_fmu(str(fmu_path))
    assert r["time"][0] == 0.0 and r["time"][-1] == pytest.approx(3.0)
    for name in ("y", "x", "v", "i"):
        assert np.all(np.isfinite(r[name]))
    # no input: the ball lies on the lower stop, the sensor reads its offset (Eq. 12, 13)
    assert np.all(r["x"] == 0.0)
    assert r["y"][-1] == pytest.approx(0.2 * 0.0125)


def test_input_table_at_1ms_lifts_and_drops_the_ball(fmu_path):
    t = np.arange(0, 1.0, 1e-3)
    u = np.where(t < 0.5, 1.0, 0.0)
    sig = np.array(list(zip(t, u)), dtype=[("time", float), ("u", float)])
    r = simulate_fmu(str(fmu_path), input=sig, stop_time=1.0, output_interval=1e-3, output=["x", "v", "i", "y"])
    x = r["x"]
    assert x[r["time"] <= 0.49].max() == pytest.approx(6.3e-3)     # reached the upper stop
    assert x[-1] == 0.0 and r["v"][-1] == 0.0                       # fell back and rests
    assert r["i"][np.searchsorted(r["time"], 0.3)] == pytest.approx(1.5)  # i_max = k_i k_DA 1 MU
    assert np.all(np.abs(r["y"]) <= 1.0)


@pytest.mark.slow
def test_sources_in_the_archive_build_a_working_binary(fmu_path, tmp_path):
    from fmpy.build import build_platform_binary

    unzipdir = extract(str(fmu_path), unzipdir=str(tmp_path / "fmu"))
    shutil.rmtree(tmp_path / "fmu" / "binaries")
    (tmp_path / "build").mkdir()
    build_platform_binary(unzipdir, build_dir=tmp_path / "build", all_warnings=True)
    assert list((tmp_path / "fmu" / "binaries").glob("*/maglev.*"))
    start = {"x_start": X_OP, "i_start": equilibrium()[0], "u": equilibrium()[1] * 1.01}
    kw = dict(start_values=start, stop_time=0.2, output_interval=1e-3, output=["y", "x"])
    a = simulate_fmu(unzipdir, **kw)
    b = simulate_fmu(str(fmu_path), **kw)
    assert np.max(np.abs(a["y"] - b["y"])) <= 1e-12
    assert a["x"][-1] > X_OP + 1e-4   # it moved: the comparison is not of two constants


def test_results_do_not_depend_on_the_communication_step():
    """Communication steps 10 us ... 0.1 s agree with the 1 ms run to the solver's accuracy.
    Measured: max |dy| 6.0e-9 MU (default parameters), 2.2e-8 MU with T_a = 3 ms, T_F = 1 ms,
    T_d = 2.5 ms (`maglev-cosim bench` prints the table)."""
    u = staircase_input()
    x = run_with_comm_step({}, u, 1e-3)[:, 1]
    flying = np.mean((x > 0) & (x < 6.3e-3))
    assert flying > 0.1, "the experiment must keep the ball in free flight part of the time"
    for extra in ({}, {"T_a": 3e-3, "T_F": 1e-3, "T_d": 2.5e-3}):
        for h, d in comm_step_study(extra, u).items():
            assert d["max_dy"] <= 1e-7, (extra, h, d)


def test_bad_values_are_rejected_with_the_variable_named(fmu_path):
    messages: list[str] = []
    with FmuPlant(fmu=fmu_path, logger=lambda status, msg: messages.append(msg)) as plant:
        with pytest.raises(FmuError, match="variable u"):
            plant.set_input(float("nan"))
        assert "variable u" in messages[-1]   # the user's logger still sees every message
        with pytest.raises(FmuError, match="m_k"):
            plant.set({"m_k": 1e-3})          # fixed parameter after initialisation
        with pytest.raises(FmuError, match="communicationStepSize"):
            plant.step(0.0)
        plant.step(1e-3)
        assert all(np.isfinite(plant.outputs()))
    for name, value in (("k_i", 0.0), ("T_a", -1.0), ("x_max", 9e-3), ("k_c", float("inf"))):
        with pytest.raises(FmuError, match=f"FMU initialisation failed: .*variable {name}"):
            FmuPlant({name: value}, fmu=fmu_path)


def test_two_instances_in_one_process_are_independent(fmu_path):
    i_eq, u_eq = equilibrium()
    start = {"x_start": X_OP, "i_start": i_eq, "u": u_eq}
    with FmuPlant(start, fmu=fmu_path) as a, FmuPlant(start, fmu=fmu_path) as b:
        a.set_input(u_eq * 1.02)
        b.set_input(u_eq * 0.98)
        ya, yb = [], []
        for _ in range(100):
            a.step(1e-3)
            b.step(1e-3)
            ya.append(a.outputs())
            yb.append(b.outputs())
    with FmuPlant(start, fmu=fmu_path) as c:
        c.set_input(u_eq * 1.02)
        yc = []
        for _ in range(100):
            c.step(1e-3)
            yc.append(c.outputs())
    assert ya == yc
    assert ya[-1][1] > X_OP > yb[-1][1]


def test_serialized_state_round_trips_and_rejects_corruption(fmu_path):
    i_eq, u_eq = equilibrium()
    with FmuPlant({"x_start": X_OP, "i_start": i_eq, "u": u_eq, "T_d": 1.5e-3}, fmu=fmu_path) as p:
        for k in range(20):
            p.set_input(u_eq * (1 + 0.01 * np.sin(k)))
            p.step(1e-3)
        fmu = p._fmu
        state = fmu.getFMUstate()
        blob = bytes(fmu.serializeFMUstate(state))
        t0 = p.time

        def run() -> list[tuple[float, ...]]:
            out = []
            for k in range(30):
                p.set_input(u_eq * (1 + 0.01 * np.cos(k)))
                p.step(1e-3)
                out.append(p.outputs())
            return out

        first = run()
        restored = fmu.deSerializeFMUstate(blob)
        p.set_state(restored, t0)
        assert run() == first
        bad = bytearray(blob)
        bad[len(bad) // 2] ^= 0xFF
        with pytest.raises(FMICallException):
            fmu.deSerializeFMUstate(bytes(bad))
        with pytest.raises(FMICallException):
            fmu.deSerializeFMUstate(blob[:-5])
        fmu.freeFMUstate(state)
        fmu.freeFMUstate(restored)


@pytest.mark.skipif(not sys.platform.startswith("linux") or shutil.which("nm") is None, reason="ELF dynamic symbols: Linux with nm")
@pytest.mark.parametrize("fmu, identifier, prefix, table", [
    (lambda: maglev_cosim.fmu_path(), "maglev", "fmi2", "maglev_variables"),
    (lambda: maglev_cosim.fmu_path(fmi_version=3), "maglev", "fmi3", "maglev_variables"),
    (lambda: pid_fmu_path(), "maglev_pid", "fmi2", "maglev_pid_variables"),
    (lambda: pid_fmu_path(fmi_version=3), "maglev_pid", "fmi3", "maglev_pid_variables")],
    ids=["plant", "plant3", "pid", "pid3"])
def test_the_shared_library_exports_exactly_the_fmi_functions(fmu, identifier, prefix, table, tmp_path):
    """Like the Windows DLL's export table (test_win64.py): the plant's own functions (maglev_step, ...) are
    hidden, so that an importer that loads two FMUs, or a library of its own, with global symbols cannot
    bind one's calls to the other's copy (whose plant may be another version). Beside the FMI functions
    only the FMU's variable table is exported: the build writes modelDescription.xml from it, and
    test_model_description.py reads it from the shipped binary."""
    with zipfile.ZipFile(fmu()) as z:
        so = Path(z.extract(host_binary(z, identifier), tmp_path))
    out = subprocess.run(["nm", "-D", "--defined-only", str(so)], capture_output=True, text=True, check=True).stdout
    exported = {ln.split()[-1] for ln in out.splitlines() if ln.strip()}
    want = fmi_functions(prefix) | {table}
    assert exported == want, f"{so.name}: missing {sorted(want - exported)}, extra {sorted(exported - want)}"
