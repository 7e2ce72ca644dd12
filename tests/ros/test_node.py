"""The rclpy node end to end: in-process publishers, an executor, topics, services, persistence.

Needs a sourced ROS 2 Jazzy (rclpy, sensor_msgs, diagnostic_msgs, std_srvs); skipped elsewhere.
Messages are built with ``tests/msgdata.py`` from the same simulated arrays the rosbags-based tests
use, and the node's calibration is compared with the pure pipeline run over the same samples. The
calibrated stream is received by a default-QoS (reliable) and a sensor-data (best-effort) subscriber
(REP-2003). The harness spins a ``SingleThreadedExecutor``, as ``main`` does; the calibrators run in the
node's worker process. ``test_node_process.py`` runs ``margcal_node`` as users do, fed from another process.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from msgdata import MessageClasses, import_rclpy, mag_msg, mag_stream, rclpy_classes

rclpy = import_rclpy()

from rclpy.context import Context  # noqa: E402
from rclpy.executors import Executor, SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from ros_margcal.model.calibration import FORCED, Calibration  # noqa: E402
from ros_margcal.model.calibration_file import save_calibrations  # noqa: E402
from ros_margcal.ros.markers import STATE_COLOURS, rotation_quaternion  # noqa: E402
from ros_margcal.ros.messages import calibration_from_string, mag_to_numpy  # noqa: E402
from ros_margcal.ros.node import MargCalNode  # noqa: E402
from ros_margcal.ros.stamps import FALLBACK_BAD  # noqa: E402
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
    """A tumbling magnetometer, 60 s at 50 Hz, in tesla, stamped from t = 1000 s (a driver's clock: a zero
    stamp is an unset one, and ``stamp_source: auto`` rightly falls back to the receive time on it)."""
    truth = sim.random_sensor(np.random.default_rng(11), "mag")
    rec = sim.magnetometer_stream(truth, 60.0, 50.0, np.random.default_rng(12), motion="tumble")
    return replace(rec, t=rec.t + 1000.0)


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
        """Publish the recording (every header stamped ``stamp`` when given), spinning until the node took each
        message: one executor serves the node and the peer's four subscribers, so each message needs several
        callbacks before the next one (a publisher in another process needs none of this: test_node_process)."""
        self.send(mag_stream(self.c, rec.t, rec.raw) if stamp is None else (mag_msg(self.c, stamp, v) for v in rec.raw))

    def send(self, msgs: Any) -> None:
        """Publish MagneticField messages one by one, each once the node took the one before (see ``publish``)."""
        start = self.node.received["mag"]
        for k, msg in enumerate(msgs, start=1):
            self.pub_mag.publish(msg)
            assert self.spin_until(lambda k=k: self.node.received["mag"] >= start + k, 2.0), f"message {k} never arrived"
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
    assert harness.spin_until(lambda: harness.node.statuses["mag"].samples_seen == len(stream), 5.0)
    harness.spin_until(lambda: False, 0.3)
    cal = calibration_from_string(harness.calibrations[-1], sensor="mag")
    truth = stream.truth
    assert np.linalg.norm(cal.offset - truth.offset) < 0.02 * truth.norm
    # the pure pipeline over the same samples gives the same calibration: the worker runs replay's corridor
    ref = SensorCalibrator("mag")
    for t, v in zip(stream.t.tolist(), stream.raw, strict=True):
        ref.push(t, v)
    assert ref.calibration is not None
    assert cal.allclose(ref.calibration, rtol=1e-9)
    harness.spin_until(lambda: False, 0.3)
    st = harness.last_status()
    assert st.level == bytes([0]) and st.message.startswith("calibrated")
    kv = {x.key: x.value for x in st.values}
    # every message reached the calibrator: none lost in the node's queue, none left in the worker's
    assert kv["state"] == "calibrated" and int(kv["samples_seen"]) == int(kv["received"]) == len(stream)
    assert kv["worker_backlog"] == "0" and float(kv["callback_max_ms"]) > 0.0
    assert kv["imu_frame_id"] == "none seen"  # no Imu message: no rates, no mounting reference
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


def test_rviz_markers_show_the_buffer_and_the_fit(harness: Harness, stream: sim.Recording) -> None:
    """/calib/markers: before data no samples and no ellipsoid; once calibrated the buffered samples (one per
    POINTS point, about one field radius from the centre), the covered bins, the fitted ellipsoid as a rotated
    SPHERE in the sensor's frame, all in the state's colour."""
    arrays: list[Any] = []
    harness.peer.create_subscription(MarkerArray, "/calib/markers", arrays.append, 10)

    def mag_markers() -> dict[int, Any]:
        return {m.id: m for m in arrays[-1].markers if m.ns == "margcal/mag"}

    assert harness.spin_until(lambda: bool(arrays), 5.0), "no MarkerArray on /calib/markers"
    first = mag_markers()
    assert first[0].type == Marker.POINTS and not first[0].points and first[2].action == Marker.DELETE
    assert "collecting" in first[3].text
    harness.publish(stream)
    assert harness.spin_until(lambda: "calibrated" in mag_markers()[3].text, 5.0)
    m = mag_markers()
    assert all(x.header.frame_id == "imu_link" for x in m.values())
    pts = np.array([[p.x, p.y, p.z] for p in m[0].points])
    assert len(pts) > 100 and 0.9 < np.median(np.linalg.norm(pts, axis=1)) < 1.1
    colour = (m[0].color.r, m[0].color.g, m[0].color.b)
    assert np.allclose(colour, STATE_COLOURS["calibrated"])
    assert m[1].type == Marker.CUBE_LIST and 0 < len(m[1].points) <= harness.node.configs["mag"].n_bins
    sphere = m[2]
    assert sphere.type == Marker.SPHERE and sphere.action == Marker.ADD and sphere.color.a < 1.0
    assert all(1.4 < d < 2.6 for d in (sphere.scale.x, sphere.scale.y, sphere.scale.z))  # a diameter of about 2
    q = sphere.pose.orientation
    assert abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1.0) < 1e-9


def test_marker_quaternion_is_the_rotation() -> None:
    """``rotation_quaternion`` inverts the quaternion-to-matrix formula for rotations near every pivot."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        q = rng.normal(size=4)
        x, y, z, w = q / np.linalg.norm(q)
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        got, want = np.array(rotation_quaternion(r)), np.array([x, y, z, w])
        assert min(np.abs(got - want).max(), np.abs(got + want).max()) < 1e-9  # q and -q: one rotation


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
    assert node.configs["mag"].max_residual == 0.02
    assert not node.set_parameters([Parameter("mag.max_residual", value=5.0)])[0].successful  # out of range
    assert not node.set_parameters([Parameter("mag.norm_min", value=9.0e-5)])[0].successful  # > norm_max
    # strict types: an integer for a double parameter is refused ("Wrong parameter type, expected 'Type.DOUBLE'")
    assert not node.set_parameters([Parameter("mag.max_residual", value=1)])[0].successful
    assert node.configs["mag"].max_residual == 0.02
    # read at start only: refused rather than accepted and ignored
    assert not node.set_parameters([Parameter("mag.enabled", value=False)])[0].successful
    # a magnetometer mounted on its side: up_axis, one of the sensor's axes
    assert node.set_parameters([Parameter("mag.up_axis", value="-y")])[0].successful
    assert node.configs["mag"].up_axis == "-y"
    res = node.set_parameters([Parameter("mag.up_axis", value="w")])[0]
    assert not res.successful and "up_axis must be one of" in res.reason
    assert node.configs["mag"].up_axis == "-y"


