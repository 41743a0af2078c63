"""Closed-loop prediction with a controller identified from the record (maglev_cosim.diagnosis.reaction):
the identification, the reaction's gain, the cross-fitting, and on an emulator record the model with
the identified controller against the model driven by u and the black box."""

from __future__ import annotations

import numpy as np
import pytest

from maglev_cosim.diagnosis import blackbox as bb
from maglev_cosim.diagnosis import reaction
from maglev_cosim.diagnosis.reaction import LinearController, last_error_gain
from maglev_cosim.diagnosis.replay import _settled_at_first_reading, baseline_params, estimate_noise
from maglev_cosim.plant import fast
from maglev_cosim.records.record import read_record
from maglev_cosim.records.synth import synth_record


def test_an_arx_controller_is_identified_exactly():
    rng = np.random.default_rng(3)
    n = 4000
    y, w, i = rng.normal(size=n), np.repeat(rng.normal(size=n // 200), 200), rng.normal(size=n)
    a, b, d, g = np.array([0.5, -0.2]), np.array([1.5, -0.7, 0.1]), np.array([-0.4, 0.3]), np.array([0.2, 0.1, 0.0])
    u = np.zeros(n)
    for t in range(3, n):
        u[t] = a @ u[t - 1:t - 3:-1] + b @ y[t:t - 3:-1] + d @ w[t:t - 2:-1] + g @ i[t:t - 3:-1] + 0.05
    orders = {"u": 2, "y": 2, "w": 1, "i": 2}
    ctl = LinearController.fit({"u": u, "y": y, "w": w, "i": i}, np.arange(3, n), orders)
    assert np.allclose(ctl.coef["u"], a) and np.allclose(ctl.b, b) and np.allclose(ctl.coef["w"], d)
    assert np.allclose(ctl.coef["i"], g) and ctl.c == pytest.approx(0.05)
    assert ctl.residual_var < 1e-20 and ctl.lags == 2
    assert np.abs(ctl.residuals({"u": u, "y": y, "w": w, "i": i})[3:]).max() < 1e-9
    with pytest.raises(ValueError, match="too few"):
        LinearController.fit({"u": u, "y": y}, np.arange(3, 20), orders)


@pytest.mark.parametrize("orders", [{}, {"y": 0}, {"u": 2, "y": 3, "w": 1, "i": 0}])
def test_the_reaction_is_the_measured_input_less_the_controller_on_the_model_s_trajectory(orders):
    """``reaction`` (vectorised over starts and steps) against its definition written sample by
    sample: r[s, j-1] = u[k+j] - ARX(k+j), the ARX reading the model's trajectory traj[k, c] for the
    readings after the start k and the measured ones up to it (NaN in the trajectory stays NaN)."""
    rng = np.random.default_rng(6)
    n, h = 600, 7
    sig = {"u": rng.normal(size=n), "y": rng.normal(size=n), "w": rng.normal(size=n), "i": rng.normal(size=n)}
    ctl = LinearController.fit(sig, np.arange(20, n), orders)
    traj = rng.normal(size=(n, h + 1))
    traj[rng.random(traj.shape) < 0.02] = np.nan
    starts = np.sort(rng.choice(np.arange(ctl.lags, n - h), 150, replace=False))
    got = ctl.reaction(sig, traj, starts, h)
    want = np.empty((len(starts), h))
    for s, k in enumerate(starts):
        for j in range(1, h + 1):
            t = k + j
            v = ctl.c
            for name, cf in ctl.coef.items():
                for m, c in enumerate(cf, start=LinearController.first(name)):
                    if name == "y" and t - m > k:
                        v += c * traj[k, t - m - k]
                    else:
                        v += c * sig[name][t - m]
            want[s, j - 1] = sig["u"][t] - v
    assert np.array_equal(np.isnan(got), np.isnan(want))
    assert np.allclose(got, want, rtol=0, atol=1e-12, equal_nan=True)
    assert ctl.reaction(sig, traj, starts[:0], h).shape == (0, h)


def test_the_reaction_gain_inverts_an_exact_controller_and_ignores_a_useless_one():
    """r = B·e exactly (no residual): the gain gives e back; with a huge residual variance, nothing."""
    rng = np.random.default_rng(4)
    h = 6
    b = np.array([2.0, -1.0, 0.3])
    A = rng.normal(size=(h, h))
    cov = A @ A.T + np.eye(h)
    e = rng.normal(size=h)
    B = np.zeros((h, h))
    for m, bm in enumerate(b):
        B += bm * np.eye(h, k=-m)
    assert last_error_gain(b, cov, 1e-12, h) @ (B @ e) == pytest.approx(e[-1], abs=1e-6)
    assert abs(last_error_gain(b, cov, 1e12, h) @ (B @ e)) < 1e-9


def test_the_last_error_gain_from_fewer_reactions_cannot_read_the_last_error_exactly():
    """Without the last reaction (the only one that holds b_0·e_h), an exact controller no longer
    gives the last error back; it is estimated from its covariance with the earlier ones."""
    rng = np.random.default_rng(6)
    h, b = 6, np.array([2.0, -1.0, 0.3])
    A = rng.normal(size=(h, h))
    cov = A @ A.T + np.eye(h)
    B = sum(bm * np.eye(h, k=-m) for m, bm in enumerate(b))
    errs = rng.multivariate_normal(np.zeros(h), cov, size=4000)
    r = errs @ B.T
    g = last_error_gain(b, cov, 1e-12, h - 1)
    assert g.shape == (h - 1,) and last_error_gain(b, cov, 0.1, 0).shape == (0,)
    left = errs[:, -1] - r[:, :h - 1] @ g
    # what is left is the last error's part the earlier ones do not carry: its conditional variance
    want = cov[-1, -1] - cov[-1, :-1] @ np.linalg.solve(cov[:-1, :-1], cov[:-1, -1])
    assert np.var(left) == pytest.approx(want, rel=0.1) and want > 0.05 * cov[-1, -1]


def test_the_prediction_does_not_read_the_actuator_value_computed_from_the_predicted_reading(monkeypatch):
    """A controller with direct feedthrough, u[t] = 2·y[t] + noise: its output at the predicted
    instant holds the reading there. The prediction h samples ahead reads the actuator signal only
    up to h − READ_BEFORE (the information of a current measured at that instant, which the
    actuator has not moved yet): its error stays that of the reading's last step; read up to h, it
    would be the reading itself."""
    rng = np.random.default_rng(7)
    n, H = 6000, 5
    steps = rng.normal(size=n) * 1e-3
    y = np.cumsum(steps)
    u = 2.0 * y + 1e-9 * rng.normal(size=n)
    traj = np.full((n, H + 1), np.nan)
    for j in range(1, H + 1):
        traj[:n - j, j] = y[:n - j]                       # the model: "stays put"
    assert reaction.READ_BEFORE == 1

    def error() -> float:
        out = reaction.predict(y, u, None, traj, [H], 1e-3, orders={"u": 1, "y": 1})
        ok = np.isfinite(out.y_pred[0])
        return float(np.sqrt(np.mean((y[ok] - out.y_pred[0][ok]) ** 2)))

    kept = error()
    assert 0.7e-3 < kept < 1.3e-3                         # one step of the reading's walk is left
    monkeypatch.setattr(reaction, "READ_BEFORE", 0)
    assert error() < 0.5 * kept                           # the reading read back through the controller


def test_a_controller_that_does_not_react_leaves_the_model_s_prediction_as_it_was():
    """An actuator signal independent of the reading (noise): what the identification finds is
    chance, and the trust chosen on other blocks keeps it from moving the prediction: the error
    stays within 1 % of the model's own."""
    rng = np.random.default_rng(5)
    n, H = 6000, 20
    y = np.cumsum(rng.normal(size=n)) * 1e-3
    traj = np.full((n, H + 1), np.nan)
    for j in range(1, H + 1):
        traj[:n - j, j] = y[:n - j] + 1e-3 * rng.normal(size=n - j)      # a model with its own errors
    u = rng.normal(size=n)
    out = reaction.predict(y, u, None, traj, [5, 20], 1e-3)
    for q, h in enumerate((5, 20)):
        ok = np.isfinite(out.y_pred[q])
        assert ok.sum() > 5000
        k = np.flatnonzero(ok) - h
        own = np.sqrt(np.mean((y[ok] - traj[k, h]) ** 2))
        loop = np.sqrt(np.mean((y[ok] - out.y_pred[q][ok]) ** 2))
        assert abs(loop / own - 1) < 0.01, (h, loop, own)


@pytest.fixture(scope="module")
def emulated(tmp_path_factory):
    """An emulator record without effects, the true model's trajectories driven by the recorded u
    from every sample, 50 samples ahead."""
    path = synth_record(tmp_path_factory.mktemp("rx") / "rec.csv", duration=8.0, seed=11)
    rec = read_record(path)
    params = baseline_params()
    noise = estimate_noise(rec, params)
    start, _ = _settled_at_first_reading(rec, params)
    H = 50
    traj = np.full((rec.n, H + 1), np.nan)
    traj[:, 0] = rec.y
    for j0 in range(1, H + 1, fast.MAX_HORIZONS):
        js = list(range(j0, min(j0 + fast.MAX_HORIZONS, H + 1)))
        o = fast.predict_horizons(start, rec.y, rec.u, ts=rec.ts, q_force=noise.q_force, f_force=noise.f_force,
                                  r_sensor=noise.r_sensor, horizons=js, f_sensor=noise.f_sensor,
                                  r_coloured=noise.r_coloured)
        for q, j in enumerate(js):
            traj[:rec.n - j, j] = o["y_pred"][q][j:]
    return rec, traj


def test_the_identified_controller_reads_the_reaction_the_model_driven_by_u_cannot(emulated):
    """The record's PID, identified on the other blocks, turns the true model's open-loop 50 ms
    prediction (behind the black box, tests/test_compare.py) into one ahead of the black box fitted
    on the same blocks; at 5 ms the reaction has little to add and the model stays ahead."""
    rec, traj = emulated
    hs = (5, 20, 50)
    out = reaction.predict(rec.y, rec.u, rec.w, traj, hs, rec.ts)
    stay = {h: bb.stays_put(rec.y, h) for h in hs}
    # the black box, fitted and judged two-fold on the same blocks as the controller
    parity = (np.arange(rec.n) // int(round(reaction.BLOCK_S / rec.ts))) % 2
    for q, h in enumerate(hs):
        yb = np.full(rec.n, np.nan)
        for f in (0, 1):
            runs = [s for s in np.split(np.arange(rec.n), np.flatnonzero(np.diff(parity)) + 1) if parity[s[0]] == f]
            box = bb.fit([bb.Series(rec.y[s], rec.u[s], rec.ts) for s in runs], h * rec.ts)
            for s in np.split(np.arange(rec.n), np.flatnonzero(np.diff(parity)) + 1):
                if parity[s[0]] != f:
                    yb[s] = box.predict(bb.Series(rec.y[s], rec.u[s], rec.ts))
        driven = np.full(rec.n, np.nan)
        driven[h:] = traj[:rec.n - h, h]
        ok = np.isfinite(out.y_pred[q]) & np.isfinite(yb) & np.isfinite(driven)
        assert ok.sum() > 2000
        loop, box, drv = (bb.skill(rec.y, p, stay[h], ok) for p in (out.y_pred[q], yb, driven))
        assert loop > box, (h, loop, box, drv)
        assert loop >= drv - 0.02, (h, loop, drv)
        if h == 50:
            assert drv < box < loop and loop > 0.6, (loop, box, drv)
    assert out.to_json()["orders"] == reaction.ORDERS
