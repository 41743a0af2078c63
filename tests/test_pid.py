"""The paper's discrete PID (Eq. 24/25) and its python-control form; the linear closed loop."""

from __future__ import annotations

import control
import numpy as np
import pytest

from maglev_cosim.loop.design import closed_loop_report, discrete_closed_loop
from maglev_cosim.plant.params import get_params
from maglev_cosim.loop import fast_loop
from maglev_cosim.loop.pid import PID, DiscretePID, pid_continuous_tf, pid_tf


def test_hand_computed_samples():
    pid = DiscretePID(PID())
    pid.reset(0.3)
    # e = 0.1, 0.1, -0.05 ; ts = 1e-3
    u0 = pid.step(0.5, 0.4)   # 2*0.1 + (0.3 + 2.97e-3*0.1) + 0.01*(0.1-0)/1e-3 = 0.2 + 0.300297 + 1.0
    assert u0 == 1.0          # clipped at u_max
    assert pid.integral == pytest.approx(0.300297)
    u1 = pid.step(0.5, 0.4)   # 0.2 + 0.300594 + 0
    assert u1 == pytest.approx(0.500594)
    u2 = pid.step(0.35, 0.4)  # e = -0.05: -0.1 + 0.3004455 + 0.01*(-0.15)/1e-3 = -1.2995545 -> 0
    assert u2 == 0.0
    assert pid.integral == pytest.approx(0.300594 - 2.97e-3 * 0.05)


def test_preload_holds_the_input_at_zero_error():
    pid = DiscretePID()
    pid.reset(0.371)
    assert [pid.step(0.4, 0.4) for _ in range(5)] == [0.371] * 5


def test_transfer_function_equals_the_difference_equation():
    cfg = PID(u_min=-1e9, u_max=1e9)
    rng = np.random.default_rng(0)
    e = rng.standard_normal(400) * 0.01
    pid = DiscretePID(cfg)
    pid.reset(0.0)
    u = np.array([pid.step(ek, 0.0) for ek in e])
    resp = control.forced_response(pid_tf(cfg), T=np.arange(400) * cfg.ts, U=e)
    assert np.max(np.abs(resp.outputs - u)) < 1e-12


def test_zeros_of_the_design_are_the_papers():
    z = np.sort(np.real(pid_continuous_tf().zeros()))
    assert z == pytest.approx([-198.5, -1.496], abs=0.01)   # the paper rounds to -200 and -1.5 (Eq. 21)


def test_anti_windup_and_filter_are_off_by_default_and_act_when_on():
    base = DiscretePID(PID())
    aw = DiscretePID(PID(anti_windup="conditional"))
    filt = DiscretePID(PID(tf=5e-3))
    for c in (base, aw, filt):
        c.reset(0.5)
    outs = {id(c): [c.step(0.9, 0.3) for _ in range(200)] for c in (base, aw, filt)}
    assert base.integral > aw.integral          # saturated at u_max: no wind-up with anti-windup
    assert aw.integral == pytest.approx(0.5)
    wide, wide_f = DiscretePID(PID(u_max=100.0)), DiscretePID(PID(u_max=100.0, tf=5e-3))
    for c in (wide, wide_f):
        c.reset(0.5)
    # the first derivative kick kd*de/ts = 6 MU is spread by the filter: (0.01*0.6)/(5e-3 + 1e-3) = 1 MU
    assert wide.step(0.9, 0.3) - wide_f.step(0.9, 0.3) == pytest.approx(5.0)
    plain = DiscretePID(PID(anti_windup="none", tf=0.0))
    plain.reset(0.5)
    assert [plain.step(0.9, 0.3) for _ in range(200)] == outs[id(base)]


def test_linear_discrete_closed_loop_is_stable_and_its_bandwidth():
    """Measured: max |pole| 0.99786, bandwidth 29.6 Hz (eq18) — the paper says about 50 Hz (Fig. 18);
    stable as the paper states."""
    r = closed_loop_report(get_params("eq18"))
    assert r["stable"] and r["max_pole_magnitude"] < 1
    assert r["bandwidth_hz"] == pytest.approx(29.64, abs=0.05)
    assert r["step_info"]["SteadyStateValue"] == pytest.approx(1.0, abs=1e-6)
    T = discrete_closed_loop(get_params("eq18"))
    assert T.dt == 1e-3


