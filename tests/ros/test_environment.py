"""The wheels' environment: AMENT_PREFIX_PATH set to the venv when unset, a sourced ROS left alone (no rclpy)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from ros_margcal.ros.environment import use_venv_ament_prefix


def test_set_to_the_prefix_when_unset_and_an_index_is_there(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    assert not use_venv_ament_prefix()  # no ament index under the prefix: nothing to point at
    (tmp_path / "share" / "ament_index").mkdir(parents=True)
    assert use_venv_ament_prefix()
    assert os.environ["AMENT_PREFIX_PATH"] == str(tmp_path)


def test_a_sourced_ros_is_left_alone(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("AMENT_PREFIX_PATH", "/opt/ros/jazzy")
    (tmp_path / "share" / "ament_index").mkdir(parents=True)
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    assert not use_venv_ament_prefix()
    assert os.environ["AMENT_PREFIX_PATH"] == "/opt/ros/jazzy"
