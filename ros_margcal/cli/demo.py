"""``margcal demo``: the calibration node on a live ROS 2 graph, fed by a simulated IMU, its status shown live.

The package's main job end to end without hardware, in three processes:

- the node as users run it, ``python -m ros_margcal.ros.node --ros-args -p calibration_file:=<run dir>/calibration.yaml
  -p status_period_s:=0.5``, its log (stdout and stderr) in ``<run dir>/node.log``;
- the driver, this module run as a script (``python -m ros_margcal.cli.demo --seed N --duration S --truth FILE``):
  a simulated accelerometer with gyro on ``imu/data_raw`` (sensor_msgs/Imu) and magnetometer on ``imu/mag``
  (sensor_msgs/MagneticField) from ``ros_margcal.sim``, 100 Hz each in real time, reliable, header stamps from its
  clock, frame ``imu_link``. One tumbling motion drives both sensors: rests at random orientations (the
  accelerometer calibrates only from still poses) joined by quick turns (``MOTION``). It writes the true
  calibrations to ``<run dir>/truth.yaml`` and logs to ``<run dir>/driver.log``;
- this process: a node on ``/calib/status``, ``/calib/mag`` and ``/calib/accel`` that shows one block per sensor
  (state, message, samples, rate, coverage, predicted error, residual), redrawn in place on a terminal and
  printed every few seconds otherwise (``watch.Display``, shared with ``margcal watch``).

It stops when both sensors are calibrated (exit 0) or after ``--timeout`` seconds (exit 1, naming the sensor that
did not calibrate and its last status), then compares each calibration with the simulated truth. The children are
always terminated and waited for, also on Ctrl-C.

rclpy and the message packages are an optional dependency (a ROS 2 Jazzy from PyPI wheels or a sourced setup):
they are imported inside the functions that use them; without them the command exits 2 saying how to get them.
The children get this process's environment, with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless set already:
the simulated data stays on this machine. The node sets ``AMENT_PREFIX_PATH`` for pip-installed ROS itself
(``ros.environment.use_venv_ament_prefix`` in its ``main``); rclpy and the message types need no ament index here.
This module imports nothing of ``ros`` (tests/test_layout.py: the CLI stays off that layer), so the calibration
messages are read with ``model.calibration_file.calibration_from_yaml``, which is what
``ros.messages.calibration_from_string`` does.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..model.calibration import Calibration
from ..model.calibration_file import calibration_from_yaml, load_calibrations, save_calibrations
from ..model.errors import CalibrationFileError, ConfigError
from ..recordings.recording import Recording
from ..sim import simulation as sim
from .watch import Display, SensorView, format_block, update_views

__all__ = ["DEFAULT_SEED", "MOTION", "register", "run", "simulate_imu"]

SENSORS = ("mag", "accel")
DEFAULT_SEED = 7
RATE_HZ = 100.0
"""Rate of each simulated stream, Hz."""
STATUS_PERIOD_S = 0.5
STOP_S = 10.0
"""A child that has not ended this long after SIGTERM is killed, s."""
MOTION: dict[str, Any] = {"still_fraction": 0.75, "still_s": (1.2, 1.8), "max_rate_dps": 250.0}
"""The driver's tumbling: rests of 1.2-1.8 s and turns up to 250 deg/s (the simulator's default, 1.5-4 s and
150 deg/s, leaves the accelerometer uncalibrated for about 50 s; with these, about 30 s)."""
ROS_MISSING = ("margcal demo: error: rclpy is not importable: install the ROS extra (pip install -e '.[ros]') "
               "or source a ROS 2 Jazzy setup (source /opt/ros/jazzy/setup.bash)")


def _screen(views: dict[str, SensorView], elapsed: float, timeout: float) -> list[str]:
    lines = [f"margcal demo: {elapsed:.0f} s of {timeout:.0f} s"]
    for s in SENSORS:
        lines += format_block(s, views[s])
    return lines


# -- the driver process ------------------------------------------------------------------------------------------


def simulate_imu(seed: int, duration_s: float) -> tuple[Recording, Recording]:
    """The accelerometer (with gyro) and magnetometer recordings of one tumbling IMU, 100 Hz, truths drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    mag_truth, accel_truth = sim.random_sensor(rng, "mag"), sim.random_sensor(rng, "accel")
    motion = sim.tumbling_motion(duration_s, RATE_HZ, rng, **MOTION)
    return sim.tumbling(accel_truth, duration_s, RATE_HZ, rng, motion=motion), \
        sim.magnetometer_stream(mag_truth, duration_s, RATE_HZ, rng, motion=motion)


