"""Coverage indicators of a calibration set (Olivares et al. 2013, §3.1) and the information indicator."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError

from ..model.errors import InputError, as_points, as_vector3

__all__ = ["HIST_BINS", "Indicators", "compute_indicators", "information_indicator"]

Array = NDArray[np.float64]


HIST_BINS = 36
"""Default number of histogram bins for theta and for phi (indicator B)."""

_RAD2DEG = 180.0 / math.pi
_TWO_PI = 2.0 * math.pi
_SPHERE = 4.0 / 3.0 * math.pi

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Indicators:
    """Coverage indicators of one set of calibration points (Olivares et al. 2013, §3.1).

    Attributes:
        A: IQR of theta plus IQR of phi, degrees.
        B: Empty bins of the theta and phi histograms (count).
        C: Sum of per-axis extents, raw units.
        D: Convex-hull volume, raw units cubed (0 with fewer than 4 or coplanar points).
        b_frac: ``B / (2 hist_bins)``, in [0, 1].
        c_norm: ``C / (6 r)``, about 1 for full coverage of a sphere of radius r.
        d_norm: ``D / (4/3 pi r^3)``, below 1, approaching 1 for dense full coverage.
        n_points: Number of points.
        radius: The radius r used for normalisation.
        e_info: Information indicator E (``information_indicator``): log10 of the smallest
            eigenvalue of the ellipsoid fit's information matrix relative to uniform directions;
            0 for uniform coverage, very negative for sets that cannot determine the fit.
        e_total: ``e_info + log10(n_points)`` (a property): the same eigenvalue for the summed
            information matrix, so it grows with the number of samples as the fit's precision does.
    """

    A: float
    B: int
    C: float
    D: float
    b_frac: float
    c_norm: float
    d_norm: float
    n_points: int = 0
    radius: float = 0.0
    e_info: float = -12.0

    @property
    def e_total(self) -> float:
        """``log10(n lambda_min / (2/15))``: worst-direction information of the whole set.

        The Cramér–Rao bound of the least-determined ellipsoid parameter combination scales as
        ``sigma / sqrt(n lambda_min)``, so a 64-sample arc and a 600-sample arc with the same
        ``e_info`` differ by about one decade here (log10 of 600/64), and by a factor of three in that bound.
        """
        return self.e_info + math.log10(max(self.n_points, 1))

    def as_dict(self) -> dict[str, float]:
        """Return the indicators as a flat dict (for status messages and JSON), ``e_total`` included."""
        return {**{k: float(v) for k, v in asdict(self).items()}, "e_total": self.e_total}


def _hist_scale(hist_bins: int) -> tuple[float, float]:
    return hist_bins / 180.0, hist_bins / 360.0


def _quartile_spread(s: list[float]) -> float:
    """Q3 - Q1 of a sorted list with numpy's default (linear) percentile interpolation."""
    n = len(s)
    if n < 2:
        return 0.0
    return _percentile(s, 0.75) - _percentile(s, 0.25)


def _percentile(s: list[float], q: float) -> float:
    h = (len(s) - 1) * q
    lo = int(h)
    frac = h - lo
    if frac == 0.0:
        return s[lo]
    a, b = s[lo], s[lo + 1]
    return a + (b - a) * frac if frac < 0.5 else b - (b - a) * (1.0 - frac)


_E_UNIFORM = 2.0 / 15.0
"""Smallest eigenvalue of the information matrix below for uniform directions."""
_E_FLOOR = 1e-12


