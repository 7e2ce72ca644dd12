"""ament_python / pip set-up for ros_margcal (installs without ROS; builds with colcon on Jazzy)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "ros_margcal"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Online in-use calibration of magnetometers and accelerometers for ROS 2",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(exclude=["tests", "tests.*"]),
    package_data={PACKAGE: ["py.typed", "data/*.mcap", "data/*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/msg_configs", glob("msg_configs/*.yaml") + glob("msg_configs/*.json")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools", "numpy>=1.24", "scipy>=1.10", "PyYAML>=6", "rosbags>=0.10", "matplotlib>=3.6", "tqdm>=4.60",
                      # the WMM field at a position (model/geomag.py; imported only where used: an apt Jazzy may lack it)
                      "pygeomag>=1.1"],
    extras_require={
        "test": ["pytest>=7", "hypothesis>=6"],
        "dev": ["ruff", "mypy"],
        # ROS 2 Jazzy from PyPI wheels, for a machine without a ROS install; with an apt-installed, sourced
        # Jazzy leave this extra out (its rclpy is the one to use)
        "ros": ["ros-jazzy-rclpy", "ros-jazzy-rmw-fastrtps-cpp", "ros-jazzy-sensor-msgs", "ros-jazzy-diagnostic-msgs",
                "ros-jazzy-std-srvs", "ros-jazzy-std-msgs", "ros-jazzy-visualization-msgs"],
    },
    # colcon test (ament_python) runs pytest when tests_require (or extras_require["test"]) names it
    tests_require=["pytest>=7", "hypothesis>=6"],
    zip_safe=True,
    entry_points={
        "console_scripts": [
            "margcal = ros_margcal.cli:main",
            "margcal_node = ros_margcal.ros.node:main",
        ],
    },
)
