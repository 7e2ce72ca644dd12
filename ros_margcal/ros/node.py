"""The rclpy node (ROS 2 Jazzy): the ROS face of one ``SensorCalibrator`` per sensor, run in a worker process.

Topics (defaults, all remappable; REP-145 names, REP-103 units):

- subscribes ``imu/data_raw`` (sensor_msgs/Imu) and ``imu/mag`` (sensor_msgs/MagneticField) best effort
  (REP-2003's sensor-data profile, which matches reliable and best-effort drivers), with a queue of
  ``queue_depth`` messages instead of its 5 (a burst of a serial driver, a pause of the interpreter);
- publishes, reliable (the system default, REP-2003 for publishers, so default-QoS and sensor-data
  subscribers both receive), ``imu_calibrated/data_raw`` and ``imu_calibrated/mag`` (header
  unchanged, covariance ``W Σ Wᵀ``; a sample with a non-finite or zero vector, or on a saturated axis
  (``stream.saturation``), is not published; nor is any while a declared sensor change has made the calibration
  wrong, until a calibration fits again: raw values then with ``publish_uncalibrated``),
  ``/calib/status`` (diagnostic_msgs/DiagnosticArray, one status per sensor, every ``status_period_s``,
  with the rate received and the callback times; also on ``/diagnostics`` when ``publish_diagnostics``),
  and the current calibration on ``/calib/mag`` and ``/calib/accel`` (std_msgs/String with the
  ``ros__parameters`` YAML, transient-local so late joiners get it), and with ``publish_markers`` the live
  view on ``/calib/markers`` (visualization_msgs/MarkerArray, every status period while someone subscribes:
  buffered samples, covered bins, the fitted ellipsoid, coloured by state; ``markers.py``) for RViz.

The field from a geomagnetic model (issue 28): a position, from the parameters ``latitude``/``longitude``/
``altitude`` (NaN: unset) or from ``gps/fix`` (sensor_msgs/NavSatFix, sensor-data QoS, when ``gps_fix``: the
first fix with a status of at least STATUS_FIX, and a later one more than ``FIX_MOVE_KM`` away), makes the
magnetometer's ``reference_norm`` the World Magnetic Model's intensity there and its inclination that of the heading
figures (``PipelineConfig.at_position``); the worker gets the new options (``configure``), and the status's
``field_model`` says which field: 'field from WMM2025 at 48.1°N 11.6°E: 48.8 µT, inclination 64.4° (2026.90)'.

Services (std_srvs/Trigger): ``~/reset`` (forget samples and calibrations), ``~/save`` (write the
calibration file now), ``~/refit`` (validate and fit now; the validator and guard rails still decide); each keeps
up to ``SERVICE_QUEUE`` requests queued, so a burst of calls is answered in full.

Threads and processes: a fit holds the interpreter (the GIL) for tens of milliseconds to seconds, so no
thread of this process may run one. The sample callbacks only convert the message, choose its time,
publish the calibrated message with the calibration the node holds and queue the sample; a timer
(``_pump``, every 50 ms: an idle executor wake-up costs about 1 ms of CPU) hands the queued samples to
the calibrators in a worker process (``worker.CalibrationWorker``: the gate, buffer, validator, fits,
change detection, the gyro pairing) and takes back calibrations, events, statuses and service answers.
``~/reset`` and ``~/refit`` await the worker's answer without blocking the executor. ``main`` spins a
``SingleThreadedExecutor``: the ``MultiThreadedExecutor`` of Jazzy's rclpy (7.1.6) cycles its wait loop at
up to a full core and loses most of a 100 Hz stream (rclpy issue 1452, fixed after Jazzy), and nothing here needs a second thread.

The magnetometer's gyro-aided fit (``gyro_aided``, ``model/fitting_gyro.py``) takes the angular rate of
the Imu message nearest in stamp (within ``GYRO_PAIR_S``) of the same ``frame_id`` (the rate must be in
the magnetometer's frame), whichever topic the executor serves first (``pairing.RatePairing``); with the
accelerometer disabled the Imu topic is still subscribed for the rates.

Sample times come from the header stamp or the receive time (``stamp_source``: ``auto`` uses the
header stamp until 2 of the last 20 are zero, go backwards or repeat the two before, then the receive time,
with one warning; receive times spaced beyond the calibrator's burst period: ``stamps.py``).

Parameters are declared with descriptors and ranges (defaults in ``msg_configs/margcal.yaml``,
float literals since rclpy types parameters strictly) and checked again as a whole
(``PipelineConfig.checked``) when set at run time, then sent to the worker. The calibration file is
written atomically (``save_calibrations``) after each accepted calibration and read at start; a corrupt
or newer file is refused with an error log line and the node starts uncalibrated.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.task import Future
from sensor_msgs.msg import Imu, MagneticField, NavSatFix, NavSatStatus
from std_msgs.msg import Header, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from ..model.calibration import FORCED, Calibration
from ..model.calibration_file import load_calibrations, save_calibrations
from ..model.errors import CalibrationFileError, ConfigError
from ..model.geomag import distance_km, field_at
from ..stream.config import PipelineConfig, plausibility
from ..stream.saturation import RailWatch
from ..stream.status import EventKind, Level, State, Status
from ..stream.units import unit_scale, unknown_unit_note
from ..validation.shipped import load_validator
from .environment import use_venv_ament_prefix
from .markers import coverage_markers
from .messages import calibrate_imu, calibrate_mag, calibration_to_string, imu_to_numpy, mag_to_numpy, status_to_diagnostic
from .stamps import STAMP_SOURCES, StampSource
from .worker import CalibrationWorker

__all__ = ["MargCalNode", "main"]

SENSORS = ("mag", "accel")
OUTPUT_DEPTH = 50
"""KEEP_LAST depth of the calibrated streams (reliable, volatile: the system default profile)."""

# per-sensor tunables: name -> (lower bound, upper bound, description); value 0.0 means "off/auto" where noted
_FLOAT_PARAMS: dict[str, tuple[float, float, str]] = {
    "max_predicted_error": (0.0, 1.0, "threshold on the validator's predicted RMS relative error; 0.0 = the validator's own"),
    "refit_min_interval_s": (0.0, 3600.0, "minimum time between validations while uncalibrated or after a change, s"),
    "recheck_interval_s": (0.0, 86400.0, "minimum time between refits while calibrated, s"),
    "max_residual": (0.001, 0.5, "guard rail: RMS relative residual limit of a new fit"),
    "max_offset_ratio": (0.01, 20.0, "guard rail: |offset| limit as a multiple of the field norm"),
    "gain_min": (0.1, 1.0, "guard rail: smallest axis gain ratio"),
    "gain_max": (1.0, 10.0, "guard rail: largest axis gain ratio"),
    "norm_min": (0.0, 1.0e9, "guard rail: smallest plausible field norm, in the sensor's unit (default: the unit's)"),
    "norm_max": (0.0, 1.0e9, "guard rail: largest plausible field norm, in the sensor's unit (default: the unit's); "
                             "0.0 = none"),
    "not_worse_tolerance": (0.0, 1.0, "guard rail: allowed relative increase of the recent residual"),
    "max_parameter_std": (1e-4, 1.0, "guard rail: largest relative one-sigma parameter uncertainty"),
    "change_threshold": (0.001, 1.0, "median relative residual of recent samples that signals a changed sensor"),
    "change_min_duration_s": (0.0, 3600.0, "the change must persist this long before the buffer is rebuilt, s"),
    "outlier_threshold": (0.01, 10.0, "relative residual above which a sample is not buffered while calibrated"),
    "max_rate_hz": (1.0, 1.0e5, "samples closer than 1/max_rate_hz are a burst and dropped"),
    "max_offset": (0.0, 1.0e9, "guard rail: absolute |offset| limit in the sensor's unit, besides max_offset_ratio "
                               "(default: the unit's); 0.0 = none"),
    "max_heading_p95_deg": (0.01, 180.0, "partial calibration: largest predicted heading p95 at the tilt seen, deg"),
    "early_heading_p95_deg": (0.01, 180.0, "early fit on rich motion: largest predicted heading p95 at 30 deg tilt "
                                           "(max_heading_p95_deg over more than half the sphere), deg"),
    "near_level_tilt_deg": (0.0, 90.0, "magnetometer: a ring this flat is held level without a gyro (a car); 0.0 = never "
                                        "(a sensor mounted tilted)"),
}
_BOOL_PARAMS: dict[str, str] = {
    "drop_saturated": "drop readings on an axis pinned at the end of the sensor's range while it turns (counted, named)",
    "partial_fit": "fit what the motion makes observable (a ring or band) when the full validator refuses",
    "early_fit": "publish a first MAP fit on rich motion once its predicted heading error is small",
    "gyro_aided": "magnetometer: the Imu angular rate (same frame_id, or the only Imu frame; stamps within 20 ms) joins "
                  "the partial fit",
}
_MAG_BOOL: dict[str, str] = {
    "calibrate_into_imu_frame": "magnetometer with a gyro: publish the calibration in the Imu's frame once its mounting "
                                "rotation is decided",
}
_MAG_STR: dict[str, str] = {
    "up_axis": "magnetometer: its axis pointing up when the vehicle is level (z; y, -x, ... for one mounted on its side, "
               "without a gyro to find its mounting): the readings are turned so that it is z; the calibration stays in "
               "the magnetometer's axes",
}
_ACCEL_BOOL: dict[str, str] = {
    "gate_learn_noise": "inactivity gate: widen the threshold to the sensor's learnt rest noise (at most 1e-2)",
}
_INT_PARAMS: dict[str, tuple[int, int, str]] = {
    "min_points": (4, 100000, "fewest buffered samples for a fit"),
    "refit_every": (1, 100000, "buffered samples between validations"),
}
_READ_ONLY_INT: dict[str, tuple[int, int, str]] = {
    "n_bins": (6, 10000, "direction bins of the buffer"),
    "per_bin": (1, 1000, "samples kept per direction bin"),
    "recent_samples": (4, 100000, "recent samples kept for change detection and the not-worse check"),
    "change_window": (2, 100000, "samples whose median residual decides a change"),
}
_ACCEL_GATE: dict[str, tuple[float, float, str]] = {
    "gate_window_s": (0.1, 60.0, "inactivity gate window, s"),
    "gate_cv_threshold": (1e-5, 1.0, "inactivity gate: coefficient of variation limit"),
    "gate_gyro_threshold": (0.0, 10.0, "inactivity gate: angular rate limit, rad/s; 0.0 = off"),
    "gate_gyro_window_s": (0.01, 60.0, "inactivity gate with a gyro reading: still window, s"),
    "gate_gyro_rest_threshold": (1e-6, 10.0, "inactivity gate with a gyro reading: largest |omega| at rest, rad/s"),
}


PUMP_PERIOD_S = 0.05
"""How often queued samples go to the worker and its answers are read, s (each wake-up of an idle executor
costs about 1 ms of CPU in rclpy: 10 ms cost 10 % of a core with no data at all)."""
REQUEST_TIMEOUT_S = 60.0
"""A service waits this long for the worker's answer, s."""
WORKER_RESTART_S = 5.0
"""A worker that ended is started again at most this often, s."""
CALLBACK_TIMES = 2000
"""Sample callback durations kept per sensor for the status's p50/p99/max."""
RATE_WINDOW_S = 5.0
"""The received rate in the status is averaged over about this long, s."""
DROP_WINDOW_S = 2.0
"""The status warns when the calibrator dropped more than ``DROP_WARN`` of the samples of about this long, s ..."""
DROP_WARN = 0.5
"""... (of at least ``DROP_MIN_SAMPLES`` samples; field disturbances, the ``outlier`` drops, not counted)."""
DROP_MIN_SAMPLES = 10
FIX_MOVE_KM = 50.0
"""A GPS fix this far from the position in use moves the field model there (the field changes ~0.1 % per 50 km)."""
OTHER_FRAME_S = 10.0
"""The status flags messages of another frame_id on a sensor's topic for this long after the last one, s."""
SERVICE_QUEUE = 100
"""Requests a service keeps queued (the default profile's 10 lost the rest of a burst of calls)."""
MAX_OTHER_FRAMES = 8
"""At most this many other frame_ids are named in the status (each up to ``FRAME_SHOWN`` characters); messages of
further ones are counted only: a frame_id changing on every message grew the status to 4 MB and the node by 50 MB."""
FRAME_TAKEOVER = 200
"""When at least ``FRAME_TAKEOVER_SHARE`` of a topic's last this many messages carry one other frame_id, the sensor
follows that frame: a driver that changed its frame_id, or a first message with a stray one (an empty frame_id once,
then imu_link: 2954 of 3000 messages were ignored for good). The calibration of the old frame is forgotten."""
FRAME_TAKEOVER_SHARE = 0.9
FRAME_SHOWN = 40


