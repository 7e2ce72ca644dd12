"""The delete-a-region jackknife covariance (model/fitting_jackknife.py) and its use in the full path's heading figures."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from ros_margcal.model.errors import DegenerateDataError, InputError
from ros_margcal.model.fitting import fit
from ros_margcal.model.fitting_core import pack
from ros_margcal.model.fitting_jackknife import REGIONS, jackknife_at, t_factor
from ros_margcal.model.fitting_prior import broad_prior, fit_with_prior, linearised_at, posterior_at
from ros_margcal.model.heading import UNORDERED_SD_FACTOR, heading_p95_quantile, inflated
from ros_margcal.stream.config import PipelineConfig
from ros_margcal.stream.observable import heading_figures

NORM = 50e-6
W_TRUE = np.array([[1.05, 0.03, -0.02], [0.03, 0.97, 0.04], [-0.02, 0.04, 1.01]])
B_TRUE = np.array([20e-6, -12e-6, 8e-6])


def _readings(seed: int, *, lowest_deg: float = -90.0, bump: float = 0.0, n: int = 400) -> np.ndarray:
    """Raw readings of directions above ``lowest_deg`` of elevation, 0.3 % noise; ``bump``: a local distortion of
    that share of the field near one direction (a shape the ellipsoid does not have)."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(np.sin(np.radians(lowest_deg)), 1.0, n)
    az = rng.uniform(0.0, 2.0 * np.pi, n)
    u = np.c_[np.sqrt(1.0 - z * z) * np.cos(az), np.sqrt(1.0 - z * z) * np.sin(az), z]
    near = np.exp(-((u - np.array([0.6, 0.0, 0.8])) ** 2).sum(axis=1) / 0.3)
    h = NORM * (u + bump * near[:, None] * np.array([1.0, 0.5, 0.0]))
    return np.linalg.solve(W_TRUE, h.T).T + B_TRUE + rng.normal(0.0, 0.003 * NORM, (n, 3))


def _level_error(cal: object) -> float:
    """The measured level heading p95 (deg) of ``cal`` against the truth, 60 deg inclination, over yaw."""
    inc = np.radians(60.0)
    m = NORM * np.array([0.0, np.cos(inc), -np.sin(inc)])
    errs = []
    for yaw in np.radians(np.arange(0.0, 360.0, 5.0)):
        c, s = np.cos(yaw), np.sin(yaw)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        body = rz.T @ m
        h = rz @ (np.asarray(cal.matrix) @ (np.linalg.solve(W_TRUE, body) + B_TRUE - np.asarray(cal.offset)))
        d = np.degrees(np.arctan2(h[0], h[1]) - np.arctan2(m[0], m[1]))
        errs.append(abs((d + 180.0) % 360.0 - 180.0))
    return float(np.percentile(errs, 95))


def _bounds(raw: np.ndarray) -> tuple[float, float, float]:
    """(measured, white-noise bound times UNORDERED_SD_FACTOR, jackknife bound times t_factor) of a full fit."""
    cal = fit(raw, model="sym", method="lm", norm=NORM)
    prior = broad_prior(raw, NORM)
    white = inflated(posterior_at(raw, cal, prior), UNORDERED_SD_FACTOR)
    jack, dof = jackknife_at(raw, cal, prior)
    return _level_error(cal), heading_p95_quantile(white), heading_p95_quantile(inflated(jack, t_factor(dof)))


@pytest.mark.parametrize("dof", [1, 2, 5, 11, 40])
def test_t_factor_is_the_f_over_chi_square_quantile(dof: int) -> None:
    want = np.sqrt(2.0 * stats.f.ppf(0.95, 2, dof) / stats.chi2.ppf(0.95, 2))
    assert t_factor(dof) == pytest.approx(want, rel=1e-9)


def test_t_factor_tends_to_one_and_refuses_nonsense() -> None:
    assert t_factor(10**6) == pytest.approx(1.0, abs=1e-5)
    assert t_factor(11) == pytest.approx(1.153, abs=1e-3)
    for bad in ({"dof": 0}, {"dof": 2.5}, {"dof": 5, "p": 1.0}, {"dof": 5, "p": float("nan")}):
        with pytest.raises(InputError):
            t_factor(**bad)


