"""Coverage patterns: unit vectors of the physical field/gravity direction in the body frame.

``directions(pattern, n, rng, **params)`` draws the calibration sets of Olivares et al. 2013 (uniform,
caps, bands, great circles and the three axis ellipses of their Fig. 7) and Gietzelt et al. 2013
(uniformly jittered points on an ellipsoid, Sect. 2.3), plus a random walk and a few static poses.
``simulation.simulate`` turns them into raw readings; ``simulation`` re-exports ``directions`` and
``PATTERNS``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model.errors import ConfigError, as_vector3

__all__ = ["PATTERNS", "directions", "unit_vectors"]

Array = NDArray[np.float64]


def unit_vectors(v: Array) -> Array:
    """``v`` scaled to unit length along its last axis (a (3,) vector or the rows of an (n, 3) array)."""
    out: Array = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return out


PATTERNS: tuple[str, ...] = ("uniform", "cap", "band", "great_circle", "axis_ellipses", "random_walk", "few_uniform")
"""Names accepted by ``directions``."""


def _rotation_z_to(axis: ArrayLike) -> Array:
    """Rotation matrix taking +z onto ``axis`` (Rodrigues)."""
    a = as_vector3(axis, "axis")
    n = np.linalg.norm(a)
    if n == 0:
        msg = "axis must be a non-zero vector"
        raise ConfigError(msg)
    a = a / n
    c = float(a[2])
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    k = np.cross([0.0, 0.0, 1.0], a)
    s = np.linalg.norm(k)
    k = k / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    rot: Array = np.eye(3) + s * kx + (1 - c) * kx @ kx
    return rot


def _uniform(n: int, rng: np.random.Generator) -> Array:
    return unit_vectors(rng.normal(size=(n, 3)))


def _zone(n: int, rng: np.random.Generator, z_lo: float, z_hi: float, axis: ArrayLike) -> Array:
    """Uniform (equal-area) points with ``z_lo <= z <= z_hi`` about ``axis`` (Archimedes)."""
    z = rng.uniform(z_lo, z_hi, size=n)
    phi = rng.uniform(0.0, 2 * np.pi, size=n)
    r = np.sqrt(np.clip(1 - z * z, 0.0, None))
    pts = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    return pts @ _rotation_z_to(axis).T


def _great_circles(n: int, rng: np.random.Generator, arc_deg: float, n_circles: int) -> Array:
    if not 0 < arc_deg <= 360 or n_circles < 1:
        msg = f"great_circle needs 0 < arc_deg <= 360 and n_circles >= 1, got {arc_deg}, {n_circles}"
        raise ConfigError(msg)
    which = np.arange(n) % n_circles
    normals = _uniform(n_circles, rng)
    starts = rng.uniform(0, 2 * np.pi, size=n_circles)
    ang = starts[which] + rng.uniform(0, np.radians(arc_deg), size=n)
    out = np.empty((n, 3))
    for k in range(n_circles):
        rot = _rotation_z_to(normals[k])
        sel = which == k
        out[sel] = np.column_stack([np.cos(ang[sel]), np.sin(ang[sel]), np.zeros(sel.sum())]) @ rot.T
    return out


def _random_walk(n: int, rng: np.random.Generator, step_deg: float) -> Array:
    step = math.radians(step_deg)
    kicks = rng.normal(size=(n, 3)) * step / math.sqrt(2.0)
    out = np.empty((n, 3))
    d = _uniform(1, rng)[0]
    for i in range(n):
        out[i] = d
        k = kicks[i] - np.dot(kicks[i], d) * d  # tangent step of rms length `step`
        d = d + k
        d = d / math.sqrt(float(d @ d))
    return out


def directions(pattern: str, n: int, rng: np.random.Generator, **params: Any) -> Array:
    """Unit vectors (n, 3) of a coverage pattern.

    Patterns and their parameters:
        - "uniform": uniform on the sphere.
        - "cap": uniform within ``half_angle_deg`` (default 45) of ``axis`` (default +z).
        - "band": uniform between latitudes ``lat_min_deg`` and ``lat_max_deg`` (default -20, 20)
          relative to the equator of ``axis`` (default +z).
        - "great_circle": ``n_circles`` (default 1) random great circles, each covered over an arc of
          ``arc_deg`` (default 360) from a random start.
        - "axis_ellipses": the three orthogonal circles about the x, y and z axes (Olivares et al.
          2013, Fig. 7): n/3 points on each of the planes x=0, y=0, z=0, ``jitter_deg`` (default 0)
          off the plane.
        - "random_walk": a path on the sphere with tangent steps of rms ``step_deg`` (default 5).
        - "few_uniform": ``k`` (default 6) uniformly drawn poses, samples spread over them with
          ``jitter_deg`` (default 1) scatter (a few static poses, as a 6-position calibration).

    Raises:
        ConfigError: unknown pattern or parameter, or a parameter out of range.
    """
    if n < 1:
        msg = f"n must be >= 1, got {n}"
        raise ConfigError(msg)
    allowed = {
        "uniform": set(),
        "cap": {"half_angle_deg", "axis"},
        "band": {"lat_min_deg", "lat_max_deg", "axis"},
        "great_circle": {"arc_deg", "n_circles"},
        "axis_ellipses": {"jitter_deg"},
        "random_walk": {"step_deg"},
        "few_uniform": {"k", "jitter_deg"},
    }
    if pattern not in allowed:
        msg = f"unknown pattern {pattern!r}; choose one of {PATTERNS}"
        raise ConfigError(msg)
    unknown = set(params) - allowed[pattern]
    if unknown:
        msg = f"pattern {pattern!r} takes {sorted(allowed[pattern])}, not {sorted(unknown)}"
        raise ConfigError(msg)
    axis = params.get("axis", (0.0, 0.0, 1.0))
    if pattern == "uniform":
        return _uniform(n, rng)
    if pattern == "cap":
        half = float(params.get("half_angle_deg", 45.0))
        if not 0 < half <= 180:
            msg = f"half_angle_deg must be in (0, 180], got {half}"
            raise ConfigError(msg)
        return _zone(n, rng, math.cos(math.radians(half)), 1.0, axis)
    if pattern == "band":
        lo, hi = float(params.get("lat_min_deg", -20.0)), float(params.get("lat_max_deg", 20.0))
        if not -90 <= lo < hi <= 90:
            msg = f"band needs -90 <= lat_min_deg < lat_max_deg <= 90, got {lo}, {hi}"
            raise ConfigError(msg)
        return _zone(n, rng, math.sin(math.radians(lo)), math.sin(math.radians(hi)), axis)
    if pattern == "great_circle":
        return _great_circles(n, rng, float(params.get("arc_deg", 360.0)), int(params.get("n_circles", 1)))
    if pattern == "axis_ellipses":
        jitter = math.radians(float(params.get("jitter_deg", 0.0)))
        plane = np.arange(n) % 3  # the axis each circle goes around (its zero coordinate)
        ang = rng.uniform(0, 2 * np.pi, size=n)
        off = np.sin(rng.normal(0.0, 1.0, size=n) * jitter) if jitter > 0 else np.zeros(n)
        c = np.sqrt(1 - off**2)
        pts = np.empty((n, 3))
        cols = np.array([[1, 2, 0], [2, 0, 1], [0, 1, 2]])[plane]
        rows = np.arange(n)
        pts[rows, cols[:, 0]] = c * np.cos(ang)
        pts[rows, cols[:, 1]] = c * np.sin(ang)
        pts[rows, cols[:, 2]] = off
        return pts
    if pattern == "random_walk":
        return _random_walk(n, rng, float(params.get("step_deg", 5.0)))
    k = int(params.get("k", 6))
    if k < 1:
        msg = f"k must be >= 1, got {k}"
        raise ConfigError(msg)
    poses = _uniform(k, rng)
    jitter = math.radians(float(params.get("jitter_deg", 1.0)))
    pts = poses[np.arange(n) % k] + rng.normal(size=(n, 3)) * jitter / math.sqrt(2.0)
    return unit_vectors(pts)
