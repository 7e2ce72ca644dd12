"""A strongly anisotropic, noisy magnetometer keeps improving its calibration (``Calibration.rms_radius``).

A real QMC5883L (axes 2.2x apart, noise 2.6 % of its field; a public recording the project had not seen) calibrated
at 138 s and then kept that calibration for 317 s, 4.5 deg from the batch fit, while its buffer grew from 250 to 920
samples over every direction: each recheck was refused by the validator ("predicted error 3.4 % > 0.38 %"). After
the first calibration the buffer normalised its indicators by the calibration's equal-volume radius, below the
sphere fit's radius the validator was trained on, so full coverage read as ``c_norm`` 1.09, a region where the
trained validator predicts large errors. Now by the calibration's RMS radius, the sphere fit's: refined to 0.5 deg.
The same on the independent generator's stream below (seeded).
"""

from __future__ import annotations

from types import ModuleType

import numpy as np
from conftest import INDEPENDENT

from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator

GEN: ModuleType = INDEPENDENT


def test_a_noisy_anisotropic_sensor_is_recalibrated_as_its_buffer_grows() -> None:
    """Seed 1: semi-axes 1.57 : 1.23 : 0.93, white noise 2.5 % of the field. The first calibration (18 s, 2.6 deg off
    at 30 deg) is replaced at the next recheck by a better one on the grown buffer; before, it stayed for good."""
    rec = GEN.generate("mag", motion="tumble", duration_s=60.0, rate_hz=50.0, seed=1, soft_iron=0.35,
                       symmetric_soft_iron=True, hard_iron_mag=30e-6, noise=1.2e-6)
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag"))
    got = []
    for t, v in zip(rec["t"].tolist(), rec["xyz"].tolist(), strict=True):
        got += [e for e in cal.push(t, v, None) if e.kind is EventKind.CALIBRATED]
    assert len(got) >= 2, [e.message for e in got]
    truth = rec["truth"]
    first, last = (GEN.heading_p95(e.calibration.matrix, e.calibration.offset, truth, 30.0) for e in (got[0], got[-1]))
    assert last < 0.8 * first, (first, last)
    ind = cal.buffer.indicators()
    assert ind.c_norm < 1.03, ind  # full coverage of an anisotropic sensor reads about 1, as in the training sets
    assert np.isclose(ind.radius, cal.calibration.rms_radius)
