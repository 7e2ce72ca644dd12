"""The level term of a near-level ring: a vehicle that is level on average keeps its ring of readings level.

On a ring turned in yaw with the sensor level, the norm of the calibrated reading cannot see a small tilt
of the calibrated frame: a cross term ``w_xz`` (or ``w_yz``) with the matching shift of ``b_x`` (``b_y``)
turns the calibrated field about the y (x) axis to first order, and the norm is blind to rotations. The
level heading then follows that unseen rotation, ``Z / H`` degrees of heading per degree of frame tilt
(about 1.7 at 60 deg inclination), with only the prior's 10 % on the cross terms to bound it (the
independent generator's car, 300 s with the tilt within +-0.2 deg: measured level p95 4-16 deg, throwaway run).

A vehicle that is level on average (a car, a ground robot on a floor) sees the calibrated field's vertical
component uncorrelated with its horizontal ones over the turns: the plane of the calibrated ring is level.
Its tilt is the pair of slopes ``a = (a_x, a_y)`` of the regression ``h_z ~ c + a_x h_x + a_y h_y`` over the
points (radians, for small tilts); the term is the pseudo-observation ``a = 0`` with standard deviation
``LEVEL_TILT_STD_DEG`` per axis, how level the vehicle is on average: an assumption, not a measurement, so
the level heading figure of such a fit has a floor of about ``1.96 (Z / H) LEVEL_TILT_STD_DEG``. The ring's own
tilt wanders too (suspension, road grade), and the slope of a few minutes of it scatters about the vehicle's mean
by its standard error (``slope_std``: the regression's on the raw points, the residual's correlation time shrinking
the sample count), added in quadrature to the posterior's covariance only (``covariance_weight``): the bound of a
fit on a rougher ring claims less, the fit itself is the same (weighted in the fit too, the iterated noise estimate
let a free-diagonal ring fit collapse its horizontal gains). Nor is a vehicle level on average over its first turn:
a turn's roll (lateral acceleration) is constant over it and the regression takes it for the ring's slope, so the
mean tilt of ``n`` turns (``turns``: the azimuth the raw ring went through, both ways) adds ``LEVEL_TILT_STD / n``
(``n >= 1``; each turn's own mean tilt as uncertain as the vehicle's). Independent car without a gyro, level
mount: bound covers 63/63 on seeds 100-119 (tuning; 39/41 with the slope error alone, whose misses were fits on
the first turn, 16-27 s) and 64/64 on 200-219; the first calibration comes later (median 42 s, was 25 s). Two residuals
only: the term pins the two directions the norm leaves free and nothing else (holding every ``h_z`` to a
constant instead also claims the vertical gain, and the fit shrinks it until the tilt's share of ``h_z``
vanishes). A sensor mounted tilted on the vehicle is calibrated in the vehicle's level frame. Applied only to
near-level rings without a usable gyro (``stream.observable``), and said so in the status.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .fitting_core import unpack

__all__ = ["LEVEL_TILT_STD_DEG", "LevelTerm", "circle_centre", "ring_tilt", "slope_std", "turns"]

Array = NDArray[np.float64]

LEVEL_TILT_STD_DEG = 0.5
"""How level a vehicle is on average over its turns, per axis (degrees, one standard deviation): roads and
floors; a vehicle parked on a slope while turning is not one (its calibration is then in the slope's frame)."""


def ring_tilt(pts: Array, theta: Array) -> Array:
    """Slopes ``(a_x, a_y)`` of the regression ``h_z ~ c + a_x h_x + a_y h_y`` of the calibrated points
    ``h = W (v - b)`` of the symmetric parameters ``theta`` (module docstring)."""
    return _tilt(_scatter(pts), unpack(theta[:9], "sym")[1])


def _scatter(pts: Array) -> Array:
    """The points' centred second moment (3, 3): the regression's slopes depend on nothing else."""
    d = pts - pts.mean(axis=0)
    return d.T @ d / max(len(pts), 1)


def _tilt(scatter: Array, mat: Array) -> Array:
    """The slopes from the calibrated points' moment ``W C W^T`` (the offset cancels in the centring)."""
    s = mat @ scatter @ mat.T
    return np.linalg.solve(s[:2, :2], s[:2, 2])


_DW = [unpack(np.eye(9)[k], "sym")[1] for k in range(3, 9)]
"""The derivative of W by each of its six symmetric parameters (W is linear in them)."""


def slope_std(pts: Array) -> float:
    """Standard error of the ring's slopes (radians, the larger axis) from the time-ordered raw points' own tilt
    wander: the regression's, its sample count shrunk by the residual's correlation time (module docstring;
    on the raw points, so that it is the data's, not an iterate's: small soft iron changes it little)."""
    if len(pts) < 8:
        return 0.0
    a = np.c_[np.ones(len(pts)), pts[:, 0], pts[:, 1]]
    r = pts[:, 2] - a @ np.linalg.lstsq(a, pts[:, 2], rcond=None)[0]
    if not np.any(r):
        return 0.0
    n_eff = max(len(r) / _correlation_time(r), 2.0)
    cov = np.linalg.pinv(a.T @ a) * float(np.mean(r**2)) * len(r) / n_eff
    return float(np.sqrt(max(cov[1, 1], cov[2, 2])))


def circle_centre(xy: Array) -> tuple[float, float]:
    """The centre of the least-squares circle through the points ``xy`` (N, 2) (linear in the centre and
    ``r^2 - |c|^2``); (0, 0) when degenerate."""
    a = np.c_[2.0 * xy, np.ones(len(xy))]
    sol = np.linalg.lstsq(a, (xy**2).sum(axis=1), rcond=None)[0]
    return (float(sol[0]), float(sol[1])) if np.all(np.isfinite(sol)) else (0.0, 0.0)


def turns(pts: Array, step_deg: float = 15.0) -> float:
    """How many turns the time-ordered raw points' azimuth went through, about the least-squares circle of their
    horizontal components, counted in steps of ``step_deg`` both ways (a sample's noise never counts as turning)."""
    if len(pts) < 3:
        return 0.0
    cx, cy = circle_centre(pts[:, :2])
    az = np.unwrap(np.arctan2(pts[:, 1] - cy, pts[:, 0] - cx))
    step, last, total = math.radians(step_deg), float(az[0]), 0.0
    for a in az[1:]:
        if abs(a - last) >= step:
            total += abs(a - last)
            last = float(a)
    return total / (2.0 * math.pi)


def _correlation_time(r: Array) -> float:
    """The integrated autocorrelation time of ``r`` in samples, ``1 + 2 sum rho_k`` over the lags before the
    autocorrelation first turns negative (a smooth wander is not AR(1): its lag-1 correlation near 1 would claim
    far fewer independent samples than it has)."""
    n = len(r)
    f = np.fft.rfft(r - r.mean(), 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    if not acf[0] > 0.0:  # a constant series: nothing to correlate
        return 1.0
    acf = acf / acf[0]
    neg = np.flatnonzero(acf[1:] < 0.0)
    stop = int(neg[0]) + 1 if len(neg) else n
    return float(max(1.0, 1.0 + 2.0 * np.sum(acf[1:stop])))


@dataclass
class LevelTerm:
    """The level pseudo-observation of a MAP fit (``fitting_prior``): the points and the weight that puts the
    tilt's standard deviation on the norm residuals' scale ``s`` (the interface of ``fitting_gyro.GyroTerm``;
    no parameters of its own: ``at`` is the end of the fit's parameter vector)."""

    pts: Array
    weight: float
    at: int
    _c: Array = field(init=False, repr=False)  # the points' centred second moment (``_scatter``)

    def __post_init__(self) -> None:
        self._c = _scatter(self.pts)

    def residuals(self, theta: Array) -> tuple[Array, Array]:
        """``ring_tilt`` at ``theta`` (2,) and its transposed Jacobian (9, 2), exact from the points' moment:
        ``a = S_xx^-1 s_xz`` with ``S = W C W^T``, so ``da = S_xx^-1 (ds_xz - dS_xx a)``; the offset's rows are 0."""
        mat = unpack(np.asarray(theta[:9], dtype=np.float64), "sym")[1]
        s = mat @ self._c @ mat.T
        a = np.linalg.solve(s[:2, :2], s[:2, 2])
        jt = np.zeros((9, 2))
        for k, dw in enumerate(_DW, start=3):
            half = dw @ self._c @ mat.T
            ds = half + half.T
            jt[k] = np.linalg.solve(s[:2, :2], ds[:2, 2] - ds[:2, :2] @ a)
        return a, jt

    def reweigh(self, theta: Array, s: float, floor: float) -> None:
        """The weight ``s / LEVEL_TILT_STD`` (radians): the assumption's, whatever the residuals."""
        self.weight = max(s, floor) / math.radians(LEVEL_TILT_STD_DEG)

    def covariance_weight(self) -> float:
        """The weight for the posterior covariance: the assumption's standard deviation, the slopes' own standard
        error (``slope_std``) and the few turns' mean tilt (``turns``) in quadrature (module docstring); the fit
        keeps ``weight``."""
        sd = math.radians(LEVEL_TILT_STD_DEG)
        few = sd / max(turns(self.pts), 1.0)
        return self.weight * sd / math.sqrt(sd * sd + slope_std(self.pts) ** 2 + few * few)
