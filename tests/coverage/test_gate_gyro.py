"""Issue 14: the gyro-aided inactivity gate (1 s of stillness with a gyro; Gietzelt's 2 s without)."""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

from ros_margcal.coverage.gate import GyroAidedGate
from ros_margcal.stream.calibrator import EventKind, SensorCalibrator

GEN: ModuleType = INDEPENDENT


@pytest.fixture(scope="module")
def short_rests() -> dict[str, Any]:
    """2.5 s of motion, 1.5 s still, 100 Hz, 60 s (the issue's case), gyro zero (plus noise, bias) at rest."""
    return GEN.generate("accel", "rest_and_move", duration_s=60.0, rate_hz=100.0, seed=5, rest_s=1.5, move_s=2.5,
                        with_gyro=True)


def _feed(cal: SensorCalibrator, rec: dict[str, Any], gyro: bool) -> list[Any]:
    g = rec["gyro"] if gyro else [None] * len(rec["t"])
    out = []
    for t, v, w in zip(rec["t"].tolist(), rec["xyz"], g, strict=True):
        out += [e for e in cal.push(t, v, w) if e.kind is EventKind.CALIBRATED]
    return out


def test_short_rests_with_a_gyro_calibrate(short_rests: dict[str, Any]) -> None:
    cal = SensorCalibrator("accel")
    events = _feed(cal, short_rests, gyro=True)
    assert events and cal.calibration is not None
    assert 10 <= cal.kept <= 20  # one still mean per 1.5 s rest (15 rests)
    truth = short_rests["truth"]
    assert np.linalg.norm(cal.calibration.offset - truth["offset"]) < 0.05  # of a 0.3 m/s^2 bias


def test_short_rests_without_a_gyro_keep_nothing_and_say_why(short_rests: dict[str, Any]) -> None:
    """Today's rule without a gyro: 2 s of stillness; the status says why nothing is kept."""
    cal = SensorCalibrator("accel")
    assert _feed(cal, short_rests, gyro=False) == []
    assert cal.kept == 0
    st = cal.status()
    assert f"0 of {cal.seen} samples still for >= 2 s" in st.message and "hold the sensor still" in st.message


def test_the_gyro_aided_gate_wants_a_still_gyro() -> None:
    """Constant |a| while rotating (a slow turn about gravity): the norm CV passes, the gyro does not."""
    t = np.arange(0.0, 3.0, 0.01)
    xyz = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    turning = np.tile([0.0, 0.0, 0.3], (len(t), 1))
    still = np.zeros((len(t), 3))
    rotating_gate, still_gate = GyroAidedGate(), GyroAidedGate()
    rot = [rotating_gate.push(ti, v, w) for ti, v, w in zip(t, xyz, turning, strict=True)]
    sta = [still_gate.push(ti, v, w) for ti, v, w in zip(t, xyz, still, strict=True)]
    assert all(r is None for r in rot)
    first = next(i for i, r in enumerate(sta) if r is not None)
    assert t[first] == pytest.approx(1.0, abs=0.02)  # one second of stillness with a gyro
    np.testing.assert_allclose(sta[first], [0.0, 0.0, 9.81])
    assert still_gate.window_s == 1.0 and GyroAidedGate().window_s == 2.0
    assert still_gate.counters["gyro_seen"] == len(t)


def test_without_a_gyro_the_gate_is_gietzelts() -> None:
    t = np.arange(0.0, 3.0, 0.01)
    xyz = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    gate = GyroAidedGate()
    out = [gate.push(ti, v) for ti, v in zip(t, xyz, strict=True)]
    first = next(i for i, r in enumerate(out) if r is not None)
    assert t[first] == pytest.approx(2.0, abs=0.02)


def test_a_level_ground_robot_accelerometer_says_what_it_could_update() -> None:
    """Gravity along body z only (yaw turns and drives, 1.5 s stops, a gyro): not calibrated, and the status
    names the parameters those poses determine and those that need more poses."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 80.0, 0.01)
    moving = (t % 4.0) >= 1.5
    ph = np.where(moving, ((t % 4.0) - 1.5) / 2.5, 0.0)
    f = np.zeros((len(t), 3))
    f[:, 0] = np.where(moving, 1.5 * np.sin(2 * np.pi * ph), 0.0)
    f[:, 2] = 9.80665
    gyro = rng.normal(0.0, 0.003, (len(t), 3))
    gyro[:, 2] += np.where(moving, 0.6 * np.sin(np.pi * ph) ** 2, 0.0)
    xyz = f @ np.diag([1.02, 0.99, 1.01]).T + np.array([0.3, -0.2, 0.25]) + rng.normal(0.0, 0.01, f.shape)
    cal = SensorCalibrator("accel")
    for ti, v, w in zip(t.tolist(), xyz, gyro, strict=True):
        cal.push(ti, v, w)
    assert cal.kept >= 12 and cal.calibration is None
    msg = cal.status().message
    assert "the poses seen determine" in msg and "need more poses" in msg
    determined, missing = msg.split("the poses seen determine ")[1].split("; ")[:2]
    assert "w_zz" in determined and "b_x" in missing and "b_y" in missing
    assert "turn it through all directions" not in msg  # a magnetometer's advice
    assert "hold it still in other poses" in msg and "pointing up and down" in msg
