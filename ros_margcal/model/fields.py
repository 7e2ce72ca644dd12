"""Strict readers of a calibration file's fields: a number is a finite real (not a bool, not a string),
within an absolute bound; a text is a string; ``stats`` has exactly its fields. ``Calibration.from_dict``
uses them so a corrupt or hand-broken file is refused with the field named, never half-loaded."""

from __future__ import annotations

import math
from typing import Any

from .errors import CalibrationFileError

__all__ = ["MAX_ABS", "MIN_NORM", "number", "numbers", "show", "stats_fields", "string", "strings"]

MAX_ABS = 1e12  # no offset, matrix entry, norm or stamp in any unit comes near this: a larger one is a corrupt file
MIN_NORM = 1e-12  # the smallest plausible field norm (tesla is 1e-5 .. 1e-4)
_STAT_INTS = ("n_points", "iterations")
_STAT_FLOATS = ("rms", "max_abs", "rms_relative", "cost")


def show(x: Any) -> str:
    """A short repr for a message (a hostile value may be huge)."""
    text = repr(x)
    return text if len(text) <= 60 else text[:57] + "..."


def number(x: Any, name: str, limit: float = MAX_ABS) -> float:
    """A YAML number (int or float, not a bool or a string), finite and at most ``limit`` in magnitude."""
    if isinstance(x, bool) or not isinstance(x, int | float):
        msg = f"field {name!r} must be a number, got {type(x).__name__} {show(x)}"
        raise CalibrationFileError(msg)
    try:
        value = float(x)
    except OverflowError:
        value = math.inf
    if not abs(value) <= limit:
        msg = f"field {name!r} must be finite and at most {limit:.0e} in magnitude, got {show(x)}"
        raise CalibrationFileError(msg)
    return value


def numbers(x: Any, name: str, size: int, limit: float = MAX_ABS) -> list[float]:
    """A flat list of ``size`` numbers (a 3x3 matrix may also be three rows of three)."""
    if isinstance(x, list) and size == 9 and len(x) == 3 and all(isinstance(r, list) and len(r) == 3 for r in x):
        x = [v for row in x for v in row]
    if not isinstance(x, list) or len(x) != size:
        got = f"{len(x)} items" if isinstance(x, list) else f"{type(x).__name__} {show(x)}"
        msg = f"field {name!r} must be a list of {size} numbers, got {got}"
        raise CalibrationFileError(msg)
    return [number(v, f"{name}[{i}]", limit) for i, v in enumerate(x)]


def string(x: Any, name: str) -> str:
    if not isinstance(x, str):
        msg = f"field {name!r} must be a string, got {type(x).__name__} {show(x)}"
        raise CalibrationFileError(msg)
    return x


def strings(x: Any, name: str) -> tuple[str, ...]:
    if not isinstance(x, list):
        msg = f"field {name!r} must be a list of strings, got {type(x).__name__} {show(x)}"
        raise CalibrationFileError(msg)
    return tuple(string(v, f"{name}[{i}]") for i, v in enumerate(x))


def stats_fields(x: Any, known: frozenset[str]) -> dict[str, Any]:
    """The ``stats`` block (``known``: FitStats' field names) as checked keyword arguments of FitStats."""
    if not isinstance(x, dict):
        msg = f"field 'stats' must be a mapping, got {type(x).__name__} {show(x)}"
        raise CalibrationFileError(msg)
    unknown = sorted(map(str, set(x) - known))
    missing = sorted({"n_points", "rms", "max_abs", "rms_relative"} - set(x))
    if unknown or missing:
        msg = f"field 'stats' has unknown keys {unknown} or lacks {missing}"
        raise CalibrationFileError(msg)
    values: dict[str, Any] = {}
    for key in _STAT_INTS:
        if key in x:
            v = x[key]
            if type(v) is not int or v < 0:
                msg = f"field 'stats.{key}' must be a non-negative integer, got {show(v)}"
                raise CalibrationFileError(msg)
            values[key] = v
    for key in _STAT_FLOATS:
        if key in x:
            values[key] = number(x[key], f"stats.{key}", MAX_ABS**2)
            if values[key] < 0:
                msg = f"field 'stats.{key}' must be non-negative, got {show(x[key])}"
                raise CalibrationFileError(msg)
    if "converged" in x:
        if not isinstance(x["converged"], bool):
            msg = f"field 'stats.converged' must be true or false, got {show(x['converged'])}"
            raise CalibrationFileError(msg)
        values["converged"] = x["converged"]
    return values
