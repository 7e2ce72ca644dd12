"""The package face: public names import without rclpy, and the margcal command lists its subcommands."""

from __future__ import annotations

import subprocess
import sys

import pytest

import ros_margcal
from ros_margcal.cli import build_parser, main


def test_public_api_is_importable_without_rclpy() -> None:
    """Every name in __all__ resolves, and importing the package (and its command line) does not pull in rclpy:
    checked in a fresh interpreter (in this one an earlier test may have imported rclpy itself)."""
    for name in ros_margcal.__all__:
        assert getattr(ros_margcal, name) is not None, name
    code = ("import sys, ros_margcal, ros_margcal.cli; [getattr(ros_margcal, n) for n in ros_margcal.__all__]; "
            "sys.exit('rclpy' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], check=False, timeout=120).returncode == 0


def test_cli_has_every_design_subcommand() -> None:
    """DESIGN.md's subcommands are all registered."""
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert {"simulate", "calibrate", "replay", "train-validator", "evaluate-validator", "diagnose", "bench"} <= set(sub.choices)


def test_cli_reports_bad_input_with_exit_code_2(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    """A corrupt recording gives a one-line error and exit code 2, not a traceback."""
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x,y,z\n0,1,2\n")
    assert main(["calibrate", str(bad), "--sensor", "mag"]) == 2
    assert "error" in capsys.readouterr().err