def _fdesc(lo: float, hi: float, text: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=text, read_only=read_only,
                               floating_point_range=[FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)])


def _idesc(lo: int, hi: int, text: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=text, read_only=read_only,
                               integer_range=[IntegerRange(from_value=int(lo), to_value=int(hi), step=1)])


def _level_bytes(level: int) -> bytes:
    """rclpy's DiagnosticStatus.level is a ``byte`` field: one-byte ``bytes``."""
    return bytes([int(level)])


def _limits(cfg: PipelineConfig) -> tuple[float, float]:
    """The raw norms the calibrator's intake takes (``stream/intake.py``); learnt ones (counts) are not known here."""
    if cfg.learn_magnitude_samples > 0:
        return 0.0, math.inf
    return cfg.min_magnitude, cfg.max_magnitude


def _publishable(v: Any, limits: tuple[float, float]) -> bool:
    """A raw vector worth publishing calibrated: finite, not zero (a failed read, a dead sensor) and within the
    magnitudes the calibrator takes (a driver in another unit): the calibrator refuses the others too."""
    n = math.hypot(float(v[0]), float(v[1]), float(v[2]))  # no overflow: squaring 1e200 raised and ended the node
    return math.isfinite(n) and limits[0] < n <= limits[1]  # False for NaN and Inf (learnt limits reach +inf)


