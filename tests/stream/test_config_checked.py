"""PipelineConfig.checked: every field has a type, a finite range and a memory bound, refused with ConfigError."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ros_margcal.model.errors import ConfigError
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.config import FIELD_SPECS, PipelineConfig, apart
from ros_margcal.validation.shipped import FallbackValidator

FIELDS = [f.name for f in dataclasses.fields(PipelineConfig)]
NUMERIC = [n for n in FIELDS if FIELD_SPECS[n].kind not in (str, bool)]
OPTIONAL = {n for n in FIELDS if FIELD_SPECS[n].none_ok}
ABSURD: list[object] = [-1, 0, -1.0, 0.0, -1e300, 1e300, math.nan, math.inf, -math.inf, 10**400, -(10**400), 10**12,
                        1e-300, "1", "", "nan", None, True, False, [1.0], {"a": 1}, b"1", 1 + 2j]


def _build(which: str, /, **overrides: object) -> PipelineConfig:
    """The defaults of sensor ``which`` with ``overrides`` put in as they are (also sensor and unit), then checked."""
    return dataclasses.replace(PipelineConfig.for_sensor(which), **overrides).checked()


def _cases() -> list[tuple[str, str, object]]:
    return [(s, n, v) for s in ("mag", "accel") for n in FIELDS for v in ABSURD]


def test_every_field_has_a_spec() -> None:
    """The table covers exactly the dataclass fields (a new field cannot slip through unchecked)."""
    assert set(FIELD_SPECS) == set(FIELDS)


@pytest.mark.parametrize("sensor", ["mag", "accel"])
def test_defaults_pass(sensor: str) -> None:
    """The defaults of both sensors, also in other units, pass their own checks unchanged."""
    base = PipelineConfig.for_sensor(sensor)
    assert base.checked() is base
    assert base.n_bins == 100 and base.per_bin == 10 and base.max_rate_hz == 2000.0
    other = PipelineConfig.for_sensor(sensor, "nT" if sensor == "mag" else "mg")
    assert other.checked() is other


def test_absurd_values_raise_config_error_or_yield_a_working_calibrator() -> None:
    """Every absurd value, in every field, for both sensors: ConfigError naming the field, or a config
    with which a calibrator builds and takes samples without raising (nothing else, never a traceback)."""
    rng = np.random.default_rng(5)
    accepted = 0
    for sensor, name, value in _cases():
        try:
            cfg = _build(sensor, **{name: value})
        except ConfigError as exc:
            assert name in str(exc), f"{name}={value!r}: {exc}"
            continue
        accepted += 1
        cal = SensorCalibrator(sensor, cfg, validator=FallbackValidator())
        g = 9.8 if sensor == "accel" else 50e-6
        for k in range(30):
            cal.push(0.01 * k, g * rng.normal(size=3), None)
        assert cal.seen == 30
    assert accepted < len(_cases()) // 4


@pytest.mark.parametrize("sensor", ["mag", "accel"])
@pytest.mark.parametrize("name", NUMERIC)
@pytest.mark.parametrize("value", [math.nan, -math.inf, 1e300, 10**400, "1", "nan", True, False, [1.0], b"1"])
def test_numbers_are_finite_in_range_and_never_strings_or_bools(sensor: str, name: str, value: object) -> None:
    """NaN, -inf, huge values, big ints, strings and bools are refused in every numeric field."""
    with pytest.raises(ConfigError, match=name):
        _build(sensor, **{name: value})


@pytest.mark.parametrize("name", sorted(set(FIELDS) - OPTIONAL))
def test_none_is_refused_where_not_optional(name: str) -> None:
    """None only means "off/auto" in the optional fields."""
    with pytest.raises(ConfigError, match=name):
        _build("mag", **{name: None})


@pytest.mark.parametrize(("overrides", "match"), [
    ({"refit_min_interval_s": math.nan}, "refit_min_interval_s"),
    ({"max_predicted_error": -0.1}, "max_predicted_error"),
    ({"max_predicted_error": math.nan}, "max_predicted_error"),
    ({"max_predicted_error": 0.0}, "max_predicted_error"),
    ({"not_worse_tolerance": math.nan}, "not_worse_tolerance"),
    ({"min_magnitude": math.nan}, "min_magnitude"),
    ({"min_points": 10**12}, "min_points"),
    ({"min_points": 5000}, "min_points"),  # more than the buffer holds: never calibrates
    ({"f_scale_rel": 0.0}, "f_scale_rel"),
    ({"f_scale_rel": -1.0}, "f_scale_rel"),
    ({"f_scale_rel": 1e-300}, "f_scale_rel"),
    ({"max_residual": 1e-300}, "max_residual"),
    ({"gyro_scale_std": 1e-300}, "gyro_scale_std"),  # passed, then its inverse square overflowed in the mounting fit
    ({"gyro_block_s": 1e-300}, "gyro_block_s"),
    ({"method": "newton"}, "method"),
    ({"loss": "l3"}, "loss"),
    ({"method": "sphere"}, "method"),  # cannot fit the sym model
    ({"method": "algebraic", "loss": "huber"}, "loss"),
    ({"max_rate_hz": "2000"}, "max_rate_hz"),
    ({"n_bins": 10_000, "per_bin": 1_000}, "n_bins"),
    ({"n_bins": 100_000, "per_bin": 10_000}, "n_bins"),
    ({"recent_samples": 1e9}, "recent_samples"),
    ({"recent_samples": 10**9}, "recent_samples"),
    ({"gate_window_s": 600.0, "max_rate_hz": 1e6}, "gate_window_s"),
    ({"sensor": "gyro"}, "sensor"),
])
def test_harmful_values_named(overrides: dict, match: str) -> None:
    """The values that were accepted and harmful (never calibrates, guards off, 22 GiB) are refused by name."""
    with pytest.raises(ConfigError, match=match):
        _build("mag", **overrides)


@pytest.mark.parametrize(("kwargs", "match"), [({"unit": 3}, "unit"), ({"unit": ["T"]}, "unit"), ({"wobble": 1.0}, "wobble")])
def test_for_sensor_names_a_bad_unit_or_an_unknown_option(kwargs: dict, match: str) -> None:
    """for_sensor refuses a unit that is not a string and an option that does not exist, with ConfigError."""
    with pytest.raises(ConfigError, match=match):
        PipelineConfig.for_sensor("mag", **kwargs)


def test_checked_refuses_a_directly_built_config() -> None:
    """The checks hold for a config built without for_sensor, and the calibrator refuses it with ConfigError."""
    bad = dataclasses.replace(PipelineConfig(), per_bin=True)
    with pytest.raises(ConfigError, match="per_bin"):
        bad.checked()
    with pytest.raises(ConfigError, match="per_bin"):
        SensorCalibrator("mag", bad, validator=FallbackValidator())


def test_numbers_of_either_python_type_are_accepted() -> None:
    """An int where a float is expected is a number (max_rate_hz=100); off values keep working."""
    cfg = PipelineConfig.for_sensor("mag", max_rate_hz=100, max_predicted_error=None, gate_gyro_threshold=0.5)
    assert cfg.min_period_s == pytest.approx(0.01)
    assert PipelineConfig.for_sensor("mag", "counts").norm_max == math.inf  # unknown unit: no field-strength check


@given(st.floats(1e-6, 1e3), st.floats(1e-6, 0.5))
def test_a_failed_comparison_prints_numbers_that_differ(a: float, rel: float) -> None:
    """``apart`` (the 'worse than the current calibration' message): two numbers that differ by at least 1e-6
    relative are printed differently ("0.54124 % vs 0.54117 %", never "0.54 % vs 0.54 %"), each a float again."""
    b = a * (1.0 + rel)
    sa, sb = apart(a, b)
    assert sa != sb
    assert float(sa) <= float(sb)
