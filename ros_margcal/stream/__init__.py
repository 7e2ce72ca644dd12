"""The streaming calibrator of one sensor: samples in, validated calibrations and a status out.

``calibrator.SensorCalibrator.push`` walks a sample through the input checks (``intake``, with the
unit's limits from ``units``), the gate, the buffer, the validator, the fit and the guard rails
(``evaluation``, ``config.guard_rails``) and the change test (``change``); ``status`` holds what
``/calib/status`` shows. Pure Python: the ROS node (``ros``) and ``margcal replay`` (``replay``) drive it.
"""

from __future__ import annotations

from .calibrator import SensorCalibrator
from .change import ChangeDetection
from .config import FIELD_SPECS, STATIC_SPREAD, FieldSpec, PipelineConfig, guard_rails, plausibility, rms_relative
from .evaluation import Evaluation
from .intake import DROP_REASONS, MAX_GYRO_RAD_S, MAX_STAMP_S, Intake
from .observable import (
    DEFAULT_INCLINATION_DEG, HeadingFigures, PartialResult, azimuth_coverage, heading_figures, partial_fit,
    sphere_radius, tilt_seen_deg
)
from .partial import PartialCalibration
from .replay import replay
from .status import Event, EventKind, Level, State, Status, pct
from .units import ACCEL_UNITS, GRAVITY, LEARN_HIGH, LEARN_LOW, LEARN_SAMPLES, MAG_UNITS, unit_scale

__all__ = [
    "ACCEL_UNITS", "DEFAULT_INCLINATION_DEG", "DROP_REASONS", "FIELD_SPECS", "GRAVITY", "LEARN_HIGH",
    "LEARN_LOW", "LEARN_SAMPLES", "MAG_UNITS", "MAX_GYRO_RAD_S", "MAX_STAMP_S", "STATIC_SPREAD",
    "ChangeDetection", "Evaluation", "Event", "EventKind", "FieldSpec", "HeadingFigures", "Intake", "Level",
    "PartialCalibration", "PartialResult", "PipelineConfig", "SensorCalibrator", "State", "Status",
    "azimuth_coverage", "guard_rails", "heading_figures", "partial_fit", "pct", "plausibility", "replay",
    "rms_relative", "sphere_radius", "tilt_seen_deg", "unit_scale"
]
