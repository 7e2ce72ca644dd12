"""The shared builder of test messages: the same arrays become rosbags or rclpy messages.

The rosbags-based tests (``test_messages.py``, ``test_pipeline.py``) and the rclpy node tests
(``test_node.py``) build their ``sensor_msgs/Imu`` and ``sensor_msgs/MagneticField`` messages here,
from the same numpy arrays, so both paths see the same data. ``rosbags_classes()`` needs only the
``rosbags`` package; ``rclpy_classes()`` needs a sourced ROS 2 Jazzy.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Iterator
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from numpy.typing import ArrayLike

UNKNOWN_COVARIANCE = np.array([-1.0] + [0.0] * 8)
"""sensor_msgs convention: element 0 == -1 means "not provided"."""


@dataclass(frozen=True)
class MessageClasses:
    """The message classes a test needs, from one implementation (rosbags or rclpy)."""

    Imu: type
    MagneticField: type
    Header: type
    Time: type
    Vector3: type
    Quaternion: type
    DiagnosticArray: type
    DiagnosticStatus: type
    KeyValue: type
    String: type
    level_encoder: Any  # int -> the DiagnosticStatus.level field type


def rosbags_classes() -> MessageClasses:
    """The ROS 2 Jazzy typestore classes of rosbags (levels are ints)."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    t = ts.types
    return MessageClasses(
        Imu=t["sensor_msgs/msg/Imu"],
        MagneticField=t["sensor_msgs/msg/MagneticField"],
        Header=t["std_msgs/msg/Header"],
        Time=t["builtin_interfaces/msg/Time"],
        Vector3=t["geometry_msgs/msg/Vector3"],
        Quaternion=t["geometry_msgs/msg/Quaternion"],
        DiagnosticArray=t["diagnostic_msgs/msg/DiagnosticArray"],
        DiagnosticStatus=t["diagnostic_msgs/msg/DiagnosticStatus"],
        KeyValue=t["diagnostic_msgs/msg/KeyValue"],
        String=t["std_msgs/msg/String"],
        level_encoder=int,
    )


def import_rclpy() -> ModuleType:
    """rclpy, or a skip where ROS 2 is absent; under CI (``CI=true``) a missing rclpy fails instead: the node
    tests must run there (the ``[ros]`` extra installs it)."""
    if os.environ.get("CI") == "true":
        return importlib.import_module("rclpy")
    return pytest.importorskip("rclpy", reason="rclpy not importable: install the [ros] extra or source ROS 2 Jazzy")


def rclpy_classes() -> MessageClasses:
    """The generated Python classes of a ROS 2 installation (levels are one-byte ``bytes``)."""
    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import Quaternion, Vector3
    from sensor_msgs.msg import Imu, MagneticField
    from std_msgs.msg import Header, String

    return MessageClasses(
        Imu=Imu,
        MagneticField=MagneticField,
        Header=Header,
        Time=Time,
        Vector3=Vector3,
        Quaternion=Quaternion,
        DiagnosticArray=DiagnosticArray,
        DiagnosticStatus=DiagnosticStatus,
        KeyValue=KeyValue,
        String=String,
        level_encoder=lambda lv: bytes([int(lv)]),
    )


def header(c: MessageClasses, t: float, frame_id: str = "imu_link") -> Any:
    """A Header at ``t`` seconds (t >= 0)."""
    sec = int(np.floor(t))
    nanosec = round((t - sec) * 1e9)
    if nanosec >= 1_000_000_000:
        sec, nanosec = sec + 1, nanosec - 1_000_000_000
    return c.Header(stamp=c.Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _vec(c: MessageClasses, xyz: ArrayLike) -> Any:
    x, y, z = (float(v) for v in np.asarray(xyz, dtype=np.float64).reshape(3))
    return c.Vector3(x=x, y=y, z=z)


def mag_msg(c: MessageClasses, t: float, xyz: ArrayLike, cov: ArrayLike | None = None, frame_id: str = "imu_link") -> Any:
    """A MagneticField (tesla) at ``t``; covariance defaults to "unknown" (all zeros)."""
    cov_arr = np.zeros(9) if cov is None else np.asarray(cov, dtype=np.float64).reshape(9)
    return c.MagneticField(header=header(c, t, frame_id), magnetic_field=_vec(c, xyz), magnetic_field_covariance=cov_arr.copy())


def imu_msg(
    c: MessageClasses,
    t: float,
    accel: ArrayLike,
    gyro: ArrayLike | None = None,
    cov: ArrayLike | None = None,
    frame_id: str = "imu_link",
) -> Any:
    """An Imu (data_raw: orientation not provided) at ``t`` with the given acceleration and rate."""
    cov_arr = np.zeros(9) if cov is None else np.asarray(cov, dtype=np.float64).reshape(9)
    return c.Imu(
        header=header(c, t, frame_id),
        orientation=c.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=UNKNOWN_COVARIANCE.copy(),
        angular_velocity=_vec(c, np.zeros(3) if gyro is None else gyro),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=_vec(c, accel),
        linear_acceleration_covariance=cov_arr.copy(),
    )


def mag_stream(c: MessageClasses, t: ArrayLike, raw: ArrayLike, frame_id: str = "imu_link") -> Iterator[Any]:
    """MagneticField messages for every row of ``raw`` (n, 3) at times ``t`` (n,)."""
    for ti, xyz in zip(np.asarray(t, dtype=np.float64), np.asarray(raw, dtype=np.float64), strict=True):
        yield mag_msg(c, float(ti), xyz, frame_id=frame_id)


def imu_stream(
    c: MessageClasses, t: ArrayLike, accel: ArrayLike, gyro: ArrayLike | None = None, frame_id: str = "imu_link"
) -> Iterator[Any]:
    """Imu messages for every row of ``accel`` (n, 3) (and ``gyro`` if given) at times ``t``."""
    acc = np.asarray(accel, dtype=np.float64)
    gyr = np.zeros_like(acc) if gyro is None else np.asarray(gyro, dtype=np.float64)
    for ti, a, g in zip(np.asarray(t, dtype=np.float64), acc, gyr, strict=True):
        yield imu_msg(c, float(ti), a, g, frame_id=frame_id)