def test_sensors_can_be_switched_off(harness: Harness) -> None:
    """accel.enabled = false: no accel status, no calibrated Imu (the Imu topic still brings the rates)."""
    assert "accel" not in harness.node.configs
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
    shipped = load_default_validator()
    assert own.threshold != shipped.threshold
    for path, threshold in ((good, own.threshold), (bad, shipped.threshold)):
        h = Harness(context, classes, tmp_path / "cal.yaml", validator_file=str(path))
        try:  # the worker's calibrator reports the threshold of the validator it uses
            assert h.spin_until(lambda h=h: h.node.statuses["mag"].error_threshold is not None, 10.0)
            assert h.node.statuses["mag"].error_threshold == pytest.approx(threshold)
        finally:
            h.close()


def test_a_refused_parameter_leaves_the_calibration_alone(harness: Harness, stream: sim.Recording) -> None:
    """A value PipelineConfig.checked() refuses is refused with its reason; calibration and options stay."""
    harness.publish(stream)
    node = harness.node
    assert harness.spin_until(lambda: node.calibrations["mag"] is not None, 5.0)
    before, config = node.calibrations["mag"], node.configs["mag"]
    res = harness.node.set_parameters([Parameter("mag.norm_min", value=9.0e-5)])[0]
    assert not res.successful and "norm_min" in res.reason
    assert node.calibrations["mag"] is before and node.configs["mag"] is config
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
        assert h.spin_until(lambda: h.node.statuses["mag"].samples_seen == n, 5.0), "a message was lost"
        st = h.node.statuses["mag"]
        if kept:  # (auto: the stamps before the third unusable one, stamps.FALLBACK_BAD; a publisher faster than
            # max_rate_hz beyond stamps.RECEIVE_CATCH_UP_S may still have receive times dropped as bursts)
            assert st.dropped.get("repeated_stamp", 0) <= (FALLBACK_BAD - 1 if mode == "auto" else 0)
            assert st.dropped.get("backwards_stamp", 0) == 0
            assert st.samples_passed > 0
        else:
            assert st.dropped["repeated_stamp"] == st.samples_seen - 1
    finally:
        h.close()


