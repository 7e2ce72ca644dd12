"""The 95 % heading bound: it covers the heading error it bounds, and says "not determined" instead of a huge number."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from ros_margcal import Calibration
from ros_margcal.model.errors import InputError
from ros_margcal.model.fitting_core import unpack
from ros_margcal.model.fitting_prior import NAMES
from ros_margcal.model.heading import (
    UNDETERMINED_DEG,
    UNORDERED_SD_FACTOR,
    attitudes,
    format_bound,
    heading_p95,
    heading_p95_quantile,
    heading_p95_typical,
    inflated,
)

N = 48e-6
INC = math.radians(60.0)


def _cal(cov: np.ndarray) -> Calibration:
    w = np.array([[1.03, 0.02, -0.01], [0.02, 0.97, 0.015], [-0.01, 0.015, 1.01]])
    return Calibration(np.array([20e-6, -10e-6, 5e-6]), w, norm=N, covariance=cov, parameter_names=NAMES)


def _ring_like_cov(rng: np.random.Generator) -> np.ndarray:
    """A correlated covariance: small horizontal terms, large vertical ones (what a ring leaves)."""
    sd = np.r_[0.004 * N, 0.004 * N, 0.05 * N, 0.004, 0.004, 0.05, 0.003, 0.03, 0.03]
    a = rng.normal(size=(9, 9))
    corr = np.corrcoef(a @ a.T + 9 * np.eye(9))
    return corr * np.outer(sd, sd)


def _measured_p95(cal: Calibration, delta: np.ndarray, tilt: float) -> float:
    """p95 over the grid of the exact heading error of ``cal`` moved by ``delta`` (no linearisation, own atan2)."""
    rot = attitudes(tilt)
    m = cal.norm * np.array([0.0, math.cos(INC), -math.sin(INC)])
    raw = np.linalg.solve(cal.matrix, np.einsum("kji,j->ki", rot, m).T).T + cal.offset
    db, dw = unpack(delta, "sym")
    h = (raw - (cal.offset + db)) @ (cal.matrix + dw).T
    world = np.einsum("kij,kj->ki", rot, h)
    err = np.arctan2(world[:, 0], world[:, 1]) - math.atan2(m[0], m[1])
    return float(np.percentile(np.abs(np.degrees(np.angle(np.exp(1j * err)))), 95))


def _coverage(cal: Calibration, true_cov: np.ndarray, tilt: float, draws: int, seed: int,
              bound_of: Callable[..., float] = heading_p95_quantile) -> float:
    """Share of errors drawn from ``true_cov`` whose exact measured p95 is within ``cal``'s bound."""
    rng = np.random.default_rng(seed)
    bound = bound_of(cal, tilt_deg=tilt)
    deltas = rng.multivariate_normal(np.zeros(9), true_cov, size=draws)
    return float(np.mean([bound >= _measured_p95(cal, d, tilt) for d in deltas]))


@pytest.mark.parametrize("tilt", [0.0, 30.0])
def test_the_quantile_bound_of_a_right_covariance_covers_95_percent(tilt: float) -> None:
    """Errors drawn from C and measured exactly (own atan2, no linearisation): the quantile bound from C covers
    95 % (400 draws: +-1.1 % sd), neither less nor far more; from a covariance 3x too small in sd (slow noise
    counted as white) far less, and ``inflated`` by the factor restores it."""
    true_cov = _ring_like_cov(np.random.default_rng(3))
    right = _coverage(_cal(true_cov), true_cov, tilt, 400, seed=5)
    small = _cal(true_cov / UNORDERED_SD_FACTOR**2)
    under = _coverage(small, true_cov, tilt, 400, seed=5)
    fixed = _coverage(inflated(small, UNORDERED_SD_FACTOR), true_cov, tilt, 400, seed=5)
    assert 0.925 <= right <= 0.975
    assert under < 0.6
    assert 0.925 <= fixed <= 0.975


def test_two_error_directions_put_the_per_attitude_bound_below_95_percent() -> None:
    """Only b_x and b_y uncertain, level: the error is A cos(yaw + phi) with A Rayleigh, so 1.96 sd per attitude
    covers only 1 - exp(-1.96^2 / 2) = 85 %; the quantile bound (about 2.45 sd) covers 95 %."""
    cov = np.zeros((9, 9))
    cov[0, 0] = cov[1, 1] = (0.005 * N) ** 2
    cal = _cal(cov)
    per_attitude = _coverage(cal, cov, 0.0, 400, seed=9, bound_of=heading_p95)
    quantile = _coverage(cal, cov, 0.0, 400, seed=9)
    assert 0.80 <= per_attitude <= 0.90
    assert 0.925 <= quantile <= 0.975
    assert heading_p95_quantile(cal) / heading_p95(cal) == pytest.approx(math.sqrt(-2 * math.log(0.05)) / 1.96, rel=0.06)


def test_inflated_scales_both_figures_by_the_factor() -> None:
    """The bound and the typical figure scale linearly with the sd factor; a bad factor is refused."""
    cal = _cal(_ring_like_cov(np.random.default_rng(4)) * 0.01)
    big = inflated(cal, 2.5)
    assert heading_p95(big, tilt_deg=30.0) == pytest.approx(2.5 * heading_p95(cal, tilt_deg=30.0), rel=1e-9)
    assert heading_p95_typical(big, tilt_deg=0.0) == pytest.approx(2.5 * heading_p95_typical(cal, tilt_deg=0.0), rel=1e-3)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(InputError, match="sd_factor"):
            inflated(cal, bad)


@pytest.mark.parametrize("offset_sd_norms", [50.0, 1e6])
def test_an_undetermined_covariance_gives_not_determined_never_a_huge_number(offset_sd_norms: float) -> None:
    """Offset sd of many field norms: the first-order figure would be thousands of degrees; it is NaN and printed
    as "not determined"."""
    cov = np.diag(np.r_[np.full(3, offset_sd_norms * N), np.full(6, 0.01)] ** 2)
    cal = _cal(cov)
    assert math.isnan(heading_p95(cal, tilt_deg=0.0)) and math.isnan(heading_p95(cal, tilt_deg=30.0))
    assert math.isnan(heading_p95_typical(cal, tilt_deg=30.0))
    assert format_bound(heading_p95(cal, tilt_deg=0.0)) == "not determined"


def test_a_covariance_that_is_not_finite_is_not_determined() -> None:
    """A NaN or infinite entry: NaN, not an exception and not a number."""
    for bad in (math.nan, math.inf):
        cov = np.diag(np.r_[np.full(3, 0.01 * N), np.full(6, 0.005)] ** 2)
        cov[1, 1] = bad
        assert math.isnan(heading_p95(_cal(cov), tilt_deg=0.0))


@pytest.mark.parametrize(("value", "text"), [(0.5731, "0.57 deg"), (12.0, "12.00 deg"), (UNDETERMINED_DEG, "90.00 deg"),
                                             (90.01, "not determined"), (9845001.4, "not determined"),
                                             (math.nan, "not determined"), (math.inf, "not determined"),
                                             (None, "not determined")])
def test_format_bound(value: float | None, text: str) -> None:
    """The one formatter: degrees with two decimals, or "not determined"."""
    assert format_bound(value) == text
