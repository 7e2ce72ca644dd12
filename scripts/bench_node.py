#!/usr/bin/env python3
"""Node benchmark for a ROS 2 Jazzy machine: the margcal node under a 1 kHz IMU and a 100 Hz magnetometer.

    source /opt/ros/jazzy/setup.bash
    python3 scripts/bench_node.py [--seconds 60] [--imu-rate 1000] [--mag-rate 100]

The node runs in this process (``MargCalNode`` on the ``MultiThreadedExecutor`` of ``margcal_node``,
its callbacks timed); ANOTHER process (this script with ``--publisher``) publishes simulated tumbling
``sensor_msgs/Imu`` on ``imu/data_raw`` and ``sensor_msgs/MagneticField`` on ``imu/mag`` (reliable,
as REP-2003 asks of drivers; header stamps from its clock) for ``--seconds``. Printed: the node's CPU
share (CPU time of this process over wall time while the data flows, in % of one core), the longest
and the 99th-percentile time of each callback (samples, the evaluation worker, the status), the
messages lost (sent by the publisher, not received by the node's subscriptions: best effort,
depth 5) and the final state of each sensor.

Without rclpy (no sourced ROS 2) it says why and exits 0.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np

try:  # rclpy and the message packages exist only in a sourced ROS 2 environment
    import rclpy
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import Quaternion, Vector3
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Imu, MagneticField
    from std_msgs.msg import Header

    from ros_margcal.ros.node import MargCalNode
except ImportError as exc:
    rclpy = None
    MISSING = f"{exc}"
else:
    MISSING = ""

from ros_margcal.sim import simulation as sim


def _stamp(ns: int) -> Any:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def publisher(seconds: float, imu_rate: float, mag_rate: float) -> int:
    """The other process: publish the simulated streams in real time; print the counts sent as JSON."""
    rng = np.random.default_rng(3)
    imu = sim.tumbling(sim.random_sensor(rng, "accel"), seconds, imu_rate, rng)
    mag = sim.magnetometer_stream(sim.random_sensor(rng, "mag"), seconds, mag_rate, rng, motion="tumble")
    rclpy.init()
    node = Node("margcal_bench_publisher")
    pub_imu = node.create_publisher(Imu, "imu/data_raw", 100)
    pub_mag = node.create_publisher(MagneticField, "imu/mag", 100)
    end = time.monotonic() + 10.0
    while (pub_imu.get_subscription_count() == 0 or pub_mag.get_subscription_count() == 0) and time.monotonic() < end:
        time.sleep(0.05)
    zero9 = np.zeros(9)
    events = sorted([(float(t), 0, i) for i, t in enumerate(imu.t)] + [(float(t), 1, i) for i, t in enumerate(mag.t)])
    sent = [0, 0]
    start = time.monotonic()
    for t, kind, i in events:
        delay = start + t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        hdr = Header(stamp=_stamp(node.get_clock().now().nanoseconds), frame_id="imu_link")
        if kind == 0:
            a, g = imu.raw[i], imu.gyro[i]
            pub_imu.publish(Imu(header=hdr, orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                                orientation_covariance=np.r_[-1.0, np.zeros(8)], angular_velocity_covariance=zero9,
                                angular_velocity=Vector3(x=float(g[0]), y=float(g[1]), z=float(g[2])),
                                linear_acceleration=Vector3(x=float(a[0]), y=float(a[1]), z=float(a[2])),
                                linear_acceleration_covariance=zero9))
        else:
            m = mag.raw[i]
            pub_mag.publish(MagneticField(header=hdr, magnetic_field=Vector3(x=float(m[0]), y=float(m[1]), z=float(m[2])),
                                          magnetic_field_covariance=zero9))
        sent[kind] += 1
    late = time.monotonic() - start - events[-1][0]
    print(json.dumps({"imu": sent[0], "mag": sent[1], "late_s": late}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


class TimedNode(MargCalNode if rclpy is not None else object):  # type: ignore[misc]
    """The node with every callback timed and the messages received counted."""

    def __init__(self, **kwargs: Any) -> None:
        self.times: dict[str, list[float]] = {"imu": [], "mag": [], "evaluation": [], "status": []}
        self._times_lock = threading.Lock()
        super().__init__(**kwargs)

    def _timed(self, name: str, fn: Any, *args: Any) -> None:
        t0 = time.perf_counter()
        fn(*args)
        dt = time.perf_counter() - t0
        with self._times_lock:
            self.times[name].append(dt)

    def _on_imu(self, msg: Any) -> None:
        self._timed("imu", super()._on_imu, msg)

    def _on_mag(self, msg: Any) -> None:
        self._timed("mag", super()._on_mag, msg)

    def _run_pending(self) -> None:
        self._timed("evaluation", super()._run_pending)

    def _publish_status(self) -> None:
        self._timed("status", super()._publish_status)


def bench(seconds: float, imu_rate: float, mag_rate: float) -> int:
    """Run the node here and the publisher in another process; print the figures."""
    rclpy.init()
    node = TimedNode(parameter_overrides=[Parameter("calibration_file", value="")])
    executor = MultiThreadedExecutor(num_threads=4)  # as margcal_node: a thread per callback group
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    cmd = [sys.executable, __file__, "--publisher", "--seconds", str(seconds), "--imu-rate", str(imu_rate),
           "--mag-rate", str(mag_rate)]
    print(f"node benchmark: {seconds:.0f} s of IMU at {imu_rate:.0f} Hz and magnetometer at {mag_rate:.0f} Hz "
          "from another process")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    while not node.times["imu"] and proc.poll() is None:  # start the clock at the first message
        time.sleep(0.001)
    wall0, cpu0 = time.monotonic(), time.process_time()
    out, _ = proc.communicate(timeout=seconds + 120.0)
    wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
    time.sleep(1.0)  # messages in flight
    executor.shutdown()
    spinner.join(timeout=10.0)
    if proc.returncode != 0 or not out.strip():
        print(f"the publisher failed (exit code {proc.returncode})")
        return 1
    sent = json.loads(out.strip().splitlines()[-1])
    with node._times_lock:
        times = {k: np.array(v) * 1e3 for k, v in node.times.items()}
    print(f"  node CPU share: {100 * cpu / wall:5.1f} % of one core over {wall:.1f} s "
          f"(publisher {sent['late_s'] * 1e3:.0f} ms late at the end)")
    for name, ms in times.items():
        if len(ms):
            print(f"  callback {name:10s}: {len(ms):7d} calls, longest {ms.max():8.2f} ms, p99 {np.percentile(ms, 99):7.3f} ms, "
                  f"mean {ms.mean():7.3f} ms")
    for kind in ("imu", "mag"):
        got = len(times[kind])
        print(f"  {kind}: sent {sent[kind]}, received {got}, lost {sent[kind] - got} "
              f"({100 * (sent[kind] - got) / max(sent[kind], 1):.2f} %)")
    for s, c in node.calibrators.items():
        st = c.status()
        print(f"  {s}: {st.state.value} [{st.level.name}] {st.message}")
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point: the benchmark, or (``--publisher``) the publishing process."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0, help="how long the publisher publishes (default 60)")
    ap.add_argument("--imu-rate", type=float, default=1000.0, help="IMU rate, Hz (default 1000)")
    ap.add_argument("--mag-rate", type=float, default=100.0, help="magnetometer rate, Hz (default 100)")
    ap.add_argument("--publisher", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if rclpy is None:
        print(f"bench_node: skipped: rclpy is not importable ({MISSING}); source a ROS 2 Jazzy setup "
              "(source /opt/ros/jazzy/setup.bash) and build or install ros_margcal there")
        return 0
    if args.publisher:
        return publisher(args.seconds, args.imu_rate, args.mag_rate)
    return bench(args.seconds, args.imu_rate, args.mag_rate)


if __name__ == "__main__":
    sys.exit(main())
