"""Tests of ros_margcal.baselines: the coverage gates of MotionCal, Android, ArduPilot and NXP."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import DegenerateDataError, InputError
from ros_margcal.validation.baselines import (
    BASELINES,
    android_eigen_ratio,
    ardupilot_fitness,
    baseline_scores,
    motioncal_gap_error,
    motioncal_region,
    nxp_bin_fill,
)


def _sphere(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _cap(rng: np.random.Generator, n: int, half_deg: float) -> np.ndarray:
    z = rng.uniform(np.cos(np.radians(half_deg)), 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z**2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def test_motioncal_regions_have_equal_area(rng: np.random.Generator) -> None:
    """The 100 MotionCal regions each hold about 1 % of uniformly drawn directions."""
    counts = np.bincount(motioncal_region(_sphere(rng, 200_000)), minlength=100)
    assert counts.size == 100
    frac = counts / counts.sum()
    assert np.all(np.abs(frac - 0.01) < 0.0015)
    assert motioncal_region([[0, 0, 1]])[0] == 0 and motioncal_region([[0, 0, -1]])[0] == 99


def test_motioncal_gap_error_values(rng: np.random.Generator) -> None:
    """Full coverage scores near 0, a 30° cap (6.7 % of the sphere) above 80, and the per-region weights are 1 / 0.2 / 0.01."""
    assert motioncal_gap_error(_sphere(rng, 3000)) < 1.0
    assert motioncal_gap_error(_cap(rng, 500, 30.0)) > 80.0
    north = np.array([[0.0, 0.0, 1.0]])
    assert motioncal_gap_error(north) == pytest.approx(99.2)
    assert motioncal_gap_error(np.repeat(north, 2, axis=0)) == pytest.approx(99.01)
    assert motioncal_gap_error(np.repeat(north, 3, axis=0)) == pytest.approx(99.0)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31), st.floats(0.01, 1e3), st.floats(-1e3, 1e3))
def test_motioncal_gap_is_relative_to_the_centre(seed: int, scale: float, shift: float) -> None:
    """Scaling the samples and moving samples and centre together leave the gap error unchanged."""
    rng = np.random.default_rng(seed)
    p = _sphere(rng, 150)
    c = np.array([shift, -shift / 2, 3.0])
    assert motioncal_gap_error(p * scale + c, c) == pytest.approx(motioncal_gap_error(p))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31), st.floats(-1e3, 1e3))
def test_android_eigen_ratio_invariant_to_pose(seed: int, shift: float) -> None:
    """The covariance eigenvalue ratio does not change under translation and rotation."""
    rng = np.random.default_rng(seed)
    p = _cap(rng, 200, 70.0) * np.array([1.0, 1.3, 0.9])
    rot = Rotation.random(random_state=seed % 1000).as_matrix()
    assert android_eigen_ratio(p @ rot.T + shift) == pytest.approx(android_eigen_ratio(p), rel=1e-6)


def test_android_eigen_ratio_values(rng: np.random.Generator) -> None:
    """Isotropic samples give a ratio near 1, a thin band a large one; too few samples are refused."""
    assert android_eigen_ratio(_sphere(rng, 5000)) < 1.2
    band = _sphere(rng, 2000)
    band[:, 2] *= 0.05
    assert android_eigen_ratio(band) > 100
    with pytest.raises(DegenerateDataError, match="at least 4"):
        android_eigen_ratio(band[:3])


def test_ardupilot_fitness_measures_relative_residual(rng: np.random.Generator, true_cal: Calibration) -> None:
    """Exact samples have zero fitness; isotropic noise of std s gives about s relative."""
    h = _sphere(rng, 4000) * true_cal.norm
    raw = true_cal.inverse_apply(h)
    assert ardupilot_fitness(raw, true_cal) < 1e-12
    noisy = true_cal.inverse_apply(h + rng.normal(size=h.shape) * 0.01 * true_cal.norm)
    assert ardupilot_fitness(noisy, true_cal) == pytest.approx(0.01, rel=0.1)


def test_nxp_bin_fill_values(rng: np.random.Generator) -> None:
    """Dense full coverage fills nearly all 392 bins, a cap few; never more than 14 x 28."""
    full = nxp_bin_fill(_sphere(rng, 20_000))
    assert 380 <= full <= 392
    assert nxp_bin_fill(_cap(rng, 2000, 20.0)) < 80
    c = np.array([5.0, -2.0, 1.0])
    p = _sphere(rng, 300)
    assert nxp_bin_fill(p + c, c) == nxp_bin_fill(p)
    with pytest.raises(InputError):
        nxp_bin_fill(np.zeros((2, 2)))


def test_baseline_scores_and_orientation(rng: np.random.Generator, true_cal: Calibration) -> None:
    """Every registered baseline is scored, and full coverage outscores a cap on each oriented score."""
    full = true_cal.inverse_apply(_sphere(rng, 1500) * true_cal.norm)
    cap = true_cal.inverse_apply(_cap(rng, 1500, 35.0) * true_cal.norm)
    s_full, s_cap = baseline_scores(full, true_cal), baseline_scores(cap, true_cal)
    assert set(s_full) == set(BASELINES)
    for name in ("motioncal_gap", "android_eigen_ratio", "nxp_bin_fill"):
        b = BASELINES[name]
        assert b.oriented(s_full[name]) > b.oriented(s_cap[name]), name
        assert bool(b.accept(s_full[name])) and not bool(b.accept(s_cap[name])), name
