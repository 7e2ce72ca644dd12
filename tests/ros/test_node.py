"""The rclpy node end to end: in-process publishers, an executor, topics, services, persistence.

Needs a sourced ROS 2 Jazzy (rclpy, sensor_msgs, diagnostic_msgs, std_srvs); skipped elsewhere.
Messages are built with ``tests/msgdata.py`` from the same simulated arrays the rosbags-based tests
use, and the node's calibration is compared with the pure pipeline run over the same samples. The
calibrated stream is received by a default-QoS (reliable) and a sensor-data (best-effort) subscriber
(REP-2003). The harness spins a single-threaded executor (deterministic); one test spins the
``MultiThreadedExecutor`` of ``main``, where the evaluation worker runs beside the sample callbacks.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy not importable: node tests need a sourced ROS 2 Jazzy environment")

from msgdata import MessageClasses, mag_msg, mag_stream, rclpy_classes  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import Executor, MultiThreadedExecutor, SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from ros_margcal.model.calibration import Calibration  # noqa: E402
from ros_margcal.model.calibration_file import save_calibrations  # noqa: E402
from ros_margcal.ros.messages import calibration_from_string, mag_to_numpy  # noqa: E402
from ros_margcal.ros.node import MargCalNode  # noqa: E402
from ros_margcal.sim import simulation as sim  # noqa: E402
from ros_margcal.stream.calibrator import SensorCalibrator  # noqa: E402

RELIABLE = QoSProfile(depth=200, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture
def context() -> Iterator[Context]:
    """A Context of our own, initialised and shut down around each test."""
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        ctx.try_shutdown()


@pytest.fixture(scope="module")
def classes() -> MessageClasses:
    """The rclpy message classes."""
    return rclpy_classes()


@pytest.fixture(scope="module")
def stream() -> sim.Recording:
    """A tumbling magnetometer, 60 s at 50 Hz, in tesla."""
    truth = sim.random_sensor(np.random.default_rng(11), "mag")
    return sim.magnetometer_stream(truth, 60.0, 50.0, np.random.default_rng(12), motion="tumble")


class Harness:
    """The node under test plus a peer node that publishes raw data and records the outputs."""

    def __init__(self, context: Context, c: MessageClasses, cal_file: Path, executor: type[Executor] = SingleThreadedExecutor,
                 **params: Any) -> None:
        overrides = [Parameter("calibration_file", value=str(cal_file)), Parameter("status_period_s", value=0.1),
                     Parameter("accel.enabled", value=False)]
        overrides += [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
        self.c = c
        self.node = MargCalNode(context=context, parameter_overrides=overrides)
        self.peer = Node("margcal_test_peer", context=context)
        self.executor = executor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.status: list[Any] = []
        self.calibrations: list[Any] = []
        self.calibrated: list[Any] = []
        self.calibrated_best_effort: list[Any] = []
        self.pub_mag = self.peer.create_publisher(c.MagneticField, "imu/mag", RELIABLE)
        self.peer.create_subscription(c.DiagnosticArray, "/calib/status", self.status.append, 10)
        self.peer.create_subscription(c.String, "/calib/mag", self.calibrations.append, LATCHED)
        self.peer.create_subscription(c.MagneticField, "imu_calibrated/mag", self.calibrated.append, RELIABLE)
        self.peer.create_subscription(c.MagneticField, "imu_calibrated/mag", self.calibrated_best_effort.append,
                                      qos_profile_sensor_data)
        self.default_qos: list[Any] = []  # depth only: the system default profile (reliable, volatile)
        self.peer.create_subscription(c.MagneticField, "imu_calibrated/mag", self.default_qos.append, 10)
        self.spin_until(lambda: self.pub_mag.get_subscription_count() > 0, 5.0)

    def spin_until(self, cond: Callable[[], bool], timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if cond():
                return True
            self.executor.spin_once(timeout_sec=0.01)
        return cond()

    def publish(self, rec: sim.Recording, stamp: float | None = None) -> None:
        """Publish the recording (every header stamped ``stamp`` when given) and spin."""
        msgs = mag_stream(self.c, rec.t, rec.raw) if stamp is None else (mag_msg(self.c, stamp, v) for v in rec.raw)
        for msg in msgs:
            self.pub_mag.publish(msg)
            self.executor.spin_once(timeout_sec=0.001)
        self.spin_until(lambda: False, 0.5)

    def call(self, name: str) -> Any:
        client = self.peer.create_client(Trigger, f"/margcal/{name}")
        assert client.wait_for_service(timeout_sec=5.0), f"service /margcal/{name} not available"
        future = client.call_async(Trigger.Request())
        self.executor.spin_until_future_complete(future, timeout_sec=10.0)
        assert future.done(), f"/margcal/{name} did not answer"
        return future.result()

    def last_status(self, sensor: str = "mag") -> Any:
        assert self.spin_until(lambda: bool(self.status), 3.0), "no /calib/status received"
        return next(s for s in self.status[-1].status if s.name == f"margcal: {sensor}")

    def close(self) -> None:
        self.executor.shutdown()
        self.peer.destroy_node()
        self.node.destroy_node()


@pytest.fixture
def harness(context: Context, classes: MessageClasses, tmp_path: Path) -> Iterator[Harness]:
    """A running node with persistence in a temporary folder."""
    h = Harness(context, classes, tmp_path / "cal.yaml")
    try:
        yield h
    finally:
        h.close()


def test_status_calibration_topic_and_calibrated_stream(harness: Harness, stream: sim.Recording) -> None:
    """A tumbling stream ends calibrated: status OK, calibration on /calib/mag, calibrated messages."""
    first = harness.last_status()
    assert first.level in (bytes([1]), bytes([3]))  # WARN collecting / STALE before samples
    harness.publish(stream)
    assert harness.spin_until(lambda: bool(harness.calibrations), 5.0), "no calibration published"
    cal = calibration_from_string(harness.calibrations[-1], sensor="mag")
    truth = stream.truth
    assert np.linalg.norm(cal.offset - truth.offset) < 0.02 * truth.norm
    # the pure pipeline over the same samples agrees
    ref = SensorCalibrator("mag")
    for t, v in zip(stream.t.tolist(), stream.raw, strict=True):
        ref.push(t, v)
    assert ref.calibration is not None
    assert np.linalg.norm(cal.offset - ref.calibration.offset) < 0.005 * truth.norm
    harness.spin_until(lambda: False, 0.3)
    st = harness.last_status()
    assert st.level == bytes([0]) and st.message.startswith("calibrated")
    kv = {x.key: x.value for x in st.values}
    assert kv["state"] == "calibrated" and int(kv["samples_seen"]) > 0.9 * len(stream)
    # calibrated messages: same stamps and frame, norm close to the field; reliable output reaches
    # reliable, default-QoS and sensor-data (best-effort) subscribers alike
    assert harness.calibrated and harness.default_qos and harness.calibrated_best_effort
    for received in (harness.default_qos, harness.calibrated_best_effort):
        assert abs(np.linalg.norm(mag_to_numpy(received[-1])[1]) - cal.norm) < 0.05 * cal.norm
    out = harness.calibrated[-1]
    t_out, h = mag_to_numpy(out)
    assert out.header.frame_id == "imu_link"
    assert np.any(np.isclose(stream.t, t_out, atol=1e-6))
    assert abs(np.linalg.norm(h) - cal.norm) < 0.05 * cal.norm


def test_late_joiner_gets_the_calibration_and_file_is_written(harness: Harness, stream: sim.Recording, tmp_path: Path) -> None:
    """Transient-local: a subscriber created after the fact still receives it; autosave wrote the file."""
    harness.publish(stream)
    late: list[Any] = []
    harness.peer.create_subscription(harness.c.String, "/calib/mag", late.append, LATCHED)
    assert harness.spin_until(lambda: bool(late), 5.0)
    assert calibration_from_string(late[-1], sensor="mag").sensor == "mag"
    assert (tmp_path / "cal.yaml").exists()


def test_services_refit_save_reset(harness: Harness, stream: sim.Recording, tmp_path: Path) -> None:
    """refit answers with the validator's reason before data; save and reset do what they say."""
    res = harness.call("refit")
    assert not res.success and "need" in res.message
    res = harness.call("save")
    assert not res.success and "nothing to save" in res.message
    harness.publish(stream)
    res = harness.call("save")
    assert res.success and str(tmp_path / "cal.yaml") in res.message
    res = harness.call("reset")
    assert res.success
    harness.status.clear()
    harness.spin_until(lambda: len(harness.status) > 1, 3.0)
    kv = {x.key: x.value for x in harness.last_status().values}
    assert kv["state"] == "collecting" and kv["samples_seen"] == "0"


