"""ros_margcal: online in-use calibration of magnetometers and accelerometers (MARG sensors).

The face of the package: the calibration value, fitting, simulation, recordings, the streaming
calibrator and the validators. Nothing here imports rclpy; the node is ``ros_margcal.node``.
"""

from __future__ import annotations

from .calibration import MODELS, Calibration, FitStats, load_calibrations, save_calibrations
from .coverage import DirectionBuffer, Indicators, compute_indicators
from .errors import (
    CalibrationFileError,
    ConfigError,
    ConvergenceError,
    DegenerateDataError,
    InputError,
    MargCalError,
    RecordingError,
)
from .fitting import METHODS, fit
from .gate import InactivityGate
from .io import read_recording, write_bag, write_csv
from .pipeline import PipelineConfig, SensorCalibrator, Status
from .simulation import EFFECTS, PATTERNS, Recording, directions, random_sensor, simulate
from .validation import FuzzyValidator, ThresholdValidator, load_default_validator

__version__ = "0.1.0"

__all__ = [
    "EFFECTS",
    "METHODS",
    "MODELS",
    "PATTERNS",
    "Calibration",
    "CalibrationFileError",
    "ConfigError",
    "ConvergenceError",
    "DegenerateDataError",
    "DirectionBuffer",
    "FitStats",
    "FuzzyValidator",
    "InactivityGate",
    "Indicators",
    "InputError",
    "MargCalError",
    "PipelineConfig",
    "Recording",
    "RecordingError",
    "SensorCalibrator",
    "Status",
    "ThresholdValidator",
    "__version__",
    "compute_indicators",
    "directions",
    "fit",
    "load_calibrations",
    "load_default_validator",
    "random_sensor",
    "read_recording",
    "save_calibrations",
    "simulate",
    "write_bag",
    "write_csv",
]
