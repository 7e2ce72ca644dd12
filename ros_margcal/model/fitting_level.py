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
the level heading figure of such a fit has a floor of about ``1.96 (Z / H) LEVEL_TILT_STD_DEG``. Two residuals
only: the term pins the two directions the norm leaves free and nothing else (holding every ``h_z`` to a
constant instead also claims the vertical gain, and the fit shrinks it until the tilt's share of ``h_z``
vanishes). A sensor mounted tilted on the vehicle is calibrated in the vehicle's level frame. Applied only to
near-level rings without a usable gyro (``stream.observable``), and said so in the status.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .fitting_core import unpack

__all__ = ["LEVEL_TILT_STD_DEG", "LevelTerm", "ring_tilt"]

Array = NDArray[np.float64]

LEVEL_TILT_STD_DEG = 0.5
"""How level a vehicle is on average over its turns, per axis (degrees, one standard deviation): roads and
floors; a vehicle parked on a slope while turning is not one (its calibration is then in the slope's frame)."""
_STEP = 1e-6  # relative step of the central differences of ``ring_tilt``


def ring_tilt(pts: Array, theta: Array) -> Array:
    """Slopes ``(a_x, a_y)`` of the regression ``h_z ~ c + a_x h_x + a_y h_y`` of the calibrated points
    ``h = W (v - b)`` of the symmetric parameters ``theta`` (module docstring)."""
    b, mat = unpack(theta[:9], "sym")
    h = (pts - b) @ mat.T
    a = np.c_[np.ones(len(h)), h[:, 0], h[:, 1]]
    return np.linalg.solve(a.T @ a, a.T @ h[:, 2])[1:]


@dataclass
class LevelTerm:
    """The level pseudo-observation of a MAP fit (``fitting_prior``): the points and the weight that puts the
    tilt's standard deviation on the norm residuals' scale ``s`` (the interface of ``fitting_gyro.GyroTerm``;
    no parameters of its own: ``at`` is the end of the fit's parameter vector)."""

    pts: Array
    weight: float
    at: int

    def residuals(self, theta: Array) -> tuple[Array, Array]:
        """``ring_tilt`` at ``theta`` (2,) and its transposed Jacobian (9, 2), central differences."""
        th = np.asarray(theta[:9], dtype=np.float64)
        jt = np.empty((9, 2))
        scale = max(float(np.max(np.abs(th[3:]))), 1e-300)
        radius = float(np.median(np.linalg.norm(self.pts - th[:3], axis=1)))
        for k in range(9):
            step = _STEP * (radius if k < 3 else scale)
            up, down = th.copy(), th.copy()
            up[k] += step
            down[k] -= step
            jt[k] = (ring_tilt(self.pts, up) - ring_tilt(self.pts, down)) / (2.0 * step)
        return ring_tilt(self.pts, th), jt

    def reweigh(self, theta: Array, s: float, floor: float) -> None:
        """The weight ``s / LEVEL_TILT_STD`` (radians): the assumption's, whatever the residuals."""
        self.weight = max(s, floor) / math.radians(LEVEL_TILT_STD_DEG)
