"""What an accelerometer that the gate never passes is told to do: not "raise accel.gate_cv_threshold" when that
would not help (fuzzed): its stamps are not seconds (all zero, milliseconds), or its readings are still and its gyro
rates are in deg/s (0.1-1 at rest, above the rest threshold of 0.05 rad/s)."""

from __future__ import annotations

import numpy as np
import pytest

from ros_margcal.stream.calibrator import SensorCalibrator


@pytest.mark.parametrize(("step", "words"), [(0.0, "the stamps do not advance"), (10.0, "they look like milliseconds")])
def test_an_accelerometer_with_stamps_not_in_seconds_is_told_so(step: float, words: str) -> None:
    cal = SensorCalibrator("accel")
    rng = np.random.default_rng(3)
    for k in range(3000):  # a still sensor at 100 Hz, stamped in ms (or not at all)
        cal.push(step * k, np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.01, 3))
    message = cal.status().message
    assert message.startswith("collecting: no still sample from the inactivity gate yet:") and words in message, message
    assert "gate_cv_threshold" not in message and message.count(words) == 1, message


def test_an_accelerometer_with_its_gyro_in_deg_s_is_told_so() -> None:
    cal = SensorCalibrator("accel")
    rng = np.random.default_rng(4)
    for k in range(1000):  # still, at 100 Hz; the gyro's rest noise of 0.005 rad/s given in deg/s (0.29)
        cal.push(0.01 * k, np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.01, 3), np.degrees(rng.normal(0.0, 0.005, 3)))
    message = cal.status().message
    assert "the readings are still but the gyro reads above 0.05 rad/s" in message and "deg/s" in message, message
    assert "gate_cv_threshold" not in message and "gate_gyro_rest_threshold" in message, message
    rad = SensorCalibrator("accel")  # the same in rad/s: still samples pass
    for k in range(1000):
        rad.push(0.01 * k, np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.01, 3), rng.normal(0.0, 0.005, 3))
    assert rad.kept > 0, rad.status().message
