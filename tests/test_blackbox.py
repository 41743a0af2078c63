"""The black-box baseline (maglev_cosim.diagnosis.blackbox): direct ridge predictors per horizon,
the naive predictors and the skill figure every real-rig table shows."""

from __future__ import annotations

import numpy as np
import pytest

from maglev_cosim.diagnosis import blackbox as bb


def _arx_record(seed: int, n: int = 6000, ts: float = 1e-3) -> bb.Series:
    """A stable second-order system driven by a random input with square terms: the position's
    change is a linear function of its past and of the input and its square, as the baseline assumes."""
    rng = np.random.default_rng(seed)
    a = np.repeat(rng.normal(0.0, 1.0, n // 20 + 1), 20)[:n] + 0.05 * rng.normal(size=n)
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = 1.6 * y[k - 1] - 0.64 * y[k - 2] + 0.02 * a[k - 1] + 0.01 * a[k - 1] ** 2
    return bb.Series(y + 1e-4 * rng.normal(size=n), a, ts)


def test_a_linear_system_is_predicted_far_better_than_stays_put_on_a_record_not_fitted():
    fitted = [_arx_record(1), _arx_record(2)]
    unseen = _arx_record(3)
    for hs in (0.005, 0.020):
        p = bb.fit(fitted, hs)
        h = int(round(hs / unseen.ts))
        yp = p.predict(unseen)
        first = int(round(bb.PAST_S / unseen.ts)) + h    # the first sample with a full window, h ahead
        assert np.isnan(yp[:first]).all() and np.isfinite(yp[first:]).all()
        assert bb.skill(unseen.y, yp, bb.stays_put(unseen.y, h)) > 0.9
        assert p.alpha in bb.ALPHAS and set(p.cv_rms) == set(bb.ALPHAS)


def test_the_prediction_uses_no_position_after_the_instant_it_is_made_from():
    s = _arx_record(4)
    hs = 0.020
    h = int(round(hs / s.ts))
    p = bb.fit([s], hs)              # one record: cross-validated by its halves
    k = 3000
    base = p.predict(s)[k + h]
    y = s.y.copy()
    y[k + 1:] += 5.0                 # every position after k changes; the input does not
    moved = p.predict(bb.Series(y, s.a, s.ts))[k + h]
    assert moved == pytest.approx(base, abs=1e-12)
    a = s.a.copy()
    a[k + h] += 3.0                  # the actuator signal up to the predicted instant is used
    assert p.predict(bb.Series(s.y, a, s.ts))[k + h] != pytest.approx(base, abs=1e-9)


def test_too_short_a_record_is_refused_with_the_counts():
    s = _arx_record(5, n=300)
    with pytest.raises(ValueError, match="needs at least"):
        bb.fit([s], 0.050)


def test_naive_predictors_and_skill():
    y = np.cumsum(np.ones(100))          # a ramp: constant velocity is exact, stays put is not
    stay = bb.stays_put(y, 5)
    cv = bb.constant_velocity(y, 5, 1e-3)
    assert np.isnan(stay[:5]).all() and stay[5] == y[0]
    assert np.allclose(cv[15:], y[15:])
    assert bb.skill(y, cv, stay) == pytest.approx(1.0)
    assert bb.skill(y, stay, stay) == pytest.approx(0.0)
    assert bb.skill(y, 2 * stay - y, stay) == pytest.approx(-1.0)
    assert np.isnan(bb.skill(np.ones(50), np.ones(50), np.ones(50)))
