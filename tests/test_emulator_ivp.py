"""The independent emulator (``maglev_cosim.records.emulator_ivp``, issue 22 item 5): written from the paper,
sharing no code with the model. Its agreement with the pure-Python reference, its controller timing,
its effects, noise and converters, and its records."""

from __future__ import annotations

import ast
import inspect
import json
import math

import numpy as np
import pytest
from scipy.signal import welch

from maglev_cosim.records import emulator_ivp as E
from maglev_cosim.loop.simulate import reference_signal, simulate as loop_simulate
from maglev_cosim.records.record import read_record

QUIET = E.IvpConfig(quantise=False)       # with noise=False: the paper's equations alone
W0 = float(E.reading_mu(QUIET, 3.2e-3))   # the reading at the paper's operating point


def _run(w, **kw):
    return E.simulate(w, QUIET.with_values(**kw), noise=False)


def test_shares_no_code_with_the_model():
    """Only params (values by name), the settings check the emulators share (emulation: no physics), numpy
    and scipy, and the record writer (I/O)."""
    tree = ast.parse(inspect.getsource(E))
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            imported.add(("." * node.level) + (node.module or ""))
        elif isinstance(node, ast.Import):
            imported.update(a.name for a in node.names)
    ours = {m for m in imported if m.startswith(".") or m.startswith("maglev_cosim")}
    assert ours == {"..plant.params", ".record", ".emulation"}, ours
    assert not imported & {"cffi", "ctypes"}


# --------------------------------------------------------------------------- against the reference

@pytest.fixture(scope="module")
def step_reference():
    """The project's pure-Python reference (solve_ivp DOP853, rtol 1e-12) in closed loop: the
    'baseline' set (Section 3, T_a = 0), a 0.05 MU step at 0.1 s from the settled 3.2 mm."""
    w = reference_signal("step", 1.0, base=W0, amplitude=0.05)
    return w, loop_simulate("baseline", w, backend="reference")


@pytest.mark.parametrize("method, bound_y, bound_u", [("LSODA", 1e-7, 3e-7), ("Radau", 1e-10, 1e-9)])
def test_step_agrees_with_the_reference(step_reference, method, bound_y, bound_u):
    """With no effect, no noise, no rounding and the PID's output at the reading instant, the two
    integrate the same equations: they differ by the integrators' tolerance only. Measured: LSODA at
    rtol 1e-8 1.3e-8 MU in y and 4.4e-8 MU in u (the PID's derivative, kd/ts = 10, multiplies the
    reading's error into u); Radau at rtol 1e-8 4e-13 and 1.5e-12 MU."""
    w, ref = step_reference
    s = E.simulate(w, QUIET.with_values(pid_offset=0.0, method=method), noise=False)
    assert np.max(np.abs(s["y"] - ref["y"])) < bound_y
    assert np.max(np.abs(s["u"] - ref["u"])) < bound_u
    assert np.max(np.abs(s["x"] - ref["x"])) < bound_y / 100      # [m]: 122 MU/m
    assert np.max(np.abs(s["u"] - ref["u"])) > 0                   # two integrators, not one


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_pid_timing_offset_is_a_delay_of_that_fraction(step_reference):
    """The output reaching the D/A a fraction of the sample after the reading: the disagreement with
    the reference grows in proportion (measured 0.94e-3, 2.9e-3, 5.0e-3 MU in y at 0.1, 0.3, 0.5 of
    the 1 ms sample), and it is exactly the reference with that transport delay (T_d = 0.3 ms)."""
    w, ref = step_reference
    dy = {}
    for off in (0.1, 0.3, 0.5):
        s = E.simulate(w, QUIET.with_values(pid_offset=off), noise=False)
        dy[off] = np.max(np.abs(s["y"] - ref["y"]))
    assert 5e-4 < dy[0.1] < dy[0.3] < dy[0.5] < 1e-2
    assert dy[0.3] / dy[0.1] == pytest.approx(3.0, rel=0.15)
    assert dy[0.5] / dy[0.1] == pytest.approx(5.0, rel=0.15)
    s = E.simulate(w, QUIET.with_values(pid_offset=0.3), noise=False)
    delayed = loop_simulate({"T_a": 0.0, "T_d": 0.3e-3}, w, backend="reference")   # baseline + delay
    assert np.max(np.abs(s["y"] - delayed["y"])) < 1e-7
    assert np.max(np.abs(s["u"] - delayed["u"])) < 3e-7


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_offset_and_transport_delay_add_up():
    """pid_offset·ts + T_d is the lag from reading to coil, however it is split."""
    w = E._reference("square", 1.5, 1e-3, 0, 1.0, QUIET)
    a = _run(w, pid_offset=0.0, T_d=2.5e-3)
    b = _run(w, pid_offset=0.5, T_d=2.0e-3)
    assert np.max(np.abs(a["y"] - b["y"])) < 1e-7


