"""Options of the streaming calibrator and the guard rails a fit must pass before it is published.

The guard rails follow ArduPilot's compass and accelerometer calibration checks (fitness limit,
offset limit, diagonal/off-diagonal limits, field strength check), restated for the
``calibrated = W (raw - b)`` model of ``calibration.py``:

- residual: ``stats.rms_relative`` (RMS of ``|W (v - b)| - norm`` over ``norm``) at most
  ``max_residual``;
- offset: ``|b|`` at most ``max_offset_ratio`` times the raw field radius (a hard iron of a few
  Earth fields is common on a robot; an accelerometer bias beyond ~0.35 g is a broken sensor);
- gains: the singular values of ``W`` scaled so that a sphere gives 1 (the axis ratios of the raw
  ellipsoid) within ``[gain_min, gain_max]``;
- field norm: the raw radius ``norm / |det W|^(1/3)`` within ``[norm_min, norm_max]`` (20–70 µT
  for the Earth field in the configured unit; 0.85–1.15 g for gravity);
- parameter uncertainty: the one-sigma std of every fitted parameter (from the fit's covariance;
  offsets over the radius, matrix elements over the mean gain) at most ``max_parameter_std``: a
  set the validator let through but that leaves the model undetermined (two great circles) is
  refused here;
- not worse: on the most recent samples, the RMS relative norm error of the new fit is at most
  ``(1 + not_worse_tolerance)`` times that of the current calibration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import MODELS, Calibration
from ..model.errors import ConfigError

__all__ = ["ACCEL_UNITS", "GRAVITY", "MAG_UNITS", "PipelineConfig", "guard_rails"]

GRAVITY = 9.80665
"""Standard gravity, m/s²."""

MAG_UNITS = {"T": 1.0, "tesla": 1.0, "mT": 1e-3, "uT": 1e-6, "µT": 1e-6, "nT": 1e-9, "gauss": 1e-4, "G": 1e-4,
             "mG": 1e-7, "mgauss": 1e-7}
"""Magnetometer units -> tesla."""
ACCEL_UNITS = {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "g": GRAVITY, "mg": GRAVITY * 1e-3}
"""Accelerometer units -> m/s²."""

EARTH_FIELD_RANGE_T = (20e-6, 70e-6)
"""Plausible geomagnetic field strength, tesla."""


@dataclass(frozen=True)
class PipelineConfig:
    """Options of ``SensorCalibrator``; ``for_sensor`` gives the defaults (also in msg_configs/margcal.yaml).

    Magnitudes (``min_magnitude``, ``max_magnitude``, ``norm_min``, ``norm_max``, ``reference_norm``)
    are in ``unit``; ratios (``max_residual``, thresholds) are fractions of the field norm.
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
    max_rate_hz: float = 2000.0
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

    @property
    def min_period_s(self) -> float:
        """Samples closer than this to the previous accepted one are a burst and dropped."""
        return 1.0 / self.max_rate_hz

    @classmethod
    def for_sensor(cls, sensor: str, unit: str | None = None, **overrides: Any) -> PipelineConfig:
        """Defaults for ``"mag"`` (raw unit tesla unless given) or ``"accel"`` (m/s² unless given)."""
        if sensor == "mag":
            u = unit or "T"
            if u not in MAG_UNITS:
                lo, hi, scale = 0.0, math.inf, 1.0  # unknown unit: no field-strength check
            else:
                scale = MAG_UNITS[u]
                lo, hi = EARTH_FIELD_RANGE_T[0] / scale, EARTH_FIELD_RANGE_T[1] / scale
            top = 20.0 * EARTH_FIELD_RANGE_T[1] / scale
            base = cls(sensor="mag", unit=u, reference_norm=None, norm_min=lo, norm_max=hi,
                       min_magnitude=1e-3 * EARTH_FIELD_RANGE_T[0] / scale, max_magnitude=top)
        elif sensor == "accel":
            u = unit or "m/s^2"
            g = GRAVITY / ACCEL_UNITS.get(u, 1.0)
            base = cls(sensor="accel", unit=u, reference_norm=g, norm_min=0.85 * g, norm_max=1.15 * g,
                       min_magnitude=1e-3 * g, max_magnitude=16.0 * g, min_points=12, refit_every=1,
                       refit_min_interval_s=0.0, recheck_interval_s=10.0, max_offset_ratio=0.35, gain_min=0.85,
                       gain_max=1.15, recent_samples=40, change_window=6, change_threshold=0.03,
                       change_min_duration_s=0.0, outlier_threshold=0.2, max_residual=0.03)
        else:
            msg = f"sensor must be 'mag' or 'accel', got {sensor!r}"
            raise ConfigError(msg)
        return replace(base, **overrides).checked() if overrides else base.checked()

    def checked(self) -> PipelineConfig:
        """Return self after checking every option; ConfigError names the bad one."""
        if self.model not in MODELS:
            raise ConfigError(f"model must be one of {MODELS}, got {self.model!r}")
        positive = ("max_parameter_std", "max_rate_hz", "max_residual", "max_offset_ratio", "gain_max", "change_threshold",
                    "outlier_threshold", "gate_window_s", "gate_cv_threshold", "max_magnitude")
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and v > 0 and not math.isnan(v)):
                raise ConfigError(f"{name} must be > 0, got {v!r}")
        for name in ("max_iter", "n_bins", "per_bin", "min_points", "refit_every", "recent_samples", "change_window"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if not 0 < self.gain_min <= 1.0 <= self.gain_max:
            raise ConfigError(f"need 0 < gain_min <= 1 <= gain_max, got {self.gain_min}, {self.gain_max}")
        if not 0 <= self.norm_min < self.norm_max:
            raise ConfigError(f"need 0 <= norm_min < norm_max, got {self.norm_min}, {self.norm_max}")
        if self.min_magnitude < 0 or self.min_magnitude >= self.max_magnitude:
            raise ConfigError(f"need 0 <= min_magnitude < max_magnitude, got {self.min_magnitude}, {self.max_magnitude}")
        if self.change_window > self.recent_samples:
            raise ConfigError(f"change_window ({self.change_window}) must not exceed recent_samples ({self.recent_samples})")
        if not self.change_min_duration_s >= 0:
            raise ConfigError(f"change_min_duration_s must be >= 0, got {self.change_min_duration_s}")
        if self.not_worse_tolerance < 0:
            raise ConfigError(f"not_worse_tolerance must be >= 0, got {self.not_worse_tolerance}")
        if self.reference_norm is not None and not self.reference_norm > 0:
            raise ConfigError(f"reference_norm must be > 0 or None, got {self.reference_norm}")
        return self


def _rms_rel(cal: Calibration, pts: NDArray[np.float64]) -> float:
    e = cal.norm_error(pts) / cal.norm
    return float(np.sqrt(np.mean(e * e)))


def guard_rails(cal: Calibration, cfg: PipelineConfig, recent: NDArray[np.float64], current: Calibration | None) -> str:
    """Why ``cal`` must not be published ("" when it passes every check)."""
    st = cal.stats
    if st is not None:
        if not st.converged:
            return f"fit did not converge after {st.iterations} iterations"
        if not st.rms_relative <= cfg.max_residual:
            return f"residual RMS {100 * st.rms_relative:.2f} % > limit {100 * cfg.max_residual:.2f} %"
    det = abs(float(np.linalg.det(cal.matrix)))
    radius = cal.norm / det ** (1.0 / 3.0)
    if not cfg.norm_min <= radius <= cfg.norm_max:
        return (f"field norm {radius:.4g} {cfg.unit} outside the plausible range "
                f"[{cfg.norm_min:.4g}, {cfg.norm_max:.4g}] {cfg.unit}")
    std = cal.parameter_std()
    if std:
        gain = cal.norm / radius  # mean gain of W: scale of its elements
        rel = {k: v / (radius if k.startswith("b_") else cal.norm if k == "norm" else gain) for k, v in std.items()}
        worst = max(rel, key=lambda k: rel[k])
        if rel[worst] > cfg.max_parameter_std:
            return (f"parameter uncertainty too large: std of {worst} is {100 * rel[worst]:.2g} % > "
                    f"{100 * cfg.max_parameter_std:.2g} % (the directions do not determine the model)")
    off = float(np.linalg.norm(cal.offset))
    if off > cfg.max_offset_ratio * radius:
        return f"offset {off:.4g} {cfg.unit} > limit {cfg.max_offset_ratio:g} x field norm ({cfg.max_offset_ratio * radius:.4g})"
    gains = np.linalg.svd(cal.matrix, compute_uv=False) * radius / cal.norm
    if gains.min() < cfg.gain_min or gains.max() > cfg.gain_max:
        return f"axis gains {np.round(gains, 3).tolist()} outside [{cfg.gain_min:g}, {cfg.gain_max:g}]"
    if current is not None and len(recent) >= 3:
        new_rms, cur_rms = _rms_rel(cal, recent), _rms_rel(current, recent)
        if new_rms > cur_rms * (1.0 + cfg.not_worse_tolerance):
            return (f"worse than the current calibration on the last {len(recent)} samples "
                    f"({100 * new_rms:.2f} % vs {100 * cur_rms:.2f} %)")
    return ""
