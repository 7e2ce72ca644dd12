"""Saturated axes: a sensor whose reading is pinned at the end of its range on one axis while it turns.

A magnetometer whose range is too small for the field plus its hard iron (a gain set for a few hundred µT near
motors, an LSM9DS1 at ±4 G beside a magnet), or an accelerometer under shock, reads the same end-of-range value
on that axis whatever the true component beyond it: those samples lie on a plane through the sphere, not on it,
and pull every fit towards the plane (a tumble with a quarter of its x readings clipped was published 4° off at
30° tilt; with a third of them, refused for a residual of 8.6 % that named no cause). ``RailWatch`` finds such a
rail from the stream itself, with no range given: on one axis, the extreme value of everything seen, held exactly
by ``RUN`` or more samples in a row while the other two components travel over more than ``SPREAD`` of their
radius (half the wider of their ranges), of their raw norm and of ``WHOLE`` of the reading's norm (the sensor turned
while the axis stayed pinned), on an axis whose range is at least ``RANGE`` of the widest axis's. The scale is
mostly the other two axes' so that a code far out on the pinned one counts too: an HMC5883L reads -4096 on an axis
whose ADC overflows, whatever the sign.

What it is not: a quantised sensor's last count at the top of its sphere holds the samples within ``sqrt(2 q / R)``
of the axis for a quantum ``q`` (0.13 R for an HMC5883L at its coarsest gain in the Earth field), a float reading's
maximum is held once, a sensor at rest or wobbling moves its other components by little against the field (the
BROAD recordings' first seconds: 2-6 µT of 47 µT, an extreme count held again and again; with the field or gravity
along the pinned axis itself, their noise against a quarter of the whole reading), and a ground robot's
vertical axis reads a few counts over its ring (its range is a few per cent of the widest; an axis clipped to 40 %
of its reach still spans 40 % of the widest). Checked on every recording in ``../shared/data/real``: no rail.

Samples on a rail are dropped (``saturated``); a value beyond it later withdraws the rail (it was no end of range).
The samples of the run that found it (``RUN`` at least, about 20 on a tumble at 50 Hz) went in before: the
calibrator takes them out again (``found``, ``on_rail``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["RailWatch", "on_rails"]


class _End:
    """One end of one axis (the top, or the bottom with the values negated): the extreme value seen, the run of
    samples in a row on it and the box of the other two components over that run."""

    __slots__ = ("box", "rail", "run", "v1")

    def __init__(self) -> None:
        self.v1 = -math.inf
        self.run = 0
        self.box = [math.inf, -math.inf, math.inf, -math.inf]  # min/max of the first other axis, then the second's
        self.rail = False

    def push(self, c: float, a: float, b: float) -> bool:
        """One more value ``c`` (others ``a``, ``b``); True when it lies on the extreme (``c == v1``)."""
        if c > self.v1:  # a new extreme: no rail there yet, a run starts
            self.v1 = c
            self.rail = False
            self.run = 0
        elif c < self.v1:
            self.run = 0
            return False
        if not self.run:
            self.box = [a, a, b, b]
        else:
            box = self.box
            if a < box[0]:
                box[0] = a
            elif a > box[1]:
                box[1] = a
            if b < box[2]:
                box[2] = b
            elif b > box[3]:
                box[3] = b
        self.run += 1
        return True

    def travel(self) -> float:
        return max(self.box[1] - self.box[0], self.box[3] - self.box[2])


class RailWatch:
    """Finds saturated axes in a stream of raw samples and tells which samples sit on them (module docstring)."""

    RUN = 5
    """Samples in a row exactly on the extreme ..."""
    SPREAD = 0.4
    """... while the other two components travel over this share of their radius (half the wider of their ranges)
    and of their raw norm ..."""
    WHOLE = 0.25
    """... (and of this share of the whole reading's norm: a sensor at rest with the field or gravity along the axis
    has no other components, and their noise no travel) ..."""
    RANGE = 0.2
    """... on an axis whose range is at least this share of the widest axis's range."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget everything seen (the calibrator's reset)."""
        self._ends = [(_End(), _End()) for _ in range(3)]
        self._inner_lo = [math.inf] * 3  # per axis, strictly between these a value changes nothing: the fast path
        self._inner_hi = [-math.inf] * 3
        self._runs = 0  # ends with a run going on (the fast path must end them)
        self.found = 0
        """Rails declared so far (a caller compares it to tell a new one: ``on_rail`` then finds what went in)."""

    def push(self, x: float, y: float, z: float) -> bool:
        """One more finite sample; True when it sits on a rail (drop it)."""
        lo, hi = self._inner_lo, self._inner_hi
        if not self._runs and lo[0] < x < hi[0] and lo[1] < y < hi[1] and lo[2] < z < hi[2]:
            return False
        v = (x, y, z)
        on = False
        runs = 0
        for k in range(3):
            a, b = v[(k + 1) % 3], v[(k + 2) % 3]
            top, bottom = self._ends[k]
            for end, c in ((top, v[k]), (bottom, -v[k])):
                if end.push(c, a, b):
                    runs += 1
                    if end.rail:
                        on = True
                    elif end.run >= self.RUN and self._is_rail(k, end, v):
                        end.rail = on = True
                        self.found += 1
            lo[k], hi[k] = -bottom.v1, top.v1
        self._runs = runs
        return on

    def _is_rail(self, k: int, end: _End, v: tuple[float, float, float]) -> bool:
        ranges = [top.v1 + bottom.v1 for top, bottom in self._ends]
        a, b = v[(k + 1) % 3], v[(k + 2) % 3]  # the other two axes: a code far out on this one inflates little
        radius = 0.5 * max(ranges[(k + 1) % 3], ranges[(k + 2) % 3])
        whole = self.WHOLE * math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        return (ranges[k] >= self.RANGE * max(ranges)
                and end.travel() > self.SPREAD * max(radius, math.sqrt(a * a + b * b), whole))

    def on_rail(self, x: float, y: float, z: float) -> bool:
        """Whether a sample sits on a rail standing now (without counting it: for samples seen before)."""
        v = (x, y, z)
        return any(v[k] == value for k, value in self.rails)

    @property
    def rails(self) -> list[tuple[int, float]]:
        """The rails found: ``(axis 0-2, value)``."""
        out = []
        for k, (top, bottom) in enumerate(self._ends):
            if top.rail:
                out.append((k, top.v1))
            if bottom.rail:
                out.append((k, -bottom.v1))
        return out

    def where(self, unit: str) -> str:
        """The rails standing now, ``x at +4e-05 T, ...`` ("" when none)."""
        return ", ".join(f"{'xyz'[k]} at {v:+.6g} {unit}" for k, v in self.rails)

    def describe(self, unit: str, dropped: int) -> str:
        """``dropped`` samples on rails, in words, for a status ("" when none were dropped)."""
        if not dropped:
            return ""
        if not self.rails:  # withdrawn since: a later reading went beyond
            return f"{dropped} samples dropped as saturated on a value a later reading went beyond (no rail now)"
        return (f"{dropped} samples dropped as saturated: {self.where(unit)}, where the readings stayed pinned while "
                "the sensor turned (the field plus hard iron, or a shock, beyond the sensor's range: set a wider one)")


def on_rails(points: ArrayLike) -> tuple[NDArray[np.bool_], RailWatch]:
    """Which rows of ``points`` (N, 3, in time order; rows not finite are skipped) sit on a rail standing at the end,
    the first ones included (a batch has them all), and the watch that found the rails (``describe``)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    watch = RailWatch()
    for x, y, z in pts[np.isfinite(pts).all(axis=1)].tolist():  # the stream's intake drops the others before
        watch.push(x, y, z)
    mask = np.zeros(len(pts), dtype=bool)
    for k, v in watch.rails:
        mask |= pts[:, k] == v
    return mask, watch
