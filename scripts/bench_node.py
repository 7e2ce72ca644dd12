#!/usr/bin/env python3
"""Node benchmark for a ROS 2 Jazzy machine: the margcal node as users run it, under IMU and magnetometer streams.

    source /opt/ros/jazzy/setup.bash            # or a venv with the rclpy wheels (AMENT_PREFIX_PATH is set for it)
    python3 scripts/bench_node.py [--seconds 20] [--rates 100:100,400:100,1000:100] [--find-max]
                                  [--publish-uncalibrated] [--json figures.json]

Three processes besides this one, all started afresh for each rate:

- the node, exactly as users start it: ``python -m ros_margcal.ros.node --ros-args -p calibration_file:=''
  -p status_period_s:=0.5`` (its ``SingleThreadedExecutor``, its calibration worker process);
- a publisher (this script with ``--publisher``): simulated tumbling ``sensor_msgs/Imu`` (with the gyro) on
  ``imu/data_raw`` and ``sensor_msgs/MagneticField`` on ``imu/mag`` of one body (the gyro turns as the field
  does, as on a real MARG unit; seed 3), reliable, depth 100 (as REP-2003 asks of drivers), in real time (it
  sleeps until the next message is due and publishes everything due; it reports how late each message went out
  and its mean publish time), header stamps from the system clock; it starts once both the node and the counter
  subscribe (then 1 s more for the subscribers' side of discovery);
- a counter (this script with ``--counter``): a trivial rclpy node with best-effort depth-1000 subscriptions
  (the sensor-data profile, deeper) that counts ``imu/data_raw``, ``imu/mag``, ``imu_calibrated/data_raw`` and
  ``imu_calibrated/mag`` and keeps the node's ``/calib/status``; after the publisher ends it waits until the
  node's ``received`` stops changing and its ``worker_backlog`` is 0 (at most 3 s; ``stable`` says which) and
  prints its counts and the final status as JSON.

Printed, per rate (``IMU:mag`` Hz) and sensor (``accel``: the Imu topic): messages published, received by the
node (``received`` of the final status), taken by the calibrator in the worker (``samples_seen``), lost
(published - received) in messages and %, received by the counter, the calibrated messages the counter received
and their rate since the first one (published only once that sensor is calibrated), the node's sample callback
p50 and p99 (final status: the last 2000 callbacks; p99 the worst of all statuses) and max (over every status
of the run) in ms, and the final state. Per rate: the node's CPU (the whole process tree under the node's pid:
the node, the forkserver and the calibration worker; CPU time over the wall time while data flows, % of one
core), the worker's share of it, the counter's CPU the same way (the cost of a trivial Python subscriber on the
same streams, measured in the same run), the ratio node/counter, and how late the publisher ran.
``--find-max`` then raises the IMU rate (1000, 1500, 2000, 3000, 4000 Hz, magnetometer 100 Hz) until a run
loses messages and prints the highest rate without loss. The node's warnings and errors are printed after the
tables (its whole log then stays in a temporary file, named there), and CROSSTALK when the run heard another run on the
same ``ROS_DOMAIN_ID`` (a topic with more than one publisher, more messages received than published).

This motion calibrates the magnetometer after about 15-20 s and the accelerometer after about 35-45 s, so short
runs measure the node before it publishes ``imu_calibrated/*``; ``--publish-uncalibrated`` adds
``-p publish_uncalibrated:=true`` so that the node publishes them from the first message (its full per-message
path). ``--json`` writes every figure, with the node's CPU per thread, its CPU every 0.5 s and the series of
``received`` of each status (on the same monotonic clock as ``t0``, the publisher's start).

Without rclpy it says why and exits 0.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import IO, Any

import numpy as np

from ros_margcal.ros.environment import use_venv_ament_prefix

try:  # rclpy and the message packages exist only in a sourced ROS 2 environment (or a venv with the wheels)
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Quaternion
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, MagneticField
    from std_msgs.msg import Header
except ImportError as exc:
    rclpy = None  # type: ignore[assignment]
    MISSING = f"{exc}"
else:
    MISSING = ""

from ros_margcal.sim import simulation as sim
from ros_margcal.sim.motion import tumbling_motion

SENSORS = {"accel": ("imu/data_raw", "imu_calibrated/data_raw"), "mag": ("imu/mag", "imu_calibrated/mag")}
"""Sensor -> (input topic, calibrated output topic)."""
FIND_MAX_RATES = (1000, 1500, 2000, 3000, 4000)
"""IMU rates ``--find-max`` tries, Hz (magnetometer 100 Hz)."""
DISCOVERY_TIMEOUT_S = 60.0
"""The publisher gives up when the node and the counter do not subscribe within this long, s."""
SETTLE_S = 1.0
"""After the publishers see their subscribers, the subscribers' side of discovery gets this long, s."""
STABLE_TIMEOUT_S = 3.0
"""After the publisher ends, the counter waits at most this long for the node's ``received`` to stop changing
(and its ``worker_backlog`` to reach 0), s."""
NODE_CMD = ["-m", "ros_margcal.ros.node", "--ros-args", "-p", "calibration_file:=''", "-p", "status_period_s:=0.5"]
"""The node's command line after the interpreter (the ``''`` reaches rcl as an empty YAML string)."""
CLK_TCK = os.sysconf("SC_CLK_TCK")


