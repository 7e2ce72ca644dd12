"""One exception tree for the whole package, plus the boundary checks that raise it.

Every error is a ``MargCalError`` (a ``ValueError``), so callers catch one root; the subclasses say
which area failed. Messages name the argument, what was wrong, and what to do.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "CalibrationFileError", "ConfigError", "ConvergenceError", "DegenerateDataError", "InputError", "MargCalError",
    "RecordingError", "RunawayError", "as_points", "as_vector3", "one_line"]


class MargCalError(ValueError):
    """Root of every error raised by ros_margcal."""


class InputError(MargCalError):
    """An argument has the wrong shape, a non-finite value or an absurd magnitude."""


class DegenerateDataError(MargCalError):
    """The data cannot determine the model: too few, identical, collinear or coplanar points."""


class ConvergenceError(MargCalError):
    """An iterative fit did not converge to a usable solution."""


class RunawayError(ConvergenceError):
    """A fit ran away to no sensor's ellipsoid: more iterations, or a few more samples of the same directions, will not
    help (other directions or a steadier field may)."""


class CalibrationFileError(MargCalError):
    """A calibration or validator file is corrupt, of an unknown kind, or of a newer format."""


class RecordingError(MargCalError):
    """A recording (CSV or rosbag2) cannot be read or holds no usable samples."""


class ConfigError(MargCalError):
    """An option or parameter value is out of range or inconsistent with another."""


def as_points(x: ArrayLike, name: str = "points", min_rows: int = 1) -> NDArray[np.float64]:
    """Return ``x`` as a finite float64 array of shape (n, 3), n >= ``min_rows``; raise InputError."""
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        msg = f"{name} must be numeric, got {type(x).__name__}: {exc}"
        raise InputError(msg) from exc
    if arr.ndim == 1 and arr.shape[0] == 3:
        arr = arr.reshape(1, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        msg = f"{name} must have shape (n, 3), got {arr.shape}"
        raise InputError(msg)
    if arr.shape[0] < min_rows:
        msg = f"{name} needs at least {min_rows} rows, got {arr.shape[0]}"
        raise InputError(msg)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        msg = f"{name} has {int(bad.sum())} row(s) with NaN or Inf (first at row {int(np.argmax(bad))}); drop them first"
        raise InputError(msg)
    return arr


def as_vector3(x: ArrayLike, name: str = "vector") -> NDArray[np.float64]:
    """Return ``x`` as a finite float64 array of shape (3,); raise InputError otherwise."""
    try:
        arr = np.asarray(x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        msg = f"{name} must be three numbers, got {x!r}"
        raise InputError(msg) from exc
    if arr.shape != (3,):
        msg = f"{name} must have 3 elements, got {arr.size}"
        raise InputError(msg)
    if not np.isfinite(arr).all():
        msg = f"{name} must be finite, got {arr.tolist()}"
        raise InputError(msg)
    return arr


def one_line(message: object) -> str:
    """``message`` (an exception or text) on one line: readers and YAML errors may span several."""
    text = " ".join(str(message).split())
    return text or (type(message).__name__ if isinstance(message, BaseException) else "")