# --------------------------------------------------------------------------- effects

@pytest.fixture(scope="module")
def square():
    w = E._reference("square", 2.0, 1e-3, 0, 1.0, QUIET)       # steps up at 0.5 s and 1.5 s
    return w, _run(w)


def _overshoot(sim, w):
    return sim["y"][500:1000].max() - w[600]


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_lags_and_delay_cost_phase(square):
    """Amplifier lag, force lag and delay each raise the overshoot after the step up (base 0.069 MU)."""
    w, base = square
    for kw in ({"T_a": 3e-3}, {"T_F": 2e-3}, {"T_d": 2.5e-3}):
        s = _run(w, **kw)
        assert _overshoot(s, w) > 1.2 * _overshoot(base, w), kw
    lagged = _run(w, T_a=3e-3)
    assert np.max(np.abs(lagged["i"] - base["i"])) > 0.05       # the current lags its command


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_viscous_damping_reduces_the_overshoot(square):
    w, base = square
    assert _overshoot(_run(w, k_FV=0.3), w) < 0.9 * _overshoot(base, w)
    assert _overshoot(_run(w, k_FV=0.0), w) > _overshoot(base, w)


def test_sensor_nonlinearity_moves_the_held_position():
    """The loop holds the reading, so the ball settles where the bent sensor reads w: with
    k_x2 < 0 between the calibration points the reading is high and the ball held lower."""
    w = np.full(3000, W0)
    k_x2 = -3e4
    s = _run(w, k_x2=k_x2)
    x_expected = E.position_reading(QUIET.with_values(k_x2=k_x2), W0)
    assert x_expected < 3.2e-3 - 4e-7
    assert s["x"][-1] == pytest.approx(x_expected, abs=2e-9)
    assert s["y"][-1] == pytest.approx(W0, abs=1e-9)


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_current_limit_caps_the_current_and_shows_in_its_share():
    """A limit caps i; lowering it raises the share of samples at the limit. With a 0.15 s square
    the ball stays up with the limit active 4 % to 35 % of the samples (measured 0.040 at 0.70 A,
    0.346 at 0.65 A); below 0.645 A the catch after a step fails and the ball falls on its stop,
    and with a 4 s sine the limit is active in about half the samples (0.48 at 0.58 A), the ball
    lying on the lower stop, from which 0.58 A cannot lift it (0.91 A would)."""
    w = E._reference("square", 2.0, 1e-3, 0, 0.15, QUIET)
    shares = {}
    for i_max in (0.70, 0.65):
        s = _run(w, i_max=i_max)
        assert s["i"].max() <= i_max + 1e-12
        assert not np.any(s["contact"])
        shares[i_max] = s["i_limited"].mean()
    assert 0.01 < shares[0.70] < 0.1 < 0.25 < shares[0.65] < 0.5
    assert _run(w)["i_limited"].mean() == 0.0
    w = E._reference("sine", 4.0, 1e-3, 0, 4.0, QUIET)
    s = _run(w, i_max=0.58)
    assert 0.4 < s["i_limited"].mean() <= 0.6
    on = s["contact"] == -1
    assert 0.2 < on.mean() < 0.6
    assert np.all(s["x"][on] == QUIET.x_min) and np.all(s["v"][on] == 0.0)   # inelastic, stuck
    assert np.all(on[np.argmax(on):])                                          # for good
    s = _run(w, i_max=0.05)                                                   # any limit > 0 runs
    assert s["contact"][-1] == -1 and s["i_limited"].mean() > 0.99


