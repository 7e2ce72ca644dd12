"""ros_margcal: online in-use calibration of magnetometers and accelerometers (MARG sensors)."""

from __future__ import annotations

from .calibration import MODELS, Calibration, FitStats, load_calibrations, save_calibrations
from .errors import (
    CalibrationFileError,
    ConfigError,
    ConvergenceError,
    DegenerateDataError,
    InputError,
    MargCalError,
    RecordingError,
)

__version__ = "0.1.0"

__all__ = [
    "MODELS",
    "Calibration",
    "CalibrationFileError",
    "ConfigError",
    "ConvergenceError",
    "DegenerateDataError",
    "FitStats",
    "InputError",
    "MargCalError",
    "RecordingError",
    "__version__",
    "load_calibrations",
    "save_calibrations",
]
