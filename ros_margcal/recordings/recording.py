"""A recording: a sensor time series, simulated or read from a file, with the checks every reader applies."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.errors import InputError, RecordingError

__all__ = ["MAX_STAMP_S", "MAX_STEP_S", "MIN_STEPS", "TIME_ORDERS", "Recording", "check_order", "check_sensor", "check_stamps",
           "continue_clock", "drop_stamp_glitches", "drop_zero_rows", "stamp_unit", "time_order"]

log = logging.getLogger(__name__)
Array = NDArray[np.float64]

TIME_ORDERS = ("check", "sort", "file")
"""What a reader does when the time goes backwards: refuse, sort stably, or keep the file's order and times."""

MAX_STAMP_S = 1e12
"""Largest plausible |stamp|, s (31,700 years; ROS time fits in 2^32 s); keeps every stamp difference finite. The
readers refuse a stamp beyond it, the stream's intake drops it as ``bad_stamp``."""
MAX_STEP_S = 2.0
"""Largest plausible typical step between samples, s: a sensor read less often (one sample per gate window)
calibrates nothing, while millisecond stamps of a sensor read at 400 Hz or less step by more."""
MIN_STEPS = 10
"""Forward steps a recording needs before its typical step is judged (a hand-made file of a few rows is not)."""
_UNITS = (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9))
_EPOCH_S = (1e8, 1e10)
"""Seconds since the epoch of a real clock (1973 to 2286)."""
_RATE_HZ = (1.0, 1e4)
"""Rates a MARG sensor is read at."""


@dataclass
class Recording:
    """A recorded (or simulated) sensor time series.

    Attributes:
        t: sample times, seconds, shape (n,), non-decreasing (unless read with ``order="file"``).
        raw: raw readings, shape (n, 3), raw units.
        truth: the true calibration (None for a real recording).
        true_field: the physical vector in the body frame before any effect, (n, 3), or None.
        still: True where the body was at rest (accelerometer streams), or None.
        gyro: angular rate in the body frame, rad/s, (n, 3), or None.
        temp: temperature, °C, (n,), or None.
        effects: the effects applied, name -> magnitude.
        sensor: "mag", "accel" or "".
        unit: unit of the raw readings ("T", "m/s^2", "gauss", ...).
        true_offset: the true offset per sample when it varies (events, drift), (n, 3), or None.
    """

    t: Array
    raw: Array
    truth: Calibration | None = None
    true_field: Array | None = None
    still: NDArray[np.bool_] | None = None
    gyro: Array | None = None
    temp: Array | None = None
    effects: dict[str, float] = field(default_factory=dict)
    sensor: str = ""
    unit: str = ""
    true_offset: Array | None = None

    def __len__(self) -> int:
        return int(self.raw.shape[0])

    def truth_at(self, time: float) -> Calibration:
        """The true calibration at ``time`` (the offset follows jumps and drift when recorded)."""
        if self.truth is None:
            msg = "this recording has no ground truth (a real recording?)"
            raise InputError(msg)
        if self.true_offset is None:
            return self.truth
        i = int(np.clip(np.searchsorted(self.t, time, side="right") - 1, 0, len(self.t) - 1))
        return self.truth.replace(offset=self.true_offset[i])

    def slice(self, index: Any) -> Recording:
        """A recording of the selected samples (slice, index array or boolean mask)."""

        def pick(a: Any) -> Any:
            return None if a is None else a[index]

        return Recording(
            t=self.t[index], raw=self.raw[index], truth=self.truth, true_field=pick(self.true_field),
            still=pick(self.still), gyro=pick(self.gyro), temp=pick(self.temp), effects=dict(self.effects),
            sensor=self.sensor, unit=self.unit, true_offset=pick(self.true_offset),
        )


def drop_zero_rows(rec: Recording) -> tuple[Recording, int]:
    """``rec`` without its all-zero readings (x = y = z = 0: a driver's placeholder, never a field or gravity),
    and how many there were (``rec`` itself when none)."""
    zero = ~np.any(np.asarray(rec.raw) != 0.0, axis=1) if len(rec) else np.zeros(0, dtype=bool)
    n = int(zero.sum())
    return (rec.slice(~zero), n) if n else (rec, 0)


GLITCH_S = 1.0
"""A stamp out of line with its neighbours by more than this (s) is a glitch (``drop_stamp_glitches``)."""


def drop_stamp_glitches(rec: Recording) -> tuple[Recording, NDArray[np.intp]]:
    """``rec`` without the samples whose stamp is out of line with its neighbours, which are in order with each other,
    by more than ``GLITCH_S`` (a stray 1e23 or zero stamp in a clock that runs on: taken for a logger restart, it moved
    every earlier stamp by 1e23 s, where float64 keeps none of them; two samples swapped are left to
    ``continue_clock``), and their indices in ``rec`` (``rec`` itself when none)."""
    t = np.asarray(rec.t, dtype=np.float64).reshape(-1)
    if t.size < 3:
        return rec, np.zeros(0, dtype=np.intp)
    before, mid, after = t[:-2], t[1:-1], t[2:]
    with np.errstate(invalid="ignore", over="ignore"):
        glitch = np.flatnonzero((before <= after) & (np.maximum(before - mid, mid - after) > GLITCH_S)) + 1
    if glitch.size == 0:
        return rec, glitch
    keep = np.ones(t.size, dtype=bool)
    keep[glitch] = False
    return rec.slice(keep), glitch


