"""The ``residual_cubic`` stage: does a cubic of each axis's whole reading explain the ellipsoid fit's residual?

An ADC's non-linearity adds ``k_i v_i^3`` to each axis of the raw reading, offset included. On the whole
sphere no ellipsoid mimics it; on a band of tilts an ellipsoid absorbs most of it and the harmonic powers of
``residual_direction`` (25 coefficients, which slow noise fills as well) hide what is left. This stage tests the
three cubic terms alone, beyond the ellipsoid's own (linearised) parameters, on the ``sym`` fit's norm residual.

The test is a Wald test with the residual's own noise model, not the plain nested F test. The F test takes the
residual for white: the slow (AR(1)) noise every real sensor has, an offset that wanders for seconds, is seen
along the moving direction, and its projection on the cubic columns is then several times what white noise of
the same size would give and varies much from one draw to the next (sqrt(F) of clean rough-motion recordings:
0.3 to 4, mean 1.6, against 0.9 +- 0.4 for white noise). Twins and recording then differ by chance more than six
twin seeds can measure. Here the score of the cubic columns ``c = X_c^T r`` (``X_c`` made orthogonal to the
ellipsoid's columns) is weighed by its covariance under the noise the residual itself shows,

    ``Cov(c) = X_c^T S X_c``,  ``S_ij = w^2 delta_ij + s^2 (d_i . d_j) exp(-|t_i - t_j| / tau)``

(white noise ``w``; slow noise ``s``, ``tau`` fitted to the residual's lag covariances along the directions,
``baseline_noise.slow_covariance``, on what the fit with the cubic leaves), so ``W = c^T Cov(c)^-1 c`` is
chi-square with 3 degrees of freedom whatever the noise's colour. The feature is its normal score by Fisher's
square root, ``sqrt(2 W) - sqrt(5)``: about N(0, 1) for a sensor without a cubic (``NULL_SD``, the stage's
floor), and, as the F test's square root was, linear in the size of a cubic the ellipsoid cannot absorb (a cube
root, Wilson-Hilferty's closer score, shrinks a strong cubic's gap against the other stages' and with it the
share the ``nonlinearity`` effect removes). A residual that varies in time (a drift, an
offset step) counts as slow noise, so it raises the covariance with it, not the feature.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.fitting_noise import ar1_product
from .baseline_noise import slow_covariance

__all__ = ["NULL_SD", "cubic_feature", "cubic_wald"]

Array = NDArray[np.float64]

NULL_SD = 1.0
"""Spread of the feature for a sensor without a cubic (a normal score by construction): the stage's floor."""
_K = 3  # cubic terms tested
_TINY = 1e-12
_RCOND_GRAM = 1e-12  # relative eigenvalue of a normal matrix below which a direction is dropped (singular value 1e-6)
_MIN_SAMPLES = 50


def _pinv_solve(g: Array, xr: Array) -> Array:
    """Least-squares coefficients from the normal equations ``g c = xr`` (``xr`` a vector or columns) of columns
    scaled to one size, by the
    pseudo-inverse of ``g`` (eigenvalues below ``_RCOND_GRAM`` of the largest dropped: exactly collinear columns,
    as the ellipsoid's scale and the constant). A small eigen-decomposition, not a LAPACK least-squares driver on
    the tall matrix: those run many threaded steps, each of which waits for a busy core (100 times slower with
    the other core busy)."""
    w, v = np.linalg.eigh(g)
    keep = w > _RCOND_GRAM * max(float(w[-1]), _TINY)
    proj = v[:, keep].T @ xr
    out: Array = v[:, keep] @ (proj / w[keep].reshape((-1,) + (1,) * (proj.ndim - 1)))
    return out