def test_persistence_across_restart(context: Context, classes: MessageClasses, stream: sim.Recording, tmp_path: Path) -> None:
    """A saved calibration is loaded by a new node and published at once."""
    path = tmp_path / "cal.yaml"
    h = Harness(context, classes, path)
    try:
        h.publish(stream)
        assert h.call("save").success
        saved = calibration_from_string(h.calibrations[-1], sensor="mag")
    finally:
        h.close()
    h2 = Harness(context, classes, path)
    try:
        assert h2.spin_until(lambda: bool(h2.calibrations), 5.0)
        assert calibration_from_string(h2.calibrations[-1], sensor="mag").allclose(saved, rtol=1e-9)
        kv = {x.key: x.value for x in h2.last_status().values}
        assert kv["state"] == "calibrated"
    finally:
        h2.close()


def test_corrupt_file_starts_uncalibrated(context: Context, classes: MessageClasses, tmp_path: Path) -> None:
    """A newer-format file is refused; the node runs, uncalibrated, and publishes no calibration."""
    path = tmp_path / "cal.yaml"
    save_calibrations(path, {"mag": Calibration.identity(50e-6, sensor="mag")})
    path.write_text(path.read_text().replace("format_version: 2", "format_version: 99"))
    h = Harness(context, classes, path)
    try:
        h.spin_until(lambda: False, 0.5)
        assert not h.calibrations
        kv = {x.key: x.value for x in h.last_status().values}
        assert kv["state"] == "collecting"
    finally:
        h.close()


