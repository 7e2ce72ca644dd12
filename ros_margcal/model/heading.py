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
``|g^T delta|``. A calibration's measured p95 lies above or below it with even odds when ``C`` is right.

**The 95 % bound on the measured figure.** ``heading_p95_quantile`` is the same distribution's 95th percentile
(``QUANTILE_DRAWS`` fixed draws): the figure a right ``C`` keeps the measured p95 below 95 % of the time. The
per-attitude ``heading_p95`` equals it only for one dominant error direction; with more it is lower: for a level
heading whose error comes from ``b_x`` and ``b_y`` alike, the error is ``A cos(yaw + phi)`` with ``A`` Rayleigh,
so ``1.96 sd`` covers 85 % and the quantile is ``sqrt(-2 ln 0.05) = 2.45 sd``. On the benchmark's calibrations
``heading_p95`` was a median 0.89 (0.80-1.01) of the quantile.

**Not determined.** Heading errors wrap at 180 deg and the first-order figure is meaningless long before: a
bound above ``UNDETERMINED_DEG`` (90 deg), or from a covariance that is not finite, is returned as NaN, and
``format_bound`` prints it as "not determined" (never "9845001.40 deg").

**Covariances that are too small.** The bound is only as right as ``C``. On the independent generator
(``scripts/bench_heading_bound.py``), the covariance of a fit to samples without time order (the full path's
direction buffer, ``fitting_prior.posterior_at`` under white noise) is too small on rich motion: the normalised
error ``delta^T C^-1 delta`` has a median of 23-29 where 9 parameters give 8.3 (9.5 for the time-ordered MAP fits
of a ground robot), as slow (AR(1)) sensor noise shared by neighbouring samples counts as independent.
``inflated(cal, UNORDERED_SD_FACTOR)`` scales such a covariance by a fixed standard-deviation factor, chosen on
the benchmark's tuning seeds as the smallest that covers 95 % there. The time-ordered MAP fit models that noise
itself (``fitting_noise``, with the small-sample bias of a short series' autocorrelation modelled) and needs no
factor once its series is long.

**Slow noise the offset absorbs.** Noise slower than the series (a sensor's 1/f drift over a fit's first
seconds) is a near-constant shift of every raw axis: it is indistinguishable from the offset, the fit takes it
as offset, and no residual shows it, so no noise model fitted to the residuals can see it (the independent
generator's tumble, 6 s, the stream's early fit: the level bound covered 16 of 23 fits on development seeds,
all 23 without the generator's AR(1) noise).
``with_offset_noise(cal, sd)`` adds ``sd^2`` per axis to the offset's variance; the stream's partial fits take
``sd`` as the series' residual noise (an assumption: the slow noise is at most the noise the residuals show;
the generator's is 0.85 of it on a 6 s tumble), as ``fitting_level`` assumes how level a vehicle is.
With it and the debiased noise model, the level coverage of ``scripts/bench_heading_bound.py``'s held-out seeds
went from 92.0 to 94.6 % (the +-20 deg band 76.9 to 89.3 %, the 20 deg ground robot 91.5 to 96.6 %), the median
bound / measured from 2.07 to 2.42, and no case's first calibration came later.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

from .calibration import Calibration
from .errors import InputError
from .fitting_core import parameter_names

__all__ = ["QUANTILE_DRAWS", "TYPICAL_DRAWS", "UNDETERMINED_DEG", "UNORDERED_SD_FACTOR", "attitudes", "format_bound",
           "heading_gradient", "heading_p95", "heading_p95_quantile", "heading_p95_typical", "heading_std_deg",
           "inclination_deg", "inflated", "with_offset_noise"]

Array = NDArray[np.float64]

_NAMES = parameter_names("sym", scale_free=False)
TYPICAL_DRAWS = 256
"""Parameter errors drawn from the covariance for ``heading_p95_typical`` (a fixed seed: deterministic)."""
_TYPICAL_Z = np.random.default_rng(20261126).standard_normal((TYPICAL_DRAWS, 9))
QUANTILE_DRAWS = 500
"""Parameter errors drawn for ``heading_p95_quantile`` (a fixed seed: deterministic; within 7 % of an 8000-draw
figure on the benchmark's covariances; about twice the cost of ``heading_p95_typical``)."""
_QUANTILE_Z = np.random.default_rng(20261127).standard_normal((QUANTILE_DRAWS, 9))
UNDETERMINED_DEG = 90.0
"""A heading figure above this (degrees) is not determined: the first-order figure is invalid long before 180."""
UNORDERED_SD_FACTOR = 2.4
"""Standard-deviation factor for a white-noise covariance of samples without time order (module docstring): with
``heading_p95_quantile``, the smallest that covers 29 of the 30 full-path calibrations of the tuning seeds of
``scripts/bench_heading_bound.py`` (2.35 level, 2.07 at 30 deg; rounded up)."""


def attitudes(tilt_deg: float, n_yaw: int = 72) -> Array:
    """Rotation matrices body -> world (K, 3, 3) over a yaw grid, roll and pitch in {-tilt, 0, tilt}
    (``R = R_z(yaw) R_y(pitch) R_x(roll)``, roll outermost, then pitch, then yaw)."""
    return _attitudes(float(tilt_deg), int(n_yaw)).copy()


@functools.lru_cache(maxsize=8)
def _attitudes(tilt_deg: float, n_yaw: int) -> Array:
    """``attitudes``, kept for the grids the figures ask again and again (0 and 30 deg); read-only."""
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
    grid = np.concatenate(out)
    grid.flags.writeable = False
    return grid


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
    with np.errstate(divide="ignore", invalid="ignore"):  # a vertical field (inclination 90 deg): no heading, NaN
        c = (hy * rot[:, 0, :] - hx * rot[:, 1, :]) / (hx * hx + hy * hy)  # (the figures read "not determined")
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


def inflated(cal: Calibration, sd_factor: float) -> Calibration:
    """``cal`` with its covariance scaled by ``sd_factor ** 2`` (module docstring: covariances that are too small).

    Raises:
        InputError: no covariance over the symmetric model's parameters, or a factor not positive and finite.
    """
    cov = _covariance(cal)
    if not (math.isfinite(sd_factor) and sd_factor > 0):
        msg = f"sd_factor must be a positive finite number, got {sd_factor!r}"
        raise InputError(msg)
    return cal.replace(covariance=cov * (sd_factor * sd_factor))


def with_offset_noise(cal: Calibration, sd: float) -> Calibration:
    """``cal`` with ``sd ** 2`` (raw units) added to the variance of each offset component (module docstring:
    slow noise longer than the series, which the offset absorbs and no residual shows).

    Raises:
        InputError: no covariance over the symmetric model's parameters, or ``sd`` negative or not finite.
    """
    cov = _covariance(cal).copy()
    if not (math.isfinite(sd) and sd >= 0):
        msg = f"sd must be a non-negative finite number, got {sd!r}"
        raise InputError(msg)
    cov[:3, :3] += sd * sd * np.eye(3)
    return cal.replace(covariance=cov)


def _determined(value: float) -> float:
    """``value``, or NaN when it is not a determined heading figure (above ``UNDETERMINED_DEG`` or not finite)."""
    return value if math.isfinite(value) and value <= UNDETERMINED_DEG else math.nan


def format_bound(value: float | None, digits: int = 2) -> str:
    """A heading figure for people: ``"0.57 deg"``, or ``"not determined"`` for None, NaN, infinity or a figure
    above ``UNDETERMINED_DEG`` (the one formatter of ``heading_p95`` and ``heading_p95_typical`` results)."""
    if value is None or not (math.isfinite(value) and value <= UNDETERMINED_DEG):
        return "not determined"
    return f"{value:.{digits}f} deg"


def heading_p95(cal: Calibration, *, tilt_deg: float = 0.0, inclination: float = 60.0, n_yaw: int = 72) -> float:
    """Predicted 95th-percentile heading error (degrees) of ``cal`` at the given tilt (module docstring); NaN
    when not determined (a covariance that is not finite, a figure above ``UNDETERMINED_DEG``).

    Raises:
        InputError: the calibration has no covariance over the symmetric model's parameters.
    """
    if not np.all(np.isfinite(_covariance(cal))):
        return math.nan
    sd = heading_std_deg(cal, attitudes(tilt_deg, n_yaw), inclination=inclination)
    return _determined(float(np.percentile(1.96 * sd, 95)))


def _draw_p95(cal: Calibration, z: Array, tilt_deg: float, inclination: float, n_yaw: int) -> Array:
    """The p95 over the grid of ``|g^T delta|`` for each error ``delta = L z`` drawn from the covariance (NaN when
    it is not finite); the 95th percentile of each row as np.percentile's linear rule, by partition (no sort)."""
    cov = _covariance(cal)
    if not np.all(np.isfinite(cov)):
        return np.full(len(z), math.nan)
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    grad = heading_gradient(cal, _attitudes(float(tilt_deg), int(n_yaw)), inclination=inclination)
    errors = z @ (grad @ (vec * np.sqrt(np.clip(lam, 0.0, None)))).T  # (draws, attitudes)
    return _row_p95(np.abs(errors, out=errors))


def _row_p95(errors: Array) -> Array:
    """The 95th percentile of each row (np.percentile's linear rule, to rounding) from one partition in place (the
    rows are reordered): after it, the next order statistic is the smallest of what lies above the first (a second
    kth made a second pass, and a copy: 2.5x the time)."""
    k = errors.shape[1]
    pos = 0.95 * (k - 1)
    lo = math.floor(pos)
    errors.partition(lo, axis=1)
    low = errors[:, lo]
    high = errors[:, lo + 1:].min(axis=1) if lo + 1 < k else low
    return low + (pos - lo) * (high - low)


def heading_p95_typical(cal: Calibration, *, tilt_deg: float = 0.0, inclination: float = 60.0, n_yaw: int = 72) -> float:
    """Predicted median of the measured heading p95 (degrees) of ``cal`` at the given tilt: the p95 over the
    grid of ``|g^T delta|``, its median over ``TYPICAL_DRAWS`` errors ``delta`` drawn from the covariance
    (module docstring). NaN when not determined (a covariance that is not finite, a figure above
    ``UNDETERMINED_DEG``).

    Raises:
        InputError: the calibration has no covariance over the symmetric model's parameters.
    """
    return _determined(float(np.median(_draw_p95(cal, _TYPICAL_Z, tilt_deg, inclination, n_yaw))))


def heading_p95_quantile(cal: Calibration, *, tilt_deg: float = 0.0, inclination: float = 60.0, n_yaw: int = 72) -> float:
    """The 95 % bound on the measured heading p95 (degrees) itself: the 95th percentile, over ``QUANTILE_DRAWS``
    fixed errors drawn from the covariance, of the p95 over the grid of ``|g^T delta|`` (module docstring: with
    two or more error directions, ``heading_p95`` is below it). NaN when not determined.

    Raises:
        InputError: the calibration has no covariance over the symmetric model's parameters.
    """
    return _determined(float(np.percentile(_draw_p95(cal, _QUANTILE_Z, tilt_deg, inclination, n_yaw), 95)))
