"""Inactivity gate: keep quasi-static accelerometer samples, one averaged sample per still window.

An accelerometer measures gravity alone only when the body is at rest, so an ellipsoid fit must see
quasi-static samples. Gietzelt et al. 2013 (§2.4) detect inactivity sections with the coefficient of
variation ``c = std / mean`` over a sliding window of two seconds, threshold ``c = 3e-3``, computed on
the x axis of *raw ADC counts*. That works there because the raw x axis sits on a large ADC offset
(hundreds of counts), so its mean is never near zero and ``std / mean`` is a scaled standard deviation.
On zero-centred SI data (m/s², REP-103) a per-axis CV is meaningless: an axis lying horizontal has a
mean near 0 and its CV blows up at rest, an axis along gravity has mean ±g, and the sign and size of
the denominator change with orientation. This gate therefore uses

- the CV of the vector norm, ``std(|f|) / mean(|f|)`` (at rest ``|f| = g`` whatever the orientation),
  with Gietzelt's threshold 3e-3 as default; and
- the per-axis spread relative to the norm, ``max_k std(f_k) / mean(|f|)``, which catches a slow
  rotation at constant norm that the norm CV cannot see; and
- optionally, when angular velocity is given, a gyro-norm threshold (every sample of the window).

A variance over two seconds reacts slowly to the first samples of a move (a few samples barely change
it), so two quick checks in the same relative units sharpen the edges of a still stretch: the mean
of the last ``short_fraction * window_s`` seconds must stay within ``axis_threshold * mean(|f|)`` of
the window mean on every axis, and the newest sample within ``outlier_factor`` times that. When a
stretch starts, its start is moved past the last sample of the window that breaks the latter bound
(the tail of the previous move).

The window is time based (message stamps, default 2.0 s: at 50 Hz the 100 samples after ``t - 2 s``, so a
pose logged as 100 samples at 50 Hz with no move recorded between poses fits in one window), kept as a deque with running sums of
deviations from a reference sample, so each push costs O(1) amortised (the sums are recomputed from
the deque now and then to stop rounding drift). A still stretch starts at the first sample of the
first window that passes; the gate emits the window mean once the stretch has lasted ``min_still_s``
and then at most once per ``window_s`` while it lasts (``max_per_stretch`` caps it), so a parked
robot produces a trickle, not a flood, and each emitted mean averages a window of independent noise.

**Gyro-aided rule** (``GyroAidedGate``). Gietzelt's two seconds are needed because the norm CV alone
must tell rest from motion: a slow rotation at constant norm, or a move whose acceleration happens to
keep ``|f|`` steady, passes a short window. With angular velocity on every sample, the gyro says the
sensor is not rotating (``|omega|`` below ``gyro_threshold`` on every sample of the window) and the norm
CV that it is not accelerating, so a window of ``gyro_window_s`` (default 1 s; at 100 Hz 100 samples,
plenty for the CV and axis-spread estimates) is enough. Samples with a gyro reading go to a gate with
the short window and the gyro check, samples without one to Gietzelt's two-second gate; a robot that
rests 1-1.5 s between moves (a pick-and-place arm, a legged robot) then yields still samples.

**Learnt rest noise** (``learn=True``). Gietzelt's 3e-3 fits his sensor, not every sensor: an MPU6050
lying on a desk shows a per-axis spread of 4-5e-3 g (white noise), so with the fixed threshold it is never
still. Once per window the gate asks whether the window's spread is white noise alone: its per-axis
spread at most ``REST_LIKE`` times the white-noise level of the same window, estimated from successive
differences (``rms(diff) / sqrt 2``, which a smooth move barely raises), and both statistics within the
cap (a shaken sensor's spread can be white too). Such rest-like windows go into a
bounded history (``LEARN_HISTORY`` windows); the thresholds become ``clip(LEARN_FACTOR x q, configured,
cap)`` where ``q`` is the history's ``LEARN_QUANTILE`` quantile of the per-axis spread and of the norm CV
(the shift and outlier bounds scale with the axis threshold). They only ever widen from the configured
values, and never beyond ``LEARN_CAP`` (1 % of the norm): a slow move has a spread far above its white
noise and is not rest-like, so it never teaches the gate; the least-moving 2 s window of the shared
MPU6050 full-sphere move has a norm CV of 0.033 and an axis spread of 0.075, 3x and 7x the cap; and the
mean of a window with 1 % spread is off the norm by at most ``spread² / 2`` = 5e-5 from a rotation.
A sensor whose noise is low-pass filtered (successive samples correlated) is never rest-like and keeps
the configured thresholds. The learning costs one pass over the window per window (O(1) amortised).

Bad input never raises: non-finite or malformed samples, repeated or backwards stamps are dropped and
counted; a gap longer than the window (or a jump back by more than a window) resets the window. Stamps
are compared by their differences, so stamps whose float spacing exceeds the window (nanoseconds since
the epoch read as seconds) are repeated stamps or gaps, never an empty window.
"""

