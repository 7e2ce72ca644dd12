"""Raw units of a recording or a driver, and the plausibility limits that follow from them.

A magnetometer may report tesla (ROS), µT, gauss or milligauss, or raw integer counts whose scale only
the driver knows (an HMC5883L at gain 1090 LSB/G reads about 540 counts in a 50 µT field, an LSM9DS1
at 6842 LSB/G about 3 400). The magnitude limits of the intake and the field-strength guard rail only
make sense in a known unit:

- a known unit (``MAG_UNITS``, ``ACCEL_UNITS``; looked up as given, then case-insensitively) scales
  the SI limits: the Earth field 20–70 µT, gravity 0.85–1.15 g, the absolute offset limit;
- an unknown unit (``counts``, ``LSB``, ``raw``, anything else) has no scale: the field-strength
  check is off and the intake learns its magnitude limits from the first samples
  (``LEARN_SAMPLES``, ``LEARN_LOW`` and ``LEARN_HIGH`` times their median norm), which the status says.
  First samples that are not the field (a sensor not yet configured reads a few counts) would make
  limits that drop every real reading: when ``RELEARN_SHARE`` of the last ``RELEARN_FACTOR`` times
  ``LEARN_SAMPLES`` samples fall outside them, the limits are learnt again from those samples (not while a
  calibration's field lies within the limits: then the samples, not the limits, are wrong; nor from samples
  that do not turn: a saturated or stuck sensor after a good start).
"""

from __future__ import annotations

__all__ = ["ACCEL_UNITS", "GRAVITY", "LEARN_HIGH", "LEARN_LOW", "LEARN_SAMPLES", "MAG_UNITS", "RELEARN_FACTOR", "RELEARN_SHARE",
           "other_sensors_unit", "unit_scale", "unknown_unit_note"]

GRAVITY = 9.80665
"""Standard gravity, m/s²."""

MAG_UNITS = {"T": 1.0, "tesla": 1.0, "mT": 1e-3, "uT": 1e-6, "µT": 1e-6, "μT": 1e-6, "microtesla": 1e-6,
             "nT": 1e-9, "gauss": 1e-4, "G": 1e-4, "Gs": 1e-4, "mG": 1e-7, "mgauss": 1e-7, "milligauss": 1e-7}
"""Magnetometer units -> tesla."""
ACCEL_UNITS = {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "g": GRAVITY, "mg": GRAVITY * 1e-3}
"""Accelerometer units -> m/s²."""

LEARN_SAMPLES = 20
"""Samples whose median norm sets the magnitude limits when the unit is unknown."""
LEARN_LOW = 1e-3
"""Lower magnitude limit in an unknown unit, times the learnt median norm (a zero vector, a dead axis)."""
LEARN_HIGH = 20.0
"""Upper magnitude limit in an unknown unit, times the learnt median norm (the ratio of the SI limits:
1.4 mT over 70 µT for the magnetometer)."""
RELEARN_FACTOR = 5
"""Learnt limits are relearnt when ``RELEARN_SHARE`` of the last this many times ``learn_magnitude_samples``
samples (100 at the defaults: 2 s at 50 Hz) fell outside them ..."""
RELEARN_SHARE = 0.9
"""... this share (nearly all: a few samples that pass, one bad stretch among real ones, do not stop it),
from the norms of the last ``learn_magnitude_samples`` of them."""


def unit_scale(sensor: str, unit: str) -> float | None:
    """SI value of one ``unit`` of ``sensor`` (tesla or m/s²), or None when the unit is unknown (counts)."""
    table = MAG_UNITS if sensor == "mag" else ACCEL_UNITS
    if unit in table:
        return table[unit]
    folded = {k.lower(): v for k, v in table.items() if k not in ("G", "mG")}  # g/G, mg/mG clash across sensors
    return folded.get(unit.strip().lower())


_A_SENSOR = {"mag": "a magnetometer", "accel": "an accelerometer"}
_MEANT = {"mag": {"g": "gauss", "mg": "mG"}}
"""Accelerometer units a magnetometer's may be meant by (g for gauss, mg for milligauss)."""


def other_sensors_unit(sensor: str, unit: str) -> str:
    """Why ``unit`` is refused for ``sensor`` when it is the other sensor's and not its own ("" otherwise): taken as
    counts it would switch every check off and be written into the calibration."""
    other = "accel" if sensor == "mag" else "mag"
    if unit_scale(sensor, unit) is not None or unit_scale(other, unit) is None:
        return ""
    meant = _MEANT.get(sensor, {}).get(unit)
    return (f"unit {unit!r} is {_A_SENSOR[other]} unit, not {_A_SENSOR[sensor]}'s"
            + (f" ({meant!r}?)" if meant else ""))


COUNT_NAMES = ("counts", "count", "lsb", "raw", "adc", "digits")
"""Names of raw counts (case-insensitive): an unknown unit by intent, which ``unknown_unit_note`` does not warn of."""


def unknown_unit_note(sensor: str, unit: str) -> str:
    """A warning for a unit no table knows and that names no counts ("" otherwise): it is read as counts, every
    magnitude check learnt from the data, which a typo (``furlongs``, ``mps2``) should not do silently."""
    if unit_scale(sensor, unit) is not None or unit.strip().lower() in COUNT_NAMES:
        return ""
    known = ", ".join(k for k in (MAG_UNITS if sensor == "mag" else ACCEL_UNITS) if k.isascii())
    return (f"unit {unit!r} is not a known {sensor} unit ({known}): read as raw counts (magnitude limits learnt from "
            "the data, no field-strength check)")
