"""Input sanity of the streaming calibrator: one raw sample in, a clean one or a counted drop out.

``Intake.take(t, xyz, gyro)`` is step 1 of ``SensorCalibrator.push``. It never raises, whatever the
objects (the node and the replay hand over what a message or a file held):

- ``xyz`` must be three real numbers: a numeric numpy array of size 3 or a sequence of length 3 of
  ints/floats/numpy scalars. Anything else (None, strings, bools, dicts, nested or short lists,
  complex or string arrays, objects whose ``len`` or ``float`` raises) is ``wrong_size``; a stamp
  that is not a real number, or beyond ``MAX_STAMP_S``, is ``bad_stamp``.
- NaN or ±Inf, also a Python int beyond the float range, is ``nonfinite``; a norm at most
  ``min_magnitude`` is ``zero``, above ``max_magnitude`` ``magnitude`` (the last offending norm is kept
  in ``last_magnitude`` for the status). With ``learn_magnitude_samples`` > 0 (a unit without a known
  scale, such as counts) the first that many samples pass with any non-zero norm up to ``max_magnitude`` and their
  median norm ``m`` sets the limits to ``[units.LEARN_LOW m, units.LEARN_HIGH m]`` (``learnt`` says so).
- Stamps, the time base: a sample is on the current time base when its step from the last one is in
  ``(0, max_stamp_gap_s]``. An equal stamp is ``repeated_stamp``. A sample off the time base
  (behind it: ``backwards_stamp``; ahead by more than ``max_stamp_gap_s``: ``stamp_jump``) is dropped
  and remembered: when ``new_time_base_after`` samples in a row are off the time base and consistent
  with each other (each one step in ``(0, max_stamp_gap_s]`` after the previous), the clock has
  restarted (a bag replayed in a loop, a driver restart, a clock switched): the last of them starts a
  new time base (counted in ``time_base_resets``; ``new_base_step`` says how far the stamps moved)
  and is taken. A lone glitch (one sample an hour or 1e9 s ahead, or a late one) is dropped once and
  the samples after it go on as before. A restart thus costs ``new_time_base_after - 1`` samples.
- ``burst``: closer than ``1 / max_rate_hz`` to the last taken sample.
- The gyro (the accelerometer's gate; the magnetometer's gyro-aided fit, ``gyro_aided``) is optional: one
  that is malformed, not finite or beyond ``MAX_GYRO_RAD_S`` is treated as absent for that sample (counted
  in ``gyro_ignored``), so a broken gyro costs the gate's motion check or the fit's rate, never the samples.

Every sample is counted once: ``seen == taken + sum(dropped.values())`` here; the calibrator adds
``outlier`` (a taken sample it refuses later) to the same ``dropped``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from typing import Any

import numpy as np

from .config import PipelineConfig
from .units import LEARN_HIGH, LEARN_LOW

__all__ = ["DROP_REASONS", "MAX_GYRO_RAD_S", "MAX_STAMP_S", "Intake"]

DROP_REASONS = ("wrong_size", "bad_stamp", "nonfinite", "zero", "magnitude", "repeated_stamp", "backwards_stamp",
                "stamp_jump", "burst", "outlier")
"""Why a sample was dropped (the keys of ``dropped``); ``outlier`` is the calibrator's."""

MAX_STAMP_S = 1e12
"""Largest plausible |stamp|, s (ROS time fits in 2^32 s); keeps every stamp difference finite."""

MAX_GYRO_RAD_S = 100.0
"""Largest plausible angular rate, rad/s (5730 °/s: above the ±4000 °/s full scale of any MEMS gyro)."""

Vec3 = tuple[float, float, float]


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
        self.last_magnitude: float | None = None
        """The norm of the last sample dropped as ``zero`` or ``magnitude``."""
        self._learning: list[float] = []
        self._learnt: tuple[float, float, float] | None = None  # (median norm, low, high)

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
        return (f"unit {self.config.unit!r} has no known scale: magnitude limits [{lo:.4g}, {hi:.4g}] learnt from "
                f"the first {self.config.learn_magnitude_samples} samples (median |v| {m:.4g}); no field-strength check")

    def take(self, t: Any, xyz: Any, gyro: Any = None) -> tuple[float, Vec3, Vec3 | None] | None:
        """``(t, (x, y, z), gyro or None)`` when the sample is good, else None (the drop is counted)."""
        self.seen += 1
        self.new_base_step = None
        got = self._check(t, xyz)
        if isinstance(got, str):
            self.dropped[got] += 1
            return None
        self.taken += 1
        g = None
        if self.use_gyro and gyro is not None:
            g = _vector3(gyro)
            if g is None or not math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) <= MAX_GYRO_RAD_S:
                g = None  # also NaN: the comparison is False
                self.gyro_ignored += 1
        return got[0], got[1], g

    def _check(self, t: Any, xyz: Any) -> str | tuple[float, Vec3]:
        v = _vector3(xyz)
        if v is None:
            return "wrong_size"
        ts = _real(t)
        if ts is None:
            return "bad_stamp"
        x, y, z = v
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(ts)):
            return "nonfinite"
        if abs(ts) > MAX_STAMP_S:
            return "bad_stamp"
        mag = math.sqrt(x * x + y * y + z * z)
        cfg = self.config
        learning = self.learning
        lo, hi = (0.0, cfg.max_magnitude) if learning else self.limits
        if mag <= lo:
            self.last_magnitude = mag
            return "zero"
        if mag > hi:
            self.last_magnitude = mag
            return "magnitude"
        reason = self._stamp(ts)
        if reason:
            return reason
        if ts - self._last_taken_t < cfg.min_period_s:
            return "burst"
        self._last_taken_t = ts
        if learning:
            self._learning.append(mag)
            if len(self._learning) >= cfg.learn_magnitude_samples:
                m = float(np.median(self._learning))
                self._learnt = (m, LEARN_LOW * m, LEARN_HIGH * m)
                self._learning = []
        return ts, v

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
        where = "learnt" if self._learnt is not None else f"{cfg.sensor}.{'max' if worst == 'magnitude' else 'min'}_magnitude"
        if worst == "magnitude" and self.last_magnitude is not None:
            return (f"{head}: {n} x |v| above the limit, last |v| = {self.last_magnitude:.4g} > {hi:.4g} {cfg.unit} "
                    f"({where}); set --unit to the recording's unit or raise {cfg.sensor}.max_magnitude")
        if worst == "zero" and self.last_magnitude is not None:
            return (f"{head}: {n} x |v| at or below the limit, last |v| = {self.last_magnitude:.4g} <= {lo:.4g} "
                    f"{cfg.unit} ({where}); set --unit to the recording's unit or lower {cfg.sensor}.min_magnitude")
        return f"{head}: {n} x {worst}"

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
                    return "backwards_stamp" if dt < 0.0 else "stamp_jump"
                self.time_base_resets += 1
                self.new_base_step = dt
                self._last_taken_t = -math.inf
        self._off_last, self._off_count = None, 0
        self._last_t = t
        return ""