def _shown(frame_id: str) -> str:
    """A frame_id for the status: quoted, cut to ``FRAME_SHOWN`` characters."""
    return repr(frame_id) if len(frame_id) <= FRAME_SHOWN else repr(frame_id[:FRAME_SHOWN]) + f"... ({len(frame_id)} chars)"


def _calibration_path(value: str, node_name: str) -> Path | None:
    """The file ``calibration_file`` names (``auto``: ``~/.ros/margcal/<node>.yaml``; empty: None).

    Raises:
        ConfigError: a ``~user`` of no user, or no home directory (pathlib's RuntimeError crashed ``~/save``).
    """
    if not value:
        return None
    try:
        if value == "auto":
            return Path.home() / ".ros" / "margcal" / (node_name.strip("/").replace("/", ".") + ".yaml")
        return Path(value).expanduser()
    except RuntimeError as exc:
        msg = f"calibration_file {value!r}: {exc}"
        raise ConfigError(msg) from exc


def _implausible(cal: Calibration, sensor: str, cfg: PipelineConfig) -> str:
    """Why a calibration read from a file does not fit this node's sensor (empty when it does): another sensor,
    another unit (a file of ``margcal calibrate --unit uT`` would publish fields 1e6 too large), a field norm
    beyond the guard rail, or an offset or gains the node would refuse from its own fit."""
    if cal.sensor and cal.sensor != sensor:
        return f"it is a calibration of the {cal.sensor}"
    if cal.unit and unit_scale(sensor, cal.unit) != unit_scale(sensor, cfg.unit):
        return (f"it is in {cal.unit}, the node's {sensor} messages are in {cfg.unit} (REP-103); "
                f"calibrate the recording in {cfg.unit}")
    if not cfg.norm_min <= cal.norm <= cfg.norm_max:
        return f"its field norm {cal.norm:.6g} {cfg.unit} is outside [{cfg.norm_min:.6g}, {cfg.norm_max:.6g}] {cfg.unit}"
    if FORCED in cal.method:
        return ""  # the user wrote it past the guard rails on purpose (margcal calibrate --force): loaded, with a warning
    # the guard rails of the node's own fits (offset, gains, field radius): a runaway batch fit is not published;
    # the parameter uncertainty is left out (a partial calibration's vertical terms are the prior's, and wide)
    why = plausibility(cal.replace(covariance=None, parameter_names=()), cfg)
    return f"it fails the guard rails of the node's own fits: {why}" if why else ""


class _Traffic:
    """What one sensor's topic brought: messages received, the rate over the last seconds, callback times."""

    def __init__(self) -> None:
        self.received = 0
        self.last_rx: float | None = None
        self.times: deque[float] = deque(maxlen=CALLBACK_TIMES)
        self.frame: str | None = None  # the frame_id the sensor is calibrated in: the first one seen (or a takeover's)
        self.recent_frames: deque[str] = deque(maxlen=FRAME_TAKEOVER)  # the last messages' frame_ids (``takeover``)
        self.recent_counts: dict[str, int] = {}
        self.other_frames: dict[str, int] = {}  # messages of other frame_ids, ignored (MAX_OTHER_FRAMES named)
        self.other_more = 0  # ... and of further frame_ids, counted only
        self.other_frame_rx = -math.inf
        self.reset_base = 0  # messages received before the last ~/reset (the worker's counts start again there)
        self._counts: deque[tuple[float, int]] = deque()
        self._drops: deque[tuple[float, int, dict[str, int]]] = deque()

    def dropping(self, now: float, st: Status) -> str:
        """What the calibrator drops when it drops more than ``DROP_WARN`` of the recent samples, else ''."""
        drops = self._drops
        drops.append((now, st.samples_seen, {k: v for k, v in st.dropped.items() if k != "outlier"}))
        while len(drops) > 2 and now - drops[1][0] >= DROP_WINDOW_S:
            drops.popleft()
        (_, n0, d0), (_, n1, d1) = drops[0], drops[-1]
        delta = {k: v - d0.get(k, 0) for k, v in d1.items() if v > d0.get(k, 0)}
        seen = n1 - n0
        if seen < DROP_MIN_SAMPLES or sum(delta.values()) <= DROP_WARN * seen:
            return ""
        why = ", ".join(f"{k} {v}" for k, v in sorted(delta.items(), key=lambda kv: -kv[1]))
        return f"dropping {100 * sum(delta.values()) / seen:.0f} % of the samples ({why} of the last {seen})"

    def forget_frames(self, frame: str | None = None) -> None:
        """Calibrate ``frame`` from now on (None: the next one seen), forgetting the other frames and the window."""
        self.frame, self.other_frames, self.other_more = frame, {}, 0
        self.recent_frames.clear()
        self.recent_counts.clear()

    def takeover(self, frame_id: str) -> bool:
        """Record one message's frame_id; True when another frame than ``frame`` now carries the topic
        (``FRAME_TAKEOVER``): the caller switches to it."""
        recent, counts = self.recent_frames, self.recent_counts
        if len(recent) == FRAME_TAKEOVER:
            old = recent[0]
            counts[old] -= 1
            if not counts[old]:
                del counts[old]
        recent.append(frame_id)
        counts[frame_id] = counts.get(frame_id, 0) + 1
        return frame_id != self.frame and counts[frame_id] >= FRAME_TAKEOVER_SHARE * FRAME_TAKEOVER

    def tick(self, now: float) -> float:
        """Record the count at ``now`` (each status); the rate over about ``RATE_WINDOW_S``, Hz."""
        counts = self._counts
        counts.append((now, self.received))
        while len(counts) > 2 and now - counts[1][0] >= RATE_WINDOW_S:
            counts.popleft()
        (t0, n0), (t1, n1) = counts[0], counts[-1]
        return (n1 - n0) / (t1 - t0) if t1 > t0 else 0.0

    def values(self, rate: float) -> list[tuple[str, str]]:
        ms = np.array(self.times) * 1e3
        p50, p99, top = (np.percentile(ms, 50), np.percentile(ms, 99), ms.max()) if len(ms) else (math.nan,) * 3
        return [("received", str(self.received)), ("rate_hz", f"{rate:.1f}"), ("callback_p50_ms", f"{p50:.3f}"),
                ("callback_p99_ms", f"{p99:.3f}"), ("callback_max_ms", f"{top:.3f}")]