def _head(rec: sim.Recording, n: int) -> sim.Recording:
    """The first ``n`` samples of a recording (times and raw values are all the harness uses)."""
    return sim.Recording(t=rec.t[:n], raw=rec.raw[:n])


# -- hostile input (issue 26): nothing wrong is published or loaded ------------------------------------------------


def _calibrate(harness: Harness, stream: sim.Recording) -> Calibration:
    harness.publish(stream)
    assert harness.spin_until(lambda: harness.node.calibrations["mag"] is not None, 10.0)
    return harness.node.calibrations["mag"]


@pytest.mark.parametrize("case", ["uT", "accel", "norm", "offset", "gains"])
def test_a_calibration_file_that_does_not_fit_the_sensor_is_refused(context: Context, classes: MessageClasses,
                                                                   tmp_path: Path, case: str) -> None:
    """A file of another unit (a `margcal calibrate --unit uT` file would publish fields 1e6 too large), of the
    accelerometer under `mag`, with an implausible field norm, or beyond the offset or gain guard rails (a runaway
    batch fit): refused, the node starts uncalibrated."""
    path = tmp_path / "cal.yaml"
    cal = {"uT": Calibration.identity(50.0, sensor="mag", unit="uT"),
           "accel": Calibration.identity(9.81, sensor="accel", unit="m/s^2"),
           "norm": Calibration.identity(5e-3, sensor="mag", unit="T"),
           # a runaway batch fit (a car's ring): offset 67 field norms; gains 0.5-1.9 about a plausible norm
           "offset": Calibration(offset=np.array([3.3e-3, 0.0, 0.0]), matrix=np.eye(3), norm=50e-6, sensor="mag", unit="T"),
           "gains": Calibration(offset=np.zeros(3), matrix=np.diag([0.5, 1.1, 1.9]), norm=50e-6, sensor="mag", unit="T"),
           }[case]
    save_calibrations(path, {"mag": cal})
    h = Harness(context, classes, path)
    try:
        h.spin_until(lambda: False, 0.5)
        assert not h.calibrations and h.node.calibrations["mag"] is None
        assert h.spin_until(lambda: h.last_status().message.startswith("collecting") or "no samples" in h.last_status().message, 5.0)
    finally:
        h.close()


def test_a_forced_calibration_file_is_loaded(context: Context, classes: MessageClasses, tmp_path: Path) -> None:
    """A file `margcal calibrate --force` wrote past the guard rails (its method says so) is loaded as given."""
    path = tmp_path / "cal.yaml"
    cal = Calibration(offset=np.array([3.3e-3, 0.0, 0.0]), matrix=np.eye(3), norm=50e-6, sensor="mag", unit="T",
                      method=f"lm {FORCED}: offset 3.3e-3 T > limit")
    save_calibrations(path, {"mag": cal})
    h = Harness(context, classes, path)
    try:
        assert h.spin_until(lambda: bool(h.calibrations), 5.0)
        assert h.node.calibrations["mag"] is not None and h.node.calibrations["mag"].allclose(cal)
    finally:
        h.close()


