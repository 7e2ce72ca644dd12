"""Motion time series: the orientation history of a body, and events that change a true offset.

``tumbling_motion`` gives rests at random orientations joined by minimum-jerk turns with linear
acceleration (what the inactivity gate of Gietzelt et al. 2013, Sect. 2.4, must sort out);
``smooth_motion`` a continuous rotation that sweeps the sphere. One ``Motion`` can drive both sensors
of an IMU (``simulation.tumbling`` and ``simulation.magnetometer_stream``, which also take the
``HardIronJump`` / ``OffsetDrift`` events defined here). ``simulation`` re-exports all public names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation, Slerp

from ..model.errors import ConfigError
from .patterns import unit_vectors

__all__ = ["HardIronJump", "Motion", "OffsetDrift", "sample_times", "smooth_motion", "tumbling_motion"]

Array = NDArray[np.float64]


@dataclass
class Motion:
    """Orientation history of a body: ``v_world = rot.apply(v_body)``.

    Attributes:
        t: times, seconds (n,).
        rot: body-to-world rotations (n of them).
        lin_acc: linear acceleration in the world frame, m/s² (n, 3).
        gyro: angular rate in the body frame, rad/s (n, 3).
        still: True while the body is at rest (n,).
    """

    t: Array
    rot: Rotation
    lin_acc: Array
    gyro: Array
    still: NDArray[np.bool_]

    def resample(self, t: ArrayLike) -> Motion:
        """The motion at other times (orientation by slerp, the rest by linear/nearest interpolation)."""
        times = np.clip(np.asarray(t, dtype=np.float64), self.t[0], self.t[-1])
        rot = Slerp(self.t, self.rot)(times)
        lin = np.column_stack([np.interp(times, self.t, self.lin_acc[:, i]) for i in range(3)])
        gyro = np.column_stack([np.interp(times, self.t, self.gyro[:, i]) for i in range(3)])
        idx = np.clip(np.searchsorted(self.t, times), 0, len(self.t) - 1)
        return Motion(times, rot, lin, gyro, self.still[idx])


def _random_rotations(k: int, rng: np.random.Generator) -> Rotation:
    return Rotation.from_quat(rng.normal(size=(k, 4)))  # a normalised Gaussian quaternion is uniform


def sample_times(duration_s: float, rate_hz: float) -> Array:
    """Sample times ``0, 1/rate_hz, ...`` covering ``duration_s`` (at least two samples).

    Raises:
        ConfigError: ``duration_s`` or ``rate_hz`` not positive and finite.
    """
    if not (duration_s > 0 and rate_hz > 0 and math.isfinite(duration_s * rate_hz)):
        msg = f"duration_s and rate_hz must be positive, got {duration_s!r}, {rate_hz!r}"
        raise ConfigError(msg)
    return np.arange(max(2, round(duration_s * rate_hz))) / rate_hz


def tumbling_motion(
    duration_s: float,
    rate_hz: float,
    rng: np.random.Generator,
    *,
    still_fraction: float = 0.6,
    still_s: tuple[float, float] = (1.5, 4.0),
    max_lin_acc: float = 2.0,
    max_rate_dps: float = 150.0,
) -> Motion:
    """Still periods at uniformly random orientations joined by smooth moves.

    Each move turns the body from one rest orientation to the next about a fixed body axis with a
    minimum-jerk profile ``s(τ) = 10τ³ - 15τ⁴ + 6τ⁵`` and carries a linear acceleration
    ``A sin(2πτ)`` (zero net velocity change) of amplitude up to ``max_lin_acc`` m/s².

    Args:
        duration_s: length, seconds.
        rate_hz: sample rate.
        rng: the random generator.
        still_fraction: share of the time at rest, in (0, 1].
        still_s: range of the rest durations, seconds.
        max_lin_acc: largest linear acceleration during a move, m/s².
        max_rate_dps: largest turn rate; a move lasts long enough to stay below it.
    """
    if not 0 < still_fraction <= 1:
        msg = f"still_fraction must be in (0, 1], got {still_fraction}"
        raise ConfigError(msg)
    t = sample_times(duration_s, rate_hz)
    max_rate = math.radians(max_rate_dps)
    starts: list[float] = []
    lengths: list[float] = []
    moving: list[bool] = []
    quats = [_random_rotations(1, rng)[0].as_quat()]
    cur = 0.0
    while cur <= t[-1]:
        rest = float(rng.uniform(*still_s))
        starts.append(cur)
        lengths.append(rest)
        moving.append(False)
        cur += rest
        if still_fraction < 1:
            nxt = _random_rotations(1, rng)[0]
            turn = (Rotation.from_quat(quats[-1]).inv() * nxt).magnitude()
            # minimum-jerk peak rate is 1.875 x the mean rate: keep it under max_rate_dps
            move = max(0.3, rest * (1 - still_fraction) / still_fraction * float(rng.uniform(0.7, 1.3)),
                       1.875 * turn / max_rate)
            starts.append(cur)
            lengths.append(move)
            moving.append(True)
            cur += move
            quats.append(nxt.as_quat())
    quats.append(quats[-1])
    starts_a, lengths_a, moving_a = np.array(starts), np.array(lengths), np.array(moving)
    seg = np.searchsorted(starts_a, t, side="right") - 1
    pose = np.cumsum(~moving_a) - 1  # the rest orientation a segment starts from
    rests = Rotation.from_quat(np.array(quats))
    n_pose = len(rests) - 1
    rel = (rests[:-1].inv() * rests[1:]).as_rotvec()  # body-frame turn from rest k to rest k+1
    amp = rng.uniform(0.3, 1.0, size=(n_pose, 1)) * max_lin_acc * unit_vectors(rng.normal(size=(n_pose, 3)))
    tau = np.clip((t - starts_a[seg]) / lengths_a[seg], 0.0, 1.0)
    mov = moving_a[seg]
    k = pose[seg]
    s = np.where(mov, 10 * tau**3 - 15 * tau**4 + 6 * tau**5, 0.0)
    ds = np.where(mov, (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / lengths_a[seg], 0.0)
    rot = rests[k] * Rotation.from_rotvec(s[:, None] * rel[k])
    gyro = ds[:, None] * rel[k]  # the turn axis is fixed in the body frame
    lin = np.where(mov[:, None], np.sin(2 * np.pi * tau)[:, None] * amp[k], 0.0)
    return Motion(t, rot, lin, gyro, ~mov)


def smooth_motion(duration_s: float, rate_hz: float, rng: np.random.Generator, *, rate_dps: float = 20.0) -> Motion:
    """A continuous rotation about slowly wandering axes that sweeps the whole sphere in a few minutes.

    Body angles about z, y and x grow at incommensurate rates (``rate_dps`` x 1, 0.61, 0.37) from random
    starting angles, so the field direction seen in the body frame covers the sphere.
    """
    t = sample_times(duration_s, rate_hz)
    w = math.radians(rate_dps) * np.array([1.0, 0.61, 0.37])
    phase = rng.uniform(0, 2 * np.pi, size=3)
    rot = Rotation.from_euler("ZYX", phase + t[:, None] * w)
    dt = np.diff(t).mean() if t.size > 1 else 1.0
    step = (rot[:-1].inv() * rot[1:]).as_rotvec() / dt
    gyro = np.vstack([step, step[-1:]])
    return Motion(t, rot, np.zeros((t.size, 3)), gyro, np.zeros(t.size, dtype=bool))


# -- events of the true offset ---------------------------------------------------------------------


@dataclass(frozen=True)
class HardIronJump:
    """At ``time`` (s) the offset changes by ``delta`` (raw units) for good (e.g. a magnet mounted nearby)."""

    time: float
    delta: tuple[float, float, float]


@dataclass(frozen=True)
class OffsetDrift:
    """From ``start`` (s) the offset moves linearly at ``rate`` (raw units per second)."""

    rate: tuple[float, float, float]
    start: float = 0.0
