"""The independent pure-Python reference plant on cases with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from maglev_cosim.plant.linear import operating_point
from maglev_cosim.plant.params import get_params
from maglev_cosim.plant.reference import ReferencePlant


def test_equilibrium_stays_put():
    p = get_params("baseline")
    op = operating_point(p, 0.0032)
    plant = ReferencePlant(p.replace(x_start=0.0032, i_start=op.i))
    plant.reset(op.u_MU)
    for _ in range(100):
        plant.step(0.01)
    assert abs(plant.outputs()["x"] - 0.0032) < 1e-12


def test_free_fall_hits_the_lower_stop_at_the_analytic_time_and_rests():
    p = get_params("section3").replace(k_FV=0.0, x_start=0.005)
    plant = ReferencePlant(p)
    plant.reset(0.0)
    t_hit = math.sqrt(2 * 0.005 / p.g)      # no current, no damping: x = x0 - g t^2 / 2
    h = 1e-4
    xs = []
    for _ in range(int(0.05 / h)):
        plant.step(h)
        xs.append(plant.outputs()["x"])
    xs = np.array(xs)
    first = np.argmax(xs == 0.0)
    assert (first + 1) * h >= t_hit - 1e-12 and first * h < t_hit
    assert np.all(xs[first:] == 0.0)
    assert plant.outputs()["v"] == 0.0


def test_upper_stop_contact_and_release():
    p = get_params("section3")
    plant = ReferencePlant(p)
    plant.reset(1.0)
    for _ in range(300):
        plant.step(1e-3)
    o = plant.outputs()
    assert o["x"] == p.x_max and o["v"] == 0.0 and o["i"] == pytest.approx(1.5)
    plant.set_input(0.0)
    plant.step(1e-3)
    assert plant.outputs()["x"] < p.x_max      # released when the current fell below the weight's


def test_current_lag_is_the_exponential_of_eq2():
    p = get_params("section3").replace(T_a=3e-3)
    plant = ReferencePlant(p)
    plant.reset(0.0)
    plant.set_input(0.4)
    for k in range(1, 6):
        plant.step(1e-3)
        assert plant.outputs()["i"] == pytest.approx(0.6 * (1 - math.exp(-k * 1e-3 / 3e-3)), rel=1e-9)


def test_delay_shifts_the_response_exactly():
    p = get_params("section3").replace(T_a=3e-3)
    td = 2.5e-3                      # not a whole number of samples
    a = ReferencePlant(p)
    b = ReferencePlant(p.replace(T_d=td))
    a.reset(0.0)
    b.reset(0.0)
    ia, ib = [], []
    for plant, out in ((a, ia), (b, ib)):
        plant.set_input(0.4)
        for _ in range(40):
            plant.step(0.5e-3)
            out.append(plant.outputs()["i"])
    shift = int(round(td / 0.5e-3))
    assert np.allclose(ib[shift:], ia[:-shift], rtol=0, atol=1e-12)
    assert np.all(np.array(ib[: shift - 1]) == 0.0)


def test_release_from_a_stop_when_the_current_jumps():
    """With T_a = 0 (Eq. 5) the current, and so the net force, jumps when the input drops: the
    ball must leave the upper stop at once, as the C plant does."""
    p = get_params("baseline")
    plant = ReferencePlant(p)
    plant.reset(1.0)
    for _ in range(300):
        plant.step(1e-3)
    assert plant.outputs()["x"] == p.x_max
    plant.set_input(0.0)
    for _ in range(10):
        plant.step(1e-3)
    x = plant.outputs()["x"]
    assert x == pytest.approx(p.x_max - 0.5 * p.g * 0.01**2, rel=0.02)   # free fall, no current
