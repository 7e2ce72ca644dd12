"""Predicted heading error of a magnetometer calibration, from its parameter covariance.

What a robot user cares about is the compass heading, not the offset. With the calibration's
parameters ``theta`` (the symmetric model of ``fitting_core``) and covariance ``C``, the heading error at
an attitude is, to first order, ``N(0, g^T C g)`` with ``g = d psi / d theta`` the sensitivity of the
tilt-compensated heading ``psi`` to the parameters. ``g`` is taken by central differences on the
reading the calibration itself predicts for that attitude (``v = W^-1 R^T m + b``), so no truth is
needed: the figure is the calibration's own honest uncertainty.

Attitudes: every yaw on a grid, with roll and pitch each in ``{-tilt, 0, +tilt}`` (level only for
``tilt = 0``). The field ``m`` has the calibration's norm and the given inclination (ENU world frame,
pointing north and down). ``heading_std_deg`` gives ``sqrt(g^T C g)`` per attitude (any attitudes);
``heading_p95`` reports the 95th percentile over the grid of the two-sided 95 % bound ``1.96 sqrt(g^T C g)``,
in degrees.

The p95 figure is a *bound*: one calibration's measured p95 scatters below it. When one parameter
direction dominates (the vertical terms of a ring, judged at a tilt not seen), the measured p95 is about
``|z| / 1.96`` of the bound with ``z ~ N(0, 1)``: a median of a third, and below a quarter one time in
five, however right ``C`` is. Whether ``C`` is right is judged per attitude, by the measured error over
``heading_std_deg`` (``scripts/study_ground_robot.py``: its RMS over seeds is 1 when it is).

``heading_p95_typical`` is the prediction of the measured figure itself: the median, over parameter errors
drawn from ``C`` (``TYPICAL_DRAWS`` fixed draws, so the figure is deterministic), of the p95 over the grid of
``|g^T delta|``. A calibration's measured p95 lies above or below it with even odds when ``C`` is right; the
p95 bound above is the same distribution's 95th percentile (for one dominant direction, about 2.9 times it).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .calibration import Calibration
from .errors import InputError
from .fitting_core import parameter_names

__all__ = ["TYPICAL_DRAWS", "attitudes", "heading_gradient", "heading_p95", "heading_p95_typical", "heading_std_deg",
           "inclination_deg"]

Array = NDArray[np.float64]

_NAMES = parameter_names("sym", scale_free=False)
TYPICAL_DRAWS = 256
"""Parameter errors drawn from the covariance for ``heading_p95_typical`` (a fixed seed: deterministic)."""
_TYPICAL_Z = np.random.default_rng(20261126).standard_normal((TYPICAL_DRAWS, 9))


def attitudes(tilt_deg: float, n_yaw: int = 72) -> Array:
    """Rotation matrices body -> world (K, 3, 3) over a yaw grid, roll and pitch in {-tilt, 0, tilt}
    (``R = R_z(yaw) R_y(pitch) R_x(roll)``, roll outermost, then pitch, then yaw)."""
    yaw = np.linspace(0.0, 2.0 * math.pi, n_yaw, endpoint=False)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rz = np.zeros((n_yaw, 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = cy, -sy, sy, cy, 1.0
    tilts = [0.0] if tilt_deg == 0 else [-math.radians(tilt_deg), 0.0, math.radians(tilt_deg)]
    out = []
    for r in tilts:
        for p in tilts:
            cr, sr, cp, sp = math.cos(r), math.sin(r), math.cos(p), math.sin(p)
            rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
            ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
            out.append(rz @ (ry @ rx))
    return np.concatenate(out)


def inclination_deg(cal: Calibration, raw: Array, gravity_body: Array | None = None) -> float:
    """Field inclination seen in ``raw``: from the gravity direction when given, else assuming the
    sensor's z axis is roughly vertical on average (a ground robot): ``asin(-mean(h_z) / |h|)``."""
    h = cal.apply(raw)
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    if gravity_body is not None:
        up = -np.asarray(gravity_body, dtype=np.float64)
        up = up / np.linalg.norm(up, axis=-1, keepdims=True)
        s = float(np.mean(np.sum(h * up, axis=-1)))
    else:
        s = float(np.mean(h[:, 2]))
    return math.degrees(math.asin(float(np.clip(-s, -1.0, 1.0))))


