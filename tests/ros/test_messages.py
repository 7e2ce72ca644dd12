"""Conversions between ROS messages (rosbags Jazzy typestore classes) and numpy."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from msgdata import UNKNOWN_COVARIANCE, imu_msg, mag_msg, rosbags_classes
from rosbags.typesys import Stores, get_typestore

from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import CalibrationFileError, InputError
from ros_margcal.ros.messages import (
    calibrate_imu,
    calibrate_mag,
    calibration_from_string,
    calibration_to_string,
    imu_to_numpy,
    mag_to_numpy,
    propagate_covariance,
    stamp_to_seconds,
    status_to_diagnostic,
)
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.status import Level
from ros_margcal.validation.shipped import FallbackValidator

C = rosbags_classes()
TS = get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture
def cal() -> Calibration:
    """A magnetometer calibration with cross terms, in tesla."""
    w = np.array([[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 0.99]])
    return Calibration(np.array([2e-6, -3e-6, 1e-5]), w, 50e-6, sensor="mag", unit="T")


def _roundtrip(msg: object) -> object:
    """Serialise and deserialise with rosbags: the message is a valid Jazzy message."""
    return TS.deserialize_cdr(TS.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)


def test_stamps_and_vectors_convert() -> None:
    """Header stamp -> seconds; vectors -> arrays, for both sensor messages."""
    m = mag_msg(C, 12.25, [1e-5, 2e-5, -3e-5])
    t, v = mag_to_numpy(m)
    assert t == pytest.approx(12.25, abs=1e-9)
    np.testing.assert_allclose(v, [1e-5, 2e-5, -3e-5])
    i = imu_msg(C, 3.5, [0.1, 0.2, 9.8], [0.01, 0.02, 0.03])
    t, acc, gyro = imu_to_numpy(i)
    assert t == pytest.approx(3.5)
    np.testing.assert_allclose(acc, [0.1, 0.2, 9.8])
    np.testing.assert_allclose(gyro, [0.01, 0.02, 0.03])
    assert stamp_to_seconds(C.Time(sec=1, nanosec=500_000_000)) == 1.5


def test_calibrated_mag_keeps_header_and_propagates_covariance(cal: Calibration) -> None:
    """W (v - b) in the vector, header unchanged, covariance W Σ Wᵀ, still a valid message."""
    cov = np.diag([1e-12, 2e-12, 3e-12]).reshape(-1)
    raw = np.array([3e-5, -1e-5, 4e-5])
    m = mag_msg(C, 7.125, raw, cov=cov, frame_id="mag_link")
    out = calibrate_mag(m, cal)
    assert out.header.frame_id == "mag_link"
    assert (out.header.stamp.sec, out.header.stamp.nanosec) == (m.header.stamp.sec, m.header.stamp.nanosec)
    np.testing.assert_allclose(mag_to_numpy(out)[1], cal.apply(raw), rtol=1e-12)
    np.testing.assert_allclose(out.magnetic_field_covariance.reshape(3, 3), cal.matrix @ np.diag([1e-12, 2e-12, 3e-12]) @ cal.matrix.T)
    back = _roundtrip(out)
    np.testing.assert_allclose(mag_to_numpy(back)[1], cal.apply(raw))
    # the raw message is untouched
    np.testing.assert_allclose(mag_to_numpy(m)[1], raw)


def test_unknown_covariance_passes_through(cal: Calibration) -> None:
    """Element 0 == -1 (not provided) is published unchanged."""
    m = mag_msg(C, 1.0, [1e-5, 1e-5, 1e-5], cov=UNKNOWN_COVARIANCE)
    out = calibrate_mag(m, cal)
    np.testing.assert_array_equal(out.magnetic_field_covariance, UNKNOWN_COVARIANCE)


def test_calibrated_imu_changes_only_the_acceleration(cal: Calibration) -> None:
    """Orientation, angular velocity and their covariances are copied; acceleration calibrated."""
    acc_cal = Calibration(np.array([0.1, -0.2, 0.05]), np.diag([1.01, 0.99, 1.02]), 9.80665, sensor="accel")
    m = imu_msg(C, 2.0, [0.3, -0.1, 9.9], [0.1, 0.2, 0.3], cov=np.eye(3).reshape(-1) * 1e-4)
    out = calibrate_imu(m, acc_cal)
    np.testing.assert_allclose(imu_to_numpy(out)[1], acc_cal.apply([0.3, -0.1, 9.9]))
    np.testing.assert_allclose(imu_to_numpy(out)[2], [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(out.orientation_covariance, m.orientation_covariance)
    assert out.orientation.w == 1.0
    np.testing.assert_allclose(out.linear_acceleration_covariance.reshape(3, 3), acc_cal.matrix @ acc_cal.matrix.T * 1e-4)
    _roundtrip(out)


def test_no_calibration_passes_raw_values() -> None:
    """cal=None publishes the raw vector and covariance."""
    m = mag_msg(C, 1.0, [1e-5, 2e-5, 3e-5], cov=np.eye(3).reshape(-1))
    out = calibrate_mag(m, None)
    np.testing.assert_allclose(mag_to_numpy(out)[1], [1e-5, 2e-5, 3e-5])
    np.testing.assert_allclose(out.magnetic_field_covariance, np.eye(3).reshape(-1))


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, (3, 3), elements=st.floats(-2.0, 2.0)), arrays(np.float64, (3, 3), elements=st.floats(-1.0, 1.0)))
def test_covariance_propagation_keeps_symmetry_and_psd(w: np.ndarray, a: np.ndarray) -> None:
    """W Σ Wᵀ of a symmetric PSD Σ is symmetric PSD and equals the matrix product."""
    sigma = a @ a.T + 1e-9 * np.eye(3)
    out = propagate_covariance(sigma.reshape(-1), w).reshape(3, 3)
    np.testing.assert_allclose(out, w @ sigma @ w.T, atol=1e-12)
    np.testing.assert_allclose(out, out.T, atol=1e-12)
    assert np.linalg.eigvalsh(out).min() > -1e-9


def test_covariance_of_wrong_size_is_refused() -> None:
    """Not 9 numbers -> InputError naming the size."""
    with pytest.raises(InputError, match="9 numbers"):
        propagate_covariance([1.0, 2.0], np.eye(3))


def test_calibration_message_round_trip(cal: Calibration) -> None:
    """The transient-local calibration topic carries the ros__parameters YAML, losslessly."""
    msg = calibration_to_string(cal.replace(stamp=42.0), C.String)
    assert "ros__parameters" in msg.data
    back = calibration_from_string(_roundtrip(msg), sensor="mag")
    assert back.allclose(cal) and back.stamp == 42.0
    with pytest.raises(CalibrationFileError):
        calibration_from_string(C.String(data="not: [a calibration"))


@pytest.mark.parametrize(("encoder", "expected"), [(int, 1), (lambda lv: bytes([lv]), b"\x01")])
def test_status_to_diagnostic_levels_and_values(encoder: object, expected: object) -> None:
    """Level from the IntEnum through the encoder (int for rosbags, bytes for rclpy); key/values as strings."""
    cal = SensorCalibrator("mag", validator=FallbackValidator())
    cal.push(0.0, [1e-5, 2e-5, 3e-5])
    st_ = cal.status()
    assert st_.level is Level.WARN
    d = status_to_diagnostic(st_, C.DiagnosticStatus, C.KeyValue, level_encoder=encoder, hardware_id="imu_link")
    assert d.level == expected
    assert d.name == "margcal: mag" and d.hardware_id == "imu_link"
    assert d.message.startswith("collecting")
    kv = {x.key: x.value for x in d.values}
    assert kv["state"] == "collecting" and kv["samples_seen"] == "1"
    if encoder is int:
        arr = C.DiagnosticArray(header=C.Header(stamp=C.Time(sec=0, nanosec=0), frame_id=""), status=[d])
        assert _roundtrip(arr).status[0].level == 1


def test_messages_and_arrays_give_the_same_calibration() -> None:
    """The message path (msgdata -> mag_to_numpy -> push) matches the array path: what the node and replay see."""
    from msgdata import mag_stream

    from ros_margcal.sim import simulation as sim

    truth = sim.random_sensor(np.random.default_rng(11), "mag")
    rec = sim.magnetometer_stream(truth, 50.0, 50.0, np.random.default_rng(12), motion="tumble")
    via_msgs, via_arrays = SensorCalibrator("mag"), SensorCalibrator("mag")
    for m in mag_stream(C, rec.t, rec.raw):
        via_msgs.push(*mag_to_numpy(m))
    for t, v in zip(rec.t.tolist(), rec.raw, strict=True):
        via_arrays.push(t, v)
    assert via_arrays.calibration is not None and via_msgs.calibration is not None
    # stamps go through sec/nanosec (ns rounding), so a sample at a bin's 0.5 s boundary may differ and
    # the two buffers are not identical: the offsets must agree within their own reported uncertainty
    a, b = via_msgs.calibration, via_arrays.calibration
    assert a.stamp == pytest.approx(b.stamp, abs=0.1)
    std = np.hypot(*[[c.parameter_std()[k] for k in ("b_x", "b_y", "b_z")] for c in (a, b)])
    assert np.all(np.abs(a.offset - b.offset) < 3.0 * std)
    np.testing.assert_allclose(a.matrix, b.matrix, atol=1e-2)
    assert via_msgs.status().samples_seen == len(rec)
