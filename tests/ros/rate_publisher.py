"""A driver in a process of its own for the node tests: simulated Imu (with gyro) and MagneticField at real rates.

    python rate_publisher.py SECONDS IMU_HZ MAG_HZ [BURST]

Waits until the node subscribes, publishes in real time (header stamps from the clock; reliable, depth 100, as
REP-2003 asks of drivers; ``BURST`` > 1 sends that many messages at once, as serial drivers do) and prints the
counts sent as JSON; its writers stay a second after the last message, as a running driver's would.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import rclpy
from msgdata import imu_msg, mag_msg, rclpy_classes
from rclpy.node import Node

from ros_margcal.sim import simulation as sim


def main(seconds: float, imu_hz: float, mag_hz: float, burst: int = 1) -> None:
    rng = np.random.default_rng(5)
    imu = sim.tumbling(sim.random_sensor(rng, "accel"), seconds, imu_hz, rng)
    mag = sim.magnetometer_stream(sim.random_sensor(rng, "mag"), seconds, mag_hz, rng, motion="tumble")
    c = rclpy_classes()
    rclpy.init()
    node = Node("margcal_test_driver")
    pub_imu = node.create_publisher(c.Imu, "imu/data_raw", 100)
    pub_mag = node.create_publisher(c.MagneticField, "imu/mag", 100)
    end = time.monotonic() + 20.0
    while (pub_imu.get_subscription_count() == 0 or pub_mag.get_subscription_count() == 0) and time.monotonic() < end:
        time.sleep(0.05)
    time.sleep(0.5)  # discovery completes both ways
    events = sorted([(float(t), 0, i) for i, t in enumerate(imu.t)] + [(float(t), 1, i) for i, t in enumerate(mag.t)])
    sent = [0, 0]
    start, t0 = time.monotonic(), node.get_clock().now().nanoseconds * 1e-9
    for k, (t, kind, i) in enumerate(events):
        if k % burst == 0:
            delay = start + events[min(k + burst - 1, len(events) - 1)][0] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        if kind == 0:
            pub_imu.publish(imu_msg(c, t0 + t, imu.raw[i], imu.gyro[i]))
        else:
            pub_mag.publish(mag_msg(c, t0 + t, mag.raw[i]))
        sent[kind] += 1
    print(json.dumps({"imu": sent[0], "mag": sent[1], "late_s": time.monotonic() - start - events[-1][0]}), flush=True)
    # a best-effort writer destroyed at once drops what is still in transit (the last burst, 1 run in 6 here):
    # a driver that keeps running does not, so the writer stays until the node has read it
    time.sleep(1.0)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main(float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4]) if len(sys.argv) > 4 else 1)
