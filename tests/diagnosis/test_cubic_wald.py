"""The ``residual_cubic`` stage's Wald test (``diagnosis.cubic``): with the residual's own noise model its null
is chi-square with 3 degrees of freedom whatever the noise's colour, where the plain F test reads slow noise on a
fast band as a cubic (issue 27: clean rough-motion recordings named ``nonlinearity``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ros_margcal.diagnosis.baseline_noise import ar1_noise
from ros_margcal.diagnosis.cubic import NULL_SD, cubic_feature, cubic_wald
from ros_margcal.diagnosis.fit_checks import closed_form_sym
from ros_margcal.diagnosis.stages import STAGE_FLOORS
from ros_margcal.model.fitting_noise import ar1_product

N = 3000
T = np.linspace(0.0, 60.0, N)


def _fast_band(seed: int, *, slow: float = 0.2, cubic: float = 0.0, drift: float = 0.0) -> np.ndarray:
    """Readings (field 48, offset 30) on a band of tilts (+-20 deg) turning fast (1.75 rad/s in yaw), neighbouring
    samples swapped (a vibrating platform), white noise 0.1, an AR(1) offset noise of std ``slow`` (per axis) and 5 s
    correlation time, a cubic ``k_i v_i^3 / 48^2`` of the whole reading (|k_i| = ``cubic``) and an offset drifting
    linearly by ``drift`` along x."""
    rng = np.random.default_rng(seed)
    yaw = 1.75 * T + rng.uniform(0, 2 * np.pi)
    tilt = np.deg2rad(20.0) * np.sin(1.5 * T + rng.uniform(0, 2 * np.pi))
    order = np.arange(N).reshape(-1, 2)
    swap = rng.random(order.shape[0]) < 0.5
    order[swap] = order[swap][:, ::-1]
    yaw, tilt = yaw[order.ravel()], tilt[order.ravel()]
    inc = np.deg2rad(-60.0) + tilt
    d = np.column_stack([np.cos(inc) * np.cos(yaw), np.cos(inc) * np.sin(yaw), np.sin(inc)])
    offset = 30.0 * np.array([0.6, -0.64, 0.48]) + np.outer(T / T[-1], [drift, 0.0, 0.0])
    v = offset + 48.0 * d + 0.1 * rng.normal(size=(N, 3))
    if slow > 0:
        v = v + ar1_noise(T, slow, 5.0, np.random.default_rng([seed, 1]))
    return v + cubic * np.array([1.0, -0.8, 0.6]) * v**3 / 48.0**2


def _feature(v: np.ndarray) -> float:
    return cubic_feature(v, closed_form_sym(v, 48.0), T)


def test_the_ar1_product_is_the_dense_ar1_correlation() -> None:
    """The two passes give ``K y`` with ``K_ij = phi^|i - j|`` (seeded)."""
    y = np.random.default_rng(2).normal(size=(40, 3))
    k = 0.93 ** np.abs(np.subtract.outer(np.arange(40), np.arange(40)))
    np.testing.assert_allclose(ar1_product(y, 0.93), k @ y, rtol=1e-12, atol=1e-12)


def test_null_is_a_normal_score_with_slow_noise_on_a_fast_band() -> None:
    """Clean sensors with slow noise on a fast, vibrating band (30 seeds): the feature's mean and spread are those of
    N(0, 1) within sampling error, the stage's floor is that spread, and no seed reaches 3.5 (the same score of
    the white-noise test, the plain F test's: mean 1.2, up to 5.5 on these seeds)."""
    feats = np.array([_feature(_fast_band(seed)) for seed in range(30)])
    assert abs(float(feats.mean())) < 0.6, f"mean {feats.mean():.3f}"
    assert 0.6 < float(feats.std(ddof=1)) < 1.5, f"sd {feats.std(ddof=1):.3f}"
    assert float(feats.max()) < 3.5, f"max {feats.max():.3f}"
    assert STAGE_FLOORS["residual_cubic"] == (NULL_SD,)


@pytest.mark.parametrize("seed", [1, 2])
def test_a_cubic_stands_out_and_a_drift_does_not(seed: int) -> None:
    """The same band: a 2 % cubic of the whole reading lies far outside the null, even under slow noise five times
    the white noise's variance; an offset drifting by 1 % of the field over the recording (a residual that varies
    in time) does not pass for a cubic."""
    cubic = _feature(_fast_band(seed, cubic=0.02))
    drift = _feature(_fast_band(seed, drift=0.5))
    assert cubic > 4.5, f"cubic {cubic:.3g}"
    assert drift < 3.0, f"drift {drift:.3g}"


def test_without_time_or_slow_noise_the_test_is_the_white_noise_one() -> None:
    """No time span (all stamps equal): white noise only, a finite chi-square of about 3 on clean readings; too few
    points or no ``sym`` fit: NaN."""
    v = _fast_band(5, slow=0.0)
    cal = closed_form_sym(v, 48.0)
    wald = cubic_wald(v, cal, np.zeros(N))
    assert math.isfinite(wald) and 0.0 <= wald < 20.0
    assert abs(cubic_wald(v, cal, T) - wald) < 0.5 * wald + 3.0  # the slow part fitted on white noise is ~0
    assert math.isnan(cubic_wald(v[:40], cal, T[:40]))
    assert math.isnan(cubic_feature(v, None, T))
