"""Cross-implementation tests: the FMU in closed loop through fmpy against the independent
pure-Python reference, against the linear discrete loop, and against the cffi fast path."""

from __future__ import annotations

import control
import numpy as np
import pytest

from maglev_cosim.plant import fast
from maglev_cosim.loop import fast_loop
from maglev_cosim.loop.design import discrete_closed_loop
from maglev_cosim.plant.linear import operating_point
from maglev_cosim.loop.simulate import LoopResponse, reference_signal, simulate
from maglev_cosim.plant.params import PlantParams, get_params
from maglev_cosim.diagnosis.effects import CATALOGUE
from rig_physics import RIG_PHYSICS, open_loop_pair

X = 0.0032


def step_w(p, amplitude: float, duration: float = 2.0) -> np.ndarray:
    return reference_signal("step", duration, 1e-3, base=operating_point(p, X).y_MU, amplitude=amplitude, t_step=0.0)


@pytest.mark.parametrize("name", ["section3", "eq18"])
def test_fmu_and_pure_python_reference_agree(fmu_path, name):
    """0.05 MU step from 3.2 mm over 2 s. Measured: max |dy| 6.5e-9 MU, |du| 1.5e-8 MU (section3)."""
    p = get_params(name)
    w = step_w(p, 0.05)
    a = simulate(p, w, backend="fmu", fmu=fmu_path)
    b = simulate(p, w, backend="reference")
    assert np.max(np.abs(a["y"] - b["y"])) <= 1e-6
    assert np.max(np.abs(a["u"] - b["u"])) <= 1e-5
    assert a["y"].max() > operating_point(p, X).y_MU + 0.05   # it moved (overshoot), not two constants


def test_small_step_agrees_with_the_linear_discrete_loop(fmu_path):
    """0.002 MU step: nonlinear FMU loop versus the ZOH-discretised Eq. 19 loop with the PID.
    Measured: max deviation 1.4 % of the step size."""
    p = get_params("section3")
    amp = 0.002
    w = step_w(p, amp)
    res = simulate(p, w, backend="fmu", fmu=fmu_path)
    T = discrete_closed_loop(p, X)
    lin = control.forced_response(T, T=res.t, U=np.full(len(w), amp)).outputs
    dev = np.max(np.abs((res["y"] - res["y"][0]) - lin))
    assert dev <= 0.03 * amp, dev


def test_fast_path_matches_the_fmu_to_1e12(fmu_path):
    p = get_params("section3")
    w = step_w(p, 0.05)
    a = simulate(p, w, backend="fmu", fmu=fmu_path)
    b = simulate(p, w, backend="fast")
    assert np.max(np.abs(a["y"] - b["y"])) <= 1e-12
    assert np.max(np.abs(a["u"] - b["u"])) <= 1e-12
    assert np.max(np.abs(a["x"] - b["x"])) <= 1e-15
    # the low level takes a PlantParams as readily as a mapping
    op = operating_point(p, X)
    c = fast_loop.closed_loop(p.replace(x_start=X, i_start=op.i), w, u_hold=op.u_MU)
    assert np.array_equal(c["y"], b["y"])


def test_one_response_type_with_named_signals():
    p = get_params("section3")
    w = step_w(p, 0.05, duration=0.5)
    r = simulate(p, w)
    assert isinstance(r, LoopResponse) and isinstance(r, control.TimeResponseData)
    assert r.output_labels == ["y", "u"] and r.state_labels == ["x", "v", "i"] and r.input_labels == ["w"]
    assert np.array_equal(r.outputs[0], r["y"]) and np.array_equal(r.states[2], r["i"])
    assert np.array_equal(r["w"], w) and np.array_equal(r.inputs[0], w)
    assert np.array_equal(r.outputs["u"], r["u"]) and np.array_equal(r.states["x"], r["x"])  # python-control's names
    assert r["t"][1] == pytest.approx(1e-3) and len(r.time) == 500
    assert r["x"][0] == X and r["y"][-1] > r["y"][0] + 0.04      # settled at 3.2 mm, then followed the step
    t, y = r                                                      # python-control's legacy unpacking still works
    assert np.array_equal(y, r.outputs)
    with pytest.raises(KeyError, match="no signal 'q'"):
        r["q"]
    df = r.to_pandas() if _has_pandas() else None
    assert df is None or list(df.columns[:3]) == ["time", "w", "y"]
    with pytest.raises(ValueError, match="unknown backend"):
        simulate(p, w, backend="simulink")
    with pytest.raises(ValueError, match="outside the stops"):
        simulate(p, w, x_op=0.01)
    assert isinstance(PlantParams(), PlantParams)