def _heading_gradient(w: Array, d: Array, rot: Array) -> Array:
    """d(heading)/d(theta) (K, 9) at raw offsets ``d = raw - b`` (K, 3): with ``H = R W d`` and
    ``psi = atan2(H_x, H_y)``, ``dpsi = c . dh``, ``c = (H_y R_0 - H_x R_1) / (H_x^2 + H_y^2)`` (R_i the rows of R),
    ``dh = -W e_i`` for ``b_i``, ``e_j d_j`` for ``w_jj``, ``e_j d_k + e_k d_j`` for ``w_jk``."""
    world = np.einsum("kij,kj->ki", rot, d @ w.T)
    hx, hy = world[:, 0:1], world[:, 1:2]
    c = (hy * rot[:, 0, :] - hx * rot[:, 1, :]) / (hx * hx + hy * hy)
    grad = np.empty((len(d), 9))
    grad[:, :3] = -(c @ w)
    grad[:, 3:6] = c * d
    grad[:, 6:9] = c[:, [0, 0, 1]] * d[:, [1, 2, 2]] + c[:, [1, 2, 2]] * d[:, [0, 0, 1]]
    return grad


def heading_gradient(cal: Calibration, rot: Array, *, inclination: float = 60.0) -> Array:
    """Sensitivity of the heading (degrees per parameter unit) to the symmetric parameters at each attitude
    ``rot`` (K, 3, 3 body -> world): (K, 9), on the reading ``cal`` predicts there (module docstring)."""
    rot = np.asarray(rot, dtype=np.float64).reshape(-1, 3, 3)
    inc = math.radians(inclination)
    m = cal.norm * np.array([0.0, math.cos(inc), -math.sin(inc)])
    body = np.einsum("kji,j->ki", rot, m)  # R^T m
    raw = np.linalg.solve(cal.matrix, body.T).T + cal.offset
    return np.degrees(_heading_gradient(cal.matrix, raw - cal.offset, rot))


def _covariance(cal: Calibration) -> Array:
    if cal.covariance is None or tuple(cal.parameter_names) != _NAMES:
        msg = f"heading error needs a covariance over {_NAMES}"
        raise InputError(msg)
    return np.asarray(cal.covariance, dtype=np.float64)


def heading_std_deg(cal: Calibration, rot: Array, *, inclination: float = 60.0) -> Array:
    """Predicted standard deviation (degrees) of the heading error of ``cal`` at each attitude ``rot``
    (K, 3, 3 body -> world): ``sqrt(g^T C g)`` (module docstring).

    Raises:
        InputError: the calibration has no covariance over the symmetric model's parameters.
    """
    cov = _covariance(cal)
    grad = heading_gradient(cal, rot, inclination=inclination)
    var = np.einsum("ki,ij,kj->k", grad, cov, grad)
    return np.sqrt(np.clip(var, 0.0, None))


def heading_p95(cal: Calibration, *, tilt_deg: float = 0.0, inclination: float = 60.0, n_yaw: int = 72) -> float:
    """Predicted 95th-percentile heading error (degrees) of ``cal`` at the given tilt (module docstring).

    Raises:
        InputError: the calibration has no covariance over the symmetric model's parameters.
    """
    sd = heading_std_deg(cal, attitudes(tilt_deg, n_yaw), inclination=inclination)
    return float(np.percentile(1.96 * sd, 95))


def heading_p95_typical(cal: Calibration, *, tilt_deg: float = 0.0, inclination: float = 60.0, n_yaw: int = 72) -> float:
    """Predicted median of the measured heading p95 (degrees) of ``cal`` at the given tilt: the p95 over the
    grid of ``|g^T delta|``, its median over ``TYPICAL_DRAWS`` errors ``delta`` drawn from the covariance
    (module docstring). NaN when the covariance is not finite.

    Raises:
        InputError: the calibration has no covariance over the symmetric model's parameters.
    """
    cov = _covariance(cal)
    if not np.all(np.isfinite(cov)):
        return math.nan
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    grad = heading_gradient(cal, attitudes(tilt_deg, n_yaw), inclination=inclination)
    errors = np.abs(_TYPICAL_Z @ (grad @ (vec * np.sqrt(np.clip(lam, 0.0, None)))).T)  # (draws, attitudes)
    k = errors.shape[1]  # the 95th percentile of each row as np.percentile's linear rule, by partition (no sort)
    pos = 0.95 * (k - 1)
    lo, hi = math.floor(pos), min(math.floor(pos) + 1, k - 1)
    part = np.partition(errors, [lo, hi], axis=1)
    return float(np.median(part[:, lo] + (pos - lo) * (part[:, hi] - part[:, lo])))