from __future__ import annotations

import logging
import math
from collections import deque

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model.errors import ConfigError

__all__ = ["LEARN_CAP", "GyroAidedGate", "InactivityGate"]

_log = logging.getLogger(__name__)

_RESUM_EVERY = 4096
"""Recompute the running sums from the window after this many pushes (rounding drift)."""
_STAMP_TOL = 1e-6
"""Stamps this close count as equal at the window's edge, s (rounding of t = i / rate; epoch stamps: 2.4e-7 s)."""
LEARN_CAP = 1e-2
"""Largest learnt threshold (norm CV and per-axis spread over the norm): 3.3x Gietzelt's (module docstring)."""
LEARN_FACTOR = 1.5
"""Learnt threshold over the rest floor: margin for the window-to-window scatter of a noise estimate."""
LEARN_QUANTILE = 25.0
"""Percentile of the rest-like windows' statistics taken as the rest floor."""
LEARN_HISTORY = 32
"""Rest-like windows remembered (about a minute at 2 s)."""
REST_LIKE = 1.5
"""A window is rest-like when its per-axis spread is at most this times its white-noise level."""


def _check(name: str, value: float | None, *, allow_none: bool = False, allow_zero: bool = False) -> float | None:
    if value is None:
        if allow_none:
            return None
        msg = f"{name} must be a number, got None"
        raise ConfigError(msg)
    v = float(value)
    if not (math.isfinite(v) and (v > 0.0 or (allow_zero and v == 0.0))):
        msg = f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}"
        raise ConfigError(msg)
    return v


