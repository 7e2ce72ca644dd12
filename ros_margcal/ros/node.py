"""The rclpy node (ROS 2 Jazzy): a thin shell around one ``SensorCalibrator`` per sensor.

Topics (defaults, all remappable; REP-145 names, REP-103 units):

- subscribes ``imu/data_raw`` (sensor_msgs/Imu) and ``imu/mag`` (sensor_msgs/MagneticField) with
  the sensor-data QoS profile (best effort: REP-2003 for consumers of raw sensor data; it matches
  reliable and best-effort drivers);
- publishes, reliable (the system default, REP-2003 for publishers, so default-QoS and sensor-data
  subscribers both receive), ``imu_calibrated/data_raw`` and ``imu_calibrated/mag`` (header
  unchanged, covariance ``W Σ Wᵀ``), ``/calib/status`` (diagnostic_msgs/DiagnosticArray, one status
  per sensor, every ``status_period_s``; also on ``/diagnostics`` when ``publish_diagnostics``), and the current
  calibration on ``/calib/mag`` and ``/calib/accel`` (std_msgs/String with the ``ros__parameters``
  YAML, transient-local so late joiners get it).

Services (std_srvs/Trigger): ``~/reset`` (forget samples and calibrations), ``~/save`` (write the
calibration file now), ``~/refit`` (validate and fit now; the validator and guard rails still decide).

Threads: the sample callbacks (conversion, stamp choice, gate, buffer insert, publishing the
calibrated message) run in one callback group per sensor; each ``SensorCalibrator`` defers its
evaluation (``defer_evaluation``), and a timer in a callback group of its own (every
``evaluation_period_s``) runs ``run_pending`` under the sensor's lock: the centre update and the
validator under it, the fit outside it on a snapshot, the new calibration swapped in under it.
Status and services use the default group. ``main`` spins a ``MultiThreadedExecutor`` with a
thread per group, so a fit never delays a sample callback, and a validation only the callbacks of
its own sensor; with a single-threaded executor the node works the same, only serially.

The magnetometer's gyro-aided fit (``gyro_aided``, ``model/fitting_gyro.py``) takes the angular rate of
the latest Imu message with each MagneticField message whose header stamp is within ``GYRO_PAIR_S`` of it
and whose ``frame_id`` is the same (the rate must be in the magnetometer's frame; with the accelerometer
disabled there is no Imu subscription and no rate).

Sample times come from the header stamp or the receive time (``stamp_source``: ``auto`` uses the
header stamp until it is zero or stops increasing, then the receive time, with one warning).

Parameters are declared with descriptors and ranges (defaults in ``msg_configs/margcal.yaml``,
float literals since rclpy types parameters strictly) and checked again as a whole
(``PipelineConfig.checked``) when set at run time. The calibration file is written atomically
(``save_calibrations``) after each accepted calibration and read at start; a corrupt or newer file
is refused with an error log line and the node starts uncalibrated.
"""

from __future__ import annotations

import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Imu, MagneticField
from std_msgs.msg import Header, String
from std_srvs.srv import Trigger

from ..model.calibration_file import load_calibrations, save_calibrations
from ..model.errors import CalibrationFileError, ConfigError
from ..stream.calibrator import SensorCalibrator
from ..stream.config import GYRO_PAIR_S, PipelineConfig
from ..stream.status import EventKind, Level
from ..validation.shipped import load_validator
from .messages import calibrate_imu, calibrate_mag, calibration_to_string, imu_to_numpy, mag_to_numpy, status_to_diagnostic
from .stamps import STAMP_SOURCES, StampSource

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
    "norm_min": (0.0, 1.0e3, "guard rail: smallest plausible field norm (tesla / m/s^2)"),
    "norm_max": (0.0, 1.0e4, "guard rail: largest plausible field norm (tesla / m/s^2)"),
    "not_worse_tolerance": (0.0, 1.0, "guard rail: allowed relative increase of the recent residual"),
    "max_parameter_std": (1e-4, 1.0, "guard rail: largest relative one-sigma parameter uncertainty"),
    "change_threshold": (0.001, 1.0, "median relative residual of recent samples that signals a changed sensor"),
    "change_min_duration_s": (0.0, 3600.0, "the change must persist this long before the buffer is rebuilt, s"),
    "outlier_threshold": (0.01, 10.0, "relative residual above which a sample is not buffered while calibrated"),
    "max_rate_hz": (1.0, 1.0e5, "samples closer than 1/max_rate_hz are a burst and dropped"),
    "max_offset": (0.0, 1.0e3, "guard rail: absolute |offset| limit (tesla / m/s^2), besides max_offset_ratio; 0.0 = none"),
    "max_heading_p95_deg": (0.01, 180.0, "partial calibration: largest predicted heading p95 at the tilt seen, deg"),
    "early_heading_p95_deg": (0.01, 180.0, "early fit on rich motion: largest predicted heading p95 at 30 deg tilt, deg"),
}
_BOOL_PARAMS: dict[str, str] = {
    "partial_fit": "fit what the motion makes observable (a ring or band) when the full validator refuses",
    "early_fit": "publish a first MAP fit on rich motion once its predicted heading error is small",
    "gyro_aided": "magnetometer: the Imu angular rate (same frame_id, stamps within 20 ms) joins the partial fit",
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


def _fdesc(lo: float, hi: float, text: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=text, read_only=read_only,
                               floating_point_range=[FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)])