# -- the publisher process ---------------------------------------------------------------------------------------


def publisher(seconds: float, imu_rate: float, mag_rate: float) -> int:
    """The publishing process: the simulated streams in real time; prints ``START`` when it starts, then JSON."""
    rng = np.random.default_rng(3)
    motion = tumbling_motion(seconds, max(imu_rate, mag_rate), rng)  # one body: the gyro turns as the field does
    imu = sim.tumbling(sim.random_sensor(rng, "accel"), seconds, imu_rate, rng, motion=motion)
    mag = sim.magnetometer_stream(sim.random_sensor(rng, "mag"), seconds, mag_rate, rng, motion=motion)
    assert imu.gyro is not None  # tumbling() simulates the gyro
    acc, gyr, mxyz = imu.raw.tolist(), imu.gyro.tolist(), mag.raw.tolist()
    times = np.concatenate([np.asarray(imu.t, float), np.asarray(mag.t, float)])
    kinds = np.concatenate([np.zeros(len(imu.t), int), np.ones(len(mag.t), int)])
    index = np.concatenate([np.arange(len(imu.t)), np.arange(len(mag.t))])
    order = np.lexsort((kinds, times))  # by due time, the Imu first at a tie
    due, kind, idx = (times[order] - times.min()).tolist(), kinds[order].tolist(), index[order].tolist()

    use_venv_ament_prefix()
    rclpy.init()
    node = Node("margcal_bench_publisher")
    try:
        pub_imu = node.create_publisher(Imu, "imu/data_raw", 100)
        pub_mag = node.create_publisher(MagneticField, "imu/mag", 100)
        end = time.monotonic() + DISCOVERY_TIMEOUT_S
        while pub_imu.get_subscription_count() < 2 or pub_mag.get_subscription_count() < 2:
            if time.monotonic() > end:
                print(json.dumps({"error": f"subscribers after {DISCOVERY_TIMEOUT_S:.0f} s: imu/data_raw "
                                           f"{pub_imu.get_subscription_count()}, imu/mag {pub_mag.get_subscription_count()}"
                                           " (want 2: the node and the counter)"}), flush=True)
                return 1
            time.sleep(0.02)
        time.sleep(SETTLE_S)
        zero9 = [0.0] * 9
        imsg = Imu(header=Header(frame_id="imu_link"), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                   orientation_covariance=[-1.0, *[0.0] * 8], angular_velocity_covariance=zero9,
                   linear_acceleration_covariance=zero9)
        mmsg = MagneticField(header=Header(frame_id="imu_link"), magnetic_field_covariance=zero9)
        ia, ig, im, mf = imsg.linear_acceleration, imsg.angular_velocity, imsg.header.stamp, mmsg.magnetic_field
        ms = mmsg.header.stamp
        late = np.empty(len(due))  # when each message went out after its due time, s
        sent = [0, 0]
        wakeups, busy = 0, 0.0
        n, i = len(due), 0
        print("START", flush=True)
        start = time.monotonic()
        while i < n:
            now = time.monotonic() - start
            if due[i] > now:
                time.sleep(due[i] - now)
                continue
            wakeups += 1
            while i < n and due[i] <= now:  # everything due
                late[i] = time.monotonic() - start - due[i]
                stamp = time.time_ns()
                if kind[i] == 0:
                    a, g = acc[idx[i]], gyr[idx[i]]
                    im.sec, im.nanosec = stamp // 1_000_000_000, stamp % 1_000_000_000
                    ia.x, ia.y, ia.z = a
                    ig.x, ig.y, ig.z = g
                    pub_imu.publish(imsg)
                else:
                    ms.sec, ms.nanosec = stamp // 1_000_000_000, stamp % 1_000_000_000
                    mf.x, mf.y, mf.z = mxyz[idx[i]]
                    pub_mag.publish(mmsg)
                busy += time.monotonic() - start - due[i] - late[i]
                sent[kind[i]] += 1
                i += 1
        wall = time.monotonic() - start
        print(json.dumps({"imu": sent[0], "mag": sent[1], "wall_s": wall, "span_s": due[-1], "wakeups": wakeups,
                          "publish_us": busy / max(n, 1) * 1e6,
                          "late_mean_ms": float(late.mean() * 1e3), "late_p99_ms": float(np.percentile(late, 99) * 1e3),
                          "late_max_ms": float(late.max() * 1e3), "late_end_ms": float(late[-1] * 1e3)}), flush=True)
        time.sleep(1.0)  # a best-effort writer destroyed at once drops its last burst in transit; a driver runs on
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


