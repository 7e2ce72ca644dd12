"""The MAP fit's solver and what the stream asks of it: Levenberg-Marquardt on the normal equations against
scipy's MINPACK, a given start and noise (a stream's refit), the posterior linearised at a given calibration."""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pytest
from scipy.optimize import least_squares

import ros_margcal.model.fitting_geometric as fg
import ros_margcal.model.fitting_prior as fp
from ros_margcal.model.errors import DegenerateDataError
from ros_margcal.model.fitting_core import pack
from ros_margcal.model.fitting_prior import NAMES, broad_prior, fit_with_prior, posterior_at
from ros_margcal.model.heading import heading_p95
from ros_margcal.model.steps import drained
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


def _ground_series(independent: ModuleType, seed: int, tilt: float) -> np.ndarray:
    rec = independent.generate("mag", "ground", duration_s=300.0, rate_hz=50.0, seed=seed, tilt_deg=tilt,
                               symmetric_soft_iron=True)
    x = rec["xyz"]
    return x[: len(x) // 10 * 10].reshape(-1, 10, 3).mean(axis=1)  # the stream's 5 Hz block means


@pytest.mark.parametrize(("seed", "tilt"), [(1, 5.0), (2, 20.0)])
def test_the_normal_equation_lm_reaches_minpacks_minimum(independent: ModuleType, seed: int, tilt: float) -> None:
    """``_lm`` and scipy's MINPACK LM on the stacked system, from the same start at the same sigma, end at
    the same minimum of the posterior cost (within 1e-6 of it) and the same parameters (within 1e-3 sd)."""
    pts = _ground_series(independent, seed, tilt)
    prior = broad_prior(pts, 48e-6)
    theta0, info0 = fp._prior_parts(prior, 1.0)
    chol = np.linalg.cholesky(info0).T
    z = np.ascontiguousarray(pts.T)
    s = fit_with_prior(pts, prior).sigma
    ours, _ = drained(fp._lm(z, theta0.copy(), theta0, info0, 48e-6, s, 500))

    def fun(th: np.ndarray) -> np.ndarray:
        return np.r_[fg.geometric(z, th, 48e-6)[0] / s, chol @ (th - theta0)]

    def jac(th: np.ndarray) -> np.ndarray:
        return np.vstack([fg.geometric(z, th, 48e-6)[1].T / s, chol])

    ref = least_squares(fun, theta0.copy(), jac=jac, method="lm", xtol=1e-12, ftol=1e-12, max_nfev=2000).x
    c_ours, c_ref = fp._cost(z, ours, theta0, chol, 48e-6, s), fp._cost(z, ref, theta0, chol, 48e-6, s)
    assert c_ours <= c_ref * (1 + 1e-6)
    post = np.linalg.inv(np.asarray(jac(ref)).T @ np.asarray(jac(ref)))
    assert np.max(np.abs(ours - ref) / np.sqrt(np.diag(post))) < 1e-3


def test_a_refit_from_the_last_solution_and_noise_is_the_full_fit(independent: ModuleType) -> None:
    """The stream's refit (one start: the fit on the first two thirds; their residual noise given) gives the
    full fit's solution (within 0.02 sd) and covariance (within 2 %), and reports the residual noise it saw."""
    pts = _ground_series(independent, 3, 5.0)
    prior = broad_prior(pts, 48e-6)
    first = fit_with_prior(pts[:1000], prior, time_ordered=True, norm_rel_std=0.05)
    assert first.residual_sigma == first.sigma  # estimated: the same figure
    full = fit_with_prior(pts, prior, time_ordered=True, norm_rel_std=0.05)
    warm = fit_with_prior(pts, prior, time_ordered=True, norm_rel_std=0.05, sigma=first.sigma, start=first.calibration)
    sd = np.sqrt(np.diag(full.calibration.covariance))
    a = pack(full.calibration.offset, full.calibration.matrix, "sym")
    b = pack(warm.calibration.offset, warm.calibration.matrix, "sym")
    assert np.max(np.abs(a - b) / sd) < 0.02
    np.testing.assert_allclose(np.diag(warm.calibration.covariance), sd**2, rtol=0.02)
    assert warm.sigma == first.sigma
    assert warm.residual_sigma == pytest.approx(full.sigma, rel=0.05)
    assert warm.iterations < full.iterations
