"""Options of the streaming calibrator and the guard rails a fit must pass before it is published.

The guard rails follow ArduPilot's compass and accelerometer calibration checks (fitness limit,
offset limit, diagonal/off-diagonal limits, field strength check), restated for the
``calibrated = W (raw - b)`` model of ``calibration.py``:

- residual: ``stats.rms_relative`` (RMS of ``|W (v - b)| - norm`` over ``norm``) at most
  ``max_residual``;
- offset: ``|b|`` at most ``max_offset_ratio`` times the raw field radius or ``max_offset`` (absolute,
  in ``unit``), whichever is larger. A hard iron of a few Earth fields is common on a robot, and a
  phone or a logger beside a battery reads more: ArduPilot accepts 1 800 mG (180 µT), real recordings
  show 231 µT in a 39 µT field; the magnetometer default is therefore 5 field norms or 1 mT (20 Earth
  fields, within the ±4.9 mT range of phone magnetometers), and 20 field norms in a unit without a
  known scale (counts). An accelerometer bias beyond ~0.35 g is a broken sensor, but in counts the
  offset is the ADC's (an unsigned ADC's mid-scale: up to 16 g at +-16 g): 20 gravity norms there
  (``COUNTS_ACCEL_OFFSET_RATIO``). The message gives the fitted offset, in the sensor's words (hard
  iron, bias), so a user can judge;
- gains: the singular values of ``W`` scaled so that a sphere gives 1 (the axis ratios of the raw
  ellipsoid) within ``[gain_min, gain_max]``;
- field norm: the raw radius ``norm / |det W|^(1/3)`` within ``[norm_min, norm_max]`` (20–70 µT
  for the Earth field in the configured unit; 0.85–1.15 g for gravity); off in a unit without a
  known scale (``units``: counts), where the intake learns its magnitude limits from the data instead;
- parameter uncertainty: the one-sigma std of every fitted parameter (from the fit's covariance;
  offsets over the radius, matrix elements over the mean gain) at most ``max_parameter_std``: a
  set the validator let through but that leaves the model undetermined (two great circles) is
  refused here;
- not worse: on the most recent samples, the RMS relative norm error of the new fit is at most
  ``(1 + not_worse_tolerance)`` times that of the current calibration.

A position (``latitude_deg``, ``longitude_deg``, ``altitude_m``; ``at_position``) takes the magnetometer's
``reference_norm`` and the heading figures' ``heading_inclination_deg`` from the World Magnetic Model
(``model/geomag.py``), as ArduPilot and PX4 scale their fits to it; ``field_model`` says which field that is.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import MODELS, Calibration
from ..model.errors import ConfigError
from ..model.fitting import LOSSES, METHODS, SUPPORTED
from ..model.geomag import GeomagField, field_at
from ..model.mounting import UP_AXES
from .units import ACCEL_UNITS, GRAVITY, LEARN_SAMPLES, MAG_UNITS, other_sensors_unit, unit_scale

__all__ = ["ACCEL_UNITS", "FIELD_SPECS", "GRAVITY", "GYRO_PAIR_S", "MAG_UNITS", "MOTION_NOT_NOISE", "RESIDUAL_NOISE_FACTOR",
           "STATIC_SPREAD", "STILL_SPREAD", "FieldSpec", "PipelineConfig", "apart", "guard_rails", "plausibility", "raise_hint",
           "readings_for", "relative_spread", "relative_std", "residual_limit", "rms_relative", "white_noise"]

EARTH_FIELD_RANGE_T = (20e-6, 70e-6)
"""Plausible geomagnetic field strength, tesla."""
GYRO_PAIR_S = 0.02
"""A magnetometer message takes the angular rate of the Imu message nearest in stamp (node, bag replay) when their
stamps are at most this far apart, s, of its frame_id or of the only Imu frame (``gyro_aided``, ``ros/pairing.py``)."""
STATIC_SPREAD = 0.03
"""RMS distance of readings from their mean, over their mean norm, below which the sensor has not turned
(an HMC5883L at rest: 0.2 %; a full turn with an offset of 10 field norms: about 10 %)."""


STILL_SPREAD = STATIC_SPREAD / 3
"""Readings this close to their mean (``relative_spread``) are a still sensor's noise, whatever the unit: no sphere's
centre (the direction bins) and no ring (a partial fit) is fitted to them; a third of ``STATIC_SPREAD``, so that a
turning sensor whose offset is 30 field norms is not taken for still (a still HMC5883L in counts, 0.13 %, had "38 %
coverage" and "the field turned through 50 % of the azimuths" beside "the sensor has not turned")."""


def relative_spread(points: NDArray[np.float64]) -> float:
    """RMS distance of ``points`` (n, 3) from their mean over their median norm (compare ``STATIC_SPREAD``)."""
    scale = float(np.median(np.linalg.norm(points, axis=1))) or 1.0
    return float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1)))) / scale
