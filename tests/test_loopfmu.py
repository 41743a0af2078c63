"""The closed loop without Python: the controller FMU, maglev_loop.ssp and the container FMU made
by fmu-manipulation-toolbox, run by its own C runtime and compared with loop.simulate."""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from conftest import host_binary
from maglev_cosim._resources import pid_fmu_path
from maglev_cosim.loop.simulate import reference_signal, simulate
from maglev_cosim.loop.loop_fmu import STOP, loop_settings, write_container, write_ssp
from maglev_cosim.plant.model_description import PID_GUID, generate, pid_identity, read_pid_table
from maglev_cosim.loop.pid import PID


@pytest.fixture(scope="module", params=[2, 3], ids=["fmi2", "fmi3"])
def pid_binary(request, tmp_path_factory) -> tuple[int, Path]:
    """(FMI version, the controller FMU's binary for this platform, extracted)."""
    with zipfile.ZipFile(pid_fmu_path(request.param)) as z:
        return request.param, Path(z.extract(host_binary(z, "maglev_pid"), tmp_path_factory.mktemp("pid_binary")))


def test_pid_description_is_what_its_c_table_generates(repo, pid_binary):
    version, binary = pid_binary
    xml = {2: "modelDescription_pid.xml", 3: "modelDescription_pid3.xml"}[version]
    committed = (repo / xml).read_text()
    assert committed == generate(read_pid_table(binary), pid_identity(version), version), (
        f"{xml} differs from the C table: run python -m maglev_cosim.plant.model_description --pid --fmi {version} "
        f"{binary} {repo / xml}")
    for src in ("c/maglev_pid_fmu.c", "tests/c/test_pid_fmu.c"):
        m = re.search(r'#define (?:MAGLEV_PID_)?GUID "(\{[^"]+\})"', (repo / src).read_text())
        assert m and m.group(1) == PID_GUID, src


@pytest.mark.parametrize("version", [2, 3], ids=["fmi2", "fmi3"])
def test_pid_fmu_passes_fmpys_checks_and_equals_the_python_pid(tmp_path, version):
    """The C controller FMU (FMI 2.0 and 3.0: one glue, one model), stepped by fmpy, against the toolkit's
    Python PID (pid.DiscretePID), written apart from the C one: the same u[k] on a reading that drives u
    into both limits."""
    from fmpy.fmi3 import FMU3Slave

    fmu = pid_fmu_path(version)
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    cfg = PID(tf=0.002, anti_windup="conditional")
    settings = {"kp": cfg.kp, "ki": cfg.ki, "kd": cfg.kd, "tf": cfg.tf, "anti_windup": 1.0, "u_hold": 0.37,
                "w0": 0.40, "w1": 0.45, "t_step": 0.02}
    unzipped = extract(str(fmu), unzipdir=str(tmp_path / "pid"))
    if version == 2:
        slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="maglev_pid", instanceName="pid")
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.setReal([vr[k] for k in settings], list(settings.values()))
        slave.enterInitializationMode()
        set_real, get_real = slave.setReal, slave.getReal
    else:
        slave = FMU3Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="maglev_pid", instanceName="pid")
        slave.instantiate()
        slave.setFloat64([vr[k] for k in settings], list(settings.values()))
        slave.enterInitializationMode(startTime=0.0)
        set_real, get_real = slave.setFloat64, slave.getFloat64
    slave.exitInitializationMode()
    ref = cfg.start(u_hold=0.37)
    n = 200
    y = 0.42 + 0.4 * np.sin(np.arange(n) * 0.05)
    got, want = [], []
    for k in range(n):
        set_real([vr["y"]], [float(y[k])])
        slave.doStep(currentCommunicationPoint=k * cfg.ts, communicationStepSize=cfg.ts)
        got.append(get_real([vr["u"]])[0])
        w = 0.45 if k * cfg.ts >= 0.02 - 1e-12 else 0.40
        want.append(ref.step(w, float(y[k])))
    slave.terminate()
    slave.freeInstance()
    assert np.max(np.abs(np.array(got) - want)) <= 1e-12
    assert min(got) == 0.0 and max(got) == 1.0          # both limits reached: the clipping is compared too


def test_ssp_is_valid_ssp_1_0_with_the_loops_connections_and_settings(tmp_path, fmu_path):
    from fmpy.ssp.ssd import read_ssd

    ssp = write_ssp(tmp_path / "loop.ssp", fmu_path, pid_fmu_path())
    ssd = read_ssd(str(ssp))                           # validates against the SSP 1.0 schema
    comps = {e.name: e for e in ssd.system.elements}
    assert {n: c.source for n, c in comps.items()} == {"pid": "resources/maglev_pid.fmu",
                                                        "plant": "resources/maglev.fmu"}
    links = {(c.startElement, c.startConnector, c.endElement, c.endConnector) for c in ssd.system.connections}
    assert {("plant", "y", "pid", "y"), ("pid", "u", "plant", "u")} <= links
    want = loop_settings()
    for name, comp in comps.items():
        values = {p.name: float(p.value) for b in comp.parameterBindings for s in b.parameterValues
                  for p in s.parameters}
        assert values == want[name], name
    with zipfile.ZipFile(ssp) as z:
        assert z.read("resources/maglev.fmu") == Path(fmu_path).read_bytes()
        assert z.read("resources/maglev_pid.fmu") == pid_fmu_path().read_bytes()