def _idesc(lo: int, hi: int, text: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=text, read_only=read_only,
                               integer_range=[IntegerRange(from_value=int(lo), to_value=int(hi), step=1)])


def _level_bytes(level: int) -> bytes:
    """rclpy's DiagnosticStatus.level is a ``byte`` field: one-byte ``bytes``."""
    return bytes([int(level)])


class MargCalNode(Node):
    """Online magnetometer/accelerometer calibration node (see the module docstring)."""

    def __init__(self, node_name: str = "margcal", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        log = self.get_logger()
        self.declare_parameter("calibration_file", str(Path.home() / ".ros" / "margcal" / "calibration.yaml"),
                               ParameterDescriptor(description="calibration YAML, read at start, written atomically; '' = none"))
        self.declare_parameter("autosave", True, ParameterDescriptor(description="write the file after each new calibration"))
        self.declare_parameter("publish_uncalibrated", False,
                               ParameterDescriptor(description="publish raw values on the calibrated topics until calibrated"))
        self.declare_parameter("publish_diagnostics", False, ParameterDescriptor(description="also publish on /diagnostics"))
        self.declare_parameter("status_period_s", 1.0, _fdesc(0.05, 60.0, "period of /calib/status, s", read_only=True))
        self.declare_parameter("stale_timeout_s", 5.0, _fdesc(0.1, 3600.0, "no samples for this long -> STALE, s"))
        self.declare_parameter("validator_file", "", ParameterDescriptor(
            description="trained validator JSON (margcal train-validator); '' = the shipped one", read_only=True))
        self.declare_parameter("stamp_source", "auto", ParameterDescriptor(
            description="sample time: 'header' stamp, 'receive' time, or 'auto' (header, falling back to the receive "
                        "time for good when stamps are zero or not increasing)", read_only=True,
            additional_constraints="one of: " + ", ".join(STAMP_SOURCES)))
        self.declare_parameter("evaluation_period_s", 0.05, _fdesc(
            0.001, 10.0, "period of the worker that runs due validations and fits off the sample callbacks, s", read_only=True))

        self._publish_raw = bool(self.get_parameter("publish_uncalibrated").value)  # read per message: cached
        self._cals: dict[str, SensorCalibrator] = {}
        self._frame: dict[str, str] = dict.fromkeys(SENSORS, "")
        self._rate: tuple[float, str, Any] | None = None  # the latest Imu: stamp, frame_id, angular rate
        self._last_rx: dict[str, float] = {}
        self._locks = {s: threading.Lock() for s in SENSORS}
        self._save_lock = threading.Lock()  # autosave runs on the worker, save on a service
        mode = str(self.get_parameter("stamp_source").value)
        if mode not in STAMP_SOURCES:
            log.error(f"stamp_source {mode!r} is not one of {STAMP_SOURCES}; using 'auto'")
            mode = "auto"
        self._stamps = {"mag": StampSource(mode, "imu/mag"), "accel": StampSource(mode, "imu/data_raw")}
        loaded = self._load_file()
        validator = self._load_validator()
        latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._pub_cal: dict[str, Any] = {}
        for s in SENSORS:
            enabled = self.declare_parameter(f"{s}.enabled", True, ParameterDescriptor(description=f"calibrate the {s}")).value
            cfg = self._declare_sensor(s)
            if not enabled:
                continue
            self._cals[s] = SensorCalibrator(s, cfg, calibration=loaded.get(s), validator=validator)
            self._cals[s].defer_evaluation = True
            self._pub_cal[s] = self.create_publisher(String, f"/calib/{s}", latched)
        if "mag" in self._cals:
            self._pub_mag = self.create_publisher(MagneticField, "imu_calibrated/mag", OUTPUT_DEPTH)
            self.create_subscription(MagneticField, "imu/mag", self._on_mag, qos_profile_sensor_data,
                                     callback_group=MutuallyExclusiveCallbackGroup())
        if "accel" in self._cals:
            self._pub_imu = self.create_publisher(Imu, "imu_calibrated/data_raw", OUTPUT_DEPTH)
            self.create_subscription(Imu, "imu/data_raw", self._on_imu, qos_profile_sensor_data,
                                     callback_group=MutuallyExclusiveCallbackGroup())
        self._pub_status = self.create_publisher(DiagnosticArray, "/calib/status", 10)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_service(Trigger, "~/reset", self._srv_reset)
        self.create_service(Trigger, "~/save", self._srv_save)
        self.create_service(Trigger, "~/refit", self._srv_refit)
        self.add_on_set_parameters_callback(self._validate_parameters)
        # post-set callbacks (rclpy >= Iron) apply values only once they are set
        self._apply_in_validation = not hasattr(self, "add_post_set_parameters_callback")
        if not self._apply_in_validation:
            self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(float(self.get_parameter("status_period_s").value), self._publish_status)
        self._eval_group = MutuallyExclusiveCallbackGroup()
        self.create_timer(float(self.get_parameter("evaluation_period_s").value), self._run_pending,
                          callback_group=self._eval_group)
        for s, c in self._cals.items():
            if c.calibration is not None:
                self._pub_cal[s].publish(calibration_to_string(c.calibration, String, node=self.get_name()))
        log.info(f"margcal started: sensors {sorted(self._cals)}, calibrated {sorted(s for s in self._cals if s in loaded)}")

    @property
    def calibrators(self) -> dict[str, SensorCalibrator]:
        """The calibrator of each enabled sensor (read them; the node feeds them)."""
        return dict(self._cals)

    # -- parameters -------------------------------------------------------------------------------

    def _declare_sensor(self, s: str) -> PipelineConfig:
        base = PipelineConfig.for_sensor(s)
        for name, (lo, hi, text) in _FLOAT_PARAMS.items():
            default = getattr(base, name)
            self.declare_parameter(f"{s}.{name}", float(default or 0.0), _fdesc(lo, hi, text))
        for name, (lo, hi, text) in _INT_PARAMS.items():
            self.declare_parameter(f"{s}.{name}", int(getattr(base, name)), _idesc(lo, hi, text))
        for name, text in _BOOL_PARAMS.items():
            self.declare_parameter(f"{s}.{name}", bool(getattr(base, name)), ParameterDescriptor(description=text))
        for name, (lo, hi, text) in _READ_ONLY_INT.items():
            self.declare_parameter(f"{s}.{name}", int(getattr(base, name)), _idesc(lo, hi, text, read_only=True))
        if s == "accel":
            for name, (lo, hi, text) in _ACCEL_GATE.items():
                self.declare_parameter(f"{s}.{name}", float(getattr(base, name) or 0.0), _fdesc(lo, hi, text))
        return self._config_from(s, {})

    def _config_from(self, s: str, changed: dict[str, Any]) -> PipelineConfig:
        """The PipelineConfig of sensor ``s`` from the declared parameters, with ``changed`` applied."""
        base = PipelineConfig.for_sensor(s)
        names = [*_FLOAT_PARAMS, *_INT_PARAMS, *_BOOL_PARAMS, *_READ_ONLY_INT, *(_ACCEL_GATE if s == "accel" else ())]
        values: dict[str, Any] = {}
        for name in names:
            key = f"{s}.{name}"
            values[name] = changed[key] if key in changed else self.get_parameter(key).value
        for name in ("max_predicted_error", "gate_gyro_threshold", "max_offset"):
            if name in values and not values[name]:
                values[name] = None  # 0.0 = off / the validator's own threshold
        return replace(base, **values).checked()

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        changed = {p.name: p.value for p in params}
        if self._apply_in_validation and "publish_uncalibrated" in changed:
            self._publish_raw = bool(changed["publish_uncalibrated"])
        for s in self._cals:
            if any(k.startswith(f"{s}.") for k in changed):
                try:
                    self._config_from(s, changed)
                except ConfigError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
                if self._apply_in_validation:
                    with self._locks[s]:
                        self._cals[s].reconfigure(self._config_from(s, changed))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        self._publish_raw = bool(self.get_parameter("publish_uncalibrated").value)
        for s, cal in self._cals.items():
            if any(p.name.startswith(f"{s}.") for p in params):
                with self._locks[s]:
                    cal.reconfigure(self._config_from(s, {}))

    # -- data -------------------------------------------------------------------------------------

    def _on_mag(self, msg: MagneticField) -> None:
        t, v = mag_to_numpy(msg)
        rate = self._rate  # written by the Imu callback (another thread): one reference, read once
        gyro = rate[2] if (rate is not None and abs(t - rate[0]) <= GYRO_PAIR_S and rate[1] == msg.header.frame_id) else None
        cal = self._ingest("mag", t, v, gyro, msg.header.frame_id)
        if cal is not None or self._publish_raw:
            self._pub_mag.publish(calibrate_mag(msg, cal))

    def _on_imu(self, msg: Imu) -> None:
        t, acc, gyro = imu_to_numpy(msg)
        self._rate = (t, msg.header.frame_id, gyro)
        cal = self._ingest("accel", t, acc, gyro, msg.header.frame_id)
        if cal is not None or self._publish_raw:
            self._pub_imu.publish(calibrate_imu(msg, cal))

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _ingest(self, s: str, t: float, v: Any, gyro: Any, frame_id: str) -> Any:
        """Push one sample (the slow evaluation is only recorded); the calibration to publish it with."""
        self._frame[s] = frame_id
        self._last_rx[s] = time.monotonic()
        src = self._stamps[s]
        t = src.choose(t, self._now_s)
        if src.warning is not None:
            self.get_logger().warning(src.pop_warning() or "")
        c = self._cals[s]
        with self._locks[s]:
            events = c.push(t, v, gyro)
            cal = c.calibration
        for ev in events:
            self._handle(ev)
        return cal

    def _run_pending(self) -> None:
        """The worker: run the evaluations the sample callbacks recorded (validation and fit)."""
        for s, c in self._cals.items():
            if c.pending:
                for ev in c.run_pending(self._locks[s]):
                    self._handle(ev)

    def _handle(self, ev: Any) -> None:
        log = self.get_logger()
        if ev.kind is EventKind.CALIBRATED and ev.calibration is not None:
            log.info(f"{ev.sensor}: {ev.message}")
            self._pub_cal[ev.sensor].publish(calibration_to_string(ev.calibration, String, node=self.get_name()))
            if self.get_parameter("autosave").value:
                self._save()
        elif ev.kind is EventKind.CHANGED or (ev.kind is EventKind.REJECTED and self._cals[ev.sensor].calibration is None):
            log.warning(f"{ev.sensor}: {ev.message}")
        elif ev.kind is EventKind.REJECTED:
            log.info(f"{ev.sensor}: {ev.message} (keeping the current calibration)")
        else:
            log.debug(f"{ev.sensor}: {ev.message}")

    # -- persistence ------------------------------------------------------------------------------

    def _path(self) -> Path | None:
        p = str(self.get_parameter("calibration_file").value)
        return Path(p).expanduser() if p else None

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
        self.get_logger().info(f"loaded calibrations {sorted(cals)} from {path}")
        return cals

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
        cals = {s: c.calibration for s, c in self._cals.items() if c.calibration is not None}
        if path is None:
            return False, "calibration_file is empty: persistence is off"
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

    def _srv_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        for s, c in self._cals.items():
            with self._locks[s]:
                c.reset()
        response.success, response.message = True, f"reset {sorted(self._cals)}: collecting"
        return response

    def _srv_save(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self._save()
        return response

    def _srv_refit(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        messages, ok = [], False
        for s, c in self._cals.items():
            with self._locks[s]:
                events = c.refit()
                status = c.status().message
            for ev in events:
                self._handle(ev)
            done = [e for e in events if e.kind in (EventKind.CALIBRATED, EventKind.REJECTED)]
            ok = ok or any(e.kind is EventKind.CALIBRATED for e in done)
            messages.append(f"{s}: " + ("; ".join(e.message for e in done) or status))
        response.success, response.message = ok, " | ".join(messages)
        return response

    # -- status -----------------------------------------------------------------------------------

    def _publish_status(self) -> None:
        now = time.monotonic()
        stale = float(self.get_parameter("stale_timeout_s").value)
        arr = DiagnosticArray(header=Header(stamp=self.get_clock().now().to_msg(), frame_id=""))
        for s, c in self._cals.items():
            with self._locks[s]:
                st = c.status()
            if s in self._last_rx and now - self._last_rx[s] > stale:
                st = replace(st, level=Level.STALE, message=f"no samples for {now - self._last_rx[s]:.0f} s; {st.message}")
            arr.status.append(status_to_diagnostic(st, DiagnosticStatus, KeyValue, level_encoder=_level_bytes,
                                                   hardware_id=self._frame[s]))
        self._pub_status.publish(arr)
        if self.get_parameter("publish_diagnostics").value:
            self._pub_diag.publish(arr)


def main(args: list[str] | None = None) -> None:
    """Console entry point ``margcal_node`` (``ros2 run ros_margcal margcal_node``)."""
    rclpy.init(args=args)
    node = None
    executor = MultiThreadedExecutor(num_threads=4)  # a thread per callback group: mag, accel, worker, default
    try:
        node = MargCalNode()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
