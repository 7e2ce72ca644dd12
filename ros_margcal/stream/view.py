"""What a calibrator has seen, for a person to look at: buffered samples, covered bins, the fitted ellipsoid.

Plain arrays, no plotting and no ROS: the node turns a ``CoverageView`` into an RViz ``MarkerArray``
(``ros/markers.py``) and ``margcal replay --plot`` draws the same view with matplotlib, so the operator sees
one picture in both (MotionCal's live sphere, in the tools ROS users already run).

Display coordinates: a raw sample minus the centre (the calibration's offset, else the buffer's centre
estimate), over the raw field radius. A perfect sensor's samples then lie on the unit sphere (1 m in RViz)
and a fitted ellipsoid shows how far the raw readings are from a sphere; the covered direction bins are
unit vectors at their bins' centres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["CoverageView", "bin_directions", "coverage_view"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CoverageView:
    """One sensor's picture (see the module docstring for the coordinates).

    ``points`` (n, 3) buffered samples; ``bins`` (m, 3) centres of the bins holding a sample; ``axes`` (3, 3)
    the ellipsoid's axis directions as columns and ``radii`` (3,) its semi-axes, both None while uncalibrated;
    ``radius`` the raw field radius that one display unit stands for, in ``unit``.
    """

    sensor: str
    state: str
    unit: str
    coverage: float
    radius: float
    points: Array
    bins: Array
    axes: Array | None
    radii: Array | None


def bin_directions(n_bands: int, n_sectors: int) -> Array:
    """Unit vectors at the centres of the buffer's equal-area bins (``coverage/buffer.py``: bands of equal z,
    sectors of equal azimuth from -pi), row ``band * n_sectors + sector``."""
    z = (np.arange(n_bands) + 0.5) / n_bands * 2.0 - 1.0
    phi = (np.arange(n_sectors) + 0.5) * (2.0 * math.pi / n_sectors) - math.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    rho = np.sqrt(1.0 - zz * zz)
    return np.column_stack([(rho * np.cos(pp)).ravel(), (rho * np.sin(pp)).ravel(), zz.ravel()])


def coverage_view(calibrator: Any) -> CoverageView:
    """The picture of a ``SensorCalibrator`` now (its buffer, its calibration, its state)."""
    buf = calibrator.buffer
    cal = calibrator.calibration
    q = getattr(calibrator, "up_rotation", None)  # up_axis: the buffer holds the turned readings q v; shown unturned
    pts = buf.points() if q is None else buf.points() @ q
    if cal is not None:
        centre = np.asarray(cal.offset, dtype=float)
        radius = cal.norm / abs(float(np.linalg.det(cal.matrix))) ** (1.0 / 3.0)
    else:
        centre = buf.center if q is None else buf.center @ q
        radius = buf.radius or (float(np.median(np.linalg.norm(pts - centre, axis=1))) if len(pts) else 1.0)
    if not (math.isfinite(radius) and radius > 0.0):
        radius = 1.0
    axes = radii = None
    if cal is not None:
        # |W (v - b)| = norm is the image of the unit sphere under norm W^-1 = norm V S^-1 U^T (W = U S V^T)
        _, s, vt = np.linalg.svd(cal.matrix)
        axes, radii = vt.T.copy(), cal.norm / (s * radius)
        if np.linalg.det(axes) < 0.0:
            axes[:, 2] *= -1.0  # a rotation (RViz takes a quaternion); the ellipsoid is the same
    dirs = bin_directions(buf.n_bands, buf.n_sectors)
    dirs = dirs if q is None else dirs @ q
    counts = np.asarray(buf.bin_counts())
    return CoverageView(sensor=calibrator.sensor, state=calibrator.state.value, unit=calibrator.config.unit,
                        coverage=float(buf.coverage()), radius=float(radius), points=(pts - centre) / radius,
                        bins=dirs[counts > 0], axes=axes, radii=radii)