COUNTS_ACCEL_OFFSET_RATIO = 20.0
"""Accelerometer offset limit in counts, gravity norms: an unsigned 16-bit ADC reads mid-scale 32768 at 0 g, which is
2 g at +-2 g (16384 counts/g) and 16 g at +-16 g (2048 counts/g); 20 covers every common range."""
MAX_OFFSET_T = 1e-3
"""Default absolute magnetometer offset limit, tesla (20 Earth fields; ArduPilot: 1 800 mG = 180 µT)."""


@dataclass(frozen=True)
class PipelineConfig:
    """Options of ``SensorCalibrator``; ``for_sensor`` gives the defaults (also in msg_configs/margcal.yaml).

    Magnitudes (``min_magnitude``, ``max_magnitude``, ``norm_min``, ``norm_max``, ``reference_norm``,
    ``max_offset``) are in ``unit``; ratios (``max_residual``, thresholds) are fractions of the field
    norm. ``learn_magnitude_samples`` > 0 makes the intake replace the magnitude limits by limits learnt
    from that many first samples (the default in a unit without a known scale, see ``units``).
    ``checked`` holds every field to its ``FIELD_SPECS`` entry (type, range, memory bound).
    """

    sensor: str = "mag"
    unit: str = "T"
    # fit
    model: str = "sym"
    method: str = "lm"
    loss: str = "soft_l1"
    f_scale_rel: float | None = None  # robust-loss scale / norm; None: fitting's default (2 MAD sigma, re-estimated)
    reference_norm: float | None = None
    max_iter: int = 200
    # input sanity
    min_magnitude: float = 1e-9
    max_magnitude: float = 1.4e-3
    learn_magnitude_samples: int = 0
    max_rate_hz: float = 2000.0
    drop_saturated: bool = True  # drop samples on an axis pinned at the end of the range (stream/saturation.py)
    max_stamp_gap_s: float = 60.0  # a forward stamp step beyond this is a jump: a glitch, or a new time base
    new_time_base_after: int = 5  # consecutive consistent samples off the current time base that make a new one
    # buffer and validator
    n_bins: int = 100
    per_bin: int = 10
    min_points: int = 60
    max_predicted_error: float | None = None
    refit_every: int = 50
    refit_min_interval_s: float = 1.0
    recheck_interval_s: float = 30.0
    # guard rails
    max_residual: float = 0.05
    max_offset_ratio: float = 5.0
    max_offset: float | None = None  # absolute offset limit in unit; the larger of the two limits applies
    gain_min: float = 0.6
    gain_max: float = 1.6
    norm_min: float = 20e-6
    norm_max: float = 70e-6
    not_worse_tolerance: float = 0.0
    max_parameter_std: float = 0.01
    recent_samples: int = 500
    # change detection
    change_window: int = 50
    change_threshold: float = 0.05
    change_min_duration_s: float = 5.0
    outlier_threshold: float = 0.08
    # accelerometer gate
    gate_window_s: float = 2.0
    gate_cv_threshold: float = 3e-3
    gate_gyro_threshold: float | None = None
    gate_gyro_window_s: float = 1.0  # with a gyro reading on every sample: the still window (Gietzelt's 2 s without)
    gate_gyro_rest_threshold: float = 0.05  # rad/s: |omega| below this on every sample of the gyro-aided window
    gate_learn_noise: bool = True  # widen the gate's thresholds to the sensor's learnt rest noise (coverage/gate.py)
    # partial calibration (stream/observable.py)
    partial_fit: bool = True  # magnetometer: fit what the motion makes observable when the full validator refuses
    max_heading_p95_deg: float = 2.5  # publish a partial fit when its predicted heading p95 at the tilt seen is within
    partial_period_s: float = 0.2  # one sample (their mean) of the partial fit's time series per this many seconds ...
    partial_samples: int = 1500  # ... the last this many (300 s at the defaults)
    partial_max_tilt_deg: float = 45.0  # a partial fit only for a ring or band: data tilted at most this much
    near_level_tilt_deg: float = 2.5  # a ring this flat, without a gyro, is held level (stream/observable.py); 0: never
    up_axis: str = "z"  # magnetometer: its axis pointing up when the vehicle is level ("y", "-x", ...: mounted on its
    # side); the readings are turned so that it is z, the calibration published in the magnetometer's own axes
    gyro_aided: bool = True  # magnetometer: a rate pushed with a sample joins the partial fit (model/fitting_gyro.py) ...
    gyro_samples: int = 15000  # ... the last this many samples with their rates (300 s at 50 Hz) ...
    gyro_block_s: float = 1.0  # ... in blocks of this length (the longer, the larger the turn against the noise)
    gyro_scale_std: float = 0.02  # ... the prior sd of each gyro scale error (model/fitting_gyro.py GYRO_SCALE_STD)
    calibrate_into_imu_frame: bool = False  # magnetometer with a gyro: publish W in the Imu's frame once the mounting
    # rotation is decided (model/mounting.py)
    partial_min_azimuth: float = 0.9  # ... turned about body z: share of 36 azimuth sectors the field visits
    early_fit: bool = True  # rich motion, uncalibrated: publish a MAP fit once its predicted heading p95 is small ...
    early_heading_p95_deg: float = 1.0  # ... at most this at +-30 deg tilt (max_heading_p95_deg once its directions
    # fill more than half the sphere: stream/observable.py RICH_REGIONS), refined by early fits while above this
    early_interval_s: float = 0.5  # evaluation cadence while an early fit is close to passing
    prior_inflate: float = 4.0  # covariance factor on a previous calibration used as the prior
    heading_inclination_deg: float | None = None  # field inclination for the heading figures (None: from the data)
    # the field from a geomagnetic model (``at_position``): sets reference_norm and heading_inclination_deg
    latitude_deg: float | None = None  # geodetic, deg; None: no position
    longitude_deg: float | None = None  # deg east (-180..360)
    altitude_m: float = 0.0  # above the WGS 84 ellipsoid, m
    field_year: float | None = None  # decimal year the model was evaluated at (None: today)

    @property
    def min_period_s(self) -> float:
        """Samples closer than this to the previous accepted one are a burst and dropped."""
        return 1.0 / self.max_rate_hz

    @classmethod
    def for_sensor(cls, sensor: str, unit: str | None = None, **overrides: Any) -> PipelineConfig:
        """Defaults for ``"mag"`` (raw unit tesla unless given) or ``"accel"`` (m/s² unless given).

        The other sensor's unit (``m/s^2`` for ``"mag"``) is a ConfigError. In a unit without a known scale
        (``units.unit_scale`` is None: counts) the field-strength check
        is off, the magnitude limits are learnt from the first ``units.LEARN_SAMPLES`` samples (unless
        ``min_magnitude`` or ``max_magnitude`` is given) and the offset limit is 20 field norms (an
        unsigned ADC's mid-scale: ``COUNTS_ACCEL_OFFSET_RATIO``).
        """
        if unit is not None and not isinstance(unit, str):
            raise ConfigError(f"unit must be a string, got {unit!r}")
        if sensor not in ("mag", "accel"):
            msg = f"sensor must be 'mag' or 'accel', got {sensor!r}"
            raise ConfigError(msg)
        u = unit or ("T" if sensor == "mag" else "m/s^2")
        scale = unit_scale(sensor, u)
        wrong = other_sensors_unit(sensor, u)
        if wrong:
            raise ConfigError(wrong)
        unknown: dict[str, Any] = {}
        if scale is None:  # counts: no field-strength check, magnitude limits from the data
            learn = 0 if {"min_magnitude", "max_magnitude"} & set(overrides) else LEARN_SAMPLES
            unknown = {"norm_min": 0.0, "norm_max": math.inf, "min_magnitude": 0.0, "max_magnitude": _MAGNITUDE_MAX,
                       "learn_magnitude_samples": learn, "reference_norm": None}
        if sensor == "mag":
            s = scale or 1.0
            base = cls(sensor="mag", unit=u, reference_norm=None, norm_min=EARTH_FIELD_RANGE_T[0] / s,
                       norm_max=EARTH_FIELD_RANGE_T[1] / s, min_magnitude=1e-3 * EARTH_FIELD_RANGE_T[0] / s,
                       max_magnitude=20.0 * EARTH_FIELD_RANGE_T[1] / s,
                       max_offset=None if scale is None else MAX_OFFSET_T / s,
                       max_offset_ratio=20.0 if scale is None else 5.0)
        else:
            g = GRAVITY / (scale or 1.0)
            base = cls(sensor="accel", unit=u, reference_norm=g, norm_min=0.85 * g, norm_max=1.15 * g,
                       min_magnitude=1e-3 * g, max_magnitude=16.0 * g, min_points=12, refit_every=1,
                       refit_min_interval_s=0.0, recheck_interval_s=10.0, max_offset_ratio=0.35, gain_min=0.85,
                       gain_max=1.15, recent_samples=40, change_window=6, change_threshold=0.03,
                       change_min_duration_s=0.0, outlier_threshold=0.2, max_residual=0.03)
        if unknown:
            base = replace(base, **unknown)
            if sensor == "accel":  # an unsigned ADC sits at mid-scale: its full-scale range in g, up to 16 (module doc)
                base = replace(base, max_offset_ratio=COUNTS_ACCEL_OFFSET_RATIO)
        bad = sorted(set(overrides) - {f.name for f in fields(cls)})
        if bad:
            raise ConfigError(f"unknown options {bad}")
        cfg = replace(base, **overrides).checked() if overrides else base.checked()
        if cfg.latitude_deg is not None and cfg.longitude_deg is not None:  # a norm given too wins over the model's
            cfg = cfg.at_position(cfg.latitude_deg, cfg.longitude_deg, cfg.altitude_m, cfg.field_year,
                                  norm="reference_norm" not in overrides)
        return cfg

    def at_position(self, lat_deg: float, lon_deg: float, alt_m: float = 0.0, when: Any = None, *,
                    norm: bool = True) -> PipelineConfig:
        """A copy for the World Magnetic Model's field at this position on ``when`` (None: today; ``geomag.field_at``):
        a magnetometer's ``reference_norm`` in its unit (unless ``norm`` is False or the unit has no known scale:
        counts) and ``heading_inclination_deg``. ConfigError for a bad position or a date outside the model."""
        f = field_at(lat_deg, lon_deg, alt_m, when)
        changes: dict[str, Any] = {"latitude_deg": f.lat_deg, "longitude_deg": f.lon_deg, "altitude_m": f.alt_m,
                                   "field_year": f.year}
        if self.sensor == "mag":
            scale = unit_scale("mag", self.unit)
            if norm and scale is not None:
                changes["reference_norm"] = f.intensity_t / scale
            changes["heading_inclination_deg"] = f.inclination_deg
        return replace(self, **changes).checked()

    def field_model(self) -> GeomagField | None:
        """The model field at this position and date (``at_position``), or None without a position."""
        if self.latitude_deg is None or self.longitude_deg is None:
            return None
        return field_at(self.latitude_deg, self.longitude_deg, self.altitude_m, self.field_year)

    def checked(self) -> PipelineConfig:
        """Return self after checking every option against ``FIELD_SPECS``; ConfigError names the bad one.

        Each field has a type (bools are not numbers, strings are not numbers), a finite range and,
        where it sizes a buffer, a memory bound; then the options that depend on each other.
        """
        for name, spec in FIELD_SPECS.items():
            spec.check(name, getattr(self, name))
        if self.model not in SUPPORTED[self.method]:
            raise ConfigError(f"method {self.method!r} cannot fit model {self.model!r}; it supports {SUPPORTED[self.method]}")
        if self.loss != "linear" and self.method != "lm":
            raise ConfigError(f"loss {self.loss!r} needs method 'lm', got method {self.method!r}: with method "
                              f"{self.method!r} set loss 'linear' too")
        if not self.gain_min <= 1.0 <= self.gain_max:
            raise ConfigError(f"need 0 < gain_min <= 1 <= gain_max, got {self.gain_min}, {self.gain_max}")
        if not self.norm_min < self.norm_max:
            raise ConfigError(f"need 0 <= norm_min < norm_max, got {self.norm_min}, {self.norm_max}")
        if not self.min_magnitude < self.max_magnitude:
            raise ConfigError(f"need 0 <= min_magnitude < max_magnitude, got {self.min_magnitude}, {self.max_magnitude}")
        if self.sensor == "accel" and self.up_axis.lstrip("+") != "z":
            raise ConfigError(f"up_axis {self.up_axis!r} is the magnetometer's option (the axis its ring turns about); "
                              "the accelerometer has none: set mag.up_axis")
        if (self.latitude_deg is None) != (self.longitude_deg is None):
            raise ConfigError(f"a position needs latitude_deg and longitude_deg, got {self.latitude_deg!r} and "
                              f"{self.longitude_deg!r}")
        if self.change_window > self.recent_samples:
            raise ConfigError(f"change_window ({self.change_window}) must not exceed recent_samples ({self.recent_samples})")
        capacity = self.n_bins * self.per_bin
        if capacity > MAX_BUFFERED:
            raise ConfigError(f"n_bins x per_bin ({self.n_bins} x {self.per_bin} = {capacity}) must not exceed "
                              f"{MAX_BUFFERED} buffered samples (memory)")
        if self.min_points > capacity:
            raise ConfigError(f"min_points ({self.min_points}) must not exceed the buffer, n_bins x per_bin = {capacity}")
        if self.gate_window_s * self.max_rate_hz > MAX_GATE_WINDOW:
            raise ConfigError(f"gate_window_s x max_rate_hz ({self.gate_window_s:g} s x {self.max_rate_hz:g} Hz) must not "
                              f"exceed {MAX_GATE_WINDOW} samples in the gate window (memory)")
        return self