class MargCalNode(Node):
    """Online magnetometer/accelerometer calibration node (see the module docstring)."""

    def __init__(self, node_name: str = "margcal", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        log = self.get_logger()
        self.declare_parameter("calibration_file", "auto", ParameterDescriptor(
            description="calibration YAML, read at start, written atomically; 'auto' = ~/.ros/margcal/<node>.yaml "
                        "(the node's namespace and name: each node its own), '' = none"))
        self.declare_parameter("autosave", True, ParameterDescriptor(description="write the file after each new calibration"))
        self.declare_parameter("publish_uncalibrated", False,
                               ParameterDescriptor(description="publish raw values on the calibrated topics until calibrated"))
        self.declare_parameter("publish_diagnostics", False, ParameterDescriptor(description="also publish on /diagnostics"))
        self.declare_parameter("publish_markers", True, ParameterDescriptor(
            description="publish the live view for RViz on /calib/markers (visualization_msgs/MarkerArray)", read_only=True))
        self.declare_parameter("status_period_s", 1.0, _fdesc(0.05, 60.0, "period of /calib/status, s", read_only=True))
        self.declare_parameter("stale_timeout_s", 5.0, _fdesc(0.1, 3600.0, "no samples for this long -> STALE, s"))
        self.declare_parameter("validator_file", "", ParameterDescriptor(
            description="trained validator JSON (margcal train-validator); '' = the shipped one", read_only=True))
        self.declare_parameter("stamp_source", "auto", ParameterDescriptor(
            description="sample time: 'header' stamp, 'receive' time, or 'auto' (header, falling back to the receive "
                        "time for good when 2 of the last 20 stamps are zero, go backwards or repeat the two before)",
            read_only=True,
            additional_constraints="one of: " + ", ".join(STAMP_SOURCES)))
        self.declare_parameter("queue_depth", 1000, _idesc(
            10, 100000, "depth of the best-effort input queues, messages (1 s at 1 kHz by default)", read_only=True))
        self._position = self._declare_position()

        self._publish_raw = bool(self.get_parameter("publish_uncalibrated").value)  # read per message: cached
        mode = str(self.get_parameter("stamp_source").value)
        if mode not in STAMP_SOURCES:
            log.error(f"stamp_source {mode!r} is not one of {STAMP_SOURCES}; using 'auto'")
            mode = "auto"
        self._stamps = {"mag": StampSource(mode, "imu/mag"), "accel": StampSource(mode, "imu/data_raw")}
        self._traffic = {s: _Traffic() for s in SENSORS}
        self._limits: dict[str, tuple[float, float]] = {}
        self._rails = {s: RailWatch() for s in SENSORS}  # saturated axes, for what is published (_pinned)
        self._units: dict[str, str] = {}
        self._batch: list[tuple[Any, ...]] = []
        self._calibration: dict[str, Calibration | None] = {}
        self._withheld: set[str] = set()  # sensors whose calibration a declared change made wrong: not applied
        self._configs: dict[str, PipelineConfig] = {}
        self._status: dict[str, Status] = {}
        self._requests: dict[int, tuple[Future, float]] = {}
        self._save_lock = threading.Lock()
        validator = self._load_validator()
        latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._pub_cal: dict[str, Any] = {}
        for s in SENSORS:
            enabled = self.declare_parameter(f"{s}.enabled", True, ParameterDescriptor(
                description=f"calibrate the {s} (read at start)", read_only=True)).value
            cfg = self._declare_sensor(s)
            if enabled:
                self._configs[s] = cfg
        loaded = self._load_file()
        for s, cfg in self._configs.items():
            self._limits[s] = _limits(cfg)
            self._calibration[s] = loaded.get(s)
            self._status[s] = Status(s, Level.WARN, State.CALIBRATED if s in loaded else State.COLLECTING,
                                     "starting the calibration worker", 0.0, 0, 0, 0)
            self._pub_cal[s] = self.create_publisher(String, f"/calib/{s}", latched)
        markers = bool(self.get_parameter("publish_markers").value)
        self._worker = CalibrationWorker(self._specs(), validator, float(self.get_parameter("status_period_s").value))
        self._pub_markers = self.create_publisher(MarkerArray, "/calib/markers", 1) if markers else None
        self._worker_started = time.monotonic()
        sensor_qos = QoSProfile(depth=int(self.get_parameter("queue_depth").value), history=HistoryPolicy.KEEP_LAST,
                                reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
        if "mag" in self._configs:
            self._pub_mag = self.create_publisher(MagneticField, "imu_calibrated/mag", OUTPUT_DEPTH)
            self.create_subscription(MagneticField, "imu/mag", self._on_mag, sensor_qos)
        if self._configs:  # the Imu topic also brings the magnetometer's rates
            self._pub_imu = self.create_publisher(Imu, "imu_calibrated/data_raw", OUTPUT_DEPTH)
            self.create_subscription(Imu, "imu/data_raw", self._on_imu, sensor_qos)
        if "mag" in self._configs and self.get_parameter("gps_fix").value:
            self.create_subscription(NavSatFix, "gps/fix", self._on_fix, qos_profile_sensor_data)
        self._pub_status = self.create_publisher(DiagnosticArray, "/calib/status", 10)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # a group of their own: a service awaiting the worker keeps its group busy, never the samples' default group
        services = ReentrantCallbackGroup()
        # the services' default request queue keeps 10: of 60 calls at once 10 were answered, the rest never (fuzzed)
        calls = QoSProfile(depth=SERVICE_QUEUE, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)
        self.create_service(Trigger, "~/reset", self._srv_reset, qos_profile=calls, callback_group=services)
        self.create_service(Trigger, "~/save", self._srv_save, qos_profile=calls, callback_group=services)
        self.create_service(Trigger, "~/refit", self._srv_refit, qos_profile=calls, callback_group=services)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(float(self.get_parameter("status_period_s").value), self._publish_status)
        self.create_timer(PUMP_PERIOD_S, self._pump)
        for s, cal in self._calibration.items():
            if cal is not None:
                self._pub_cal[s].publish(calibration_to_string(cal, String, node=self.get_name()))
        log.info(f"margcal started: sensors {sorted(self._configs)}, calibrated {sorted(loaded)}, "
                 f"worker process {self._worker.pid}")

    @property
    def calibrations(self) -> dict[str, Calibration | None]:
        """The calibration each enabled sensor's messages are published with now (None: uncalibrated)."""
        return dict(self._calibration)

    @property
    def received(self) -> dict[str, int]:
        """Messages received per sensor topic (``accel``: the Imu topic) since the start."""
        return {s: t.received for s, t in self._traffic.items()}

    @property
    def configs(self) -> dict[str, PipelineConfig]:
        """The options of each enabled sensor, as the worker has them."""
        return dict(self._configs)

    @property
    def statuses(self) -> dict[str, Status]:
        """The latest status of each enabled sensor from the worker."""
        return dict(self._status)

    def _specs(self) -> dict[str, tuple[PipelineConfig, Calibration | None]]:
        return {s: (cfg, self._calibration[s]) for s, cfg in self._configs.items()}

    def destroy_node(self) -> None:
        """Stop the worker, then the node."""
        self._worker.stop()
        super().destroy_node()

    # -- parameters -------------------------------------------------------------------------------

    def _declare_position(self) -> tuple[float, float, float] | None:
        """The field model's position from the parameters (None: unset or refused, with an error log line)."""
        for name, text in (("latitude", "geodetic latitude, deg, for the field model (WMM2025); NaN = unset"),
                           ("longitude", "longitude, deg east, for the field model; NaN = unset"),
                           ("altitude", "altitude above the WGS 84 ellipsoid, m, for the field model; NaN = 0")):
            self.declare_parameter(name, math.nan, ParameterDescriptor(description=text, read_only=True))
        self.declare_parameter("gps_fix", True, ParameterDescriptor(
            description="take the field model's position from gps/fix (sensor_msgs/NavSatFix)", read_only=True))
        lat, lon, alt = (float(self.get_parameter(n).value) for n in ("latitude", "longitude", "altitude"))
        if math.isnan(lat) and math.isnan(lon):
            return None
        return self._usable(lat, lon, 0.0 if math.isnan(alt) else alt, "the parameters latitude/longitude")

    def _usable(self, lat: float, lon: float, alt: float, source: str) -> tuple[float, float, float] | None:
        """``(lat, lon, alt)`` if the field model takes it; else None and an error log line saying why."""
        try:
            field = field_at(lat, lon, alt)
        except ConfigError as exc:
            self.get_logger().error(f"position from {source} refused: {exc}; the field model is not used",
                                    throttle_duration_sec=60.0)  # a bad fix repeats at the receiver's rate
            return None
        self.get_logger().info(f"{field.describe()} (from {source}): the magnetometer's reference norm and inclination")
        return lat, lon, alt

    def _on_fix(self, msg: NavSatFix) -> None:
        """A GPS fix: the field model's position when there is none yet or this one is ``FIX_MOVE_KM`` away."""
        if msg.status.status < NavSatStatus.STATUS_FIX:
            return
        lat, lon, alt = float(msg.latitude), float(msg.longitude), float(msg.altitude)
        if not (math.isfinite(lat) and math.isfinite(lon)):
            return
        now = self._position
        if now is not None and distance_km(now[0], now[1], lat, lon) <= FIX_MOVE_KM:
            return
        alt = alt if math.isfinite(alt) else 0.0
        position = self._usable(lat, lon, alt, "gps/fix")
        if position is None or "mag" not in self._configs:
            return
        self._position = position
        self._configs["mag"] = self._config_from("mag", {})
        self._worker.request("configure", "mag", self._configs["mag"])

    def _declare_sensor(self, s: str) -> PipelineConfig:
        si = "T" if s == "mag" else "m/s^2"
        unit = str(self.declare_parameter(f"{s}.unit", si, ParameterDescriptor(
            description=f"unit of the driver's {s} messages ({si} per REP-103; e.g. gauss, uT, g; 'counts' learns "
                        "the magnitudes from the data); the calibrated messages are in the same unit", read_only=True)).value)
        try:
            if not unit.strip():
                raise ConfigError("empty")
            PipelineConfig.for_sensor(s, unit=unit)
        except ConfigError as exc:
            self.get_logger().error(f"{s}.unit {unit!r} refused ({exc}); using {si}")
            unit = si
        if note := unknown_unit_note(s, unit):
            self.get_logger().warning(f"{s}.unit: {note}")
        self._units[s] = unit
        base = PipelineConfig.for_sensor(s, unit=unit)
        for name, (lo, hi, text) in _FLOAT_PARAMS.items():
            default = getattr(base, name)
            default = 0.0 if default is None or math.isinf(default) else default
            self.declare_parameter(f"{s}.{name}", float(default), _fdesc(lo, hi, text))
        for name, (lo, hi, text) in _INT_PARAMS.items():
            self.declare_parameter(f"{s}.{name}", int(getattr(base, name)), _idesc(lo, hi, text))
        for name, text in _BOOL_PARAMS.items():
            self.declare_parameter(f"{s}.{name}", bool(getattr(base, name)), ParameterDescriptor(description=text))
        for name, (lo, hi, text) in _READ_ONLY_INT.items():
            self.declare_parameter(f"{s}.{name}", int(getattr(base, name)), _idesc(lo, hi, text, read_only=True))
        if s == "accel":
            for name, (lo, hi, text) in _ACCEL_GATE.items():
                self.declare_parameter(f"{s}.{name}", float(getattr(base, name) or 0.0), _fdesc(lo, hi, text))
            for name, text in _ACCEL_BOOL.items():
                self.declare_parameter(f"{s}.{name}", bool(getattr(base, name)), ParameterDescriptor(description=text))
        if s == "mag":
            for name, text in _MAG_BOOL.items():
                self.declare_parameter(f"{s}.{name}", bool(getattr(base, name)), ParameterDescriptor(description=text))
            for name, text in _MAG_STR.items():
                self.declare_parameter(f"{s}.{name}", str(getattr(base, name)), ParameterDescriptor(description=text))
        return self._config_from(s, {})

    def _config_from(self, s: str, changed: dict[str, Any]) -> PipelineConfig:
        """The PipelineConfig of sensor ``s`` from the declared parameters, with ``changed`` applied."""
        base = PipelineConfig.for_sensor(s, unit=self._units[s])
        own = [*_ACCEL_GATE, *_ACCEL_BOOL] if s == "accel" else [*_MAG_BOOL, *_MAG_STR]
        names = [*_FLOAT_PARAMS, *_INT_PARAMS, *_BOOL_PARAMS, *_READ_ONLY_INT, *own]
        values: dict[str, Any] = {}
        for name in names:
            key = f"{s}.{name}"
            values[name] = changed[key] if key in changed else self.get_parameter(key).value
        for name in ("max_predicted_error", "gate_gyro_threshold", "max_offset"):
            if name in values and not values[name]:
                values[name] = None  # 0.0 = off / the validator's own threshold
        if not values["norm_max"]:
            values["norm_max"] = math.inf  # 0.0 = none (a unit without a scale: counts)
        cfg = replace(base, **values).checked()
        if s == "mag" and self._position is not None:
            cfg = cfg.at_position(*self._position)
        return cfg

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        changed = {p.name: p.value for p in params}
        if "calibration_file" in changed:
            try:
                _calibration_path(str(changed["calibration_file"]), self.get_fully_qualified_name())
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        for s in self._configs:
            if any(k.startswith(f"{s}.") for k in changed):
                try:
                    self._config_from(s, changed)
                except ConfigError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        self._publish_raw = bool(self.get_parameter("publish_uncalibrated").value)
        for s in self._configs:
            if any(p.name.startswith(f"{s}.") for p in params):
                self._configs[s] = self._config_from(s, {})
                self._worker.request("configure", s, self._configs[s])

    # -- data -------------------------------------------------------------------------------------

    def _on_mag(self, msg: MagneticField) -> None:
        t0 = time.perf_counter()
        t, v = mag_to_numpy(msg)
        self._take("mag", t, v, None, msg.header.frame_id)
        cal = None if "mag" in self._withheld else self._calibration["mag"]
        publish = cal is not None or self._publish_raw
        if _publishable(v, self._limits["mag"]) and self._frame_ok("mag", msg) and not self._pinned("mag", v) and publish:
            self._pub_mag.publish(calibrate_mag(msg, cal))
        self._traffic["mag"].times.append(time.perf_counter() - t0)

    def _on_imu(self, msg: Imu) -> None:
        t0 = time.perf_counter()
        t, acc, gyro = imu_to_numpy(msg)
        self._take("accel", t, acc, gyro, msg.header.frame_id)
        if "accel" in self._configs:
            cal = None if "accel" in self._withheld else self._calibration["accel"]
            publish = cal is not None or self._publish_raw
            if (_publishable(acc, self._limits["accel"]) and self._frame_ok("accel", msg)
                    and not self._pinned("accel", acc) and publish):
                self._pub_imu.publish(calibrate_imu(msg, cal))
        self._traffic["accel"].times.append(time.perf_counter() - t0)

    def _take(self, s: str, t: float, v: Any, gyro: Any, frame_id: str) -> None:
        """Count one message, choose its time and queue it for the worker (``worker.Sample``)."""
        now = time.monotonic()
        traffic = self._traffic[s]
        traffic.received += 1
        traffic.last_rx = now
        if traffic.frame is None:
            traffic.frame = frame_id
        if traffic.other_frames and traffic.takeover(frame_id):  # (nothing to count while one frame alone arrives)
            self._follow_frame(s, frame_id)
        elif frame_id != traffic.frame:  # a second sensor on the topic: pooled, it would spoil both calibrations
            others = traffic.other_frames
            if frame_id in others or len(others) < MAX_OTHER_FRAMES:
                others[frame_id] = others.get(frame_id, 0) + 1
            else:
                traffic.other_more += 1
            traffic.other_frame_rx = now
            return
        src = self._stamps[s]
        cfg = self._configs.get(s)  # receive times spaced a little beyond the calibrator's burst period (stamps.py)
        t = src.choose(t, self._now_s, 0.0 if cfg is None else 1.01 * cfg.min_period_s)
        if src.warning is not None:
            self.get_logger().warning(src.pop_warning() or "")
        g = (math.nan,) * 3 if gyro is None else (float(gyro[0]), float(gyro[1]), float(gyro[2]))
        self._batch.append((s, t, float(v[0]), float(v[1]), float(v[2]), *g, frame_id, now))

    def _follow_frame(self, s: str, frame_id: str) -> None:
        """Another frame carries the topic now (``FRAME_TAKEOVER``): calibrate that one, from nothing (the old frame's
        calibration, samples and choice of stamps are another sensor's, or a stray frame_id's)."""
        traffic = self._traffic[s]
        self.get_logger().warning(
            f"{s}: {FRAME_TAKEOVER_SHARE:.0%} of the last {FRAME_TAKEOVER} messages carry frame_id {_shown(frame_id)}, not "
            f"{_shown(traffic.frame or '')}: following {_shown(frame_id)}, its calibration started afresh")
        traffic.forget_frames(frame_id)
        self._batch = [b for b in self._batch if b[0] != s]  # the old frame's, not sent yet: not the new one's
        traffic.reset_base = traffic.received - 1  # the worker counts from this message on
        self._calibration[s] = None
        self._withheld.discard(s)
        old = self._stamps[s]  # the new frame's driver: its header stamps judged afresh (stamp_source auto)
        self._stamps[s] = StampSource(old.mode, old.stream)
        self._worker.request("reset_sensor", s)

    def _pinned(self, s: str, v: Any) -> bool:
        """A reading on a saturated axis (``stream.saturation``, the worker's calibrator drops it too): its calibrated
        value would be wrong, so it is not published. Every publishable reading is watched, calibrated or not yet."""
        return self._configs[s].drop_saturated and self._rails[s].push(float(v[0]), float(v[1]), float(v[2]))

    def _frame_ok(self, s: str, msg: Any) -> bool:
        """True when the message is of the frame the sensor is calibrated in (see ``_take``)."""
        return msg.header.frame_id == self._traffic[s].frame

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _pump(self) -> None:
        """Hand the queued samples to the worker; take what it sent back (a timer, every ``PUMP_PERIOD_S``)."""
        batch, self._batch = self._batch, []
        self._worker.send(batch)
        for item in self._worker.poll():
            kind = item[0]
            if kind == "calibration":
                self._calibration[item[1]] = item[2]
            elif kind == "event":
                self._handle(item[1])
            elif kind == "status":
                self._status.update(item[1])
            elif kind == "view":
                self._publish_markers(item[1])
            elif kind == "reply":
                request = self._requests.pop(item[1], None)
                if request is not None:
                    request[0].set_result((item[2], item[3]))
            elif kind == "error":
                self.get_logger().error(f"calibration worker: {item[1]}")
        now = time.monotonic()
        for rid, (future, since) in list(self._requests.items()):
            if now - since > REQUEST_TIMEOUT_S:
                del self._requests[rid]
                future.set_result((False, f"the calibration worker did not answer within {REQUEST_TIMEOUT_S:.0f} s"))

    def _check_worker(self) -> None:
        """A worker that died is started again from the calibrations the node holds (its buffers are lost)."""
        now = time.monotonic()
        if self._worker.alive or now - self._worker_started < WORKER_RESTART_S:
            return
        self.get_logger().error("the calibration worker process ended; starting a new one from the current calibrations")
        self._worker.restart(self._specs())
        self._withheld.clear()  # the new worker starts calibrated from them and declares a change again if there is one
        self._worker_started = now
        for future, _ in self._requests.values():
            future.set_result((False, "the calibration worker was restarted"))
        self._requests.clear()

    def _handle(self, ev: Any) -> None:
        log = self.get_logger()
        if ev.kind is EventKind.CALIBRATED and ev.calibration is not None:
            log.info(f"{ev.sensor}: {ev.message}")
            self._calibration[ev.sensor] = ev.calibration
            self._withheld.discard(ev.sensor)
            self._pub_cal[ev.sensor].publish(calibration_to_string(ev.calibration, String, node=self.get_name()))
            if self.get_parameter("autosave").value:
                self._save()
        elif ev.kind is EventKind.CHANGED:  # the calibration no longer fits the sensor: not applied until one does
            self._withheld.add(ev.sensor)
            log.warning(f"{ev.sensor}: {ev.message}; the calibrated topic is silent (raw values with publish_uncalibrated) "
                        "until the sensor is calibrated again or the change withdrawn")
        elif ev.kind is EventKind.REJECTED and self._calibration.get(ev.sensor) is None:
            log.warning(f"{ev.sensor}: {ev.message}")
        elif ev.kind is EventKind.REJECTED:
            log.info(f"{ev.sensor}: {ev.message} (keeping the current calibration)")
        elif ev.kind is EventKind.TIME_BASE:
            log.warning(f"{ev.sensor}: {ev.message}")
        else:
            log.debug(f"{ev.sensor}: {ev.message}")

    # -- persistence ------------------------------------------------------------------------------

    def _path(self) -> Path | None:
        """The calibration file; None when ``calibration_file`` is empty, or names a home that does not exist
        (logged: persistence is off; a parameter set at run time is refused instead, ``_validate_parameters``)."""
        try:
            return _calibration_path(str(self.get_parameter("calibration_file").value), self.get_fully_qualified_name())
        except ConfigError as exc:
            self.get_logger().error(f"{exc}: persistence is off")
            return None

    def _set_aside(self) -> str:
        """After a reset: move the calibration file to ``<file>.reset`` so a restart starts uncalibrated too."""
        path = self._path()
        if path is None or not path.exists():
            return ""
        path = path.resolve()  # a link to a persistent volume stays a link: its target is set aside
        aside = path.with_name(path.name + ".reset")
        try:
            with self._save_lock:
                path.replace(aside)
        except OSError as exc:
            self.get_logger().error(f"cannot set {path} aside: {exc}; a restart would load it")
            return f"; cannot set {path} aside: {exc}"
        self.get_logger().info(f"reset: {path} set aside as {aside}")
        return f"; {path} set aside as {aside}"

    def _load_file(self) -> dict[str, Any]:
        path = self._path()
        if path is None or not path.exists():
            self.get_logger().info(f"no calibration file at {path}; starting uncalibrated")
            return {}
        try:
            cals = load_calibrations(path)
        except CalibrationFileError as exc:
            self.get_logger().error(f"refusing calibration file {path}: {exc}; starting UNCALIBRATED")
            return {}
        usable = {}
        for s, cal in cals.items():
            if s not in self._configs:
                continue
            why = _implausible(cal, s, self._configs[s])
            if why:
                self.get_logger().error(f"refusing the {s} calibration of {path}: {why}; the {s} starts UNCALIBRATED")
                continue
            if FORCED in cal.method:
                self.get_logger().warning(f"the {s} calibration of {path} is {cal.method!r}: loaded as given "
                                          "(margcal calibrate --force)")
            usable[s] = cal
        self.get_logger().info(f"loaded calibrations {sorted(usable)} from {path}")
        return usable

    def _load_validator(self) -> Any:
        """The validator named by ``validator_file``; None (the shipped one) when unset or untrustworthy."""
        name = str(self.get_parameter("validator_file").value)
        if not name:
            return None
        path = Path(name).expanduser()
        try:
            v = load_validator(path)
        except CalibrationFileError as exc:
            self.get_logger().error(f"refusing validator file {path}: {exc}; using the shipped validator")
            return None
        self.get_logger().info(f"validator {path}: inputs {list(v.inputs)}, threshold {v.threshold}")
        return v

    def _save(self) -> tuple[bool, str]:
        path = self._path()
        cals = {s: c for s, c in self._calibration.items() if c is not None}
        if path is None:
            return False, "calibration_file is empty (or names no home directory): persistence is off"
        if not cals:
            return False, "nothing to save: no sensor is calibrated"
        try:
            with self._save_lock:
                save_calibrations(path, cals, node=self.get_name())
        except OSError as exc:
            self.get_logger().error(f"cannot write {path}: {exc}")
            return False, f"cannot write {path}: {exc}"
        return True, f"saved {sorted(cals)} to {path}"

    # -- services ---------------------------------------------------------------------------------

    async def _ask_worker(self, kind: str, response: Trigger.Response) -> Trigger.Response:
        """Send a command to the worker and await its answer (the executor goes on serving samples meanwhile)."""
        future = Future()
        self._requests[self._worker.request(kind)] = (future, time.monotonic())
        response.success, response.message = await future
        return response

    async def _srv_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self._withheld.clear()
        for s in self._calibration:
            self._calibration[s] = None  # nothing more is published with the old calibration
        for s, traffic in self._traffic.items():
            traffic.forget_frames()
            # the worker forgets what it has seen; what is still queued here reaches it after the reset
            traffic.reset_base = traffic.received - sum(1 for b in self._batch if b[0] == s)
        aside = self._set_aside()
        response = await self._ask_worker("reset", response)
        response.message += aside
        return response

    def _srv_save(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self._save()
        return response

    async def _srv_refit(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        return await self._ask_worker("refit", response)

    # -- status -----------------------------------------------------------------------------------

    def _publish_markers(self, views: dict[str, Any]) -> None:
        """The worker's views as one MarkerArray, each sensor in its frame (RViz's fixed frame: the sensor's)."""
        if self._pub_markers is None:
            return
        out = MarkerArray()
        stamp = self.get_clock().now().to_msg()
        for s, view in sorted(views.items()):
            frame = self._traffic[s].frame or f"margcal_{s}"  # no message yet: a frame RViz can still be set to
            out.markers.extend(coverage_markers(view, Header(stamp=stamp, frame_id=frame)).markers)
        self._pub_markers.publish(out)

    def _publish_status(self) -> None:
        self._check_worker()
        if self._pub_markers is not None and self._pub_markers.get_subscription_count():
            self._worker.want_view()  # built in the worker only while someone looks: the answer comes to the pump
        now = time.monotonic()
        stale = float(self.get_parameter("stale_timeout_s").value)
        arr = DiagnosticArray(header=Header(stamp=self.get_clock().now().to_msg(), frame_id=""))
        for s, st in self._status.items():
            traffic = self._traffic[s]
            if traffic.last_rx is not None and now - traffic.last_rx > stale:
                st = replace(st, level=Level.STALE, message=f"no samples for {now - traffic.last_rx:.0f} s; {st.message}")
            warn = traffic.dropping(now, st)
            if now - traffic.other_frame_rx <= OTHER_FRAME_S:
                topic = "imu/mag" if s == "mag" else "imu/data_raw"
                others = ", ".join(f"{_shown(f)} ({n} messages)" for f, n in sorted(traffic.other_frames.items()))
                if traffic.other_more:
                    others += f" and {traffic.other_more} messages of further frames"
                warn = "; ".join(x for x in (warn, f"{topic} carries other frames than {traffic.frame!r}: {others}, "
                                             "ignored (one sensor per topic)") if x)
            if warn:
                st = replace(st, level=max(st.level, Level.WARN), message=f"{warn}; {st.message}")
            msg = status_to_diagnostic(st, DiagnosticStatus, KeyValue, level_encoder=_level_bytes,
                                       hardware_id=traffic.frame or "")
            ignored = sum(traffic.other_frames.values()) + traffic.other_more
            backlog = traffic.received - traffic.reset_base - ignored - st.samples_seen
            extra = [*traffic.values(traffic.tick(now)), *self._field_values(s), ("ignored_other_frames", str(ignored)),
                     ("worker_backlog", str(max(backlog, 0))),
                     ("worker_restarts", str(self._worker.restarts))]
            msg.values.extend(KeyValue(key=k, value=v) for k, v in extra)
            arr.status.append(msg)
        self._pub_status.publish(arr)
        if self.get_parameter("publish_diagnostics").value:
            self._pub_diag.publish(arr)

    def _field_values(self, s: str) -> list[tuple[str, str]]:
        """The magnetometer's ``field_model`` status value (which model field it is scaled to, or that none is) and
        ``imu_frame_id``, the frame of the Imu rates its mounting is found against (its own is ``hardware_id``)."""
        if s != "mag":
            return []
        field = self._configs[s].field_model() if s in self._configs else None
        return [("field_model", field.describe() if field is not None else
                 "none: no position (parameters latitude/longitude or gps/fix); norm from the data"),
                ("imu_frame_id", self._traffic["accel"].frame or "none seen")]


def main(args: list[str] | None = None) -> None:
    """Console entry point ``margcal_node`` (``ros2 run ros_margcal margcal_node``)."""
    use_venv_ament_prefix()
    rclpy.init(args=args)
    node = None
    executor = SingleThreadedExecutor()  # see the module docstring: Jazzy's MultiThreadedExecutor loses messages
    try:
        node = MargCalNode()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():
            raise
        # a SIGTERM or Ctrl-C while the node was being built: rclpy shut the context down under it
    finally:
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