class InactivityGate:
    """Sliding-window still detector that emits averaged quasi-static samples.

    Args:
        window_s: Window length, seconds of message stamps (Gietzelt: 2 s).
        cv_threshold: Upper bound of ``std(|f|) / mean(|f|)`` (Gietzelt: 3e-3).
        axis_threshold: Upper bound of ``max_k std(f_k) / mean(|f|)``; ``cv_threshold`` when None.
        gyro_threshold: Upper bound of ``|omega|`` (rad/s) for every sample in the window that has a
            gyro reading; off when None.
        min_still_s: Still duration (from the window start) required before the first emission; a
            full passing window (``window_s``) is always required, so None (0) adds nothing.
        max_per_stretch: Emissions per still stretch at most; unlimited (one per window) when None.
        short_fraction: Length of the short window for the mean-shift check, as a fraction of ``window_s``.
        outlier_factor: Bound of a single sample's deviation from the window mean, in units of
            ``axis_threshold * mean(|f|)``.
        learn: Learn the sensor's rest noise and widen both thresholds to it, up to ``learn_cap``
            (module docstring, *learnt rest noise*).
        learn_cap: Largest learnt threshold (a fraction of the norm).
    """

    def __init__(
        self,
        window_s: float = 2.0,
        cv_threshold: float = 3e-3,
        axis_threshold: float | None = None,
        gyro_threshold: float | None = None,
        min_still_s: float | None = None,
        *,
        max_per_stretch: int | None = None,
        short_fraction: float = 0.125,
        outlier_factor: float = 3.0,
        learn: bool = False,
        learn_cap: float = LEARN_CAP,
    ) -> None:
        self.window_s = _check("window_s", window_s)
        self.cv_threshold = _check("cv_threshold", cv_threshold)
        self.axis_threshold = _check("axis_threshold", axis_threshold, allow_none=True) or self.cv_threshold
        self.gyro_threshold = _check("gyro_threshold", gyro_threshold, allow_none=True)
        self.min_still_s = _check("min_still_s", min_still_s, allow_none=True, allow_zero=True)
        if self.min_still_s is None:
            self.min_still_s = 0.0
        if max_per_stretch is not None and (not isinstance(max_per_stretch, int) or max_per_stretch < 1):
            msg = f"max_per_stretch must be a positive int or None, got {max_per_stretch!r}"
            raise ConfigError(msg)
        self.max_per_stretch = max_per_stretch
        self.short_s = self.window_s * _check("short_fraction", short_fraction)  # type: ignore[operator]
        self.outlier_factor = _check("outlier_factor", outlier_factor)
        self.learn = bool(learn)
        self.base_thresholds = (self.cv_threshold, self.axis_threshold)
        """The configured (norm CV, axis spread) thresholds; the learnt ones never go below them."""
        self.learn_cap = max(_check("learn_cap", learn_cap), *self.base_thresholds)  # type: ignore[type-var]
        self._rest: deque[tuple[float, float]] = deque(maxlen=LEARN_HISTORY)  # survives reset: the sensor's
        self._pushed = self._nonfinite = self._invalid = self._time = self._resets = 0
        self._emitted = self._stretches = 0
        self.reset()
        self._resets = 0

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Empty the window and end any still stretch (counted in ``counters['resets']``)."""
        self._win: deque[tuple[float, float, float, float, float, bool]] = deque()
        self._ref = (0.0, 0.0, 0.0, 0.0)
        self._s = [0.0] * 8  # sums of dx, dy, dz, dn, dx², dy², dz², dn² (deviations from _ref)
        self._n_gyro_high = 0
        self._short: deque[tuple[float, float, float, float]] = deque()
        self._ss = [0.0, 0.0, 0.0]  # sums of dx, dy, dz over the short window
        self._t_first: float | None = None
        self._t_last: float | None = None
        self._since_resum = 0
        self._still_since: float | None = None
        self._last_emit = -math.inf
        self._n_emit_stretch = 0
        self._last_cv = math.inf
        self._last_axis = math.inf
        self._last_shift = math.inf
        self._last_learn = -math.inf
        self._resets += 1

    @property
    def counters(self) -> dict[str, int]:
        """Pushed, dropped (nonfinite, time, invalid), resets, emitted samples and still stretches."""
        return {
            "pushed": self._pushed,
            "dropped_nonfinite": self._nonfinite,
            "dropped_time": self._time,
            "dropped_invalid": self._invalid,
            "resets": self._resets,
            "emitted": self._emitted,
            "stretches": self._stretches,
        }

    @property
    def is_still(self) -> bool:
        """True while the current window passes every test."""
        return self._still_since is not None

    @property
    def still_since(self) -> float | None:
        """Stamp of the first sample of the current still stretch, or None when moving."""
        return self._still_since

    @property
    def window_stats(self) -> tuple[float, float]:
        """The last evaluated (norm CV, per-axis spread / norm); inf before the window is full."""
        return self._last_cv, self._last_axis

    @property
    def thresholds(self) -> tuple[float, float]:
        """The (norm CV, axis spread) thresholds in use: the configured ones, or wider learnt ones."""
        return self.cv_threshold, self.axis_threshold

    @property
    def gyro_high_share(self) -> float:
        """Share of the window's samples whose rate is above ``gyro_threshold`` (0 without one or an empty window)."""
        return self._n_gyro_high / len(self._win) if self._win else 0.0

    @property
    def learnt(self) -> str:
        """The learnt thresholds in words ("" while none has widened)."""
        if (self.cv_threshold, self.axis_threshold) == self.base_thresholds:
            return ""
        return (f"learnt from {len(self._rest)} rest windows: CV < {self.cv_threshold:.2g}, axis spread < "
                f"{self.axis_threshold:.2g} (configured {self.base_thresholds[0]:.2g}, cap {self.learn_cap:.2g})")

    def _learn(self, t: float, mean_n: float) -> None:
        """Once per window: keep the window's statistics when they are white noise alone; widen the thresholds."""
        self._last_learn = t
        a = np.array([w[1:4] for w in self._win])
        white = float(np.sqrt(np.mean(np.diff(a, axis=0) ** 2, axis=0) / 2.0).max()) / mean_n
        if not (self._last_axis <= REST_LIKE * white and max(self._last_axis, self._last_cv) <= self.learn_cap):
            return  # a move (spread beyond its white noise), or too noisy to be still even at the cap
        self._rest.append((self._last_cv, self._last_axis))
        cv, axis = np.percentile(np.array(self._rest), LEARN_QUANTILE, axis=0) * LEARN_FACTOR
        base_cv, base_axis = self.base_thresholds
        self.cv_threshold = min(max(float(cv), base_cv), self.learn_cap)
        self.axis_threshold = min(max(float(axis), base_axis), self.learn_cap)

    # ------------------------------------------------------------------ window sums
    def _add(self, x: float, y: float, z: float, n: float, sign: float) -> None:
        rx, ry, rz, rn = self._ref
        dx, dy, dz, dn = x - rx, y - ry, z - rz, n - rn
        s = self._s
        s[0] += sign * dx
        s[1] += sign * dy
        s[2] += sign * dz
        s[3] += sign * dn
        s[4] += sign * dx * dx
        s[5] += sign * dy * dy
        s[6] += sign * dz * dz
        s[7] += sign * dn * dn

    def _resum(self) -> None:
        self._since_resum = 0
        self._s = [0.0] * 8
        if self._win:
            _, x, y, z, n, _ = self._win[-1]
            self._ref = (x, y, z, n)
        for _, x, y, z, n, _ in self._win:
            self._add(x, y, z, n, 1.0)
        rx, ry, rz, _ = self._ref
        self._ss = [0.0, 0.0, 0.0]
        for _, x, y, z in self._short:
            self._short_add(x - rx, y - ry, z - rz, 1.0)

    def _short_add(self, dx: float, dy: float, dz: float, sign: float) -> None:
        ss = self._ss
        ss[0] += sign * dx
        ss[1] += sign * dy
        ss[2] += sign * dz

    # ------------------------------------------------------------------ streaming path
    def push(self, t: float, xyz: ArrayLike, gyro: ArrayLike | None = None) -> NDArray[np.float64] | None:
        """Offer one sample; return the averaged still sample (3,) when one is emitted, else None."""
        self._pushed += 1
        try:
            t = float(t)
            x, y, z = float(xyz[0]), float(xyz[1]), float(xyz[2])  # type: ignore[index]
            g2 = None
            if gyro is not None:
                gx, gy, gz = float(gyro[0]), float(gyro[1]), float(gyro[2])  # type: ignore[index]
                if gx - gx != 0.0 or gy - gy != 0.0 or gz - gz != 0.0:
                    gx = math.nan
                g2 = gx * gx + gy * gy + gz * gz  # a finite but huge rate overflows to inf: rotating, not invalid
        except (TypeError, ValueError, IndexError, OverflowError):
            self._invalid += 1
            return None
        if t - t != 0.0:
            self._time += 1
            return None
        chk = x + y + z + (0.0 if g2 is None or g2 == math.inf else g2)
        if chk - chk != 0.0:
            self._nonfinite += 1
            return None
        if self._t_last is not None:
            dt = t - self._t_last
            if dt > self.window_s or dt < -self.window_s:
                _log.debug("inactivity gate reset: stamp step %.3f s", dt)
                self.reset()
            elif dt <= 0.0:
                self._time += 1
                return None
        self._t_last = t
        if self._t_first is None:
            self._t_first = t
        n = math.sqrt(x * x + y * y + z * z)
        high = g2 is not None and self.gyro_threshold is not None and g2 > self.gyro_threshold**2
        win = self._win
        if not win:
            self._ref = (x, y, z, n)
        win.append((t, x, y, z, n, high))
        self._add(x, y, z, n, 1.0)
        self._n_gyro_high += high
        # a window of window_s holds window_s x rate samples, not one more; stamp differences, not t - window_s, which
        # rounds back to t where float spacing exceeds the window (ns epoch stamps, 1.7e18) and emptied the window
        edge = self.window_s - _STAMP_TOL
        while t - win[0][0] >= edge:
            _, ox, oy, oz, on, oh = win.popleft()
            self._add(ox, oy, oz, on, -1.0)
            self._n_gyro_high -= oh
        rx, ry, rz, _ = self._ref
        short = self._short
        short.append((t, x, y, z))
        self._short_add(x - rx, y - ry, z - rz, 1.0)
        while t - short[0][0] > self.short_s:
            _, ox, oy, oz = short.popleft()
            self._short_add(ox - rx, oy - ry, oz - rz, -1.0)
        self._since_resum += 1
        if self._since_resum >= _RESUM_EVERY:
            self._resum()
        return self._evaluate(t)

    def _evaluate(self, t: float) -> NDArray[np.float64] | None:
        if t - self._t_first < self.window_s - _STAMP_TOL:  # type: ignore[operator]
            return None
        k = len(self._win)
        s = self._s
        rx, ry, rz, rn = self._ref
        mean_n = rn + s[3] / k
        if k < 2 or not mean_n > 0.0:
            self._still_since = None
            return None
        var_n = max(s[7] / k - (s[3] / k) ** 2, 0.0)
        var_ax = max(s[4] / k - (s[0] / k) ** 2, s[5] / k - (s[1] / k) ** 2, s[6] / k - (s[2] / k) ** 2, 0.0)
        self._last_cv = math.sqrt(var_n) / mean_n
        self._last_axis = math.sqrt(var_ax) / mean_n
        if self.learn and t - self._last_learn >= self.window_s:
            self._learn(t, mean_n)
        m = len(self._short)
        ss = self._ss
        shift = max(abs(ss[0] / m - s[0] / k), abs(ss[1] / m - s[1] / k), abs(ss[2] / m - s[2] / k)) / mean_n
        self._last_shift = shift
        bound = self.outlier_factor * self.axis_threshold * mean_n
        mx, my, mz = rx + s[0] / k, ry + s[1] / k, rz + s[2] / k
        _, x, y, z, _, _ = self._win[-1]
        still = (
            self._last_cv < self.cv_threshold
            and self._last_axis < self.axis_threshold
            and shift < self.axis_threshold
            and self._n_gyro_high == 0
            and abs(x - mx) < bound
            and abs(y - my) < bound
            and abs(z - mz) < bound
        )
        if not still:
            self._still_since = None
            return None
        if self._still_since is None:
            self._still_since = self._win[0][0]
            after_outlier = False
            for ts, x, y, z, _, _ in self._win:  # trim the tail of the previous move (once per stretch)
                if after_outlier:
                    self._still_since = ts
                after_outlier = abs(x - mx) >= bound or abs(y - my) >= bound or abs(z - mz) >= bound
            self._n_emit_stretch = 0
            self._stretches += 1
        if t - self._still_since < self.min_still_s or t - self._last_emit < self.window_s:  # type: ignore[operator]
            return None
        if self.max_per_stretch is not None and self._n_emit_stretch >= self.max_per_stretch:
            return None
        self._last_emit = t
        self._n_emit_stretch += 1
        self._emitted += 1
        return np.array([mx, my, mz])