MAX_BUFFERED = 100_000
"""Most samples the direction buffer may hold (``n_bins * per_bin``): a few tens of MB and a fit of bounded cost."""
MAX_GATE_WINDOW = 1_000_000
"""Most samples the inactivity gate's window may hold (``gate_window_s * max_rate_hz``)."""
_MAGNITUDE_MAX = 1e12
"""Upper bound of every magnitude option, in any unit (nT, mg, counts all stay far below)."""
_DAY_S = 86400.0
_RATIO_MIN = 1e-6
_MAGNITUDE_MIN = 1e-12


@dataclass(frozen=True)
class FieldSpec:
    """Type and range of one ``PipelineConfig`` field.

    ``kind`` is ``float`` (an int or float, never a bool or a string), ``int`` (a Python int, never a
    bool) or ``str``; numbers must lie in ``[lo, hi]`` (``(lo, hi]`` when ``open_lo``), NaN never does;
    ``none_ok`` admits None, ``inf_ok`` admits +inf (an "off" value), ``choices`` lists the admitted strings.
    """

    kind: type
    lo: float = 0.0
    hi: float = 0.0
    open_lo: bool = False
    none_ok: bool = False
    inf_ok: bool = False
    choices: tuple[str, ...] | None = None

    def check(self, name: str, value: Any) -> None:
        """Raise ConfigError naming ``name`` unless ``value`` fits this spec."""
        if value is None:
            if self.none_ok:
                return
            raise ConfigError(f"{name} must not be None")
        if self.kind is bool:
            if not isinstance(value, bool):
                raise ConfigError(f"{name} must be true or false, got {value!r}")
            return
        if self.kind is str:
            if not isinstance(value, str):
                raise ConfigError(f"{name} must be a string, got {value!r}")
            if self.choices is not None and value not in self.choices:
                raise ConfigError(f"{name} must be one of {self.choices}, got {value!r}")
            if not 0 < len(value) <= 64:
                raise ConfigError(f"{name} must be a non-empty string of at most 64 characters, got {value!r}")
            return
        if isinstance(value, bool) or not isinstance(value, int if self.kind is int else numbers.Real):
            raise ConfigError(f"{name} must be {'an int' if self.kind is int else 'a number'}, got {value!r}")
        if self.inf_ok and value == math.inf:
            return
        low_ok = value > self.lo if self.open_lo else value >= self.lo
        if not (low_ok and value <= self.hi):  # False for NaN; big ints compare exactly
            raise ConfigError(f"{name} must be in {'(' if self.open_lo else '['}{self.lo:g}, {self.hi:g}]"
                              f"{' or inf' if self.inf_ok else ''}, got {value!r}")