def check_sensor(sensor: str | None) -> None:
    if sensor not in (None, "mag", "accel"):
        msg = f"sensor must be 'mag', 'accel' or None, got {sensor!r}"
        raise RecordingError(msg)


def time_order(order: str, sort: bool) -> str:
    """The readers' ``order`` with the older ``sort`` flag folded in (``sort=True`` is ``order="sort"``)."""
    if order not in TIME_ORDERS:
        msg = f"order must be one of {TIME_ORDERS}, got {order!r}"
        raise RecordingError(msg)
    if sort and order == "file":
        msg = "sort=True and order='file' contradict each other; give one"
        raise RecordingError(msg)
    return "sort" if sort else order


def continue_clock(t: Array) -> tuple[Array, NDArray[np.intp]]:
    """File-order times made non-decreasing, and the indices after which the time went backwards.

    A clock that goes back (a logger or driver restart) starts a new time base; the samples after it were
    still recorded later. Each backwards step is replaced by the typical step (the median positive step,
    0 without one) and the earlier time bases are moved back by as much, so every interval is kept, the
    time bases follow each other in file order (never interleaved, as sorting would) and the last time
    base keeps its stamps: the clock the recording ended with, the one a calibration's stamp refers to
    (as the streaming calibrator moves its stamps onto a new time base).
    """
    times = np.asarray(t, dtype=np.float64).reshape(-1)
    steps = np.diff(times)
    back = np.flatnonzero(steps < 0)
    if back.size == 0:
        return times.copy(), back
    forward = steps[steps > 0]
    typical = float(np.median(forward)) if forward.size else 0.0
    add = np.zeros(times.size)
    add[back + 1] = typical - steps[back]
    shift = np.cumsum(add)
    return times + (shift - shift[-1]), back


def stamp_unit(stamp: float, step: float | None) -> str:
    """The unit stamps count in when not seconds, in words ("" when none fits): ``stamp`` a typical stamp, ``step``
    the typical step (None: unknown). A unit fits when the step is a sensor's rate in it and the stamp a time since
    the epoch in it (named so, and preferred) or a time below ``MAX_STAMP_S`` in it."""
    fits = []
    for name, f in _UNITS:
        if step is not None and not _RATE_HZ[0] <= f / step <= _RATE_HZ[1]:
            continue
        rate = "" if step is None else f" (a {f / step:.4g} Hz sensor)"
        if _EPOCH_S[0] <= abs(stamp) / f < _EPOCH_S[1]:
            return f"{name} since the epoch{rate}"
        if abs(stamp) / f <= MAX_STAMP_S:
            fits.append(f"{name}{rate}")
    return " or ".join(fits)


def check_stamps(t: Array, where: str) -> None:
    """Refuse stamps that are not seconds, naming the unit they look like (``stamp_unit``).

    Most stamps beyond ``MAX_STAMP_S`` (nanoseconds since the epoch: 1.7e18), or a median forward step above
    ``MAX_STEP_S`` (milliseconds at 100 Hz: 10): the recording is refused with the likely unit (``where`` names it).
    A few stamps beyond it among seconds are glitches, kept: the stream drops them (``bad_stamp``), a batch consumer
    takes them as a clock that jumped.
    """
    times = np.asarray(t, dtype=np.float64).reshape(-1)
    steps = np.diff(times)
    steps = steps[steps > 0.0]
    step = float(np.median(steps)) if steps.size else None
    beyond = np.flatnonzero(~(np.abs(times) <= MAX_STAMP_S))
    if 2 * beyond.size > times.size:
        typical = float(np.median(np.abs(times)))
        unit = stamp_unit(typical, step)
        what = f"they look like {unit}" if unit else "no time in seconds"
        msg = f"{where}: stamps of {typical:.6g} are beyond {MAX_STAMP_S:g} s (31,700 years): {what}; give seconds"
        raise RecordingError(msg)
    if step is not None and steps.size >= MIN_STEPS and step > MAX_STEP_S:
        unit = stamp_unit(float(np.median(np.abs(times))), step)
        what = f"they look like {unit}" if unit else "not seconds"
        msg = (f"{where}: stamps step by {step:.4g} (the median), one sample every {step:.4g} s if seconds: {what}; "
               "give seconds")
        raise RecordingError(msg)


def check_order(t: Array, where: str, sort: bool) -> NDArray[np.intp] | None:
    """None when ``t`` never decreases; the stable sort order when ``sort``; RecordingError otherwise."""
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size == 0:
        return None
    if not sort:
        msg = (
            f"{where}: time goes backwards at {back.size} place(s), first after sample {int(back[0])} "
            f"({float(t[back[0]])!r} -> {float(t[back[0] + 1])!r}); fix the file, or read it with sort=True "
            "(sorted by time) or order='file' (file order: a clock restart)"
        )
        raise RecordingError(msg)
    log.warning("%s: %d backwards time step(s); samples sorted by time", where, back.size)
    return np.argsort(t, kind="stable")
