"""Incremental 3-D convex hull whose volume follows single-point inserts and deletes (indicator D).

The per-direction buffer (``coverage.DirectionBuffer``) replaces one sample at a time; rebuilding the
hull with Qhull on every change would cost O(n log n) per sample. Here an insert removes the facets
the new point sees and fans the horizon to it; a delete re-hulls only the deleted vertex's link (its
neighbours plus points inside the removed cone). Both keep a running volume as a sum of signed
tetrahedra, with a full Qhull rebuild every ``_REBUILD_EVERY`` local changes to bound rounding drift,
and fall back to a rebuild whenever the local step meets a degenerate configuration.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

__all__ = ["IncrementalHull"]

Array = NDArray[np.float64]


_REBUILD_EVERY = 4000
"""Full Qhull rebuild after this many local hull changes, bounding floating-point drift of the volume."""


def _single_cycle(nxt: dict[int, int]) -> bool:
    """True if the successor map ``nxt`` is one simple cycle through all of its keys."""
    if len(nxt) < 3 or len(set(nxt.values())) != len(nxt):
        return False
    start = next(iter(nxt))
    v = start
    for steps in range(1, len(nxt) + 1):
        nv = nxt.get(v)
        if nv is None:
            return False
        v = nv
        if v == start:
            return steps == len(nxt)
    return False


def _boundary(tris: list[tuple[int, int, int]]) -> set[tuple[int, int]]:
    """Directed edges of oriented triangles whose reverse is not in the set (the boundary of a disc)."""
    edges = {e for a, b, c in tris for e in ((a, b), (b, c), (c, a))}
    return {(u, w) for (u, w) in edges if (w, u) not in edges}


def _cross(a: Array, b: Array) -> Array:
    """Row-wise cross product (np.cross is slow for small arrays)."""
    return np.stack(
        (a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2], a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]),
        axis=1,
    )


class IncrementalHull:
    """Convex-hull volume (indicator D) of a changing point set, updated locally.

    Points are slots of a shared (capacity, 3) array, mirrored in three float lists for scalar
    access. Facets are triangles oriented counter-clockwise seen from outside, with unit outward
    normals ``n`` and offsets ``o`` (``x`` is beyond a facet when ``n . x + o > eps``).

    - Insert p (beneath-beyond): the facets visible from p are replaced by the cone from p over their
      horizon; the volume grows by the tetrahedra (p, visible facet), ``area * height / 3`` each.
    - Delete a hull vertex v: let L be its link (the neighbours, a cycle) and Q the non-vertex points
      in the cap cut off by the plane through L (normal: the sum of the star normals). Every vertex
      of the new hull's facets that v sees (the floor) lies in L ∪ Q, so the floor is exactly the set
      of facets of ``conv(L ∪ Q)`` visible from v, and its boundary is the link. The star of v is
      replaced by that floor; the volume shrinks by the tetrahedra (v, floor facet). The floor comes
      from Qhull on the few points of L ∪ Q (a triangle when L has three points and Q is empty).
      Deleting a non-vertex changes nothing.

    Consistency checks (horizon and link simple cycles, floor boundary equal to the link, the points'
    mean beneath every new facet) fall back to a full Qhull rebuild, as does every
    ``_REBUILD_EVERY``-th change and any Qhull error. Fewer than 4 or coplanar points give volume 0.
    """

    def __init__(self, pts: Array, xs: list[float], ys: list[float], zs: list[float]) -> None:
        self._pts = pts
        self._xyz = (xs, ys, zs)
        self.rebuilds = 0
        self.clear()

    def clear(self) -> None:
        """Forget every point."""
        self.volume = 0.0
        self._live: set[int] = set()
        self._inner: set[int] = set()
        self._inner_mask = np.zeros(self._pts.shape[0], dtype=bool)
        self._vf: dict[int, set[int]] = {}
        self._tri: list[tuple[int, int, int] | None] = []
        self._eq = np.zeros((0, 4))
        self._area = np.zeros(0)
        self._free_rows: list[int] = []
        self._hw = 0
        self._valid = False
        self._suspended = False
        self._changes = 0
        self._eps = 0.0

    def set_lists(self, xs: list[float], ys: list[float], zs: list[float]) -> None:
        """Point the scalar mirrors at new lists (the buffer re-creates them on clear)."""
        self._xyz = (xs, ys, zs)

    def suspend(self) -> None:
        """Only record membership until :meth:`resume` (bulk loading)."""
        self._suspended = True

    def resume(self) -> None:
        """Rebuild from scratch after a bulk load."""
        self._suspended = False
        self._rebuild()

    def vertex_count(self) -> int:
        """Number of hull vertices (0 when the hull is degenerate)."""
        return len(self._vf) if self._valid else 0

    def _set_inner(self, slot: int, inner: bool) -> None:
        if inner:
            self._inner.add(slot)
        else:
            self._inner.discard(slot)
        self._inner_mask[slot] = inner

    # ------------------------------------------------------------------ full rebuild
    def _rebuild(self) -> None:
        self.rebuilds += 1
        self._changes = 0
        self._valid = False
        self.volume = 0.0
        self._vf = {}
        self._tri = []
        self._free_rows = []
        self._hw = 0
        self._inner = set(self._live)
        self._inner_mask[:] = False
        live = np.fromiter(self._live, dtype=np.intp, count=len(self._live))
        self._inner_mask[live] = True
        if live.size < 4:
            return
        p = self._pts[live]
        try:
            h = ConvexHull(p)
        except QhullError:
            return
        simp = live[h.simplices]
        eq = h.equations
        a, b, c = self._pts[simp[:, 0]], self._pts[simp[:, 1]], self._pts[simp[:, 2]]
        cr = _cross(b - a, c - a)
        flip = np.einsum("ij,ij->i", cr, eq[:, :3]) < 0.0
        simp[flip] = simp[flip][:, [0, 2, 1]]
        m = simp.shape[0]
        cap = max(64, 2 * m)
        self._eq = np.zeros((cap, 4))
        self._eq[:, 3] = -math.inf
        self._eq[:m] = eq
        self._area = np.zeros(cap)
        self._area[:m] = 0.5 * np.sqrt(np.einsum("ij,ij->i", cr, cr))
        self._tri = [(int(i), int(j), int(k)) for i, j, k in simp.tolist()]
        self._tri += [None] * (cap - m)
        self._free_rows = list(range(cap - 1, m - 1, -1))
        self._hw = m
        vf = self._vf
        for f, (i, j, k) in enumerate(self._tri[:m]):  # type: ignore[misc]
            for v in (i, j, k):
                vf.setdefault(v, set()).add(f)
        for v in vf:
            self._set_inner(v, False)
        self.volume = float(h.volume)
        self._eps = 1e-12 * float(np.abs(p).max())
        self._valid = True

    # ------------------------------------------------------------------ facet bookkeeping
    def _alloc(self, k: int) -> list[int]:
        while len(self._free_rows) < k:
            cap = self._eq.shape[0]
            new = max(64, cap)
            self._eq = np.vstack([self._eq, np.tile([0.0, 0.0, 0.0, -math.inf], (new, 1))])
            self._area = np.concatenate([self._area, np.zeros(new)])
            self._tri += [None] * new
            self._free_rows = list(range(cap + new - 1, cap - 1, -1)) + self._free_rows
        rows = [self._free_rows.pop() for _ in range(k)]
        self._hw = max(self._hw, max(rows) + 1)
        return rows

    def _facets(self, tris: list[tuple[int, int, int]], ref: tuple[float, float, float]) -> list[tuple[float, ...]] | None:
        """(nx, ny, nz, offset, area) of oriented triangles; None if one is degenerate or ``ref`` is beyond it."""
        xs, ys, zs = self._xyz
        rx, ry, rz = ref
        eps = self._eps
        out = []
        for a, b, c in tris:
            ax, ay, az = xs[a], ys[a], zs[a]
            ux, uy, uz = xs[b] - ax, ys[b] - ay, zs[b] - az
            vx, vy, vz = xs[c] - ax, ys[c] - ay, zs[c] - az
            nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
            nrm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if not nrm > 0.0:
                return None
            nx, ny, nz = nx / nrm, ny / nrm, nz / nrm
            off = -(nx * ax + ny * ay + nz * az)
            if nx * rx + ny * ry + nz * rz + off > eps:
                return None
            out.append((nx, ny, nz, off, 0.5 * nrm))
        return out

    def _replace(self, old: list[int], tris: list[tuple[int, int, int]], fac: list[tuple[float, ...]]) -> None:
        touched: set[int] = set()
        tri, vf = self._tri, self._vf
        for f in old:
            for v in tri[f]:  # type: ignore[union-attr]
                s = vf.get(v)
                if s is not None:
                    s.discard(f)
                    touched.add(v)
            tri[f] = None
            self._free_rows.append(f)
        self._eq[old] = (0.0, 0.0, 0.0, -math.inf)
        self._area[old] = 0.0
        rows = self._alloc(len(tris))
        arr = np.array(fac)
        self._eq[rows] = arr[:, :4]
        self._area[rows] = arr[:, 4]
        for row, t in zip(rows, tris, strict=True):
            tri[row] = t
            for v in t:
                s = vf.get(v)
                if s is None:
                    vf[v] = {row}
                    self._set_inner(v, False)
                else:
                    s.add(row)
        for v in touched:
            if not vf.get(v, True):
                del vf[v]
                if v in self._live:
                    self._set_inner(v, True)
        self._changes += 1

    # ------------------------------------------------------------------ updates
    def insert(self, slot: int, ref: tuple[float, float, float]) -> None:
        """Add point ``slot``; ``ref`` is a point strictly inside the new hull (the points' mean)."""
        self._live.add(slot)
        if self._suspended:
            return
        if not self._valid or self._changes >= _REBUILD_EVERY:
            self._rebuild()
            return
        p = self._pts[slot]
        eq = self._eq[: self._hw]
        d = eq[:, :3] @ p + eq[:, 3]
        vis = np.flatnonzero(d > self._eps)
        if vis.size == 0:
            self._set_inner(slot, True)
            return
        vis_l = vis.tolist()
        tri = self._tri
        horizon = list(_boundary([tri[f] for f in vis_l]))  # type: ignore[misc]
        nxt = dict(horizon)
        if len(nxt) != len(horizon) or not _single_cycle(nxt):
            self._rebuild()
            return
        tris = [(u, w, slot) for u, w in horizon]
        fac = self._facets(tris, ref)
        if fac is None:
            self._rebuild()
            return
        self.volume += float(self._area[vis] @ d[vis]) / 3.0
        self._replace(vis_l, tris, fac)

    def delete(self, slot: int, ref: tuple[float, float, float]) -> None:
        """Remove point ``slot``; ``ref`` is a point strictly inside the remaining hull."""
        self._live.discard(slot)
        if self._suspended:
            return
        if self._valid and slot in self._inner:
            self._set_inner(slot, False)
            return
        self._inner_mask[slot] = False
        if not self._valid or self._changes >= _REBUILD_EVERY or len(self._live) < 4:
            self._rebuild()
            return
        star = list(self._vf.get(slot, ()))
        link: dict[int, int] = {}
        for f in star:
            a, b, c = self._tri[f]  # type: ignore[misc]
            u, w = (b, c) if a == slot else (c, a) if b == slot else (a, b)
            link[u] = w
        if len(link) != len(star) or not _single_cycle(link):
            self._rebuild()
            return
        ring = [next(iter(link))]
        while len(ring) < len(link):
            ring.append(link[ring[-1]])
        nc = self._eq[star, :3].sum(axis=0)
        cut = float((self._pts[ring] @ nc).min()) - self._eps * float(np.abs(nc).sum())
        cand: list[int] = []
        if self._inner:  # superset of the non-vertices inside conv(L ∪ v): a slab, then a ball
            q = np.flatnonzero(self._inner_mask & (self._pts @ nc >= cut))
            if q.size:
                lv = self._pts[[*ring, slot]]
                mid = lv.mean(axis=0)
                rad2 = (math.sqrt(float(((lv - mid) ** 2).sum(axis=1).max())) * (1.0 + 1e-9) + self._eps) ** 2
                cand = q[((self._pts[q] - mid) ** 2).sum(axis=1) <= rad2].tolist()
        tris = self._floor(slot, ring, cand)
        if tris is None or _boundary(tris) != set(link.items()):
            self._rebuild()
            return
        fac = self._facets(tris, ref)
        if fac is None:
            self._rebuild()
            return
        xs, ys, zs = self._xyz
        vx, vy, vz = xs[slot], ys[slot], zs[slot]
        heights = [nx * vx + ny * vy + nz * vz + off for nx, ny, nz, off, _ in fac]
        if min(heights) <= 0.0:
            self._rebuild()
            return
        del self._vf[slot]
        self.volume -= sum(h * f[4] for h, f in zip(heights, fac, strict=True)) / 3.0
        self._replace(star, tris, fac)

    def _floor(self, slot: int, ring: list[int], cand: list[int]) -> list[tuple[int, int, int]] | None:
        """Oriented facets of conv(ring ∪ cand) that ``slot`` sees; None when that cannot be decided."""
        cs = ring + cand
        m = len(cs)
        v = self._pts[slot]
        if m == 3:  # ring is in cycle order: the single floor triangle follows it
            return [(ring[0], ring[1], ring[2])]
        pts = self._pts[cs]
        try:
            h = ConvexHull(pts)
        except QhullError:
            return None
        dv = h.equations[:, :3] @ v + h.equations[:, 3]
        fl = np.flatnonzero(dv > self._eps)
        simp = np.asarray(cs)[h.simplices[fl]]
        a, b, c3 = self._pts[simp[:, 0]], self._pts[simp[:, 1]], self._pts[simp[:, 2]]
        flip = np.einsum("ij,ij->i", _cross(b - a, c3 - a), h.equations[fl, :3]) < 0.0
        simp[flip] = simp[flip][:, [0, 2, 1]]
        return [(int(x), int(y), int(z)) for x, y, z in simp.tolist()]