def _real(lo: float, hi: float, *, open_lo: bool = False, none_ok: bool = False, inf_ok: bool = False) -> FieldSpec:
    return FieldSpec(float, lo, hi, open_lo=open_lo, none_ok=none_ok, inf_ok=inf_ok)


def _ratio(hi: float, *, none_ok: bool = False) -> FieldSpec:
    """A fraction or factor: at least ``_RATIO_MIN`` (a zero or a denormal would switch a check off or on for good)."""
    return FieldSpec(float, _RATIO_MIN, hi, none_ok=none_ok)


FIELD_SPECS: dict[str, FieldSpec] = {
    "sensor": FieldSpec(str, choices=("mag", "accel")),
    "unit": FieldSpec(str),  # an unknown unit only turns the field-strength check off (``for_sensor``)
    "model": FieldSpec(str, choices=MODELS),
    "method": FieldSpec(str, choices=METHODS),
    "loss": FieldSpec(str, choices=LOSSES),
    "f_scale_rel": _ratio(10.0, none_ok=True),
    "reference_norm": _real(_MAGNITUDE_MIN, _MAGNITUDE_MAX, none_ok=True),
    "max_iter": FieldSpec(int, 1, 100_000),
    "min_magnitude": _real(0.0, _MAGNITUDE_MAX),
    "max_magnitude": _real(_MAGNITUDE_MIN, _MAGNITUDE_MAX),
    "learn_magnitude_samples": FieldSpec(int, 0, 10_000),
    "max_rate_hz": _real(1e-3, 1e6),
    "drop_saturated": FieldSpec(bool),
    "n_bins": FieldSpec(int, 6, 10_000),
    "per_bin": FieldSpec(int, 1, 1_000),
    "min_points": FieldSpec(int, 4, MAX_BUFFERED),
    "max_predicted_error": _ratio(1.0, none_ok=True),
    "refit_every": FieldSpec(int, 1, 100_000),
    "refit_min_interval_s": _real(0.0, _DAY_S),
    "recheck_interval_s": _real(0.0, _DAY_S),
    "max_residual": _ratio(1.0),
    "max_offset_ratio": _ratio(100.0),
    "max_offset": _real(_MAGNITUDE_MIN, _MAGNITUDE_MAX, none_ok=True),
    "gain_min": _real(1e-3, 1.0),
    "gain_max": _real(1.0, 100.0),
    "norm_min": _real(0.0, _MAGNITUDE_MAX),
    "norm_max": _real(0.0, _MAGNITUDE_MAX, open_lo=True, inf_ok=True),  # inf: no field-strength check
    "not_worse_tolerance": _real(0.0, 10.0),
    "max_parameter_std": _ratio(10.0),
    "recent_samples": FieldSpec(int, 4, 100_000),
    "change_window": FieldSpec(int, 1, 100_000),
    "change_threshold": _ratio(10.0),
    "change_min_duration_s": _real(0.0, _DAY_S),
    "outlier_threshold": _ratio(100.0),
    "gate_window_s": _real(1e-3, 600.0),
    "gate_cv_threshold": _ratio(1.0),
    "gate_gyro_threshold": _ratio(100.0, none_ok=True),
    "gate_gyro_window_s": _real(1e-3, 600.0),
    "gate_gyro_rest_threshold": _ratio(100.0),
    "gate_learn_noise": FieldSpec(bool),
    "partial_fit": FieldSpec(bool),
    "max_heading_p95_deg": _real(0.0, 180.0, open_lo=True),
    "partial_period_s": _real(0.0, 3600.0),
    "partial_samples": FieldSpec(int, 10, 100_000),
    "prior_inflate": _real(1.0, 1e6),
    "partial_max_tilt_deg": _real(0.0, 90.0),
    "near_level_tilt_deg": _real(0.0, 90.0),
    "up_axis": FieldSpec(str, choices=UP_AXES),
    "partial_min_azimuth": _ratio(1.0),
    "gyro_aided": FieldSpec(bool),
    "gyro_samples": FieldSpec(int, 100, 1_000_000),
    "gyro_block_s": _real(1e-3, 60.0),
    "gyro_scale_std": _real(1e-6, 1.0),  # a prior sd below a ppm is no MEMS gyro's (and 1e-300 overflowed its inverse)
    "calibrate_into_imu_frame": FieldSpec(bool),
    "early_fit": FieldSpec(bool),
    "early_heading_p95_deg": _real(0.0, 180.0, open_lo=True),
    "early_interval_s": _real(0.0, 3600.0),
    "heading_inclination_deg": _real(-90.0, 90.0, none_ok=True),
    "latitude_deg": _real(-90.0, 90.0, none_ok=True),
    "longitude_deg": _real(-180.0, 360.0, none_ok=True),
    "altitude_m": _real(-1000.0, 850e3),
    "field_year": _real(1900.0, 2100.0, none_ok=True),
    "max_stamp_gap_s": _real(1e-3, _DAY_S),
    "new_time_base_after": FieldSpec(int, 2, 1_000),
}
"""The type and range of every ``PipelineConfig`` field (``checked`` refuses a field missing here)."""


