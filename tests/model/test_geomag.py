"""The WMM2025 field at a position: NOAA's test values, the status line, bad input refused."""

from __future__ import annotations

import datetime as dt
import math

import pytest

from ros_margcal.model import geomag
from ros_margcal.model.errors import ConfigError

pytest.importorskip("pygeomag")

# NOAA NCEI, WMM2025_TEST_VALUES.txt (published with the model, Dec 2024): date, height km, lat, lon, F nT, I, D deg
NOAA_WMM2025 = [
    (2025.0, 0, 80, 0, 55178.5, 83.21, 1.28), (2025.0, 0, 0, 120, 41064.3, -14.93, -0.16),
    (2025.0, 0, -80, 240, 54698.2, -72.00, 68.78), (2025.0, 100, 80, 0, 52964.9, 83.26, 0.85),
    (2025.0, 100, 0, 120, 39032.1, -15.08, -0.15), (2025.0, 100, -80, 240, 52035.0, -72.19, 68.21),
    (2027.5, 0, 80, 0, 55253.9, 83.24, 2.59), (2027.5, 0, 0, 120, 41036.9, -14.65, -0.24),
    (2027.5, 0, -80, 240, 54474.2, -71.92, 68.49), (2027.5, 100, 80, 0, 53034.3, 83.29, 2.16),
    (2027.5, 100, 0, 120, 39007.4, -14.81, -0.23), (2027.5, 100, -80, 240, 51825.7, -72.10, 67.93),
]


@pytest.mark.parametrize(("year", "h_km", "lat", "lon", "f_nt", "inc", "dec"), NOAA_WMM2025)
def test_matches_noaa_test_values(year: float, h_km: float, lat: float, lon: float, f_nt: float, inc: float,
                                  dec: float) -> None:
    """Every NOAA test point to the table's rounding (0.1 nT, 0.01 deg)."""
    f = geomag.field_at(lat, lon, h_km * 1000.0, year)
    assert f.intensity_t == pytest.approx(f_nt * 1e-9, abs=0.1e-9)
    assert f.inclination_deg == pytest.approx(inc, abs=0.01)
    assert f.declination_deg == pytest.approx(dec, abs=0.01)
    assert f.model == "WMM2025" and f.year == year


def test_status_line_names_model_position_and_date() -> None:
    """Munich in 2026: about 48.8 uT at 64.4 deg, said with the model, the position and the date."""
    f = geomag.field_at(48.1, 11.6, 500.0, dt.date(2026, 7, 2))
    assert 48.0e-6 < f.intensity_t < 49.5e-6 and 63.5 < f.inclination_deg < 65.0
    text = f.describe()
    assert text.startswith("field from WMM2025 at 48.1°N 11.6°E: ") and "inclination 64." in text and "(2026.50)" in text
    assert geomag.format_position(-33.87, -70.5) == "33.9°S 70.5°W"


def test_decimal_year() -> None:
    """Dates and datetimes as decimal years; a number passes through; None is now."""
    assert geomag.decimal_year(dt.date(2026, 1, 1)) == 2026.0
    assert geomag.decimal_year(dt.datetime(2027, 7, 2, 12, 0, 0)) == pytest.approx(2027.5, abs=1e-3)
    assert geomag.decimal_year(2028.25) == 2028.25
    now = dt.datetime.now(dt.timezone.utc)
    assert abs(geomag.decimal_year() - (now.year + (now.timetuple().tm_yday - 1) / 365.25)) < 0.01


@pytest.mark.parametrize(("args", "match"), [
    ((math.nan, 11.6), "latitude must be a finite number"),
    ((48.1, math.inf), "longitude must be a finite number"),
    ((90.5, 11.6), r"latitude must be in \[-90, 90\] deg, got 90.5"),
    ((48.1, -180.01), r"longitude must be in \[-180, 360\] deg, got -180.01"),
    ((48.1, 11.6, 900e3), "altitude must be in"),
    ((48.1, 11.6, 0.0, 2031.0), r"the date 2031.000 is outside WMM2025's validity \[2025, 2030\)"),
    ((48.1, 11.6, 0.0, dt.date(2024, 12, 31)), r"the date 2024.997 is outside"),
    (("48.1", 11.6), "latitude must be a finite number"),
    ((48.1, 11.6, 0.0, "2026"), "must be a date"),
])
def test_bad_input_refused(args: tuple, match: str) -> None:
    """NaN, a position or altitude out of range, a date outside the model: a ConfigError saying which."""
    with pytest.raises(ConfigError, match=match):
        geomag.field_at(*args)


def test_longitude_east_of_180_wraps() -> None:
    """240 deg E is 120 deg W."""
    a, b = geomag.field_at(-80, 240, 0.0, 2025.0), geomag.field_at(-80, -120, 0.0, 2025.0)
    assert a.intensity_t == b.intensity_t and b.lon_deg == -120.0


def test_missing_package_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without pygeomag (an apt-only ROS install) a position is refused with the pip command, not a traceback."""
    monkeypatch.setitem(__import__("sys").modules, "pygeomag", None)
    geomag._model.cache_clear()
    with pytest.raises(ConfigError, match="pip install pygeomag"):
        geomag.field_at(48.1, 11.6)


def test_distance_km() -> None:
    """Munich to Berlin about 504 km; a degree of latitude about 111 km."""
    assert geomag.distance_km(48.14, 11.58, 52.52, 13.40) == pytest.approx(504.0, abs=5.0)
    assert geomag.distance_km(10.0, 20.0, 11.0, 20.0) == pytest.approx(111.2, abs=0.1)
