"""Cross-implementation tests: the FMU in closed loop through fmpy against the independent
pure-Python reference, against the linear discrete loop, and against the cffi fast path."""

from __future__ import annotations

import control
import numpy as np
import pytest

from maglev_cosim import fast
from maglev_cosim.analysis import discrete_closed_loop
from maglev_cosim.cosim import reference_signal, simulate_closed_loop
from maglev_cosim.linear import operating_point
from maglev_cosim.params import get_params
from maglev_cosim.reference import simulate_closed_loop_reference

X = 0.0032


def step_w(p, amplitude: float, n: int = 2000) -> np.ndarray:
    return reference_signal("step", n, 1e-3, base=operating_point(p, X).y_MU, amplitude=amplitude, t_step=0.0)


@pytest.mark.parametrize("name", ["section3", "eq18"])
def test_fmu_and_pure_python_reference_agree(fmu_path, name):
    """0.05 MU step from 3.2 mm over 2 s. Measured: max |dy| 6.5e-9 MU, |du| 1.5e-8 MU (section3)."""
    p = get_params(name)
    w = step_w(p, 0.05)
    a = simulate_closed_loop(w, params=p, fmu=fmu_path)
    b = simulate_closed_loop_reference(p, w)
    assert np.max(np.abs(a.y - b["y"])) <= 1e-6
    assert np.max(np.abs(a.u - b["u"])) <= 1e-5
    assert a.y.max() > operating_point(p, X).y_MU + 0.05   # it moved (overshoot), not two constants


def test_small_step_agrees_with_the_linear_discrete_loop(fmu_path):
    """0.002 MU step: nonlinear FMU loop versus the ZOH-discretised Eq. 19 loop with the PID.
    Measured: max deviation 1.4 % of the step size."""
    p = get_params("section3")
    amp = 0.002
    w = step_w(p, amp)
    res = simulate_closed_loop(w, params=p, fmu=fmu_path)
    T = discrete_closed_loop(p, X)
    lin = control.forced_response(T, T=res.t, U=np.full(len(w), amp)).outputs
    dev = np.max(np.abs((res.y - res.y[0]) - lin))
    assert dev <= 0.03 * amp, dev


def test_fast_path_matches_the_fmu_to_1e12(fmu_path):
    p = get_params("section3")
    op = operating_point(p, X)
    w = step_w(p, 0.05)
    a = simulate_closed_loop(w, params=p, fmu=fmu_path)
    b = fast.closed_loop(p.replace(x_start=X, i_start=op.i).to_start_values(), w, u_hold=op.u_MU)
    assert np.max(np.abs(a.y - b["y"])) <= 1e-12
    assert np.max(np.abs(a.u - b["u"])) <= 1e-12
    assert np.max(np.abs(a.x - b["x"])) <= 1e-15


def test_fast_open_loop_matches_the_fmu(fmu_path):
    from maglev_cosim.fmu import FmuPlant

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
        fast.closed_loop({"m_k": -1.0, "x_start": X}, w, u_hold=0.37)
    with pytest.raises(ValueError, match="nonsense"):
        fast.closed_loop({"nonsense": 1.0}, w)
    w[50] = np.nan
    with pytest.raises(ValueError, match=r"w\[50\]"):
        fast.closed_loop({"x_start": X}, w, u_hold=0.37)


def test_closed_loop_result_writes_a_record(tmp_path, fmu_path):
    from maglev_cosim.record import read_record

    p = get_params("section3")
    res = simulate_closed_loop(reference_signal("square", 2500, 1e-3, base=0.4, amplitude=0.03, period=1.0),
                               params=p, fmu=fmu_path)
    rec = read_record(res.to_csv(tmp_path / "r.csv"))
    assert rec.n == 2500 and np.allclose(rec.y, res.y, atol=1e-12)
    assert {"x", "v", "i"} <= set(rec.extra)


@pytest.mark.parametrize("effect", [
    {"T_a": 3e-3},
    {"T_F": 2e-3},
    {"T_d": 2.5e-3},
    {"k_x2": -3e4},
    {"i_max": 0.62},
    {"A_d": 0.01, "f_d": 37.0, "phi_d": 1.0},
])
def test_each_effect_agrees_between_the_c_plant_and_the_reference(fmu_path, effect):
    """The catalogue's effects, written twice (C and Python), agree in closed loop: 1 s with a
    0.05 MU step. The baseline is Section 3 with T_a = 0 (Eq. 5), as in the diagnosis."""
    p = get_params("baseline").replace(**effect)
    w = step_w(p, 0.05, n=1000)
    a = simulate_closed_loop(w, params=p, fmu=fmu_path)
    b = simulate_closed_loop_reference(p, w)
    base = simulate_closed_loop(w, params=get_params("baseline"), fmu=fmu_path)
    assert np.max(np.abs(a.y - base.y)) > 1e-4          # the effect acts
    assert np.max(np.abs(a.y - b["y"])) <= 1e-6
    assert np.max(np.abs(a.u - b["u"])) <= 1e-5
