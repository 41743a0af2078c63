"""Hostile values through Python (issue 10): the FMU wrapper, the cffi fast path and the replay
refuse them with one line naming the variable: no NaN, no hang, no traceback from inside."""

from __future__ import annotations

import math

import numpy as np
import pytest

from maglev_cosim.plant import fast
from maglev_cosim.loop import fast_loop
from maglev_cosim.loop.fmu import FmuError, FmuPlant
from maglev_cosim.records.record import Record
from maglev_cosim.diagnosis.replay import baseline_params, replay

#: (variable, value): each one the fuzz campaign or a slip of units could produce.
HOSTILE = [
    ("k_c", math.nan), ("x_0", math.inf), ("m_k", -math.inf), ("k_c", 0.0), ("k_i", -0.3),
    ("solver_step", 1e-11), ("f_d", 1e308), ("v_start", 1e308), ("T_d", 5.0), ("T_F", 1e-9),
    ("x_start", 3.2), ("g", 0.0), ("i_max", 1e300),
]


def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and len(text) < 300, text
    return text


@pytest.mark.parametrize(("name", "value"), HOSTILE)
def test_fmu_plant_refuses(fmu_path, name, value):
    with pytest.raises(FmuError) as err:
        FmuPlant({name: value}, fmu=fmu_path)
    assert f"variable {name}" in one_line(err.value)


@pytest.mark.parametrize(("name", "value"), HOSTILE)
def test_fast_path_refuses(name, value):
    w = np.full(50, 0.4)
    with pytest.raises(ValueError) as err:
        fast_loop.closed_loop({name: value}, w)
    assert f"variable {name}" in one_line(err.value)
    with pytest.raises(ValueError) as err:
        fast.open_loop({name: value}, np.full(50, 0.3))
    assert f"variable {name}" in one_line(err.value)


def _record(n: int = 200) -> Record:
    t = np.arange(n) * 1e-3
    return Record(path="mem", t=t, w=np.full(n, 0.4), u=np.full(n, 0.37), y=np.full(n, 0.4), ts=1e-3,
                  kp=2.0, ki=2.97, kd=0.01, u_min=0.0, u_max=1.0, meta={})


@pytest.mark.parametrize(("name", "value"), HOSTILE)
def test_replay_refuses_before_any_arithmetic(name, value):
    with pytest.raises(ValueError) as err:
        replay(_record(), {**baseline_params(), name: value})
    assert f"variable {name}" in one_line(err.value)


def test_relations_are_checked_by_the_fast_path():
    with pytest.raises(ValueError, match="variable x_max: must be below x_0"):
        fast_loop.closed_loop({"x_max": 9e-3}, np.full(10, 0.4))


def test_fmu_refuses_a_step_beyond_its_budget_and_carries_on(fmu_path):
    """A levitating ball at solver_step = 1e-6 s stays off the stops for about a second: a 10 s step
    would need 1e7 RK4 steps. The FMU refuses it, keeps its state and time, and takes the next step."""
    x = 0.0032
    i = (8.3e-3 - x) * math.sqrt(8.4e-3 * 9.81 / 6.9e-6)
    with FmuPlant({"x_start": x, "i_start": i, "u": i / 1.5, "solver_step": 1e-6}, fmu=fmu_path) as p:
        before = p.outputs()
        with pytest.raises(FmuError, match="RK4 steps.*shorter communication steps") as err:
            p.step(10.0)
        one_line(err.value)
        assert p.outputs() == before and p.time == 0.0
        p.step(1e-3)
        assert all(math.isfinite(v) for v in p.outputs())
        with pytest.raises(FmuError, match="time range"):
            p.step(1e20)


def test_fmu_fast_forwards_a_ball_at_rest(fmu_path):
    with FmuPlant({"u": 0.0}, fmu=fmu_path) as p:
        p.step(1e6)
        y, x, v, i = p.outputs()
        assert (x, v, i) == (0.0, 0.0, 0.0) and p.time == 1e6


def test_fmu_outputs_in_initialization_mode_need_consistent_parameters(fmu_path):
    from fmpy.fmi1 import FMICallException

    with FmuPlant(fmu=fmu_path) as p:
        fmu = p._fmu
        fmu.reset()
        fmu.setReal([p.vr["x_start"]], [8.3e-3])
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            fmu.getReal([p.vr["F"]])
        assert "x_start" in p._last_error
