"""diagnosis/neldermead.py: the Nelder-Mead that evaluates the points it may need side by side walks
scipy's path to the bit (the same result, the same count of evaluations), whatever map runs them."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from scipy.optimize import minimize

from maglev_cosim.diagnosis.neldermead import nelder_mead


def rosen(z):
    return float(np.sum(100.0 * (z[1:] - z[:-1] ** 2) ** 2 + (1 - z[:-1]) ** 2))


def plateau(z):
    # a refused region (a huge finite cost, as real_rig.REFUSED_COST) and a flat floor: shrinks and ties
    if z[0] < -0.5:
        return 1e30
    return float(max(np.sum((z - 0.3) ** 2), 1e-3))


def bowl(z):
    return float(np.sum(np.arange(1, len(z) + 1) * (z - 0.2) ** 2) + 0.1 * np.sin(5 * z[0]))


@pytest.mark.parametrize("fun", [rosen, plateau, bowl])
@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("maxfev", [1, 3, 5, 13, 30])
def test_same_path_as_scipy(fun, dim, maxfev):
    rng = np.random.default_rng(dim * 100 + maxfev)
    for _ in range(3):
        z0 = rng.uniform(-1, 1, dim)
        simplex = [z0] + [z0 + 0.05 * np.eye(dim)[k] for k in range(dim)]
        ref = minimize(fun, z0, method="Nelder-Mead",
                       options={"maxfev": maxfev, "xatol": 1e-3, "fatol": 1e-4, "initial_simplex": simplex})
        with ThreadPoolExecutor(2) as ex:
            got = nelder_mead(fun, simplex, maxfev=maxfev, xatol=1e-3, fatol=1e-4,
                              map_fn=lambda f, xs: list(ex.map(f, xs)))
        assert np.array_equal(got.x, ref.x), (got.x, ref.x)
        assert got.fun == ref.fun
        assert got.nfev == ref.nfev
        assert got.evaluated >= got.nfev
        serial = nelder_mead(fun, simplex, maxfev=maxfev, xatol=1e-3, fatol=1e-4)
        assert np.array_equal(serial.x, ref.x) and serial.fun == ref.fun


def test_guesses_save_rounds():
    # on a smooth 2-D fit most steps need a second point; the guessed one is often right, so the
    # rounds of evaluation (what the wall time follows) are fewer than the evaluations counted
    rounds = []

    def counting_map(f, xs):
        rounds.append(len(xs))
        return [f(x) for x in xs]

    z0 = np.array([-0.8, 0.9])
    got = nelder_mead(rosen, [z0, z0 + [0.05, 0], z0 + [0, 0.05]], maxfev=60, map_fn=counting_map)
    assert got.nfev == 60
    assert len(rounds) < got.nfev