def test_parameters_are_checked(harness: Harness) -> None:
    """Descriptor ranges, strict types and whole-config consistency are enforced on set."""
    node = harness.node
    assert node.set_parameters([Parameter("mag.max_residual", value=0.02)])[0].successful
    assert node.calibrators["mag"].config.max_residual == 0.02
    assert not node.set_parameters([Parameter("mag.max_residual", value=5.0)])[0].successful  # out of range
    assert not node.set_parameters([Parameter("mag.norm_min", value=9.0e-5)])[0].successful  # > norm_max
    # strict types: an integer for a double parameter is refused ("Wrong parameter type, expected 'Type.DOUBLE'")
    assert not node.set_parameters([Parameter("mag.max_residual", value=1)])[0].successful
    assert node.calibrators["mag"].config.max_residual == 0.02


def test_sensors_can_be_switched_off(harness: Harness) -> None:
    """accel.enabled = false: no Imu subscription, no accel status."""
    assert harness.node.count_subscribers("imu/data_raw") == 0
    assert harness.node.count_subscribers("imu/mag") >= 1
    harness.last_status()
    assert [s.name for s in harness.status[-1].status] == ["margcal: mag"]


def test_validator_file_is_used_and_a_bad_one_refused(context: Context, classes: MessageClasses, tmp_path: Path) -> None:
    """validator_file loads a trained model; a corrupt one is refused and the shipped model used."""
    from ros_margcal.validation.fuzzy import FuzzyValidator
    from ros_margcal.validation.shipped import load_default_validator

    rng = np.random.default_rng(3)
    x = rng.uniform(size=(200, 1))
    own = FuzzyValidator(["d_norm"], 4).fit(x, 10 ** (-1 - 2 * x[:, 0]), repeats=2)
    good, bad = tmp_path / "own.json", tmp_path / "bad.json"
    own.save(good)
    bad.write_text("{not json")
    h = Harness(context, classes, tmp_path / "cal.yaml", validator_file=str(good))
    try:
        assert h.node.calibrators["mag"].validator.inputs == ("d_norm",)
    finally:
        h.close()
    h = Harness(context, classes, tmp_path / "cal.yaml", validator_file=str(bad))
    try:
        assert h.node.calibrators["mag"].validator.inputs == load_default_validator().inputs
    finally:
        h.close()


def test_a_refused_parameter_leaves_the_calibration_alone(harness: Harness, stream: sim.Recording) -> None:
    """A value PipelineConfig.checked() refuses is refused with its reason; calibration and options stay."""
    harness.publish(stream)
    cal = harness.node.calibrators["mag"]
    assert harness.spin_until(lambda: cal.calibration is not None, 5.0)
    before, config = cal.calibration, cal.config
    res = harness.node.set_parameters([Parameter("mag.norm_min", value=9.0e-5)])[0]
    assert not res.successful and "norm_min" in res.reason
    assert cal.calibration is before and cal.config is config
    assert harness.node.get_parameter("mag.norm_min").value == pytest.approx(config.norm_min)
    harness.spin_until(lambda: False, 0.3)
    kv = {x.key: x.value for x in harness.last_status().values}
    assert kv["state"] == "calibrated"


