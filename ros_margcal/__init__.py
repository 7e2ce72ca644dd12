"""ros_margcal: online in-use calibration of magnetometers and accelerometers (MARG sensors).

The face of the package: the calibration value, fitting, simulation, recordings, the streaming
calibrator and the validators. Nothing here imports rclpy; the node is ``ros_margcal.ros.node``.
"""

from __future__ import annotations

from .coverage.buffer import DirectionBuffer
from .coverage.gate import InactivityGate
from .coverage.indicators import Indicators, compute_indicators
from .model.calibration import MODELS, Calibration, FitStats
from .model.calibration_file import load_calibrations, save_calibrations
from .model.errors import (
    CalibrationFileError, ConfigError, ConvergenceError, DegenerateDataError, InputError, MargCalError,
    RecordingError
)
from .model.fitting import METHODS, fit
from .recordings.bag import write_bag
from .recordings.csvfile import write_csv
from .recordings.read import read_recording
from .recordings.recording import Recording
from .sim.simulation import EFFECTS, PATTERNS, directions, random_sensor, simulate
from .stream.calibrator import SensorCalibrator
from .stream.config import PipelineConfig
from .stream.status import Status
from .validation.fuzzy import FuzzyValidator
from .validation.shipped import load_default_validator
from .validation.threshold import ThresholdValidator

__version__ = "0.1.0"

__all__ = [
    "EFFECTS", "METHODS", "MODELS", "PATTERNS", "Calibration", "CalibrationFileError", "ConfigError",
    "ConvergenceError", "DegenerateDataError", "DirectionBuffer", "FitStats", "FuzzyValidator", "InactivityGate",
    "Indicators", "InputError", "MargCalError", "PipelineConfig", "Recording", "RecordingError", "SensorCalibrator",
    "Status", "ThresholdValidator", "__version__", "compute_indicators", "directions", "fit", "load_calibrations",
    "load_default_validator", "random_sensor", "read_recording", "save_calibrations", "simulate", "write_bag",
    "write_csv"
]
