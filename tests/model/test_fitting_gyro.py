"""The gyro-aided magnetometer fit (``model.fitting_gyro``): its residual and Jacobian, its blocks, and the
MAP fit with it, on the independent generator (tests/independent: no code shared with the package)."""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.model import fitting_geometric as fg
from ros_margcal.model.errors import InputError
from ros_margcal.model.fitting_gyro import MIN_EXPLAINED, explained, gyro_blocks, gyro_residuals
from ros_margcal.model.fitting_prior import broad_prior, fit_with_prior


def _ground(independent: ModuleType, seed: int, tilt: float, seconds: float) -> dict:
    return independent.generate("mag", "ground", duration_s=seconds, rate_hz=50.0, seed=seed, tilt_deg=tilt,
                                symmetric_soft_iron=True, hard_iron_mag=30e-6)


def _sym(p: np.ndarray) -> np.ndarray:
    return np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])


def test_the_jacobian_is_the_residuals_derivative(independent: ModuleType) -> None:
    rec = _ground(independent, 5, 20.0, 30.0)
    tr = rec["truth"]
    blocks = gyro_blocks(rec["t"], rec["xyz"], rec["gyro"], 10)
    w = tr["W_sym"]
    rng = np.random.default_rng(3)
    th = np.r_[tr["offset"], w[0, 0], w[1, 1], w[2, 2], w[0, 1], w[0, 2], w[1, 2], tr["gyro_bias"], 0.0, 0.0, 0.0]
    th = th + rng.normal(0.0, 1e-3, 15) * np.r_[[1e-5] * 3, [1.0] * 12] + np.r_[[0.0] * 12, 0.02, -0.01, 0.03]

    def f(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return gyro_residuals(blocks, p[:3], _sym(p[3:9]), p[9:12], p[12:15])

    _, jt = f(th)
    assert jt.shape == (15, 3 * len(blocks))
    for i in range(15):
        h = 1e-12 if i < 3 else 1e-7
        e = np.zeros(15)
        e[i] = h
        num = (f(th + e)[0] - f(th - e)[0]) / (2 * h)
        assert np.max(np.abs(num - jt[i])) <= 1e-6 * np.max(np.abs(num)), i


def test_at_the_truth_the_residuals_are_noise_and_a_wrong_frame_explains_little(independent: ModuleType) -> None:
    rec = _ground(independent, 5, 5.0, 60.0)
    tr = rec["truth"]
    blocks = gyro_blocks(rec["t"], rec["xyz"], rec["gyro"], 50)  # 1 s blocks, the stream's
    r, _ = gyro_residuals(blocks, tr["offset"], tr["W_sym"], tr["gyro_bias"], np.zeros(3))
    white = rec["meta"]["noise"]["white"]
    assert np.sqrt(np.mean(r * r)) < 2.0 * np.sqrt(2.0) * white  # two samples' white noise, and the gyro's
    assert explained(blocks, r) > 0.99
    swapped = gyro_blocks(rec["t"], rec["xyz"], rec["gyro"][:, [1, 0, 2]] * [1.0, -1.0, 1.0], 50)
    r_sw, _ = gyro_residuals(swapped, tr["offset"], tr["W_sym"], tr["gyro_bias"], np.zeros(3))
    assert explained(swapped, r_sw) < MIN_EXPLAINED


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), rate=st.floats(0.05, 2.0), soft=st.floats(0.0, 0.2))
def test_noise_free_rotation_leaves_no_residual(seed: int, rate: float, soft: float) -> None:
    """Property: a constant field seen by a sensor turning at any rate, through any symmetric soft iron, hard
    iron, gyro bias and gyro scale errors, leaves residuals at the trapezoid rule's error only (far below the
    field's change)."""
    rng = np.random.default_rng(seed)
    n, dt = 400, 0.01
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    omega = rate * axis + 0.3 * rate * np.sin(np.arange(n) * dt * 2.0)[:, None] * rng.normal(size=3)
    field = rng.normal(size=3) * 30.0
    c = np.empty((n, 3))
    c[0] = field
    for k in range(1, n):  # dc/dt = -omega x c, integrated finely (Rodrigues on each half step of 10 sub-steps)
        v = c[k - 1]
        for j in range(10):
            w = omega[k - 1] + (omega[k] - omega[k - 1]) * (j + 0.5) / 10.0
            ang = -w * dt / 10.0
            a = np.linalg.norm(ang)
            ax = ang / a
            v = v * np.cos(a) + np.cross(ax, v) * np.sin(a) + ax * (ax @ v) * (1 - np.cos(a))
        c[k] = v
    a_soft = rng.uniform(-soft, soft, (3, 3))
    w_mat = np.eye(3) + 0.5 * (a_soft + a_soft.T)
    b = rng.normal(size=3) * 20.0
    beta = rng.normal(size=3) * 0.02
    kappa = rng.uniform(-0.05, 0.05, 3)
    raw = c @ np.linalg.inv(w_mat).T + b
    blocks = gyro_blocks(np.arange(n) * dt, raw, (omega + beta) / (1.0 + kappa), 10)  # true = (1 + kappa) meas - beta
    r, _ = gyro_residuals(blocks, b, w_mat, beta, kappa)
    assert np.sqrt(np.mean(r * r)) <= 1e-3 * np.sqrt(np.mean(blocks.d * blocks.d))