def rms_relative(cal: Calibration, pts: NDArray[np.float64]) -> float:
    """RMS of ``|W (v - b)| - norm`` over ``norm`` on ``pts`` (0 for no points)."""
    if not len(pts):
        return 0.0
    e = cal.norm_error(pts) / cal.norm
    return float(np.sqrt(np.mean(e * e)))


RESIDUAL_NOISE_FACTOR = 1.5
"""A fit's residual RMS is refused beyond ``max_residual`` or this many times the sensor's white noise
(``white_noise``, relative to the raw radius), whichever is wider: a noisy sensor's residual is its noise, not a
misfit (a QMC5883L whose readings scatter by 4.8 % of its field was refused for a 6.2 % residual; a slow disturbance,
a magnet moving, leaves the second differences, and so the limit, alone)."""


MOTION_NOT_NOISE = 0.1
"""A "white noise" above this share of the field is the motion between samples (readings without time order, pose
means, a slow sensor turned fast: their second differences are the field's own size), not noise: the limit stays."""


def white_noise(points: NDArray[np.float64]) -> float:
    """The white noise of time-ordered raw samples, one axis, raw units: the robust sd of their second differences
    over sqrt(6) (a smooth motion adds little at the sample rate, a slow disturbance nothing); 0 for fewer than 3
    samples. A reading repeated exactly (a logger faster than the sensor) counts once: its steps are the sensor's."""
    v = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(v) > 1:
        v = v[np.concatenate([[True], np.any(v[1:] != v[:-1], axis=1)])]
    if len(v) < 3:
        return 0.0
    with np.errstate(over="ignore", invalid="ignore"):  # a 1e308 cell: its differences are inf, the median holds
        d2 = v[2:] - 2.0 * v[1:-1] + v[:-2]
        sd = 1.4826 * float(np.median(np.abs(d2))) / math.sqrt(6.0)
    return sd if math.isfinite(sd) else 0.0


