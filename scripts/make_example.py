#!/usr/bin/env python3
"""Make the example recording shipped with ros_margcal (deterministic: same seed, same messages and truth).

Writes ``ros_margcal/data/example_imu.mcap``: six minutes of a hand-tumbled IMU, still periods of
2.5-5 s at random orientations joined by smooth turns (up to 150 °/s) with linear acceleration:

- ``/imu/data_raw`` (sensor_msgs/Imu, 100 Hz): accelerometer in m/s² and gyro in rad/s, no orientation;
- ``/imu/mag`` (sensor_msgs/MagneticField, 50 Hz): magnetometer in tesla, with a hard-iron jump of
  0.8 x the field at t = 180 s (a magnet mounted beside the sensor).

and ``ros_margcal/data/example_truth.yaml`` with the true calibrations (``calibration.save_calibrations``):
``accel``, ``mag_before`` and ``mag_after`` (whose ``stamp`` is the jump time).

Same messages, not the same bytes: the .mcap's zstd-compressed chunks depend on the compressor build,
and the truth file is written in the current format (the shipped one may be an older format_version).
``tests/recordings/test_recordings.py`` compares topics, stamps, serialised messages and calibrations.

Usage: ``python scripts/make_example.py [--out-dir DIR] [--force]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ros_margcal.model.calibration_file import save_calibrations
from ros_margcal.recordings.bag import write_bag
from ros_margcal.sim.simulation import HardIronJump, magnetometer_stream, random_sensor, tumbling, tumbling_motion

SEED = 20261121
DURATION_S = 360.0
IMU_RATE_HZ = 100.0
MAG_RATE_HZ = 50.0
JUMP_AT_S = 180.0
JUMP_FRACTION = 0.8  # of the field norm
IMU_TOPIC = "/imu/data_raw"
MAG_TOPIC = "/imu/mag"
DATA_DIR = Path(__file__).resolve().parents[1] / "ros_margcal" / "data"


def make(out_dir: Path, force: bool = False) -> tuple[Path, Path]:
    """Write the example bag and its truth sidecar into ``out_dir``; returns both paths."""
    rng = np.random.default_rng(SEED)
    accel_truth = random_sensor(rng, "accel")
    mag_truth = random_sensor(rng, "mag")
    direction = rng.normal(size=3)
    delta = JUMP_FRACTION * mag_truth.norm * direction / np.linalg.norm(direction)
    motion = tumbling_motion(DURATION_S, IMU_RATE_HZ, rng, still_fraction=0.6, still_s=(2.5, 5.0))
    imu = tumbling(accel_truth, DURATION_S, IMU_RATE_HZ, rng, motion=motion, noise=0.002)
    mag = magnetometer_stream(mag_truth, DURATION_S, MAG_RATE_HZ, rng, motion=motion, noise=0.005,
                              events=[HardIronJump(JUMP_AT_S, tuple(delta))])
    bag = write_bag(out_dir / "example_imu.mcap", {IMU_TOPIC: imu, MAG_TOPIC: mag}, overwrite=force)
    after = mag_truth.replace(offset=mag_truth.offset + delta, stamp=JUMP_AT_S)
    truth = save_calibrations(out_dir / "example_truth.yaml",
                              {"accel": accel_truth, "mag_before": mag_truth, "mag_after": after})
    truth.chmod(0o644)  # package data: readable by everyone
    return bag, truth


def main(argv: list[str] | None = None) -> int:
    """Command line entry."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out-dir", type=Path, default=DATA_DIR)
    parser.add_argument("--force", action="store_true", help="replace existing files")
    args = parser.parse_args(argv)
    bag, truth = make(args.out_dir, args.force)
    print(f"wrote {bag} ({bag.stat().st_size / 1e6:.2f} MB) and {truth}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