@pytest.mark.parametrize(("mode", "kept"), [("auto", True), ("receive", True), ("header", False)])
def test_stamp_source_with_a_constant_header_stamp(context: Context, classes: MessageClasses, stream: sim.Recording,
                                                   tmp_path: Path, mode: str, kept: bool) -> None:
    """A driver stamping every message alike: auto and receive use the receive time, header drops them all."""
    h = Harness(context, classes, tmp_path / "cal.yaml", stamp_source=mode)
    try:
        n = 300
        h.publish(_head(stream, n), stamp=0.0 if mode == "auto" else 5.0)
        cal = h.node.calibrators["mag"]
        assert cal.seen >= 0.9 * n
        if kept:  # (receive times closer than 1/max_rate_hz may still be dropped as bursts)
            assert cal.dropped["repeated_stamp"] == 0 and cal.dropped["backwards_stamp"] == 0 and cal.passed > 0
        else:
            assert cal.dropped["repeated_stamp"] == cal.seen - 1
    finally:
        h.close()


def _head(rec: sim.Recording, n: int) -> sim.Recording:
    """The first ``n`` samples of a recording (times and raw values are all the harness uses)."""
    return sim.Recording(t=rec.t[:n], raw=rec.raw[:n])


def test_multithreaded_executor_calibrates(context: Context, classes: MessageClasses, stream: sim.Recording,
                                           tmp_path: Path) -> None:
    """main's executor: sample callbacks and the evaluation worker on threads of their own; the calibration arrives."""
    h = Harness(context, classes, tmp_path / "cal.yaml", executor=MultiThreadedExecutor)
    try:
        h.publish(stream)
        assert h.spin_until(lambda: bool(h.calibrations), 5.0), "no calibration published"
        assert h.node.calibrators["mag"].calibration is not None
        assert not h.node.calibrators["mag"].pending or h.spin_until(lambda: not h.node.calibrators["mag"].pending, 2.0)
    finally:
        h.close()


def test_each_mag_message_takes_the_latest_imu_rate_of_its_frame(context: Context, classes: MessageClasses,
                                                                 tmp_path: Path) -> None:
    """gyro_aided: a MagneticField message gets the angular rate of the latest Imu message when the stamps are
    within 20 ms and the frame_ids match (the rate must be in the magnetometer's frame); else none."""
    from msgdata import imu_msg

    node = MargCalNode(context=context, parameter_overrides=[Parameter("calibration_file", value=str(tmp_path / "c.yaml"))])
    peer = Node("margcal_test_rates", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(peer)
    try:
        pub_imu = peer.create_publisher(classes.Imu, "imu/data_raw", RELIABLE)
        pub_mag = peer.create_publisher(classes.MagneticField, "imu/mag", RELIABLE)
        end = time.monotonic() + 5.0
        while time.monotonic() < end and (pub_imu.get_subscription_count() == 0 or pub_mag.get_subscription_count() == 0):
            executor.spin_once(timeout_sec=0.01)
        for k, frame in enumerate(["imu_link"] * 30 + ["mag_link"] * 10):
            t = 100.0 + 0.02 * k
            pub_imu.publish(imu_msg(classes, t, [0.0, 0.0, 9.81], [0.0, 0.0, 0.3]))
            executor.spin_once(timeout_sec=0.05)
            pub_mag.publish(mag_msg(classes, t + 0.005, [20e-6, 1e-6 * k, 40e-6], frame_id=frame))
            executor.spin_once(timeout_sec=0.05)
        end = time.monotonic() + 2.0
        while time.monotonic() < end and node._cals["mag"].seen < 40:
            executor.spin_once(timeout_sec=0.01)
        rows = list(node._cals["mag"]._gyro_buf)
        assert len(rows) == 40, "every magnetometer sample after the first rate is kept (a gap without one)"
        rates = np.array([r[4:] for r in rows])
        assert np.allclose(rates[:30], [0.0, 0.0, 0.3]) and np.isnan(rates[30:]).all()
    finally:
        executor.shutdown()
        peer.destroy_node()
        node.destroy_node()
