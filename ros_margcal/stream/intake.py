"""Input sanity of the streaming calibrator: one raw sample in, a clean one or a counted drop out.

``Intake.take(t, xyz, gyro)`` is step 1 of ``SensorCalibrator.push``. It never raises, whatever the
objects (the node and the replay hand over what a message or a file held):

- ``xyz`` must be three real numbers: a numeric numpy array of size 3 or a sequence of length 3 of
  ints/floats/numpy scalars. Anything else (None, strings, bools, dicts, nested or short lists,
  complex or string arrays, objects whose ``len`` or ``float`` raises) is ``wrong_size``; a stamp
  that is not a real number, or beyond ``MAX_STAMP_S``, is ``bad_stamp``.
- NaN or ±Inf, also a Python int beyond the float range, is ``nonfinite``; a norm at most
  ``min_magnitude`` is ``zero`` (an all-zero row, a driver's placeholder, also counted in ``zero_rows`` and
  called so), above ``max_magnitude`` ``magnitude`` (the last non-zero offending norm of each is kept in
  ``last_norms`` for the status). With ``learn_magnitude_samples`` > 0 (a unit without a known
  scale, such as counts) the first that many samples pass with any non-zero norm up to ``max_magnitude`` and their
  median norm ``m`` sets the limits to ``[units.LEARN_LOW m, units.LEARN_HIGH m]`` (``learnt`` says so). Limits
  learnt from a bad start are relearnt (``units.RELEARN_SHARE`` of a window outside them; ``relearnt_now``
  tells the calibrator, ``learnt`` the status), unless the current calibration's field (``expected``) lies within.
- Stamps, the time base: a sample is on the current time base when its step from the last one is in
  ``(0, max_stamp_gap_s]``. An equal stamp is ``repeated_stamp``. A sample off the time base
  (behind it: ``backwards_stamp``; ahead by more than ``max_stamp_gap_s``: ``stamp_jump``) is dropped
  and remembered: when ``new_time_base_after`` samples in a row are off the time base and consistent
  with each other (each one step in ``(0, max_stamp_gap_s]`` after the previous), the clock has
  restarted (a bag replayed in a loop, a driver restart, a clock switched): the last of them starts a
  new time base (counted in ``time_base_resets``; ``new_base_step`` says how far the stamps moved)
  and is taken. A lone glitch (one sample an hour or 1e9 s ahead, or a late one) is dropped once and
  the samples after it go on as before. A restart thus costs ``new_time_base_after - 1`` samples.
- Stamps that are not seconds (nanoseconds since the epoch, all 0, ms that step by 10 "s"): ``stamp_note`` says
  so, with the unit they look like (``recordings.recording.stamp_unit``), when nearly every sample was dropped for
  its stamp or nearly every step on the time base is longer than ``MAX_STEP_S``; ``drop_summary`` adds it.
- ``burst``: closer than ``1 / max_rate_hz`` to the last taken sample.
- ``saturated``: on an axis pinned at the end of the sensor's range while it turns (``saturation.RailWatch``,
  ``rails``), which the status names; ``drop_saturated`` false keeps them.
- The gyro (the accelerometer's gate; the magnetometer's gyro-aided fit, ``gyro_aided``) is optional: one
  that is malformed, not finite or beyond ``MAX_GYRO_RAD_S`` is treated as absent for that sample (counted
  in ``gyro_ignored``), so a broken gyro costs the gate's motion check or the fit's rate, never the samples.

Every sample is counted once: ``seen == taken + sum(dropped.values())`` here; the calibrator adds
``spike`` and ``outlier`` (taken samples it refuses later) to the same ``dropped``.

``SpikeFilter`` is the magnetometer's check of a taken sample against its neighbours in time (the
accelerometer's gate does that job for it). A field reading moves continuously as the sensor turns,
so a sample that leaves the stream by far more than its usual step and comes straight back is a glitch
(a bit error, a bus fault), whatever its magnitude: before a calibration exists nothing else can tell
it from the field, and one such sample decided the buffer's centre (a linear sphere fit through it).
A sample that steps more than ``FAR`` times the upper quartile of the last ``STEPS`` steps away from the
last sample handed on is held (at most ``HOLD`` in a row); the next sample decides: back near the last one
handed on (``BACK`` times nearer than both steps of the excursion) makes the held samples spikes,
otherwise (a real jump: a magnet, a fast turn after rest) they go on, one to ``HOLD`` samples late.
"""