def drive(seed: int, duration_s: float, truth_path: Path) -> int:
    """The driver: write the truth, wait for the node, publish both streams in real time, print the counts sent."""
    # rclpy and the messages are an optional dependency (the ROS extra or a sourced ROS 2): imported where used
    import rclpy
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import Quaternion, Vector3
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import Imu, MagneticField
    from std_msgs.msg import Header

    imu, mag = simulate_imu(seed, duration_s)
    assert imu.truth is not None and mag.truth is not None and imu.gyro is not None  # the simulator sets them
    save_calibrations(truth_path, {"mag": mag.truth, "accel": imu.truth}, node="margcal_demo_driver")
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # the demo ends us with SIGTERM: leave through finally
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = Node("margcal_demo_driver")
    sent = [0, 0]
    try:
        qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
        pub_imu, pub_mag = node.create_publisher(Imu, "imu/data_raw", qos), node.create_publisher(MagneticField, "imu/mag", qos)
        end = time.monotonic() + 30.0
        while (pub_imu.get_subscription_count() == 0 or pub_mag.get_subscription_count() == 0) and time.monotonic() < end:
            time.sleep(0.05)
        print(f"subscribers: imu {pub_imu.get_subscription_count()}, mag {pub_mag.get_subscription_count()}", flush=True)
        zero9, no_orientation = [0.0] * 9, [-1.0] + [0.0] * 8

        def vec(x: Any) -> Any:
            return Vector3(x=float(x[0]), y=float(x[1]), z=float(x[2]))

        start = time.monotonic()
        for i, t in enumerate(imu.t):
            delay = start + float(t) - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            ns = node.get_clock().now().nanoseconds
            hdr = Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="imu_link")
            pub_imu.publish(Imu(header=hdr, orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                                orientation_covariance=no_orientation, angular_velocity=vec(imu.gyro[i]),
                                angular_velocity_covariance=zero9, linear_acceleration=vec(imu.raw[i]),
                                linear_acceleration_covariance=zero9))
            pub_mag.publish(MagneticField(header=hdr, magnetic_field=vec(mag.raw[i]), magnetic_field_covariance=zero9))
            sent[0] += 1
            sent[1] += 1
    except KeyboardInterrupt:
        pass
    finally:
        print(f"sent: imu {sent[0]}, mag {sent[1]}", flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


# -- the demo process --------------------------------------------------------------------------------------------


@dataclass
class _Outcome:
    views: dict[str, SensorView]
    cals: dict[str, Calibration]
    elapsed: float
    failure: str = ""


def _watch(children: dict[str, subprocess.Popen[bytes]], logs: dict[str, Path], timeout: float) -> _Outcome:
    """Show the status live until both sensors are calibrated, the time is up, or a child fails."""
    # rclpy and the messages are an optional dependency (the ROS extra or a sourced ROS 2): imported where used
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import String

    out = _Outcome({s: SensorView() for s in SENSORS}, {}, 0.0)
    start = time.monotonic()

    def on_status(msg: Any) -> None:
        update_views(out.views, msg, time.monotonic() - start, add=False)

    def on_calibration(s: str) -> Any:
        def take(msg: Any) -> None:
            try:
                out.cals[s] = calibration_from_yaml(msg.data, sensor=s)  # ros.messages.calibration_from_string's body
            except CalibrationFileError as exc:
                out.failure = f"the node published an unreadable /calib/{s}: {exc}"
        return take

    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)  # Ctrl-C: a KeyboardInterrupt here
    executor = SingleThreadedExecutor(context=context)
    node = None
    display = Display(sys.stdout)
    try:
        node = Node("margcal_demo_monitor", context=context)
        executor.add_node(node)
        latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(DiagnosticArray, "/calib/status", on_status, 10)
        for s in SENSORS:
            node.create_subscription(String, f"/calib/{s}", on_calibration(s), latched)
        while True:
            executor.spin_once(timeout_sec=0.1)
            out.elapsed = time.monotonic() - start
            display.show(_screen(out.views, out.elapsed, timeout), out.elapsed)
            if all(out.views[s].state == "calibrated" and s in out.cals for s in SENSORS) or out.elapsed > timeout \
                    or out.failure:
                break
            ended = {name: p.returncode for name, p in children.items() if p.poll() is not None}
            if "node" in ended or ended.get("driver", 0) != 0:
                name = "node" if "node" in ended else "driver"
                out.failure = f"the {name} ended with exit code {ended[name]}; see its log {logs[name]}"
                break
        display.show(_screen(out.views, out.elapsed, timeout), out.elapsed, force=True)
    finally:
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        context.try_shutdown()
    return out


def _stop(children: dict[str, subprocess.Popen[bytes]]) -> None:
    """Terminate every child and wait for it; one that does not end within ``STOP_S`` (or a second Ctrl-C) is killed."""
    for p in children.values():
        if p.poll() is None:
            p.terminate()
    deadline = time.monotonic() + STOP_S
    for p in children.values():
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except (subprocess.TimeoutExpired, KeyboardInterrupt):
            p.kill()
            p.wait()