class GyroAidedGate:
    """Two inactivity gates: a short one with a gyro check for samples with angular velocity, and
    Gietzelt's for samples without (see the module docstring's *gyro-aided rule*).

    Args:
        window_s, cv_threshold, gyro_threshold: the gate without a gyro (``InactivityGate``).
        gyro_window_s: the window when the sample has a gyro reading, s.
        gyro_rest_threshold: ``|omega|`` limit (rad/s) of the gyro-aided gate (``gyro_threshold`` when
            that is set and smaller).
    """

    def __init__(self, window_s: float = 2.0, cv_threshold: float = 3e-3, gyro_threshold: float | None = None,
                 *, gyro_window_s: float = 1.0, gyro_rest_threshold: float = 0.05, learn: bool = False) -> None:
        rest = _check("gyro_rest_threshold", gyro_rest_threshold)
        if gyro_threshold is not None:
            rest = min(rest, float(gyro_threshold))  # type: ignore[type-var]
        self.plain = InactivityGate(window_s=window_s, cv_threshold=cv_threshold, gyro_threshold=gyro_threshold,
                                    learn=learn)
        self.aided = InactivityGate(window_s=gyro_window_s, cv_threshold=cv_threshold, gyro_threshold=rest, learn=learn)
        self.gyro_seen = 0
        """Samples that came with a gyro reading (went to the gyro-aided gate)."""

    @property
    def window_s(self) -> float:
        """The still time in use: the gyro-aided window once a gyro has been seen, else Gietzelt's."""
        return float(self.aided.window_s if self.gyro_seen else self.plain.window_s)  # type: ignore[arg-type]

    @property
    def window_stats(self) -> tuple[float, float]:
        """The last evaluated (norm CV, per-axis spread / norm) of the window in use; inf before it is full."""
        return (self.aided if self.gyro_seen else self.plain).window_stats

    @property
    def thresholds(self) -> tuple[float, float]:
        """The (norm CV, axis spread) thresholds in use (learnt or configured) of the window in use."""
        return (self.aided if self.gyro_seen else self.plain).thresholds

    @property
    def learnt(self) -> str:
        """The learnt thresholds of the window in use in words ("" while none has widened)."""
        return (self.aided if self.gyro_seen else self.plain).learnt

    @property
    def gyro_busy(self) -> tuple[float, float] | None:
        """``(share, rest threshold rad/s)`` when the gyro-aided window in use holds rates above its threshold, else
        None: the accelerometer may be still while the gyro says it turns (a gyro in deg/s at rest reads ~0.1-1)."""
        share = self.aided.gyro_high_share if self.gyro_seen else 0.0
        return (share, float(self.aided.gyro_threshold)) if share > 0.0 else None  # type: ignore[arg-type]

    def reset(self) -> None:
        """Empty both windows."""
        self.plain.reset()
        self.aided.reset()

    @property
    def counters(self) -> dict[str, int]:
        """Both gates' counters summed, and ``gyro_seen``."""
        a, b = self.plain.counters, self.aided.counters
        return {**{k: a[k] + b[k] for k in a}, "gyro_seen": self.gyro_seen}

    def push(self, t: float, xyz: ArrayLike, gyro: ArrayLike | None = None) -> NDArray[np.float64] | None:
        """Offer one sample to the gate its gyro reading selects; the averaged still sample or None."""
        if gyro is None:
            return self.plain.push(t, xyz)
        self.gyro_seen += 1
        return self.aided.push(t, xyz, gyro)
