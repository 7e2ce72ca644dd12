"""Bounded per-direction calibration buffer and the coverage indicators A–D.

Directions are taken about the current centre estimate ``c`` (raw data lie on an offset ellipsoid),
``d = v - c``, with elevation ``theta = atan2(d_z, hypot(d_x, d_y))`` in [-90, 90] deg and azimuth
``phi = atan2(d_y, d_x)`` in [-180, 180] deg.

The buffer splits the sphere of directions into equal-area bins: ``n_bands`` bands of equal height
in ``z = d_z / |d|`` (Archimedes: equal height means equal area) times ``n_sectors`` azimuth sectors.
Each bin holds at most ``per_bin`` samples (Gietzelt et al. 2013, §2.4: "only up to ten measurements
of a certain direction"), the newest replacing the oldest, so the buffer follows a drifting sensor
while its memory stays bounded by ``n_bins * per_bin`` samples whatever the stream length. A bin
takes a new sample at most once per ``min_interval_s`` seconds, so most samples of a dense stream are
refused after a handful of float operations.

Indicators (Olivares et al. 2013, §3.1, Eqs. 9–12 counting the paper's displayed equations), over the
buffered points G:

- A = (Q3(theta) - Q1(theta)) + (Q3(phi) - Q1(phi)), degrees, in [0, 540]              (Eq. 9)
- B = #{empty bins of the theta histogram} + #{empty bins of the phi histogram}        (Eq. 10)
  (``hist_bins`` equal-width bins each over [-90, 90] and [-180, 180]; the paper's N = 1024 came
  from its 10-bit ADC; the default here, 36, suits a buffer of a few hundred points)
- C = sum over axes k of (max(g_k) - min(g_k)), raw units                               (Eq. 11)
- D = V(Qhull(G)), the convex-hull volume, raw units cubed                              (Eq. 12)

and their unit-free versions, so one trained validator serves any sensor and unit:
``b_frac = B / (2 hist_bins)``, ``c_norm = C / (6 r)``, ``d_norm = D / (4/3 pi r^3)`` with ``r`` the
radius the calibrator sets (a sphere fit's, then the calibration's RMS radius, ``Calibration.rms_radius``: the
validator's training sets were normalised by a sphere fit's; the equal-volume radius put an anisotropic sensor's
full coverage at ``c_norm`` 1.09) or, without one, the mean distance of the points from the centre.

The buffer updates the indicators on every insert and evict instead of recomputing them: sorted lists
give the quartiles (A) and the per-axis extremes (C), bin counts give B, and an incremental hull
(``hull.IncrementalHull``) gives D. :func:`compute_indicators` is the from-scratch reference.
"""

from __future__ import annotations

import bisect
import logging
import math
from collections import deque
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError

from ..model.errors import ConfigError, InputError, as_vector3
from .hull import IncrementalHull
from .indicators import (
    _E_FLOOR,
    _RAD2DEG,
    _TWO_PI,
    HIST_BINS,
    Indicators,
    _e_info,
    _hist_scale,
    _jacobian_rows,
    _normalise,
    _quartile_spread,
)

__all__ = ["DirectionBuffer"]

_log = logging.getLogger(__name__)
Array = NDArray[np.float64]


def _grid(n_bins: int) -> tuple[int, int]:
    """Bands and sectors for about ``n_bins`` equal-area bins of roughly square shape at the equator."""
    n_bands = max(1, round(math.sqrt(n_bins / math.pi)))
    return n_bands, max(1, round(n_bins / n_bands))


