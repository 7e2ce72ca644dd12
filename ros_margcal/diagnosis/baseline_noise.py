"""What the twin's baseline sensor holds beyond the simulator's: slow noise and the sensor's own shape.

- *Slow noise*: real sensors (and the independent test generator) have a slowly wandering offset
  (Gauss-Markov / AR(1) noise, flicker) besides the white rest noise. A twin with white noise only has
  too tight a residual spread for them: ``estimate_slow_noise`` measures it on the recording's residual
  and ``ar1_noise`` simulates it (``twin.Twin.features`` adds it before the read-out).
- *Shape*: a magnetometer always has some soft iron; ``shaped_truth`` keeps cross-axis terms up to a
  tolerance the caller gives as part of the baseline sensor, so only a larger shape is a gap.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from ..model.calibration import Calibration

__all__ = ["ar1_noise", "estimate_slow_noise", "shaped_truth", "slow_covariance"]

Array = NDArray[np.float64]

_SLOW_MIN_SHARE = 0.04
_SLOW_MAX_RATIO = 1.0
_SLOW_LAGS = 30  # lags at which the slow noise's covariance is measured
_SLOW_TAUS = 80  # correlation times tried


def ar1_noise(t: Array, std: float, tau: float, rng: np.random.Generator) -> Array:
    """Gauss-Markov (AR(1)) noise (n, 3) of stationary ``std`` and correlation time ``tau`` at times ``t``
    (the step of the median sample interval: a recording with gaps keeps its correlation per sample)."""
    n = t.size
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    phi = math.exp(-max(dt, 0.0) / max(tau, 1e-9))
    innov = rng.normal(size=(n, 3)) * (std * math.sqrt(max(1.0 - phi * phi, 0.0)))
    if n:
        innov[0] = rng.normal(size=3) * std
    return np.asarray(lfilter([1.0], [1.0, -phi], innov, axis=0), dtype=np.float64)


def estimate_slow_noise(t: Array, residual: Array, white: float, dirs: Array) -> tuple[float, float]:
    """Slow (coloured) noise beyond the white noise, from the best fit's norm residual (fractions of the radius).

    What the residual holds beyond its mean is white noise plus a slow part: its autocorrelation at short lags
    (1-5 samples of ``t``) is the slow part's share ``a`` of the variance, its correlation time the one whose
    exponential fits the residual's lag covariances along the directions (``slow_covariance``). The slow
    part counts when ``a`` exceeds ``_SLOW_MIN_SHARE`` (white noise alone: ~0.01), with a std of at most
    ``_SLOW_MAX_RATIO`` times the white rest noise ``white`` (a larger slow part is an effect, a drift
    or a temperature course, not noise). Real sensors and the independent test generator have such
    noise; a twin with white noise only has too tight a residual spread for them.
    """
    if residual.size < 100 or not white > 0 or np.ptp(t) <= 0:
        return 0.0, 1.0
    left = residual - residual.mean()
    den = float(left @ left)
    if den <= 0:
        return 0.0, 1.0
    acf = np.array([float(left[k:] @ left[:-k]) / den for k in range(1, 6)])
    share = float(np.mean(acf))
    if share <= _SLOW_MIN_SHARE:
        return 0.0, 1.0
    std = min(math.sqrt(share * den / left.size), _SLOW_MAX_RATIO * white)
    return std, slow_covariance(t, left, dirs)[1]


def _lag_covariance(t: Array, left: Array, dirs: Array, lags: NDArray[np.intp]) -> tuple[Array, Array]:
    """Covariance of the slow noise at each lag (samples) and the lag's time: the norm residual sees an offset
    noise ``n`` along the direction, ``r_i r_j ~ (d_i . d_j) cov(n_i, n_j)``, so the slope of ``r_i r_{i+k}`` on
    ``d_i . d_{i+k}`` is the per-axis covariance at lag k whatever the motion (white noise adds none at k >= 1)."""
    cov = np.empty(lags.size)
    for j, k in enumerate(lags):
        x = np.einsum("ij,ij->i", dirs[k:], dirs[:-k])
        cov[j] = float(x @ (left[k:] * left[:-k])) / max(float(x @ x), 1e-300)
    return cov, _lag_times(np.ascontiguousarray(t, dtype=np.float64).tobytes(), lags.tobytes())


@functools.lru_cache(maxsize=4)
def _lag_times(t_bytes: bytes, lags_bytes: bytes) -> Array:
    """Median time of each lag (samples) of the times ``t`` (their bytes: a recording and all its twins share one
    time base, and the cubic stage asks for it at every twin, so it is computed once)."""
    t, lags = np.frombuffer(t_bytes, dtype=np.float64), np.frombuffer(lags_bytes, dtype=np.intp)
    out = np.array([float(np.median(t[k:] - t[:-k])) for k in lags])
    out.flags.writeable = False
    return out


def slow_covariance(t: Array, left: Array, dirs: Array) -> tuple[float, float]:
    """Variance ``s^2`` and correlation time ``tau`` of the slow noise in a norm residual ``left`` (mean removed):
    the AR(1) covariance ``s^2 exp(-lag / tau)``, less the variance of its mean over the recording (the fit's offset
    takes the mean), that fits the residual's own lag covariances (``_lag_covariance``, lags log-spaced up to a
    quarter of the recording) best in least squares, ``s^2`` in closed form per ``tau`` of a log-spaced grid from
    0.05 s to the recording's span. No slow noise: ``s^2`` near 0."""
    n = t.size
    lags = np.unique(np.geomspace(1, max(n // 4, 2), _SLOW_LAGS).astype(np.intp))
    cov, lag_t = _lag_covariance(t, left, dirs, lags)
    span = max(float(np.ptp(t)), 0.1)
    taus = np.geomspace(0.05, span, _SLOW_TAUS)[:, None]  # one row per correlation time tried
    u = taus / span  # the fit's offset takes the noise's mean over the recording: its variance, 2u(1 - u(1 - e^-1/u))
    e = np.exp(-lag_t[None, :] / taus) - 2.0 * u * (1.0 - u * (1.0 - np.exp(-1.0 / u)))
    s2 = np.maximum((e @ cov) / np.maximum(np.sum(e * e, axis=1), 1e-300), 0.0)
    j = int(np.argmin(np.sum((cov[None, :] - s2[:, None] * e) ** 2, axis=1)))
    return float(s2[j]), float(taus[j, 0])


def shaped_truth(diag: Calibration, best: Calibration, tolerance: float, *, cross_only: bool = False) -> Calibration:
    """The twin's true sensor: the baseline ``diag`` fit, or with ``tolerance`` > 0 the best (``sym``)
    fit whose cross-axis terms (off-diagonal entries of W relative to its diagonal) are scaled down so
    that their size, the root sum of squares of the three, is at most ``tolerance``: a shape within the
    tolerance counts as the sensor's baseline and only its excess is left as a gap (the
    ``ellipsoid_shape`` effects). The shape is one quantity: a bound per entry would let three terms
    each up to the tolerance pass, a shape ``sqrt(3)`` times the expected one. With ``cross_only`` only
    those cross terms are taken from ``best``, onto the offset and gains of ``diag`` (a ``best``
    fitted on part of the sphere, whose scale along the unseen directions is not to be trusted)."""
    if tolerance <= 0 or best.model != "sym" or best is diag:
        return diag
    w = np.asarray(best.matrix, dtype=np.float64)
    d = np.sqrt(np.abs(np.diag(w)))
    c = w / np.outer(d, d)
    c = 0.5 * (c + c.T)
    upper = np.triu(np.ones((3, 3), dtype=bool), 1)
    size = float(np.sqrt(np.sum(c[upper] ** 2)))
    if size > tolerance:
        off = ~np.eye(3, dtype=bool)
        c[off] *= tolerance / size
    if cross_only:
        d = np.sqrt(np.abs(np.diag(np.asarray(diag.matrix, dtype=np.float64))))
        return diag.replace(matrix=c * np.outer(d, d), model="sym")
    return best.replace(matrix=c * np.outer(d, d), model="sym")