def test_the_ball_sticks_to_a_stop_until_the_force_pulls_it_off():
    """Started on the lower stop, held there by its equilibrium current, it leaves when the reference
    asks for 3.2 mm; asked beyond the upper stop it sticks there (x = x_max, v = 0) and leaves when
    the reference comes back and the controller drops the current."""
    low, high = float(E.reading_mu(QUIET, 0.0)), float(E.reading_mu(QUIET, QUIET.x_max))
    w = np.concatenate([np.full(200, low), np.full(600, W0), np.full(600, high + 0.03), np.full(600, W0)])
    s = _run(w)
    assert np.all(s["contact"][:201] == -1) and np.all(s["x"][:201] == 0.0)      # the output of 200 lands at 200.3
    assert not np.any(s["contact"][201:800]) and np.all(s["x"][500:800] > 2.5e-3)
    top = s["contact"] == 1
    assert top[800:1400].mean() > 0.9 and not np.any(top[:800]) and not np.any(top[1402:])
    assert np.all(s["x"][top] == QUIET.x_max) and np.all(s["v"][top] == 0.0)
    assert 2e-3 < s["x"][-1] < 5e-3                   # caught again (the wound-up integrator still unwinding)


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_pickup_shows_at_its_frequency(square):
    w, base = square
    s = _run(w, A_d=0.01, f_d=37.0, phi_d=0.5)
    f = np.fft.rfftfreq(len(w), 1e-3)
    spec = np.abs(np.fft.rfft(s["u"] - base["u"]))
    assert f[np.argmax(spec[f > 5]) + np.sum(f <= 5)] == pytest.approx(37.0, abs=0.5)


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_coulomb_friction_makes_the_controller_push_along_the_motion():
    """Friction of 2 % of the weight, smoothed over v_c = 1 mm/s, on a 2 s sine (3.2 ± 0.6 mm,
    |v| up to 3.8 mm/s): the controller supplies F_c·tanh(v/v_c) more in the direction of motion,
    about F_c/(∂F/∂u) with ∂F/∂u = 2·m_k·g·k_i·k_DA/i = 0.44 N/MU (measured 4.1e-3 MU against
    3.4e-3 predicted with the sine's mean |tanh|), and the ball trails the reference (by 1.6e-3 MU
    on average, 8 steps of the 12-bit converter). Smoothed friction leaves no offset at rest."""
    w = E._reference("sine", 4.0, 1e-3, 0, 2.0, QUIET)
    base = _run(w)
    F_c = 0.02 * QUIET.m_k * QUIET.g
    s = _run(w, F_c=F_c)
    part = slice(1000, 4000)
    direction = np.sign(base["v"][part])
    push = np.mean((s["u"] - base["u"])[part] * direction)
    i_eq = math.sqrt(QUIET.m_k * QUIET.g / QUIET.k_c) * (QUIET.x_0 - 3.2e-3)
    dF_du = 2 * QUIET.m_k * QUIET.g / i_eq * QUIET.k_i * QUIET.k_DA
    predicted = F_c * np.mean(np.abs(np.tanh(base["v"][part] / QUIET.v_c))) / dF_du
    assert push == pytest.approx(predicted, rel=0.4)
    trail = np.mean((s["y"] - base["y"])[part] * direction)
    assert trail < -1e-3
    held = _run(np.full(2000, W0), F_c=F_c)
    assert abs(held["y"][-1] - W0) < 1e-9


# --------------------------------------------------------------------------- noise and converters

