"""The effect registry ``EFFECTS`` and the sensor model that applies it.

A raw three-axis reading of a physical vector ``h`` (tesla or m/s², ``|h| = truth.norm``) is made as

    v = W^-1 h + b + e                     (the inverse of ``Calibration.apply``)

with the true calibration ``(b, W)`` and white noise ``e``. On top of this baseline, ``EFFECTS`` holds
the effects real sensors show and the baseline lacks (the list of DESIGN.md, "The sim-to-real gap").
``sensor_model`` applies them in physical order:

1. field side (body frame): ``disturbance`` / ``motion_leak`` add a vector, ``soft_iron`` deforms the
   field ``h -> (I + m S) h``, ``misalignment`` rotates it into the sensor frame;
2. sensor model: ``nonorthogonality`` (skewed axes), gains ``W^-1`` (with the ``temperature`` gain
   change), offset ``b`` (plus ``bias_drift``, ``hard_iron_jump`` and the ``temperature`` offset), then
   ``nonlinearity`` (a cubic term of the whole reading, offset included: an ADC sees the raw value);
3. read-out: noise (baseline and the ``noise`` effect), ``saturation`` (clipping), ``quantization``.

Every random quantity of an effect is drawn from its own generator seeded from one draw of the
caller's ``rng``, so for a given seed a magnitude change only rescales the effect (the diagnosis fits
magnitudes on common random numbers) and magnitude 0 reproduces the effect-free data bit for bit.

Users switch effects on through ``simulation.simulate`` / ``tumbling`` / ``magnetometer_stream``
(``effects={name: magnitude}``); ``simulation`` re-exports ``Effect`` and ``EFFECTS``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from ..model.calibration import Calibration
from ..model.errors import ConfigError
from .patterns import unit_vectors

__all__ = ["EFFECTS", "Effect", "check_effects", "sensor_model"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Effect:
    """A named deviation from the baseline sensor model, switched on with ``effects={name: magnitude}``.

    Attributes:
        name: registry key.
        description: what it does and what its magnitude means.
        sensors: the sensors it applies to.
        observable: False when norm-based calibration data cannot see it at all.
        group: effects with the same group give the same data family and cannot be told apart.
        magnitude_unit: unit of the magnitude (0 is always "off").
        default_magnitude: a typical value.
        magnitude_range: the range a diagnosis should search.
        stage: "field" (physical vector), "sensor" (sensor model) or "readout".
        limit: magnitudes must stay below this (inf when unbounded).
        varying: the effect changes in time (drift, warm-up, bursts, a jump): a property of the
            moment, not of the sensor; the others are the same at every instant.
    """

    name: str
    description: str
    sensors: tuple[str, ...]
    observable: bool
    group: str
    magnitude_unit: str
    default_magnitude: float
    magnitude_range: tuple[float, float]
    stage: str = "sensor"
    limit: float = math.inf
    varying: bool = False


_BOTH = ("mag", "accel")
EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect("noise", "extra white Gaussian noise per axis, std = magnitude x field radius (raw units), "
               "on top of the baseline noise", _BOTH, True, "noise", "fraction of norm (std)", 0.005, (0.0, 0.05),
               "readout"),
        Effect("quantization", "readings rounded to an LSB step of magnitude x field radius", _BOTH, True,
               "quantization", "fraction of norm (LSB step)", 0.002, (0.0, 0.02), "readout"),
        Effect("nonorthogonality", "sensor axes skewed: y tilted towards x, z towards x and y, by up to magnitude "
               "degrees each (random share 0.5-1, random sign); a non-symmetric mixing", _BOTH, True,
               "ellipsoid_shape", "deg (largest axis skew)", 1.0, (0.0, 10.0), "sensor", 30.0),
        Effect("soft_iron", "field deformed by I + magnitude S, S a random symmetric matrix of spectral norm 1",
               ("mag",), True, "ellipsoid_shape", "fraction (spectral norm of the deformation)", 0.05, (0.0, 0.3),
               "field", 1.0),
        Effect("misalignment", "sensor frame rotated by magnitude degrees about a random axis: the norm is kept, "
               "so norm-based calibration cannot see it", _BOTH, False, "misalignment", "deg", 2.0, (0.0, 10.0),
               "field"),
        Effect("bias_drift", "offset drifts linearly at magnitude x field radius per minute along a random "
               "direction, plus a random walk of rms 0.5 x that per sqrt(minute) per axis", _BOTH, True,
               "bias_drift", "fraction of norm per minute", 0.01, (0.0, 0.1), "sensor", varying=True),
        Effect("temperature", "offset (random direction) and per-axis gains (random signs) linear in temperature "
               "about its mean: magnitude x field radius per K and magnitude per K; a warm-up curve of 25->40 °C "
               "is synthesised when no temperature is given", _BOTH, True, "temperature",
               "fraction of norm per K", 0.002, (0.0, 0.03), "sensor", varying=True),
        Effect("disturbance", "transient field bursts: about 5 % of the time in windows of 1-3 s, an extra "
               "vector of random direction and 0.5-1 x magnitude x norm is added", ("mag",), True, "disturbance",
               "fraction of norm (burst amplitude)", 0.3, (0.0, 2.0), "field", varying=True),
        Effect("motion_leak", "linear acceleration left in: about 20 % of the time in windows of 0.2-1 s, an "
               "extra acceleration of random direction and 0.5-1 x magnitude x norm", ("accel",), True,
               "motion_leak", "fraction of norm (acceleration amplitude)", 0.05, (0.0, 0.5), "field",
               varying=True),
        Effect("saturation", "readings clipped at a full scale of (1 - magnitude) x the largest clean reading of "
               "the recording (what the motion reached, not what the sphere would)", _BOTH, True, "saturation",
               "fraction of the range clipped", 0.1, (0.0, 0.3), "readout", 1.0),
        Effect("nonlinearity", "cubic term per axis of the whole reading, offset included (an ADC's): v_i + "
               "magnitude c_i v_i^3 / r_i^2 (c_i = ±0.5-1, r_i = |b_i| + the axis' full deflection): magnitude is "
               "the relative deviation at the largest reading; a hard iron makes it quadratic in the field as well",
               _BOTH, True, "nonlinearity", "fraction at the largest reading", 0.01, (0.0, 0.1), "sensor", 1.0 / 3.0),
        Effect("hard_iron_jump", "the offset steps once by magnitude x field radius along a random direction, "
               "at a random time in the middle half of the recording (a magnetised part moved or was "
               "attached on the platform)", ("mag",), True, "hard_iron_jump", "fraction of norm (step size)", 0.1,
               (0.0, 1.0), "sensor", varying=True),
    )
}
"""The registry of effects, in the order ``simulate`` applies them within a stage."""

_EFFECT_SEED = {name: i + 1 for i, name in enumerate(EFFECTS)}


def check_effects(effects: dict[str, float] | None, sensor: str) -> dict[str, float]:
    """Validated ``{name: float magnitude}`` for a ``sensor`` ("mag", "accel" or "" for any).

    Raises:
        ConfigError: unknown effect, magnitude negative, non-finite or not below its ``limit``, or an
            effect for another sensor.
    """
    out: dict[str, float] = {}
    for name, value in (effects or {}).items():
        if name not in EFFECTS:
            msg = f"unknown effect {name!r}; choose from {sorted(EFFECTS)}"
            raise ConfigError(msg)
        eff = EFFECTS[name]
        m = float(value)
        if not math.isfinite(m) or m < 0 or m >= eff.limit:
            msg = f"effect {name!r} magnitude must be in [0, {eff.limit}) ({eff.magnitude_unit}), got {value!r}"
            raise ConfigError(msg)
        if sensor and sensor not in eff.sensors:
            msg = f"effect {name!r} applies to {eff.sensors}, not to a {sensor!r} sensor"
            raise ConfigError(msg)
        out[name] = m
    return out


def _bursts(t: Array, rng: np.random.Generator, coverage: float, dur: tuple[float, float]) -> Array:
    """Windows covering about ``coverage`` of the time span, each with one vector of rms-norm 0.5-1."""
    n = t.shape[0]
    span = float(t[-1] - t[0]) if n > 1 else 0.0
    k = max(1, round(coverage * span / (0.5 * (dur[0] + dur[1]))))
    centres = rng.integers(0, n, size=k)
    widths = rng.uniform(dur[0], dur[1], size=k)
    vecs = unit_vectors(rng.normal(size=(k, 3))) * rng.uniform(0.5, 1.0, size=(k, 1))
    lo = np.searchsorted(t, t[centres] - widths / 2, side="left")
    hi = np.maximum(np.searchsorted(t, t[centres] + widths / 2, side="right"), centres + 1)
    delta = np.zeros((n + 1, 3))  # difference array: vec added on [lo, hi)
    np.add.at(delta, lo, vecs)
    np.add.at(delta, hi, -vecs)
    return np.cumsum(delta, axis=0)[:n]


def _warmup_temperature(t: Array) -> Array:
    """A deterministic warm-up curve 25 -> ~40 °C with a slow ripple (used when none is given)."""
    span = max(float(t[-1] - t[0]), 1e-9) if t.size > 1 else 1.0
    tau = (t - t[0]) / span
    temp: Array = 25.0 + 15.0 * (1.0 - np.exp(-3.0 * tau)) + 1.5 * np.sin(2 * np.pi * 2.0 * tau)
    return temp


def sensor_model(
    truth: Calibration,
    h: Array,
    t: Array,
    rng: np.random.Generator,
    noise: float,
    effects: dict[str, float],
    temperature: Array | None,
    extra_offset: Array | None = None,
) -> tuple[Array, Array | None, Array | None]:
    """Raw readings of the physical vectors ``h`` (n, 3): returns (raw, temperature, true offset per sample)."""
    n = h.shape[0]
    seed = int(rng.integers(0, 2**63 - 1))

    def sub(name: str) -> np.random.Generator:
        return np.random.default_rng([seed, _EFFECT_SEED[name]])

    m = effects.get
    norm = truth.norm
    w_inv = np.linalg.inv(truth.matrix)
    r_raw = truth.raw_radius
    r_axis = norm * np.linalg.norm(w_inv, axis=1)  # largest offset-free deflection per axis
    g = h.copy()
    # 1. field side
    if m("disturbance", 0.0) > 0:
        g += _bursts(t, sub("disturbance"), 0.05, (1.0, 3.0)) * (m("disturbance", 0.0) * norm)
    if m("motion_leak", 0.0) > 0:
        g += _bursts(t, sub("motion_leak"), 0.2, (0.2, 1.0)) * (m("motion_leak", 0.0) * norm)
    if m("soft_iron", 0.0) > 0:
        a = sub("soft_iron").normal(size=(3, 3))
        s = 0.5 * (a + a.T)
        s /= np.abs(np.linalg.eigvalsh(s)).max()
        g = g @ (np.eye(3) + m("soft_iron", 0.0) * s).T
    if m("misalignment", 0.0) > 0:
        axis = unit_vectors(sub("misalignment").normal(size=3))
        g = Rotation.from_rotvec(axis * math.radians(m("misalignment", 0.0))).apply(g)
    # 2. sensor model
    if m("nonorthogonality", 0.0) > 0:
        r = sub("nonorthogonality")
        ang = np.radians(m("nonorthogonality", 0.0)) * r.uniform(0.5, 1.0, size=3) * r.choice([-1.0, 1.0], size=3)
        sa, sb, sc = np.sin(ang)
        skew = np.array([[1.0, 0.0, 0.0], [sa, math.sqrt(1 - sa * sa), 0.0], [sb, sc, math.sqrt(1 - sb * sb - sc * sc)]])
        g = g @ skew.T
    u = g @ w_inv.T  # offset-free raw reading, Camps Eq. 1 without beta
    offset = np.broadcast_to(truth.offset, (n, 3)).copy()
    varying = False
    temp = None if temperature is None else np.asarray(temperature, dtype=np.float64)
    if m("temperature", 0.0) > 0:
        if temp is None:
            temp = _warmup_temperature(t)
        r = sub("temperature")
        direction = unit_vectors(r.normal(size=3))
        signs = r.choice([-1.0, 1.0], size=3) * r.uniform(0.5, 1.0, size=3)
        dtemp = (temp - temp.mean())[:, None]
        mt = m("temperature", 0.0)
        u = u * (1.0 + mt * signs * dtemp)
        offset += mt * r_raw * direction * dtemp
        varying = True
    if m("bias_drift", 0.0) > 0:
        r = sub("bias_drift")
        direction = unit_vectors(r.normal(size=3))
        minutes = (t - t[0]) / 60.0
        # the random walk lives on a 1-s time grid (interpolated at the samples), so it is a function of
        # time: two recordings of the same sensor over the same span share it whatever their rates
        n_knots = math.ceil(60.0 * float(minutes[-1])) + 2 if n else 2
        knots = np.arange(n_knots) / 60.0
        walk = np.cumsum(r.normal(size=(n_knots, 3)) * math.sqrt(1.0 / 60.0), axis=0)
        walk -= walk[0]
        steps = np.column_stack([np.interp(minutes, knots, walk[:, a]) for a in range(3)])
        offset += m("bias_drift", 0.0) * r_raw * (direction * minutes[:, None] + 0.5 * steps)
        varying = True
    if m("hard_iron_jump", 0.0) > 0 and n > 0:
        r = sub("hard_iron_jump")
        direction = unit_vectors(r.normal(size=3))
        t_jump = t[0] + r.uniform(0.25, 0.75) * (t[-1] - t[0])
        offset += m("hard_iron_jump", 0.0) * r_raw * direction * (t >= t_jump)[:, None]
        varying = True
    if extra_offset is not None:
        offset += extra_offset
        varying = True
    raw = u + offset
    if m("nonlinearity", 0.0) > 0:  # the converter sees the whole reading, offset (hard iron) included
        r = sub("nonlinearity")
        c = r.choice([-1.0, 1.0], size=3) * r.uniform(0.5, 1.0, size=3)
        r_full = np.abs(truth.offset) + r_axis
        raw = raw + m("nonlinearity", 0.0) * c * raw**3 / r_full**2
    peak = float(np.max(np.abs(raw))) if n else 0.0  # the largest clean reading of this motion
    # 3. read-out
    if noise > 0:
        raw += np.random.default_rng([seed, 0]).normal(size=(n, 3)) * (noise * r_raw)
    if m("noise", 0.0) > 0:
        raw += sub("noise").normal(size=(n, 3)) * (m("noise", 0.0) * r_raw)
    if m("saturation", 0.0) > 0:
        full_scale = (1.0 - m("saturation", 0.0)) * peak
        raw = np.clip(raw, -full_scale, full_scale)
    if m("quantization", 0.0) > 0:
        step = m("quantization", 0.0) * r_raw
        raw = np.round(raw / step) * step
    return raw, temp, (offset if varying else None)