from __future__ import annotations

import math
import numbers
from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..recordings.recording import MAX_STAMP_S, MAX_STEP_S, MIN_STEPS, stamp_unit
from .config import STATIC_SPREAD, PipelineConfig, raise_hint, relative_spread
from .saturation import RailWatch
from .units import LEARN_HIGH, LEARN_LOW, RELEARN_FACTOR, RELEARN_SHARE

__all__ = ["DROP_REASONS", "MAX_GYRO_RAD_S", "MAX_STAMP_S", "STAMP_NOTE_SHARE", "STAMP_REASONS", "Intake", "Sample",
           "SpikeFilter"]

DROP_REASONS = ("wrong_size", "bad_stamp", "nonfinite", "zero", "magnitude", "repeated_stamp", "backwards_stamp",
                "stamp_jump", "burst", "saturated", "spike", "outlier")
"""Why a sample was dropped (the keys of ``dropped``); ``spike`` (``SpikeFilter``) and ``outlier`` are the calibrator's."""

STAMP_REASONS = ("bad_stamp", "repeated_stamp", "backwards_stamp", "stamp_jump")
"""The drops for a sample's stamp; when they are nearly all (``STAMP_NOTE_SHARE``) the stamps are no seconds."""
STAMP_NOTE_SHARE = 0.9
"""Share of the samples dropped for their stamps (or of the steps longer than ``MAX_STEP_S``) that says so."""

MAX_GYRO_RAD_S = 100.0
"""Largest plausible angular rate, rad/s (5730 °/s: above the ±4000 °/s full scale of any MEMS gyro)."""

Vec3 = tuple[float, float, float]
Sample = tuple[float, float, float, float, Vec3 | None]
"""A taken sample: ``(t, x, y, z, gyro or None)``."""


def _real(v: Any) -> float | None:
    """``v`` as a float if it is a real number (never a bool); ±inf for an int beyond the float range."""
    if type(v) is float:
        return v
    if isinstance(v, bool | np.bool_) or not isinstance(v, numbers.Real):
        return None
    try:
        try:
            return float(v)
        except OverflowError:  # a Python int or Fraction beyond the float range
            return math.inf if v > 0 else -math.inf
    except Exception:  # a Real whose float() or comparison raises: not a usable number
        return None


def _vector3(v: Any) -> Vec3 | None:
    """``v`` as three floats, or None when it is not three real numbers (never raises)."""
    tv = type(v)
    if (tv is list or tv is tuple) and len(v) == 3:  # the common case first: three Python floats
        x, y, z = v
        if type(x) is float and type(y) is float and type(z) is float:
            return x, y, z
    try:
        if isinstance(v, np.ndarray):
            if v.size != 3:
                return None
            kind = v.dtype.kind
            if kind in "iuf":
                x, y, z = np.asarray(v).reshape(3).tolist()  # asarray: an np.matrix reshapes to (1, 3)
                return float(x), float(y), float(z)
            if kind != "O":
                return None  # bool, complex, string, datetime arrays
            v = np.asarray(v).reshape(3).tolist()
        elif isinstance(v, str | bytes | bytearray | Mapping) or len(v) != 3:
            return None
        x, y, z = _real(v[0]), _real(v[1]), _real(v[2])
    except Exception:  # an arbitrary object may raise anything from len, indexing or float: malformed
        return None
    if x is None or y is None or z is None:
        return None
    return x, y, z