def test_refused_samples_are_not_published(harness: Harness, stream: sim.Recording) -> None:
    """Once calibrated: a zero vector (a failed read), NaN, and a value beyond the intake's magnitude (gauss numbers
    sent as tesla) are not published calibrated; a good sample still is."""
    _calibrate(harness, stream)
    harness.spin_until(lambda: False, 0.3)
    before = len(harness.calibrated)
    t = float(stream.t[-1]) + 1.0
    bad = [[0.0, 0.0, 0.0], [float("nan"), 1e-5, 2e-5], [0.2, 0.3, 0.4]]
    harness.send(mag_msg(harness.c, t + 0.01 * k, v) for k, v in enumerate(bad))
    harness.spin_until(lambda: False, 0.3)
    assert len(harness.calibrated) == before
    harness.send([mag_msg(harness.c, t + 1.0, stream.raw[0])])
    assert harness.spin_until(lambda: len(harness.calibrated) == before + 1, 2.0)


def test_status_leaves_ok_while_samples_are_dropped(harness: Harness, stream: sim.Recording) -> None:
    """Calibrated, then 2 s of gauss numbers published as tesla: the status warns that samples are dropped and
    why; none of them is published."""
    _calibrate(harness, stream)
    harness.spin_until(lambda: harness.last_status().level == bytes([0]), 3.0)
    before = len(harness.calibrated)
    t = float(stream.t[-1]) + 1.0
    harness.send(mag_msg(harness.c, t + 0.01 * k, 1e4 * v) for k, v in enumerate(stream.raw[:200]))
    harness.status.clear()
    assert harness.spin_until(lambda: bool(harness.status) and "dropping" in harness.last_status().message, 5.0)
    st = harness.last_status()
    assert st.level == bytes([1]) and "magnitude" in st.message
    assert len(harness.calibrated) == before


def test_a_saturated_axis_is_dropped_named_and_the_rest_calibrated(harness: Harness, stream: sim.Recording) -> None:
    """The magnetometer's x axis clipped at 60 % of its reach (a range too small for the field plus hard iron): the
    node drops the pinned samples, its status names the axis and value, and the calibration is the sensor's."""
    raw = np.array(stream.raw, dtype=np.float64)
    lim = 0.6 * np.abs(raw[:, 0]).max()
    raw[:, 0] = np.clip(raw[:, 0], -lim, lim)
    assert np.mean(np.abs(raw[:, 0]) == lim) > 0.1
    harness.publish(replace(stream, raw=raw))
    assert harness.spin_until(lambda: harness.node.calibrations["mag"] is not None, 10.0)
    harness.status.clear()
    assert harness.spin_until(lambda: bool(harness.status) and "dropped as saturated" in harness.last_status().message,
                              5.0)
    assert "dropped as saturated: x at" in harness.last_status().message
    cal, truth = harness.node.calibrations["mag"], stream.truth
    assert np.linalg.norm(cal.offset - truth.offset) < 0.02 * truth.norm
    before = len(harness.calibrated)  # once calibrated: a pinned reading's calibrated value would be wrong
    t = float(stream.t[-1]) + 1.0
    harness.send(mag_msg(harness.c, t + 0.02 * k, v) for k, v in enumerate(raw[:500]))
    rails = [v for k, v in harness.node._rails["mag"].rails if k == 0]
    assert lim in rails or -lim in rails
    pinned = int(np.sum(np.isin(raw[:500, 0], rails)))
    assert pinned > 20
    assert harness.spin_until(lambda: len(harness.calibrated) >= before + 500 - pinned, 5.0)
    harness.spin_until(lambda: False, 0.5)
    got = np.array([[m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z] for m in harness.calibrated[before:]])
    assert len(got) == 500 - pinned
    assert np.allclose(np.linalg.norm(got, axis=1), cal.norm, rtol=0.03)


