"""Conversions between ROS messages and numpy, duck-typed so that no rclpy import is needed.

Everything here works on any object with the attribute layout of the ROS 2 message types
(``sensor_msgs/msg/Imu``, ``sensor_msgs/msg/MagneticField``, ``diagnostic_msgs/msg/*``,
``std_msgs/msg/String``): the rclpy classes on a robot, the ``rosbags`` typestore classes in the
tests and the offline replay. New messages of the same type as an input are built with
``type(msg)(field=..., ...)``, which both rclpy and rosbags classes accept.

Conventions (REP-103, REP-145, the message definitions):

- stamps are ``sec + nanosec * 1e-9`` seconds; the header (stamp, frame_id) of a calibrated message
  is the header of the raw one, unchanged;
- a covariance whose element 0 is ``-1`` means "this field is not provided" and passes through
  unchanged; any other covariance ``Σ`` of the raw vector becomes ``W Σ Wᵀ`` for the calibrated
  vector ``W (v - b)`` (the offset does not change the covariance; its own uncertainty is ignored);
- the calibration topic carries ``std_msgs/String`` whose ``data`` is the ``ros__parameters``
  YAML of ``calibration_to_yaml`` (one sensor per topic, read back with
  ``calibration_from_yaml``). A String with YAML was chosen over a DiagnosticArray because it
  is lossless (covariance, fit statistics, format version) and is the very text a node accepts as
  ``--params-file``;
- the status level is ``pipeline.Level`` (an ``IntEnum``) up to the last step: ``status_to_diagnostic``
  takes a ``level_encoder`` so that the node can hand rclpy the ``bytes`` it wants for the ``byte``
  field while rosbags classes take the ``int``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.calibration_file import calibration_from_yaml, calibration_to_yaml
from ..model.errors import CalibrationFileError, InputError

__all__ = [
    "calibrate_imu", "calibrate_mag", "calibration_from_string", "calibration_to_string", "imu_to_numpy",
    "mag_to_numpy", "propagate_covariance", "stamp_to_seconds", "status_to_diagnostic", "vector3_to_numpy"
]

Array = NDArray[np.float64]


def stamp_to_seconds(stamp: Any) -> float:
    """``builtin_interfaces/Time`` -> seconds (float)."""
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def vector3_to_numpy(v: Any) -> Array:
    """``geometry_msgs/Vector3`` -> array (3,)."""
    return np.array([v.x, v.y, v.z], dtype=np.float64)


def mag_to_numpy(msg: Any) -> tuple[float, Array]:
    """``sensor_msgs/MagneticField`` -> (stamp seconds, field (3,) in tesla)."""
    return stamp_to_seconds(msg.header.stamp), vector3_to_numpy(msg.magnetic_field)


def imu_to_numpy(msg: Any) -> tuple[float, Array, Array]:
    """``sensor_msgs/Imu`` -> (stamp seconds, linear acceleration (3,) m/s², angular velocity (3,) rad/s)."""
    return (
        stamp_to_seconds(msg.header.stamp),
        vector3_to_numpy(msg.linear_acceleration),
        vector3_to_numpy(msg.angular_velocity),
    )


def propagate_covariance(cov: Sequence[float] | Array, matrix: Array) -> Array:
    """Row-major 3x3 covariance (9,) of a raw vector -> covariance of ``W (v - b)``: ``W Σ Wᵀ``.

    Element 0 == -1 ("not provided", sensor_msgs convention) is returned unchanged, as is a
    covariance with a NaN (nothing sensible to propagate).

    Raises:
        InputError: when ``cov`` does not hold 9 numbers.
    """
    c = np.asarray(cov, dtype=np.float64).reshape(-1)
    if c.size != 9:
        msg = f"covariance must hold 9 numbers (row-major 3x3), got {c.size}"
        raise InputError(msg)
    if c[0] == -1.0 or not np.isfinite(c).all():
        return c.copy()
    w = np.asarray(matrix, dtype=np.float64).reshape(3, 3)
    return (w @ c.reshape(3, 3) @ w.T).reshape(-1)


def _vector3_like(template: Any, xyz: Array) -> Any:
    return type(template)(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def _calibrated(vec: Any, covariance: Any, cal: Calibration | None) -> tuple[Array, Array]:
    """``W (v - b)`` and ``W Σ Wᵀ`` of one Vector3 and its flat covariance (passed through when ``cal`` is None)."""
    xyz = vector3_to_numpy(vec)
    cov = np.asarray(covariance, dtype=np.float64).reshape(-1)
    if cal is None:
        return xyz, cov
    return cal.apply(xyz), propagate_covariance(cov, cal.matrix)


def calibrate_mag(msg: Any, cal: Calibration | None) -> Any:
    """A new MagneticField of the same type: same header, ``W (v - b)``, covariance ``W Σ Wᵀ``.

    With ``cal=None`` the raw values are passed through (the node publishes raw data until the
    first calibration is accepted only when asked to).
    """
    raw, cov = _calibrated(msg.magnetic_field, msg.magnetic_field_covariance, cal)
    return type(msg)(
        header=msg.header,
        magnetic_field=_vector3_like(msg.magnetic_field, raw),
        magnetic_field_covariance=np.array(cov, dtype=np.float64),
    )


def calibrate_imu(msg: Any, cal: Calibration | None) -> Any:
    """A new Imu of the same type with the linear acceleration calibrated; everything else copied."""
    acc, cov = _calibrated(msg.linear_acceleration, msg.linear_acceleration_covariance, cal)
    return type(msg)(
        header=msg.header,
        orientation=msg.orientation,
        orientation_covariance=np.array(msg.orientation_covariance, dtype=np.float64),
        angular_velocity=msg.angular_velocity,
        angular_velocity_covariance=np.array(msg.angular_velocity_covariance, dtype=np.float64),
        linear_acceleration=_vector3_like(msg.linear_acceleration, acc),
        linear_acceleration_covariance=np.array(cov, dtype=np.float64),
    )


def calibration_to_string(cal: Calibration, string_cls: type, node: str = "margcal") -> Any:
    """The message of the transient-local calibration topic: ``std_msgs/String`` with the YAML."""
    return string_cls(data=calibration_to_yaml(cal, node=node))


def calibration_from_string(msg: Any, sensor: str | None = None) -> Calibration:
    """Inverse of ``calibration_to_string``; CalibrationFileError when the text is not one."""
    text = getattr(msg, "data", None)
    if not isinstance(text, str):
        msg_ = "calibration message has no string 'data' field"
        raise CalibrationFileError(msg_)
    return calibration_from_yaml(text, sensor=sensor)


def status_to_diagnostic(
    status: Any,
    status_cls: type,
    key_value_cls: type,
    *,
    level_encoder: Callable[[int], Any] = int,
    hardware_id: str = "",
) -> Any:
    """A ``pipeline.Status`` -> ``diagnostic_msgs/DiagnosticStatus``.

    Args:
        status: the status value (``level``, ``name``, ``message``, ``values()`` -> list of pairs).
        status_cls: the DiagnosticStatus class (rclpy or rosbags).
        key_value_cls: the KeyValue class.
        level_encoder: turns the integer level into the field type: ``int`` for rosbags,
            ``lambda lv: bytes([lv])`` for rclpy (the node passes that).
        hardware_id: the hardware id field (the frame id of the sensor, typically).
    """
    return status_cls(
        level=level_encoder(int(status.level)),
        name=str(status.name),
        message=str(status.message),
        hardware_id=str(hardware_id),
        values=[key_value_cls(key=str(k), value=str(v)) for k, v in status.values()],
    )
