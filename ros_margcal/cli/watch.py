"""``margcal watch``: a running node's ``/calib/status`` in the terminal, one block per sensor, refreshing.

The live status of ``margcal demo`` for any node (a robot's, a bag replayed with ``ros2 bag play``): state,
message, samples and rate, coverage, predicted error and residual per sensor, redrawn in place on a terminal
and printed every ``PLAIN_REFRESH_S`` seconds otherwise. Ends on Ctrl-C (exit 0), after ``--duration`` seconds,
or with ``--once`` after the first status (exit 1 when none came within ``--timeout``).

rclpy and diagnostic_msgs are an optional dependency (the ROS extra or a sourced ROS 2 Jazzy): imported where
used; without them the command exits 2 saying how to get them. This module imports nothing of ``ros``
(tests/test_layout.py: the CLI stays off that layer).
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from typing import Any, TextIO

from ..model.errors import ConfigError

__all__ = ["Display", "SensorView", "format_block", "register", "run", "update_views"]

TTY_REFRESH_S = 0.5
PLAIN_REFRESH_S = 5.0
"""Without a terminal, the screen is printed this often, s."""
ROS_MISSING = ("rclpy is not importable: install the ROS extra (pip install -e '.[ros]') "
               "or source a ROS 2 Jazzy setup (source /opt/ros/jazzy/setup.bash)")
_LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


@dataclass
class SensorView:
    """The last status of one sensor from ``/calib/status``; when it was first calibrated (watch time, s) and
    the samples it had seen then."""

    level: int = -1
    message: str = "waiting for /calib/status"
    values: dict[str, str] = field(default_factory=dict)
    calibrated_at: float | None = None
    calibrated_samples: str = ""

    @property
    def state(self) -> str:
        """The ``state`` value (collecting, ready, calibrated, rejected), ``-`` before the first status."""
        return self.values.get("state", "-")


def update_views(views: dict[str, SensorView], msg: Any, elapsed: float, *, add: bool = True) -> None:
    """Take one DiagnosticArray of ``/calib/status`` into ``views`` (per sensor; new sensors too when ``add``)."""
    for st in msg.status:
        s = st.name.removeprefix("margcal: ")
        if s not in views and not add:
            continue
        level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
        old = views.get(s, SensorView())
        view = SensorView(level, st.message, {kv.key: kv.value for kv in st.values}, old.calibrated_at,
                          old.calibrated_samples)
        if view.state == "calibrated" and view.calibrated_at is None:
            view.calibrated_at = elapsed
            view.calibrated_samples = view.values.get("samples_seen", "")
        views[s] = view


def _percent(text: str | None, digits: int) -> str:
    try:
        x = float(text or "")
    except ValueError:
        return "-"
    return f"{100 * x:.{digits}f} %" if math.isfinite(x) else "-"


def format_block(sensor: str, view: SensorView) -> list[str]:
    """The three lines of one sensor's status (pure: the live view and the plain printout both use it)."""
    v = view.values
    return [f"{sensor:<6s}{view.state:<11s} {_LEVELS.get(view.level, '-'):<5s} {view.message}",
            f"      samples {v.get('samples_seen') or '-'} (received {v.get('received') or '-'}, "
            f"{v.get('rate_hz') or '-'} Hz), coverage {_percent(v.get('coverage'), 0)}",
            f"      predicted error {_percent(v.get('predicted_error'), 2)}, residual {_percent(v.get('residual'), 3)}"]


class Display:
    """Redraws the screen in place on a terminal (ANSI cursor moves); otherwise prints it every few seconds."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.tty = out.isatty()
        self.drawn = 0
        self.last = -math.inf

    def show(self, lines: list[str], now: float, *, force: bool = False) -> None:
        """Draw ``lines`` unless the last draw is more recent than the refresh period (``force``: always)."""
        if not force and now - self.last < (TTY_REFRESH_S if self.tty else PLAIN_REFRESH_S):
            return
        self.last = now
        if self.tty:
            width = max(20, shutil.get_terminal_size().columns - 1)  # no wrapped line: the cursor moves count lines
            up = f"\x1b[{self.drawn}F" if self.drawn else ""
            self.out.write(up + "".join(f"\x1b[2K{line[:width]}\n" for line in lines))
        else:
            self.out.write(("\n" if self.drawn else "") + "\n".join(lines) + "\n")
        self.drawn = len(lines)
        self.out.flush()


def run(args: argparse.Namespace) -> int:
    """Entry of ``margcal watch``."""
    for name in ("timeout", "duration"):
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f"--{name} must be a positive number of seconds, got {value}")
    try:  # optional dependency (the ROS extra or a sourced ROS 2): imported where used
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
    except ImportError:
        print(f"margcal watch: error: {ROS_MISSING}", file=sys.stderr)
        return 2
    views: dict[str, SensorView] = {}
    start = time.monotonic()
    received = [0]

    def on_status(msg: Any) -> None:
        received[0] += 1
        update_views(views, msg, time.monotonic() - start)

    rclpy.init()
    node = Node(f"margcal_watch_{os.getpid()}")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    node.create_subscription(DiagnosticArray, args.topic, on_status, 10)
    display = Display(sys.stdout)
    end = start + (args.duration if args.duration is not None else math.inf)
    try:
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)
            elapsed = time.monotonic() - start
            header = f"margcal watch {args.topic}: {elapsed:.0f} s" + ("" if received[0] else ", no status yet")
            lines = [header] + [line for s in sorted(views) for line in format_block(s, views[s])]
            if not args.once:
                display.show(lines, elapsed)
            elif received[0]:
                display.show(lines, elapsed, force=True)  # one screen, the first status
                break
            elif elapsed > args.timeout:
                break
    except KeyboardInterrupt:
        pass  # Ctrl-C is how a user ends the watch: the status below and exit 0
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    if not received[0]:
        print(f"margcal watch: no status on {args.topic} (is the node running, on this ROS_DOMAIN_ID?)", file=sys.stderr)
        return 1
    return 0


def register(subparsers: Any) -> None:
    """Add the ``watch`` subcommand."""
    p = subparsers.add_parser("watch", help="show a running node's /calib/status live, one block per sensor",
                              description=__doc__.splitlines()[0])
    p.add_argument("--topic", default="/calib/status", help="the status topic (default /calib/status)")
    p.add_argument("--once", action="store_true", help="print the first status and exit")
    p.add_argument("--timeout", type=float, default=10.0, help="with --once: give up after this many seconds (default 10)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    p.set_defaults(func=run)
