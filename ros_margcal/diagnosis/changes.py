"""Locate one offset change (a hard-iron step) in a recording that no single calibration fits.

When a magnet or a magnetised part is attached near a magnetometer in mid-recording, the offset ``b``
steps and the whole recording no longer lies on one ellipsoid: the baseline fit of ``twin.build_twin``
may not converge at all. ``locate_offset_change`` finds where the step is, so the failure can say so
and the parts before and after it can be diagnosed separately.

Method: on the samples where the sensor moves (``moving_mask``: a still stretch lies on no ellipsoid
and would let any split look good), the linear ellipsoid fit with the trace constraint (``_design``:
``|u|^2`` regressed on nine quadric terms, a sphere fit plus five shape terms) is computed for every
split point at once from cumulative sums of ``X^T X``, ``X^T y`` and ``y^T y`` (a change point of a
linear regression). The split with the lowest total residual sum of squares wins; it counts as an
offset change when it removes at least ``MIN_DROP`` of the single fit's residual sum of squares
(simulated recordings: one hard-iron jump of 0.15 field radii removes > 0.95; no effect, soft iron,
drift or non-linearity remove < 0.45), and when the same is true with *one shape and two centres*
(``shared_drop``: the five shape terms shared, the centre and constant per side). Two free ellipsoids
fitted to the two halves of a tumble each cover part of the sphere and absorb a non-ellipsoidal
distortion (clipping, a cubic non-linearity) locally, so the free split alone is no evidence of a
step; a hard-iron step moves the centre and keeps the shape, which the shared fit tests.

A step is evidence only when each side on its own goes round (``sectors``: about its own mean, in the
plane of its largest spread, it visits at least ``MIN_SECTORS`` of ``_SECTORS`` azimuth sectors) or moves
in three dimensions (``MIN_THICKNESS``). One smooth turn (a car's single circle, a partial arc) split in
two leaves two arcs, each of which its own centre fits better than the whole ring does, so the split looks
good (a simulated 360° turn at 1.5° tilt: 0.50-0.67 removed by one shape with two centres) although
nothing changed; each half visits 8-9 sectors. Hard-iron steps during a tumble, a ground robot's or a
car's repeated turns, and BROAD 32 and 36 (a magnet attached mid-recording) pass on both sides.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .stages import rest_noise

__all__ = ["MIN_DROP", "MIN_SECTORS", "MIN_SHARED_DROP", "MIN_THICKNESS", "OffsetChange", "locate_offset_change",
           "moving_mask", "sectors", "step_evidence"]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

MIN_DROP = 0.6
"""Share of the single ellipsoid fit's residual sum of squares a split must remove to count as an offset change."""
MIN_SHARED_DROP = 0.65
"""The same for one shape with two centres (simulated and independent-generator jumps of 0.1-0.9 field
radii: > 0.77; clipping, cubic non-linearity, drift, no effect: < 0.6)."""
MIN_SECTORS = 11
"""Azimuth sectors (of ``_SECTORS``) each side of a split must visit on its own (``sectors``)."""
_SECTORS = 12
MIN_THICKNESS = 0.2
"""Smallest over largest spread (singular values) from which points are a 3-D motion, not a ring or an arc."""
_MIN_SIDE = 0.1  # each side of the split holds at least this share of the moving samples
_N_CANDIDATES = 400
_MOVE_SIGMAS = 3.0
_WINDOW_S = 1.0
_MIN_MOVING = 40
_P = 9  # quadric coefficients


@dataclass(frozen=True)
class OffsetChange:
    """An offset change found by ``locate_offset_change``.

    Attributes:
        t: time of the change, seconds (midway between the last moving sample before it and the first after).
        drop: share of the single ellipsoid fit's residual sum of squares the split removes.
        offset_before: ellipsoid-fit centre of the moving samples before the change, raw units.
        offset_after: the same after the change.
        radius: median distance of the moving samples before the change from ``offset_before``, raw units.
        shared_drop: share of the single fit's residual sum of squares removed by one shape with two
            centres split at the change.
        sectors: azimuth sectors the side that goes round less visits on its own (``sectors``).
    """

    t: float
    drop: float
    offset_before: Array
    offset_after: Array
    radius: float
    shared_drop: float = 1.0
    sectors: int = _SECTORS

    @property
    def step(self) -> float:
        """Size of the offset step, raw units."""
        return float(np.linalg.norm(self.offset_after - self.offset_before))

    @property
    def relative_step(self) -> float:
        """Offset step as a fraction of the field radius (the unit of the ``hard_iron_jump`` effect)."""
        return self.step / max(self.radius, 1e-300)


