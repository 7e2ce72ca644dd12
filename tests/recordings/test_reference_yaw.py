"""The real-recording study's check against another AHRS's yaw (scripts/study_real_recordings.py
``reference_heading_p95``): a car's heading, tilt-compensated with the reference's roll and pitch, against its yaw."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from conftest import load_script


@pytest.fixture(scope="module")
def study() -> ModuleType:
    """The script, loaded as when it runs (``conftest.load_script``)."""
    return load_script("study_real_recordings")


def _car(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Three loops of a car with the sensor rolled 12 deg (NED body axes, ZYX yaw-pitch-roll in degrees): the
    readings of a 65 deg dipping field and the attitude."""
    n = 3000
    yaw = np.linspace(0.0, 3 * 360.0, n)
    pitch = 3.0 * np.sin(np.radians(5 * yaw)) + rng.normal(0.0, 0.3, n)
    roll = 12.0 + 4.0 * np.sin(np.radians(3 * yaw))
    inc = np.radians(65.0)
    m = np.array([np.cos(inc), 0.0, np.sin(inc)])  # north, east, down
    y, p, r = np.radians(yaw), np.radians(pitch), np.radians(roll)
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    # R = Rz(yaw) Ry(pitch) Rx(roll), body -> NED; the body reads R^T m
    rot = np.stack([np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
                    np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
                    np.stack([-sp, cp * sr, cp * cr], -1)], -2)
    return np.einsum("nji,j->ni", rot, m), np.column_stack([(yaw + 180.0) % 360.0 - 180.0, pitch, roll])


def test_an_exact_field_agrees_with_the_reference_and_a_hard_iron_does_not(study: ModuleType) -> None:
    h, att = _car(np.random.default_rng(71))
    assert study.reference_heading_p95(h, att) < 1e-6
    declined = att.copy()
    declined[:, 0] += 14.0  # a declination (or the mounting's yaw): a constant, taken off
    assert study.reference_heading_p95(h, declined) < 1e-6
    other_hand = att.copy()
    other_hand[:, 0] = -other_hand[:, 0]  # a reference whose yaw turns the other way
    assert study.reference_heading_p95(h, other_hand) < 1e-6
    iron = h + np.array([0.3, -0.1, 0.05])  # 30 % of the field: tens of degrees
    assert study.reference_heading_p95(iron, att) > 10.0
    assert study.reference_heading_p95(h + np.array([0.0, 0.0, 0.3]), att) > 1.0  # vertical iron, seen through the roll


def test_the_table_reads_the_attitude_beside_a_recording(study: ModuleType, tmp_path: Path) -> None:
    """``NAME_attitude.csv`` beside ``NAME_mag.csv``: a table row for the raw readings (and none without the file)."""
    h, att = _car(np.random.default_rng(72))
    t = np.arange(len(h)) / 25.0
    mag = tmp_path / "car_mag.csv"
    np.savetxt(mag, np.column_stack([t, 50.0 * h + np.array([20.0, -5.0, 3.0])]), delimiter=",", header="t,x,y,z",
               comments="")
    assert study.against_reference_yaw(mag, "uT") == []
    np.savetxt(tmp_path / "car_attitude.csv", np.column_stack([t, att]), delimiter=",",
               header="t,yaw_deg,pitch_deg,roll_deg", comments="")
    lines = study.against_reference_yaw(mag, "uT")
    raw = next(line for line in lines if "| uncalibrated |" in line)
    assert float(raw.split("|")[4].strip().rstrip("°")) > 10.0, lines
