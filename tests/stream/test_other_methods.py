"""The stream's full fit with another method than lm (fuzzed: ``--set method=mvee`` was rejected for ever, "init
only applies to method 'lm'": the stream passed lm's start to every method)."""

from __future__ import annotations

import numpy as np
import pytest

from ros_margcal.model.errors import ConfigError
from ros_margcal.sim import simulation as sim
from ros_margcal.stream.calibrator import PipelineConfig, SensorCalibrator


def test_the_stream_calibrates_with_mvee() -> None:
    rng = np.random.default_rng(41)
    truth = sim.random_sensor(rng, "mag")
    rec = sim.magnetometer_stream(truth, 30.0, 50.0, rng, motion="tumble")
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", method="mvee", loss="linear", early_fit=False,
                                                            partial_fit=False))
    for t, v in zip(rec.t.tolist(), rec.raw, strict=True):
        cal.push(t, v)
    cal.finish_fit()  # a fit in progress at the recording's end (as replay does)
    assert cal.calibration is not None and cal.calibration.method.startswith("mvee"), cal.status().message
    assert np.linalg.norm(cal.calibration.offset - truth.offset) < 0.1 * truth.norm  # (mvee: the enclosing ellipsoid)


def test_a_robust_loss_with_another_method_says_what_to_set() -> None:
    with pytest.raises(ConfigError, match="set loss 'linear' too"):
        PipelineConfig.for_sensor("mag", method="mvee").checked()
