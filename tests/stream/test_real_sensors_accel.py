"""Real-sensor accelerometers in the stream: a noisy MEMS part, raw unsigned ADC counts, the shared recordings."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from ros_margcal.coverage.gate import InactivityGate
from ros_margcal.model.calibration import Calibration
from ros_margcal.recordings.read import read_recording
from ros_margcal.stream.calibrator import SensorCalibrator, State
from ros_margcal.stream.config import PipelineConfig, plausibility
from ros_margcal.stream.intake import Intake
from ros_margcal.stream.replay import replay

G = 9.80665
RATE = 100.0


def _poses(rng: np.random.Generator, n_poses: int, rest_s: float = 4.0, move_s: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """Times and true specific force (in g) of a body held in ``n_poses`` random poses, turned smoothly between."""
    rots = Rotation.random(n_poses, random_state=rng.integers(1 << 31))
    t, f = [], []
    t0 = 0.0
    for k in range(n_poses):
        n_rest = int(rest_s * RATE)
        t.append(t0 + np.arange(n_rest) / RATE)
        f.append(np.tile(rots[k].inv().apply([0.0, 0.0, 1.0]), (n_rest, 1)))
        t0 += n_rest / RATE
        if k + 1 < n_poses:
            n_move = int(move_s * RATE)
            s = np.arange(n_move) / n_move
            ease = 0.5 - 0.5 * np.cos(np.pi * s)  # starts and ends at rest
            turn = Slerp([0.0, 1.0], Rotation.concatenate([rots[k], rots[k + 1]]))(ease)
            hand = 0.05 * np.sin(2 * np.pi * s)[:, None] * rng.normal(size=3)  # the hand's own push, g
            t.append(t0 + np.arange(n_move) / RATE)
            f.append(turn.inv().apply([0.0, 0.0, 1.0]) + hand)
            t0 += n_move / RATE
    return np.concatenate(t), np.concatenate(f)


def _mems(rng: np.random.Generator, noise_g: float = 6e-3) -> tuple[np.ndarray, np.ndarray, Calibration]:
    """A MEMS accelerometer at 2x Gietzelt's noise (6e-3 g white per axis, 100 Hz), gain errors of a few %, 0.05 g
    bias, 16 poses: its times, raw readings in g and the truth (h = W (raw - b))."""
    t, f = _poses(rng, 16)
    gains = np.diag([1.03, 0.97, 1.02])
    cross = np.array([[0.0, 0.01, -0.005], [0.01, 0.0, 0.008], [-0.005, 0.008, 0.0]])
    k = gains + cross  # raw = K h + b
    bias = np.array([0.05, -0.03, 0.04])
    raw = f @ k.T + bias + rng.normal(scale=noise_g, size=f.shape)
    return t, raw, Calibration(bias, np.linalg.inv(k), norm=1.0, sensor="accel", unit="g")


def _run(cal: SensorCalibrator, t: np.ndarray, raw: np.ndarray) -> float | None:
    """Feed the stream; the time of the first calibration (None if none)."""
    first = None
    for ti, v in zip(t, raw, strict=True):
        cal.push(float(ti), v)
        if first is None and cal.calibration is not None:
            first = float(ti)
    return first


def test_a_mems_accelerometer_at_twice_gietzelts_noise_calibrates_from_still_poses() -> None:
    """6e-3 g per axis (Gietzelt's CV 3e-3 x 2): the gate learns the rest noise, finds the poses, the fit is right."""
    t, raw, truth = _mems(np.random.default_rng(61))
    cal = SensorCalibrator("accel", PipelineConfig.for_sensor("accel", "g"))
    first = _run(cal, t, raw)
    st = cal.status()
    assert st.state is State.CALIBRATED, st.message
    assert first is not None and first < t[-1]
    fitted = cal.calibration
    assert fitted is not None
    assert np.linalg.norm(fitted.offset - truth.offset) < 0.01, fitted.offset  # g
    cv, axis = cal._gate.thresholds
    assert 3e-3 < axis <= 1e-2 and cv <= 1e-2  # widened, within the cap
    # a still pose's calibrated norm is 1 g within the noise of a window mean
    check = cal.calibration.apply(truth.inverse_apply(np.eye(3)))
    assert np.abs(np.linalg.norm(check, axis=1) - 1.0).max() < 5e-3


def test_the_gate_learns_but_still_refuses_a_move() -> None:
    """The learnt gate emits nothing during the moves of the MEMS stream: every emitted mean is a pose's."""
    t, raw, truth = _mems(np.random.default_rng(62))
    gate = InactivityGate(learn=True)
    out = [e for e in (gate.push(ti, v) for ti, v in zip(t, raw, strict=True)) if e is not None]
    assert len(out) >= 14
    norms = np.linalg.norm(truth.apply(np.array(out)), axis=1)
    assert np.abs(norms - 1.0).max() < 5e-3, norms  # a mean over a move would be off by the hand's push


def test_raw_unsigned_counts_calibrate() -> None:
    """An unsigned 16-bit ADC (mid-scale 32768, 1 g = 16384 counts): the offset guard in counts lets it through."""
    rng = np.random.default_rng(63)
    t, f = _poses(rng, 16)
    k = np.diag([16384 * 1.02, 16384 * 0.98, 16384 * 1.01])
    raw = f @ k.T + np.array([32768.0, 32768.0 + 300.0, 32768.0 - 200.0]) + rng.normal(scale=40.0, size=f.shape)
    cal = SensorCalibrator("accel", PipelineConfig.for_sensor("accel", "counts"))
    _run(cal, t, raw)
    st = cal.status()
    assert st.state is State.CALIBRATED, st.message
    assert cal.calibration is not None
    assert np.allclose(cal.calibration.offset, [32768.0, 33068.0, 32568.0], atol=50.0)


def test_an_accelerometer_offset_is_refused_in_its_own_words() -> None:
    """The accelerometer's offset guard speaks of bias and gravity norms, never of hard iron, and says how to raise it."""
    cfg = PipelineConfig.for_sensor("accel", "g")
    why = plausibility(Calibration(np.array([0.5, 0.0, 0.0]), np.eye(3), norm=1.0, sensor="accel", unit="g"), cfg)
    assert "bias" in why and "gravity norms" in why and "hard iron" not in why
    assert "--set max_offset_ratio=" in why and "accel.max_offset_ratio" in why
    assert "0.5 gravity norms" in why


def test_the_uncertainty_message_shows_enough_digits() -> None:
    """"std of b_x is 1 % > 1 %" cannot happen: three significant digits on both sides."""
    cfg = PipelineConfig.for_sensor("mag", "uT", max_parameter_std=0.0104)
    cal = Calibration(np.zeros(3), np.eye(3), norm=50.0, sensor="mag", unit="uT", parameter_names=("b_x",),
                      covariance=np.array([[(0.0106 * 50.0) ** 2]]))  # b_x std 1.06 % of the radius
    why = plausibility(cal, cfg)
    assert "std of b_x is 1.06 % > 1.04 %" in why, why


def test_zero_rows_are_called_zero_rows_and_counted_once() -> None:
    """All-zero rows: dropped as ``zero`` once each and called so, never "last |v| = 0 > limit"."""
    intake = Intake(PipelineConfig.for_sensor("mag", "T"))
    for i in range(5):
        intake.take(float(i), (0.0, 0.0, 0.0))
    intake.take(5.0, (1.0, 0.0, 0.0))  # 1 T: above the limit
    for i in range(6, 9):
        intake.take(float(i), (0, 0, 0))
    assert intake.dropped["zero"] == 8 and intake.dropped["magnitude"] == 1 and intake.zero_rows == 8
    summary = intake.drop_summary()
    assert "8 all-zero rows" in summary and "|v| = 0 " not in summary, summary


def _replay(path: Path) -> SensorCalibrator:
    return replay(path, sensor="accel", unit="g", status_every=0.0, progress=False)["calibrators"]["accel"]


def test_the_lsm9ds1_static_poses_calibrate(real_recording: Callable[[str], Path]) -> None:
    """ck_lsm9ds1_static_poses_acc: 160 poses of 100 samples back to back; each fits one 2 s window, and they calibrate."""
    cal = _replay(real_recording("ck_lsm9ds1_static_poses_acc.csv"))
    st = cal.status()
    assert st.state is State.CALIBRATED, st.message
    assert cal.kept >= 60
    assert cal.calibration is not None and abs(cal.calibration.raw_radius - 1.0) < 0.05


@pytest.mark.parametrize("name", ["sunsided_mpu6050_unmoved-with-x-pointing-forward_acc.csv",
                                  "sunsided_mpu6050_unmoved-with-z-pointing-front-and-x-up_acc.csv",
                                  "sunsided_mpu6050_unmoved-with-z-pointing-front-and-y-down_acc.csv"])
def test_an_mpu6050_on_a_desk_is_still(real_recording: Callable[[str], Path], name: str) -> None:
    """The MPU6050 at rest (4-5e-3 g per axis) is found still by the learning gate, not by Gietzelt's fixed one."""
    rec = read_recording(real_recording(name), sensor="accel")
    learnt, fixed = InactivityGate(learn=True), InactivityGate()
    for t, v in zip(rec.t, rec.raw, strict=True):
        learnt.push(t, v)
        fixed.push(t, v)
    assert learnt.counters["emitted"] >= 40
    assert fixed.counters["emitted"] == 0
    assert "learnt from" in learnt.learnt


def test_the_mpu6050_full_sphere_move_is_not_still(real_recording: Callable[[str], Path]) -> None:
    """The MPU6050 turned by hand all through its recording: the learning gate finds nothing still."""
    rec = read_recording(real_recording("sunsided_mpu6050_full_sphere_acc.csv"), sensor="accel")
    gate = InactivityGate(learn=True)
    for t, v in zip(rec.t, rec.raw, strict=True):
        gate.push(t, v)
    assert gate.counters["emitted"] == 0
    assert gate.thresholds == (3e-3, 3e-3)  # a move taught it nothing
