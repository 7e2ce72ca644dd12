"""The predicted heading error per attitude (``heading_std_deg``) and its p95 bound."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ros_margcal import Calibration
from ros_margcal.model.errors import InputError
from ros_margcal.model.fitting_core import pack, unpack
from ros_margcal.model.fitting_prior import NAMES
from ros_margcal.model.heading import (
    _heading_gradient,
    attitudes,
    heading_gradient,
    heading_p95,
    heading_p95_typical,
    heading_std_deg,
)


def _cal(n: float = 48e-6) -> Calibration:
    cov = np.diag(np.r_[np.full(3, 0.01 * n), np.full(6, 0.005)] ** 2)
    return Calibration(np.zeros(3), np.eye(3), norm=n, covariance=cov, parameter_names=NAMES)


def test_the_p95_bound_is_the_percentile_of_the_per_attitude_std() -> None:
    """``heading_p95`` is the 95th percentile of ``1.96 heading_std_deg`` over its attitudes."""
    cal = _cal()
    for tilt in (0.0, 30.0):
        sd = heading_std_deg(cal, attitudes(tilt), inclination=60.0)
        assert heading_p95(cal, tilt_deg=tilt) == pytest.approx(float(np.percentile(1.96 * sd, 95)), rel=1e-12)


def test_a_horizontal_offset_error_is_seen_level_as_its_angle() -> None:
    """Only b_x uncertain (sd 1 % of the horizontal field): the level heading std peaks at 0.573 deg
    (a 0.01 rad angle) when the field points along y, and is zero when it points along x."""
    n, inc = 48e-6, np.radians(60.0)
    cov = np.zeros((9, 9))
    cov[0, 0] = (0.01 * n * np.cos(inc)) ** 2
    cal = Calibration(np.zeros(3), np.eye(3), norm=n, covariance=cov, parameter_names=NAMES)
    sd = heading_std_deg(cal, attitudes(0.0, n_yaw=4), inclination=60.0)
    assert sd.max() == pytest.approx(np.degrees(0.01), rel=1e-4)
    assert sd.min() == pytest.approx(0.0, abs=1e-9)


def test_a_single_attitude_and_no_covariance() -> None:
    """One rotation matrix is accepted; a calibration without covariance is refused."""
    sd = heading_std_deg(_cal(), np.eye(3))
    assert sd.shape == (1,) and sd[0] > 0
    with pytest.raises(InputError):
        heading_std_deg(Calibration.identity(48e-6), np.eye(3))


@pytest.mark.parametrize("tilt", [0.0, 3.5, 30.0])
def test_attitudes_are_yaw_pitch_roll_rotations(tilt: float) -> None:
    """The grid: R = Rz(yaw) Ry(pitch) Rx(roll) over 72 yaws and roll, pitch in {-tilt, 0, tilt}."""
    got = attitudes(tilt)
    tilts = [0.0] if tilt == 0 else [-tilt, 0.0, tilt]
    yaws = np.degrees(np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False))
    want = [Rotation.from_euler("ZYX", [y, p, r], degrees=True).as_matrix() for r in tilts for p in tilts for y in yaws]
    np.testing.assert_allclose(got, np.array(want), atol=1e-12)


def test_the_analytic_heading_gradient_is_the_finite_difference_one() -> None:
    """``_heading_gradient`` against central differences of the tilt-compensated heading, every parameter."""
    rng = np.random.default_rng(8)
    n = 48e-6
    w = np.eye(3) + 0.03 * (lambda a: a + a.T)(rng.normal(size=(3, 3)))
    b = rng.normal(scale=0.5 * n, size=3)
    rot = attitudes(30.0, 12)
    m = n * np.array([0.0, np.cos(np.radians(60.0)), -np.sin(np.radians(60.0))])
    raw = np.linalg.solve(w, np.einsum("kji,j->ki", rot, m).T).T + b + rng.normal(scale=0.01 * n, size=(len(rot), 3))

    def headings(theta: np.ndarray) -> np.ndarray:
        bb, ww = unpack(theta, "sym")
        world = np.einsum("kij,kj->ki", rot, (raw - bb) @ ww.T)
        return np.arctan2(world[:, 0], world[:, 1])

    theta = pack(b, w, "sym")
    want = np.empty((len(rot), 9))
    for k in range(9):
        e = np.zeros(9)
        e[k] = 1e-7 * (n if k < 3 else 1.0)
        d = headings(theta + e) - headings(theta - e)
        want[:, k] = ((d + np.pi) % (2 * np.pi) - np.pi) / (2 * e[k])
    got = _heading_gradient(w, raw - b, rot)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * np.abs(want).max())


def test_the_typical_figure_is_the_median_of_the_measured_p95_under_the_covariance() -> None:
    """Errors drawn from the covariance (an independent generator and far more draws than the figure's own)
    measure a p95 whose median is the typical figure, at level and at 30 deg; the bound is above it."""
    cal = _cal()
    rng = np.random.default_rng(11)
    for tilt in (0.0, 30.0):
        grad = heading_gradient(cal, attitudes(tilt), inclination=60.0)
        delta = rng.multivariate_normal(np.zeros(9), cal.covariance, size=4000)
        measured = np.percentile(np.abs(delta @ grad.T), 95, axis=1)
        typical = heading_p95_typical(cal, tilt_deg=tilt)
        assert typical == pytest.approx(float(np.median(measured)), rel=0.08)
        assert 0.42 < float(np.mean(measured <= typical)) < 0.58
        assert heading_p95(cal, tilt_deg=tilt) > typical


def test_one_error_direction_puts_the_bound_at_about_three_times_the_typical_figure() -> None:
    """Only b_x uncertain: the measured p95 is |z| times a fixed figure, so bound / typical = 1.96 / 0.674."""
    n = 48e-6
    cov = np.zeros((9, 9))
    cov[0, 0] = (0.01 * n) ** 2
    cal = Calibration(np.zeros(3), np.eye(3), norm=n, covariance=cov, parameter_names=NAMES)
    ratio = heading_p95(cal, tilt_deg=0.0) / heading_p95_typical(cal, tilt_deg=0.0)
    assert ratio == pytest.approx(1.96 / 0.6745, rel=0.1)


def test_the_typical_figure_is_deterministic_and_scales_with_the_error() -> None:
    """Fixed draws: the same figure every call, four times the covariance gives twice the figure; a covariance
    with a NaN gives NaN; no covariance is refused."""
    cal = _cal()
    a, b = heading_p95_typical(cal, tilt_deg=30.0), heading_p95_typical(cal, tilt_deg=30.0)
    assert a == b
    assert heading_p95_typical(cal.replace(covariance=4.0 * cal.covariance), tilt_deg=30.0) == pytest.approx(2 * a, rel=1e-9)
    bad = np.array(cal.covariance)
    bad[2, 2] = np.nan
    assert np.isnan(heading_p95_typical(cal.replace(covariance=bad), tilt_deg=0.0))
    with pytest.raises(InputError):
        heading_p95_typical(Calibration.identity(48e-6))


def test_the_typical_figure_takes_numpys_percentile_rule() -> None:
    """The partition shortcut is ``np.percentile``'s linear rule on the module's fixed draws."""
    from ros_margcal.model import heading

    cal = _cal()
    lam, vec = np.linalg.eigh(np.asarray(cal.covariance))
    for tilt in (0.0, 30.0):
        grad = heading_gradient(cal, attitudes(tilt), inclination=60.0)
        errors = np.abs(heading._TYPICAL_Z @ (grad @ (vec * np.sqrt(np.clip(lam, 0.0, None)))).T)
        assert heading_p95_typical(cal, tilt_deg=tilt) == pytest.approx(float(np.median(np.percentile(errors, 95, axis=1))), rel=1e-12)


@pytest.mark.parametrize("inclination", [90.0, -90.0])
def test_a_vertical_field_has_no_heading_and_says_so_without_a_warning(inclination: float) -> None:
    """At an inclination of 90 deg the field has no horizontal part: every heading figure is NaN ("not determined"),
    without numpy's divide-by-zero RuntimeWarning leaking to a user's console (``--set heading_inclination_deg=90``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(heading_p95(_cal(), inclination=inclination))
        assert np.isnan(heading_p95_typical(_cal(), tilt_deg=30.0, inclination=inclination))