def moving_mask(t: Array, raw: Array, noise: float | None = None, window_s: float = _WINDOW_S) -> NDArray[np.bool_]:
    """Samples in time windows of ``window_s`` where some axis spreads by more than ``_MOVE_SIGMAS``
    noise stds (std over the window): the turning parts of a recording, without its still stretches."""
    n = raw.shape[0]
    sigma = rest_noise(raw) if noise is None else noise
    span = float(t[-1] - t[0]) if n > 1 else 0.0
    if n < 3 or span <= 0:
        return np.ones(n, dtype=bool)
    idx = np.minimum(((t - t[0]) / window_s).astype(np.intp), int(span / window_s))
    out = np.zeros(n, dtype=bool)
    for w in np.unique(idx):
        sel = idx == w
        if int(sel.sum()) >= 3:
            out[sel] = float(np.max(np.std(raw[sel], axis=0))) > _MOVE_SIGMAS * sigma
    return out


def _rss(g: Array, xy: Array, yy: Array) -> Array:
    """Residual sums of squares of the least-squares fits with normal equations ``g`` (k, 9, 9)."""
    ridge = 1e-10 * np.einsum("kii->k", g)[:, None, None] * np.eye(_P) + 1e-300 * np.eye(_P)
    coef = np.linalg.solve(g + ridge, xy[:, :, None])[:, :, 0]
    return np.maximum(yy - np.einsum("ki,ki->k", xy, coef), 0.0)


def _design(u: Array) -> tuple[Array, Array]:
    """Linear ellipsoid fit with the trace constraint: ``|u|^2 = a (x^2 + y^2 - 2 z^2) + b (x^2 - 2 y^2 + z^2)
    + 2 (e xy + f xz + g yz) + 2 d . u + k`` (a sphere when ``a = b = e = f = g = 0``)."""
    x0, x1, x2 = u[:, 0], u[:, 1], u[:, 2]
    sq = u * u
    cols = [sq[:, 0] + sq[:, 1] - 2 * sq[:, 2], sq[:, 0] - 2 * sq[:, 1] + sq[:, 2], 2 * x0 * x1, 2 * x0 * x2,
            2 * x1 * x2, 2 * x0, 2 * x1, 2 * x2, np.ones(len(u))]
    return np.column_stack(cols), np.sum(sq, axis=1)


def _centre(g: Array, xy: Array) -> Array:
    """Centre ``(I - M)^{-1} d`` of the ellipsoid fitted by ``_design`` with normal equations ``g``, ``xy``."""
    q = np.linalg.solve(g + 1e-10 * np.trace(g) * np.eye(_P), xy)
    a, b, e, f, h = q[:5]
    m = np.array([[a + b, e, f], [e, a - 2 * b, h], [f, h, -2 * a + b]])
    return np.asarray(np.linalg.solve(np.eye(3) - m, q[5:8]), dtype=np.float64)


def sectors(points: Array) -> int:
    """Azimuth sectors (of ``_SECTORS``, each visited at least twice) of ``points`` (n, 3) about their mean, in the
    plane of their largest spread: ``_SECTORS`` for a ring that goes round, 8-9 for half a ring; ``_SECTORS`` also
    for points spread in three dimensions (their smallest spread at least ``MIN_THICKNESS`` of their largest): the
    check is for rings and arcs."""
    if len(points) < 3:
        return 0
    c = points - points.mean(axis=0)
    _, spread, axes = np.linalg.svd(c, full_matrices=False)
    if spread[2] >= MIN_THICKNESS * spread[0]:
        return _SECTORS
    phi = np.arctan2(c @ axes[1], c @ axes[0])
    _, counts = np.unique(((phi + np.pi) / (2 * np.pi) * _SECTORS).astype(np.intp) % _SECTORS, return_counts=True)
    return int((counts >= 2).sum())