class DirectionBuffer:
    """Bounded buffer of samples, at most ``per_bin`` per equal-area direction bin, with live indicators.

    Args:
        n_bins: Approximate number of direction bins (the grid is ``n_bands x n_sectors``, see
            ``n_bins`` attribute for the exact count).
        per_bin: Maximum samples per bin (K); the newest replaces the oldest.
        center: Initial centre estimate (raw units); the origin when None.
        radius: Radius for the normalised indicators; the mean distance from the centre when None.
        min_interval_s: A bin accepts a new sample only if its newest one is at least this many
            seconds older (or newer: stamps that jump back by more than this are accepted).
        hist_bins: Histogram bins for indicator B.
        hull_on_read: no incremental convex hull: its volume (indicator D) comes from one Qhull run when
            the indicators are read after a change. Cheaper when reads are rarer than a few changes (the
            calibrator reads at each validation, every few seconds, while a tumble keeps ~3 samples a second
            at 50 Hz; one Qhull run on 1000 points costs about as much as five incremental updates).
    """

    def __init__(
        self,
        n_bins: int = 100,
        per_bin: int = 10,
        center: ArrayLike | None = None,
        *,
        radius: float | None = None,
        min_interval_s: float = 0.5,
        hist_bins: int = HIST_BINS,
        hull_on_read: bool = False,
    ) -> None:
        if not (isinstance(n_bins, int) and 1 <= n_bins <= 100_000):
            msg = f"n_bins must be an int in [1, 100000], got {n_bins!r}"
            raise ConfigError(msg)
        if not (isinstance(per_bin, int) and 1 <= per_bin <= 10_000):
            msg = f"per_bin must be an int in [1, 10000], got {per_bin!r}"
            raise ConfigError(msg)
        if not (math.isfinite(min_interval_s) and min_interval_s >= 0.0):
            msg = f"min_interval_s must be finite and >= 0, got {min_interval_s!r}"
            raise ConfigError(msg)
        if not (isinstance(hist_bins, int) and hist_bins >= 1):
            msg = f"hist_bins must be an int >= 1, got {hist_bins!r}"
            raise ConfigError(msg)
        self.n_bands, self.n_sectors = _grid(n_bins)
        self.n_bins = self.n_bands * self.n_sectors
        self.per_bin = per_bin
        self.capacity = self.n_bins * per_bin
        self.min_interval_s = float(min_interval_s)
        self.hist_bins = hist_bins
        self._hscale = _hist_scale(hist_bins)
        self._center = (0.0, 0.0, 0.0)
        self._radius: float | None = None
        self._pts = np.zeros((self.capacity, 3))
        self.hull_on_read = bool(hull_on_read)
        self._hull = IncrementalHull(self._pts, [], [], [])
        self.clear()
        if center is not None or radius is not None:
            self.set_center(np.zeros(3) if center is None else center, radius)

    # ------------------------------------------------------------------ state
    def clear(self) -> None:
        """Drop every sample and reset the counters (the centre and radius are kept)."""
        cap = self.capacity
        self._x = [0.0] * cap
        self._y = [0.0] * cap
        self._z = [0.0] * cap
        self._t = [0.0] * cap
        self._th = [0.0] * cap
        self._ph = [0.0] * cap
        self._seq = [0] * cap
        self._next_seq = 0
        self._free = list(range(cap - 1, -1, -1))
        self._bins: list[deque[int]] = [deque() for _ in range(self.n_bins)]
        self._last = [-math.inf] * self.n_bins
        self._s_th: list[float] = []
        self._s_ph: list[float] = []
        self._s_xyz: tuple[list[float], list[float], list[float]] = ([], [], [])
        self._h_th = [0] * self.hist_bins
        self._h_ph = [0] * self.hist_bins
        self._empty = 2 * self.hist_bins
        self._sum_r = 0.0
        self._sum_p = [0.0, 0.0, 0.0]
        self._scatter = np.zeros((9, 9))  # sum of j j^T about the centre (indicator E) ...
        self._scatter_rows: list[tuple[float, ...]] = []  # ... but for these rows, added (or removed) on demand
        self._scatter_signs: list[float] = []
        self._scatter_updates = 0
        self._n_occupied = 0
        self._hull.clear()
        self._hull.set_lists(self._x, self._y, self._z)
        self._hull_read = (0.0, 0)  # hull_on_read: (volume, vertices) of the last Qhull run
        self._hull_stale = False
        self._hull_runs = 0
        self._cache: Indicators | None = None
        self._offered = self._kept = self._refused = self._invalid = self._evicted = 0
        self._rebins = 0

    def __len__(self) -> int:
        return self.capacity - len(self._free)

    @property
    def center(self) -> Array:
        """The centre estimate the directions are taken about."""
        return np.array(self._center)

    @property
    def radius(self) -> float | None:
        """The radius set with :meth:`set_center`, or None."""
        return self._radius

    def coverage(self) -> float:
        """Fraction of direction bins holding at least one sample."""
        return self._n_occupied / self.n_bins

    def stats(self) -> dict[str, int]:
        """Counters: offered, kept, refused (bin too recent or at the centre), invalid (non-finite or bad
        shape), evicted, rebins (centre moves), hull_rebuilds (full Qhull runs), hull_vertices."""
        return {
            "offered": self._offered,
            "kept": self._kept,
            "refused": self._refused,
            "invalid": self._invalid,
            "evicted": self._evicted,
            "rebins": self._rebins,
            "hull_rebuilds": self._hull_runs if self.hull_on_read else self._hull.rebuilds,
            "hull_vertices": self._hull_state()[1],
        }

    @property
    def counters(self) -> dict[str, int]:
        """The same as :meth:`stats` (named like ``InactivityGate.counters``)."""
        return self.stats()

    def _live(self) -> list[int]:
        free = set(self._free)
        live = [s for s in range(self.capacity) if s not in free]
        live.sort(key=self._seq.__getitem__)
        return live

    def points(self) -> Array:
        """Buffered samples, (n, 3), oldest insertion first."""
        return self._pts[self._live()].copy()

    def times(self) -> Array:
        """Stamps of the buffered samples, (n,), in the order of :meth:`points`."""
        return np.array([self._t[s] for s in self._live()], dtype=np.float64)

    def bin_of(self, xyz: ArrayLike) -> int:
        """Index in ``[0, n_bins)`` of the direction bin of raw sample ``xyz`` about the current centre.

        Raises:
            InputError: If ``xyz`` is not three finite numbers or lies at the centre.
        """
        v = as_vector3(xyz, "xyz")
        cx, cy, cz = self._center
        dx, dy, dz = float(v[0]) - cx, float(v[1]) - cy, float(v[2]) - cz
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        if r == 0.0:
            msg = "xyz lies at the centre estimate: it has no direction"
            raise InputError(msg)
        return self._bin_of(dx, dy, dz, r)

    def bin_counts(self) -> list[int]:
        """Number of samples in each direction bin."""
        return [len(q) for q in self._bins]

    # ------------------------------------------------------------------ streaming path
    def _bin_of(self, dx: float, dy: float, dz: float, r: float) -> int:
        band = int((dz / r + 1.0) * 0.5 * self.n_bands)
        if band >= self.n_bands:
            band = self.n_bands - 1
        sector = int((math.atan2(dy, dx) + math.pi) * (self.n_sectors / _TWO_PI))
        if sector >= self.n_sectors:
            sector = self.n_sectors - 1
        return band * self.n_sectors + (sector if sector >= 0 else 0)

    def push(self, t: float, xyz: ArrayLike) -> bool:
        """Offer one sample; return True if it was kept.

        Never raises for bad samples: non-finite values or a wrong shape are counted as invalid, a
        sample at the centre or in a bin that took one less than ``min_interval_s`` ago is refused.
        """
        try:
            x = float(xyz[0])  # type: ignore[index]
            y = float(xyz[1])  # type: ignore[index]
            z = float(xyz[2])  # type: ignore[index]
            t = float(t)
        except (TypeError, ValueError, IndexError):
            self._offered += 1
            self._invalid += 1
            return False
        s = x + y + z + t
        if s - s != 0.0:  # NaN or Inf somewhere
            self._offered += 1
            self._invalid += 1
            return False
        return self.push_finite(t, x, y, z)

    def push_finite(self, t: float, x: float, y: float, z: float) -> bool:
        """``push`` for a caller that already checked the sample: four finite Python floats (the calibrator's
        intake did); return True if it was kept."""
        self._offered += 1
        cx, cy, cz = self._center
        dx, dy, dz = x - cx, y - cy, z - cz
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        if r == 0.0:
            self._refused += 1
            return False
        b = self._bin_of(dx, dy, dz, r)
        if abs(t - self._last[b]) < self.min_interval_s:
            self._refused += 1
            return False
        self._last[b] = t
        q = self._bins[b]
        if len(q) >= self.per_bin:
            self._remove(q.popleft())
            self._evicted += 1
        elif not q:
            self._n_occupied += 1
        slot = self._free.pop()
        q.append(slot)
        self._insert(slot, t, x, y, z, dx, dy, dz, r)
        self._kept += 1
        return True

    # ------------------------------------------------------------------ incremental indicators
    def _insert(self, slot: int, t: float, x: float, y: float, z: float, dx: float, dy: float, dz: float, r: float) -> None:
        self._x[slot], self._y[slot], self._z[slot], self._t[slot] = x, y, z, t
        self._seq[slot] = self._next_seq
        self._next_seq += 1
        pts = self._pts
        pts[slot, 0] = x
        pts[slot, 1] = y
        pts[slot, 2] = z
        th = math.atan2(dz, math.hypot(dx, dy)) * _RAD2DEG
        ph = math.atan2(dy, dx) * _RAD2DEG
        self._th[slot], self._ph[slot] = th, ph
        bisect.insort(self._s_th, th)
        bisect.insort(self._s_ph, ph)
        sx, sy, sz = self._s_xyz
        bisect.insort(sx, x)
        bisect.insort(sy, y)
        bisect.insort(sz, z)
        self._hist_add(th, ph, 1)
        self._sum_r += r
        sp = self._sum_p
        sp[0] += x
        sp[1] += y
        sp[2] += z
        self._scatter_add(dx, dy, dz, 1.0)
        if self.hull_on_read:
            self._hull_stale = True
        else:
            self._hull.insert(slot, self._mean())
        self._cache = None

    def _remove(self, slot: int) -> None:
        _discard(self._s_th, self._th[slot])
        _discard(self._s_ph, self._ph[slot])
        sx, sy, sz = self._s_xyz
        x, y, z = self._x[slot], self._y[slot], self._z[slot]
        _discard(sx, x)
        _discard(sy, y)
        _discard(sz, z)
        self._hist_add(self._th[slot], self._ph[slot], -1)
        cx, cy, cz = self._center
        self._sum_r -= math.sqrt((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2)
        sp = self._sum_p
        sp[0] -= x
        sp[1] -= y
        sp[2] -= z
        self._scatter_add(x - cx, y - cy, z - cz, -1.0)
        self._free.append(slot)
        if self._scatter_updates >= 4096:
            self._refresh_scatter()
        if self.hull_on_read:
            self._hull_stale = True
        else:
            self._hull.delete(slot, self._mean())
        self._cache = None

    def _scatter_add(self, dx: float, dy: float, dz: float, sign: float) -> None:
        """Queue ``sign j j^T`` for the indicator-E sum: a 9 x 9 update costs ~3 us a sample, the queued rows
        are added as one product when the indicators are read (``_scatter_flush``)."""
        self._scatter_rows.append((dx, dy, dz, dx * dx, dy * dy, dz * dz, 2 * dx * dy, 2 * dx * dz, 2 * dy * dz))
        self._scatter_signs.append(sign)
        self._scatter_updates += 1

    def _scatter_flush(self) -> None:
        if self._scatter_rows:
            j = np.array(self._scatter_rows)
            self._scatter += (j * np.array(self._scatter_signs)[:, None]).T @ j
            self._scatter_rows, self._scatter_signs = [], []

    def _refresh_scatter(self) -> None:
        """Recompute the indicator-E sum from the live samples (bounds add/subtract rounding drift)."""
        self._scatter_updates = 0
        self._scatter_rows, self._scatter_signs = [], []
        live = self._live()
        if not live:
            self._scatter = np.zeros((9, 9))
            return
        jac = _jacobian_rows(self._pts[live] - np.array(self._center))
        self._scatter = jac.T @ jac

    def _mean(self) -> tuple[float, float, float]:
        n = len(self)
        if n == 0:
            return (0.0, 0.0, 0.0)
        sp = self._sum_p
        return (sp[0] / n, sp[1] / n, sp[2] / n)

    def _hist_add(self, th: float, ph: float, inc: int) -> None:
        st, sp = self._hscale
        nb = self.hist_bins
        i = min(max(int((th + 90.0) * st), 0), nb - 1)
        j = min(max(int((ph + 180.0) * sp), 0), nb - 1)
        for h, k in ((self._h_th, i), (self._h_ph, j)):
            before = h[k]
            h[k] = before + inc
            if before == 0:
                self._empty -= 1
            elif h[k] == 0:
                self._empty += 1

    def _hull_state(self) -> tuple[float, int]:
        """(volume, vertex count) of the convex hull of the samples: the incremental hull's, or with
        ``hull_on_read`` one Qhull run after a change (0 for fewer than 4 or coplanar points)."""
        if not self.hull_on_read:
            return self._hull.volume, self._hull.vertex_count()
        if self._hull_stale:
            self._hull_stale = False
            self._hull_runs += 1
            live = self._live()
            self._hull_read = (0.0, 0)
            if len(live) >= 4:
                try:
                    h = ConvexHull(self._pts[live])
                    self._hull_read = (float(h.volume), len(h.vertices))
                except QhullError:
                    pass
        return self._hull_read

    def indicators(self) -> Indicators:
        """Current indicators A–D and their normalised versions (cached until the buffer changes)."""
        if self._cache is not None:
            return self._cache
        n = len(self)
        if n == 0:
            radius = self._radius or 0.0
            return _normalise(0.0, 2 * self.hist_bins, 0.0, 0.0, 0, radius, self.hist_bins, float(np.log10(_E_FLOOR)))
        a = _quartile_spread(self._s_th) + _quartile_spread(self._s_ph)
        c = sum(s[-1] - s[0] for s in self._s_xyz)
        radius = self._radius if self._radius is not None else self._sum_r / n
        self._scatter_flush()
        e_info = _e_info(self._scatter, n, radius)
        self._cache = _normalise(a, self._empty, c, self._hull_state()[0], n, radius, self.hist_bins, e_info)
        return self._cache

    # ------------------------------------------------------------------ re-binning
    def set_center(self, center: ArrayLike, radius: float | None = None) -> None:
        """Move the centre estimate (and set the normalisation radius), re-binning every sample.

        Bins that overflow after the move keep their ``per_bin`` newest samples.

        Raises:
            InputError: If ``center`` is not three finite numbers or ``radius`` is not positive.
        """
        c = as_vector3(center, "center")
        if radius is not None and not (math.isfinite(radius) and radius > 0.0):
            msg = f"radius must be a positive finite number or None, got {radius!r}"
            raise InputError(msg)
        self._radius = None if radius is None else float(radius)
        new_center = (float(c[0]), float(c[1]), float(c[2]))
        self._cache = None
        if new_center == self._center:
            return
        samples = [(self._t[s], self._x[s], self._y[s], self._z[s]) for s in self._live()]
        self._center = new_center
        self._rebin(samples, rebins=1)

    def discard(self, drop: Callable[[float, float, float], bool]) -> int:
        """Remove the samples for which ``drop(x, y, z)`` is true (counted as evicted; the rest re-binned as they
        were) and return how many: samples found bad after they went in (a saturated axis, ``stream.saturation``)."""
        return self._discard(lambda item: drop(item[1], item[2], item[3]))

    def discard_before(self, t: float) -> int:
        """Remove the samples taken before ``t`` (as ``discard``) and return how many: a sensor that changed before
        its first calibration (``stream.partial``)."""
        return self._discard(lambda item: item[0] < t)

    def _discard(self, drop: Callable[[tuple[float, float, float, float]], bool]) -> int:
        live = [(self._t[s], self._x[s], self._y[s], self._z[s]) for s in self._live()]
        keep = [item for item in live if not drop(item)]
        n = len(live) - len(keep)
        if n:
            self._cache = None
            self._rebin(keep, rebins=0)
            self._evicted += n
        return n

    def _rebin(self, samples: list[tuple[float, float, float, float]], rebins: int) -> None:
        """Empty the buffer and insert ``samples`` (time, x, y, z in insertion order) about the current centre; the
        counters are kept (``rebins`` added)."""
        counters = (self._offered, self._kept, self._refused, self._invalid, self._evicted, self._rebins + rebins)
        runs = self._hull_runs
        self.clear()
        self._hull_runs = runs
        self._offered, self._kept, self._refused, self._invalid, self._evicted, self._rebins = counters
        new_center = self._center
        cx, cy, cz = new_center
        by_bin: dict[int, list[tuple[float, float, float, float]]] = {}
        for t, x, y, z in samples:
            dx, dy, dz = x - cx, y - cy, z - cz
            r = math.sqrt(dx * dx + dy * dy + dz * dz)
            if r == 0.0:
                self._evicted += 1
                continue
            by_bin.setdefault(self._bin_of(dx, dy, dz, r), []).append((t, x, y, z))
        if not self.hull_on_read:
            self._hull.suspend()
        for b, items in by_bin.items():
            self._evicted += max(0, len(items) - self.per_bin)
            keep = items[-self.per_bin :]  # samples are in insertion order: keep the newest
            self._n_occupied += 1
            self._last[b] = max(item[0] for item in keep)
            for t, x, y, z in keep:
                slot = self._free.pop()
                self._bins[b].append(slot)
                dx, dy, dz = x - cx, y - cy, z - cz
                self._insert(slot, t, x, y, z, dx, dy, dz, math.sqrt(dx * dx + dy * dy + dz * dz))
        if not self.hull_on_read:
            self._hull.resume()
        _log.debug("re-binned %d samples about %s", len(self), new_center)


def _discard(s: list[float], v: float) -> None:
    i = bisect.bisect_left(s, v)
    del s[i]