class Intake:
    """Sanity checks, stamp handling and drop counts of one sensor's samples (see the module docstring).

    Args:
        config: the calibrator's options (magnitudes, ``max_rate_hz``, ``max_stamp_gap_s``,
            ``new_time_base_after``).
        use_gyro: read the gyro argument (the accelerometer's gate; the magnetometer's gyro-aided fit).
    """

    def __init__(self, config: PipelineConfig, *, use_gyro: bool = False) -> None:
        self.config = config
        self.use_gyro = use_gyro
        self.dropped = dict.fromkeys(DROP_REASONS, 0)
        self.seen = 0
        self.taken = 0
        self.gyro_ignored = 0
        self.time_base_resets = 0
        self.new_base_step: float | None = None
        """Set by ``take`` to ``t - last`` when this sample started a new time base, else None."""
        self._last_t: float | None = None
        self._last_taken_t = -math.inf
        self._off_last: float | None = None
        self._off_count = 0
        self._bad: tuple[float | None, float | None] = (None, None)  # the last two stamps beyond MAX_STAMP_S
        self._jump: tuple[float, float] | None = None  # (stamp, step) of the last stamp_jump
        self._slow = 0  # steps on the time base longer than MAX_STEP_S (against ``taken``: no count per sample)
        self._slow_step = 0.0
        self.last_norms: dict[str, float] = {}
        """The norm of the last sample dropped as ``zero`` and of the last dropped as ``magnitude``."""
        self.zero_rows = 0
        """Samples dropped as ``zero`` that were exactly (0, 0, 0): a driver's placeholder, not a reading."""
        self._learning: list[float] = []
        self._learnt: tuple[float, float, float] | None = None  # (median norm, low, high)
        self._window_n = max(1, RELEARN_FACTOR * config.learn_magnitude_samples)
        self._window: deque[Vec3 | None] = deque(maxlen=self._window_n)
        self._outside = 0  # samples of the window outside the learnt limits (the samples; None: within)
        self._recheck = 0  # samples to wait before the next relearn check after one refused
        self._relearnt: tuple[int, float, float, float, float] | None = None  # times, t, old median, old low, old high
        self._relearn_refused = False
        self.relearnt_now = False
        """Set by ``take`` when this sample made the intake relearn its limits (and is within the new ones)."""
        self.expected: float | None = None
        """The current calibration's typical raw norm (set by the calibrator): learnt limits that hold it are kept."""
        self.rails = RailWatch()
        """Saturated axes found in the samples that passed the checks before it (``saturated``)."""

    @property
    def limits(self) -> tuple[float, float]:
        """The magnitude limits in use: the learnt ones, else the configuration's."""
        if self._learnt is not None:
            return self._learnt[1], self._learnt[2]
        return self.config.min_magnitude, self.config.max_magnitude

    @property
    def learning(self) -> bool:
        """The limits are still being learnt from the first samples."""
        return self._learnt is None and self.config.learn_magnitude_samples > 0

    @property
    def learnt(self) -> str:
        """How the limits were learnt ("" when they come from the configuration)."""
        if self._learnt is None:
            return "" if not self.learning else (f"learning magnitude limits for unit {self.config.unit!r} "
                                                 f"({len(self._learning)} of {self.config.learn_magnitude_samples} samples)")
        m, lo, hi = self._learnt
        n = self.config.learn_magnitude_samples
        if self._relearnt is None:
            how = f"learnt from the first {n} samples (median |v| {m:.4g})"
        else:
            k, t, m0, lo0, hi0 = self._relearnt
            how = (f"relearnt at t={t:.2f} s{f' ({k}x)' if k > 1 else ''} from {n} samples (median |v| {m:.4g}): "
                   f"at least {RELEARN_SHARE:.0%} of the last {self._window_n} samples were outside the limits "
                   f"[{lo0:.4g}, {hi0:.4g}] learnt before (median |v| {m0:.4g})")
        return (f"unit {self.config.unit!r} has no known scale: magnitude limits [{lo:.4g}, {hi:.4g}] {how}; "
                "no field-strength check")

    def take(self, t: Any, xyz: Any, gyro: Any = None) -> tuple[float, Vec3, Vec3 | None] | None:
        """``(t, (x, y, z), gyro or None)`` when the sample is good, else None (the drop is counted)."""
        self.seen += 1
        self.new_base_step = None
        self.relearnt_now = False
        got = self._check(t, xyz)
        if type(got) is str:
            self.dropped[got] += 1
            return None
        self.taken += 1
        if gyro is None or not self.use_gyro:
            return got
        g = _vector3(gyro)
        if g is None or not math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) <= MAX_GYRO_RAD_S:
            g = None  # also NaN: the comparison is False
            self.gyro_ignored += 1
        return got[0], got[1], g

    def gyro_note(self) -> str:
        """What a status says of the gyro rates ignored ("" when none): a count of ignored rates alone left a gyro given in
        raw counts unexplained (every rate of a real log ignored, the status silent)."""
        if not self.gyro_ignored:
            return ""
        return (f"{self.gyro_ignored} of {self.taken} samples' gyro rates ignored (not finite, or above {MAX_GYRO_RAD_S:g} "
                "rad/s: give the rates in rad/s; raw counts need the gyro's scale)")

    def _check(self, t: Any, xyz: Any) -> str | tuple[float, Vec3, None]:
        """``(t, (x, y, z), None)`` for a good sample (``take`` reads the gyro), else the drop reason."""
        v = _vector3(xyz)
        if v is None:
            return "wrong_size"
        ts = t if type(t) is float else _real(t)  # the common case without a call
        if ts is None:
            return "bad_stamp"
        x, y, z = v
        mag = math.sqrt(x * x + y * y + z * z)  # finite unless a component is not (or the squares overflow)
        finite = mag < math.inf or (math.isfinite(x) and math.isfinite(y) and math.isfinite(z))
        if not (finite and math.isfinite(ts)):
            return "nonfinite"
        if not -MAX_STAMP_S <= ts <= MAX_STAMP_S:
            self._bad = (self._bad[1], ts)
            return "bad_stamp"
        cfg = self.config
        learnt = self._learnt
        learning = learnt is None and cfg.learn_magnitude_samples > 0  # ``learning`` and ``limits``, without the calls
        if learnt is not None:
            lo, hi = learnt[1], learnt[2]
        else:
            lo, hi = (0.0, cfg.max_magnitude) if learning else (cfg.min_magnitude, cfg.max_magnitude)
        if not lo < mag <= hi:
            if mag:  # a zero row is counted as one (``zero_rows``), never quoted as a norm
                self.last_norms["zero" if mag <= lo else "magnitude"] = mag if mag < math.inf else math.hypot(x, y, z)  # 1e308s
            if self._learnt is None or not self._watch(v if mag else None, ts):
                self.zero_rows += mag == 0.0
                return "zero" if mag <= lo else "magnitude"
        elif learnt is not None:
            self._watch(None, ts)
        reason = self._stamp(ts)
        if reason:
            return reason
        if ts - self._last_taken_t < cfg.min_period_s:
            return "burst"
        self._last_taken_t = ts
        if cfg.drop_saturated and self.rails.push(x, y, z):
            return "saturated"
        if learning:
            self._learning.append(mag)
            if len(self._learning) >= cfg.learn_magnitude_samples:
                m = float(np.median(self._learning))
                self._learnt = (m, LEARN_LOW * m, LEARN_HIGH * m)
                self._learning = []
        return ts, v, None

    def _watch(self, v: Vec3 | None, t: float) -> bool:
        """One more sample against learnt limits (``v`` when outside them and not zero, else None); True when
        the limits were relearnt just now from the samples outside them and hold this one (``units``).

        Not relearnt: while the current calibration's field lies within the limits (``expected``: the samples
        are wrong, not the limits), nor from samples that do not turn (``STATIC_SPREAD``: a sensor that reads
        its rails, saturated or stuck, for a while after a good start; a field at rest waits until it turns)."""
        w = self._window
        if len(w) == self._window_n and w[0] is not None:
            self._outside -= 1
        w.append(v)
        if v is None:
            return False
        self._outside += 1
        self._recheck -= 1
        if len(w) < self._window_n or self._outside < RELEARN_SHARE * len(w) or self._recheck > 0:
            return False
        assert self._learnt is not None
        m0, lo0, hi0 = self._learnt
        n = self.config.learn_magnitude_samples
        pts = np.array([u for u in w if u is not None], dtype=np.float64)
        self._relearn_refused = self.expected is not None and lo0 < self.expected <= hi0
        if self._relearn_refused or relative_spread(pts) < STATIC_SPREAD:
            self._recheck = n  # both are slow to change: look again in a while (it costs a few tens of us)
            return False
        m = float(np.median(np.linalg.norm(pts[-n:], axis=1)))
        self._learnt = (m, LEARN_LOW * m, LEARN_HIGH * m)
        self._relearnt = (1 if self._relearnt is None else self._relearnt[0] + 1, t, m0, lo0, hi0)
        w.clear()
        self._outside = 0
        mag = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        self.relearnt_now = LEARN_LOW * m < mag <= LEARN_HIGH * m
        return self.relearnt_now

    def drop_summary(self) -> str:
        """Why the samples were dropped, with the count, the offending norm, the limit and a hint ("" if none)."""
        total = sum(self.dropped.values())
        if not total:
            return ""
        worst = max(self.dropped, key=lambda k: self.dropped[k])
        n = self.dropped[worst]
        head = f"{total} of {self.seen} samples dropped"
        cfg = self.config
        lo, hi = self.limits
        bound = "max" if worst == "magnitude" else "min"
        if self._learnt is not None:  # no option to change: the limits follow the data
            where = "learnt"
            hint = ("the calibration's field lies within the limits: these samples are not the field" if self._relearn_refused
                    else f"the limits are relearnt once {RELEARN_SHARE:.0%} of the last {self._window_n} samples fall "
                         "outside them")
        else:
            where = raise_hint(cfg.sensor, f"{bound}_magnitude", "raise" if bound == "max" else "lower")
            hint = f"set the raw unit: --unit in margcal replay and calibrate, {cfg.sensor}.unit in the node"
        last = self.last_norms.get(worst)
        if worst == "magnitude" and last is not None:
            return (f"{head}: {n} x |v| above the limit, last |v| = {last:.4g} > {hi:.4g} {cfg.unit} "
                    f"({where}); {hint}")
        if worst == "zero" and self.zero_rows == n:
            return f"{head}: {n} all-zero rows (0, 0, 0): no reading, dropped"
        if worst == "zero" and last is not None:
            zeros = f", {self.zero_rows} of them all-zero rows" if self.zero_rows else ""
            return (f"{head}: {n} x |v| at or below the limit{zeros}, last non-zero |v| = {last:.4g} <= {lo:.4g} {cfg.unit} "
                    f"({where}); {hint}")
        note = self.stamp_note() if worst in STAMP_REASONS else ""
        return f"{head}: {n} x {worst}{'; ' + note if note else ''}"

    def stamp_note(self) -> str:
        """What the stamps look like when they are not seconds, and what to do ("" when they may be seconds):
        nearly every sample dropped for its stamp (beyond ``MAX_STAMP_S``, repeated, jumping), or nearly every
        step on the time base longer than ``MAX_STEP_S`` (ms stamps of a 100 Hz sensor step by 10)."""
        d = self.dropped
        stamps = sum(d[k] for k in STAMP_REASONS)
        if self.seen >= MIN_STEPS and stamps >= STAMP_NOTE_SHARE * self.seen:
            worst = max(STAMP_REASONS, key=lambda k: d[k])
            prev, last = self._bad
            if worst == "bad_stamp" and last is not None:
                step = last - prev if prev is not None and last > prev else None
                unit = stamp_unit(last, step)
                what = f"they look like {unit}" if unit else "no time in seconds"
                return f"stamps of {last:.6g} are beyond {MAX_STAMP_S:g} s (31,700 years): {what}; give seconds"
            if worst == "repeated_stamp" and self._last_t is not None:
                return f"the stamps do not advance (each {self._last_t:.6g}): give each sample its time in seconds"
            if worst == "stamp_jump" and self._jump is not None:
                t, step = self._jump
                return self._step_note(t, step, f"a jump beyond max_stamp_gap_s {self.config.max_stamp_gap_s:g} s")
        if self.taken >= MIN_STEPS and self._slow >= STAMP_NOTE_SHARE * self.taken and self._last_t is not None:
            return self._step_note(self._last_t, self._slow_step, "the last step")
        return ""

    @staticmethod
    def _step_note(t: float, step: float, which: str) -> str:
        unit = stamp_unit(t, step)
        what = f"they look like {unit}" if unit else "not seconds"
        return f"stamps step by {step:.4g} ({which}), one sample every {step:.4g} s if seconds: {what}; give seconds"

    def _stamp(self, t: float) -> str:
        """"" when ``t`` is on the time base (or starts a new one), else the drop reason."""
        last = self._last_t
        gap = self.config.max_stamp_gap_s
        if last is not None:
            dt = t - last
            if dt == 0.0:
                return "repeated_stamp"
            if not 0.0 < dt <= gap:
                off = self._off_last
                self._off_count = self._off_count + 1 if off is not None and 0.0 < t - off <= gap else 1
                self._off_last = t
                if self._off_count < self.config.new_time_base_after:
                    if dt > 0.0:  # the step from the sample before (stamps that all jump: their step)
                        self._jump = (t, t - off if off is not None and t > off else dt)
                        return "stamp_jump"
                    return "backwards_stamp"
                self.time_base_resets += 1
                self.new_base_step = dt
                self._last_taken_t = -math.inf
            elif dt > MAX_STEP_S:
                self._slow += 1
                self._slow_step = dt
        self._off_last, self._off_count = None, 0
        self._last_t = t
        return ""


