"""The loop layer's controllers (maglev_cosim.loop.controllers, MaglevController in c/maglev_replay.h):
PID, cascade and state feedback with an observer, each in C and in Python (cross-checked), in
closed loop on every backend, the band anti-windup, controller files and their errors, the design
on the C plant's linearisation, and the declared controllers checked on the shared real records."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from maglev_cosim.loop import fast_loop
from maglev_cosim.loop.controllers import (Cascade, ControllerError, StateFeedback, design_state_feedback, discrete_plant,
                                      load_controller, start)
from maglev_cosim.loop.simulate import reference_signal, simulate
from maglev_cosim.plant import formulas
from maglev_cosim.plant.params import get_params
from maglev_cosim.loop.pid import PID
from maglev_cosim.rigs import load_rig

from real_data import REAL

X = 0.0032
LAGGED = get_params("section3").replace(T_a=2e-3)   # a current lag: the cascade's inner loop has work
CASCADE = Cascade(PID(kp=3.0, ki=4.5, kd=0.015, u_max=1.5, tf=2e-4, anti_windup="clamping"),
                  PID(kp=2.0, ki=400.0, kd=0.0, anti_windup="conditional"))


def _lqi(p=LAGGED):
    return design_state_feedback(p, X, 1e-3, q=(10 / 0.002**2, 0.0, 1 / 0.5**2), r=0.5, integral=1e4,
                                 rn=(1e-8, 1e-6))


@pytest.fixture(scope="module")
def lqi():
    return _lqi()


def test_python_and_c_controllers_agree_on_the_same_signals(lqi):
    """The controller alone, C against Python, on signals that saturate its output and its
    integrator: the one set of equations in both languages."""
    rng = np.random.default_rng(3)
    n = 3000
    w = 0.4 + 0.1 * (np.arange(n) > 500) - 0.2 * (np.arange(n) > 2000)
    y = 0.4 + np.cumsum(rng.normal(0, 0.004, n))
    i = 0.55 + np.cumsum(rng.normal(0, 0.01, n))
    band = PID(kp=2.0, ki=30.0, kd=0.01, tf=1e-3, anti_windup="band", i_lo=-0.5, i_hi=0.5, backoff=0.9)
    for ctl in (PID(anti_windup="conditional"), band, CASCADE, lqi):
        x0 = (X, 0.0, 0.55)
        c = fast_loop.control(ctl, w, y, i, 0.37, x0)
        run = start(ctl, 0.37, x0, w[0])
        py = np.array([run.step(w[k], y[k], i[k]) for k in range(n)])
        assert np.max(np.abs(c - py)) < 1e-12, type(ctl).__name__
        # settled at a reading away from the first reference, the error standing (y_before)
        c = fast_loop.control(ctl, w, y, i, 0.37, x0, y_before=0.39)
        run = start(ctl, 0.37, x0, w[0], 0.39)
        py = np.array([run.step(w[k], y[k], i[k]) for k in range(n)])
        assert np.max(np.abs(c - py)) < 1e-12, type(ctl).__name__
        assert np.any(c == ctl.u_max) or np.any(c == ctl.u_min)   # a limit was exercised


def test_band_anti_windup_integrates_only_inside_the_band():
    pid = PID(kp=0.0, ki=100.0, kd=0.0, u_min=-10, u_max=10, anti_windup="band", i_lo=-0.5, i_hi=0.5, backoff=0.9)
    u = fast_loop.pid_only(pid, np.ones(20), np.zeros(20), 0.0)
    # +0.1 per sample from 0 while the integral lies inside (-0.5, 0.5); at 0.5 it is pulled back
    # to 0.45 and integrates again
    assert np.allclose(u[:9], [0.1, 0.2, 0.3, 0.4, 0.5, 0.45, 0.55, 0.45, 0.55])
    with pytest.raises(ValueError, match="band"):
        PID(anti_windup="band", i_lo=0.5, i_hi=0.5)


@pytest.mark.parametrize("backend", ["reference", "fmu"])
def test_cascade_and_state_feedback_loops_agree_on_every_backend(backend, lqi):
    w = reference_signal("step", 0.6, base=0.394, amplitude=0.04, t_step=0.1)
    for ctl in (CASCADE, lqi):
        a = simulate(LAGGED, w, controller=ctl, backend="fast")
        b = simulate(LAGGED, w, controller=ctl, backend=backend)
        tol = 1e-12 if backend == "fmu" else 1e-7
        assert np.max(np.abs(a["y"] - b["y"])) < tol and np.max(np.abs(a["u"] - b["u"])) < 1e-6, type(ctl).__name__


def test_both_new_controllers_levitate_and_track_a_step(lqi):
    w = reference_signal("step", 1.5, base=0.394, amplitude=0.04, t_step=0.1)
    for ctl in (CASCADE, lqi):
        r = simulate(LAGGED, w, controller=ctl)
        assert abs(r["y"][-1] - w[-1]) < 2e-3, type(ctl).__name__
        assert np.all((r["x"] > LAGGED.x_min) & (r["x"] < LAGGED.x_max))   # never on a stop


def test_discrete_linearisation_matches_the_continuous_one():
    """The central differences of the C plant's one-sample map against the analytic linearisation
    of Eq. 14-17 (linear.linearize), discretised by python-control."""
    import control

    from maglev_cosim.plant.linear import linearize

    p = LAGGED
    d = discrete_plant(p, X, 1e-4)
    c = control.c2d(linearize(p, X), 1e-4, method="zoh")
    # the same state ordering (x, v, i) in both
    assert np.allclose(d.A, c.A, rtol=1e-4, atol=1e-6)
    assert np.allclose(d.B[:, 0], c.B[:, 0], rtol=1e-4, atol=1e-9)


def test_lqi_design_is_stable_and_integrates(lqi):
    assert lqi.k_int != 0 and lqi.k_w == 0
    assert max(abs(z) for z in lqi.design["closed_loop_poles"]) < 1
    lqr = design_state_feedback(LAGGED, X, 1e-3, q=(10 / 0.002**2, 0.0, 1.0), r=0.5)
    assert lqr.k_int == 0 and lqr.k_w != 0


# ---------------------------------------------------------------------------- controller files

def test_shipped_levitador_cascade_maps_the_record_units_onto_the_plant():
    cf = load_controller("levitador-cascade")
    rig = load_rig("levitador")
    c = cf.controller
    assert isinstance(c, Cascade) and cf.rig == "levitador" and c.ts == 0.01
    # position gains on the gap [A/m] -> on the reading [A/MU]: the gap falls as the reading rises
    assert np.isclose(c.outer.kp, -100.0 * -rig.position_scale)
    assert np.isclose(c.inner.kp, 12.0 / 9.86) and c.inner.u_max == 1.0   # volts -> MU
    assert c.outer.anti_windup == "band" and np.isclose(c.outer.i_hi, 0.827) and c.outer.backoff == 0.95


def test_shipped_inteco_lqi_levitates_the_inteco_model_through_a_step():
    rig = load_rig("inteco-mls2em")
    c = load_controller("inteco-lqi").controller
    assert isinstance(c, StateFeedback)
    n = 2000
    gap_ref = np.where(np.arange(n) * 1e-3 >= 0.5, 0.008, 0.010)
    r = simulate(rig.params, rig.reading(gap_ref), controller=c, x_op=float(rig.to_x(0.010)))
    gap = rig.from_x(r["x"])
    assert abs(gap[-1] - 0.008) < 2e-4 and np.all(gap < 0.0215)


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "ctl.toml"
    p.write_text(text)
    return p


BASE = """name = "t"
rig = "levitador"
type = "cascade"
sample_time = 0.01
[position]
kp = -100.0
limits = [0.0, 0.8]
[current]
kp = 12.0
limits = [0.0, 9.86]
"""


@pytest.mark.parametrize("edit, key, words", [
    (("type = \"cascade\"", "type = \"fuzzy\""), "type", "must be one of"),
    (("sample_time = 0.01", "sample_time = -0.01"), "sample_time", "non-physical"),
    (("limits = [0.0, 0.8]", "limits = [0.8, 0.0]"), "position.limits", "ascending"),
    (("kp = 12.0", "kp = 12.0\nkq = 1.0"), "current.kq", "unknown key"),
    (("rig = \"levitador\"", "rig = \"inteco-mls2em\""), "rig", "not 'levitador'"),
    (("kp = 12.0", "kp = \"twelve\""), "current.kp", "finite number"),
    (("kp = -100.0", "kp = -100.0\nderivative = \"setpoint\""), "position.derivative", "must be one of"),
])
def test_bad_controller_files_name_the_file_and_key(tmp_path, edit, key, words):
    p = _write(tmp_path, BASE.replace(*edit, 1) if edit[0] != "kp = 12.0" else BASE.replace(*edit))
    with pytest.raises(ControllerError) as e:
        load_controller(p, "levitador")
    assert str(p) in str(e.value) and f"'{key}'" in str(e.value) and words in str(e.value)


def test_a_pid_section_declares_the_derivative_of_the_reading(tmp_path):
    c = load_controller(_write(tmp_path, BASE.replace("kp = -100.0", 'kp = -100.0\nderivative = "measurement"')),
                        "levitador")
    assert c.controller.outer.derivative == "measurement" and c.controller.inner.derivative == "error"


def test_record_units_need_a_linear_position_reading(tmp_path):
    p = _write(tmp_path, BASE.replace('rig = "levitador"', 'rig = "ce152"'))
    with pytest.raises(ControllerError, match="signals"):
        load_controller(p)
    c = load_controller(_write(tmp_path, 'signals = "plant"\n' + BASE.replace('rig = "levitador"', 'rig = "ce152"')))
    assert c.controller.outer.kp == -100.0 and c.controller.inner.u_max == 9.86   # taken as they are


# ---------------------------------------------------------------------------- the shared real records

LEVITADOR = REAL / "levitador-benchmark" / "data" / "datos_levitador.txt"


@pytest.mark.skipif(not LEVITADOR.exists(), reason="shared real records not found")
@pytest.mark.slow
def test_levitador_cascade_reproduces_each_recorded_loop():
    """The declared cascade, each loop fed the recorded signals, against the record's current
    reference and voltage: what is left is the record's print precision (0.1 mm through the
    derivative, 1e-4 A and V)."""
    from maglev_cosim.records.measured import read_levitador
    from maglev_cosim.diagnosis.real_rig import controller_check

    rig = load_rig("levitador")
    res = controller_check(rig, read_levitador(LEVITADOR), load_controller("levitador-cascade").controller)
    loops = res.loops
    assert loops["position -> current reference"]["fit"] > 95 and loops["position -> current reference"]["rms_A"] < 0.01
    assert loops["current -> actuator"]["fit"] > 95 and loops["current -> actuator"]["rms_input_units"] < 0.1
    # wrong declarations fit worse: clamping instead of the firmware's band, the current gain halved
    c = load_controller("levitador-cascade").controller
    clamp = Cascade(c.outer.replace(anti_windup="clamping"), c.inner.replace(anti_windup="clamping"))
    half = Cascade(c.outer, c.inner.replace(kp=c.inner.kp / 2))
    m = read_levitador(LEVITADOR)
    assert controller_check(rig, m, clamp).loops["current -> actuator"]["fit"] < 90
    assert controller_check(rig, m, half).loops["current -> actuator"]["fit"] < loops["current -> actuator"]["fit"] - 2


@pytest.mark.skipif(not LEVITADOR.exists(), reason="shared real records not found")
def test_levitador_record_contradicts_its_rig_files_current_scale():
    """The shipped levitador rig (the benchmark's published model) carries under 20 % of the ball's
    weight at the recorded currents, and Ohm's law wants a larger current too: both say so."""
    from maglev_cosim.records.measured import read_levitador
    from maglev_cosim.diagnosis.real_rig import force_balance

    fb = force_balance(load_rig("levitador"), read_levitador(LEVITADOR))
    assert not fb.consistent and fb.median < 0.2 and fb.current_scale_for_weight > 2
    assert fb.ohm["median_V_over_Ri"] > 2
    good = force_balance(load_rig("inteco-mls2em"), _inteco("step", "LQI - KF.mat"))
    assert good.consistent and 0.8 < good.ohm["median_V_over_Ri"] < 1.25


def _inteco(profile, name):
    from maglev_cosim.records.measured import read_inteco_mat

    return read_inteco_mat(REAL / "inteco-mls2em" / "results" / profile / name)


@pytest.mark.parametrize("factor, words", [(20.0, "outside rig levitador's travel"), (1e-4, "m read as mm?")])
def test_a_record_whose_position_contradicts_the_rig_is_refused_naming_the_column(tmp_path, factor, words):
    from maglev_cosim.records.measured import Measured
    from maglev_cosim.records.record import RecordError
    from maglev_cosim.diagnosis.real_rig import prepare

    n = 500
    t = np.arange(n) * 0.01
    gap = 0.005 + 0.001 * np.sin(t)
    m = Measured(path=tmp_path / "r.txt", fmt="levitador", t=t, position=gap * factor, reference=np.full(n, 0.005),
                 current=np.full(n, 0.5), drive=np.full(n, 5.0), drive_unit="V")
    with pytest.raises(RecordError, match=words) as e:
        prepare(load_rig("levitador"), m)
    assert str(e.value).startswith(f"{tmp_path / 'r.txt'}:0:0: column 'position'")
    prepare(load_rig("levitador"), Measured(**{**m.__dict__, "position": gap}))   # the right units pass


CE152_CASCADE = """name = "ce152-cascade"
rig = "ce152"
type = "cascade"
sample_time = 0.001
signals = "plant"
[position]
kp = 3.0
ki = 4.5
kd = 0.015
tf = 2e-4
limits = [0.0, 1.5]
anti_windup = "clamping"
[current]
kp = 2.0
ki = 400.0
limits = [0.0, 1.0]
anti_windup = "conditional"
"""


def test_a_record_declares_its_controller_file_and_the_replay_runs_it(tmp_path):
    """A CE152 record whose metadata names a controller file (docs/record-format.md): the file is
    read relative to the record, its controller replays the record exactly, and its limits are
    the record's."""
    from maglev_cosim.records.record import read_record
    from maglev_cosim.diagnosis.replay import record_controller, replay

    (tmp_path / "ctl").mkdir()
    (tmp_path / "ctl" / "cascade.toml").write_text(CE152_CASCADE)
    ctl = load_controller(tmp_path / "ctl" / "cascade.toml", "ce152").controller
    assert ctl == CASCADE
    w = reference_signal("step", 1.0, base=0.394, amplitude=0.04, t_step=0.1)
    # settled at its first reference, as the replay of a record starts (replay.py)
    r = simulate(LAGGED, w, controller=ctl, x_op=formulas.position(LAGGED, 0.394))
    f = r.to_csv(tmp_path / "rec.csv", controller_file="ctl/cascade.toml")
    rec = read_record(f)
    assert record_controller(rec) == CASCADE and (rec.u_min, rec.u_max) == (0.0, 1.0)
    again = replay(rec, LAGGED.to_start_values())
    assert np.max(np.abs(again["y"] - r["y"])) < 1e-9


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace("ctl/cascade.toml", "ctl/missing.toml"), r"rec.csv:2:\d+: controller 'ctl/missing.toml': .*no such file"),
    (lambda t: t.replace("# ts: 0.001", "# ts: 0.001\n# kp: 2"), r"rec.csv:2:1: kp: the controller is declared by the file"),
    (lambda t: t.replace("# ts: 0.001", "# ts: 0.002"), r"rec.csv:1:\d+: ts 0.002 disagrees with the sample time 0.001"),
])
def test_a_declared_controller_file_that_does_not_fit_is_refused_where_the_record_says_it(tmp_path, edit, words):
    from maglev_cosim.records.record import RecordError, read_record

    (tmp_path / "ctl").mkdir()
    (tmp_path / "ctl" / "cascade.toml").write_text(CE152_CASCADE)
    w = reference_signal("step", 1.0, base=0.394, amplitude=0.04, t_step=0.1)
    f = simulate(LAGGED, w, controller=CASCADE).to_csv(tmp_path / "rec.csv", controller_file="ctl/cascade.toml")
    f.write_text(edit(f.read_text()))
    with pytest.raises(RecordError, match=words):
        read_record(f)


@pytest.mark.slow
def test_the_diagnosis_runs_a_record_with_a_declared_cascade_and_finds_its_lag(tmp_path):
    """A CE152 record of the cascade on a plant with a 2 ms amplifier lag (Eq. 2): every replay of
    the diagnosis runs the declared cascade, so the lag is found (measured: T_a = 2.000 ms)."""
    from maglev_cosim.diagnosis import pipeline
    from maglev_cosim.records.record import read_record

    (tmp_path / "ctl").mkdir()
    (tmp_path / "ctl" / "cascade.toml").write_text(CE152_CASCADE)
    w = reference_signal("square", 8.0, base=0.394, amplitude=0.03, period=2.0)
    f = simulate(LAGGED, w, controller=CASCADE).to_csv(tmp_path / "rec.csv", controller_file="ctl/cascade.toml")
    d = pipeline.run(read_record(f))
    assert "amplifier_lag" in d.selected
    assert d.parameters["T_a"] == pytest.approx(2e-3, rel=0.02)