def locate_offset_change(t: Array, raw: Array, *, noise: float | None = None, min_drop: float = MIN_DROP,
                         min_shared_drop: float = MIN_SHARED_DROP,
                         min_sectors: int = MIN_SECTORS) -> OffsetChange | None:
    """The offset change that best splits ``raw`` (n, 3) into two ellipsoids, or None when there is none.

    Args:
        t: times (n,), seconds, non-decreasing.
        raw: readings (n, 3) in time order (an evenly spaced subsample is fine).
        noise: white noise std in raw units for the still/moving decision (None: ``stages.rest_noise``).
        min_drop, min_shared_drop: the evidence a split needs (0, 0: the best split whatever it removes).
        min_sectors: the azimuth sectors each side must visit on its own (``sectors``; 0: any split).
    """
    times = np.asarray(t, dtype=np.float64).reshape(-1)
    v = np.asarray(raw, dtype=np.float64)
    keep = moving_mask(times, v, noise)
    if int(keep.sum()) < _MIN_MOVING:
        return None
    tm, vm = times[keep], v[keep]
    centre = vm.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((vm - centre) ** 2, axis=1)))) or 1.0
    u = (vm - centre) / scale  # conditioning: the fit is shift-equivariant, b = centre + scale * b_u
    x, y = _design(u)
    g = np.cumsum(x[:, :, None] * x[:, None, :], axis=0)
    xy = np.cumsum(x * y[:, None], axis=0)
    yy = np.cumsum(y * y)
    m = len(u)
    total = float(_rss(g[-1:], xy[-1:], yy[-1:])[0])
    k = np.unique(np.linspace(int(_MIN_SIDE * m), int((1 - _MIN_SIDE) * m), _N_CANDIDATES).astype(np.intp))
    k = k[(k > 4) & (k < m - 4)]
    if k.size == 0 or total <= 0:
        return None
    cost = _rss(g[k - 1], xy[k - 1], yy[k - 1]) + _rss(g[-1] - g[k - 1], xy[-1] - xy[k - 1], yy[-1] - yy[k - 1])
    j = int(np.argmin(cost))
    drop = 1.0 - float(cost[j]) / total
    kj = int(k[j])
    log.debug("offset change: best split at t=%.3f s removes %.3f of the ellipsoid fit's RSS", tm[kj], drop)
    if drop < min_drop:
        return None
    shared = 1.0 - _shared_rss(x, y, kj) / total
    log.debug("offset change: one shape with two centres removes %.3f", shared)
    if shared < min_shared_drop:
        return None
    went = min(sectors(vm[:kj]), sectors(vm[kj:]))
    log.debug("offset change: each side goes through at least %d of %d azimuth sectors", went, _SECTORS)
    if went < min_sectors:
        return None
    before = centre + scale * _centre(g[kj - 1], xy[kj - 1])
    after = centre + scale * _centre(g[-1] - g[kj - 1], xy[-1] - xy[kj - 1])
    radius = float(np.median(np.linalg.norm(vm[:kj] - before, axis=1)))
    return OffsetChange(t=0.5 * float(tm[kj - 1] + tm[kj]), drop=drop, offset_before=before, offset_after=after,
                        radius=radius, shared_drop=shared, sectors=went)


def _shared_rss(x: Array, y: Array, k: int) -> float:
    """Residual sum of squares of the ``_design`` fit with the five shape terms shared and the centre
    and constant terms separate before and after sample ``k``."""
    side = (np.arange(len(y)) >= k)[:, None]
    lin = x[:, 5:]
    xs = np.hstack([x[:, :5], np.where(side, 0.0, lin), np.where(side, lin, 0.0)])
    coef, *_ = np.linalg.lstsq(xs, y, rcond=None)
    res = y - xs @ coef
    return float(res @ res)


def step_evidence(t: Array, raw: Array, noise: float | None = None) -> float:
    """How well one offset step explains ``raw`` (n, 3): the share of the single ellipsoid fit's residual
    sum of squares that the best split with one shape and two centres removes (``shared_drop`` of
    ``locate_offset_change`` without thresholds); 0 when no split can be evaluated.

    An offset step leaves two flat stretches: the split removes all of the change and only the noise is
    left (a share removed near 1). A random walk or a warm-up keeps changing on either side of any one
    split, and bursts are no step at all: much is left (about 0.2-0.7 removed). The value depends on how
    large the change is against the noise, so a recording is compared with twins of each candidate effect
    at its fitted size (``ranking.separate_step_from_walk``), never with a fixed level.
    """
    c = locate_offset_change(t, raw, noise=noise, min_drop=0.0, min_shared_drop=0.0, min_sectors=0)
    return 0.0 if c is None else float(min(max(c.shared_drop, 0.0), 1.0))
