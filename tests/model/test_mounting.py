"""The magnetometer's mounting against the IMU from the gyro (``model.mounting``), on the independent generator
(tests/independent: no code shared with the package), with a gyro with data-sheet errors (3 % scale errors)."""

from __future__ import annotations

import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from ros_margcal.model import mounting as mt
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.calibration_file import load_calibrations, save_calibrations
from ros_margcal.model.errors import InputError
from ros_margcal.model.fitting_gyro import gyro_blocks, gyro_residuals, rotated_blocks, turning_share
from ros_margcal.model.mounting import ROTATIONS, axis_angle, find_mounting, into_imu_frame, rotation_name, rotvec


def _rec(independent: ModuleType, motion: str, k: int, mis: float, seed: int, seconds: float, tilt: float = 5.0) -> dict:
    return independent.generate("mag", motion, duration_s=seconds, rate_hz=50.0, seed=seed, tilt_deg=tilt,
                                gyro_scale=0.03, symmetric_soft_iron=True, mag_mount=ROTATIONS[k],
                                mag_mount_misalign_deg=mis)


def _blocks(rec: dict, gyro: np.ndarray | None = None) -> mt.GyroBlocks:
    return gyro_blocks(rec["t"], rec["xyz"], rec["gyro"] if gyro is None else gyro, 50)


def test_the_24_rotations_are_proper_distinct_and_named() -> None:
    """24 distinct proper rotations, the identity first; axis_angle inverts rotvec; names say where each axis goes."""
    assert len(ROTATIONS) == 24 and np.allclose(ROTATIONS[0], np.eye(3))
    assert all(abs(np.linalg.det(r) - 1.0) < 1e-12 for r in ROTATIONS)
    assert len({tuple(r.round().astype(int).ravel()) for r in ROTATIONS}) == 24
    for r in ROTATIONS:
        assert np.allclose(rotvec(axis_angle(r)), r, atol=1e-9)
    assert rotation_name(np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])) == "x->-y, y->x, z->z (90 deg about -z)"


def test_the_lean_residual_is_gyro_residuals_and_its_jacobian_the_derivative(independent: ModuleType) -> None:
    """The residual under a rotation is ``gyro_residuals`` of the turned rates; its Jacobian over a small turn
    ``r exp([eps]x)``, the bias, the scale errors and the rates' time offset matches central differences."""
    rec = _rec(independent, "tumble", 7, 3.0, 4, 20.0)
    tr = rec["truth"]
    blocks = _blocks(rec)
    r = ROTATIONS[7] @ rotvec([0.01, -0.02, 0.015])
    p = np.r_[tr["gyro_bias"], 0.01, -0.02, 0.0, 0.0]
    pre = mt._pre(blocks, tr["offset"], tr["W_sym"])
    res = mt._lean(pre, r, p)[0]
    want = gyro_residuals(rotated_blocks(blocks, r.T), tr["offset"], tr["W_sym"], p[:3], p[3:6])[0]
    assert np.allclose(res, want, rtol=0.0, atol=1e-12 * np.max(np.abs(want)))
    p[6] = 0.008  # the rates 8 ms late
    _, jt = mt._lean(pre, r, p)
    for i in range(10):
        h = 1e-6 if i < 3 else 1e-7
        e = np.zeros(10)
        e[i] = h

        def at(x: np.ndarray) -> np.ndarray:
            return mt._lean(pre, r @ rotvec(x[:3]), p + x[3:])[0]

        num = (at(e) - at(-e)) / (2 * h)
        assert np.max(np.abs(num - jt[i])) <= 1e-5 * np.max(np.abs(num)), i


