"""Benchmark of the streaming pipeline: replay throughput and per-message cost.

``margcal bench pipeline [--quick]`` (or ``python scripts/bench_pipeline.py``) measures, in one run:

- per-message cost of ``SensorCalibrator.push`` for a magnetometer and an accelerometer stream
  (median and 99th percentile of single-call timings; target: median <= 20 µs, so a 1 kHz IMU costs
  under 2 % of a core before rclpy), as a ratio to the baseline measured in the same run: the bare
  conversion of the same message to numpy (``messages.mag_to_numpy`` / ``imu_to_numpy``);
- per-message cost of building the calibrated output message (``messages.calibrate_mag``), the
  other thing the node does per message, against the same baseline;
- replay throughput in samples per second for the pipeline alone (arrays in) and for the whole
  ``margcal replay`` path from an .mcap bag (deserialisation included).

Every figure is printed with the baseline of the same run, so results from different machines
compare as ratios.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..recordings.bag import iter_bag_messages, write_bag
from ..ros.messages import calibrate_mag, imu_to_numpy, mag_to_numpy
from ..sim import simulation as sim
from ..stream.calibrator import SensorCalibrator
from ..stream.replay import replay

__all__ = ["main"]

TARGET_US = 20.0


def _typestore_classes() -> dict[str, Any]:
    from rosbags.typesys import Stores, get_typestore  # optional dependency: bags only (a ROS install may lack rosbags)

    t = get_typestore(Stores.ROS2_JAZZY).types
    return {k: t[v] for k, v in {
        "Imu": "sensor_msgs/msg/Imu", "MagneticField": "sensor_msgs/msg/MagneticField", "Header": "std_msgs/msg/Header",
        "Time": "builtin_interfaces/msg/Time", "Vector3": "geometry_msgs/msg/Vector3",
        "Quaternion": "geometry_msgs/msg/Quaternion"}.items()}


def _messages(c: dict[str, Any], rec: sim.Recording, kind: str) -> list[Any]:
    out = []
    zero9 = np.zeros(9)
    for i, (t, v) in enumerate(zip(rec.t.tolist(), rec.raw.tolist(), strict=True)):
        sec = int(t)
        hdr = c["Header"](stamp=c["Time"](sec=sec, nanosec=int((t - sec) * 1e9)), frame_id="imu_link")
        vec = c["Vector3"](x=v[0], y=v[1], z=v[2])
        if kind == "mag":
            out.append(c["MagneticField"](header=hdr, magnetic_field=vec, magnetic_field_covariance=zero9))
        else:
            g = rec.gyro[i] if rec.gyro is not None else np.zeros(3)
            out.append(c["Imu"](header=hdr, orientation=c["Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                                orientation_covariance=zero9, angular_velocity=c["Vector3"](x=g[0], y=g[1], z=g[2]),
                                angular_velocity_covariance=zero9, linear_acceleration=vec,
                                linear_acceleration_covariance=zero9))
    return out


def _per_message(msgs: list[Any], kind: str) -> dict[str, Any]:
    """Single-call timings (seconds) of: conversion alone, conversion + push, output message."""
    perf = time.perf_counter
    cal = SensorCalibrator("mag" if kind == "mag" else "accel")
    conv, push, out = [], [], []
    if kind == "mag":
        for m in msgs:
            t0 = perf()
            mag_to_numpy(m)
            t1 = perf()
            t, v = mag_to_numpy(m)
            cal.push(t, v)
            t2 = perf()
            conv.append(t1 - t0)
            push.append(t2 - t1)
        c = cal.calibration
        for m in msgs[: min(len(msgs), 5000)]:
            t0 = perf()
            calibrate_mag(m, c)
            out.append(perf() - t0)
    else:
        for m in msgs:
            t0 = perf()
            imu_to_numpy(m)
            t1 = perf()
            t, a, g = imu_to_numpy(m)
            cal.push(t, a, g)
            t2 = perf()
            conv.append(t1 - t0)
            push.append(t2 - t1)
    return {"convert": np.array(conv), "push": np.array(push), "output": np.array(out), "calibrated": cal.calibration is not None}


def _throughput(rec: sim.Recording, sensor: str) -> float:
    cal = SensorCalibrator(sensor)
    g = rec.gyro if (sensor == "accel" and rec.gyro is not None) else [None] * len(rec)
    t0 = time.perf_counter()
    for t, v, w in zip(rec.t.tolist(), rec.raw, g, strict=True):
        cal.push(t, v, w)
    return len(rec) / (time.perf_counter() - t0)


def _bag_throughput(mag: sim.Recording, imu: sim.Recording) -> tuple[float, float]:
    """Samples/s of the full replay from an .mcap, and of reading the bag alone (the baseline)."""

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        write_bag(path, {"/imu/data_raw": imu, "/imu/mag": mag})
        t0 = time.perf_counter()
        n_read = sum(1 for _ in iter_bag_messages(path))
        t_read = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = replay(path, status_every=0.0, progress=False)
        t_replay = time.perf_counter() - t0
    return res["messages"] / t_replay, n_read / t_read


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the figures; returns 0 (1 when the median target is missed)."""
    parser = argparse.ArgumentParser(prog="margcal bench pipeline", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short streams (about 10 s in all)")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)
    duration = 60.0 if args.quick else 300.0
    rng = np.random.default_rng(args.seed)
    mag_truth = sim.random_sensor(rng, "mag")
    acc_truth = sim.random_sensor(rng, "accel")
    mag = sim.magnetometer_stream(mag_truth, duration, 50.0, rng, motion="tumble")
    imu = sim.tumbling(acc_truth, duration, 100.0, rng)
    classes = _typestore_classes()

    print(f"pipeline benchmark ({'quick' if args.quick else 'full'}: {duration:.0f} s of mag at 50 Hz, IMU at 100 Hz)")
    print("\nper-message cost (single calls; baseline = the bare numpy conversion of the same message)")
    ok = True
    for kind, rec in (("mag", mag), ("imu", imu)):
        r = _per_message(_messages(classes, rec, kind), kind)
        base = float(np.median(r["convert"])) * 1e6
        med = float(np.median(r["push"])) * 1e6
        p99 = float(np.percentile(r["push"], 99)) * 1e6
        mean = float(np.mean(r["push"])) * 1e6
        ok &= med <= TARGET_US
        print(f"  {kind:4s} convert {base:6.2f} us | push median {med:6.2f} us ({med / base:5.1f}x), "
              f"p99 {p99:8.1f} us, mean {mean:6.1f} us (fits included) | calibrated: {r['calibrated']} | "
              f"target median <= {TARGET_US:.0f} us: {'met' if med <= TARGET_US else 'MISSED'}")
        if len(r["output"]):
            out = float(np.median(r["output"])) * 1e6
            print(f"  {kind:4s} calibrated output message median {out:6.2f} us ({out / base:5.1f}x the conversion)")
    print("\nreplay throughput (samples/s)")
    t_mag = _throughput(mag, "mag")
    t_imu = _throughput(imu, "accel")
    print(f"  pipeline only: mag {t_mag:10.0f}/s ({t_mag / 50.0:6.0f}x real time), "
          f"imu {t_imu:10.0f}/s ({t_imu / 100.0:6.0f}x real time)")
    t_bag, t_read = _bag_throughput(mag, imu)
    print(f"  margcal replay from .mcap: {t_bag:10.0f} msgs/s; reading the bag alone {t_read:10.0f} msgs/s "
          f"(replay = {t_bag / t_read:.2f}x of the read rate)")
    return 0 if ok else 1
