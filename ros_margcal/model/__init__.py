"""The calibration model: the calibration value, its errors and the ellipsoid fits.

The value ``Calibration`` (h = W (v - b), Camps et al. 2009 Eq. 2, norm |h|) and its YAML file
(``calibration_file``); the fits of ``fitting`` (``sphere`` and ``lin_auto``: Gietzelt et al. 2013,
Eqs. 5-17, in ``fitting_linear``; ``lm``: Camps et al. 2009, Eqs. 6-12, with ``fitting_core`` holding
the shared Gauss-Newton pieces). Everything else builds on this package; it imports nothing of the rest.
"""

from __future__ import annotations

from .calibration import MODELS, Calibration, FitStats
from .calibration_file import calibration_from_yaml, calibration_to_yaml, load_calibrations, save_calibrations
from .errors import (
    CalibrationFileError, ConfigError, ConvergenceError, DegenerateDataError, InputError, MargCalError,
    RecordingError, as_points, as_vector3
)
from .fitting import LOSSES, METHODS, SUPPORTED, fit, residuals
from .fitting_core import (
    N_PARAMS, OFF, Prepared, abs_model, check_geometry, check_singular, finish, gn_covariance, gram, mad_sigma,
    pack, parameter_names, prepare, raw_scale, resjac, solve_spd3, unpack
)
from .fitting_linear import algebraic, lin_auto, lin_auto_fit, mvee, sphere, sqrt_pd

__all__ = [
    "LOSSES", "METHODS", "MODELS", "N_PARAMS", "OFF", "SUPPORTED", "Calibration", "CalibrationFileError",
    "ConfigError", "ConvergenceError", "DegenerateDataError", "FitStats", "InputError", "MargCalError",
    "Prepared", "RecordingError", "abs_model", "algebraic", "as_points", "as_vector3", "calibration_from_yaml",
    "calibration_to_yaml", "check_geometry", "check_singular", "finish", "fit", "gn_covariance", "gram",
    "lin_auto", "lin_auto_fit", "load_calibrations", "mad_sigma", "mvee", "pack", "parameter_names", "prepare",
    "raw_scale", "residuals", "resjac", "save_calibrations", "solve_spd3", "sphere", "sqrt_pd", "unpack"
]
