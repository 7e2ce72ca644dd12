"""The noise of time-ordered fit residuals: white plus AR(1), and the filter that whitens it.

Real sensors drift slowly (1/f noise): a fit to a time series whose residuals are correlated knows its
slowly fed parameters less well than a white-noise covariance says, and an unweighted fit lets the slow
noise move them. ``noise_model`` fits the residuals' sample autocorrelation ``rho_l = c phi^l``
(``l >= 1``; ``c`` the coloured share of the variance) by a log-linear fit over the lags where it is at
least ``NOISE_RHO_MIN``. White plus AR(1) noise is an ARMA(1, 1) process: ``u_t = x_t - phi x_(t-1)`` has
autocovariances ``g_0 = s^2 (1 + phi^2 - 2 c phi^2)``, ``g_1 = -s^2 phi (1 - c)`` and none beyond lag 1, so
``u_t = e_t - m e_(t-1)`` with ``m / (1 + m^2) = -g_1 / g_0`` (``|m| < 1``) and ``e`` white: ``whitener``
returns the filter ``e = (1 - phi B) / (1 - m B) x`` (``B`` the lag operator), with which ``fitting_prior``
fits time series by generalised least squares.

**Short series.** The sample autocorrelation of a short series is biased low: its mean is taken out (and with
it part of the slow noise: ``Var(mean)`` is the noise's long-run variance over ``m``) and the estimator divides
lag ``l``'s ``m - l`` products by ``m``. A log-linear fit to it found ``phi`` 0.91-0.94 for a true 0.961 on
100-300 points (the stream's first minute of 0.2 s block means of a 5 s correlation time), so the long-run
variance ``(1 - c) + c (1 + phi) / (1 - phi)`` came out at a third to two thirds of the truth, and a young fit's
covariance with it (Kendall's ``E[phi_hat] ~ phi - (1 + 3 phi) / m`` is the lag-1 case). ``noise_model``
therefore fits ``(c, phi)`` to the *expected* sample autocorrelation of a series of that length
(``expected_acf``: the ratio of the estimator's expected autocovariances, exact for the mean-removed series; the
ratio's own bias, 0.05 on 80 points, is not modelled), starting from the log-linear fit: the long-run variance's
median within 10 % of the truth from 100 points (``tests/model/test_fitting_noise_short.py``). Short series
scatter widely (a tenth of them below about a third of the truth on 300 points): unbiased, not sure.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.signal import lfilter

__all__ = ["NOISE_RHO_MIN", "Whitener", "expected_acf", "noise_model", "whitener"]

Array = NDArray[np.float64]

NOISE_RHO_MIN = 0.1
"""The residual autocorrelation below which a lag is not used to fit the coloured noise."""
_MAX_NOISE_LAG = 400
_PHI_MAX = 0.995
_C_MAX = 0.99


def noise_model(r: Array) -> tuple[float, float] | None:
    """White plus AR(1) noise fitted to the residuals' autocorrelation ``rho_l = c phi^l`` (module docstring:
    matched to the expected sample autocorrelation of a series of ``len(r)`` points): ``(c, phi)``, or None when
    the residuals look white."""
    m = len(r)
    max_lag = min(m // 10, _MAX_NOISE_LAG)
    if max_lag < 2:
        return None
    rc = r - r.mean()
    f = np.fft.rfft(rc, 2 * m)
    acf = np.fft.irfft(f * np.conj(f), 2 * m)[: max_lag + 1]
    if not acf[0] > 0:
        return None
    rho = acf[1:] / acf[0]
    if rho[0] < NOISE_RHO_MIN or rho[1] <= 0:
        return None
    below = np.flatnonzero(rho < NOISE_RHO_MIN)
    lags = np.arange(1, max(int(below[0]) if below.size else max_lag, 2) + 1)
    slope, icpt = np.polyfit(lags, np.log(np.maximum(rho[: lags.size], 1e-6)), 1)
    start = (min(math.exp(icpt), _C_MAX), min(math.exp(slope), _PHI_MAX))
    return _debiased(rho[: lags.size], m, lags, start)


def expected_acf(c: float, phi: float, m: int, lags: Array) -> Array:
    """Expected sample autocorrelation at ``lags`` (>= 1) of ``m`` points of unit white plus AR(1) noise
    ``(c, phi)``, mean removed and each lag's sum divided by ``m`` (module docstring: short series), as the ratio
    of the expected autocovariances: ``m E[c_l] = (m - l)(g_l + v) - sum_(t < m - l) (a_t + a_(t + l))`` with
    ``a_t = Cov(x_t, mean)`` and ``v = Var(mean)``."""
    s = np.arange(m)
    geo = phi * (1.0 - phi ** s) / (1.0 - phi)  # sum_(k=1..s) phi^k
    a = (1.0 + c * (geo + geo[::-1])) / m  # a_t = sum_u g_|u - t| / m
    cum = np.r_[0.0, np.cumsum(a)]
    lag = np.r_[0, np.asarray(lags, dtype=np.int64)]
    g = np.where(lag == 0, 1.0, c * phi ** lag)
    ec = (m - lag) * (g + cum[m] / m) - (cum[m - lag] + cum[m] - cum[lag])
    return ec[1:] / ec[0]


def _debiased(rho: Array, m: int, lags: Array, start: tuple[float, float]) -> tuple[float, float]:
    """``(c, phi)`` whose ``expected_acf`` fits the sample autocorrelation ``rho`` at ``lags`` best (least squares,
    from the log-linear ``start``; ``phi <= _PHI_MAX``, ``c <= _C_MAX``)."""
    x0 = np.clip(start, 1e-3, [_C_MAX - 1e-3, _PHI_MAX - 1e-3])
    fit = least_squares(lambda p: expected_acf(p[0], p[1], m, lags) - rho, x0, bounds=([0.0, 0.0], [_C_MAX, _PHI_MAX]))
    return float(fit.x[0]), float(fit.x[1])


Whitener = Callable[[Array], Array]
"""A causal filter along the last axis that turns the modelled noise white (unit gain on the innovations)."""


def whitener(model: tuple[float, float]) -> Whitener:
    """The ARMA(1, 1) filter ``(1 - phi B) / (1 - m B)`` that whitens white plus AR(1) noise ``(c, phi)``
    (module docstring); applied along the last axis."""
    c, phi = model
    g0 = 1.0 + phi * phi - 2.0 * c * phi * phi
    k = phi * (1.0 - c) / g0  # m / (1 + m^2), below 1/2 for c, phi in [0, 1)
    m = 0.0 if k <= 0.0 else (1.0 - math.sqrt(max(1.0 - 4.0 * k * k, 0.0))) / (2.0 * k)
    num, den = np.array([1.0, -phi]), np.array([1.0, -m])
    return lambda x: lfilter(num, den, x, axis=-1)