# -- the counter process -----------------------------------------------------------------------------------------


def _parse_status(msg: Any) -> dict[str, dict[str, Any]]:
    """A DiagnosticArray of the node -> sensor -> {key: value, "level": int, "message": str}."""
    out: dict[str, dict[str, Any]] = {}
    for st in msg.status:
        name = str(st.name)
        sensor = name.split(":", 1)[1].strip() if name.startswith("margcal:") else name
        level = st.level[0] if isinstance(st.level, bytes | bytearray) else int(st.level)
        out[sensor] = {"level": int(level), "message": str(st.message), **{kv.key: kv.value for kv in st.values}}
    return out


def _float(text: Any) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return float("nan")


def counter() -> int:
    """The counting process: count the four streams and keep the node's status until ``stop`` on stdin; print JSON."""
    use_venv_ament_prefix()
    rclpy.init()
    node = Node("margcal_bench_counter")
    executor = SingleThreadedExecutor()
    try:
        qos = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)  # qos_profile_sensor_data, depth 1000
        counts: dict[str, int] = {}
        first: dict[str, float] = {}
        last: dict[str, float] = {}

        def make_counter(topic: str) -> Any:
            counts[topic] = 0

            def cb(_msg: Any) -> None:
                now = time.monotonic()
                if not counts[topic]:
                    first[topic] = now
                counts[topic] += 1
                last[topic] = now

            return cb

        for topic, cls in (("imu/data_raw", Imu), ("imu/mag", MagneticField), ("imu_calibrated/data_raw", Imu),
                           ("imu_calibrated/mag", MagneticField)):
            node.create_subscription(cls, topic, make_counter(topic), qos)
        statuses: list[dict[str, dict[str, Any]]] = []
        series: list[list[Any]] = []  # (monotonic time, {sensor: received}) of each status
        worst: dict[str, dict[str, float]] = {}
        publishers: dict[str, int] = {}  # the most publishers seen on each topic: more than 1 = another run's

        def on_status(msg: Any) -> None:
            for topic in (*counts, "/calib/status"):
                publishers[topic] = max(publishers.get(topic, 0), node.count_publishers(topic))
            st = _parse_status(msg)
            statuses.append(st)
            series.append([time.monotonic(), {s: kv.get("received") for s, kv in st.items()}])
            for s, kv in st.items():
                w = worst.setdefault(s, {"callback_max_ms": 0.0, "callback_p99_ms": 0.0})
                for key in w:
                    v = _float(kv.get(key))
                    if v == v:  # not NaN
                        w[key] = max(w[key], v)

        node.create_subscription(DiagnosticArray, "/calib/status", on_status, 10)
        stop = threading.Event()

        def read_stdin() -> None:
            for line in sys.stdin:
                if line.strip() == "stop":
                    break
            stop.set()

        threading.Thread(target=read_stdin, daemon=True).start()
        executor.add_node(node)
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
        stopped, seen = time.monotonic(), len(statuses)
        stable = False
        while time.monotonic() - stopped < STABLE_TIMEOUT_S:  # until the node's `received` stops changing
            executor.spin_once(timeout_sec=0.05)  # (and the worker took them all: its status lags the node's)
            if len(statuses) > seen and len(statuses) >= 2:
                rx = [{s: kv.get("received") for s, kv in st.items()} for st in statuses[-2:]]
                if rx[0] == rx[1] and all(kv.get("worker_backlog") == "0" for kv in statuses[-1].values()):
                    stable = True
                    break
        rates = {t: (counts[t] - 1) / (last[t] - first[t]) if counts[t] > 1 and last[t] > first[t] else 0.0 for t in counts}
        print(json.dumps({"counts": counts, "rate_hz": rates, "status": statuses[-1] if statuses else {},
                          "statuses": len(statuses), "worst": worst, "stable": stable, "series": series,
                          "publishers": publishers}), flush=True)
        return 0
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