@pytest.mark.parametrize(("k", "mis", "seed"), [(9, 3.0, 5), (17, 0.0, 6)])
def test_a_tumble_finds_the_rotation_and_the_misalignment_within_its_sd(independent: ModuleType, k: int, mis: float,
                                                                      seed: int) -> None:
    """A 30 s tumble: the true axis-aligned rotation, decided; the misalignment's error within 4 predicted sds."""
    rec = _rec(independent, "tumble", k, mis, seed, 30.0)
    tr = rec["truth"]
    m = find_mounting(_blocks(rec), tr["offset"], tr["W_sym"])
    assert m.rotation is not None and np.allclose(m.rotation, ROTATIONS[k]), m.reason
    assert m.chi2 >= mt.DECIDE_CHI2 and m.explained >= 0.99
    e = axis_angle(m.full_rotation.T @ tr["R_to_imu"])
    assert np.all(np.abs(e) <= 4.0 * np.sqrt(np.diag(m.covariance))), (e, np.sqrt(np.diag(m.covariance)))
    assert abs(m.misalignment_deg - mis) < 1.0
    assert "fix the static transform" in m.message() or k == 0


def test_a_pure_yaw_turn_names_the_axis_and_leaves_the_rest_undecided(independent: ModuleType) -> None:
    """A robot turning in yaw alone (no roll or pitch) fixes only which magnetometer axis is vertical: said, not guessed."""
    k = 14
    rec = _rec(independent, "ground", k, 0.0, 3, 30.0, tilt=0.0)
    tr = rec["truth"]
    m = find_mounting(_blocks(rec), tr["offset"], tr["W_sym"])
    assert m.rotation is None and m.turn_axis == "z"
    along = mt._axis_name(ROTATIONS[k].T[:, 2])
    assert f"the magnetometer's {along} lies along it" in m.reason, m.reason
    assert "not determined" in m.message("imu_link")


def test_a_mirrored_axis_is_a_wiring_fault_not_a_rotation(independent: ModuleType) -> None:
    """A magnetometer axis negated by the driver (a left-handed frame): named as a mirror image, no rotation."""
    rec = _rec(independent, "tumble", 0, 0.0, 7, 20.0)
    tr = rec["truth"]
    flipped = rec["gyro"] * np.array([1.0, 1.0, -1.0])  # the same as the magnetometer's z negated, seen from the gyro
    m = find_mounting(_blocks(rec, flipped), tr["offset"], tr["W_sym"])
    assert m.rotation is None and m.mirror == "x->x, y->y, z->-z"
    assert "wiring or sign fault" in m.message()


def test_rates_of_another_motion_fit_no_rotation_and_few_blocks_decide_nothing(independent: ModuleType) -> None:
    """Rates that have nothing to do with the field's turning: "no axis-aligned rotation fits"; 19 blocks: too few."""
    rec = _rec(independent, "tumble", 0, 0.0, 8, 20.0)
    other = _rec(independent, "tumble", 0, 0.0, 9, 20.0)
    tr = rec["truth"]
    m = find_mounting(_blocks(rec, other["gyro"]), tr["offset"], tr["W_sym"])
    assert m.rotation is None and "no axis-aligned rotation fits" in m.reason
    few = gyro_blocks(rec["t"][:950], rec["xyz"][:950], rec["gyro"][:950], 50)
    assert "fewer than 20" in find_mounting(few, tr["offset"], tr["W_sym"]).reason


@pytest.mark.parametrize(("factor", "named"), [(math.pi / 180.0, "57.3x larger: the rates converted from deg/s to rad/s twice?"),
                                               (180.0 / math.pi, "57.3x smaller: the rates in deg/s, not rad/s (REP-103)?")])