def _jacobian_rows(d: Array) -> Array:
    """Rows ``(dx, dy, dz, dx², dy², dz², 2dxdy, 2dxdz, 2dydz)`` of the ellipsoid residual at the sphere."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.column_stack([x, y, z, x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z])


def _e_info(scatter: Array, n: int, radius: float) -> float:
    """``log10(lambda_min(M) / (2/15))`` with ``M = D S D / n`` and ``D`` scaling by 1/r and 1/r²."""
    if n < 9 or not radius > 0.0:
        return float(np.log10(_E_FLOOR))
    scale = np.r_[np.full(3, 1.0 / radius), np.full(6, 1.0 / radius**2)]
    m = scatter * np.outer(scale, scale) / n
    lam = float(np.linalg.eigvalsh(0.5 * (m + m.T))[0])
    return float(np.log10(max(lam / _E_UNIFORM, _E_FLOOR)))


def information_indicator(points: ArrayLike, center: ArrayLike, radius: float) -> float:
    """Indicator E: how well the directions determine the ellipsoid (E-optimal design).

    With ``u_i = (v_i - c) / r`` and the Jacobian row of the ellipsoid residual at the sphere,
    ``j_i = (u_x, u_y, u_z, u_x², u_y², u_z², 2 u_x u_y, 2 u_x u_z, 2 u_y u_z)`` (offset and the six
    entries of the symmetric matrix), the information matrix is ``M = (1/n) sum j_i j_i^T``. Its
    smallest eigenvalue is ~0 when some ellipsoid deformation leaves every sample's norm unchanged:
    a cap, a band, or two great circles (the quadric ``(n1·u)(n2·u)`` vanishes on both), sets that
    C and D rate as well covered. Returned as ``log10(lambda_min / (2/15))``: 0 for uniform
    directions, floored at -12.
    """
    d = as_points(points, "points") - as_vector3(center, "center")
    jac = _jacobian_rows(d)
    return _e_info(jac.T @ jac, d.shape[0], float(radius))


def _normalise(a: float, b: int, c: float, d: float, n: int, radius: float, hist_bins: int, e_info: float) -> Indicators:
    r = radius if radius > 0.0 else float("nan")
    return Indicators(
        A=a,
        B=b,
        C=c,
        D=d,
        b_frac=b / (2.0 * hist_bins),
        c_norm=c / (6.0 * r),
        d_norm=d / (_SPHERE * r**3),
        n_points=n,
        radius=radius,
        e_info=e_info,
    )


def compute_indicators(
    points: ArrayLike, center: ArrayLike | None = None, radius: float | None = None, *, hist_bins: int = HIST_BINS
) -> Indicators:
    """Compute indicators A–D from scratch (the batch reference for :class:`DirectionBuffer`).

    Args:
        points: (n, 3) raw samples, n >= 1.
        center: Centre estimate the directions are taken about; the origin when None.
        radius: Radius for the normalised indicators; the mean distance from ``center`` when None.
        hist_bins: Number of histogram bins for theta and for phi (indicator B).

    Returns:
        The indicators.

    Raises:
        InputError: On a bad shape, non-finite values or a non-positive radius.
    """
    p = as_points(points, "points")
    c = np.zeros(3) if center is None else as_vector3(center, "center")
    if hist_bins < 1:
        msg = f"hist_bins must be >= 1, got {hist_bins}"
        raise InputError(msg)
    d = p - c
    if radius is None:
        radius = float(np.mean(np.sqrt(np.einsum("ij,ij->i", d, d))))
    elif not (math.isfinite(radius) and radius > 0.0):
        msg = f"radius must be a positive finite number, got {radius!r}"
        raise InputError(msg)
    theta = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])) * _RAD2DEG
    phi = np.arctan2(d[:, 1], d[:, 0]) * _RAD2DEG
    q_t = np.percentile(theta, [25.0, 75.0])
    q_p = np.percentile(phi, [25.0, 75.0])
    a = float((q_t[1] - q_t[0]) + (q_p[1] - q_p[0]))  # Eq. 9
    st, sp = _hist_scale(hist_bins)
    it = np.clip(((theta + 90.0) * st).astype(np.intp), 0, hist_bins - 1)
    ip = np.clip(((phi + 180.0) * sp).astype(np.intp), 0, hist_bins - 1)
    b = int(hist_bins - np.unique(it).size + hist_bins - np.unique(ip).size)  # Eq. 10
    c_ind = float(np.sum(p.max(axis=0) - p.min(axis=0)))  # Eq. 11
    d_ind = 0.0  # Eq. 12
    if p.shape[0] >= 4:
        try:
            d_ind = float(ConvexHull(p).volume)
        except QhullError:
            d_ind = 0.0
    jac = _jacobian_rows(d)
    e_info = _e_info(jac.T @ jac, p.shape[0], float(radius))
    return _normalise(a, b, c_ind, d_ind, p.shape[0], float(radius), hist_bins, e_info)
