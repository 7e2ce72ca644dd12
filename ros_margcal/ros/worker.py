"""The node's calibrators in a process of their own, so that no fit ever delays a message (no rclpy).

A fit holds the interpreter for tens of milliseconds to seconds (the GIL): on a thread of the node it
stalls every sample callback, and a best-effort queue at 100-1000 Hz overflows. So the node does only the
per-message work (conversion, stamp choice, publishing the calibrated message with the calibration it
holds) and hands the samples, in batches, to ``serve`` running in a worker process, which owns one
``SensorCalibrator`` per sensor and runs the whole corridor on them exactly as ``margcal replay`` does
(evaluations inline, a fit one step a sample: the same samples give the same calibrations; a fit in progress when
the stream stops runs to its end after ``_IDLE_FINISH_S``), pairing each magnetometer sample with the Imu rate
nearest in stamp (``pairing.RatePairing``).

``CalibrationWorker`` is the node's handle: ``send`` queues samples (never blocks), ``request`` a command
(``reset``, ``refit``, ``configure``), ``poll`` returns what came back without waiting:

- ``("calibration", sensor, Calibration | None)``: the current calibration changed (a fit, a reset);
- ``("event", Event)``: what ``push`` and ``refit`` reported;
- ``("status", {sensor: Status})``: at most every ``status_period_s`` and after each command;
- ``("view", {sensor: CoverageView})``: the answer to ``want_view`` (the node's RViz markers, asked for only while
  someone subscribes to them);
- ``("reply", request_id, success, message)``: the answer to a ``request``;
- ``("error", text)``: an exception in the worker, which goes on with the next message.

The worker ends with its parent (a ``stop`` message, the parent's exit, or the parent gone). A worker that
died is started again by ``restart`` from the calibrations the node holds.
"""

from __future__ import annotations

import gc
import math
import multiprocessing
import queue
import signal
import time
import traceback
from typing import Any

import numpy as np

from ..model.calibration import Calibration
from ..model.errors import MargCalError
from ..stream.calibrator import SensorCalibrator
from ..stream.config import GYRO_PAIR_S, PipelineConfig
from ..stream.status import EventKind
from ..stream.view import coverage_view
from .pairing import RatePairing

__all__ = ["CalibrationWorker", "Sample", "serve"]

Sample = tuple[str, float, float, float, float, float, float, float, str, float]
"""One sample as the node queues it: sensor, time, x, y, z, gyro x, y, z (NaN: none), frame_id, arrival
(``time.monotonic()`` when the callback ran)."""

_POLL_S = 0.02  # the worker's wait for input, s: how late a held sample or a status may be at most
_IDLE_FINISH_S = 1.0
"""No sample for this long: the stream stopped, and a fit in progress runs to its end (``_Calibrators.idle``). Not
sooner: between batches of a flowing stream the fits step with the samples, as in replay (the same calibrations)."""


def _context() -> Any:
    """forkserver where there is one (a fresh server process, no DDS threads forked; later starts are quick), else spawn."""
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    if "forkserver" in methods:
        ctx.set_forkserver_preload([__name__])
    return ctx


