"""The streaming calibrator of one sensor: samples in, validated calibrations and a status out.

``SensorCalibrator.push(t, xyz, gyro=None)`` is the whole online flow of DESIGN.md for one
magnetometer or accelerometer, in pure Python (no rclpy):

1. *Input sanity* (``intake.Intake``). Anything but three real numbers, NaN/Inf (also ints beyond
   the float range), zero vectors, absurd magnitudes, repeated or backwards stamps, stamp jumps and
   bursts faster than ``max_rate_hz`` are dropped and counted per reason; ``push`` never raises,
   whatever the objects. A lone stamp glitch is dropped once; a clock that restarts (a bag replayed
   in a loop, a driver restart: ``new_time_base_after`` consistent samples off the time base) starts
   a new time base: the stored times are moved onto it, the gate is emptied, the buffer and the
   calibration are kept, an ``EventKind.TIME_BASE`` event and the status say so. A gyro that is
   malformed, not finite or beyond ``intake.MAX_GYRO_RAD_S`` is ignored for that sample. In a unit
   without a known scale the magnitude limits are learnt from the first samples and relearnt when
   nearly every sample falls outside them (a bad start); before a calibration, what the old limits let
   through is then forgotten. Magnetometer samples then pass the spike filter (``intake.SpikeFilter``):
   one that leaves the stream by far more than its usual step and comes straight back (a glitch, of
   any magnitude) is dropped as ``spike``; the others go on, a far step one to three samples late.
2. *Gate.* Accelerometer samples go through ``gate.InactivityGate`` (Gietzelt et al. 2013, §2.4:
   coefficient of variation of the norm over a 2 s window below 3e-3; 1 s with a gyro reading below
   ``gate_gyro_rest_threshold``, ``gate.GyroAidedGate``; with ``gate_learn_noise`` both thresholds widen to
   the sensor's learnt rest noise, at most 1e-2) and only its averaged still samples go on;
   magnetometer samples go straight on (and into the partial calibration's time series).
3. *Buffer.* ``coverage.DirectionBuffer`` keeps at most K samples per direction bin (newest
   replaces oldest) and the coverage indicators A–D of Olivares et al. 2013 (§3.1).
4. *Validator.* At most every ``refit_every`` samples and ``refit_min_interval_s`` seconds
   (``recheck_interval_s`` while calibrated), the buffer centre is re-estimated (a linear sphere
   fit while uncalibrated) and the fuzzy validator (Olivares §3.3, Eq. 17) predicts the calibration
   error from the indicators; the fit runs only when the prediction is within the threshold. The
   refit cost is therefore never paid per sample.
5. *Fit.* ``fitting.fit(points, model="sym", method="lm", loss="soft_l1")`` from a ``lin_auto``
   start (Gietzelt Eqs. 5–17, then Camps et al. 2009 LM with the symmetric matrix).
6. *Guard rails* (``config.guard_rails``, after ArduPilot's compass/accel calibration
   checks) before a fit is published: convergence, residual RMS limit, plausible field norm (gravity
   for the accelerometer, 20–70 µT for the Earth field), parameter uncertainty, offset limit, gain
   (axis ratio) limits, and the new fit must not be worse than the current calibration on the most
   recent samples. A rejected fit is reported with its reason. When the validator refuses a
   magnetometer buffer, the partial calibration (``partial``, ``observable``) fits what the motion
   makes observable and publishes it when its predicted heading error at the tilt seen is small.
7. *Rolling use.* Each sample's relative norm error under the current calibration is kept for the
   last ``recent_samples``; samples beyond ``outlier_threshold`` are not buffered (field
   disturbances). When the median over the last ``change_window`` samples has stayed above
   ``change_threshold`` for ``change_min_duration_s``, the sensor has changed (a hard-iron jump, a
   drift): the buffer is rebuilt from the samples since the change began and the next validated fit
   describes the new sensor (the not-worse check then uses only those samples, on which the old
   calibration is poor); a change withdraws itself when the old calibration explains the samples
   again (a bad stretch that passed). A slow drift makes the calibration stale between rechecks: a
   recheck then re-centres it on the samples since its fit (``change``). The status residual leaves
   out the recent samples the calibration calls outliers (they were dropped) unless they are most.

The state is one of ``State`` (collecting, ready, calibrated, rejected); ``status()`` returns a
``Status`` with everything ``/calib/status`` shows, its ``level`` an ``IntEnum`` (the node turns it
into the bytes rclpy wants).

Counting: every pushed sample is counted once, ``seen == passed + sum(dropped.values())``. ``dropped``
holds the intake's reasons, ``spike`` (a magnetometer sample the spike filter dropped; one it holds back
counts as passed meanwhile) and ``outlier`` (while calibrated, a sample too far from the calibration;
for the accelerometer, the sample whose push made the gate emit an outlying still mean); ``passed``
holds the rest: handed to the buffer stage (magnetometer) or to the gate (accelerometer, where most
samples end inside a window mean; ``kept`` counts what the buffer took).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..coverage.buffer import DirectionBuffer
from ..coverage.gate import GyroAidedGate
from ..model.calibration import Calibration
from ..model.errors import ConfigError, InputError
from ..model.mounting import turned, up_rotation
from ..validation.shipped import default_validator
from .change import ChangeDetection
from .config import STATIC_SPREAD, PipelineConfig, raise_hint, relative_spread
from .evaluation import Evaluation
from .intake import DROP_REASONS, Intake, Sample, SpikeFilter
from .status import Event, EventKind, Level, State, Status, pct

__all__ = ["DROP_REASONS", "Event", "EventKind", "Level", "PipelineConfig", "SensorCalibrator", "State", "Status",
           "default_validator"]

log = logging.getLogger(__name__)
"""What an Event also says is logged at debug level only: replay's timeline and the node's log print the events
(each once); warnings are for what no event carries."""

_WAITING = "waiting for samples"
"""The reason before any evaluation; the status then counts what is buffered (24 pose readings said \"waiting\")."""

Array = NDArray[np.float64]

class SensorCalibrator(ChangeDetection, Evaluation):
    """Online calibration of one sensor (see the module docstring for the flow).

    Args:
        sensor: ``"mag"`` or ``"accel"``.
        config: the options; ``PipelineConfig.for_sensor(sensor)`` when None.
        validator: an object with ``predict_indicators(indicators) -> float`` and ``threshold``;
            None loads the trained default (``default_validator``).
        calibration: a calibration to start from (loaded from file); the state is then calibrated.
    """

    def __init__(
        self,
        sensor: str = "mag",
        config: PipelineConfig | None = None,
        *,
        validator: Any | None = None,
        calibration: Calibration | None = None,
    ) -> None:
        if sensor not in ("mag", "accel"):
            msg = f"sensor must be 'mag' or 'accel', got {sensor!r}"
            raise ConfigError(msg)
        self.sensor = sensor
        self.config = (config or PipelineConfig.for_sensor(sensor)).checked()
        if self.config.sensor != sensor:
            self.config = replace(self.config, sensor=sensor)
        self.validator = validator if validator is not None else default_validator()
        self._set_up(self.config)
        calibration = self._inward(calibration)
        self._initial = calibration
        self.reset()
        if calibration is not None:
            self._install(calibration)
            self._set_prior(calibration)

    # -- lifecycle --------------------------------------------------------------------------------

    def reset(self, *, keep_calibration: bool = False) -> None:
        """Forget all samples (and the calibration unless ``keep_calibration``); counters restart."""

        cfg = self.config
        cal = self._cal if keep_calibration and hasattr(self, "_cal") else None
        self._buffer = DirectionBuffer(n_bins=cfg.n_bins, per_bin=cfg.per_bin, hull_on_read=True)
        self._gate: Any = None
        if self.sensor == "accel":
            self._gate = GyroAidedGate(window_s=cfg.gate_window_s, cv_threshold=cfg.gate_cv_threshold,
                                       gyro_threshold=cfg.gate_gyro_threshold, gyro_window_s=cfg.gate_gyro_window_s,
                                       gyro_rest_threshold=cfg.gate_gyro_rest_threshold, learn=cfg.gate_learn_noise)
        self._recent_t: deque[float] = deque(maxlen=cfg.recent_samples)
        self._recent_v: deque[tuple[float, float, float]] = deque(maxlen=cfg.recent_samples)
        self._recent_r: deque[float] = deque(maxlen=cfg.recent_samples)
        self._early_t: deque[float] = deque(maxlen=2 * cfg.recent_samples)  # an early fit's window (partial.py), filled
        self._early_v: deque[tuple[float, float, float]] = deque(maxlen=2 * cfg.recent_samples)  # while early fits may run
        self._intake = Intake(cfg, use_gyro=self._gate is not None or cfg.gyro_aided)
        self._spikes = SpikeFilter()
        self._rails_found = 0  # the intake's rails seen (_rail_found)
        self.dropped = self._intake.dropped  # the intake's reasons and "outlier", one dict
        self.passed = 0
        self.kept = 0
        self._time_base_note = ""
        self._since_eval = 0
        self._last_eval_t = -math.inf
        self._runaways = 0
        self._t = 0.0
        self._state = State.COLLECTING
        self._cal: Calibration | None = None
        self._changed = False
        self._suspect_since: float | None = None
        self._change_onset: float | None = None
        self._stale_note = ""
        self._recentred: Calibration | None = None  # the current calibration when a re-centring (change.py) made it
        self._back_since: float | None = None  # after a change: since when the old calibration explains the samples
        self._pre_change: tuple[Any, Any] | None = None  # the buffer's times and points before the change
        self._known: tuple[tuple[Any, ...], ...] = ()  # calibrations earlier changes ended (change.py ``_check_known``)
        self._fit_times, self._fit_points = np.zeros(0), np.zeros((0, 3))  # the buffer when the calibration was installed
        self._predicted: float | None = None
        self._figures_due = None  # a full fit's heading figures, computed when next read (evaluation.py)
        self._hold_figures = False  # the push that installed that fit: its figures wait for the next one
        self._sliced = None  # the fit in progress, a step per push (evaluation.py)
        self._indicators: Any = None
        self._last_rejection = ""
        self._last_reason = _WAITING
        self.fits_accepted = 0
        self.fits_rejected = 0
        self.changes = 0
        self._w: tuple[float, ...] = ()
        self._partial_reset()
        if cal is not None:
            self._install(cal)

    def reconfigure(self, config: PipelineConfig) -> None:
        """Use new options from now on; buffer or gate options rebuild them (the calibration is kept; a new
        ``up_axis`` turns it and starts the samples over: the buffered ones are turned the old way)."""
        config = replace(config.checked(), sensor=self.sensor)
        rebuild = any(getattr(config, k) != getattr(self.config, k) for k in
                      ("n_bins", "per_bin", "recent_samples", "gate_window_s", "gate_cv_threshold", "gate_gyro_threshold",
                       "gate_gyro_window_s", "gate_gyro_rest_threshold", "gate_learn_noise", "gyro_aided", "gyro_samples",
                       "up_axis"))
        if config.up_axis != self.config.up_axis:
            kept = self.calibration
            self._set_up(config)
            self._cal = self._inward(kept)
        self.config = config
        self._intake.config = config
        if rebuild:
            self.reset(keep_calibration=True)

    def _set_up(self, config: PipelineConfig) -> None:
        """The turn of the readings ``up_axis`` asks for (``model.mounting.up_rotation``; None: none), as the
        turned sample's (source axis, sign) per axis for the sample path."""
        q = up_rotation(config.up_axis) if self.sensor == "mag" else None
        self._q = q
        self._q_axes = None if q is None else tuple((int(np.argmax(np.abs(r))), float(r[np.argmax(np.abs(r))])) for r in q)
        self._out_of: Calibration | None = None  # the internal calibration ``_out`` was turned from
        self._out: Calibration | None = None

    def _inward(self, cal: Calibration | None) -> Calibration | None:
        """A calibration of the magnetometer's own readings, for the turned readings (``up_axis``)."""
        return cal if cal is None or self._q is None else turned(cal, self._q)

    def _outward(self, cal: Calibration | None) -> Calibration | None:
        """A calibration of the turned readings (``up_axis``), for the magnetometer's own: ``b = q^T b'``,
        ``W = q^T W' q`` (the calibrated field in the magnetometer's axes, the same norms)."""
        return cal if cal is None or self._q is None else turned(cal, self._q.T)

    def _outward_events(self, events: list[Event]) -> list[Event]:
        """``events`` with their calibrations in the magnetometer's own axes (``up_axis``)."""
        if self._q is None or not events:
            return events
        return [e if e.calibration is None else replace(e, calibration=self._out_calibration(e.calibration))
                for e in events]

    def _out_calibration(self, cal: Calibration) -> Calibration:
        """``_outward(cal)``, the same object for the same calibration (the node's worker sends a calibration when
        the object it reads changes)."""
        if cal is not self._out_of:
            self._out_of, self._out = cal, self._outward(cal)
        assert self._out is not None
        return self._out

    def set_calibration(self, cal: Calibration | None) -> None:
        """Replace the current calibration (None: forget it and start collecting); a fit in progress is dropped."""
        self._sliced = None
        if cal is None:
            self._cal, self._w = None, ()
            self._state = State.COLLECTING
            self._intake.expected = None
        else:
            cal = self._inward(cal)
            self._install(cal)
        self._partial, self._figures = None, None
        self._set_prior(cal)

    @property
    def seen(self) -> int:
        """Samples pushed since the last reset (``passed + sum(dropped.values())``)."""
        return self._intake.seen

    @property
    def clock(self) -> float:
        """Stamp of the last sample taken onto the time base (0.0 before any): a dropped sample's stamp (far
        future, a single jump) never moves it."""
        return self._t

    @property
    def calibration(self) -> Calibration | None:
        """The current (last accepted) calibration, or None; of the magnetometer's own readings (``up_axis``)."""
        cal = self._cal
        return cal if cal is None or self._q is None else self._out_calibration(cal)

    @property
    def up_rotation(self) -> NDArray[np.float64] | None:
        """The rotation the readings are turned by before the buffer (``up_axis``), or None: the buffer's points
        ``p'`` are ``q p``."""
        return self._q

    @property
    def state(self) -> State:
        """The current state."""
        return self._state

    @property
    def buffer(self) -> Any:
        """The direction buffer (read it, do not push into it)."""
        return self._buffer

    def _install(self, cal: Calibration) -> None:
        self._cal = cal
        w, b = cal.matrix, cal.offset
        self._w = (*w.reshape(-1).tolist(), *b.tolist(), cal.norm)
        self._intake.expected = math.sqrt(float(b @ b) + cal.raw_radius**2)  # the raw field's RMS norm: learnt limits hold it
        self._state = State.CALIBRATED
        self._changed = False
        self._suspect_since = None
        self._change_onset = None
        self._back_since = None
        self._pre_change = None
        if len(self._recent_v):
            r = np.abs(cal.norm_error(np.array(self._recent_v))) / cal.norm
            self._recent_r = deque(r.tolist(), maxlen=self.config.recent_samples)
        self._fit_times, self._fit_points = self._buffer.times(), self._buffer.points()  # what it was fitted on (change)
        old = self._buffer.center  # a move within CENTER_MOVE_TOLERANCE keeps the bins (no re-binning)
        near = float(np.linalg.norm(cal.offset - old)) <= self.CENTER_MOVE_TOLERANCE * cal.raw_radius
        # the indicators' radius as the validator's training sets had it, a sphere fit's (an anisotropic sensor's
        # equal-volume radius put its full coverage at c_norm 1.09, where the validator predicts 4 % error)
        self._buffer.set_center(old if near else cal.offset, cal.rms_radius)

    # -- the sample path --------------------------------------------------------------------------

    def push(self, t: float, xyz: ArrayLike, gyro: ArrayLike | None = None) -> list[Event]:
        """Feed one raw sample at message time ``t`` (seconds); returns what happened (often nothing).

        Never raises, whatever ``t``, ``xyz`` and ``gyro`` are: bad samples are dropped and counted in
        ``dropped`` (see ``intake`` for the rules, the module docstring for the counting).
        """
        events = self._push(t, xyz, gyro)
        return events if self._q is None or not events else self._outward_events(events)

    def refit(self, t: float | None = None) -> list[Event]:
        """Validate and fit now, ignoring the cadence (the refit service). The validator still decides."""
        return self._outward_events(super().refit(t))

    def run_pending(self, lock: Any = None) -> list[Event]:
        """``Evaluation.run_pending``, its calibrations in the magnetometer's own axes (``up_axis``)."""
        return self._outward_events(super().run_pending(lock))

    def finish_fit(self) -> list[Event]:
        """``Evaluation.finish_fit``, its calibrations in the magnetometer's own axes (``up_axis``)."""
        return self._outward_events(super().finish_fit())

    def _push(self, t: float, xyz: ArrayLike, gyro: ArrayLike | None = None) -> list[Event]:
        """``push`` with the calibrations of its events in the turned readings' axes (``up_axis``)."""
        if self._sliced is not None:  # a fit in progress: one step a push, whatever the sample (evaluation.py)
            stepped = self._fit_step()
            if stepped:  # it ended: its events first, then this sample under what it installed (no fit in progress now)
                self._hold_figures = True  # its heading figures in a later push, not on top of its last step
                try:
                    return stepped + self._push(t, xyz, gyro)
                finally:
                    self._hold_figures = False
        intake = self._intake
        got = intake.take(t, xyz, gyro)
        if got is None:
            if intake.rails.found != self._rails_found:  # the sample that found a rail is on it: dropped
                self._rail_found()
            return []
        t, (x, y, z), g = got
        if self._q_axes is not None:  # up_axis: the readings (and rates) turned so that the up axis is z
            (i, si), (j, sj), (k, sk) = self._q_axes
            v = (x, y, z)
            x, y, z = si * v[i], sj * v[j], sk * v[k]
            if g is not None:
                g = (si * g[i], sj * g[j], sk * g[k])
        events = [] if intake.new_base_step is None else self._new_time_base(t, intake.new_base_step)
        if intake.relearnt_now:
            self._limits_relearnt(t)
        if intake.rails.found != self._rails_found:
            self._rail_found()
        self._t = t
        if self._gate is None:  # the magnetometer: held back while it may be a spike (intake.SpikeFilter)
            out, n = self._spikes.push((t, x, y, z, g))
            self.passed += 1 - len(out) - n  # the change in samples held: a held one counts as passed until it is a spike
            if n:
                self.dropped["spike"] += n
            if not out:
                return events
            handed = self._hand_on(out)
            return events + handed if events else handed
        out = self._gate.push(t, (x, y, z), g)
        if out is None:
            self.passed += 1  # handed to the gate, which keeps it inside a window (or finds motion)
            return events
        x, y, z = (float(v) for v in out.tolist())
        return events + self._accept(t, x, y, z)

    def _hand_on(self, samples: list[Sample]) -> list[Event]:
        """The magnetometer samples the spike filter handed on: the gyro-aided fit's rows, then the sample path."""
        events: list[Event] = []
        gyro = self._intake.use_gyro
        for t, x, y, z, g in samples:
            if gyro:
                self._gyro_push(t, x, y, z, g)
            events += self._accept(t, x, y, z)
        return events

    def _new_time_base(self, t: float, step: float) -> list[Event]:
        """The stamps restarted (``intake``): move the stored times onto the new time base, empty the gate.

        The old time base's last sample is put one ``min_period_s`` before ``t``, so the recent-sample
        windows, the change detector and the refit cadence see one continuous stream; the buffer (its
        bins compare stamps by their distance) and the calibration are kept.
        """
        held = self._spikes.flush() if self._gate is None else []  # the old time base's, handed on before the move
        self.passed -= len(held)
        events = self._hand_on(held)
        self._spikes.reset()
        shift = step - self.config.min_period_s
        self._recent_t = deque((s + shift for s in self._recent_t), maxlen=self._recent_t.maxlen)
        self._early_t = deque((s + shift for s in self._early_t), maxlen=self._early_t.maxlen)
        if self._suspect_since is not None:
            self._suspect_since += shift
        if self._change_onset is not None:
            self._change_onset += shift
        self._known = tuple((k[0], k[1] + shift, *k[2:]) for k in self._known)  # their buffers' stamps (change.py)
        self._last_eval_t += shift
        self._full_eval_t += shift  # the back-offs' clock (evaluation.py)
        if self._cal is not None:
            self._cal = self._cal.replace(stamp=self._cal.stamp + shift)
        if self._gate is not None:
            self._gate.reset()
        self._gyro_buf.clear()  # its blocks need consecutive stamps
        n = self._intake.time_base_resets
        self._time_base_note = f"stamps restarted {n}x, last at t={t:.2f} s (a {step:+.6g} s jump)"
        msg = (f"new time base: stamps jumped {step:+.6g} s to t={t:.3f} s and went on "
               f"({self.config.new_time_base_after} consistent samples); the calibration and buffer are kept")
        log.debug("%s: %s", self.sensor, msg)
        return [*events, Event(EventKind.TIME_BASE, t, self.sensor, msg)]

    def _rail_found(self) -> None:
        """The intake found a saturated axis (``saturation``): the samples on it that went in before (the run that
        found it) leave the buffer and the recent samples; before a calibration the series, whose block means hold
        them, starts again (a rail shows in the first turns, and the first fits are made of those samples)."""
        rails = self._intake.rails
        self._rails_found = rails.found
        gone = self._buffer.discard(rails.on_rail)
        gone = max(gone, self._drop_on_rail(("_recent_t", "_recent_v", "_recent_r")))
        self._drop_on_rail(("_early_t", "_early_v"))
        if self._cal is None:
            self._series.clear()
            self._series_times.clear()
            self._series_acc = [0.0, 0.0, 0.0, 0.0, 0.0]
        log.warning("%s: saturated: %s (readings pinned there while the sensor turned): dropped from now on, and %d "
                    "that went in before taken out", self.sensor, rails.where(self.config.unit), gone)

    def _drop_on_rail(self, names: tuple[str, ...]) -> int:
        """Take the samples on a rail out of the deques ``names`` (appended together, the readings second); how many."""
        rails = self._intake.rails
        keep = [not rails.on_rail(*v) for v in getattr(self, names[1])]
        for name in names if not all(keep) else ():
            old = getattr(self, name)
            if len(old) == len(keep):  # they are appended together (never raise in push for a deque out of step)
                setattr(self, name, deque((a for a, k in zip(old, keep, strict=True) if k), maxlen=old.maxlen))
        return keep.count(False)

    def _limits_relearnt(self, t: float) -> None:
        """The intake relearnt its magnitude limits (a unit without a known scale): before a calibration, what
        the old limits let through (the bad start they were learnt from) is forgotten; the counters stay."""
        log.warning("%s: %s", self.sensor, self._intake.learnt)
        if self._cal is not None:
            return
        self._buffer.clear()
        for d in (self._recent_t, self._recent_v, self._recent_r, self._early_t, self._early_v):
            d.clear()
        self._partial_reset()
        self._spikes.reset()
        self._since_eval = 0
        self._last_full = None
        self._predicted = None
        self._indicators = None
        self._last_reason = "magnitude limits relearnt: collecting again"

    def _accept(self, t: float, x: float, y: float, z: float) -> list[Event]:
        events: list[Event] = []
        cfg = self.config
        if self._figures_due is not None and not self._hold_figures:  # the last full fit's figures, a push after it
            self._settle_figures()
        r = 0.0
        if self._cal is not None:  # the relative norm error under the current calibration, W (v - b) against its norm
            w00, w01, w02, w10, w11, w12, w20, w21, w22, bx, by, bz, norm = self._w
            dx, dy, dz = x - bx, y - by, z - bz
            hx = w00 * dx + w01 * dy + w02 * dz
            hy = w10 * dx + w11 * dy + w12 * dz
            hz = w20 * dx + w21 * dy + w22 * dz
            r = abs(math.sqrt(hx * hx + hy * hy + hz * hz) / norm - 1.0)
        v = (x, y, z)
        self._recent_t.append(t)
        self._recent_v.append(v)
        if self._cal is None or self._early_installed:  # once neither, no early fit runs again (partial._early_open)
            self._early_t.append(t)
            self._early_v.append(v)
        self._recent_r.append(r)
        self._series_push(t, x, y, z)
        if self._cal is not None and not self._changed:
            if r > cfg.change_threshold or self._suspect_since is not None:
                events += self._check_change(t)
            if not self._changed and r > cfg.outlier_threshold:
                self.dropped["outlier"] += 1
                return events
        elif self._changed and (r <= cfg.change_threshold or self._back_since is not None):
            events += self._check_return(t)
        if self._changed and self._known:
            events += self._check_known(t)
        self.passed += 1
        if self._buffer.push_finite(t, x, y, z):
            self.kept += 1
        self._since_eval += 1
        if self._sliced is not None or self._since_eval < (cfg.refit_every // 2 or 1):  # a fit in progress (push
            return events  # steps it: evaluation.py); the cadence never asks for fewer (a cheap test first)
        every, interval = self._cadence()
        if self._since_eval >= every and t - self._last_eval_t >= interval:
            events += self._evaluate(t, force=False)
        return events

    def _set_state(self, state: State, t: float) -> list[Event]:
        if state == self._state:
            return []
        old, self._state = self._state, state
        return [Event(EventKind.STATE, t, self.sensor, f"{old.value} -> {state.value}")]

    # -- status -----------------------------------------------------------------------------------

    def residual(self) -> float | None:
        """RMS relative norm error of the current calibration on the recent samples, without those it calls
        outliers (beyond ``outlier_threshold``: dropped, never buffered) unless they are most of them (a change)."""
        got = self._residual_figures()
        return None if got is None else got[0]

    def _residual_figures(self) -> tuple[float, int, int] | None:
        """``(residual, outliers left out, recent samples)`` of the current calibration (``residual``), or None.

        The recent samples keep the outliers for the change detector (its median residual), but a dropped
        sample is no measure of the calibration: one 1000 µT glitch made an exact calibration's residual
        80 % for the next ``recent_samples`` samples."""
        if self._cal is None or not len(self._recent_r):
            return None
        # the recent samples' |norm error| / norm under the current calibration, kept so by _accept and _install: a
        # status a second reads them (recomputing 500 of them was nearly half of a status read, 350 -> 200 us)
        e = np.fromiter(self._recent_r, dtype=np.float64, count=len(self._recent_r))
        if self._changed and self._change_onset is not None:  # as _recent_points
            e = e[np.fromiter(self._recent_t, dtype=np.float64, count=len(self._recent_t)) >= self._change_onset]
        n = len(e)
        if not n:
            return None
        out = e > self.config.outlier_threshold
        n_out = int(np.count_nonzero(out))
        if n_out and 2 * n_out < n:
            e = e[~out]
        else:
            n_out = 0
        return float(np.sqrt(np.mean(e * e))), n_out, n

    def _static_note(self) -> str:
        """"; the sensor has not turned ..." when the recent samples stay within ``STATIC_SPREAD`` of their mean."""
        pts = np.array(self._recent_v, dtype=np.float64).reshape(-1, 3)
        if len(pts) < self.config.change_window:
            return ""
        spread = relative_spread(pts)
        if spread >= STATIC_SPREAD:
            return ""
        what = ("one pose: it fixes gravity's norm only); hold it still in other poses, each axis up and down"
                if self.sensor == "accel" else "static: they fix the field norm only); turn it through all directions")
        return f"; the sensor has not turned: the last {len(pts)} samples stay within {pct(spread)} of their mean ({what}"

    def _gate_advice(self) -> str:
        """What to do when the gate passed no sample: the gyro's rest threshold when the window's readings are still
        by their CV and spread but the gyro reads above it (rates in deg/s: 0.1-1 at rest), else the CV threshold."""
        cv, axis = self._gate.window_stats
        cv_max, axis_max = self._gate.thresholds
        busy = self._gate.gyro_busy
        if busy is not None and cv <= cv_max and axis <= axis_max:
            return (f"the readings are still but the gyro reads above {busy[1]:g} rad/s on {pct(busy[0])} of the window: "
                    "are the rates in deg/s, not rad/s (REP-103)? Else hold it still, or "
                    f"{raise_hint(self.sensor, 'gate_gyro_rest_threshold')}")
        return f"hold the sensor still in a few poses, or for a noisy sensor {raise_hint(self.sensor, 'gate_cv_threshold')}"

    def _gate_figures(self) -> str:
        """The gate's last window against its thresholds, `` (last window CV .. vs .., axis spread .. vs ..; learnt)``."""
        cv, axis = self._gate.window_stats
        if not math.isfinite(cv):
            return ""
        cv_max, axis_max = self._gate.thresholds
        learnt = self._gate.learnt
        return (f" (last window CV {cv:.3g} vs {cv_max:.3g}, axis spread {axis:.3g} vs {axis_max:.3g}"
                f"{'; ' + learnt if learnt else ''})")

    def status(self, now: float | None = None) -> Status:
        """The status at message time ``now`` (default: the last sample's time).

        Raises:
            InputError: ``now`` is not a number of seconds (a float's range).
        """
        try:
            t = self._t if now is None else float(now)
        except (TypeError, ValueError, OverflowError) as exc:
            msg = f"status(now=...) takes a time in seconds, got {now!r:.40}"
            raise InputError(msg) from exc
        self._settle_figures()
        cal = self.calibration  # in the magnetometer's own axes (up_axis)
        figures = self._residual_figures()
        res = None if figures is None else figures[0]
        st = self._state
        if self.seen == 0:
            level, msg = Level.STALE, "no samples received yet"
        elif st is State.CALIBRATED and not self._changed:
            level = Level.OK
            left_out = "" if not (figures and figures[1]) else \
                f" (without {figures[1]} outliers of the last {figures[2]} samples, dropped)"
            msg = f"calibrated: residual {pct(res)}{left_out}, age {max(0.0, t - cal.stamp):.0f} s" if cal else "calibrated"
            if self._last_rejection:
                msg += f"; last refit rejected: {self._last_rejection}"
        elif st is State.REJECTED:
            level, msg = Level.ERROR, f"rejected: {self._last_rejection}"
        elif st is State.READY:
            level, msg = Level.WARN, f"ready: predicted error {pct(self._predicted)} <= {pct(self.threshold)}, fitting"
        else:
            level = Level.WARN
            if self._changed:
                msg = f"collecting after a sensor change (residual {pct(res)}): {self._last_reason}"
            elif self._predicted is not None:
                shown = pct(self._predicted) if self._predicted <= 1.0 else "over 100 % (not determined)"
                msg = f"collecting: {pct(self.coverage)} coverage, predicted error {shown} > {pct(self.threshold)}"
            elif self.passed == 0 and self.seen:
                msg = f"collecting: every sample dropped so far: {self._intake.drop_summary()}"
            elif self.kept == 0 and self._gate is not None and (note := self._intake.stamp_note()):  # not the gate's
                why = self._intake.drop_summary() or note  # (ms stamps are taken: no drop)
                msg = f"collecting: no still sample from the inactivity gate yet: {why}"
            elif self.kept == 0 and self._gate is not None:
                msg = (f"collecting: no still sample from the inactivity gate yet: {self.passed} samples reached it; "
                       f"0 of {self.passed} samples still for >= {self._gate.window_s:g} s{self._gate_figures()}: "
                       f"{self._gate_advice()}")
            elif self._last_reason == _WAITING and len(self._buffer):  # no evaluation yet (refit_every samples): say so
                msg = f"collecting: {len(self._buffer)} samples buffered, need {self.config.min_points}"
            else:
                msg = f"collecting: {self._last_reason}"
            msg += self._static_note()
            dropped = sum(self.dropped.values())
            if self.passed and 2 * dropped > self.seen and (summary := self._intake.drop_summary()) not in msg:
                msg += f"; {summary}"
        if self._intake.learnt:
            msg += f"; {self._intake.learnt}"
        if self.dropped["saturated"]:
            msg += f"; {self._intake.rails.describe(self.config.unit, self.dropped['saturated'])}"
        if gyro_note := self._intake.gyro_note():
            msg += f"; {gyro_note}"
        msg += self._partial_message()
        if self._time_base_note:
            msg += f"; {self._time_base_note}"
        if self._q is not None:
            msg += (f"; readings turned so that the magnetometer's {self.config.up_axis} axis is z ({self.sensor}.up_axis): "
                    "the axes named above are the turned readings', the calibration is in the magnetometer's own")
        ind = self._indicators
        ind_d: dict[str, float] = {}
        if ind is not None:
            for k in ("A", "B", "C", "D", "b_frac", "c_norm", "d_norm"):
                v = getattr(ind, k, None)
                if v is not None:
                    ind_d[k] = float(v)
        return Status(
            sensor=self.sensor, level=level, state=st, message=msg, t=t, samples_seen=self.seen,
            samples_kept=self.kept, samples_rejected=sum(self.dropped.values()),
            dropped={k: v for k, v in self.dropped.items() if v}, buffer_size=len(self._buffer),
            coverage=self.coverage, indicators=ind_d, predicted_error=self._predicted, error_threshold=self.threshold,
            residual=res, offset=None if cal is None else tuple(cal.offset.tolist()),
            matrix=None if cal is None else tuple(cal.matrix.reshape(-1).tolist()),
            norm=None if cal is None else cal.norm, age=None if cal is None else max(0.0, t - cal.stamp),
            fits_accepted=self.fits_accepted, fits_rejected=self.fits_rejected,
            last_rejection=self._last_rejection, changes_detected=self.changes, samples_passed=self.passed,
            time_base_resets=self._intake.time_base_resets, gyro_ignored=self._intake.gyro_ignored,
            **self._partial_fields(),
        )