def test_rates_in_the_wrong_unit_are_named_under_the_rotation_that_fits(independent: ModuleType, factor: float,
                                                                       named: str) -> None:
    """A tumble's rates 57.3x off (a driver converting deg/s twice, or not at all), on a magnetometer mounted rotated:
    no rotation fits them as they come, and the reason names the unit and the rotation under which they explain the
    turning (it read "the best explains 4.7 %" and no more; 57.3x too large: "-304702 %")."""
    k = 9
    rec = _rec(independent, "tumble", k, 0.0, 11, 20.0)
    tr = rec["truth"]
    m = find_mounting(_blocks(rec, rec["gyro"] * factor), tr["offset"], tr["W_sym"])
    assert m.rotation is None and "no axis-aligned rotation fits" in m.reason
    assert f"under {rotation_name(ROTATIONS[k])}, taken {named}" in m.reason, m.reason
    assert ("none of the field's turning (misfit" in m.reason) == (factor > 1.0), m.reason
    right = find_mounting(_blocks(rec), tr["offset"], tr["W_sym"])
    assert right.rotation is not None and np.allclose(right.rotation, ROTATIONS[k]), right.reason


def test_a_negative_share_reads_none_with_its_misfit() -> None:
    """``turning_share``: a share as a status prints it, a negative one as "none" with the misfit's size."""
    assert turning_share(0.8974) == "89.7 % of the field's turning"
    assert turning_share(0.03, 0) == "3 % of the field's turning"
    assert turning_share(-3047.0) == "none of the field's turning (misfit 55x the turning)"
    assert turning_share(-0.12) == "none of the field's turning (misfit 1.1x the turning)"


def test_into_imu_frame_turns_the_output_and_survives_the_file(independent: ModuleType, tmp_path: Path) -> None:
    """``W`` becomes ``R W``: the output is the field in the IMU's frame; the calibration file keeps it."""
    k = 5
    rec = _rec(independent, "tumble", k, 2.0, 10, 30.0)
    tr = rec["truth"]
    m = find_mounting(_blocks(rec), tr["offset"], tr["W_sym"])
    cal = Calibration(tr["offset"], tr["W_sym"], norm=tr["norm"], sensor="mag", unit="T")
    imu = into_imu_frame(cal, m)
    h_imu = imu.apply(rec["xyz"][:100])
    assert np.allclose(h_imu, cal.apply(rec["xyz"][:100]) @ m.full_rotation.T)
    truth_imu = cal.apply(rec["xyz"][:100]) @ tr["R_to_imu"].T
    worst = np.degrees(np.max(np.arccos(np.clip(np.sum(h_imu * truth_imu, 1) / (np.linalg.norm(h_imu, axis=1)
                                                                              * np.linalg.norm(truth_imu, axis=1)), -1, 1))))
    assert worst < 4.0 * m.misalignment_sd_deg + 0.05, worst
    back = load_calibrations(save_calibrations(tmp_path / "cal.yaml", {"mag": imu}))["mag"]
    assert np.allclose(back.matrix, imu.matrix, rtol=1e-9) and np.allclose(back.offset, imu.offset)
    with pytest.raises(InputError, match="no mounting rotation decided"):
        into_imu_frame(cal, mt.Mounting(None, "", reason="too few"))
    assert math.isfinite(m.misalignment_sd_deg)


def test_a_tumbles_misalignment_sd_is_honest(independent: ModuleType) -> None:
    """20 seeded 30 s tumbles (random rotation, 0-5 deg misalignment), the true calibration held: the rms of the
    misalignment error's components in predicted sds is near 1 (0.97; 1.21 with the least squares' sd alone, which
    the jackknife's corrects: ``JACKKNIFE_CHUNKS``)."""
    z = []
    for seed in range(20):
        k, mis = (7 * seed + 3) % 24, float(seed % 6)
        rec = _rec(independent, "tumble", k, mis, 700 + seed, 30.0)
        tr = rec["truth"]
        m = find_mounting(_blocks(rec), tr["offset"], tr["W_sym"])
        assert m.rotation is not None and np.allclose(m.rotation, ROTATIONS[k]), m.reason
        z.extend(axis_angle(m.full_rotation.T @ tr["R_to_imu"]) / np.sqrt(np.diag(m.covariance)))
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.75 <= rms <= 1.12, rms