def test_a_second_frame_on_the_topic_is_ignored_and_flagged(harness: Harness, stream: sim.Recording) -> None:
    """Two magnetometers on imu/mag told apart by frame_id: the first frame is calibrated, the other is neither
    pooled nor published, and the status names it."""
    msgs = []
    for k, (t, v) in enumerate(zip(stream.t, stream.raw, strict=True)):
        msgs.append(mag_msg(harness.c, float(t), v, frame_id="imu_link"))
        if k % 2 == 0:  # another sensor's field: offset by 30 uT
            msgs.append(mag_msg(harness.c, float(t) + 0.005, v + 3e-5, frame_id="mag2_link"))
    harness.send(msgs)
    assert harness.spin_until(lambda: harness.node.calibrations["mag"] is not None, 10.0)
    cal, truth = harness.node.calibrations["mag"], stream.truth
    assert np.linalg.norm(cal.offset - truth.offset) < 0.02 * truth.norm  # not pulled toward the other sensor
    harness.status.clear()
    assert harness.spin_until(lambda: bool(harness.status) and "other frames" in harness.last_status().message, 5.0)
    kv = {x.key: x.value for x in harness.last_status().values}
    assert int(kv["ignored_other_frames"]) == (len(stream) + 1) // 2 and "mag2_link" in harness.last_status().message
    assert harness.calibrated and {m.header.frame_id for m in harness.calibrated} == {"imu_link"}


def test_a_frame_id_changing_on_every_message_keeps_the_status_small(harness: Harness, stream: sim.Recording) -> None:
    """Fuzzed on real rclpy: 1000 messages each of another frame_id (some 10 kB long) made every status 4.2 MB and
    grew the node by 50 MB. Now eight other frames are named (cut to 40 characters), the rest counted only."""
    harness.send(mag_msg(harness.c, 1000.0 + 0.02 * k, v, frame_id="imu_link") for k, v in enumerate(stream.raw[:20]))
    names = [f"frame_{k}_" + ("x" * 10_000 if k % 3 == 0 else "") for k in range(300)]
    harness.send(mag_msg(harness.c, 1001.0 + 0.02 * k, stream.raw[k], frame_id=f) for k, f in enumerate(names))
    harness.status.clear()
    assert harness.spin_until(lambda: bool(harness.status) and "other frames" in harness.last_status().message, 5.0)
    st = harness.last_status()
    kv = {x.key: x.value for x in st.values}
    assert int(kv["ignored_other_frames"]) == 300 and kv["worker_backlog"] == "0"
    assert len(st.message) < 2000 and "and 292 messages of further frames" in st.message, st.message[:300]
    assert len(harness.node._traffic["mag"].other_frames) == 8


def test_the_backlog_is_zero_again_after_a_reset(harness: Harness, stream: sim.Recording) -> None:
    """Fuzzed: after ~/reset the status showed the messages received before it as a worker backlog for ever (the
    worker's count starts again, the node's did not)."""
    harness.publish(replace(stream, t=stream.t[:300], raw=stream.raw[:300]))
    assert harness.spin_until(lambda: harness.node.statuses["mag"].samples_seen == 300, 5.0)
    assert harness.call("reset").success
    harness.send(mag_msg(harness.c, 2000.0 + 0.02 * k, v) for k, v in enumerate(stream.raw[:200]))
    assert harness.spin_until(lambda: harness.node.statuses["mag"].samples_seen == 200, 5.0)
    harness.status.clear()
    harness.spin_until(lambda: len(harness.status) >= 2, 3.0)
    kv = {x.key: x.value for x in harness.last_status().values}
    assert kv["received"] == "500" and kv["samples_seen"] == "200" and kv["worker_backlog"] == "0", kv


def test_sixty_service_calls_at_once_are_all_answered(harness: Harness) -> None:
    """Fuzzed: of 60 ~/save calls made at once 10-30 were answered (the default request queue of 10); every one is."""
    clients = [harness.peer.create_client(Trigger, "/margcal/save") for _ in range(60)]
    assert harness.spin_until(lambda: all(c.service_is_ready() for c in clients), 5.0)
    futures = [c.call_async(Trigger.Request()) for c in clients]
    assert harness.spin_until(lambda: all(f.done() for f in futures), 15.0), sum(f.done() for f in futures)
    assert all(not f.result().success and "nothing to save" in f.result().message for f in futures)


def test_a_calibration_file_under_a_home_that_does_not_exist_is_refused_not_fatal(harness: Harness) -> None:
    """Fuzzed: calibration_file '~nosuchuser/cal.yaml' was accepted, and ~/save then killed the node (pathlib's
    RuntimeError through the executor). Set at run time it is refused; the node answers ~/save as before."""
    got = harness.node.set_parameters([Parameter("calibration_file", value="~nosuchuser_margcal/cal.yaml")])[0]
    assert not got.successful and "~nosuchuser_margcal/cal.yaml" in got.reason
    res = harness.call("save")
    assert not res.success and "nothing to save" in res.message