def test_one_newton_step_is_the_refit() -> None:
    """Each region's step against the MAP fit refitted without it: the same covariance within 5 % on a full sphere."""
    raw = _readings(3)
    prior = broad_prior(raw, NORM)
    cal = fit_with_prior(raw, prior).calibration
    jack, dof = jackknife_at(raw, cal, prior)
    sigma = linearised_at(raw, cal, prior).sigma
    w, b = np.asarray(cal.matrix), np.asarray(cal.offset)
    region = np.argmax((raw - b) @ w.T @ REGIONS.T, axis=1)
    theta = pack(b, w, "sym")
    steps = []
    for k in np.unique(region):
        refit = fit_with_prior(raw[region != k], prior, sigma=sigma, start=cal).calibration
        steps.append(pack(np.asarray(refit.offset), np.asarray(refit.matrix), "sym") - theta)
    d = np.array(steps) - np.mean(steps, axis=0)
    brute = dof / (dof + 1) * d.T @ d
    assert dof == len(REGIONS) - 1
    assert np.linalg.norm(jack.covariance - brute) <= 0.05 * np.linalg.norm(brute)


def test_a_shape_the_model_misses_is_seen_by_the_jackknife() -> None:
    """A hemisphere with a local distortion of 3 % of the field: the white-noise bound (even times 2.4) is below the
    measured level error on most seeds, the jackknife's bound on none (20 seeds: counts that can fail)."""
    rows = [_bounds(_readings(seed, lowest_deg=0.0, bump=0.03)) for seed in range(20)]
    white = sum(w >= e for e, w, _ in rows)
    jack = sum(j >= e for e, _, j in rows)
    assert white <= 5 and jack >= 19


def test_on_clean_full_data_the_jackknife_is_not_wider() -> None:
    """A clean full sphere: the jackknife's bound covers (19 of 20 seeds) and is not wider than the white one's in the
    median, so the wider of the two (the status's) costs nothing where the model holds."""
    rows = [_bounds(_readings(seed)) for seed in range(20)]
    assert sum(j >= e for e, _, j in rows) >= 19
    assert np.median([j / w for _, w, j in rows]) <= 1.0


def test_too_few_regions_are_refused() -> None:
    raw = _readings(1, lowest_deg=75.0, n=200)  # a cap around +z: one or two regions
    prior = broad_prior(raw, NORM)
    cal = fit_with_prior(raw, prior).calibration
    with pytest.raises(DegenerateDataError, match="regions"):
        jackknife_at(raw, cal, prior)


@settings(max_examples=15, deadline=None)
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_the_order_of_the_samples_does_not_matter(seed: int) -> None:
    raw = _readings(5, lowest_deg=-20.0, n=150)
    prior = broad_prior(raw, NORM)
    cal = fit(raw, model="sym", method="lm", norm=NORM)
    perm = np.random.default_rng(seed).permutation(len(raw))
    a, _ = jackknife_at(raw, cal, prior)
    b, _ = jackknife_at(raw[perm], cal, prior)
    assert np.allclose(a.covariance, b.covariance, rtol=1e-8, atol=1e-30)


def test_the_status_figures_take_the_wider_covariance() -> None:
    """``heading_figures`` of a full fit (no covariance of its own, as the stream's full path publishes it): the
    jackknife's covariance where the model misses a shape, the white one's (times 2.4) where the model holds."""
    cfg = PipelineConfig.for_sensor("mag")
    for raw, want_jack in ((_readings(0, lowest_deg=0.0, bump=0.03), True), (_readings(0), False)):
        cal = fit(raw, model="sym", method="lm", norm=NORM).replace(covariance=None, parameter_names=())
        prior = broad_prior(raw, NORM)
        out = heading_figures(cal, raw, cfg)
        assert out is not None
        jack, dof = jackknife_at(raw, cal, prior)
        want = inflated(jack, t_factor(dof)) if want_jack else inflated(posterior_at(raw, cal, prior), UNORDERED_SD_FACTOR)
        assert np.allclose(out[1].covariance, want.covariance, rtol=1e-9)
