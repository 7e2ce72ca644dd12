"""Benchmark of the streaming pipeline: replay throughput and per-message cost.

``margcal bench pipeline [--quick]`` (or ``python scripts/bench_pipeline.py``) measures, in one run:

- per-message cost of ``SensorCalibrator.push`` for a magnetometer and an accelerometer stream
  (median and 99th percentile of single-call timings; target: median <= 20 µs, so a 1 kHz IMU costs
  under 2 % of a core before rclpy), as a ratio to the baseline measured in the same run: the bare
  conversion of the same message to numpy (``messages.mag_to_numpy`` / ``imu_to_numpy``);
- per-message cost of building the calibrated output message (``messages.calibrate_mag``), the
  other thing the node does per message, against the same baseline;
- mean and p99 cost per sample *all in* (validation, hull rebuilds and fits included) of
  ``SensorCalibrator.push`` fed sample by sample, on a tumble (rich motion: calibrates) and on a
  ground robot's motion (``ground_motion``: yaw turns with a few degrees of tilt, which never
  calibrates), with the validator calls and fits per 10 000 samples; the mean is what a node pays
  on average (target: <= 10 µs), as a ratio to the bare conversion of the same messages;
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
from scipy.spatial.transform import Rotation

from ..recordings.bag import iter_bag_messages, write_bag
from ..ros.messages import calibrate_mag, imu_to_numpy, mag_to_numpy
from ..sim import simulation as sim
from ..sim.motion import Motion, sample_times
from ..stream.calibrator import SensorCalibrator
from ..stream.replay import replay

__all__ = ["ground_motion", "main"]

TARGET_US = 20.0
TARGET_MEAN_US = 10.0


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


def ground_motion(duration_s: float, rate_hz: float, rng: np.random.Generator, *, tilt_deg: float = 3.0) -> Motion:
    """A ground robot: straight runs and yaw turns (0.2–0.9 rad/s, 1–5 s each) with roll and pitch
    wobbling within ``tilt_deg``: the field directions stay near one cone, so the sensor never calibrates."""
    t = sample_times(duration_s, rate_hz)
    rate = np.zeros(t.size)
    start, turning = 0.0, False
    while start <= t[-1]:
        dur = float(rng.uniform(1.5, 5.0) if turning else rng.uniform(1.0, 4.0))
        rate[(t >= start) & (t < start + dur)] = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 0.9)) if turning else 0.0
        start, turning = start + dur, not turning
    yaw = float(rng.uniform(-np.pi, np.pi)) + np.cumsum(rate) / rate_hz
    phase = rng.uniform(0.0, 2 * np.pi, size=2)
    tilt = np.radians(tilt_deg)
    rot = Rotation.from_euler("ZYX", np.c_[yaw, tilt * np.sin(0.17 * t + phase[1]), tilt * np.sin(0.31 * t + phase[0])])
    step = (rot[:-1].inv() * rot[1:]).as_rotvec() * rate_hz
    return Motion(t, rot, np.zeros((t.size, 3)), np.vstack([step, step[-1:]]), np.zeros(t.size, dtype=bool))


class _Counting:
    """A validator that counts its calls."""

    def __init__(self, inner: Any) -> None:
        self.inner, self.threshold, self.calls = inner, inner.threshold, 0

    def predict_indicators(self, ind: Any) -> float:
        self.calls += 1
        return float(self.inner.predict_indicators(ind))


def _all_in(rec: sim.Recording, sensor: str, *, deferred: bool = False, gyro_aided: bool = False) -> dict[str, Any]:
    """Single-call timings (µs) of push, everything included, and the evaluations per 10 000 samples;
    ``deferred``: the node's sample callback (the evaluation runs after each push, untimed, as its worker);
    ``gyro_aided``: the magnetometer gets the recording's rates too (the gyro-aided partial fit)."""
    cal = SensorCalibrator(sensor)
    cal.defer_evaluation = deferred
    val = cal.validator = _Counting(cal.validator)
    use = (sensor == "accel" or gyro_aided) and rec.gyro is not None
    gyro = rec.gyro.tolist() if use else [None] * len(rec)
    perf = time.perf_counter
    dt = []
    for t, v, w in zip(rec.t.tolist(), rec.raw.tolist(), gyro, strict=True):
        t0 = perf()
        cal.push(t, v, w)
        dt.append(perf() - t0)
        if cal.pending:
            cal.run_pending()
    us = np.array(dt) * 1e6
    per = 1e4 / len(rec)
    return {"mean": float(us.mean()), "p99": float(np.percentile(us, 99)), "max": float(us.max()), "validator": val.calls * per,
            "fits": (cal.fits_accepted + cal.fits_rejected) * per, "calibrated": cal.calibration is not None}