def _has_pandas() -> bool:
    try:
        import pandas  # noqa: F401
    except ImportError:
        return False
    return True


def test_fast_open_loop_matches_the_fmu(fmu_path):
    from maglev_cosim.loop.fmu import FmuPlant

    p = get_params("section3").replace(T_d=1.5e-3, x_start=X, i_start=operating_point(get_params("section3"), X).i)
    u = operating_point(p, X).u_MU * (1 + 0.01 * np.sin(np.arange(300) * 0.05))
    b = fast.open_loop(p.to_start_values(), u)
    ys = []
    with FmuPlant({**p.to_start_values(), "u": u[0]}, fmu=fmu_path) as f:
        for k in range(len(u)):
            ys.append(f.outputs()[0])
            f.set_input(u[k])
            f.step(1e-3)
    assert np.max(np.abs(np.array(ys) - b["y"])) <= 1e-12


def test_fast_path_rejects_bad_parameters_and_data():
    w = np.full(100, 0.4)
    with pytest.raises(ValueError, match="m_k"):
        fast_loop.closed_loop({"m_k": -1.0, "x_start": X}, w, u_hold=0.37)
    with pytest.raises(ValueError, match="nonsense"):
        fast_loop.closed_loop({"nonsense": 1.0}, w)
    w[50] = np.nan
    with pytest.raises(ValueError, match=r"w\[50\]"):
        fast_loop.closed_loop({"x_start": X}, w, u_hold=0.37)


def test_closed_loop_result_writes_a_record(tmp_path, fmu_path):
    from maglev_cosim.records.record import read_record

    p = get_params("section3")
    res = simulate(p, reference_signal("square", 2.5, 1e-3, base=0.4, amplitude=0.03, period=1.0),
                   backend="fmu", fmu=fmu_path)
    rec = read_record(res.to_csv(tmp_path / "r.csv"))
    assert rec.n == 2500 and np.allclose(rec.y, res["y"], atol=1e-12)
    assert {"x", "v", "i"} <= set(rec.extra)


#: Effects at magnitudes that show the numerics' corners, then every other catalogue entry at its example
#: magnitude (diagnosis/effects.py): an effect added to the catalogue is checked here by itself.
_EFFECT_CASES = [
    {"T_a": 3e-3},
    {"T_a": 3e-4},                  # a transient RK4 sees only through transient_squares' weights
    {"T_a": 3e-4, "T_F": 1e-3},     # with a force lag: ETDRK4 on substeps refined over the transient
    {"T_F": 2e-3},
    {"T_d": 2.5e-3},
    {"k_x2": -3e4},
    {"i_max": 0.62},
    {"A_d": 0.01, "f_d": 37.0, "phi_d": 1.0},
    {"F_c": 2e-3},
    {"n_F": 3.0},
    {"n_F": 1.5, "x_n": 2.0e-3},
    {"u_dz": 1.2},
    {"T_y": 2e-3},
    {"T_y": 1e-3, "T_a": 1e-3, "T_d": 1e-3},
    {"beta_F": 0.6, "T_F2": 0.015, "T_F": 1e-3},    # the second force lag beside the first (ETDRK4's stages)
    {"beta_F": 0.5, "T_F2": 5e-3, "T_a": 3e-4},     # without the first: RK4 with transient_squares' weights
]
_EFFECT_CASES += [dict(e.example) for e in CATALOGUE.values()
                  if not set(e.params) & {p for case in _EFFECT_CASES for p in case}]