class _Calibrators:
    """The worker's side: one ``SensorCalibrator`` per sensor, the rate pairing, what was last sent."""

    def __init__(self, specs: dict[str, tuple[PipelineConfig, Calibration | None]], validator: Any, outbox: Any) -> None:
        self.cals = {s: SensorCalibrator(s, cfg, calibration=cal, validator=validator) for s, (cfg, cal) in specs.items()}
        self.pairing = RatePairing(GYRO_PAIR_S)
        self.outbox = outbox
        self.sent = {s: c.calibration for s, c in self.cals.items()}
        # a calibration from the file is stamped on its recording's clock: its age counts from our first sample
        self.restamp = {s for s, c in self.cals.items() if c.calibration is not None}

    def samples(self, batch: list[Sample]) -> None:
        for sensor, t, x, y, z, gx, gy, gz, frame, arrival in batch:
            gyro = None if math.isnan(gx) else np.array([gx, gy, gz])
            if sensor == "accel":
                if "mag" in self.cals and gyro is not None:
                    self._push_mag(self.pairing.add_rate(t, frame, gyro, arrival))
                if "accel" in self.cals:
                    self._push("accel", t, (x, y, z), gyro)
            elif sensor == "mag" and "mag" in self.cals:
                self._push_mag(self.pairing.add_mag(t, frame, (x, y, z), arrival))

    def _push_mag(self, released: list[tuple[float, Any, Any]]) -> None:
        for t, xyz, gyro in released:
            self._push("mag", t, xyz, gyro)

    def _push(self, sensor: str, t: float, xyz: Any, gyro: Any) -> None:
        c = self.cals[sensor]
        for ev in c.push(t, xyz, gyro):
            self.event(ev)
        if sensor in self.restamp and c.passed:
            self.restamp.discard(sensor)
            if c.calibration is not None and c.calibration is self.sent[sensor]:
                c.set_calibration(c.calibration.replace(stamp=c.status().t))

    def idle(self) -> None:
        """The stream stopped (``_IDLE_FINISH_S``): a fit in progress runs to its end now (``stream.evaluation``,
        **Fits in steps**: it steps with the samples, and would wait for the next one)."""
        for c in self.cals.values():
            for ev in c.finish_fit():
                self.event(ev)

    def event(self, ev: Any) -> None:
        self.outbox.put(("event", ev))

    def flush(self) -> None:
        """Release the held magnetometer samples whose wait is over; send the calibrations that changed."""
        if "mag" in self.cals:
            self._push_mag(self.pairing.release(time.monotonic()))
        for s, c in self.cals.items():
            if c.calibration is not self.sent[s]:
                self.sent[s] = c.calibration
                self.outbox.put(("calibration", s, c.calibration))

    def status(self) -> None:
        self.outbox.put(("status", {s: c.status() for s, c in self.cals.items()}))

    def view(self) -> None:
        self.outbox.put(("view", {s: coverage_view(c) for s, c in self.cals.items()}))

    def command(self, kind: str, args: tuple[Any, ...]) -> tuple[bool, str]:
        if kind == "configure":
            sensor, config = args
            self.cals[sensor].reconfigure(config)
            return True, f"{sensor}: reconfigured"
        if kind == "reset":
            self._push_mag(self.pairing.release(time.monotonic(), everything=True))
            self.pairing.clear()
            for c in self.cals.values():
                c.reset()
            self.restamp.clear()
            return True, f"reset {sorted(self.cals)}: collecting"
        if kind == "reset_sensor":  # the node follows another frame_id on this sensor's topic
            (sensor,) = args
            self.cals[sensor].reset()
            self.restamp.discard(sensor)
            return True, f"{sensor}: reset: collecting"
        if kind == "refit":
            self._push_mag(self.pairing.release(time.monotonic(), everything=True))
            messages = [self._refit(s, c) for s, c in self.cals.items()]
            return all(c.calibration is not None for c in self.cals.values()), " | ".join(messages)
        msg = f"unknown worker command {kind!r}"
        raise MargCalError(msg)

    def _refit(self, s: str, c: SensorCalibrator) -> str:
        """Refit one sensor; what happened: a new calibration, the current one kept (a fit no better), or why none."""
        events = c.refit()
        for ev in events:
            self.event(ev)
        new = [e.message for e in events if e.kind is EventKind.CALIBRATED]
        refused = "; ".join(e.message for e in events if e.kind is EventKind.REJECTED)
        if new:
            return f"{s}: {'; '.join(new)}"
        if c.calibration is not None:
            return f"{s}: kept the current calibration" + (f" ({refused})" if refused else "")
        return f"{s}: {refused or c.status().message}"


