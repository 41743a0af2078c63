"""The coil of a voltage drive (issue 21, "current fit from PWM"): its resistance warming during the run,
R_c*(1 + kappa_R*t) (docs/model.md), C plant against the reference; its rate recovered from the
current computed from the PWM alone within ±2σ (real_rig.calibrate_coil, each segment's own coil); and
that current a free run of the coil model (the filter's ``coil_free``: the gap's innovations never
move it), whatever the disturbance model."""

from __future__ import annotations

import numpy as np
import pytest

from maglev_cosim.diagnosis import real_rig
from maglev_cosim.loop import fast_loop
from maglev_cosim.loop.controllers import load_controller
from maglev_cosim.plant import fast, formulas
from maglev_cosim.records.measured import Segment
from maglev_cosim.rigs import load_rig
from rig_physics import INTECO, open_loop_pair

PLANTED = 0.004      # [1/s]: the resistance 2.4 % higher after 6 s (a winding warming by about 6 K)


def test_the_warming_resistance_agrees_between_the_c_plant_and_the_reference():
    c, r = open_loop_pair(INTECO, {"kappa_R": 0.05})
    none, _ = open_loop_pair(INTECO)
    assert np.max(np.abs(c["i"] - none["i"])) > 1e-3            # [A] the drift acts
    assert np.max(np.abs(c["i"] - r["i"])) <= 1e-7              # [A]
    assert np.max(np.abs(c["x"] - r["x"])) <= 1e-8              # [m]


@pytest.mark.parametrize("bad", [0.06, -0.06, float("nan")])
def test_off_by_default_and_bad_rates_refused_naming_the_variable(bad):
    rig = load_rig("inteco-mls2em")
    assert rig.params.kappa_R == 0.0
    with pytest.raises(ValueError, match="variable kappa_R"):
        rig.params.replace(kappa_R=bad).validate()
    with pytest.raises(ValueError, match="kappa_R"):
        fast.open_loop(rig.params.replace(kappa_R=bad).to_start_values(), np.full(10, 0.4))


def _record(rig, params, n: int, seed: int) -> real_rig.RigRecord:
    """The Inteco model ``params`` under the shipped LQI, the gap stepping between 10 and 8.5 mm every
    0.5 s, read through 10 µm of sensor noise and 5 mA of current noise."""
    rng = np.random.default_rng(seed)
    gap_ref = np.where((np.arange(n) * 1e-3 // 0.5) % 2 == 0, 0.010, 0.0085)
    start = params.replace(x_start=float(rig.to_x(0.010)), v_start=0.0, i_start=rig.equilibrium_current(0.010))
    r = fast_loop.closed_loop(start, rig.reading(gap_ref), pid=load_controller("inteco-lqi").controller,
                              u_hold=float(formulas.equilibrium_input(start.to_start_values())))
    gap = rig.from_x(r["x"]) + rng.normal(0.0, 1e-5, n)
    return real_rig.RigRecord(label=f"heating {seed}", ts=1e-3, y=np.asarray(rig.reading(gap)), u=np.asarray(r["u"]),
                              current=np.asarray(r["i"]) + rng.normal(0.0, 5e-3, n), position=gap,
                              segment=Segment(0, n))


def test_a_planted_warming_is_recovered_within_two_sigma_from_the_current_computed_from_the_pwm():
    rig = load_rig("inteco-mls2em")
    r = _record(rig, rig.params.replace(kappa_R=PLANTED), 6000, seed=7)
    p, info = real_rig.calibrate_coil(rig, [r], rig.params)
    est, sd = info.values["kappa_R"], info.sigma["kappa_R"]
    assert 0 < sd < 0.25 * PLANTED, sd
    assert abs(est - PLANTED) <= 2 * sd, (est, sd)
    assert abs(info.values["R_c"] - rig.params.R_c) <= 2 * info.sigma["R_c"]
    # the segment's own coil carries it, with its σ, into the figures and the report
    _, own = real_rig._own_coil(rig, r, rig.params, {"calibrated": True})
    assert own["kappa_R"] == pytest.approx(est, abs=0.2 * sd) and own["kappa_R_sigma"] > 0


def test_the_current_from_the_pwm_is_the_coil_model_free_run_whatever_the_disturbance_model():
    """Without a measured current the filter keeps the coil out of the gap's updates: the current
    from the PWM moves with the tracked gap only through L(x) and the motional EMF, so with the ball's
    inductance off it is the same under any disturbance model; the filter of before (coil_free off)
    pulls the current towards what the gap suggests, by an amount that depends on that model."""
    rig = load_rig("inteco-mls2em")
    r = _record(rig, rig.params, 3000, seed=3)
    p = rig.params.replace(L_x=0.0)
    loose = real_rig.noise_defaults(rig, p)
    tight = {**loose, "q_force": 0.02 * loose["q_force"], "f_force": 0.3}
    free = [real_rig.predict(rig, r, p, r.ts, use_current=False, noise=nz)["i_pred"] for nz in (loose, tight)]
    ok = np.isfinite(free[0])
    assert ok.sum() > 2900 and np.max(np.abs(free[0][ok] - free[1][ok])) < 1e-9
    start = real_rig._start(rig, r, p)
    pulled = [fast.predict_measured(start, r.y, r.u, ts=r.ts, q_force=nz["q_force"], f_force=nz["f_force"],
                                    r_sensor=nz["r_sensor"], horizon=1)["i_pred"] for nz in (loose, tight)]
    assert np.max(np.abs(pulled[0][ok] - pulled[1][ok])) > 2e-4               # [A]