def _columns(pts: Array, cal: Calibration) -> tuple[Array, Array, Array] | None:
    """The norm residual of ``cal``, the unit directions and the regressors: the ellipsoid's tangent columns (its
    derivatives with respect to the offset and the symmetric matrix) then the three cubic ones,
    ``(W^T u)_i v_i^3``, each scaled to RMS 1. All are evaluated at the points projected onto the fitted ellipsoid
    (``(v - b) / (1 + r) + b``): regressors taken from the noisy readings would correlate with the noise
    (``3 v_i^2 e_i``) and explain part of it. None when a point sits at the offset."""
    w = np.asarray(cal.matrix, dtype=np.float64)
    b = np.asarray(cal.offset, dtype=np.float64)
    v = pts - b
    h = v @ w.T
    lengths = np.linalg.norm(h, axis=1)
    if not np.all(lengths > 0):
        return None
    r = lengths / float(cal.norm) - 1.0
    u = h / lengths[:, None]
    v = v / (1.0 + r)[:, None]
    grad = u @ w
    pairs = [(a, c) for a in range(3) for c in range(a, 3)]
    tangent = [grad, np.ones((r.size, 1))] + [(u[:, a] * v[:, c] + u[:, c] * v[:, a])[:, None] for a, c in pairs]
    full = v + b
    cubic = grad * (full / max(float(np.max(np.abs(full))), _TINY)) ** 3
    x = np.hstack([*tangent, cubic])
    return r, u, x / np.maximum(np.sqrt(np.mean(x**2, axis=0)), _TINY)


def _score_covariance(xc: Array, left: Array, u: Array, t: Array) -> Array:
    """Covariance of the cubic score ``xc^T e`` under the noise model ``left`` shows (module docstring): white
    noise plus an AR(1) offset noise seen along the directions ``u``, per sample of the median interval."""
    s2, tau = slow_covariance(t, left, u) if np.ptp(t) > 0 else (0.0, 1.0)
    white2 = max(float(np.mean(left**2)) - s2, 0.0)
    cov = white2 * (xc.T @ xc)
    if s2 > 0:
        dt = float(np.median(np.diff(t)))
        phi = math.exp(-max(dt, 0.0) / max(tau, 1e-9))
        for a in range(3):
            y = xc * u[:, a:a + 1]
            cov += s2 * (y.T @ ar1_product(y, phi))
    return cov


def cubic_wald(pts: Array, cal: Calibration | None, t: Array) -> float:
    """The Wald statistic ``W`` of the three cubic terms (module docstring): chi-square with 3 degrees of freedom
    without a cubic. NaN without a ``sym`` fit, with fewer than 50 points or a residual without noise.

    Args:
        pts: raw readings (n, 3) in time order.
        cal: the ``sym`` fit whose residual is tested.
        t: their times (n,), seconds.
    """
    if cal is None or cal.model != "sym" or pts.shape[0] < _MIN_SAMPLES:
        return math.nan
    cols = _columns(pts, cal)
    if cols is None:
        return math.nan
    r, u, x = cols
    p0 = x.shape[1] - _K
    tan, cub = x[:, :p0], x[:, p0:]
    xc = cub - tan @ _pinv_solve(tan.T @ tan, tan.T @ cub)  # the cubic columns beyond the ellipsoid's
    score = xc.T @ r
    g = xc.T @ xc
    left = r - tan @ _pinv_solve(tan.T @ tan, tan.T @ r) - xc @ _pinv_solve(g, score)
    left = left - left.mean()
    cov = _score_covariance(xc, left, u, np.asarray(t, dtype=np.float64))
    if not np.all(np.isfinite(cov)) or not float(np.trace(cov)) > 0:
        return math.nan
    return float(score @ _pinv_solve(cov, score))


def cubic_feature(pts: Array, cal: Calibration | None, t: Array) -> float:
    """The ``residual_cubic`` feature: Fisher's normal score of ``cubic_wald``, ``sqrt(2 W) - sqrt(2 k - 1)`` (about
    N(0, 1) without a cubic, ``NULL_SD``; linear in the cubic's size, as the F test's square root was, so a strong
    cubic's gap keeps its size); NaN when the statistic is."""
    wald = cubic_wald(pts, cal, t)
    if not math.isfinite(wald):
        return math.nan
    return math.sqrt(2.0 * max(wald, 0.0)) - math.sqrt(2.0 * _K - 1.0)
