"""A magnetometer mounted on its side (``up_axis``): its readings turned so that the up axis is z, the calibration
published in the magnetometer's own axes; without the option, the status names the axis its ring turns about.

On the independent generator: a ground robot's readings with the sensor's y (or -x) axis up are the level-mounted
readings turned by a signed permutation, so the turned stream is the level one exactly (the same fits, the same
figures) and every calibration it publishes is the level one's, turned back (``model.mounting.turned``)."""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import ConfigError, InputError
from ros_margcal.model.fitting_core import parameter_names
from ros_margcal.model.mounting import UP_AXES, turned, up_rotation
from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator

GEN: ModuleType = INDEPENDENT


@pytest.fixture(scope="module")
def robot() -> dict[str, Any]:
    """120 s of a ground robot at 50 Hz, +-5 deg of tilt (seed 17: not a benchmark seed)."""
    return GEN.generate("mag", "ground", duration_s=120.0, rate_hz=50.0, seed=17, tilt_deg=5.0, hard_iron_mag=30e-6,
                        symmetric_soft_iron=True)


def _run(t: Any, xyz: Any, up: str = "z") -> tuple[SensorCalibrator, list[Any]]:
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", up_axis=up))
    events = []
    for tk, v in zip(t.tolist(), np.asarray(xyz).tolist(), strict=True):
        events += [e for e in cal.push(tk, v) if e.kind is EventKind.CALIBRATED]
    return cal, events


@pytest.fixture(scope="module")
def level(robot: dict[str, Any]) -> tuple[SensorCalibrator, list[Any]]:
    return _run(robot["t"], robot["xyz"])


@pytest.mark.parametrize("up", ["y", "-x"])
def test_a_ring_on_its_side_calibrates_as_the_level_mounted_one(robot: dict[str, Any], level: Any, up: str) -> None:
    q = up_rotation(up)
    assert q is not None
    side = robot["xyz"] @ q  # each reading q^T v: the sensor's `up` axis points up
    cal, events = _run(robot["t"], side, up)
    ref = level[1]
    assert ref and [e.t for e in events] == [e.t for e in ref]  # the same stream, turned: the same publications
    for e, r in zip(events, ref, strict=True):
        np.testing.assert_allclose(e.calibration.offset, q.T @ r.calibration.offset, rtol=0, atol=1e-12)
        np.testing.assert_allclose(e.calibration.matrix, q.T @ r.calibration.matrix @ q, rtol=0, atol=1e-12)
    # in the magnetometer's own axes: it calibrates the side readings as the level one calibrates the level readings
    np.testing.assert_allclose(np.linalg.norm(cal.calibration.apply(side), axis=1),
                               np.linalg.norm(level[0].calibration.apply(robot["xyz"]), axis=1), rtol=1e-9)
    st_side, st_level = cal.status(), level[0].status()
    assert st_side.heading_p95_level_deg == pytest.approx(st_level.heading_p95_level_deg, rel=1e-9)
    np.testing.assert_allclose(st_side.offset, cal.calibration.offset)
    assert f"the magnetometer's {up} axis is z (mag.up_axis)" in st_side.message
    assert GEN.heading_p95(q @ cal.calibration.matrix @ q.T, q @ cal.calibration.offset, robot["truth"], 0.0) <= 2.5


def test_without_up_axis_the_status_names_the_axis_the_ring_turns_about(robot: dict[str, Any]) -> None:
    q = up_rotation("y")
    assert q is not None
    cal, events = _run(robot["t"], robot["xyz"] @ q)
    message = cal.status().message
    assert not events, message  # the ring rules take z as up: no calibration of a ring about y ...
    assert "ring about the magnetometer's y axis" in message and "set mag.up_axis=y" in message  # ... and it says so


def test_a_calibration_given_or_read_is_in_the_magnetometers_axes() -> None:
    """Loaded, set, read back, shown in the status, kept over a new up_axis: always the magnetometer's own axes,
    the same object on every read (the node's worker sends a calibration when the object it reads changes)."""
    cal = Calibration(offset=np.array([1e-5, -2e-5, 3e-5]),
                      matrix=np.array([[1.1, 0.02, -0.01], [0.02, 0.95, 0.03], [-0.01, 0.03, 1.02]]), norm=48e-6,
                      sensor="mag", unit="T")
    c = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", up_axis="x"), calibration=cal)
    assert c.calibration is c.calibration
    np.testing.assert_allclose(c.calibration.offset, cal.offset, atol=1e-20)
    np.testing.assert_allclose(c.calibration.matrix, cal.matrix, atol=1e-15)
    np.testing.assert_allclose(c.status().offset, cal.offset, atol=1e-20)
    other = cal.replace(offset=np.array([4e-6, 5e-6, 6e-6]))
    c.set_calibration(other)
    np.testing.assert_allclose(c.calibration.offset, other.offset, atol=1e-20)
    c.reconfigure(PipelineConfig.for_sensor("mag", up_axis="-y"))
    np.testing.assert_allclose(c.calibration.offset, other.offset, atol=1e-20)
    np.testing.assert_allclose(c.calibration.matrix, other.matrix, atol=1e-15)


def test_up_axis_is_checked() -> None:
    with pytest.raises(ConfigError, match="up_axis must be one of"):
        PipelineConfig.for_sensor("mag", up_axis="w").checked()
    with pytest.raises(ConfigError, match=r"the accelerometer has none: set mag\.up_axis"):
        PipelineConfig.for_sensor("accel", up_axis="y").checked()
    with pytest.raises(InputError):
        up_rotation("up")


@settings(max_examples=60, deadline=None)
@given(axis=st.sampled_from(UP_AXES), seed=st.integers(0, 2**32 - 1), with_norm=st.booleans())
def test_turning_is_a_proper_rotation_and_turns_back_exactly(axis: str, seed: int, with_norm: bool) -> None:
    """``up_rotation`` takes the axis to +z with det +1; a calibration turned and turned back is itself, its
    covariance too (over the symmetric parameters, the norm last when it has one), and its norms are the same."""
    q = up_rotation(axis)
    if q is None:
        assert axis.lstrip("+") == "z"
        return
    e = np.zeros(3)
    e["xyz".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
    np.testing.assert_array_equal(q @ e, [0.0, 0.0, 1.0])
    assert round(float(np.linalg.det(q))) == 1 and set(np.abs(q).ravel()) == {0.0, 1.0}
    rng = np.random.default_rng(seed)
    names = parameter_names("sym", scale_free=with_norm)
    a = rng.standard_normal((len(names), len(names)))
    m = np.eye(3) + 0.1 * rng.standard_normal((3, 3))
    cal = Calibration(offset=rng.standard_normal(3), matrix=0.5 * (m + m.T), norm=1.0, covariance=a @ a.T,
                      parameter_names=names)
    there = turned(cal, q)
    back = turned(there, q.T)
    np.testing.assert_allclose(back.offset, cal.offset, atol=1e-12)
    np.testing.assert_allclose(back.matrix, cal.matrix, atol=1e-12)
    np.testing.assert_allclose(back.covariance, cal.covariance, atol=1e-9)
    v = rng.standard_normal((20, 3))
    np.testing.assert_allclose(np.linalg.norm(there.apply(v @ q.T), axis=1), np.linalg.norm(cal.apply(v), axis=1),
                               rtol=1e-12)
