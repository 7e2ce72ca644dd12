"""The noise of time-ordered fit residuals: white plus AR(1), and the data information it leaves a fit.

Real sensors drift slowly (1/f noise): a fit to a time series whose residuals are correlated knows its
slowly fed parameters less well than a white-noise covariance says. ``noise_model`` fits the residuals'
sample autocorrelation ``rho_l = c phi^l`` (``l >= 1``; ``c`` the coloured share of the variance) by a
log-linear fit over the lags where it is at least ``NOISE_RHO_MIN``; ``coloured_information`` gives the
sandwich ``A B^-1 A`` (``A = J^T J``, ``B = J^T Sigma J``, ``Sigma_ij = s^2 ((1 - c) delta_ij + c phi^|i-j|)``,
``Sigma J`` by one forward and one backward AR(1) filter). Used by ``fitting_prior`` (see its docstring).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

__all__ = ["NOISE_RHO_MIN", "coloured_information", "noise_model"]

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


def coloured_information(jt: Array, r: Array) -> Array:
    """Data information ``A B^-1 A`` of time-ordered residuals under the white plus AR(1) noise fitted to them:
    ``A = J^T J``, ``B = J^T Sigma J``, ``Sigma_ij = s^2 ((1 - c) delta_ij + c phi^|i-j|)`` (module docstring)."""
    a = jt @ jt.T
    var = float(np.mean((r - r.mean()) ** 2))
    model = noise_model(r)
    if model is None:
        return a / var
    c, phi = model
    fwd = lfilter([1.0], [1.0, -phi], jt, axis=-1)  # sum_(j <= i) phi^(i-j) J_j
    bwd = lfilter([1.0], [1.0, -phi], jt[:, ::-1], axis=-1)[:, ::-1]  # sum_(j >= i)
    b = var * ((1.0 - c) * a + c * (jt @ (fwd + bwd - jt).T))
    return a @ np.linalg.solve(0.5 * (b + b.T), a)
