"""diagnosis/jacobian.py: the difference Jacobian the fits use (scipy's steps, columns side by side) and
Broyden's update between its refreshes."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative

from maglev_cosim.diagnosis.jacobian import difference_jacobian, gauss_newton_gain, steps

T = np.linspace(0.0, 1.0, 60)
LO = np.array([0.0, 0.0, -1.0, -2.0])
HI = np.array([3.0, 5.0, 1.0, 2.0])


def _model(z: np.ndarray) -> np.ndarray:
    return z[0] * np.exp(-z[1] * T) + z[2] * np.sin(3 * T + z[3])


Y = _model(np.array([1.0, 2.0, 0.5, 0.3])) + 0.01 * np.random.default_rng(0).standard_normal(len(T))


def _resid(z: np.ndarray) -> np.ndarray:
    return _model(z) - Y


@pytest.mark.parametrize("z", [[0.5, 1.0, 0.1, 0.0],            # interior, a coordinate at 0
                               [3.0 - 1e-9, 5.0, -0.5, 1.9],    # on and next to upper bounds: the step turns
                               [0.0, 4.99, 0.0, -2.0],          # on lower bounds
                               [1e-300, 1e-12, 0.7, 0.0]])      # steps that vanish in z + h: scipy's fallback
@pytest.mark.parametrize("rel_step", [1e-6, 1e-3])
def test_differences_are_scipys_2point_jacobian(z, rel_step):
    z = np.array(z, float)
    want = approx_derivative(_resid, z, method="2-point", rel_step=rel_step, f0=_resid(z), bounds=(LO, HI))
    fun, jac = difference_jacobian(_resid, LO, HI, rel_step)
    assert np.array_equal(jac(z), want)
    assert np.array_equal(jac.differences(z), want)
    h = steps(z, LO, HI, rel_step)
    assert np.all((z + h >= LO) & (z + h <= HI)) and np.all(h != 0)


def test_unit_floor_steps_move_a_coordinate_near_zero_by_the_relative_step():
    z = np.array([0.0, 1e-9, 2.0, -0.5])
    h = steps(z, LO, HI, 1e-3, unit_floor=True)
    assert np.allclose(np.abs(h), [1e-3, 1e-3, 2e-3, 1e-3])
    assert h[0] > 0 and h[3] < 0    # the sign of z, + at 0, and inside the bounds


def test_columns_side_by_side_are_the_columns_one_by_one():
    z = np.array([0.5, 1.0, 0.1, 0.0])
    with ThreadPoolExecutor(2) as ex:
        _, jac2 = difference_jacobian(_resid, LO, HI, 1e-6, map_fn=lambda f, xs: list(ex.map(f, xs)))
        _, jac1 = difference_jacobian(_resid, LO, HI, 1e-6)
        assert np.array_equal(jac2(z), jac1(z))


def test_broydens_update_meets_the_secant_condition_and_keeps_a_linear_maps_jacobian():
    A = np.random.default_rng(1).standard_normal((7, 3))
    lo, hi = np.full(3, -10.0), np.full(3, 10.0)
    fun, jac = difference_jacobian(lambda z: A @ z + 1.0, lo, hi, 1e-6, refresh=5, scale=np.array([1.0, 10.0, 0.1]))
    z0, z1 = np.array([0.1, 0.2, 0.3]), np.array([0.4, -0.1, 0.35])
    fun(z0)
    J0 = jac(z0)                         # differences
    f1 = fun(z1)
    J1 = jac(z1)                         # Broyden: no replay
    assert np.allclose(J0, A, atol=1e-7) and np.allclose(J1, A, atol=1e-7)
    # on a nonlinear map the update maps the step onto the change of the residuals
    fun, jac = difference_jacobian(_resid, LO, HI, 1e-6, refresh=3)
    za, zb = np.array([0.5, 1.0, 0.1, 0.0]), np.array([0.6, 1.3, 0.05, 0.1])
    jac(za)
    fa = fun(za)
    fb = fun(zb)
    Jb = jac(zb)
    assert np.allclose(Jb @ (zb - za), fb - fa, rtol=1e-10, atol=1e-12)
    assert not np.allclose(Jb, jac.differences(zb), atol=1e-3)   # an update, not differences
    del f1


@pytest.mark.parametrize("z0", [[0.5, 1.0, 0.1, 0.0], [2.9, 0.1, -0.5, 1.9], [1e-9, 4.9, 0.0, 0.5]])
def test_least_squares_with_broyden_between_refreshes_reaches_scipys_optimum_with_fewer_replays(z0):
    z0 = np.array(z0, float)
    ref = least_squares(_resid, z0, bounds=(LO, HI), diff_step=1e-6, ftol=1e-10, xtol=1e-10, gtol=1e-12)
    calls = [0]

    def counted(z: np.ndarray) -> np.ndarray:
        calls[0] += 1
        return _resid(z)

    fun, jac = difference_jacobian(counted, LO, HI, 1e-6, refresh=3)
    got = least_squares(fun, z0, jac=jac, bounds=(LO, HI), ftol=1e-10, xtol=1e-10, gtol=1e-12)
    assert abs(got.cost - ref.cost) <= 1e-9 * ref.cost
    assert np.allclose(got.x, ref.x, atol=1e-5)
    assert calls[0] < ref.nfev + len(z0) * ref.njev


def test_gauss_newton_gain_is_the_linear_fits_fall_and_zero_at_its_optimum():
    A = np.random.default_rng(2).standard_normal((20, 3))
    b = np.random.default_rng(3).standard_normal(20)
    lo, hi = np.full(3, -100.0), np.full(3, 100.0)
    best = np.linalg.lstsq(A, b, rcond=None)[0]
    z = best + np.array([0.3, -0.2, 0.1])
    f = A @ z - b
    gain = gauss_newton_gain(A, f, z, lo, hi)
    assert np.isclose(gain, 0.5 * f @ f - 0.5 * np.sum((A @ best - b) ** 2), rtol=1e-10)
    assert abs(gauss_newton_gain(A, A @ best - b, best, lo, hi)) < 1e-12
    # a bound in the way: the coordinate stays, the others take their best with it held
    hi2 = np.array([z[0], 100.0, 100.0]) if best[0] > z[0] else hi
    lo2 = np.array([z[0], -100.0, -100.0]) if best[0] < z[0] else lo
    held = gauss_newton_gain(A, f, z, lo2, hi2)
    sub = np.linalg.lstsq(A[:, 1:], -f, rcond=None)[0]
    assert np.isclose(held, 0.5 * f @ f - 0.5 * np.sum((f + A[:, 1:] @ sub) ** 2), rtol=1e-10)
    assert 0 < held < gain


def test_parameter_columns_are_the_differences_per_unit_of_each_scale():
    from maglev_cosim.diagnosis.jacobian import parameter_columns

    def fun(v):
        return np.array([v["a"] ** 2, 3.0 * v["b"], v["a"] * v["b"]])

    values, scales = {"a": 2.0, "b": -1.0}, {"a": 0.5, "b": 4.0}
    got = parameter_columns(fun, values, scales, fun(values))
    exact = np.array([[2 * 2.0, 0.0], [0.0, 3.0], [-1.0, 2.0]]) * np.array([0.5, 4.0])
    assert got.shape == (3, 2)
    assert np.allclose(got, exact, rtol=1e-3, atol=1e-9)
