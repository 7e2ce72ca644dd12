"""The noise a fit absorbed (model/fitting_noise.py ``Absorbed``, ``noise_model(r, absorbed=U)``)."""

from __future__ import annotations

import numpy as np
import pytest

from ros_margcal.model.fitting_noise import Absorbed, expected_acf, noise_model


def _brute(u: np.ndarray, c: float, phi: float, lags: np.ndarray) -> np.ndarray:
    """The expected sample autocorrelation of ``C (I - U U^T) e`` from the full covariance matrix."""
    m = len(u)
    idx = np.arange(m)
    s = (1.0 - c) * np.eye(m) + c * phi ** np.abs(np.subtract.outer(idx, idx))
    k = np.eye(m) - u @ u.T
    cen = np.eye(m) - np.ones((m, m)) / m
    cov = cen @ k @ s @ k @ cen
    d = np.array([np.trace(cov, offset=int(lag)) for lag in np.r_[0, lags]])
    return d[1:] / d[0]


@pytest.mark.parametrize(("c", "phi"), [(0.3, 0.95), (0.7, 0.6), (0.05, 0.99)])
def test_the_expected_autocorrelation_is_exact(c: float, phi: float) -> None:
    t = np.linspace(0.0, 1.0, 200)
    u = 0.05 * np.c_[np.sin(6 * t), np.cos(3 * t), t**2, np.sin(20 * t + 1)]
    lags = np.array([1, 2, 3, 5, 8, 13, 19])
    assert np.allclose(Absorbed(u, lags).expected(c, phi), _brute(u, c, phi, lags), atol=1e-12)


def test_nothing_absorbed_is_the_short_series_model() -> None:
    lags = np.arange(1, 31)
    got = Absorbed(np.zeros((300, 1)), lags).expected(0.4, 0.97)
    assert np.allclose(got, expected_acf(0.4, 0.97, 300, lags), atol=1e-12)


def _residual(seed: int, m: int, c: float, phi: float, u: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ar = np.empty(m)
    ar[0] = rng.normal()
    for k in range(1, m):
        ar[k] = phi * ar[k - 1] + np.sqrt(1.0 - phi * phi) * rng.normal()
    e = np.sqrt(1.0 - c) * rng.normal(size=m) + np.sqrt(c) * ar
    q = np.linalg.qr(np.c_[np.ones(m), u])[0]
    return e - q @ (q.T @ e)


def test_a_slow_noise_the_fit_took_in_is_found_again() -> None:
    """Slow parameter directions take most of a slow noise: the plain estimate calls it white on most seeds; with
    the absorbed directions the model finds the colour on most (seeded, so a count that can fail)."""
    m, c, phi = 400, 0.5, 0.99
    t = np.linspace(0.0, 1.0, m)
    u = np.c_[t, t**2, np.sin(2 * np.pi * t), np.cos(2 * np.pi * t), np.sin(4 * np.pi * t), np.cos(4 * np.pi * t)]
    q = np.linalg.qr(np.c_[np.ones(m), u])[0]
    plain = found = 0
    for seed in range(20):
        r = _residual(seed, m, c, phi, u)
        plain += noise_model(r) is not None
        found += noise_model(r, q) is not None
    assert found >= 17 and plain <= 10


def test_white_noise_stays_white() -> None:
    m = 400
    t = np.linspace(0.0, 1.0, m)
    q = np.linalg.qr(np.c_[np.ones(m), t, np.sin(2 * np.pi * t), np.cos(2 * np.pi * t)])[0]
    rng = np.random.default_rng(3)
    white = 0
    for _ in range(20):
        e = rng.normal(size=m)
        white += noise_model(e - q @ (q.T @ e), q) is None
    assert white >= 17