def _convert_mean_us(msgs: list[Any], kind: str) -> float:
    """Mean single-call time (µs) of the bare conversion of the messages: the all-in baseline."""
    conv = mag_to_numpy if kind == "mag" else imu_to_numpy
    perf = time.perf_counter
    dt = []
    for m in msgs:
        t0 = perf()
        conv(m)
        dt.append(perf() - t0)
    return float(np.mean(dt)) * 1e6


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
    if args.seed < 0:  # one line, as the CLI's (not numpy's traceback)
        parser.exit(2, f"{parser.prog}: error: --seed must be a non-negative integer, got {args.seed}\n")
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
    print(f"\nall-in cost per sample (validation and fits included; target mean <= {TARGET_MEAN_US:.0f} us; "
          "baseline = mean conversion of the same messages)")
    ground = ground_motion(duration, 100.0, rng)
    ground_mag = sim.magnetometer_stream(mag_truth, duration, 100.0, rng, motion=ground)
    streams = (("tumble", "mag", mag, False), ("tumble", "imu", imu, False), ("ground", "mag", ground_mag, False),
               ("ground", "mag+gyro", ground_mag, True),
               ("ground", "imu", sim.tumbling(acc_truth, duration, 100.0, rng, motion=ground), False))
    for motion, kind, rec, aided in streams:
        kind_msg = "mag" if kind.startswith("mag") else "imu"
        base = _convert_mean_us(_messages(classes, rec, kind_msg), kind_msg)
        r = _all_in(rec, "mag" if kind_msg == "mag" else "accel", gyro_aided=aided)
        d = _all_in(rec, "mag" if kind_msg == "mag" else "accel", deferred=True, gyro_aided=aided)
        print(f"  {motion:6s} {kind:4s} mean {r['mean']:7.1f} us ({r['mean'] / base:5.1f}x), p99 {r['p99']:8.1f} us "
              f"({r['p99'] / base:6.1f}x) | validator {r['validator']:5.1f}, fits {r['fits']:5.1f} per 10k samples | "
              f"calibrated: {r['calibrated']} | mean target: {'met' if r['mean'] <= TARGET_MEAN_US else 'MISSED'}")
        print(f"  {'':6s} {kind:4s} node callback (evaluation deferred to the worker): mean {d['mean']:7.1f} us "
              f"({d['mean'] / base:5.1f}x), p99 {d['p99']:8.1f} us ({d['p99'] / base:6.1f}x), max {d['max']:8.1f} us")
    print("\nreplay throughput (samples/s)")
    t_mag = _throughput(mag, "mag")
    t_imu = _throughput(imu, "accel")
    print(f"  pipeline only: mag {t_mag:10.0f}/s ({t_mag / 50.0:6.0f}x real time), "
          f"imu {t_imu:10.0f}/s ({t_imu / 100.0:6.0f}x real time)")
    t_bag, t_read = _bag_throughput(mag, imu)
    print(f"  margcal replay from .mcap: {t_bag:10.0f} msgs/s; reading the bag alone {t_read:10.0f} msgs/s "
          f"(replay = {t_bag / t_read:.2f}x of the read rate)")
    return 0 if ok else 1
