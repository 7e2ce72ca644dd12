"""Seeded sensor simulator: true calibrations, coverage patterns, motion time series and named effects.

This module is the face of the simulator; the parts live in

- ``patterns``: coverage patterns ``directions`` / ``PATTERNS`` (Olivares et al. 2013, Gietzelt et al. 2013);
- ``effects``: the effect registry ``EFFECTS`` / ``Effect`` and the sensor model applying it;
- ``motion``: orientation histories ``Motion``, ``tumbling_motion``, ``smooth_motion`` and the offset
  events ``HardIronJump`` / ``OffsetDrift``;

and this module keeps ``Recording``, ``random_sensor`` and the generators of recordings. Import from
here: every name of ``__all__`` is re-exported.

A raw three-axis reading of a physical vector ``h`` (tesla or m/s², ``|h| = truth.norm``) is made as

    v = W^-1 h + b + e                     (the inverse of ``Calibration.apply``)

with the true calibration ``(b, W)`` of ``random_sensor`` and white noise ``e``, plus the effects of
``EFFECTS`` in physical order (field side, sensor model, read-out; see ``effects``). Every random
quantity of an effect is drawn from its own generator seeded from one draw of the caller's ``rng``, so
for a given seed a magnitude change only rescales the effect and magnitude 0 reproduces the effect-free
data bit for bit.

Generators: ``simulate`` (readings along given directions at any times ``t``), ``tumbling``
(accelerometer and gyro: ``f = R^T (a + g e_z)``) and ``magnetometer_stream`` (``h = R^T m`` for a
field of inclination 60°, with ``HardIronJump`` / ``OffsetDrift`` events). One ``Motion`` can drive
both sensors of an IMU.

Cost: ``simulate`` is vectorised; 10^4 samples with any effect take about 1-3 ms here.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model.calibration import Calibration
from ..model.errors import ConfigError, InputError, as_points, as_vector3
from ..recordings.recording import Recording
from .effects import EFFECTS, Effect
from .effects import check_effects as _check_effects
from .effects import sensor_model as _sensor_model
from .motion import HardIronJump, Motion, OffsetDrift, smooth_motion, tumbling_motion
from .motion import sample_times as _sample_times
from .patterns import PATTERNS, directions
from .patterns import unit_vectors as _unit

__all__ = [
    "EFFECTS", "GRAVITY", "PATTERNS", "Effect", "HardIronJump", "Motion", "OffsetDrift", "Recording", "directions",
    "magnetometer_stream", "random_sensor", "simulate", "smooth_motion", "tumbling", "tumbling_motion"
]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

GRAVITY = 9.80665
"""Standard gravity, m/s² (the accelerometer reference norm)."""
EARTH_FIELD_T = 50e-6
"""Typical geomagnetic field norm, tesla."""
INCLINATION_DEG = 60.0
"""Inclination of the simulated geomagnetic field below the horizon."""


# -- the data a simulation produces ----------------------------------------------------------------


# -- true sensors ----------------------------------------------------------------------------------


def random_sensor(
    rng: np.random.Generator,
    kind: str = "mag",
    *,
    model: str = "sym",
    offset_scale: float | None = None,
    gain_spread: float = 0.05,
    skew: float = 0.02,
    norm: float | None = None,
) -> Calibration:
    """A realistic TRUE calibration (``apply`` maps raw -> physical) for a simulated sensor.

    Args:
        rng: the random generator.
        kind: "mag" (tesla, norm 50 µT, hard iron up to ``offset_scale`` x norm, default 3) or
            "accel" (m/s², norm 9.80665, offsets 0.1-0.5 m/s² per axis: ``offset_scale`` 0.05 x norm).
        model: "eye" (offset only), "diag" (offset and gains) or "sym" (plus symmetric cross terms).
        offset_scale: largest offset as a fraction of the norm.
        gain_spread: gains are ``1 ± gain_spread`` (uniform).
        skew: symmetric cross terms are ``± skew`` (uniform), "sym" only.
        norm: the reference norm (default: the physical one of ``kind``).

    Returns:
        A Calibration with ``sensor`` and ``unit`` set.
    """
    if kind not in ("mag", "accel"):
        msg = f"kind must be 'mag' or 'accel', got {kind!r}"
        raise ConfigError(msg)
    if model not in ("eye", "diag", "sym"):
        msg = f"model must be 'eye', 'diag' or 'sym', got {model!r}"
        raise ConfigError(msg)
    if kind == "mag":
        ref = EARTH_FIELD_T if norm is None else float(norm)
        direction = _unit(rng.normal(size=3))
        scale = 3.0 if offset_scale is None else offset_scale
        offset = direction * ref * scale * rng.uniform(0.1, 1.0)
        unit = "T"
    else:
        ref = GRAVITY if norm is None else float(norm)
        scale = 0.05 if offset_scale is None else offset_scale
        offset = rng.choice([-1.0, 1.0], size=3) * rng.uniform(0.2, 1.0, size=3) * ref * scale
        unit = "m/s^2"
    gains = np.ones(3) if model == "eye" else 1.0 + rng.uniform(-gain_spread, gain_spread, size=3)
    gain = np.diag(gains)
    if model == "sym":
        sxy, sxz, syz = rng.uniform(-skew, skew, size=3)
        gain = gain + np.array([[0.0, sxy, sxz], [sxy, 0.0, syz], [sxz, syz, 0.0]])
    # Camps Eq. 1: V = alpha h + beta with alpha = W^-1 symmetric.
    matrix: Array = np.asarray(np.linalg.inv(gain), dtype=np.float64)
    return Calibration(offset, matrix, ref, model=model, sensor=kind, unit=unit, method="truth")


# -- recordings ------------------------------------------------------------------------------------


def _times(t: ArrayLike | None, n: int) -> Array:
    if t is None:
        return np.arange(n, dtype=np.float64)
    arr = np.asarray(t, dtype=np.float64).reshape(-1)
    if arr.shape != (n,):
        msg = f"t must have one time per direction ({n}), got shape {arr.shape}"
        raise InputError(msg)
    if not np.isfinite(arr).all() or (n > 1 and np.any(np.diff(arr) < 0)):
        msg = "t must be finite and non-decreasing"
        raise InputError(msg)
    return arr


def _temperature(temperature: ArrayLike | None, n: int) -> Array | None:
    if temperature is None:
        return None
    arr = np.asarray(temperature, dtype=np.float64).reshape(-1)
    if arr.shape != (n,) or not np.isfinite(arr).all():
        msg = f"temperature must be {n} finite values (°C), got shape {arr.shape}"
        raise InputError(msg)
    return arr


def simulate(
    truth: Calibration,
    dirs: ArrayLike,
    *,
    noise: float = 0.0,
    rng: np.random.Generator,
    t: ArrayLike | None = None,
    effects: dict[str, float] | None = None,
    temperature: ArrayLike | None = None,
) -> Recording:
    """Raw readings of a field of norm ``truth.norm`` along ``dirs``: ``v = W^-1 h + b + e`` plus effects.

    Args:
        truth: the true calibration (its ``sensor`` restricts the allowed effects when set).
        dirs: (n, 3) directions of the physical vector in the body frame (normalised here).
        noise: white noise std per axis as a fraction of the norm (in raw units: of the field radius).
        rng: the random generator; one draw seeds all the randomness of this call.
        t: sample times, seconds (default ``0, 1, 2, ...``): used by the time-dependent effects.
        effects: ``{name: magnitude}`` from ``EFFECTS``; magnitude 0 is the same as absent.
        temperature: °C per sample (for the temperature effect; synthesised when needed and absent).

    Returns:
        A Recording with ``true_field`` = ``norm * dirs``.

    Raises:
        InputError: bad ``dirs``, ``t`` or ``temperature``.
        ConfigError: unknown effect, negative magnitude, an effect for another sensor, negative noise.
    """
    d = as_points(dirs, "dirs")
    lengths = np.linalg.norm(d, axis=1)
    if np.any(lengths == 0):
        msg = "dirs has zero vectors; directions must be non-zero"
        raise InputError(msg)
    if not (math.isfinite(noise) and noise >= 0):
        msg = f"noise must be a non-negative fraction of the norm, got {noise!r}"
        raise ConfigError(msg)
    n = d.shape[0]
    times = _times(t, n)
    eff = _check_effects(effects, truth.sensor)
    h = d / lengths[:, None] * truth.norm
    raw, temp, offsets = _sensor_model(truth, h, times, rng, noise, eff, _temperature(temperature, n))
    return Recording(t=times, raw=raw, truth=truth, true_field=h, temp=temp, effects=eff, sensor=truth.sensor,
                     unit=truth.unit, true_offset=offsets)


def tumbling(
    truth: Calibration,
    duration_s: float,
    rate_hz: float,
    rng: np.random.Generator,
    *,
    still_fraction: float = 0.6,
    noise: float = 0.002,
    gravity: float | None = None,
    effects: dict[str, float] | None = None,
    temperature: ArrayLike | None = None,
    motion: Motion | None = None,
    gyro_noise: float = 0.005,
) -> Recording:
    """An accelerometer (and gyro) time series of a tumbling body with still periods.

    The accelerometer measures the specific force in the body frame, ``f = R^T (a + g e_z)``; at rest
    ``|f| = gravity``. ``still`` is the true rest mask (``motion_leak`` adds accelerations within it).

    Args:
        truth: the true accelerometer calibration.
        duration_s: length, seconds.
        rate_hz: sample rate.
        rng: the random generator.
        still_fraction: share of the time at rest.
        noise: accelerometer white noise, fraction of the norm.
        gravity: gravity in the truth's output unit (default ``truth.norm``, 9.80665 m/s² for
            ``random_sensor(rng, "accel")``).
        effects: ``{name: magnitude}`` as in ``simulate``.
        temperature: °C per sample.
        motion: a motion to use instead of a new ``tumbling_motion`` (resampled to ``rate_hz``).
        gyro_noise: gyro white noise std, rad/s.
    """
    t = _sample_times(duration_s, rate_hz)
    if motion is None:
        motion = tumbling_motion(duration_s, rate_hz, rng, still_fraction=still_fraction)
    else:
        motion = motion.resample(t)
    eff = _check_effects(effects, truth.sensor)
    g = truth.norm if gravity is None else float(gravity)
    f = motion.rot.inv().apply(motion.lin_acc * (g / GRAVITY) + np.array([0.0, 0.0, g]))
    raw, temp, offsets = _sensor_model(truth, f, t, rng, noise, eff, _temperature(temperature, t.size))
    gyro = motion.gyro + rng.normal(size=motion.gyro.shape) * gyro_noise
    return Recording(t=t, raw=raw, truth=truth, true_field=f, still=motion.still.copy(), gyro=gyro, temp=temp,
                     effects=eff, sensor=truth.sensor or "accel", unit=truth.unit, true_offset=offsets)


def magnetometer_stream(
    truth: Calibration,
    duration_s: float,
    rate_hz: float,
    rng: np.random.Generator,
    *,
    motion: str | Motion = "smooth",
    noise: float = 0.005,
    effects: dict[str, float] | None = None,
    events: Sequence[HardIronJump | OffsetDrift] = (),
    temperature: ArrayLike | None = None,
    inclination_deg: float = INCLINATION_DEG,
    gyro_noise: float = 0.005,
) -> Recording:
    """A magnetometer time series of a rotating body, with optional hard-iron jumps and drift.

    The world field is ``norm (0, cos I, -sin I)`` (ENU, inclination I); the body sees ``R^T m``.

    Args:
        truth: the true magnetometer calibration.
        duration_s: length, seconds.
        rate_hz: sample rate.
        rng: the random generator.
        motion: "smooth" (``smooth_motion``, continuous), "tumble" (``tumbling_motion``) or a Motion
            (e.g. the one an accelerometer stream shares; resampled to ``rate_hz``).
        noise: white noise, fraction of the norm.
        effects: ``{name: magnitude}`` as in ``simulate``.
        events: HardIronJump / OffsetDrift changes of the true offset (``Recording.true_offset``).
        temperature: °C per sample.
        inclination_deg: field inclination below the horizon.
        gyro_noise: gyro white noise std, rad/s.
    """
    t = _sample_times(duration_s, rate_hz)
    if isinstance(motion, Motion):
        mot = motion.resample(t)
    elif motion == "smooth":
        mot = smooth_motion(duration_s, rate_hz, rng)
    elif motion == "tumble":
        mot = tumbling_motion(duration_s, rate_hz, rng)
    else:
        msg = f"motion must be 'smooth', 'tumble' or a Motion, got {motion!r}"
        raise ConfigError(msg)
    eff = _check_effects(effects, truth.sensor)
    inc = math.radians(inclination_deg)
    field_world = truth.norm * np.array([0.0, math.cos(inc), -math.sin(inc)])
    h = mot.rot.inv().apply(np.tile(field_world, (t.size, 1)))
    extra = None
    if events:
        extra = np.zeros((t.size, 3))
        for ev in events:
            if isinstance(ev, HardIronJump):
                extra[t >= ev.time] += as_vector3(ev.delta, "delta")
            elif isinstance(ev, OffsetDrift):
                extra += np.clip(t - ev.start, 0.0, None)[:, None] * as_vector3(ev.rate, "rate")
            else:
                msg = f"events must be HardIronJump or OffsetDrift, got {type(ev).__name__}"
                raise ConfigError(msg)
    raw, temp, offsets = _sensor_model(truth, h, t, rng, noise, eff, _temperature(temperature, t.size), extra)
    gyro = mot.gyro + rng.normal(size=mot.gyro.shape) * gyro_noise
    return Recording(t=t, raw=raw, truth=truth, true_field=h, still=mot.still.copy(), gyro=gyro, temp=temp,
                     effects=eff, sensor=truth.sensor or "mag", unit=truth.unit, true_offset=offsets)
