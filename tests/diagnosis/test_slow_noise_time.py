"""The slow noise's correlation time read from the residual's own lag covariances along the directions."""

from __future__ import annotations

import numpy as np
import pytest

from ros_margcal.diagnosis.baseline_noise import ar1_noise, estimate_slow_noise


def _turning_residual(tau: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """60 s at 50 Hz of a norm residual: AR(1) offset noise (std 0.001, correlation time ``tau``) seen along a
    direction that turns a few degrees per sample (a fast platform), plus white noise (0.002)."""
    rng = np.random.default_rng(seed)
    t = np.arange(3000) * 0.02
    steps = rng.normal(scale=np.deg2rad(3.0), size=(3000, 3))
    dirs = np.cumsum(steps, axis=0)
    dirs = np.column_stack([np.cos(dirs[:, 0]) * np.cos(dirs[:, 1]), np.sin(dirs[:, 0]) * np.cos(dirs[:, 1]),
                            np.sin(dirs[:, 1])])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    slow = ar1_noise(t, 0.001, tau, rng)
    return t, np.einsum("ij,ij->i", dirs, slow) + 0.002 * rng.normal(size=3000), dirs


@pytest.mark.parametrize("seed", [3, 8])
def test_correlation_time_of_turning_slow_noise_is_found(seed: int) -> None:
    """A 5 s correlation time is read within a factor of two on a turning sensor, and a 0.3 s one as shorter
    than 1 s: the two are told apart (the simulated grid search read 1.2 s for a 5 s noise on a rough band)."""
    t, r, dirs = _turning_residual(5.0, seed)
    std, tau = estimate_slow_noise(t, r, 0.002, dirs)
    assert std > 0
    assert 2.5 < tau < 10.0, f"correlation time {tau:.3f} s for a 5 s noise"
    t, r, dirs = _turning_residual(0.3, seed)
    std, tau = estimate_slow_noise(t, r, 0.002, dirs)
    assert std > 0
    assert tau < 1.0, f"correlation time {tau:.3f} s for a 0.3 s noise"
