"""The raw unit and the sensor of a recording, with one meaning in every command (calibrate, replay, diagnose).

``--unit`` is always the unit of the recording's raw readings. A known unit (``units.MAG_UNITS``,
``units.ACCEL_UNITS``) is checked against the readings' size: an Earth field (20-70 µT) or gravity
(0.85-1.15 g), widened by ``SLACK`` for offsets and motion (still narrower than the factor 10 between
neighbouring units: gauss and mT, mG and µT). A size the unit does not fit is refused with the unit it
would fit ("36.9 in gauss is not an Earth field; 36.9 uT is: --unit uT?"). A unit without a known
scale (counts) is not checked: the calibrator learns its limits from the data.

Without ``--unit``, a bag's MagneticField is tesla and its Imu m/s² (REP-145), checked the same way; a
CSV's unit is inferred from the readings' size, with a warning naming it, and refused when no unit or
several fit (static readings that no unit fits are read in ``UNKNOWN``, said: a hard iron of unknown size
adds to the field, and the fit refuses them as static anyway). The sensor, when neither ``--sensor`` nor the
file says it, is inferred the same way (the only sensor with a fitting unit), else refused naming ``--sensor``.

The size of the readings (``sizes``), most trusted first: for readings that turn, the radius about the
sphere fitted through them and the half-extent of their widest axis (a hard iron moves neither, a spike
neither), then their median norm; the first size that some unit fits decides an inference.
"""

from __future__ import annotations

import sys

import numpy as np
from numpy.typing import NDArray

from ..model.errors import ConfigError, RecordingError
from ..recordings.recording import Recording, drop_zero_rows
from ..stream.config import STATIC_SPREAD, PipelineConfig
from ..stream.saturation import on_rails
from ..stream.units import other_sensors_unit, unit_scale
from .fit_rescue import MAX_READING

__all__ = ["SLACK", "UNIT_CHOICES", "UNKNOWN", "fitting_units", "infer_sensor", "prepare", "resolve_unit", "sizes"]

Array = NDArray[np.float64]

UNIT_CHOICES = {"mag": ("T", "mT", "uT", "nT", "gauss", "mG"), "accel": ("m/s^2", "g", "mg")}
"""The units a refusal or an inference names, per sensor (each also accepted under its other spellings)."""
SLACK = 1.4
"""A size is plausible in a unit within ``[norm_min / SLACK, norm_max * SLACK]`` of the online calibrator's
field-strength range in that unit (magnetometer 14-98 µT: a ratio of 6.9, below the factor 10 between units)."""
UNKNOWN = "raw"
"""The unit of static readings no unit fits: a unit without a known scale (no field-strength checks)."""
_WHAT = {"mag": "an Earth field", "accel": "gravity"}
_NAME = {"mag": "magnetometer", "accel": "accelerometer"}
_SIZE_POINTS = 6000


