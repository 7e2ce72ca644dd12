"""The heading figures' faster draws (issue 28 item 3) give exactly what np.percentile gives."""

from __future__ import annotations

import numpy as np
import pytest

from ros_margcal.model import heading
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.fitting_core import parameter_names

NAMES = parameter_names("sym", scale_free=False)


@pytest.mark.parametrize("k", [1, 2, 3, 20, 72, 648])
def test_row_p95_is_numpys_percentile(k: int) -> None:
    """One partition and the minimum above it: bit for bit the two-kth partition it replaced, and np.percentile's
    linear rule to rounding (numpy interpolates from the upper value past the middle), ties included."""
    rng = np.random.default_rng(k)
    x = np.abs(rng.standard_normal((50, k)))
    x[:5] = np.round(x[:5], 1)  # ties
    pos = 0.95 * (k - 1)
    lo, hi = int(np.floor(pos)), min(int(np.floor(pos)) + 1, k - 1)
    part = np.partition(x, [lo, hi], axis=1)
    before = part[:, lo] + (pos - lo) * (part[:, hi] - part[:, lo])
    got = heading._row_p95(x.copy())
    np.testing.assert_array_equal(got, before)
    np.testing.assert_allclose(got, np.percentile(x, 95, axis=1), rtol=1e-14, atol=0)


def _reference_quantile(cal: Calibration, tilt: float, inc: float) -> float:
    """heading_p95_quantile written plainly: every draw's errors over the grid, np.percentile twice."""
    cov = np.asarray(cal.covariance)
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    grad = heading.heading_gradient(cal, heading.attitudes(tilt), inclination=inc)
    errors = np.abs(heading._QUANTILE_Z @ (grad @ (vec * np.sqrt(np.clip(lam, 0.0, None)))).T)
    return float(np.percentile(np.percentile(errors, 95, axis=1), 95))


@pytest.mark.parametrize(("tilt", "inc"), [(0.0, 60.0), (30.0, 60.0), (12.5, 45.0)])
def test_quantile_unchanged(tilt: float, inc: float) -> None:
    """The published bound is the plain computation's (a random calibration and covariance)."""
    rng = np.random.default_rng(7)
    a = rng.standard_normal((9, 9))
    w = np.eye(3) + 0.05 * rng.standard_normal((3, 3))
    sd = np.array([2e-7] * 3 + [2e-3] * 6)  # offsets in tesla, matrix entries dimensionless
    cal = Calibration(np.array([20e-6, -10e-6, 5e-6]), 0.5 * (w + w.T), norm=48e-6, covariance=np.outer(sd, sd) * (a @ a.T) / 9,
                      parameter_names=NAMES)
    got = heading.heading_p95_quantile(cal, tilt_deg=tilt, inclination=inc)
    assert got == pytest.approx(_reference_quantile(cal, tilt, inc), rel=1e-12)
    assert 0.0 < got < heading.UNDETERMINED_DEG


def test_attitudes_cached_but_callers_own_their_copy() -> None:
    """A caller that writes into the grid it got does not change the next caller's grid."""
    first = heading.attitudes(30.0)
    first[:] = 0.0
    again = heading.attitudes(30.0)
    assert again.shape == (648, 3, 3)
    np.testing.assert_allclose(np.einsum("kij,kil->kjl", again, again), np.broadcast_to(np.eye(3), again.shape),
                               atol=1e-12)
