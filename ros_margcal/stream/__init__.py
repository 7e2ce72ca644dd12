"""The streaming calibrator of one sensor: samples in, validated calibrations and a status out.

``calibrator.SensorCalibrator.push`` walks a sample through the gate, the buffer, the validator, the
fit and the guard rails (``config.guard_rails``); ``status`` holds what ``/calib/status`` shows.
Pure Python: the ROS node (``ros``) and ``margcal replay`` drive it.
"""

from __future__ import annotations

from .calibrator import SensorCalibrator
from .config import ACCEL_UNITS, GRAVITY, MAG_UNITS, PipelineConfig, guard_rails
from .replay import replay
from .status import Event, EventKind, Level, State, Status, pct

__all__ = [
    "ACCEL_UNITS", "GRAVITY", "MAG_UNITS", "Event", "EventKind", "Level", "PipelineConfig", "SensorCalibrator",
    "State", "Status", "guard_rails", "pct", "replay"
]
