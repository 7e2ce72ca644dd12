"""What a diagnosis accepts: its options (``check_options``) and a recording's arrays in file order
(``recording_arrays``; a clock that goes back, a logger restart: ``file_order_times``).

A bad option is refused before any work: inside the diagnosis a fit's refusal of it would become an
``unexplained`` verdict, not an error. A recording whose clock restarts is one sensor's samples in the
order they were taken; sorted by time its parts would interleave.
"""

from __future__ import annotations

import itertools
import logging
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.errors import ConfigError

__all__ = ["check_options", "file_order_times", "recording_arrays"]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

_CLI_NAMES = {"split": "--holdout", "n_sets": "--retrain-sets"}


def check_options(*, norm: float | None = None, rest_noise: float | None = None, n_fit: int | None = None,
                  shape_tolerance: float | None = None, split: float | None = None, n_sets: int | None = None,
                  cli: bool = False) -> None:
    """Refuse option values no diagnosis can use, before any work (ConfigError, one line naming the option).

    Without this a bad value reached a fit inside the diagnosis, whose errors make an ``unexplained``
    verdict (or a skipped validator stage, a withheld part "not measured") instead of an error: ``norm``
    finite and positive, ``rest_noise`` finite and non-negative, ``n_fit`` at least 100,
    ``shape_tolerance`` finite and non-negative, ``split`` in [0.1, 0.9], ``n_sets`` at least 2 (a
    retraining corpus holds both groups of its swap). None is not checked. ``cli``: name the options as
    ``margcal diagnose`` spells them (``--norm``, ``--holdout``, ``--retrain-sets``).
    """
    def bad(key: str, rule: str, value: object) -> ConfigError:
        name = _CLI_NAMES.get(key, "--" + key.replace("_", "-")) if cli else key
        msg = f"{name} must be {rule}, got {value!r}"
        return ConfigError(msg)

    def number(x: object) -> float:
        return float(x) if isinstance(x, int | float | np.integer | np.floating) else math.nan

    if norm is not None and not (math.isfinite(number(norm)) and number(norm) > 0):
        raise bad("norm", "a positive finite number (the reference norm of the calibrated vector)", norm)
    if rest_noise is not None and not (math.isfinite(number(rest_noise)) and number(rest_noise) >= 0):
        raise bad("rest_noise", "a non-negative finite std in raw units", rest_noise)
    if n_fit is not None and not (isinstance(n_fit, int | np.integer) and n_fit >= 100):
        raise bad("n_fit", "an integer of at least 100", n_fit)
    if shape_tolerance is not None and not (math.isfinite(number(shape_tolerance)) and number(shape_tolerance) >= 0):
        raise bad("shape_tolerance", "a non-negative finite fraction", shape_tolerance)
    if split is not None and not 0.1 <= number(split) <= 0.9:
        raise bad("split", "a fraction in [0.1, 0.9] (the share of the recording to fit on)", split)
    if n_sets is not None and not (isinstance(n_sets, int | np.integer) and n_sets >= 2):
        raise bad("n_sets", "an integer of at least 2", n_sets)


CLOCK_JUMP_S = 86400.0
"""A forward step between two samples longer than this (a day) is the clock jumping, not a pause: the twin would
simulate the span in between (a 1e12 s jump asked for 7 TiB); the part after it is moved like one after a step back."""


def file_order_times(t: Array) -> tuple[Array, list[int]]:
    """Times that never decrease for samples in file order whose clock went back (a logger restart) or jumped ahead
    by more than ``CLOCK_JUMP_S``.

    A recording whose clock restarts (its stamps fall back to about 0 halfway) is one sensor's samples in
    the order they were taken: sorting them by time would interleave the parts. Each part after a step
    back (or a jump ahead) is moved in time to start one typical sample interval (the median forward step) after
    the end of the part before, as the online calibrator moves its stored samples onto a new time base. Returns the
    times (``t`` itself when it never decreases nor jumps) and the samples after which the clock went back or jumped.
    """
    times = np.asarray(t, dtype=np.float64).reshape(-1)
    steps = np.diff(times)
    back = np.flatnonzero((steps < 0) | (steps > CLOCK_JUMP_S))
    if back.size == 0:
        return t, []
    forward = steps[(steps > 0) & (steps <= CLOCK_JUMP_S)]
    dt = float(np.median(forward)) if forward.size else 0.0
    out = times.copy()
    ends = [*(back + 1).tolist(), len(times)]
    for start, end in itertools.pairwise(ends):  # each part from its own first stamp: a 1e30 s glitch
        out[start:end] = (times[start:end] - times[start]) + (out[start - 1] + dt)  # added to 1e3 s would erase it
    return out, [int(i) for i in back]


def recording_arrays(recording: Any) -> tuple[Array, Array, Array | None, str, list[int]]:
    """The recording's times (in file order, ``file_order_times``), readings, temperature, sensor label and
    the samples after which its clock went back."""
    try:
        t, raw, temp, label = recording.t, recording.raw, getattr(recording, "temp", None), getattr(recording, "sensor", "")
    except AttributeError as exc:
        msg = f"recording must have t and raw (a simulation.Recording), got {type(recording).__name__}"
        raise ConfigError(msg) from exc
    try:
        t, restarts = file_order_times(t)
    except (TypeError, ValueError):  # not numbers: ``twin.build_twin`` says what is wrong with t
        restarts = []
    if restarts:
        log.warning("the recording's clock goes back (or jumps ahead over %g s) %d time(s), first after sample %d: "
                    "samples taken in file order, the times after each step continued", CLOCK_JUMP_S, len(restarts),
                    restarts[0])
    return t, raw, temp, str(label), restarts