def _corner_of(noise: np.ndarray) -> float:
    """The corner [Hz] of a first-order low-pass whose spectrum, sampled at 1 kHz (the aliased
    Lorentzian 1/(1 + a² − 2a·cos ω), a = exp(−2π f_c ts)), best fits the noise's Welch spectrum
    on log axes, 1 to 450 Hz."""
    f, p = welch(noise, fs=1000.0, nperseg=4096)
    band = (f >= 1) & (f <= 450)
    omega = 2 * np.pi * f[band] * 1e-3

    def misfit(fc: float) -> float:
        a = math.exp(-2 * math.pi * fc * 1e-3)
        r = np.log(p[band]) + np.log(1 + a * a - 2 * a * np.cos(omega))
        return float(np.var(r))

    grid = np.geomspace(3.0, 300.0, 400)
    return float(grid[np.argmin([misfit(fc) for fc in grid])])


def test_sensor_noise_is_coloured_with_its_corner():
    """A first-order low-passed Gaussian sampled at 1 kHz: its RMS, the corner its spectrum shows,
    and its spectrum half the plateau there (measured corners 29.9 and 99.5 Hz)."""
    rng = np.random.default_rng(1)
    sigma = 3e-4
    for corner in (30.0, 100.0):
        n = E.sensor_noise(2 ** 18, sigma, corner, 1e-3, rng)
        assert np.std(n) == pytest.approx(sigma, rel=0.05)
        assert _corner_of(n) == pytest.approx(corner, rel=0.05)
    f, p = welch(n, fs=1000.0, nperseg=4096)
    at = lambda fr: np.mean(p[np.abs(f - fr) < 5])  # noqa: E731
    assert at(100.0) / at(10.0) == pytest.approx(0.5, abs=0.08)
    white = E.sensor_noise(2 ** 16, sigma, math.inf, 1e-3, rng)
    assert abs(np.corrcoef(white[:-1], white[1:])[0, 1]) < 0.02


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_the_loop_reads_through_the_noise_and_feels_the_random_force():
    w = np.full(4000, W0)
    s = E.simulate(w, E.IvpConfig(quantise=False, sigma_F_rel=0.0, f_y=50.0, seed=3))
    assert np.allclose(s["y"], E.reading_mu(QUIET, s["x"]) + s["y_noise"], atol=1e-12)
    assert np.std(s["y_noise"]) == pytest.approx(2e-4, rel=0.15)
    a = math.exp(-1e-3 * 2 * math.pi * 50.0)
    assert np.corrcoef(s["y_noise"][:-1], s["y_noise"][1:])[0, 1] == pytest.approx(a, abs=0.03)
    s = E.simulate(w, E.IvpConfig(quantise=False, sigma_y=0.0, sigma_F_rel=5e-3, tau_F_noise=0.02, seed=3))
    weight = QUIET.m_k * QUIET.g
    assert np.std(s["F_random"]) == pytest.approx(5e-3 * weight, rel=0.3)
    assert np.corrcoef(s["F_random"][:-1], s["F_random"][1:])[0, 1] == pytest.approx(math.exp(-1e-3 / 0.02), abs=0.01)
    assert np.std(s["x"]) > 1e-7                  # the ball moves under it


@pytest.mark.slow   # the quick tier's 2-minute budget: a few seconds of ODE solving each
def test_converters_put_y_and_u_on_their_grid():
    w = E._reference("square", 2.0, 1e-3, 0, 1.0, QUIET)
    for bits in (12, 10):
        lsb = 2.0 / 2 ** bits
        s = E.simulate(w, E.IvpConfig(bits=bits, seed=2))
        for sig in (s["y"], s["u"]):
            assert np.max(np.abs(sig / lsb - np.round(sig / lsb))) < 1e-9
        assert s["u"].max() <= 1.0 - lsb               # two's complement: +1 MU is not a code
        assert len(np.unique(s["y"])) > 20


# --------------------------------------------------------------------------- records

