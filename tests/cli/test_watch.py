"""``margcal watch``: the status of /calib/status taken into per-sensor views; the message without rclpy.

The end-to-end run against a live node is in ``tests/ros/test_node_process.py`` (real rclpy)."""

from __future__ import annotations

import sys
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from ros_margcal.cli import main
from ros_margcal.cli.watch import SensorView, update_views

_T = get_typestore(Stores.ROS2_JAZZY).types


def status_array(rows: list[tuple[str, int, str, str]]) -> Any:
    """A real diagnostic_msgs/DiagnosticArray (rosbags' Jazzy types) with (sensor, level, state, samples_seen) rows."""
    kv, st = _T["diagnostic_msgs/msg/KeyValue"], _T["diagnostic_msgs/msg/DiagnosticStatus"]
    header = _T["std_msgs/msg/Header"](stamp=_T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="")
    return _T["diagnostic_msgs/msg/DiagnosticArray"](header=header, status=[
        st(level=level, name=f"margcal: {s}", message=state, hardware_id="imu_link",
           values=[kv(key="state", value=state), kv(key="samples_seen", value=samples)])
        for s, level, state, samples in rows])


def test_update_views_takes_every_sensor_and_remembers_when_it_calibrated() -> None:
    """Each sensor's latest status; the time of its first calibrated status is kept, later ones do not move it."""
    views: dict[str, SensorView] = {}
    update_views(views, status_array([("mag", 1, "collecting", "100")]), 1.0)
    update_views(views, status_array([("mag", 0, "calibrated", "900"), ("accel", 1, "collecting", "5")]), 9.0)
    update_views(views, status_array([("mag", 0, "calibrated", "1000")]), 12.0)
    assert sorted(views) == ["accel", "mag"]
    assert views["mag"].state == "calibrated" and views["mag"].calibrated_at == 9.0
    assert views["mag"].calibrated_samples == "900" and views["mag"].values["samples_seen"] == "1000"
    only: dict[str, SensorView] = {"mag": SensorView()}
    update_views(only, status_array([("accel", 1, "collecting", "5")]), 1.0, add=False)
    assert sorted(only) == ["mag"]


def test_watch_without_rclpy_exits_2_saying_what_to_install(monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """No rclpy: exit code 2 and one line naming the ROS extra."""
    monkeypatch.setitem(sys.modules, "rclpy", None)
    assert main(["watch", "--once"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install -e '.[ros]'" in err[0]


@pytest.mark.parametrize("bad", [["--timeout", "nan"], ["--duration", "-1"]])
def test_watch_refuses_absurd_times(bad: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """A non-finite or negative time is refused with exit 2 before anything starts."""
    assert main(["watch", *bad]) == 2
    assert "positive number of seconds" in capsys.readouterr().err