def test_blocks_drop_gaps_and_samples_without_a_rate() -> None:
    t = np.arange(100) * 0.02
    xyz = np.ones((100, 3))
    rate = np.zeros((100, 3))
    assert len(gyro_blocks(t, xyz, rate, 10)) == 10
    rate[15] = np.nan  # block 1 has a sample without a rate
    t2 = t.copy()
    t2[45:] += 1.0  # a gap inside block 4 ... (index 44 -> 45)
    t2[75] = t2[74]  # ... and a repeated stamp inside block 7
    got = gyro_blocks(t2, xyz, rate, 10)
    assert len(got) == 7
    assert len(gyro_blocks(t[:5], xyz[:5], rate[:5], 10)) == 0
    with pytest.raises(InputError):
        gyro_blocks(t, xyz[:50], rate, 10)
    with pytest.raises(InputError):
        gyro_blocks(t, xyz, rate, 1)


def test_the_gyro_fixes_what_a_ring_leaves_to_the_prior(independent: ModuleType) -> None:
    """A 5 deg ring: without the gyro the vertical gain keeps the prior and the heading at 30 deg tilt is
    the prior's; with it every parameter is updated and the 30 deg heading error falls several-fold."""
    rec = _ground(independent, 22, 5.0, 150.0)
    tr = rec["truth"]
    pts, spread = fg.block_means(rec["xyz"][: len(rec["xyz"]) // 10 * 10], 10)
    prior = broad_prior(pts, float(np.linalg.norm(tr["field"])))
    alone = fit_with_prior(pts, prior, time_ordered=True, spread=spread)
    aided = fit_with_prior(pts, prior, time_ordered=True, spread=spread,
                           gyro=gyro_blocks(rec["t"], rec["xyz"], rec["gyro"], 50))
    assert "w_zz" in alone.from_prior and not alone.gyro_used
    assert aided.gyro_used and aided.gyro_explained >= MIN_EXPLAINED and aided.from_prior == ()
    np.testing.assert_allclose(aided.gyro_bias[:2], tr["gyro_bias"][:2], atol=2e-3)  # the z bias: barely seen in yaw
    assert abs(aided.gyro_scale[2]) < 0.005  # the generator's gyro has no scale error; yaw fixes the z axis's

    def p95(fit: object, tilt: float) -> float:
        c = fit.calibration  # type: ignore[attr-defined]
        return float(independent.heading_p95(c.matrix, c.offset, tr, tilt_deg=tilt))

    assert p95(aided, 30.0) < 0.3 * p95(alone, 30.0)
    assert p95(aided, 30.0) < 1.5
    assert p95(aided, 0.0) < 1.0


def test_a_gyro_in_another_frame_is_not_used(independent: ModuleType) -> None:
    rec = _ground(independent, 22, 5.0, 60.0)
    pts, spread = fg.block_means(rec["xyz"][: len(rec["xyz"]) // 10 * 10], 10)
    prior = broad_prior(pts, float(np.linalg.norm(rec["truth"]["field"])))
    alone = fit_with_prior(pts, prior, time_ordered=True, spread=spread)
    other = gyro_blocks(rec["t"], rec["xyz"], rec["gyro"][:, [1, 0, 2]] * [1.0, -1.0, 1.0], 50)
    wrong = fit_with_prior(pts, prior, time_ordered=True, spread=spread, gyro=other)
    assert not wrong.gyro_used and wrong.gyro_explained < MIN_EXPLAINED
    np.testing.assert_array_equal(wrong.calibration.offset, alone.calibration.offset)
    np.testing.assert_array_equal(wrong.calibration.matrix, alone.calibration.matrix)


def test_a_bad_scale_prior_is_refused() -> None:
    pts = np.random.default_rng(1).normal(size=(50, 3))
    prior = broad_prior(pts, 1.0)
    for bad in (0.0, -0.1, float("nan"), float("inf")):
        with pytest.raises(InputError):
            fit_with_prior(pts, prior, gyro_scale_std=bad)
