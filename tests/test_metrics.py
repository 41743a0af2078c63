"""The System Identification figures: compare's NRMSE fit, resid's correlations and bands."""

from __future__ import annotations

import numpy as np
import pytest

from maglev_cosim.diagnosis.metrics import (chi2_quantile, correlation, fit_ceiling, nrmse_fit, psd, resid,
                                            white_noise_rms)


def test_nrmse_fit_matches_matlabs_definition():
    y = np.sin(np.linspace(0, 10, 500))
    assert nrmse_fit(y, y) == 100.0
    assert nrmse_fit(y, np.full_like(y, y.mean())) == pytest.approx(0.0, abs=1e-12)
    half = y.mean() + 0.5 * (y - y.mean())            # half the deviation: fit 50 %
    assert nrmse_fit(y, half) == pytest.approx(50.0)
    assert nrmse_fit(y, -y) < 0                        # worse than the mean
    assert np.isnan(nrmse_fit(np.ones(10), np.zeros(10)))


def test_the_white_noise_under_a_slow_signal_and_the_fit_it_allows():
    """white_noise_rms reads the white floor of a signal above its band (a coil current's noise under
    its own 2-20 Hz motion, 1 kHz samples), and fit_ceiling is the fit of a prediction whose only error
    is that noise: the noise-free signal's own fit to the noisy one."""
    rng = np.random.default_rng(4)
    t = np.arange(15000) * 1e-3
    slow = 0.1 * np.sin(2 * np.pi * 2 * t) + 0.03 * np.sin(2 * np.pi * 20 * t + 1)
    for sigma in (2e-3, 6e-3, 2e-2):
        noisy = slow + rng.normal(0.0, sigma, len(t))
        assert white_noise_rms(noisy - slow, 1e-3) == pytest.approx(sigma, rel=0.05)
        assert white_noise_rms(noisy, 1e-3) == pytest.approx(sigma, rel=0.05)      # the slow part is below the band
        assert fit_ceiling(noisy, sigma) == pytest.approx(nrmse_fit(noisy, slow), abs=0.5)
    assert np.isnan(white_noise_rms(np.zeros(8), 1e-3)) and np.isnan(fit_ceiling(np.ones(50), 1e-3))


def test_resid_band_holds_white_noise_and_flags_coloured_noise():
    rng = np.random.default_rng(0)
    e = rng.standard_normal(20000)
    u = rng.standard_normal(20000)
    r = resid(e, u, max_lag=25, confidence=0.99)
    assert r.band == pytest.approx(2.5758 / np.sqrt(20000), rel=1e-4)
    assert r.auto[r.lags == 0][0] == pytest.approx(1.0)
    assert r.auto_out <= 2 and r.cross_out <= 2        # 1 % of 50 lags expected outside
    coloured = np.convolve(e, np.ones(5) / 5, mode="same")
    assert resid(coloured, u).auto_out >= 8            # lags 1..4 both sides
    leaking = e + 0.3 * np.roll(u, 3)                  # the input 3 samples earlier leaks into the residual
    lags, c = correlation(leaking, u, 10)
    assert lags[np.argmax(c)] == 3


def test_psd_finds_a_tone():
    t = np.arange(20000) * 1e-3
    x = np.sin(2 * np.pi * 50 * t) + 0.01 * np.random.default_rng(1).standard_normal(len(t))
    f, p = psd(x, 1e-3)
    assert f[np.argmax(p)] == pytest.approx(50.0, abs=0.5)


@pytest.mark.parametrize("q", [0.5, 0.95, 0.99, 1 - 1e-3, 1 - 1e-4])
@pytest.mark.parametrize("dof", [1, 2, 3, 7, 30])
def test_chi2_quantile_is_scipy_stats_chi2_ppf(q, dof):
    # the verdicts' thresholds: the same numbers as scipy.stats, which the package no longer imports
    from scipy.stats import chi2, norm

    assert chi2_quantile(q, dof) == pytest.approx(chi2.ppf(q, dof), rel=1e-13)
    band = resid(np.ones(100) + np.arange(100) % 3, np.arange(100.0), confidence=0.99).band
    assert band == pytest.approx(norm.ppf(0.995) / 10, rel=1e-13)