def test_reset_sets_the_file_aside_and_the_default_file_is_the_nodes(context: Context, classes: MessageClasses,
                                                                      stream: sim.Recording, tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """calibration_file 'auto' is ~/.ros/margcal/<node>.yaml; after ~/reset the file is set aside, so a restart
    starts uncalibrated too."""
    monkeypatch.setenv("HOME", str(tmp_path))
    h = Harness(context, classes, tmp_path / "unused.yaml", calibration_file="auto")
    path = tmp_path / ".ros" / "margcal" / "margcal.yaml"
    try:
        _calibrate(h, stream)
        assert h.spin_until(path.exists, 3.0), "autosave wrote no file at the node's own path"
        res = h.call("reset")
        assert res.success and "set aside" in res.message
        assert not path.exists() and path.with_name("margcal.yaml.reset").exists()
    finally:
        h.close()
    h2 = Harness(context, classes, tmp_path / "unused.yaml", calibration_file="auto")
    try:
        h2.spin_until(lambda: False, 0.5)
        assert not h2.calibrations and h2.node.calibrations["mag"] is None
    finally:
        h2.close()


def test_the_accelerometers_unit_given_to_the_magnetometer_is_refused(context: Context, classes: MessageClasses,
                                                                      stream: sim.Recording, tmp_path: Path) -> None:
    """mag.unit 'm/s^2' was taken as counts (every check off, the unit written into the file); now it is refused at
    start, said in the log, and the magnetometer is read in tesla (REP-103)."""
    h = Harness(context, classes, tmp_path / "cal.yaml", mag__unit="m/s^2")
    try:
        assert h.node._configs["mag"].unit == "T"
        h.publish(stream)
        assert h.spin_until(lambda: h.node.calibrations["mag"] is not None, 10.0), h.last_status().message
        assert h.node.calibrations["mag"].unit == "T"
    finally:
        h.close()


def test_a_driver_in_microtesla_is_calibrated_with_mag_unit(context: Context, classes: MessageClasses,
                                                            stream: sim.Recording, tmp_path: Path) -> None:
    """mag.unit uT: a driver publishing µT (many do, against REP-103) is calibrated in µT, its limits and guard
    rails those of the unit; the calibrated messages are in µT too."""
    h = Harness(context, classes, tmp_path / "cal.yaml", mag__unit="uT")
    try:
        h.publish(replace(stream, raw=stream.raw * 1e6))
        assert h.spin_until(lambda: h.node.calibrations["mag"] is not None, 10.0), h.last_status().message
        cal = h.node.calibrations["mag"]
        assert cal.unit == "uT" and abs(cal.norm - 1e6 * stream.truth.norm) < 0.02 * 1e6 * stream.truth.norm
        h.spin_until(lambda: False, 0.3)
        assert abs(np.linalg.norm(mag_to_numpy(h.calibrated[-1])[1]) - cal.norm) < 0.05 * cal.norm
    finally:
        h.close()


def test_an_overflowing_vector_is_dropped_and_the_node_lives(harness: Harness, stream: sim.Recording) -> None:
    """Components of 1e200 or 1e308 overflow a squared norm: such a message is dropped and counted as any absurd
    magnitude, never an exception out of the callback (it ended the node)."""
    head = _head(stream, 100)
    harness.publish(head)
    last = float(head.t[-1])
    harness.send(mag_msg(harness.c, last + 0.02 * (k + 1), v) for k, v in
                 enumerate([(1e200, 0.0, 0.0), (1e308, 1e308, 1e308), (-2e154, 3e154, 1e154)]))
    n = len(head) + 3
    assert harness.spin_until(lambda: harness.node.statuses["mag"].samples_seen == n, 5.0)
    assert harness.node.statuses["mag"].dropped.get("magnitude", 0) == 3
    assert all(np.all(np.isfinite(mag_to_numpy(m)[1])) for m in harness.calibrated)


def test_a_declared_change_withholds_the_calibrated_topic(context: Context, classes: MessageClasses,
                                                           stream: sim.Recording, tmp_path: Path) -> None:
    """Started with a calibration 30 % of the field off, the node declares a sensor change within seconds; once it
    knows, it publishes nothing calibrated with the calibration it knows is wrong, until a new one fits."""
    ref = SensorCalibrator("mag")
    for t, v in zip(stream.t.tolist(), stream.raw, strict=True):
        ref.push(t, v)
    assert ref.calibration is not None
    wrong = ref.calibration.replace(offset=ref.calibration.offset + np.array([0.3 * ref.calibration.norm, 0.0, 0.0]))
    save_calibrations(tmp_path / "cal.yaml", {"mag": wrong})
    h = Harness(context, classes, tmp_path / "cal.yaml")
    events: list[tuple[str, float, int]] = []  # (kind, stamp, calibrated messages received when the node handled it)
    handle = h.node._handle
    h.node._handle = lambda ev: (events.append((ev.kind.value, ev.t, len(h.calibrated))), handle(ev))  # type: ignore[method-assign]
    try:
        h.publish(stream)
        assert h.spin_until(lambda: h.node.statuses["mag"].samples_seen == len(stream), 5.0)
        h.spin_until(lambda: False, 0.5)
        changed = next(((t, k) for kind, t, k in events if kind == "changed"), None)
        assert changed is not None, events
        later = next(((t, k) for kind, t, k in events if kind == "calibrated" and t > changed[0]), None)
        assert later is not None, events  # a tumble: the changed sensor is calibrated again within the minute
        stamps = np.array([mag_to_numpy(m)[0] for m in h.calibrated])
        assert np.all(stamps[:changed[1]] < changed[0] + 30.0) and changed[1] > 0  # the loaded calibration before
        # from the node's hearing of the change (the worker may lag the harness's fast stream) until the new
        # calibration: nothing (a few messages in flight to the peer aside)
        withheld = stamps[changed[1] + 5:later[1]]
        assert not len(withheld), (events, withheld[:5])
        assert len(stamps) > later[1] and np.all(stamps[later[1] + 5:] > later[0])  # ... then the new one
    finally:
        h.close()


def test_the_sensor_follows_the_frame_that_carries_the_topic(harness: Harness, stream: sim.Recording) -> None:
    """Fuzzed on real rclpy: a first message with an empty frame_id, then imu_link, had 2954 of 3000 messages
    ignored for good. Once 90 % of the last 200 messages carry one other frame the sensor follows it, its
    calibration started afresh; a driver that changes its frame_id later is followed too."""
    node = harness.node
    harness.send(mag_msg(harness.c, 999.9 + 0.01 * k, stream.raw[0], frame_id="") for k in range(3))
    harness.publish(stream)
    assert node._traffic["mag"].frame == "imu_link"
    assert harness.spin_until(lambda: node.calibrations["mag"] is not None, 10.0)
    assert harness.spin_until(lambda: node.statuses["mag"].samples_seen >= len(stream) - 200, 5.0)
    assert harness.calibrated and {m.header.frame_id for m in harness.calibrated} == {"imu_link"}
    before = node.calibrations["mag"]
    # the driver now says mag_link: its first 180 messages are another frame's (the window counts from its second),
    # then the sensor follows it
    later = replace(stream, t=stream.t + 100.0)
    node._stamps["mag"].fell_back = True  # as if imu_link's driver had broken stamps: mag_link's are judged afresh
    harness.send(mag_msg(harness.c, float(t), v, frame_id="mag_link") for t, v in zip(later.t[:180], later.raw[:180],
                                                                                        strict=True))
    assert node._traffic["mag"].frame == "imu_link" and node.calibrations["mag"] is before
    harness.send(mag_msg(harness.c, float(t), v, frame_id="mag_link") for t, v in zip(later.t[180:], later.raw[180:],
                                                                                        strict=True))
    assert node._traffic["mag"].frame == "mag_link" and node._stamps["mag"].using == "header"
    assert harness.spin_until(lambda: node.calibrations["mag"] is not None and node.calibrations["mag"] is not before, 10.0)
    harness.status.clear()
    harness.spin_until(lambda: bool(harness.status), 3.0)
    kv = {x.key: x.value for x in harness.last_status().values}
    assert kv["ignored_other_frames"] == "0" and kv["worker_backlog"] == "0", kv
    assert int(kv["samples_seen"]) == len(later) - 180  # the worker counts from the takeover on