def residual_limit(cal: Calibration, cfg: PipelineConfig, noise: float = 0.0) -> tuple[float, str]:
    """The residual RMS limit of ``cal`` (``RESIDUAL_NOISE_FACTOR``) given the sensor's white ``noise`` (raw units),
    and the words a refusal adds when the noise set it ("" when ``max_residual`` did)."""
    radius = cal.raw_radius
    rel = noise / radius if noise > 0 and math.isfinite(radius) and radius > 0 else 0.0
    if rel > MOTION_NOT_NOISE or RESIDUAL_NOISE_FACTOR * rel <= cfg.max_residual:
        return cfg.max_residual, ""
    return RESIDUAL_NOISE_FACTOR * rel, f" ({RESIDUAL_NOISE_FACTOR:g} x the sensor's white noise, {100 * rel:.3g} %)"


def guard_rails(cal: Calibration, cfg: PipelineConfig, recent: NDArray[np.float64], current: Calibration | None,
                noise: float = 0.0) -> str:
    """Why ``cal`` must not be published ("" when it passes every check); ``noise``: the sensor's white noise in raw
    units (``white_noise``), which widens the residual limit (``residual_limit``)."""
    st = cal.stats
    if st is not None:
        if not st.converged:
            return f"fit did not converge after {st.iterations} iterations"
        limit, why = residual_limit(cal, cfg, noise)
        if not st.rms_relative <= limit:
            return f"residual RMS {100 * st.rms_relative:.2f} % > limit {100 * limit:.2f} %{why}"
    reason = plausibility(cal, cfg)
    if reason:
        return reason
    if current is not None and len(recent) >= 3:
        new_rms, cur_rms = rms_relative(cal, recent), rms_relative(current, recent)
        if new_rms > cur_rms * (1.0 + cfg.not_worse_tolerance):
            new_text, cur_text = apart(100 * new_rms, 100 * cur_rms)
            return (f"worse than the current calibration on the last {len(recent)} samples "
                    f"({new_text} % vs {cur_text} %)")
    return ""