def serve(inbox: Any, outbox: Any, specs: dict[str, tuple[PipelineConfig, Calibration | None]], validator: Any,
          status_period_s: float) -> None:
    """The worker process: take samples and commands from ``inbox`` until ``stop`` (see the module docstring)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the node stops us
    parent = multiprocessing.parent_process()  # the node's process (with forkserver too), via its sentinel
    cals = _Calibrators(specs, validator, outbox)
    cals.status()
    # the imports' and start-up objects are not traversed again: a full collection over them paused one push by up
    # to 59 ms (scripts/bench_speed.py --freeze)
    gc.freeze()
    next_status = time.monotonic() + status_period_s
    last_input = time.monotonic()
    while True:
        try:
            msg = inbox.get(timeout=_POLL_S)
        except queue.Empty:
            msg = None
        except (EOFError, OSError):
            return  # the parent closed the queue
        if parent is not None and not parent.is_alive():
            return  # the parent is gone: no one reads what we would publish
        try:
            kind = None if msg is None else msg[0]
            if kind == "stop":
                return
            if kind is None and time.monotonic() - last_input >= _IDLE_FINISH_S:
                cals.idle()
            if kind == "samples":
                cals.samples(msg[1])
                last_input = time.monotonic()
            elif kind == "view":
                cals.view()
            elif kind == "request":
                _, command, request_id, args = msg
                ok, text = cals.command(command, args)
                cals.flush()  # the calibration a command changed arrives before its answer
                outbox.put(("reply", request_id, ok, text))
                cals.status()
                next_status = time.monotonic() + status_period_s
            cals.flush()  # also without input: held magnetometer samples whose wait is over
            if time.monotonic() >= next_status:
                cals.status()
                next_status = time.monotonic() + status_period_s
        except Exception:
            outbox.put(("error", traceback.format_exc(limit=8)))
            if msg is not None and msg[0] == "request":
                outbox.put(("reply", msg[2], False, "the worker failed on this request (see the node's log)"))


class CalibrationWorker:
    """The node's handle on the worker process (see the module docstring).

    Args:
        specs: per sensor, its options and the calibration to start from (None: uncalibrated).
        validator: the validator object (None: the shipped one).
        status_period_s: how often the worker sends the status.
    """

    def __init__(self, specs: dict[str, tuple[PipelineConfig, Calibration | None]], validator: Any,
                 status_period_s: float) -> None:
        self._ctx = _context()
        self._validator = validator
        self._period = float(status_period_s)
        self._requests = 0
        self.restarts = 0
        self._start(specs)

    def _start(self, specs: dict[str, tuple[PipelineConfig, Calibration | None]]) -> None:
        self._inbox = self._ctx.Queue()
        self._outbox = self._ctx.Queue()
        self._proc = self._ctx.Process(target=serve, name="margcal-worker", daemon=True,
                                       args=(self._inbox, self._outbox, specs, self._validator, self._period))
        self._proc.start()

    @property
    def alive(self) -> bool:
        """True while the worker process runs."""
        return self._proc.is_alive()

    @property
    def pid(self) -> int | None:
        """The worker's process id."""
        return self._proc.pid

    def restart(self, specs: dict[str, tuple[PipelineConfig, Calibration | None]]) -> None:
        """Start a new worker from ``specs`` (the old one died: its buffers are lost, the calibrations are not)."""
        self.stop(timeout_s=0.5)
        self.restarts += 1
        self._start(specs)

    def send(self, batch: list[Sample]) -> None:
        """Queue samples for the worker (never blocks: the queue's own thread writes them)."""
        if batch:
            self._inbox.put(("samples", batch))

    def want_view(self) -> None:
        """Ask for one ``view`` message (never blocks)."""
        self._inbox.put(("view",))

    def request(self, kind: str, *args: Any) -> int:
        """Queue a command (``reset``, ``refit``, ``configure``); its request id (the ``reply`` names it)."""
        self._requests += 1
        self._inbox.put(("request", kind, self._requests, args))
        return self._requests

    def poll(self) -> list[tuple[Any, ...]]:
        """Everything the worker sent since the last poll, without waiting."""
        out = []
        while True:
            try:
                out.append(self._outbox.get_nowait())
            except queue.Empty:
                return out
            except (EOFError, OSError):
                return out

    def stop(self, timeout_s: float = 2.0) -> None:
        """Ask the worker to end; terminate it when it does not within ``timeout_s``."""
        if self._proc.is_alive():
            try:
                self._inbox.put(("stop",))
            except (ValueError, OSError):
                pass
            self._proc.join(timeout_s)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(1.0)
        for q in (self._inbox, self._outbox):
            q.cancel_join_thread()
            q.close()