def _compare(cal: Calibration, truth: Calibration) -> list[str]:
    """Offset error over the true norm; matrix error with both matrices scaled to a unit field (relative Frobenius)."""
    w, w_true = cal.matrix / cal.norm, truth.matrix / truth.norm
    off = float(np.linalg.norm(cal.offset - truth.offset) / truth.norm)
    mat = float(np.linalg.norm(w - w_true) / np.linalg.norm(w_true))
    vec = ", ".join(f"{x:.4g}" for x in cal.offset)
    true_vec = ", ".join(f"{x:.4g}" for x in truth.offset)
    return [f"  offset [{vec}] {cal.unit}, true [{true_vec}]: error {100 * off:.2f} % of the norm",
            f"  matrix error {100 * mat:.2f} % (relative, both scaled to a unit field)",
            f"  norm {cal.norm:.5g} {cal.unit}, true {truth.norm:.5g}"]


def _report(out: _Outcome, truth_path: Path, timeout: float) -> int:
    """Print each calibration against the truth; 0 when both sensors calibrated, 1 otherwise."""
    try:
        truth = load_calibrations(truth_path)
    except (CalibrationFileError, OSError) as exc:
        truth = {}
        print(f"no simulated truth to compare with ({exc})")
    print()
    missing = [s for s in SENSORS if out.views[s].state != "calibrated" or s not in out.cals]
    for s in SENSORS:
        view, cal = out.views[s], out.cals.get(s)
        when = "" if view.calibrated_at is None else f" after {view.calibrated_at:.1f} s ({view.calibrated_samples} samples)"
        print(f"{s}: {view.state}{when}\n  status: {view.message}")
        if cal is not None and s in truth:
            print("\n".join(_compare(cal, truth[s])))
    if out.failure:
        print(f"margcal demo: {out.failure}", file=sys.stderr)
        return 1
    if missing:
        for s in missing:
            print(f"margcal demo: {s} did not calibrate within {timeout:.0f} s; its last status ({out.views[s].state}): "
                  f"{out.views[s].message}", file=sys.stderr)
        return 1
    return 0


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _environment() -> dict[str, str]:
    """This process's environment for rclpy and the children, with discovery on this machine unless set."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return dict(os.environ)


def run(args: argparse.Namespace) -> int:
    """Entry of ``margcal demo``."""
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        msg = f"--timeout must be a positive number of seconds, got {args.timeout}"
        raise ConfigError(msg)
    try:
        import rclpy  # noqa: F401  # optional dependency (the ROS extra or a sourced ROS 2): only checked here
    except ImportError:
        print(ROS_MISSING, file=sys.stderr)
        return 2
    workdir: Path = args.workdir if args.workdir is not None else Path(tempfile.mkdtemp(prefix="margcal_demo_"))
    workdir.mkdir(parents=True, exist_ok=True)
    logs = {"node": workdir / "node.log", "driver": workdir / "driver.log"}
    truth_path, cal_path = workdir / "truth.yaml", workdir / "calibration.yaml"
    for stale in (truth_path, cal_path):
        stale.unlink(missing_ok=True)  # a file of an earlier run in the same --workdir would be loaded or compared
    env = _environment()
    commands = {
        "node": [sys.executable, "-m", "ros_margcal.ros.node", "--ros-args", "-p", f"calibration_file:={cal_path}",
                 "-p", f"status_period_s:={STATUS_PERIOD_S}"],
        "driver": [sys.executable, "-m", __name__, "--seed", str(args.seed), "--duration", str(args.timeout + 30.0),
                   "--truth", str(truth_path)],
    }
    print(f"margcal demo: seed {args.seed}, timeout {args.timeout:.0f} s; node log {logs['node']}, "
          f"driver log {logs['driver']}", flush=True)
    children: dict[str, subprocess.Popen[bytes]] = {}
    previous = signal.signal(signal.SIGTERM, _interrupt)  # a kill of the demo ends its children too
    try:
        for name, cmd in commands.items():
            with logs[name].open("wb") as log:
                children[name] = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env)
        out = _watch(children, logs, args.timeout)
    finally:
        _stop(children)
        signal.signal(signal.SIGTERM, previous)
    return _report(out, truth_path, args.timeout)


def register(subparsers: Any) -> None:
    """Add the ``demo`` subcommand."""
    p = subparsers.add_parser("demo", help="run the node on a live ROS 2 graph fed by a simulated IMU; show its status",
                              description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=DEFAULT_SEED, help=f"seed of the simulated IMU (default {DEFAULT_SEED})")
    p.add_argument("--timeout", type=float, default=90.0, help="give up after this many seconds (default 90)")
    p.add_argument("--workdir", type=Path, help="folder for the logs, the truth and the node's calibration file "
                   "(default: a new temporary folder, kept)")
    p.set_defaults(func=run)


def _driver_main(argv: list[str]) -> int:
    """``python -m ros_margcal.cli.demo``: the driver process of ``margcal demo``."""
    ap = argparse.ArgumentParser(prog="margcal demo driver", description=drive.__doc__)
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED)
    ap.add_argument("--duration", type=float, required=True, help="seconds of data")
    ap.add_argument("--truth", type=Path, required=True, help="where to write the true calibrations (YAML)")
    args = ap.parse_args(argv)
    return drive(args.seed, args.duration, args.truth)


if __name__ == "__main__":
    sys.exit(_driver_main(sys.argv[1:]))
