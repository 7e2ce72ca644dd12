"""An accelerometer whose stamps are not seconds: its status names the stamps, not the gate's threshold (fuzzed:
all-zero and millisecond stamps were told to "raise accel.gate_cv_threshold", which would not help)."""

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