@pytest.mark.parametrize("effect", _EFFECT_CASES)
def test_each_effect_agrees_between_the_c_plant_and_the_reference(fmu_path, effect):
    """The catalogue's effects, written twice (C and Python), agree in closed loop: 1 s with a
    0.05 MU step. The baseline is Section 3 with T_a = 0 (Eq. 5), as in the diagnosis."""
    p = get_params("baseline").replace(**effect)
    w = step_w(p, 0.05, duration=1.0)
    a = simulate(p, w, backend="fmu", fmu=fmu_path)
    b = simulate(p, w, backend="reference")
    base = simulate("baseline", w, backend="fmu", fmu=fmu_path)
    assert np.max(np.abs(a["y"] - base["y"])) > 1e-4          # the effect acts
    # Friction's tanh(v/0.1 mm/s) turns sharply where the ball reverses: the C plant's RK4 steps
    # through it with 3.1e-6 MU of error (16 nm; a hundredth of the CE152's sensor noise) against the
    # adaptive DOP853 reference, at substeps of h*F_c/(m_k*v_c) <= 0.5 (1.2e-6 MU at 0.1, five times
    # the substeps).
    tol = 5e-6 if "F_c" in effect else 1e-6
    assert np.max(np.abs(a["y"] - b["y"])) <= tol
    assert np.max(np.abs(a["u"] - b["u"])) <= 10 * tol


@pytest.mark.parametrize("name", list(RIG_PHYSICS))
def test_rig_physics_agrees_between_the_c_plant_and_the_reference(name):
    """The voltage-driven coil and the other force laws, written twice (C and Python), agree in open
    loop: from rest at the equilibrium, a 2 % input wobble lifts or drops the ball within 0.3 s
    (the open-loop plant is unstable), so the comparison crosses free flight and a stop."""
    c, r = open_loop_pair(RIG_PHYSICS[name])
    assert np.ptp(c["x"]) > 2e-3                             # the ball travels
    assert np.max(np.abs(c["i"] - r["i"])) <= 1e-7           # [A]
    assert np.max(np.abs(c["x"] - r["x"])) <= 1e-8           # [m]


def test_a_short_force_lag_tends_to_none():
    """The force lag's ETDRK4 (c/maglev_plant.c) stays stable and accurate where plain RK4 needed
    substeps below T_F/2: in closed loop a lag of 1 us or 10 us departs from none in proportion
    to T_F, as a lag far below the loop's time scales does."""
    p = get_params("baseline")
    w = step_w(p, 0.05, duration=1.0)
    none = simulate(p, w)
    dev = {tf: float(np.max(np.abs(simulate(p.replace(T_F=tf), w)["y"] - none["y"]))) for tf in (1e-6, 1e-5)}
    assert 0 < dev[1e-6] < 2e-5
    assert 8 < dev[1e-5] / dev[1e-6] < 12


@pytest.mark.parametrize("T_F", [0.0, 1e-3])
def test_a_current_transient_far_below_a_substep_enters_as_an_impulse(T_F):
    """A current transient far shorter than the substep: without a force lag RK4's stage weights
    integrate it exactly (transient_squares), with one the C plant replaces it by the impulse it
    gives the lag once T_a is at most a 64th of the substep. T_a = 1.2 us at the default 0.1 ms
    substep and at 0.05 ms (with a force lag: an impulse, then resolved) agree in closed loop where
    the lag itself moves y by far more, and its effect grows in proportion to T_a."""
    p = get_params("baseline").replace(T_F=T_F)
    w = step_w(p, 0.05, duration=1.0)
    none = simulate(p, w)
    assert p.solver_step == 1e-4
    imp = simulate(p.replace(T_a=1.2e-6), w)
    res = simulate(p.replace(T_a=1.2e-6, solver_step=5e-5), w)
    dev = float(np.max(np.abs(imp["y"] - none["y"])))
    assert dev > 5e-6
    assert np.max(np.abs(imp["y"] - res["y"])) <= 5e-8         # measured 6.5e-9 MU (7.6e-9 with T_F)
    assert np.max(np.abs(imp["u"] - res["u"])) <= 2e-7
    dev_small = float(np.max(np.abs(simulate(p.replace(T_a=1.2e-7), w)["y"] - none["y"])))
    assert 8 < dev / dev_small < 12
