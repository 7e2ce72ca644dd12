"""The calibration value: what a fit produces, the node applies, and a file keeps.

A three-axis sensor reading ``v`` (raw units) of a field ``h`` of constant norm is modelled as

    v = W^-1 h + b + e            so that            h = W (v - b)

with offset ``b`` (hard iron / accelerometer bias) and matrix ``W`` (gains, cross-axis terms, soft
iron). The papers use other parametrisations of the same model:

- Gietzelt et al. 2013, Eq. 1: ``sum(((v - o) / s) ** 2) = 1`` gives ``b = o`` and
  ``W = norm * diag(1 / s)``; their Eq. 2, ``(v - o)^T A (v - o) = 1`` with ``A = U^T U``, gives
  ``W = norm * A^(1/2)`` (the symmetric square root, one member of the rotation family of ``U``).
- Camps et al. 2009, Eq. 1 and Eq. 6: ``V = alpha h + beta`` with ``alpha`` symmetric (gains on the
  diagonal, non-orthogonality factors ``s_ij`` off it) gives ``b = beta`` and ``W = alpha^-1``.

A calibration is serialised as a ``ros__parameters`` YAML block with a format version, so a node can
read it back with ``--params-file`` and an older ros_margcal refuses a newer file instead of
misreading it. Version 2 (this one) adds a checksum line to the file (``calibration_file``); the
entry itself is the same as version 1's, which is still read. ``from_dict`` is strict: a file is
untrusted input, so a mistyped, non-finite or absurd value is refused naming its field.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import CalibrationFileError, InputError, as_vector3
from .fields import MAX_ABS, MIN_NORM, number, numbers, show, stats_fields, string, strings

__all__ = ["FORCED", "MODELS", "Calibration", "FitStats"]

MODELS = ("eye", "diag", "sym")
FORCED = "forced past the guard rails"
"""In ``method``: ``margcal calibrate --force`` wrote a calibration the guard rails refuse (the node loads it, warning)."""
"""Model kinds: offset only (W = k I), offset and per-axis gains, offset and symmetric matrix."""

Array = NDArray[np.float64]

_MAX_CONDITION = 1e12  # a larger condition number is a singular matrix for our purposes


@dataclass(frozen=True)
class FitStats:
    """Residual statistics of ``|W (v - b)| - norm`` over the fitted points, in output units."""

    n_points: int
    rms: float
    max_abs: float
    rms_relative: float
    iterations: int = 0
    converged: bool = True
    cost: float = 0.0

    @classmethod
    def _trusted(
        cls, n_points: int, rms: float, max_abs: float, rms_relative: float, iterations: int, converged: bool, cost: float
    ) -> FitStats:
        """The same value as ``FitStats(...)`` without the frozen dataclass's field-by-field ``object.__setattr__``.

        For ``fitting`` only (values of the right types); ``test_calibration`` checks the fields match.
        """
        stats = object.__new__(cls)
        object.__setattr__(stats, "__dict__", {
            "n_points": n_points, "rms": rms, "max_abs": max_abs, "rms_relative": rms_relative,
            "iterations": iterations, "converged": converged, "cost": cost,
        })  # fmt: skip
        return stats


_STAT_NAMES = frozenset(f.name for f in dataclasses.fields(FitStats))
"""The fields of FitStats, for the strict reader of a file's ``stats`` block."""


def _as_matrix(x: ArrayLike, name: str) -> Array:
    arr = np.asarray(x, dtype=np.float64)
    if arr.size == 9:
        arr = arr.reshape(3, 3)
    if arr.shape != (3, 3):
        msg = f"{name} must be a 3x3 matrix (or 9 numbers, row-major), got shape {arr.shape}"
        raise InputError(msg)
    if not np.isfinite(arr).all():
        msg = f"{name} must be finite, got {arr.tolist()}"
        raise InputError(msg)
    return arr


def _condition_1(matrix: Array) -> float:
    """1-norm condition ``|W|_1 |W^-1|_1`` of a 3x3 matrix from its adjugate (inf when singular).

    Closed form, no SVD: ``W^-1 = adj(W) / det(W)`` with ``adj`` the transposed cofactors. For 3x3 it is
    within a factor 3 of the 2-norm condition (``cond_2 / 3 <= cond_1 <= 3 cond_2``).
    """
    entries = matrix.ravel().tolist()
    big = max(map(abs, entries))
    if not big > 0.0:
        return math.inf
    (a, b, c, d, e, f, g, h, i) = (x / big for x in entries)  # the condition is scale-free; this avoids overflow
    c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g  # cofactors of row 0 (= column 0 of adj)
    c10, c11, c12 = c * h - b * i, a * i - c * g, b * g - a * h
    c20, c21, c22 = b * f - c * e, c * d - a * f, a * e - b * d
    det = a * c00 + b * c01 + c * c02
    if not abs(det) > 0.0:
        return math.inf
    norm_w = max(abs(a) + abs(d) + abs(g), abs(b) + abs(e) + abs(h), abs(c) + abs(f) + abs(i))  # max column sum
    norm_adj = max(abs(c00) + abs(c01) + abs(c02), abs(c10) + abs(c11) + abs(c12), abs(c20) + abs(c21) + abs(c22))
    cond = norm_w * norm_adj / abs(det)
    return cond if math.isfinite(cond) else math.inf