@pytest.mark.slow
def test_record_is_read_back_and_diagnosed(tmp_path):
    path = E.synth_record(tmp_path / "r.csv", effects={"delay": {"T_d": 0.002}}, reference="square", duration=2.0,
                          seed=4, period=1.0)
    rec = read_record(path)
    assert rec.n == 2000 and rec.ts == 1e-3
    assert rec.meta["emulator"].startswith("ivp") and rec.meta["seed"] == "4"
    assert rec.meta["effects"] == "delay(T_d=0.002)"
    truth = json.loads((tmp_path / "r.csv.truth.json").read_text())
    assert truth["emulator"] == "ivp" and truth["effects"] == {"delay": {"T_d": 0.002}}
    assert truth["settings"]["pid_offset"] == 0.3
    lsb = 1 / 2048
    assert np.max(np.abs(rec.y / lsb - np.round(rec.y / lsb))) < 1e-6 / lsb * 2
    from maglev_cosim.diagnosis import pipeline

    d = pipeline.run(rec, effects=["delay"], workers=1)
    assert d.verdict.verdict


def test_settings_are_read_from_name_value_texts():
    """``--setting NAME=VALUE``: words stay words, numbers (inf too) become numbers, for the command
    line and the benchmark alike."""
    assert E.parse_settings([" pid_derivative = measurement", "f_y=inf", "pid_tf=0.001"]) == {
        "pid_derivative": "measurement", "f_y": math.inf, "pid_tf": 0.001}
    with pytest.raises(ValueError, match="expected NAME=VALUE"):
        E.parse_settings(["f_y"])
    with pytest.raises(ValueError, match="'abc' is not a number"):
        E.parse_settings(["pid_tf=abc"])


def test_synth_record_refuses_what_it_does_not_have(tmp_path):
    with pytest.raises(ValueError, match="not in this emulator"):
        E.synth_record(tmp_path / "r.csv", effects={"slew_rate": {"di_max": 20.0}}, duration=1.0)
    with pytest.raises(ValueError, match="no parameter 'T_a'"):
        E.synth_record(tmp_path / "r.csv", effects={"delay": {"T_a": 1e-3}}, duration=1.0)
    with pytest.raises(ValueError, match="unknown emulator setting"):
        E.synth_record(tmp_path / "r.csv", settings={"warp": 1.0}, duration=1.0)
    with pytest.raises(ValueError, match="pid_offset"):
        E.synth_record(tmp_path / "r.csv", settings={"pid_offset": 1.5}, duration=1.0)
    with pytest.raises(ValueError, match="pid_derivative"):
        E.synth_record(tmp_path / "r.csv", settings={"pid_derivative": "setpoint"}, duration=1.0)
    assert not (tmp_path / "r.csv").exists()


def test_disturbance_draws_and_the_command_line(tmp_path):
    """The benchmark's disturbance family drives it as it drives the rig emulator, and
    ``maglev-cosim synth --emulator ivp`` writes its record."""
    from maglev_cosim.cli import main
    from maglev_cosim.records.synth import draw_disturbance

    dist = draw_disturbance(400)
    path = E.synth_record(tmp_path / "d.csv", seed=400, disturbance=dist, duration=1.5, reference="square")
    truth = json.loads((tmp_path / "d.csv.truth.json").read_text())
    assert truth["disturbance"]["bits"] == dist["bits"] and truth["pid"]["kp"] == dist["kp"]
    lsb = 2.0 / 2 ** dist["bits"]
    rec = read_record(path, plausibility="warn")
    assert np.max(np.abs(rec.u / lsb - np.round(rec.u / lsb))) < 2e-6 / lsb
    out = tmp_path / "c.csv"
    assert main(["synth", "--emulator", "ivp", "--out", str(out), "--duration", "1.2", "--reference", "square",
                 "--effect", "current_saturation:i_max=1.2", "--setting", "pid_offset=0.5", "--setting",
                 "f_y=inf"]) == 0
    truth = json.loads((tmp_path / "c.csv.truth.json").read_text())
    assert truth["settings"]["pid_offset"] == 0.5 and math.isinf(truth["settings"]["f_y"])
    assert truth["config"]["i_max"] == 1.2
    assert main(["synth", "--out", str(tmp_path / "e.csv"), "--setting", "pid_offset=0.5"]) == 2