def sizes(points: Array) -> tuple[float, ...]:
    """The readings' sizes, raw units, most trusted first: for readings that turn, the median distance from the
    centre of the sphere fitted through them and the half-extent of their widest axis (2nd to 98th percentile:
    a spike moves neither), then their median norm (moved by a hard iron)."""
    pts = np.asarray(points, dtype=np.float64)
    pts = pts[np.all(np.abs(pts) <= MAX_READING, axis=1)] if len(pts) else pts  # absurd rows: the fit drops them too
    if not len(pts):
        return ()
    pts = pts[:: max(1, len(pts) // _SIZE_POINTS)]
    median = float(np.median(np.linalg.norm(pts, axis=1)))
    spread = float(np.median(np.linalg.norm(pts - np.median(pts, axis=0), axis=1))) / (median or 1.0)
    if len(pts) < 10 or spread < STATIC_SPREAD:  # medians: a spike does not make a still sensor turn
        return (median,)
    a = np.c_[2.0 * pts, np.ones(len(pts))]
    sol = np.linalg.lstsq(a, (pts * pts).sum(axis=1), rcond=None)[0]
    radius = float(np.median(np.linalg.norm(pts - sol[:3], axis=1))) if np.all(np.isfinite(sol)) else 0.0
    centred = pts - pts.mean(axis=0)
    along = centred @ np.linalg.svd(centred, full_matrices=False)[2][0]
    half = 0.5 * float(np.subtract(*np.percentile(along, [98.0, 2.0])))
    return (radius, half, median)


def _window(sensor: str, unit: str) -> tuple[float, float] | None:
    """The plausible size range in ``unit`` (module docstring), None for a unit without a known scale."""
    if unit_scale(sensor, unit) is None:
        return None
    cfg = PipelineConfig.for_sensor(sensor, unit)
    return cfg.norm_min / SLACK, cfg.norm_max * SLACK


def fitting_units(sensor: str, size: tuple[float, ...]) -> list[str]:
    """The units of ``UNIT_CHOICES[sensor]`` in which a size is plausible: those of the first size that has any."""
    return _deciding(sensor, size)[0]


def _deciding(sensor: str, size: tuple[float, ...]) -> tuple[list[str], float]:
    """``fitting_units`` and the size that decided them (the first size when none fits)."""
    for s in size:
        out = [u for u in UNIT_CHOICES[sensor] if _fits(sensor, u, s)]
        if out:
            return out, s
    return [], size[0] if size else 0.0


def _fits(sensor: str, unit: str, size: float) -> bool:
    window = _window(sensor, unit)
    return window is not None and window[0] <= size <= window[1]


def _refusal(sensor: str, unit: str, size: tuple[float, ...], where: str) -> str:
    lo, hi = _window(sensor, unit) or (0.0, 0.0)
    units, s = _deciding(sensor, size)
    head = f"readings of size {s:.4g} {where}: {s:.4g} in {unit} is not {_WHAT[sensor]} ({lo:.3g}-{hi:.3g} {unit})"
    alt = [u for u in units if unit_scale(sensor, u) != unit_scale(sensor, unit)]
    if alt:
        return f"{head}; {s:.4g} {alt[0]} is: --unit {alt[0]}?"
    return (f"{head}, nor in any unit of {'a magnetometer' if sensor == 'mag' else 'an accelerometer'} "
            f"({', '.join(UNIT_CHOICES[sensor])}); raw counts: --unit counts")


def resolve_unit(sensor: str, points: Array, given: str | None, *, default: str | None = None, where: str = "") -> str:
    """The raw unit of ``points`` of ``sensor``: ``given`` (checked), else ``default`` (a bag's REP-145 unit,
    checked), else inferred from the size with a warning on stderr (module docstring).

    Raises:
        ConfigError: the size is implausible in the given or default unit (the message names the unit that
            fits), or no unit or several fit an inference.
    """
    if given is not None:
        _not_the_other_sensors(sensor, given)
    size = sizes(points)
    unit = given if given is not None else default
    if not size or not any(x > 0 for x in size):
        return unit or ""  # no readings to judge: the reader or the fit says why
    if unit is not None:
        if _window(sensor, unit) is not None and not any(_fits(sensor, unit, s) for s in size):
            whence = "" if given is not None else " (the REP-145 unit of the bag's messages)"
            raise ConfigError(_refusal(sensor, unit, size, f"{where}{whence}".strip() or "in the recording"))
        return unit
    cands, decided = _deciding(sensor, size)
    if len(cands) == 1:
        print(f"no --unit: the readings' size {decided:.4g} is {_WHAT[sensor]} in {cands[0]}: read as {cands[0]} "
              "(give --unit to say otherwise)", file=sys.stderr)
        return cands[0]
    if not cands and len(size) == 1:  # static: a hard iron adds to the field, the size says no unit
        print(f"no --unit, and the readings do not turn: their size {size[0]:.4g} (field plus any hard iron) says no "
              f"unit; read as '{UNKNOWN}', without field-strength checks (give --unit to check them)", file=sys.stderr)
        return UNKNOWN
    if not cands:
        msg = (f"no --unit, and readings of size {size[0]:.4g} are {_WHAT[sensor]} in none of "
               f"{', '.join(UNIT_CHOICES[sensor])}: give --unit (--unit counts for raw counts)")
    else:
        msg = f"no --unit, and readings of size {decided:.4g} fit several units ({', '.join(cands)}): give --unit"
    raise ConfigError(msg)


def _not_the_other_sensors(sensor: str, unit: str) -> None:
    """ConfigError for a ``--unit`` that is empty, or the other sensor's (``units.other_sensors_unit``)."""
    own = f"{_NAME[sensor]} units: {', '.join(UNIT_CHOICES[sensor])}; counts, unchecked"
    if not unit.strip():
        raise ConfigError(f"--unit {unit!r} names no unit ({own})")
    wrong = other_sensors_unit(sensor, unit)
    if wrong:
        raise ConfigError(f"--{wrong} ({own})")


def infer_sensor(points: Array, given: str | None, from_file: str, unit: str | None) -> str:
    """The sensor: ``given``, else the file's (name or message type), else the only one whose units fit the
    readings (said on stderr); ConfigError naming ``--sensor`` when that is not clear."""
    if given:
        return given
    if from_file:
        return from_file
    size = sizes(points)
    owners = [s for s in ("mag", "accel") if unit is None or unit_scale(s, unit) is not None]
    if unit is not None and len(owners) == 1:
        found = owners
    else:
        found = [s for s in owners if size and fitting_units(s, size)]
    if len(found) == 1:
        print(f"no --sensor and none in the file name: the readings' size {size[0] if size else 0.0:.4g} is "
              f"{_WHAT[found[0]]}: read as --sensor {found[0]}", file=sys.stderr)
        return found[0]
    why = "could be either" if found else "fit neither an Earth field nor gravity in a known unit"
    msg = (f"which sensor is this? The file name says neither 'mag' nor 'acc' and the readings "
           f"(size {size[0] if size else 0.0:.4g}) {why}: give --sensor mag or --sensor accel")
    raise ConfigError(msg)


def prepare(rec: Recording, sensor: str | None, unit: str | None, where: str) -> tuple[Recording, str, str]:
    """``rec`` without its all-zero rows (counted on stderr), its sensor (``infer_sensor``) and raw unit
    (``resolve_unit``; a bag's ``rec.unit`` is its REP-145 default)."""
    rec, zeros = drop_zero_rows(rec)
    if zeros:
        print(f"dropped {zeros} all-zero row(s) of {zeros + len(rec)} (x = y = z = 0: no field or gravity reads that)",
              file=sys.stderr)
    if zeros and not len(rec):  # was "points needs at least 1 rows, got 0" from deep inside the fit
        raise RecordingError(f"every row of {where} is all-zero (x = y = z = 0): no reading to use")
    name = infer_sensor(rec.raw, sensor, rec.sensor, unit)
    raw_unit = resolve_unit(name, rec.raw, unit, default=rec.unit or None, where=f"in {where}")
    rec.sensor, rec.unit = name, raw_unit
    return rec, name, raw_unit


def drop_saturated(rec: Recording) -> Recording:
    """``rec`` (in time order, its unit resolved) without its rows on a saturated axis (``stream.saturation``, all of
    them: a batch has the whole recording), said on stderr: a fit's input, not the diagnosis's (it names clipping)."""
    pinned, watch = on_rails(rec.raw) if len(rec) else (np.zeros(0, dtype=bool), None)
    n = int(pinned.sum())
    if not n or watch is None:
        return rec
    print(f"{watch.describe(rec.unit, n)} ({n} of {len(rec)} rows)", file=sys.stderr)
    return rec.slice(~pinned)
