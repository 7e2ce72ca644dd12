"""``margcal_node`` as users run it (its own process), fed at real rates by a driver in another process:
every message is counted by the node and reaches its calibrators; the status says the rate received."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from msgdata import import_rclpy

rclpy = import_rclpy()

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402

HERE = Path(__file__).resolve().parent


@pytest.fixture
def node_process(tmp_path: Path) -> Iterator[subprocess.Popen[str]]:
    """``python -m ros_margcal.ros.node`` with persistence off and a 0.25 s status."""
    log = (tmp_path / "node.log").open("w")
    proc = subprocess.Popen([sys.executable, "-m", "ros_margcal.ros.node", "--ros-args", "-p", "calibration_file:=''",
                             "-p", "status_period_s:=0.25"], stdout=log, stderr=subprocess.STDOUT, text=True)
    try:
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


class StatusListener:
    """Keeps the latest key/values of each sensor from /calib/status."""

    def __init__(self) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node("margcal_test_listener", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.last: dict[str, dict[str, str]] = {}
        self.node.create_subscription(DiagnosticArray, "/calib/status", self._on_status, 10)

    def _on_status(self, msg: Any) -> None:
        for st in msg.status:
            self.last[st.name.removeprefix("margcal: ")] = {kv.key: kv.value for kv in st.values}

    def spin_until(self, cond: Any, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if cond():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return cond()

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


@pytest.mark.parametrize(("imu_hz", "mag_hz", "burst"), [(400.0, 100.0, 1), (200.0, 200.0, 10)])
def test_nothing_is_lost_from_a_driver_in_another_process(node_process: subprocess.Popen[str], imu_hz: float,
                                                          mag_hz: float, burst: int) -> None:
    """6 s at 400 Hz IMU + 100 Hz magnetometer, and 200 + 200 Hz in bursts of 10 every 50 ms (a serial
    driver): the node receives every message and its calibrators take every one; rate_hz shows the rate."""
    listener = StatusListener()
    try:
        assert listener.spin_until(lambda: {"mag", "accel"} <= set(listener.last), 20.0), "no /calib/status from the node"
        driver = subprocess.run([sys.executable, str(HERE / "rate_publisher.py"), "6", str(imu_hz), str(mag_hz), str(burst)],
                                capture_output=True, text=True, timeout=60, cwd=HERE, check=False)
        assert driver.returncode == 0, driver.stderr[-2000:]
        sent = json.loads(driver.stdout.strip().splitlines()[-1])
        topic = {"accel": "imu", "mag": "mag"}
        # the node counts what it received at once; its worker takes the samples a moment later
        done = lambda: all(int(listener.last[s]["samples_seen"]) >= sent[topic[s]] for s in topic)  # noqa: E731
        listener.spin_until(done, 10.0)
        for s, name in topic.items():
            kv = listener.last[s]
            assert int(kv["received"]) == sent[name], f"{s}: {kv['received']} of {sent[name]} received"
            assert int(kv["samples_seen"]) == sent[name], f"{s}: the calibrator took {kv['samples_seen']} of {sent[name]}"
        assert listener.last["mag"]["imu_frame_id"] == "imu_link"  # the frame the mounting is found against
        assert node_process.poll() is None, "the node ended"
    finally:
        listener.close()


def test_status_says_the_rate_received(node_process: subprocess.Popen[str]) -> None:
    """While a 100 Hz magnetometer streams, rate_hz (averaged over the last 5 s) is about 100."""
    listener = StatusListener()
    try:
        assert listener.spin_until(lambda: "mag" in listener.last, 20.0)
        driver = subprocess.Popen([sys.executable, str(HERE / "rate_publisher.py"), "8", "100", "100"], cwd=HERE,
                                  stdout=subprocess.PIPE, text=True)
        try:
            listener.spin_until(lambda: int(listener.last["mag"]["received"]) > 650, 30.0)
            rate = float(listener.last["mag"]["rate_hz"])
            assert 80.0 < rate < 120.0, rate
        finally:
            driver.communicate(timeout=30)
    finally:
        listener.close()


def test_margcal_watch_shows_the_running_node(node_process: subprocess.Popen[str]) -> None:
    """``margcal watch --once``, in a process of its own as a user runs it, prints one block per sensor of the
    running node (state, samples, rate) and exits 0."""
    code = "import sys; from ros_margcal.cli import main; sys.exit(main(sys.argv[1:]))"
    done = subprocess.run([sys.executable, "-c", code, "watch", "--once", "--timeout", "30"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("margcal watch /calib/status")
    blocks = {line.split()[0]: line for line in lines[1:] if not line.startswith(" ")}
    assert set(blocks) == {"mag", "accel"} and all("collecting" in b for b in blocks.values()), lines
    assert any("samples 0 (received 0" in line for line in lines), lines


def test_margcal_watch_without_a_node_says_so() -> None:
    """No status on the topic within ``--timeout``: exit 1 and a line asking whether the node runs."""
    code = "import sys; from ros_margcal.cli import main; sys.exit(main(sys.argv[1:]))"
    done = subprocess.run([sys.executable, "-c", code, "watch", "--once", "--timeout", "2", "--topic", "/calib/nobody"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1 and "no status on /calib/nobody" in done.stderr, (done.returncode, done.stderr)
