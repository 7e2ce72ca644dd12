"""The coloured-noise model of short series: the sample autocorrelation's small-sample bias is modelled, so a
young series' slow noise (its long-run variance, which sets a young fit's covariance) is not underestimated."""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from ros_margcal.model.fitting_noise import expected_acf, noise_model


def _white_plus_ar1(rng: np.random.Generator, n: int, m: int, phi: float, c: float) -> np.ndarray:
    """``n`` stationary series of ``m`` points: unit variance, a share ``c`` of it AR(1) with coefficient ``phi``."""
    innov = rng.normal(size=(n, m)) * math.sqrt(1 - phi * phi)
    innov[:, 0] = rng.normal(size=n)  # the stationary start
    ar = lfilter([1.0], [1.0, -phi], innov, axis=1)
    return math.sqrt(c) * ar + math.sqrt(1 - c) * rng.normal(size=(n, m))


def _long_run(c: float, phi: float) -> float:
    """Long-run variance (sum of all autocovariances) of unit white plus AR(1) noise."""
    return (1 - c) + c * (1 + phi) / (1 - phi)


def test_the_expected_sample_acf_matches_simulation() -> None:
    """``expected_acf`` is the mean of the mean-removed sample autocovariances of 80 points over the mean of the
    variances (4000 series: within 0.01 at every lag), far below the process's own ``c phi^l`` (by 0.15 or more);
    the mean of the ratios is lower still (by 0.05 here: the ratio's own bias, not modelled)."""
    rng = np.random.default_rng(11)
    m, phi, c, lags = 80, 0.961, 0.7, np.arange(1, 9)
    x = _white_plus_ar1(rng, 4000, m, phi, c)
    x -= x.mean(axis=1, keepdims=True)
    acf = np.array([np.sum(x[:, : m - k] * x[:, k:], axis=1) for k in range(9)])
    sample = np.mean(acf[1:], axis=1) / np.mean(acf[0])
    expected = expected_acf(c, phi, m, lags)
    assert np.max(np.abs(sample - expected)) < 0.01
    assert np.min(c * phi**lags - expected) > 0.15


def test_a_short_series_long_run_variance_is_not_underestimated() -> None:
    """300 points (the stream's first minute of 0.2 s block means, a 5 s correlation time): the median fitted
    ``phi`` is within 0.01 of 0.961 and the median long-run variance within 20 % of the truth (35.5); the
    log-linear fit to the raw sample autocorrelation gave 0.938 and 22 (a young fit's covariance too small)."""
    rng = np.random.default_rng(12)
    phi, c = 0.961, 0.7
    fits = [noise_model(x) for x in _white_plus_ar1(rng, 80, 300, phi, c)]
    got = np.array([f for f in fits if f is not None])
    assert len(got) >= 76
    assert abs(float(np.median(got[:, 1])) - phi) < 0.01
    lrv = np.median([_long_run(cc, pp) for cc, pp in got])
    assert 0.8 < lrv / _long_run(c, phi) < 1.25


def test_a_long_series_is_fitted_as_before() -> None:
    """3000 points of a fast AR(1) (phi 0.8): the correction is small, the fit recovers c and phi (0.50, 0.75)."""
    rng = np.random.default_rng(13)
    got = noise_model(_white_plus_ar1(rng, 1, 3000, 0.8, 0.5)[0])
    assert got is not None
    assert abs(got[0] - 0.5) < 0.08 and abs(got[1] - 0.8) < 0.06
