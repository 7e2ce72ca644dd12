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
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

__all__ = ["NOISE_RHO_MIN", "Whitener", "noise_model", "whitener"]

Array = NDArray[np.float64]

NOISE_RHO_MIN = 0.1
"""The residual autocorrelation below which a lag is not used to fit the coloured noise."""
_MAX_NOISE_LAG = 400
_PHI_MAX = 0.995
_C_MAX = 0.99


def noise_model(r: Array) -> tuple[float, float] | None:
    """White plus AR(1) noise fitted to the residuals' autocorrelation ``rho_l = c phi^l`` (module docstring):
    ``(c, phi)``, or None when the residuals look white."""
    rc = r - r.mean()
    m = len(rc)
    max_lag = min(m // 10, _MAX_NOISE_LAG)
    if max_lag < 2:
        return None
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
    return float(min(math.exp(icpt), _C_MAX)), float(min(math.exp(slope), _PHI_MAX))


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