@pytest.mark.slow
def test_container_fmu_levitates_as_the_python_loop_does(tmp_path, fmu_path):
    """The loop as one FMU built by fmu-manipulation-toolbox, run by its container runtime (the
    master: it steps the PID, then the plant, every ts) inside fmpy, against loop.simulate on the
    same settings: y and x agree to 1e-9 at every sample, and the ball follows the step."""
    pytest.importorskip("fmu_manipulation_toolbox", reason="fmu-manipulation-toolbox (the test extra) is not installed")
    from fmpy import simulate_fmu

    import logging

    records: list[logging.LogRecord] = []
    handler = logging.Handler(logging.WARNING)
    handler.emit = records.append
    toolbox_log = logging.getLogger("fmu_manipulation_toolbox")
    toolbox_log.addHandler(handler)
    try:
        fmu = write_container(tmp_path / "maglev_loop.fmu", fmu_path, pid_fmu_path())
    finally:
        toolbox_log.removeHandler(handler)
    # nothing dangling, and the feedback loop's expected initialisation warning filtered (docs/fmu.md)
    assert [r.getMessage() for r in records] == []
    s = loop_settings()
    ts = s["pid"]["ts"]
    r = simulate_fmu(str(fmu), stop_time=STOP, step_size=ts, output_interval=ts, output=["y", "x", "u", "w"])
    n = int(round(STOP / ts))
    w = reference_signal("step", STOP, ts, base=s["pid"]["w0"], amplitude=s["pid"]["w1"] - s["pid"]["w0"],
                         t_step=s["pid"]["t_step"])
    py = simulate("section3", w, backend="fmu", fmu=fmu_path)
    assert np.allclose(r["time"][:n], py["t"], rtol=0, atol=1e-12)
    dy = np.max(np.abs(r["y"][:n] - py["y"]))
    dx = np.max(np.abs(r["x"][:n] - py["x"]))
    # the container's u and w at t_k+1 are what the PID set at t_k (held over [t_k, t_k+1])
    du = np.max(np.abs(r["u"][1:n + 1] - py["u"]))
    dw = np.max(np.abs(r["w"][1:n + 1] - py["w"]))
    print(f"container vs loop.simulate: max|dy| {dy:.3g} MU, max|dx| {dx:.3g} m, max|du| {du:.3g} MU, "
          f"max|dw| {dw:.3g} MU over {n} samples")
    assert dy <= 1e-9 and dx <= 1e-12 and du <= 1e-9 and dw == 0.0
    # it levitates: off both stops, and the reading settles on the new reference
    assert np.all((r["x"] > 1e-4) & (r["x"] < 6.2e-3))
    assert abs(r["y"][-1] - s["pid"]["w1"]) < 0.01 and abs(r["y"][0] - s["pid"]["w0"]) < 1e-6
    fast = simulate("section3", w, backend="fast")
    assert np.max(np.abs(r["y"][:n] - fast["y"])) <= 1e-9


@pytest.mark.slow
def test_pid_fmu_sources_build_a_working_binary(tmp_path):
    """The controller FMU's sources/ (listed in <SourceFiles>) compile elsewhere: fmpy builds a
    binary from them that gives the same output as the shipped one."""
    import shutil

    from fmpy import simulate_fmu
    from fmpy.build import build_platform_binary

    unzipdir = extract(str(pid_fmu_path()), unzipdir=str(tmp_path / "fmu"))
    shutil.rmtree(tmp_path / "fmu" / "binaries")
    (tmp_path / "build").mkdir()
    build_platform_binary(unzipdir, build_dir=tmp_path / "build", all_warnings=True)
    kw = dict(start_values={"u_hold": 0.3, "w0": 0.4, "w1": 0.45, "t_step": 0.01}, stop_time=0.05,
              output_interval=1e-3, output=["u"], input=np.array([(0.0, 0.41)], dtype=[("time", float), ("y", float)]))
    a, b = simulate_fmu(unzipdir, **kw), simulate_fmu(str(pid_fmu_path()), **kw)
    assert np.array_equal(a["u"], b["u"]) and len(set(a["u"])) > 10


def test_container_links_or_exposes_every_port_of_both_fmus(fmu_path):
    """No port left dangling (fmu-manipulation-toolbox warns about each one when setup.sh builds the
    container): every input and output of the plant and the PID is linked, or is the container's."""
    from maglev_cosim.loop.loop_fmu import container_description

    desc = container_description(loop_settings())
    used = {(f, p) for f, p, _, _ in desc["link"]} | {(f, p) for _, _, f, p in desc["link"]}
    used |= {(f, p) for _, f, p in desc["input"]} | {(f, p) for f, p, _ in desc["output"]}
    for name, path in (("maglev.fmu", fmu_path), ("maglev_pid.fmu", pid_fmu_path())):
        ports = {v.name for v in read_model_description(str(path)).modelVariables
                 if v.causality in ("input", "output")}
        assert ports and {p for f, p in used if f == name} >= ports, name
    assert ["w_in", "maglev_pid.fmu", "w_in"] in desc["input"]
