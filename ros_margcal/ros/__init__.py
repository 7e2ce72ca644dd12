"""ROS 2 glue: message conversion (``messages``), the choice of sample time (``stamps``), the gyro pairing
(``pairing``), the calibrators' worker process (``worker``) and the wheels' environment (``environment``),
none needing rclpy, and the node (``node``, rclpy).

This face does not import ``node``: import ``ros_margcal.ros.node`` where rclpy is available.
"""

from __future__ import annotations

from .messages import (
    calibrate_imu, calibrate_mag, calibration_from_string, calibration_to_string, imu_to_numpy, mag_to_numpy,
    propagate_covariance, stamp_to_seconds, status_to_diagnostic, vector3_to_numpy
)
from .environment import use_venv_ament_prefix
from .pairing import RatePairing
from .stamps import STAMP_SOURCES, StampSource
from .worker import CalibrationWorker

__all__ = [
    "STAMP_SOURCES", "CalibrationWorker", "RatePairing", "StampSource",
    "calibrate_imu", "calibrate_mag", "calibration_from_string", "calibration_to_string", "imu_to_numpy",
    "mag_to_numpy", "propagate_covariance", "stamp_to_seconds", "status_to_diagnostic", "use_venv_ament_prefix",
    "vector3_to_numpy"
]