# -- the benchmark: processes, CPU ---------------------------------------------------------------------------------


def _stat(pid: int) -> tuple[int, int, int] | None:
    """(ppid, utime + stime in ticks, start time) of ``pid`` from /proc; None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    rest = text[text.rindex(")") + 2:].split()  # after "pid (comm) ": state ppid ... utime(11) stime(12) ... starttime(19)
    return int(rest[1]), int(rest[11]) + int(rest[12]), int(rest[19])


def process_tree(root: int) -> dict[int, tuple[int, int]]:
    """pid -> (CPU ticks, start time) of ``root`` and every descendant (a scan of /proc by ppid)."""
    children: dict[int, list[int]] = {}
    info: dict[int, tuple[int, int]] = {}
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            st = _stat(int(entry.name))
            if st is not None:
                children.setdefault(st[0], []).append(int(entry.name))
                info[int(entry.name)] = (st[1], st[2])
    out: dict[int, tuple[int, int]] = {}
    todo = [root]
    while todo:
        pid = todo.pop()
        if pid in info:
            out[pid] = info[pid]
            todo.extend(children.get(pid, []))
    return out


def _threads(pid: int) -> dict[str, float]:
    """CPU seconds of the threads of ``pid`` by thread name (``/proc/<pid>/task``; threads of one name summed)."""
    out: dict[str, float] = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            text = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
        except OSError:
            continue
        name = "main" if tid == str(pid) else text[text.index("(") + 1:text.rindex(")")]
        rest = text[text.rindex(")") + 2:].split()
        out[name] = out.get(name, 0.0) + (int(rest[11]) + int(rest[12])) / CLK_TCK
    return out


def _cpu(root: int) -> tuple[float, float]:
    """(CPU seconds of the whole tree under ``root``, of its descendants only)."""
    tree = process_tree(root)
    total = sum(t for t, _ in tree.values())
    own = tree.get(root, (0, 0))[0]
    return total / CLK_TCK, (total - own) / CLK_TCK


class Lines:
    """The lines a child writes to a pipe, read by a thread (a read with a timeout)."""

    def __init__(self, pipe: IO[str]) -> None:
        self._q: queue.Queue[str | None] = queue.Queue()
        self._thread = threading.Thread(target=self._read, args=(pipe,), daemon=True)
        self._thread.start()

    def _read(self, pipe: IO[str]) -> None:
        for line in pipe:
            self._q.put(line.rstrip("\n"))
        self._q.put(None)

    def next(self, timeout_s: float) -> str | None:
        """The next line; None at the end of the pipe or after ``timeout_s``."""
        try:
            return self._q.get(timeout=timeout_s)
        except queue.Empty:
            return None


def _end(proc: subprocess.Popen[Any] | None, grace_s: float = 0.0, wait_s: float = 10.0) -> None:
    """End a child we started: ``grace_s`` to end by itself, then SIGINT (a clean ROS shutdown), SIGTERM, SIGKILL;
    then any process of its tree that outlived it (the node's worker and forkserver), by pid and start time."""
    if proc is None:
        return
    tree = process_tree(proc.pid)
    try:
        proc.wait(grace_s)
    except subprocess.TimeoutExpired:
        pass
    for sig, wait in ((signal.SIGINT, wait_s), (signal.SIGTERM, 3.0), (signal.SIGKILL, 3.0)):
        if proc.poll() is not None:
            break
        proc.send_signal(sig)
        try:
            proc.wait(wait)
        except subprocess.TimeoutExpired:
            pass
    deadline = time.monotonic() + 3.0
    for pid, (_, started) in tree.items():
        while pid != proc.pid and (st := _stat(pid)) is not None and st[2] == started:
            if time.monotonic() > deadline:
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
                break
            time.sleep(0.05)


def run(seconds: float, imu_rate: float, mag_rate: float, node_cmd: list[str]) -> dict[str, Any]:
    """One run: the node (``node_cmd`` after the interpreter), the counter and the publisher in processes of their
    own; the figures as a dict."""
    here = str(Path(__file__).resolve())
    log = tempfile.NamedTemporaryFile("w+", prefix="margcal_bench_node_", suffix=".log", delete=False)
    node = cnt = pub = None
    out: dict[str, Any] = {"imu_rate": imu_rate, "mag_rate": mag_rate, "log": log.name}
    t_start = time.monotonic()
    try:
        node = subprocess.Popen([sys.executable, *node_cmd], stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        cnt = subprocess.Popen([sys.executable, here, "--counter"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        pub = subprocess.Popen([sys.executable, here, "--publisher", "--seconds", str(seconds), "--imu-rate", str(imu_rate),
                                "--mag-rate", str(mag_rate)], stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)
        assert cnt.stdout is not None and pub.stdout is not None and cnt.stdin is not None
        pub_lines, cnt_lines = Lines(pub.stdout), Lines(cnt.stdout)
        line = pub_lines.next(DISCOVERY_TIMEOUT_S + 30.0)
        if line != "START":
            out["error"] = f"the publisher did not start: {line!r} (exit code {pub.poll()}); node log {log.name}"
            return out
        wall0, (node0, worker0), (cnt0, _), thr0 = time.monotonic(), _cpu(node.pid), _cpu(cnt.pid), _threads(node.pid)
        out["cpu_series"] = series = []  # (time, node tree CPU s, node main thread CPU s, counter CPU s)
        sampling = threading.Event()

        def sample() -> None:
            while not sampling.wait(0.5):
                series.append([time.monotonic(), _cpu(node.pid)[0], _threads(node.pid).get("main", 0.0), _cpu(cnt.pid)[0]])

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        line = pub_lines.next(seconds + 60.0)
        sampling.set()
        sampler.join()
        wall1, (node1, worker1), (cnt1, _), thr1 = time.monotonic(), _cpu(node.pid), _cpu(cnt.pid), _threads(node.pid)
        out["t0"] = wall0  # the counter's status series is on the same (system-wide monotonic) clock
        out["node_threads"] = {name: 100 * (v - thr0.get(name, 0.0)) / (wall1 - wall0) for name, v in thr1.items()}
        if line is None or not line.startswith("{"):
            out["error"] = f"the publisher ended without its counts: {line!r} (exit code {pub.poll()})"
            return out
        out["pub"] = json.loads(line)
        wall = wall1 - wall0
        out["cpu"] = {"wall_s": wall, "node": 100 * (node1 - node0) / wall, "worker": 100 * (worker1 - worker0) / wall,
                      "counter": 100 * (cnt1 - cnt0) / wall}
        cnt.stdin.write("stop\n")
        cnt.stdin.flush()
        line = cnt_lines.next(STABLE_TIMEOUT_S + 20.0)
        if line is None or not line.startswith("{"):
            out["error"] = f"the counter ended without its counts: {line!r} (exit code {cnt.poll()})"
            return out
        out["counter"] = json.loads(line)
        out["node_alive"] = node.poll() is None
        return out
    finally:
        _end(pub, grace_s=5.0)  # both end by themselves once they printed
        _end(cnt, grace_s=5.0)
        _end(node)
        log.close()
        out["run_s"] = time.monotonic() - t_start
        try:
            text = Path(log.name).read_text(errors="replace").splitlines()
        except OSError:
            text = []
        out["log_problems"] = [ln for ln in text if "[WARN]" in ln or "[ERROR]" in ln or "Traceback" in ln]
        out["log_calibrated"] = [ln for ln in text if "calibrated" in ln.lower() and "[INFO]" in ln]
        if not out["log_problems"] and "error" not in out:
            Path(log.name).unlink(missing_ok=True)  # kept only when it has something to say
            out["log"] = ""


def crosstalk(r: dict[str, Any]) -> str:
    """Why the run heard another run (more than one publisher on a topic, or more received than published), or ''."""
    if "counter" not in r:
        return ""
    extra = {t: n for t, n in r["counter"].get("publishers", {}).items() if n > 1}
    more = [s for s in SENSORS if _lost(r, s) < 0]
    if not extra and not more:
        return ""
    return (f"another run on ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}: publishers {extra or '-'}, "
            f"more received than published: {more or '-'}; this run's figures are void")


def _lost(r: dict[str, Any], sensor: str) -> int:
    pub = r["pub"]["imu" if sensor == "accel" else "mag"]
    return pub - int(r["counter"]["status"].get(sensor, {}).get("received", 0))


def sensor_rows(r: dict[str, Any]) -> list[str]:
    """The per-sensor table rows of one run."""
    rows = []
    rate = f"{r['imu_rate']:.0f}:{r['mag_rate']:.0f}"
    for sensor, (topic, out_topic) in SENSORS.items():
        published = r["pub"]["imu" if sensor == "accel" else "mag"]
        st = r["counter"]["status"].get(sensor, {})
        worst = r["counter"]["worst"].get(sensor, {})
        lost = _lost(r, sensor)
        n_out = r["counter"]["counts"][out_topic]
        rows.append(f"{rate:>9s} {sensor:>6s} {published:>9d} {st.get('received', '?'):>8s} {st.get('samples_seen', '?'):>10s} "
                    f"{lost:>6d} {100 * lost / max(published, 1):>6.2f} {r['counter']['counts'][topic]:>8d} {n_out:>8d} "
                    f"{r['counter']['rate_hz'][out_topic]:>7.1f} {_float(st.get('callback_p50_ms')):>7.3f} "
                    f"{worst.get('callback_p99_ms', float('nan')):>7.3f} {worst.get('callback_max_ms', float('nan')):>8.2f} "
                    f"{st.get('worker_backlog', '?'):>7s}  {st.get('state', '?')}")
    return rows


SENSOR_HEADER = (f"{'IMU:mag':>9s} {'sensor':>6s} {'published':>9s} {'node rx':>8s} {'calibrator':>10s} {'lost':>6s} "
                 f"{'lost %':>6s} {'counter':>8s} {'cal out':>8s} {'out Hz':>7s} {'cb p50':>7s} {'cb p99':>7s} "
                 f"{'cb max':>8s} {'backlog':>7s}  state")


def run_row(r: dict[str, Any]) -> str:
    """The per-run table row (CPU, publisher timing)."""
    c, p = r["cpu"], r["pub"]
    ratio = c["node"] / c["counter"] if c["counter"] > 0 else float("nan")
    return (f"{r['imu_rate']:.0f}:{r['mag_rate']:.0f}".rjust(9) + f" {c['wall_s']:>6.1f} {c['node']:>7.1f} {c['worker']:>7.1f} "
            f"{c['counter']:>8.1f} {ratio:>6.2f} {p['late_mean_ms']:>8.3f} {p['late_p99_ms']:>8.3f} {p['late_max_ms']:>8.2f} "
            f"{p['late_end_ms']:>8.2f} {p['publish_us']:>6.0f} {r['counter']['statuses']:>8d} "
            f"{'yes' if r['counter']['stable'] else 'no':>6s} {r['run_s']:>6.1f}")


RUN_HEADER = (f"{'IMU:mag':>9s} {'wall s':>6s} {'node %':>7s} {'worker':>7s} {'counter%':>8s} {'ratio':>6s} "
              f"{'late avg':>8s} {'late p99':>8s} {'late max':>8s} {'late end':>8s} {'pub us':>6s} {'statuses':>8s} "
              f"{'stable':>6s} {'run s':>6s}")


def print_tables(results: list[dict[str, Any]]) -> None:
    """The two tables of the runs that completed; the node's warnings and errors per run."""
    ok = [r for r in results if "counter" in r]
    print("\nper sensor (accel = the Imu topic; cb = the node's sample callback, ms; cal out = imu_calibrated/* received by "
          "the counter, out Hz its rate since the first one):")
    print(SENSOR_HEADER)
    for r in ok:
        print("\n".join(sensor_rows(r)))
    print("\nper run (CPU in % of one core over the wall time while the data flows; node = the node's whole process tree, "
          "worker = the worker's part of it; ratio = node / counter; publisher lateness, ms):")
    print(RUN_HEADER)
    for r in ok:
        print(run_row(r))
    for r in results:
        rate = f"{r['imu_rate']:.0f}:{r['mag_rate']:.0f}"
        if "error" in r:
            print(f"{rate}: FAILED: {r['error']}")
        if crosstalk(r):
            print(f"{rate}: CROSSTALK: {crosstalk(r)}")
        if "counter" in r and not r["counter"]["statuses"]:
            print(f"{rate}: no /calib/status came from the node: its figures are '?' (log {r['log']})")
        if r.get("node_alive") is False:
            print(f"{rate}: the node had ended before the run was over (log {r['log']})")
        for ln in r.get("log_problems", [])[:5]:
            print(f"{rate}: node log: {ln[:200]}")
        if len(r.get("log_problems", [])) > 5:
            print(f"{rate}: ... {len(r['log_problems']) - 5} more warnings/errors in {r['log']}")


def _rates(text: str) -> list[tuple[float, float]]:
    out = []
    for item in text.split(","):
        imu, _, mag = item.strip().partition(":")
        out.append((float(imu), float(mag or 100.0)))
    return out


def _progress(r: dict[str, Any]) -> None:
    rate = f"{r['imu_rate']:.0f}:{r['mag_rate']:.0f} Hz"
    if "counter" not in r:
        print(f"  {rate}: failed ({r.get('error')}), {r['run_s']:.0f} s", flush=True)
        return
    lost = {s: _lost(r, s) for s in SENSORS}
    print(f"  {rate}: lost accel {lost['accel']}, mag {lost['mag']}; node CPU {r['cpu']['node']:.1f} %, "
          f"counter {r['cpu']['counter']:.1f} %; {r['run_s']:.0f} s" + (" (CROSSTALK: void)" if crosstalk(r) else ""),
          flush=True)


def bench(seconds: float, rates: list[tuple[float, float]], find_max: bool, publish_uncalibrated: bool = False,
          json_path: str = "") -> int:
    """Run every rate (and ``--find-max``); print the tables."""
    node_cmd = [*NODE_CMD, "-p", "publish_uncalibrated:=true"] if publish_uncalibrated else NODE_CMD
    print(f"node benchmark: {seconds:g} s per rate; node `{Path(sys.executable).name} {' '.join(node_cmd)}`, "
          f"publisher and counter in processes of their own; {os.cpu_count()} CPUs", flush=True)
    t0 = time.monotonic()
    results: list[dict[str, Any]] = []
    found: list[dict[str, Any]] = []
    for imu_rate, mag_rate in rates:
        results.append(run(seconds, imu_rate, mag_rate, node_cmd))
        _progress(results[-1])
    print_tables(results)
    if find_max:
        print(f"\nfind-max: IMU rates {', '.join(str(r) for r in FIND_MAX_RATES)} Hz with the magnetometer at 100 Hz, "
              "until a run loses messages", flush=True)
        best: float | None = None
        for imu_rate in FIND_MAX_RATES:
            r = run(seconds, float(imu_rate), 100.0, node_cmd)
            found.append(r)
            _progress(r)
            if "counter" not in r or crosstalk(r) or any(_lost(r, s) > 0 for s in SENSORS):
                break
            best = float(imu_rate)
        print_tables(found)
        top = found[-1]
        if "pub" in top and top["pub"]["late_end_ms"] > 0.1 * seconds * 1e3:
            print(f"note: the publisher ended {top['pub']['late_end_ms'] / 1e3:.1f} s late at {top['imu_rate']:.0f} Hz: "
                  "it could not keep the rate")
        if crosstalk(top):
            print("note: the last run heard another run (CROSSTALK): the search stopped there")
        print("highest IMU rate without loss: " + ("none of them" if best is None else f"{best:.0f} Hz")
              + (" (the highest tried)" if best == FIND_MAX_RATES[-1] else ""))
    if json_path:
        Path(json_path).write_text(json.dumps({"seconds": seconds, "node_cmd": node_cmd, "runs": results,
                                               "find_max": found}, indent=1))
    print(f"\ntotal {time.monotonic() - t0:.0f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point: the benchmark, or (hidden flags) the publishing or the counting process."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="how long each run publishes, s (default 20)")
    ap.add_argument("--rates", default="100:100,400:100,1000:100", help="IMU:mag rates in Hz, comma-separated "
                    "(default 100:100,400:100,1000:100)")
    ap.add_argument("--find-max", action="store_true", help="then raise the IMU rate until messages are lost")
    ap.add_argument("--json", default="", help="also write every figure of every run (and the status series) here")
    ap.add_argument("--publish-uncalibrated", action="store_true", help="also pass -p publish_uncalibrated:=true: the "
                    "node publishes imu_calibrated/* from the first message (its full per-message path)")
    ap.add_argument("--publisher", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--counter", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--imu-rate", type=float, default=1000.0, help=argparse.SUPPRESS)  # the publisher's
    ap.add_argument("--mag-rate", type=float, default=100.0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if rclpy is None:
        print(f"bench_node: skipped: rclpy is not importable ({MISSING}); source a ROS 2 Jazzy setup "
              "(source /opt/ros/jazzy/setup.bash) and build or install ros_margcal there")
        return 0
    if args.publisher:
        return publisher(args.seconds, args.imu_rate, args.mag_rate)
    if args.counter:
        return counter()
    return bench(args.seconds, _rates(args.rates), args.find_max, args.publish_uncalibrated, args.json)


if __name__ == "__main__":
    sys.exit(main())