@pytest.mark.parametrize("cfg", [
    PID(), PID(tf=2e-3), PID(anti_windup="conditional"), PID(anti_windup="clamping", tf=1e-3),
    PID(ts=1e-2, kp=1.2, ki=8.0, kd=0.02, u_min=-0.5, u_max=0.8, anti_windup="clamping"),
    PID(derivative="measurement"), PID(derivative="measurement", tf=1e-3, anti_windup="conditional"),
])
def test_the_c_pid_and_the_python_pid_are_one_equation(cfg):
    """The difference equation exists twice, in C (the fast path) and in Python (the FMU and
    reference loops): over random w, y that drive the output into both limits they agree exactly."""
    rng = np.random.default_rng(3)
    w = 0.4 + 0.3 * np.sign(np.sin(np.arange(3000) / 150.0))
    y = 0.4 + 0.05 * rng.standard_normal(3000)
    c = fast_loop.pid_only(cfg, w, y, u_hold=0.37)
    ctl = cfg.start(0.37, w[0])
    py = np.array([ctl.step(a, b) for a, b in zip(w, y)])
    assert np.mean(c == cfg.u_max) > 0.01 and np.mean(c == cfg.u_min) > 0.01   # both limits reached
    assert np.array_equal(c, py)
    # settled at a reading away from the first reference (y_before), the error standing
    c = fast_loop.control(cfg, w, y, None, 0.37, y_before=0.385)
    ctl = cfg.start(0.37, w[0], 0.385)
    assert np.array_equal(c, np.array([ctl.step(a, b) for a, b in zip(w, y)]))


@pytest.mark.parametrize("cfg", [PID(), PID(tf=2e-3), PID(derivative="measurement"), PID(anti_windup="clamping")])
def test_a_loop_settled_away_from_its_reference_holds_its_output(cfg):
    """The settled start at a first reading y0 away from the first reference w0 (a record cut from
    a running loop whose integrator still creeps): the output holds ``u_hold`` while the reading
    stays, then moves by ki·ts·e0 a sample (the integrator alone); no derivative kick, no jump by
    kp·e0. At y0 = w0 the start is the settled start at zero error."""
    w0, y0, hold, n = 0.40, 0.388, 0.37, 6
    e0 = w0 - y0
    w, y = np.full(n, w0), np.full(n, y0)
    c = fast_loop.control(cfg, w, y, None, hold, y_before=y0)
    expected = hold + cfg.ki * cfg.ts * e0 * np.arange(1, n + 1)
    assert np.allclose(c, expected, rtol=0, atol=1e-12)
    py = cfg.start(hold, w0, y0)
    assert np.allclose([py.step(w0, y0) for _ in range(n)], expected, rtol=0, atol=1e-12)
    at_w = cfg.start(hold, w0)             # y0 left out: the reading at the reference
    assert at_w.integral == hold and at_w.e_prev == (-w0 if cfg.derivative == "measurement" else 0.0)
    # at zero error before t = 0 (a simulation whose reference steps at t = 0) the step acts at once
    kicked = fast_loop.pid_only(cfg, w, y, u_hold=hold)
    assert kicked[0] - hold == pytest.approx(cfg.kp * e0 + cfg.ki * cfg.ts * e0 + cfg.kd * e0 / (cfg.tf + cfg.ts),
                                             abs=1e-12)


def test_the_derivative_of_the_reading_spares_the_output_the_kick_of_a_reference_step():
    """``derivative="measurement"`` differentiates -y alone: at a reference step of dw the output
    lacks the error form's kd*dw/ts, at every other sample the two are one; settled at the first
    reference, the first sample gives the holding input."""
    w = np.r_[np.full(5, 0.4), np.full(5, 0.45)]
    y = 0.4 + 1e-3 * np.arange(10)
    err, meas = PID(u_min=-10, u_max=10), PID(u_min=-10, u_max=10, derivative="measurement")
    ue, um = fast_loop.pid_only(err, w, y, u_hold=0.3), fast_loop.pid_only(meas, w, y, u_hold=0.3)
    assert um[0] == pytest.approx(0.3, abs=1e-12)
    assert ue[5] - um[5] == pytest.approx(0.01 * 0.05 / 1e-3)
    assert np.allclose(np.delete(ue - um, 5), 0.0, atol=1e-12)
    with pytest.raises(ValueError, match="derivative must be one of error, measurement"):
        PID(derivative="setpoint")


def test_clamping_keeps_the_integrator_within_the_limits():
    ctl = PID(anti_windup="clamping").start(0.5)
    for _ in range(2000):
        ctl.step(0.9, 0.3)
    assert ctl.integral == 1.0
    free = PID().start(0.5)
    for _ in range(2000):
        free.step(0.9, 0.3)
    assert free.integral == pytest.approx(0.5 + 2.97e-3 * 0.6 * 2000)


def test_bad_settings_are_refused_in_one_line():
    with pytest.raises(ValueError, match="u_min < u_max"):
        PID(u_min=1.0, u_max=0.0)
    with pytest.raises(ValueError, match="anti_windup must be one of none, conditional, clamping"):
        PID(anti_windup="yes")
    with pytest.raises(ValueError, match="finite"):
        PID(kp=float("nan"))
