"""The plant's formulas (equilibrium, sensor and its inverse, force slopes) live once, in C; here
they are checked against the independent pure-Python reference plant (plant/reference.py)."""

from __future__ import annotations

import numpy as np
import pytest

from maglev_cosim.plant import formulas
from maglev_cosim.plant.params import get_params
from maglev_cosim.plant.reference import ReferencePlant


@pytest.mark.parametrize("k_x2", [0.0, 3e4, -5e4])
def test_reading_and_its_inverse_agree_with_the_reference(k_x2):
    p = get_params("section3").replace(k_x2=k_x2)
    xs = np.linspace(0.2e-3, 6.1e-3, 12)
    ref = []
    for x in xs:
        plant = ReferencePlant(p.replace(x_start=float(x)))
        ref.append(plant.outputs()["y"])
    ys = np.array([formulas.point(p, x).y for x in xs])
    assert np.max(np.abs(ys - ref)) <= 1e-15
    back = formulas.positions(p, ys)
    # the old inverse in diagnosis/identify.py ignored k_x2: off by k_x2*x*(x - x_cal)/k_x, up to 0.12 mm here
    assert np.max(np.abs(back - xs)) <= 1e-12


def test_readings_beyond_the_travel_give_the_nearest_stop():
    p = get_params("section3")
    lo, hi = formulas.point(p, p.x_min).y, formulas.point(p, p.x_max).y
    assert list(formulas.positions(p, [lo - 0.1, hi + 0.1])) == [p.x_min, p.x_max]


def test_equilibrium_holds_the_ball_in_the_reference_plant():
    """At the equilibrium current and input the reference plant's ball stays put (Eq. 8 at rest)."""
    p = get_params("eq18")
    pt = formulas.point(p, 0.0032)
    plant = ReferencePlant(p.replace(x_start=0.0032, i_start=pt.i))
    plant.reset(pt.u)
    assert plant.outputs()["F"] == pytest.approx(p.m_k * p.g, rel=1e-14)
    plant.step(0.05)
    assert abs(plant.outputs()["x"] - 0.0032) < 1e-9
    assert pt.i == pytest.approx(0.5573394407, rel=1e-9)   # Eq. 8 with the Section 3 k_c, x_0


def test_force_slopes_match_finite_differences_of_the_reference_force():
    p = get_params("section3")
    x, i = 0.0032, 0.6
    pt = formulas.point(p, x, i)
    force = ReferencePlant(p)._force
    h = 1e-7
    assert pt.F == pytest.approx(force(i, x), rel=1e-15)
    assert pt.dF_dx == pytest.approx((force(i, x + h) - force(i, x - h)) / (2 * h), rel=1e-7)
    assert pt.dF_di == pytest.approx((force(i + h, x) - force(i - h, x)) / (2 * h), rel=1e-7)


def test_formulas_refuse_bad_parameters_in_one_line():
    with pytest.raises(ValueError, match="variable k_c"):
        formulas.point({"k_c": -1.0}, 0.003)


def test_plant_params_match_the_c_table():
    """PlantParams is the typed face of the C variable table: same names, order and defaults."""
    from dataclasses import fields

    from maglev_cosim.plant.fast import param_table
    from maglev_cosim.plant.params import PlantParams

    table = param_table()
    assert [f.name for f in fields(PlantParams)] == list(table)
    assert PlantParams().to_start_values() == {n: row[0] for n, row in table.items()}
    for name, (default, lo, hi, unit) in table.items():
        assert lo <= default <= hi, name
        assert unit


def test_plant_params_validate_with_the_c_rules():
    from maglev_cosim.plant.params import PlantParams

    PlantParams().validate()
    with pytest.raises(ValueError, match=r"variable k_c: must be in \[0, 1\] N.m2/A2, got -1"):
        PlantParams(k_c=-1.0).validate()
    with pytest.raises(ValueError, match="variable x_max: must be below x_0"):
        PlantParams(x_max=9e-3).validate()
