"""Run the margcal node with msg_configs/margcal.yaml, optionally beside an IMU driver.

    ros2 launch ros_margcal margcal.launch.py
    ros2 launch ros_margcal margcal.launch.py driver_package:=my_imu driver_executable:=imu_node
    ros2 launch ros_margcal margcal.launch.py params_file:=/path/to/margcal.yaml imu_ns:=imu
    ros2 launch ros_margcal margcal.launch.py stamp_source:=receive   # a driver with broken header stamps

The driver (when given) must publish sensor_msgs/Imu on ``<imu_ns>/data_raw`` and
sensor_msgs/MagneticField on ``<imu_ns>/mag``; the node publishes ``imu_calibrated/*``.
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    """The launch description: arguments, the optional driver, the margcal node."""
    default_params = os.path.join(get_package_share_directory("ros_margcal"), "msg_configs", "margcal.yaml")
    params_file = LaunchConfiguration("params_file")
    driver_package = LaunchConfiguration("driver_package")
    driver_executable = LaunchConfiguration("driver_executable")
    imu_ns = LaunchConfiguration("imu_ns")
    stamp_source = LaunchConfiguration("stamp_source")
    have_driver = PythonExpression(["'", driver_package, "' != '' and '", driver_executable, "' != ''"])
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params, description="node parameters (YAML)"),
        DeclareLaunchArgument("driver_package", default_value="", description="IMU driver package ('' = none)"),
        DeclareLaunchArgument("driver_executable", default_value="", description="IMU driver executable"),
        DeclareLaunchArgument("imu_ns", default_value="imu", description="namespace of the driver's raw topics"),
        DeclareLaunchArgument("stamp_source", default_value="auto",
                              description="sample time: header, receive or auto (header, else receive time)"),
        Node(
            package=driver_package,
            executable=driver_executable,
            name="imu_driver",
            output="screen",
            condition=IfCondition(have_driver),
        ),
        Node(
            package="ros_margcal",
            executable="margcal_node",
            name="margcal",
            output="screen",
            parameters=[params_file, {"stamp_source": stamp_source}],
            remappings=[
                ("imu/data_raw", [imu_ns, "/data_raw"]),
                ("imu/mag", [imu_ns, "/mag"]),
            ],
        ),
    ])
