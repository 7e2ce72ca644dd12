"""``PipelineConfig`` at a position: the WMM2025 field sets the magnetometer's norm (in its unit) and inclination."""

from __future__ import annotations

import pytest

from ros_margcal.model.errors import ConfigError
from ros_margcal.model.geomag import field_at
from ros_margcal.stream.config import PipelineConfig

pytest.importorskip("pygeomag")

MUNICH = field_at(48.1, 11.6, 0.0, 2026.5)


@pytest.mark.parametrize(("unit", "scale"), [("T", 1.0), ("uT", 1e-6), ("gauss", 1e-4)])
def test_norm_in_the_unit_and_inclination(unit: str, scale: float) -> None:
    """for_sensor with a position: reference_norm is the model intensity in the unit; the inclination is the model's."""
    cfg = PipelineConfig.for_sensor("mag", unit, latitude_deg=48.1, longitude_deg=11.6, field_year=2026.5)
    assert cfg.reference_norm == pytest.approx(MUNICH.intensity_t / scale, rel=1e-12)
    assert cfg.heading_inclination_deg == pytest.approx(MUNICH.inclination_deg)
    assert cfg.field_model() == MUNICH


def test_a_norm_given_wins_and_counts_get_only_the_inclination() -> None:
    """An explicit reference_norm is kept; a unit without a scale (counts) gets no norm, only the inclination."""
    cfg = PipelineConfig.for_sensor("mag", "uT", reference_norm=44.0, latitude_deg=48.1, longitude_deg=11.6)
    assert cfg.reference_norm == 44.0 and cfg.heading_inclination_deg is not None
    counts = PipelineConfig.for_sensor("mag", "counts", latitude_deg=48.1, longitude_deg=11.6, field_year=2026.5)
    assert counts.reference_norm is None and counts.heading_inclination_deg == pytest.approx(MUNICH.inclination_deg)


def test_accelerometer_and_no_position_are_unchanged() -> None:
    """The accelerometer keeps gravity; without a position nothing is set and there is no field model."""
    acc = PipelineConfig.for_sensor("accel", latitude_deg=48.1, longitude_deg=11.6)
    assert acc.reference_norm == pytest.approx(9.80665) and acc.heading_inclination_deg is None
    plain = PipelineConfig.for_sensor("mag")
    assert plain.field_model() is None and plain.reference_norm is None


def test_at_position_moves_the_field() -> None:
    """at_position on a configured copy moves norm and inclination to the new place (Sydney: upward field)."""
    cfg = PipelineConfig.for_sensor("mag").at_position(48.1, 11.6, when=2026.5).at_position(-33.9, 151.2, when=2026.5)
    sydney = field_at(-33.9, 151.2, 0.0, 2026.5)
    assert cfg.reference_norm == pytest.approx(sydney.intensity_t) and cfg.heading_inclination_deg < -60.0


@pytest.mark.parametrize(("opts", "match"), [
    ({"latitude_deg": 48.1}, "a position needs latitude_deg and longitude_deg, got 48.1 and None"),
    ({"latitude_deg": 91.0, "longitude_deg": 0.0}, r"latitude_deg must be in \[-90, 90\], got 91.0"),
    ({"latitude_deg": 48.1, "longitude_deg": 11.6, "field_year": 2031.5}, "outside WMM2025's validity"),
    ({"latitude_deg": 48.1, "longitude_deg": 11.6, "altitude_m": 1e6}, r"altitude_m must be in"),
])
def test_bad_positions_refused(opts: dict, match: str) -> None:
    """Half a position, out of range, out of the model's dates: ConfigError naming the option."""
    with pytest.raises(ConfigError, match=match):
        PipelineConfig.for_sensor("mag", **opts)
