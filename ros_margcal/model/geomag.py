"""The Earth's field at a position from the World Magnetic Model (WMM2025, through ``pygeomag``).

Autopilots (ArduPilot, PX4) scale their compass fit to the model's field at the GPS position; we use it
for ``reference_norm`` (the calibrated field's norm) and for the inclination of every heading figure
(``heading``), instead of a norm by hand and 60° everywhere. ``field_at`` evaluates the model once per
position (about 0.2 ms): intensity in tesla, inclination and declination in degrees, positive down and east.

``pygeomag`` (MIT, pure Python, no dependencies, 0.25 MB wheel) reproduces NOAA's WMM2025 test values to
their rounding (0.05 nT, 0.005°; docs/METHODS.md compares the candidates). It is imported where it is used:
a ROS install from apt may lack it, and then only a position asks for it, with the ``pip install`` to run.
WMM2025 holds from 2025.0 to 2030.0; a date outside is refused (the next model needs a new ``pygeomag``).
"""

from __future__ import annotations

import datetime as dt
import functools
import math
from dataclasses import dataclass
from typing import Any

from .errors import ConfigError

__all__ = ["FIELD_MODEL", "GeomagField", "decimal_year", "distance_km", "field_at", "format_position"]

FIELD_MODEL = "WMM2025"
"""The model ``field_at`` evaluates (``pygeomag``'s ``wmm/WMM_2025.COF``)."""
_COF = "wmm/WMM_2025.COF"
_NT = 1e-9
_ALT_RANGE_M = (-1000.0, 850_000.0)
"""WMM's altitude range above the WGS 84 ellipsoid: -1 km to 850 km."""


@dataclass(frozen=True)
class GeomagField:
    """The model field at one position and date (intensity in tesla; angles in degrees, positive down and east)."""

    intensity_t: float
    inclination_deg: float
    declination_deg: float
    model: str
    year: float
    lat_deg: float
    lon_deg: float
    alt_m: float

    def describe(self) -> str:
        """One line for a status: 'field from WMM2025 at 48.1°N 11.6°E: 48.3 µT, inclination 64.2°'."""
        return (f"field from {self.model} at {format_position(self.lat_deg, self.lon_deg)}: "
                f"{self.intensity_t * 1e6:.1f} µT, inclination {self.inclination_deg:.1f}° ({self.year:.2f})")


def format_position(lat_deg: float, lon_deg: float) -> str:
    """'48.1°N 11.6°E' (one decimal: 11 km, far finer than the field's change)."""
    return f"{abs(lat_deg):.1f}°{'N' if lat_deg >= 0 else 'S'} {abs(lon_deg):.1f}°{'E' if lon_deg >= 0 else 'W'}"


def decimal_year(when: dt.date | dt.datetime | float | None = None) -> float:
    """``when`` as a decimal year (2026.5 is about 2 July 2026); None: now (UTC); a number is taken as one."""
    if when is None:
        when = dt.datetime.now(dt.timezone.utc)
    if isinstance(when, bool) or not isinstance(when, (int, float, dt.date)):
        raise ConfigError(f"the field model's date must be a date, a datetime or a decimal year, got {when!r}")
    if isinstance(when, (int, float)):
        return float(when)
    start = dt.date(when.year, 1, 1)
    days = (dt.date(when.year + 1, 1, 1) - start).days
    day = (when.date() if isinstance(when, dt.datetime) else when) - start
    frac = day.days + ((when.hour * 3600 + when.minute * 60 + when.second) / 86400.0 if isinstance(when, dt.datetime) else 0.0)
    return when.year + frac / days


def _check_position(lat_deg: Any, lon_deg: Any, alt_m: Any) -> tuple[float, float, float]:
    """Finite numbers in range (latitude +-90, longitude -180..360, altitude -1..850 km), longitude wrapped to +-180."""
    out = []
    for name, v in (("latitude", lat_deg), ("longitude", lon_deg), ("altitude", alt_m)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"the field model's {name} must be a finite number, got {v!r}")
        out.append(float(v))
    lat, lon, alt = out
    if not -90.0 <= lat <= 90.0:
        raise ConfigError(f"latitude must be in [-90, 90] deg, got {lat!r}")
    if not -180.0 <= lon <= 360.0:
        raise ConfigError(f"longitude must be in [-180, 360] deg, got {lon!r}")
    if not _ALT_RANGE_M[0] <= alt <= _ALT_RANGE_M[1]:
        raise ConfigError(f"altitude must be in [{_ALT_RANGE_M[0]:g}, {_ALT_RANGE_M[1]:g}] m above the WGS 84 "
                          f"ellipsoid (the model's range), got {alt!r}")
    if lon > 180.0:
        lon -= 360.0
    return lat, lon, alt


@functools.lru_cache(maxsize=1)
def _model() -> Any:
    """The WMM2025 model, loaded once (its coefficients take milliseconds to read; a failed import is not cached)."""
    try:
        from pygeomag import GeoMag  # optional dependency: only a position needs it (a ROS install may lack it)
    except ImportError as exc:
        msg = (f"the field from a position needs the WMM package pygeomag: pip install pygeomag ({exc}); "
               "or give the reference norm by hand")
        raise ConfigError(msg) from exc
    return GeoMag(coefficients_file=_COF)


def field_at(lat_deg: float, lon_deg: float, alt_m: float = 0.0,
             when: dt.date | dt.datetime | float | None = None) -> GeomagField:
    """The WMM2025 field at geodetic ``lat_deg``, ``lon_deg`` (deg; longitude -180..360), ``alt_m`` above the
    WGS 84 ellipsoid, on ``when`` (a date, a datetime, a decimal year; None: now). ConfigError for NaN, a
    position out of range, or a date outside the model's 2025.0-2030.0."""
    lat, lon, alt = _check_position(lat_deg, lon_deg, alt_m)
    year = decimal_year(when)
    geo = _model()
    start, end = geo.life_span
    if not start <= year < end:
        raise ConfigError(f"the date {year:.3f} is outside {FIELD_MODEL}'s validity [{start:g}, {end:g}): give a date "
                          "within it, or the reference norm by hand (a newer model needs a newer pygeomag)")
    r = geo.calculate(glat=lat, glon=lon, alt=alt / 1000.0, time=year)
    return GeomagField(float(r.f) * _NT, float(r.i), float(r.d), FIELD_MODEL, year, lat, lon, alt)


def distance_km(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float) -> float:
    """Great-circle distance between two positions, km (haversine on a 6371 km sphere: the field changes by
    about 0.1 % over 50 km, so the sphere's 0.5 % error is irrelevant here)."""
    p1, p2 = math.radians(lat1_deg), math.radians(lat2_deg)
    dp, dl = p2 - p1, math.radians(lon2_deg - lon1_deg)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2.0 * 6371.0 * math.asin(min(1.0, math.sqrt(a)))