class SpikeFilter:
    """Held-back check of each taken magnetometer sample against its neighbours (see the module docstring).

    ``push(sample)`` returns the samples to hand on now, in stamp order, and how many held ones were
    spikes; ``pending`` samples are held; ``flush`` hands them on (a new time base). The first two samples
    of a stream have no predecessor: they are held until the third, and one far from both others (``FAR``
    times farther than those two are apart, or than ``FLOOR`` of their norm) is a spike.
    """

    FAR = 10.0
    """A step beyond this many times the usual step (the upper quartile of the last ``STEPS``) holds the sample ..."""
    STEPS = 16
    """... those steps (between consecutive taken samples) ...,"""
    FLOOR = 1e-2
    """... the usual step at least this share of the last sample's norm and the smallest step seen that was not 0
    (a quantised sensor at rest steps by 0 or by one count)."""
    HOLD = 3
    """Most samples held in a row: a longer excursion is the stream moving (a jump, a fast turn), handed on."""
    BACK = 2.0
    """The held samples are spikes when the next one is this many times nearer to the last sample handed on
    than both the step into the excursion and the step out of it."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the stream (a new time base): the next samples start one."""
        self._anchor: Vec3 | None = None  # the last sample handed on
        self._last: Vec3 = (0.0, 0.0, 0.0)  # the last sample taken
        self._steps: deque[float] = deque(maxlen=self.STEPS)
        self._quantum = math.inf  # the smallest step seen that was not 0
        self._held: list[Sample] = []  # held back: the first samples of a stream, or a far step and what followed

    @property
    def pending(self) -> int:
        """Samples held back."""
        return len(self._held)

    def flush(self) -> list[Sample]:
        """The held samples, handed on (the filter keeps no sample)."""
        out, self._held = self._held, []
        return out

    def push(self, sample: Sample) -> tuple[list[Sample], int]:
        """``(samples to hand on now, spikes dropped)`` after one more taken sample."""
        if self._anchor is None:
            return self._start(sample)
        _, x, y, z, _ = sample
        v = (x, y, z)
        step = self._step(v)
        held, anchor = self._held, self._anchor
        if held:
            back = math.dist(anchor, v) * self.BACK
            if back < math.dist(anchor, held[0][1:4]) and back < step:  # out and back: the held ones were spikes
                n = len(held)
                held.clear()
                self._anchor = v
                return [sample], n
            if len(held) < self.HOLD:
                held.append(sample)
                return [], 0
            out = [*held, sample]
            held.clear()
            self._anchor = v
            return out, 0
        if self._usual is not None and step > self._far():  # None: within the bound that needs no sort (_step)
            held.append(sample)
            return [], 0
        self._anchor = v
        return [sample], 0

    def _step(self, v: Vec3) -> float:
        """The step from the last sample taken to ``v`` (recorded after the usual step was read: ``_far``).

        The usual step (a sort of the last ``STEPS``) is read only for a step beyond ``FAR`` times the quantum
        and the floor, the part of ``_far`` that needs no sort: a smaller step is no far one whatever the
        usual step, and nearly every step is smaller (a sort per sample was a tenth of the sample path). For such
        a step ``_usual`` is None: ``push`` then reads no ``_far``, which would be that bound."""
        step = math.dist(self._last, v)
        steps = self._steps
        if 0.0 < step < self._quantum:
            self._quantum = step
        a = self._anchor  # (the bound below is _far's own value without the usual step, to the last bit)
        cheap = 0.0
        if a is not None:
            q, floor = self._quantum, self.FLOOR * math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
            cheap = self.FAR * (floor if floor > q else q)  # max(q, floor) without the call (a tenth of the filter's time)
        self._usual = (sorted(steps)[(3 * len(steps)) // 4] if steps else step) if step > cheap else None
        steps.append(step)
        self._last = v
        return step

    def _far(self) -> float:
        """The step beyond which a sample is held: ``FAR`` times the usual step or its floor."""
        a = self._anchor
        assert a is not None and self._usual is not None
        return self.FAR * max(self._usual, self._quantum, self.FLOOR * math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]))

    def _start(self, sample: Sample) -> tuple[list[Sample], int]:
        """The first three samples of a stream: drop the one far from both others, start the stream from the rest."""
        held = self._held
        held.append(sample)
        if len(held) < 3:
            return [], 0
        s0, s1, s2 = held
        p0, p1, p2 = s0[1:4], s1[1:4], s2[1:4]
        d01, d12, d02 = math.dist(p0, p1), math.dist(p1, p2), math.dist(p0, p2)
        held.clear()
        floor = self.FLOOR * math.sqrt(p2[0] * p2[0] + p2[1] * p2[1] + p2[2] * p2[2])
        if self.FAR * max(d12, floor) < min(d01, d02):
            out, n = [s1], 1  # s0 a spike: s1 starts the stream
        elif self.FAR * max(d02, floor) < min(d01, d12):
            out, n = [s0], 1  # s1 a spike
        else:
            out, n = [s0, s1], 0
            self._last = p0
            self._step(p1)
        self._anchor = self._last = out[-1][1:4]
        more, k = self.push(s2)
        return out + more, n + k