def apart(a: float, b: float) -> tuple[str, str]:
    """``a`` and ``b`` with the fewest significant digits (3 to 8) that tell them apart: a comparison that failed
    shows why ("0.54124 % vs 0.54117 %", not "0.54 % vs 0.54 %")."""
    for digits in range(3, 9):
        sa, sb = f"{a:.{digits}g}", f"{b:.{digits}g}"
        if sa != sb:
            break
    return sa, sb


def plausibility(cal: Calibration, cfg: PipelineConfig) -> str:
    """Why the parameters of ``cal`` are implausible ("" when they are not): field norm, uncertainty, offset, gains.

    The checks of ``guard_rails`` that look at the calibration alone (not at its fit statistics or at
    the current calibration); ``margcal calibrate`` uses them to tell a batch fit that ran away.
    """
    det = abs(float(np.linalg.det(cal.matrix)))
    radius = cal.norm / det ** (1.0 / 3.0)
    if not cfg.norm_min <= radius <= cfg.norm_max:
        return (f"field norm {radius:.4g} {cfg.unit} outside the plausible range "
                f"[{cfg.norm_min:.4g}, {cfg.norm_max:.4g}] {cfg.unit}")
    rel = relative_std(cal)
    if rel:
        worst = max(rel, key=lambda k: rel[k])
        if rel[worst] > cfg.max_parameter_std:
            return (f"parameter uncertainty too large: std of {worst} is {100 * rel[worst]:.3g} % > "
                    f"{100 * cfg.max_parameter_std:.3g} % (the directions do not determine the model: {worst} needs "
                    f"{readings_for(worst, cfg.sensor)})")
    off = float(np.linalg.norm(cal.offset))
    limit = max(cfg.max_offset_ratio * radius, cfg.max_offset or 0.0)
    if off > limit:
        return _offset_reason(cal, cfg, off, radius, limit)
    gains = np.linalg.svd(cal.matrix, compute_uv=False) * radius / cal.norm
    if gains.min() < cfg.gain_min or gains.max() > cfg.gain_max:
        return f"axis gains {np.round(gains, 3).tolist()} outside [{cfg.gain_min:g}, {cfg.gain_max:g}]"
    return ""


