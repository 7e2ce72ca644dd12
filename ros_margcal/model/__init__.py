"""The calibration model: the calibration value, its errors and the ellipsoid fits.

The value ``Calibration`` (h = W (v - b), Camps et al. 2009 Eq. 2, norm |h|) and its YAML file
(``calibration_file``, strict field readers in ``fields``); the fits of ``fitting``: ``sphere`` and
``lin_auto`` (Gietzelt et al. 2013, Eqs. 5-17, in ``fitting_linear``), ``lm`` (Camps et al. 2009,
Eqs. 6-12), with ``fitting_core`` holding the shared Gauss-Newton pieces; the MAP fit with a prior
that updates only what the data determine (``fitting_prior``, its geometric residual in
``fitting_geometric``, the coloured-noise model of its time series in ``fitting_noise``) and the heading
error predicted from a calibration's covariance (``heading``), and the Earth's field at a position from
the World Magnetic Model (``geomag``: the reference norm and the heading figures' inclination). Everything
else builds on this package; it imports nothing of the rest.
"""

from __future__ import annotations

from .calibration import MODELS, Calibration, FitStats
from .calibration_file import calibration_from_yaml, calibration_to_yaml, load_calibrations, save_calibrations
from .errors import (
    CalibrationFileError, ConfigError, ConvergenceError, DegenerateDataError, InputError, MargCalError,
    RecordingError, RunawayError, as_points, as_vector3, one_line
)
from .fitting import LOSSES, METHODS, fit, residuals
from .fitting_core import (
    N_PARAMS, OFF, Prepared, abs_model, check_geometry, check_singular, finish, gn_covariance, gram, mad_sigma,
    pack, parameter_names, prepare, raw_scale, resjac, solve_spd3, unpack
)
from .fitting_linear import algebraic, lin_auto, lin_auto_fit, mvee, sphere, sqrt_pd
from .fitting_prior import (
    BROAD_MATRIX_STD, BROAD_OFFSET_STD, UPDATED_VARIANCE_RATIO, PriorFit, broad_prior, fit_with_prior, posterior_at
)
from .geomag import FIELD_MODEL, GeomagField, decimal_year, distance_km, field_at, format_position
from .heading import (
    attitudes, format_bound, heading_gradient, heading_p95, heading_p95_quantile, heading_p95_typical, heading_std_deg,
    inclination_deg, inflated, with_offset_noise
)
from .mounting import ROTATIONS, Mounting, find_mounting, into_imu_frame, rotation_name

__all__ = [
    "BROAD_MATRIX_STD", "BROAD_OFFSET_STD", "FIELD_MODEL", "LOSSES", "METHODS", "MODELS", "N_PARAMS", "OFF",
    "ROTATIONS", "UPDATED_VARIANCE_RATIO", "Calibration", "CalibrationFileError", "ConfigError", "ConvergenceError",
    "DegenerateDataError", "FitStats", "GeomagField", "InputError", "MargCalError", "Mounting", "Prepared",
    "PriorFit", "RecordingError", "RunawayError", "abs_model", "algebraic", "as_points", "as_vector3", "attitudes", "broad_prior",
    "calibration_from_yaml", "calibration_to_yaml", "check_geometry", "check_singular", "decimal_year",
    "distance_km", "field_at", "find_mounting", "finish", "fit", "fit_with_prior", "format_bound",
    "format_position", "gn_covariance", "gram", "heading_gradient", "heading_p95", "heading_p95_quantile",
    "heading_p95_typical", "heading_std_deg", "inclination_deg", "inflated", "into_imu_frame", "lin_auto",
    "lin_auto_fit", "load_calibrations", "mad_sigma", "mvee", "one_line", "pack", "parameter_names", "posterior_at",
    "prepare", "raw_scale", "residuals", "resjac", "rotation_name", "save_calibrations", "solve_spd3", "sphere",
    "sqrt_pd", "unpack", "with_offset_noise"
]