def _frozen(arr: Array) -> Array:
    out = np.array(arr, dtype=np.float64, copy=True)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class Calibration:
    """Offset ``b`` and matrix ``W`` with ``calibrated = W (raw - b)``; SI units inside the node.

    Attributes:
        offset: b, shape (3,), in raw units.
        matrix: W, shape (3, 3); maps offset-free raw values to output units.
        norm: reference norm of the calibrated vector (tesla, m/s², or the raw unit).
        model: one of ``MODELS``.
        method: the fitting method that produced it ("" when built by hand).
        sensor: "mag", "accel" or "".
        unit: unit of the calibrated output ("T", "m/s^2", "gauss", ...).
        stats: residual statistics of the fit, if fitted.
        covariance: parameter covariance over ``parameter_names``, if known.
        parameter_names: names of the fitted parameters, in covariance order.
        stamp: time of the fit in seconds (message time in the node).
    """

    offset: Array
    matrix: Array
    norm: float = 1.0
    model: str = "sym"
    method: str = ""
    sensor: str = ""
    unit: str = ""
    stats: FitStats | None = None
    covariance: Array | None = None
    parameter_names: tuple[str, ...] = ()
    stamp: float = 0.0

    FORMAT_VERSION: ClassVar[int] = 2

    def __post_init__(self) -> None:
        offset = as_vector3(self.offset, "offset")
        matrix = _as_matrix(self.matrix, "matrix")
        cond = _condition_1(matrix)
        if not cond <= _MAX_CONDITION:
            msg = f"matrix must be invertible (1-norm condition {cond:.3g} > {_MAX_CONDITION:.0e}), got {matrix.tolist()}"
            raise InputError(msg)
        if not (np.isfinite(self.norm) and self.norm > 0):
            msg = f"norm must be a positive finite number, got {self.norm!r}"
            raise InputError(msg)
        if self.model not in MODELS:
            msg = f"model must be one of {MODELS}, got {self.model!r}"
            raise InputError(msg)
        object.__setattr__(self, "offset", _frozen(offset))
        object.__setattr__(self, "matrix", _frozen(matrix))
        object.__setattr__(self, "norm", float(self.norm))
        object.__setattr__(self, "parameter_names", tuple(self.parameter_names))
        if self.covariance is not None:
            cov = np.asarray(self.covariance, dtype=np.float64)
            p = len(self.parameter_names)
            if cov.shape != (p, p):
                msg = f"covariance must be {p}x{p} to match parameter_names, got {cov.shape}"
                raise InputError(msg)
            object.__setattr__(self, "covariance", _frozen(cov))

    @classmethod
    def _trusted(
        cls, *, offset: Array, matrix: Array, norm: float = 1.0, model: str = "sym", method: str = "", sensor: str = "",
        unit: str = "", stats: FitStats | None = None, covariance: Array | None = None,
        parameter_names: tuple[str, ...] = (), stamp: float = 0.0,
    ) -> Calibration:  # fmt: skip
        """Build from values a fit has already checked, skipping ``__post_init__``'s conversions and copies.

        For ``fitting`` only: float64 arrays of the right shapes made for this calibration (they are
        frozen in place, not copied), an invertible matrix, a positive float norm, a known model, a tuple
        of names. The keywords are the fields with their defaults (``test_calibration`` checks they match).
        """
        offset.setflags(write=False)  # setflags: half the cost of assigning flags.writeable
        matrix.setflags(write=False)
        if covariance is not None:
            covariance.setflags(write=False)
        cal = object.__new__(cls)
        object.__setattr__(cal, "__dict__", {  # what a frozen dataclass's __init__ stores, without __post_init__
            "offset": offset, "matrix": matrix, "norm": norm, "model": model, "method": method, "sensor": sensor,
            "unit": unit, "stats": stats, "covariance": covariance, "parameter_names": parameter_names, "stamp": stamp,
        })  # fmt: skip
        return cal

    # -- use -------------------------------------------------------------------------------------

    def apply(self, raw: ArrayLike) -> Array:
        """Calibrate one sample (3,) or many (n, 3): ``W (raw - b)``."""
        v = np.asarray(raw, dtype=np.float64)
        return (v - self.offset) @ self.matrix.T

    def norm_error(self, raw: ArrayLike) -> Array:
        """``|W (raw - b)| - norm`` per sample: the residual every fit minimises."""
        return np.linalg.norm(np.atleast_2d(self.apply(raw)), axis=1) - self.norm

    def median_relative_error(self, raw: ArrayLike) -> float:
        """Median of ``|W (v - b)| / norm - 1`` in magnitude over readings ``raw`` (0 for none): how far they sit off
        the field this calibration expects, robust to a few outliers (the change detector's and the rests' measure)."""
        pts = np.atleast_2d(np.asarray(raw, dtype=np.float64))
        return float(np.median(np.abs(self.norm_error(pts)) / self.norm)) if pts.size else 0.0

    @property
    def raw_radius(self) -> float:
        """Field radius in raw units: the radius ``norm / |det W|^(1/3)`` of the raw ellipsoid's equal-volume sphere."""
        return float(self.norm / abs(float(np.linalg.det(self.matrix))) ** (1.0 / 3.0))

    @property
    def rms_radius(self) -> float:
        """RMS distance of the raw ellipsoid from its centre over uniform field directions, ``norm sqrt(tr(W^-1 W^-T)
        / 3)``: the radius a sphere fit of readings that cover every direction finds (``raw_radius`` for a round one)."""
        inv = np.linalg.inv(self.matrix)
        return float(self.norm * math.sqrt(float(np.sum(inv * inv)) / 3.0))

    def inverse_apply(self, calibrated: ArrayLike) -> Array:
        """Raw reading of a physical vector: ``W^-1 h + b`` (what the simulator needs)."""
        h = np.asarray(calibrated, dtype=np.float64)
        return np.linalg.solve(self.matrix, h.T).T + self.offset

    def parameter_std(self) -> dict[str, float]:
        """One-sigma uncertainty of each fitted parameter, from the covariance (empty if unknown)."""
        if self.covariance is None:
            return {}
        std = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return dict(zip(self.parameter_names, std.tolist(), strict=True))

    def replace(self, **changes: Any) -> Calibration:
        """A copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def allclose(self, other: Calibration, rtol: float = 1e-9, atol: float = 0.0) -> bool:
        """True when offset, matrix and norm agree within tolerance."""
        return bool(
            np.allclose(self.offset, other.offset, rtol=rtol, atol=atol * max(1.0, self.norm))
            and np.allclose(self.matrix, other.matrix, rtol=rtol, atol=atol)
            and np.isclose(self.norm, other.norm, rtol=rtol, atol=atol)
        )

    # -- constructors from the papers' parametrisations ------------------------------------------

    @classmethod
    def identity(cls, norm: float = 1.0, **kwargs: Any) -> Calibration:
        """No correction: ``b = 0``, ``W = I``."""
        kwargs.setdefault("model", "eye")
        return cls(np.zeros(3), np.eye(3), norm, **kwargs)

    @classmethod
    def from_gietzelt(cls, o: ArrayLike, s: ArrayLike, norm: float = 1.0, **kwargs: Any) -> Calibration:
        """Gietzelt Eq. 1: centre ``o`` and radii ``s`` -> ``b = o``, ``W = norm diag(1/s)``."""
        radii = as_vector3(s, "s")
        if (radii <= 0).any():
            msg = f"radii s must be positive, got {radii.tolist()}"
            raise InputError(msg)
        kwargs.setdefault("model", "diag")
        return cls(as_vector3(o, "o"), norm * np.diag(1.0 / radii), norm, **kwargs)

    @classmethod
    def from_quadric(cls, o: ArrayLike, a: ArrayLike, norm: float = 1.0, **kwargs: Any) -> Calibration:
        """Gietzelt Eq. 2: ``(v - o)^T A (v - o) = 1`` with A positive definite -> ``W = norm A^(1/2)``."""
        quad = _as_matrix(a, "A")
        quad = 0.5 * (quad + quad.T)
        eigval, eigvec = np.linalg.eigh(quad)
        if eigval.min() <= 0:
            msg = f"A must be positive definite (an ellipsoid), eigenvalues {eigval.tolist()}"
            raise InputError(msg)
        root = (eigvec * np.sqrt(eigval)) @ eigvec.T
        kwargs.setdefault("model", "sym")
        return cls(as_vector3(o, "o"), norm * root, norm, **kwargs)

    @classmethod
    def from_camps(
        cls,
        alpha: ArrayLike,
        beta: ArrayLike,
        s: ArrayLike = (0.0, 0.0, 0.0),
        norm: float = 1.0,
        **kwargs: Any,
    ) -> Calibration:
        """Camps Eq. 1/6: ``V = alpha h + beta``; gains ``alpha``, factors ``s = (s_xy, s_xz, s_yz)``."""
        a = as_vector3(alpha, "alpha")
        sxy, sxz, syz = as_vector3(s, "s")
        gain = np.array([[a[0], sxy, sxz], [sxy, a[1], syz], [sxz, syz, a[2]]])
        if np.linalg.cond(gain) > 1e12:
            msg = f"alpha matrix is singular: {gain.tolist()}"
            raise InputError(msg)
        kwargs.setdefault("model", "sym" if np.any([sxy, sxz, syz]) else "diag")
        return cls(as_vector3(beta, "beta"), np.linalg.inv(gain), norm, **kwargs)

    def to_camps(self) -> tuple[Array, Array, Array]:
        """Camps' ``(alpha, beta, s)`` for this calibration (W must be symmetric for Eq. 6 to hold)."""
        gain = np.linalg.inv(self.matrix)
        return np.diag(gain).copy(), self.offset.copy(), np.array([gain[0, 1], gain[0, 2], gain[1, 2]])

    # -- serialisation --------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Plain types only (floats, lists, strings), typed as rclpy parameters expect."""
        out: dict[str, Any] = {
            "format_version": self.FORMAT_VERSION,
            "model": self.model,
            "method": self.method,
            "sensor": self.sensor,
            "unit": self.unit,
            "offset": [float(x) for x in self.offset],
            "matrix": [float(x) for x in self.matrix.reshape(-1)],
            "norm": float(self.norm),
            "stamp": float(self.stamp),
        }
        if self.stats is not None:
            out["stats"] = {k: (v if isinstance(v, bool | int) else float(v)) for k, v in dataclasses.asdict(self.stats).items()}
        if self.covariance is not None and self.parameter_names:
            out["parameter_names"] = list(self.parameter_names)
            out["covariance"] = [float(x) for x in self.covariance.reshape(-1)]
        return out

    @classmethod
    def from_dict(cls, d: Any) -> Calibration:
        """Inverse of ``to_dict``; CalibrationFileError naming the field on anything missing, mistyped, absurd or newer.

        Strict on purpose (a file is untrusted input): numbers must be YAML numbers (not strings or
        booleans), finite and of a sane magnitude; strings must be strings; the stats block must
        have FitStats' fields with their types. Versions 1 (no checksum) and 2 read the same entry.
        """
        if not isinstance(d, dict):
            msg = f"calibration entry must be a mapping, got {type(d).__name__}"
            raise CalibrationFileError(msg)
        version = d.get("format_version")
        if type(version) is not int or version < 1:
            msg = f"calibration entry has no integer format_version >= 1 (got {show(version)}): not a ros_margcal calibration"
            raise CalibrationFileError(msg)
        if version > cls.FORMAT_VERSION:
            msg = (
                f"calibration format_version {version} is newer than this ros_margcal understands "
                f"({cls.FORMAT_VERSION}); upgrade ros_margcal or refit"
            )
            raise CalibrationFileError(msg)
        try:
            names = strings(d.get("parameter_names", []), "parameter_names")
            cov = None
            if "covariance" in d:
                cov = np.array(numbers(d["covariance"], "covariance", len(names) ** 2, MAX_ABS**2)).reshape(len(names), -1)
            norm = number(d.get("norm"), "norm")
            if norm < MIN_NORM:
                msg = f"field 'norm' must be in [{MIN_NORM:.0e}, {MAX_ABS:.0e}], got {norm!r}"
                raise CalibrationFileError(msg)
            return cls(
                offset=np.array(numbers(d.get("offset"), "offset", 3)),
                matrix=np.array(numbers(d.get("matrix"), "matrix", 9)),
                norm=norm,
                model=string(d.get("model", "sym"), "model"),
                method=string(d.get("method", ""), "method"),
                sensor=string(d.get("sensor", ""), "sensor"),
                unit=string(d.get("unit", ""), "unit"),
                stats=FitStats(**stats_fields(d["stats"], _STAT_NAMES)) if "stats" in d else None,
                covariance=cov,
                parameter_names=names,
                stamp=number(d.get("stamp", 0.0), "stamp"),
            )
        except (CalibrationFileError, InputError) as exc:
            msg = f"calibration entry is malformed: {exc}"
            raise CalibrationFileError(msg) from exc
