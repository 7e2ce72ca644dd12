"""Labels of a calibration set: its error against a reference, measured over fixed directions."""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration

__all__ = ["MEASURE_DIRS", "label_error", "recording_error", "reference_readings"]

log = logging.getLogger(__name__)
Array = NDArray[np.float64]


def _fixed_uniform(n: int) -> Array:
    u = np.random.default_rng(20261121).normal(size=(n, 3))
    out: Array = u / np.linalg.norm(u, axis=1, keepdims=True)
    return out


MEASURE_DIRS: Array = _fixed_uniform(400)
"""The fixed uniform directions a set's error against a recording's best fit is measured over
(``recording_error``)."""


def label_error(cal: Calibration, test_raw: Array) -> float:
    """The label (step 3): RMS over the test readings ``test_raw`` of ``|W (v - b)| / norm - 1`` of the
    fit ``cal``."""
    rel = np.linalg.norm(cal.apply(test_raw), axis=1) / cal.norm - 1.0
    return float(np.sqrt(np.mean(rel**2)))


def reference_readings(reference: Calibration, dirs: Array) -> Array:
    """Noiseless raw readings of the unit directions ``dirs`` by the sensor ``reference``."""
    out: Array = reference.inverse_apply(dirs * reference.norm)
    return out


def recording_error(cal: Calibration, reference: Calibration) -> float:
    """The error of a set's fit ``cal`` against the best fit ``reference`` of the recording the set was
    drawn from, standing in for the truth: ``label_error`` over ``MEASURE_DIRS`` read by ``reference``.

    The label of ``make_set(recording=k)`` and the measured error of a real recording's set
    (``diagnosis.downstream.validator_errors``) are both this number.
    """
    return label_error(cal, reference_readings(reference, MEASURE_DIRS))
