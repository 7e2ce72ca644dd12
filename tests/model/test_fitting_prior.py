"""The observability-aware (MAP) fit and the predicted heading error, checked on data from the
independent generator (tests/independent) and the package simulator."""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pytest

from ros_margcal import Calibration, fit
from ros_margcal.model.errors import InputError
from ros_margcal.model.fitting_prior import NAMES, broad_prior, fit_with_prior
from ros_margcal.model.heading import heading_p95, inclination_deg
from ros_margcal.sim.simulation import directions, random_sensor, simulate


def _ground(independent: ModuleType, seed: int, tilt: float, seconds: float = 300.0) -> dict:
    return independent.generate("mag", "ground", duration_s=seconds, rate_hz=50.0, seed=seed, tilt_deg=tilt,
                                symmetric_soft_iron=True)


def test_full_sphere_map_agrees_with_the_least_squares_fit() -> None:
    """With rich data the broad prior does not matter: the MAP fit is the lm sym fit, every parameter updated."""
    rng = np.random.default_rng(5)
    truth = random_sensor(rng, "mag")
    rec = simulate(truth, directions("uniform", 600, rng), noise=0.004, rng=rng)
    pf = fit_with_prior(rec.raw, broad_prior(rec.raw, truth.norm))
    ls = fit(rec.raw, model="sym", method="lm", norm=truth.norm)
    assert set(pf.updated) == set(NAMES) and not pf.partial
    assert np.linalg.norm(pf.calibration.offset - ls.offset) < 2e-3 * truth.raw_radius
    assert np.abs(pf.calibration.matrix - ls.matrix).max() < 5e-3 * np.abs(ls.matrix).max()


@pytest.mark.parametrize(("seed", "tilt"), [(11, 5.0), (12, 20.0)])
def test_ground_robot_gets_a_level_heading_within_a_degree(independent: ModuleType, seed: int, tilt: float) -> None:
    """Yaw turning with small tilt (a ground robot, independent generator): the MAP fit from the broad
    prior gives a level heading p95 under 1.5 deg; the predicted p95 (coloured-noise aware) is never
    optimistic by more than 1.5x, and at most 3x (or 0.5 deg) pessimistic."""
    rec = _ground(independent, seed, tilt)
    tr = rec["truth"]
    pts = rec["xyz"][::10]
    cal = fit_with_prior(pts, broad_prior(pts, tr["norm"]), time_ordered=True).calibration
    measured = independent.heading_p95(cal.matrix, cal.offset, tr, tilt_deg=0.0)
    predicted = heading_p95(cal, tilt_deg=0.0, inclination=inclination_deg(cal, pts))
    assert measured < 1.5
    assert measured / 1.5 < predicted < max(3.0 * measured, 0.5)
    assert np.linalg.norm((cal.offset - tr["offset"])[:2]) < 0.03 * tr["norm"]


def test_a_ring_is_not_flattened_into_a_far_ellipsoid(independent: ModuleType) -> None:
    """The geometric residual keeps a yaw-only ring from being 'fitted' by a huge flat ellipsoid: the
    vertical offset stays within half a norm of the truth and the gains near one (the plain norm residual
    runs away to offsets of tens of norms with gains near 0.1). Near-level data fix the vertical offset
    only weakly: slow (coloured) noise moves it by more than its white-noise sigma, see the module doc."""
    rec = _ground(independent, 13, 5.0)
    tr = rec["truth"]
    pts = rec["xyz"][::10]
    cal = fit_with_prior(pts, broad_prior(pts, tr["norm"])).calibration
    assert abs(cal.offset[2] - tr["offset"][2]) < 0.5 * tr["norm"]
    assert np.all(np.abs(np.diag(cal.matrix) - 1.0) < 0.2)