def relative_std(cal: Calibration) -> dict[str, float]:
    """Each fitted parameter's one-sigma std on its own scale (empty without a covariance): offsets over the field's
    radius in raw units, matrix elements over the mean gain, the norm over itself; what ``max_parameter_std`` bounds."""
    std = cal.parameter_std()
    if not std:
        return {}
    radius = cal.norm / abs(float(np.linalg.det(cal.matrix))) ** (1.0 / 3.0)
    gain = cal.norm / radius  # mean gain of W: scale of its elements
    return {k: v / (radius if k.startswith("b_") else cal.norm if k == "norm" else gain) for k, v in std.items()}


def readings_for(name: str, sensor: str) -> str:
    """The readings that determine parameter ``name`` (``b_x``, ``w_xy``, ``norm``), for advice: an offset or a gain
    of one axis needs that axis pointing both ways; a cross term ``w_ij`` readings with axes i and j both large."""
    if name == "norm":
        return "the field's strength (reference_norm, or a position for the geomagnetic model)"
    axes = name.split("_")[-1]
    i, j = axes[0], axes[-1]
    if sensor == "accel":
        return f"poses with {i} pointing up and down" if i == j else \
            f"a pose tilted halfway between the {i} and {j} axes, {i} and {j} both far from 0"
    return f"readings with the field along +{i} and -{i}" if i == j else \
        f"readings with the field between the {i} and {j} axes, both components large"


def raise_hint(sensor: str, name: str, verb: str = "raise") -> str:
    """How to change the option a message names: ``raise NAME (replay/calibrate: --set NAME=...; node: SENSOR.NAME)``
    (``verb``: "raise", "lower"), the one wording of every such advice."""
    if name not in FIELD_SPECS:
        raise ConfigError(f"raise_hint: no option {name!r}")
    return f"{verb} {name} (replay/calibrate: --set {name}=...; node: {sensor}.{name})"


def _offset_reason(cal: Calibration, cfg: PipelineConfig, off: float, radius: float, limit: float) -> str:
    """Why the offset is refused, in the sensor's words (a magnetometer's hard iron, an accelerometer's bias)."""
    vec = ", ".join(f"{x:.4g}" for x in cal.offset)
    norms = "field norms" if cfg.sensor == "mag" else "gravity norms"
    absolute = f" or {cfg.max_offset:.4g} {cfg.unit} (max_offset)" if cfg.max_offset is not None else ""
    what = "the sensor really carries this hard iron" if cfg.sensor == "mag" else "the accelerometer really has this bias"
    return (f"offset {off:.4g} {cfg.unit} (fitted [{vec}], {off / radius:.4g} {norms}) > limit {limit:.4g} {cfg.unit}: "
            f"the larger of {cfg.max_offset_ratio:g} x {norms[:-1]} (max_offset_ratio){absolute}; if {what}, "
            f"{raise_hint(cfg.sensor, 'max_offset_ratio')}")
