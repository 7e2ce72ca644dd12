"""The linearised posterior of a given calibration (``posterior_at``) and the attitude grid of the heading figures."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ros_margcal.model.errors import DegenerateDataError
from ros_margcal.model.fitting_prior import NAMES, broad_prior, fit_with_prior, posterior_at
from ros_margcal.model.heading import attitudes, heading_p95
from ros_margcal.sim.simulation import directions, random_sensor, simulate


def test_posterior_at_the_map_estimate_is_the_map_covariance() -> None:
    """On a full sphere, linearising at the MAP estimate gives the covariance the MAP fit attaches (same sigma)."""
    rng = np.random.default_rng(5)
    truth = random_sensor(rng, "mag")
    raw = simulate(truth, directions("uniform", 400, rng), noise=0.005, rng=rng).raw
    prior = broad_prior(raw, truth.norm)
    pf = fit_with_prior(raw, prior)
    lin = posterior_at(raw, pf.calibration, prior, sigma=pf.sigma)
    assert lin.parameter_names == NAMES
    np.testing.assert_allclose(lin.covariance, pf.calibration.covariance, rtol=1e-6)
    np.testing.assert_array_equal(lin.offset, pf.calibration.offset)  # the value is kept
    # sigma estimated from the residuals (MAD): the same heading figure within a few per cent
    est = posterior_at(raw, pf.calibration, prior)
    assert heading_p95(est, tilt_deg=30.0) == pytest.approx(heading_p95(pf.calibration, tilt_deg=30.0), rel=0.1)


def test_posterior_at_a_full_fit_keeps_its_value_and_refuses_too_few_points() -> None:
    rng = np.random.default_rng(6)
    truth = random_sensor(rng, "mag")
    raw = simulate(truth, directions("uniform", 300, rng), noise=0.005, rng=rng).raw
    prior = broad_prior(raw, truth.norm)
    got = posterior_at(raw, truth, prior)
    np.testing.assert_array_equal(got.matrix, truth.matrix)
    assert np.all(np.linalg.eigvalsh(got.covariance) > 0)
    # the data shrink every variance far below the broad prior's on a full sphere
    assert np.all(np.diag(got.covariance) < 0.01 * np.diag(prior.covariance))
    with pytest.raises(DegenerateDataError):
        posterior_at(raw[:2], truth, prior)


@pytest.mark.parametrize("tilt", [0.0, 3.5, 30.0])
def test_attitudes_are_yaw_pitch_roll_rotations(tilt: float) -> None:
    """The grid: R = Rz(yaw) Ry(pitch) Rx(roll) over 72 yaws and roll, pitch in {-tilt, 0, tilt}."""
    got = attitudes(tilt)
    tilts = [0.0] if tilt == 0 else [-tilt, 0.0, tilt]
    yaws = np.degrees(np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False))
    want = [Rotation.from_euler("ZYX", [y, p, r], degrees=True).as_matrix() for r in tilts for p in tilts for y in yaws]
    np.testing.assert_allclose(got, np.array(want), atol=1e-12)