def test_static_data_keep_the_prior(independent: ModuleType) -> None:
    """A static recording determines almost nothing: the off-diagonal terms come from the prior and move
    less than three prior sigmas (they only absorb the one constraint a single direction gives)."""
    rec = independent.generate("mag", "static", duration_s=20.0, rate_hz=50.0, seed=14, symmetric_soft_iron=True)
    tr = rec["truth"]
    prior = Calibration(tr["offset"] + 1e-6, tr["W"], norm=tr["norm"], model="sym",
                        covariance=np.diag(np.r_[np.full(3, 4e-6), np.full(6, 0.02)] ** 2), parameter_names=NAMES)
    pf = fit_with_prior(rec["xyz"], prior)
    assert pf.partial
    assert {"w_xy", "w_xz", "w_yz"} <= set(pf.from_prior)
    assert np.abs(pf.calibration.matrix - prior.matrix).max() < 3 * 0.02
    assert len(pf.updated) <= 3
    assert all(0.0 <= v <= 1.0 for v in pf.data_share.values())


def test_bad_input_is_refused() -> None:
    """NaN points, a prior without covariance, a non-positive sigma or inflate: InputError."""
    pts = np.random.default_rng(1).normal(size=(50, 3))
    prior = broad_prior(pts, 1.0)
    with pytest.raises(InputError):
        fit_with_prior(np.r_[pts, [[np.nan, 0, 0]]], prior)
    with pytest.raises(InputError):
        fit_with_prior(pts, Calibration.identity(1.0))
    with pytest.raises(InputError):
        fit_with_prior(pts, prior, sigma=-1.0)
    with pytest.raises(InputError):
        fit_with_prior(pts, prior, inflate=float("nan"))
    with pytest.raises(InputError):
        broad_prior(pts, 0.0)


def test_predicted_heading_error_scales_with_the_covariance_and_matches_monte_carlo(independent: ModuleType) -> None:
    """The prediction is linear in the parameter std, zero without uncertainty, and close to the p95
    of heading errors of calibrations drawn from the covariance (measured with the generator's heading)."""
    n = 48e-6
    cov = np.diag(np.r_[np.full(3, 0.01 * n), np.full(6, 0.005)] ** 2)
    cal = Calibration(np.zeros(3), np.eye(3), norm=n, covariance=cov, parameter_names=NAMES)
    p = heading_p95(cal, tilt_deg=30.0)
    assert heading_p95(cal.replace(covariance=4.0 * cov), tilt_deg=30.0) == pytest.approx(2.0 * p, rel=1e-6)
    assert heading_p95(cal.replace(covariance=0.0 * cov), tilt_deg=30.0) == 0.0
    rng = np.random.default_rng(15)
    inc = np.radians(60.0)
    truth = {"offset": np.zeros(3), "M": np.eye(3), "field": n * np.array([0.0, np.cos(inc), -np.sin(inc)])}
    draws = rng.multivariate_normal(np.r_[np.zeros(3), 1, 1, 1, 0, 0, 0], cov, size=200)
    errs = []
    for d in draws:
        w = np.array([[d[3], d[6], d[7]], [d[6], d[4], d[8]], [d[7], d[8], d[5]]])
        errs.append(independent.heading_p95(w, d[:3], truth, tilt_deg=30.0, n_yaw=72))
    assert 0.5 * np.median(errs) < p < 2.0 * np.median(errs)
    with pytest.raises(InputError):
        heading_p95(Calibration.identity(n))


def test_coloured_noise_widens_the_weak_terms_only(independent: ModuleType) -> None:
    """For a time series the Newey-West information widens the vertical offset (fed by slow tilt, which
    slow noise can fake) far more than the horizontal one (fed by yaw turning), and the vertical error
    then lies within three of its sigmas."""
    rec = _ground(independent, 11, 5.0)
    tr = rec["truth"]
    pts = rec["xyz"][::10]
    prior = broad_prior(pts, tr["norm"])
    white = fit_with_prior(pts, prior).calibration.parameter_std()
    hac_fit = fit_with_prior(pts, prior, time_ordered=True).calibration
    hac = hac_fit.parameter_std()
    assert hac["b_z"] / white["b_z"] > 1.5 * hac["b_x"] / white["b_x"]
    assert abs(hac_fit.offset[2] - tr["offset"][2]) < 3.0 * hac["b_z"]
