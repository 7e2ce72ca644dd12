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

**Absorbed noise.** A young fit's residuals are not the noise: the fit took into its parameters the noise's
share along their directions, ``r = (I - U U^T) e`` (``U U^T = J (J^T J + s^2 P_0^-1)^-1 J^T``, the MAP fit's hat
matrix), and a slow noise over a few of its correlation times looks like parameters: on the independent
generator's +-20 deg band after 13 s (5 s correlation time, a fifth of the variance) the residual's lag-1
correlation was -0.05 to 0.02, so the noise read white and the fit's offset sat 6-7 sd from the truth (3.7 sd
with this model, 5.8 with the generator's own). ``noise_model(r, absorbed=U)`` matches ``(c, phi)`` to the
expected sample autocorrelation of such residuals (``Absorbed``: ``E[r r^T] = C K S K C``, ``K = I - U U^T``,
``C`` the mean's removal, summed along each lag's diagonal; exact) and calls the noise white when the fitted
noise's own lag-1 correlation ``c phi`` is below ``NOISE_RHO_MIN``, the rule the plain estimate applies to the
residual. A noise a fit absorbed entirely leaves no trace: then nothing can tell it (two of three such bands).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.fft import next_fast_len
from scipy.optimize import least_squares
from scipy.signal import lfilter

from .steps import Steps, drained

__all__ = ["NOISE_RHO_MIN", "Absorbed", "Whitener", "ar1_product", "expected_acf", "noise_model", "noise_model_steps",
           "whitener"]

Array = NDArray[np.float64]

NOISE_RHO_MIN = 0.1
"""The residual autocorrelation below which a lag is not used to fit the coloured noise."""
_MAX_NOISE_LAG = 400
_PHI_MAX = 0.995
_C_MAX = 0.99
_ABSORBED_LAGS = 24


def noise_model(r: Array, absorbed: Array | None = None) -> tuple[float, float] | None:
    """White plus AR(1) noise fitted to the residuals' autocorrelation ``rho_l = c phi^l`` (module docstring:
    matched to the expected sample autocorrelation of a series of ``len(r)`` points): ``(c, phi)``, or None when
    the residuals look white. ``absorbed`` (m, p): the fit's share of the noise, ``r = (I - U U^T) e`` (module
    docstring, **Absorbed noise**): the model is then matched to what such residuals show, and None means the
    fitted noise's own lag-1 correlation ``c phi`` is below ``NOISE_RHO_MIN``."""
    return drained(noise_model_steps(r, absorbed))


def noise_model_steps(r: Array, absorbed: Array | None = None) -> Steps[tuple[float, float] | None]:
    """``noise_model`` in steps (``steps``): two with ``absorbed`` (the grid of ``phi``, then its refinement), one
    without."""
    m = len(r)
    max_lag = min(m // 10, _MAX_NOISE_LAG)
    if max_lag < 2:
        return None
    rc = r - r.mean()
    n2 = next_fast_len(2 * m, real=True)  # zero-padded to at least 2m: the circular correlation is the linear one
    f = np.fft.rfft(rc, n2)
    acf = np.fft.irfft(f * np.conj(f), n2)[: max_lag + 1]
    if not acf[0] > 0:
        return None
    rho = acf[1:] / acf[0]
    if absorbed is not None:
        return (yield from _absorbed_model(rho, absorbed, max_lag))
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


def _absorbed_model(rho: Array, absorbed: Array, max_lag: int) -> Steps[tuple[float, float] | None]:
    """``(c, phi)`` whose ``Absorbed`` expected autocorrelation fits ``rho`` best over lags spread geometrically up to
    ``max_lag``: for each ``phi`` of a grid (and a golden-section refinement about the best) the best ``c`` of a
    dense grid; None when ``c phi < NOISE_RHO_MIN``."""
    lags = np.unique(np.round(np.geomspace(1, max_lag, _ABSORBED_LAGS)).astype(np.int64))
    model = Absorbed(absorbed, lags)
    target = rho[lags - 1]
    cs = np.linspace(0.0, _C_MAX, 100)

    def best_c(phi: float) -> tuple[float, float]:
        dw, da = model.parts(phi)
        d = (1.0 - cs[:, None]) * dw + cs[:, None] * da
        err = np.sum((d[:, 1:] / d[:, :1] - target) ** 2, axis=1)
        k = int(np.argmin(err))
        return float(err[k]), float(cs[k])

    # phi on a logit scale: 0.3 .. _PHI_MAX
    lo, hi = math.log(0.3 / 0.7), math.log(_PHI_MAX / (1.0 - _PHI_MAX))
    xs = np.linspace(lo, hi, 7)
    errs = [best_c(_expit(x))[0] for x in xs]
    yield  # the refinement next
    k = int(np.argmin(errs))
    a, b = xs[max(k - 1, 0)], xs[min(k + 1, len(xs) - 1)]
    g = (math.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = b - g * (b - a), a + g * (b - a)
    f1, f2 = best_c(_expit(x1))[0], best_c(_expit(x2))[0]
    for _ in range(6):
        if f1 < f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - g * (b - a)
            f1 = best_c(_expit(x1))[0]
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + g * (b - a)
            f2 = best_c(_expit(x2))[0]
    phi = _expit(0.5 * (a + b))
    c = best_c(phi)[1]
    return (c, phi) if c * phi >= NOISE_RHO_MIN else None


def _expit(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x))


class Absorbed:
    """The expected sample autocorrelation of residuals ``(I - U U^T) e`` of white plus AR(1) noise ``e`` (module
    docstring, **Absorbed noise**), the series' mean removed: exact for any ``U`` (m, p), at ``lags`` (>= 1).
    A ``phi`` costs two AR(1) filters of ``U`` and one FFT correlation."""

    def __init__(self, u: Array, lags: Array) -> None:
        m = len(u)
        self.m, self.n2 = m, next_fast_len(2 * m, real=True)  # at least 2m, of small prime factors: 2m = 2 x 233 cost 5x
        self.lags = np.r_[0, np.asarray(lags, dtype=np.int64)]
        self.u = np.asarray(u, dtype=np.float64)
        self.e = np.full(m, 1.0 / math.sqrt(m))
        self._fu = np.conj(np.fft.rfft(self.u, self.n2, axis=0))
        self.x = np.stack([self.u[: m - k].T @ self.u[k:] for k in self.lags])  # X_jk(l) = sum_t u_tj u_(t+l)k
        self.ee = (m - self.lags) / m  # sum_t e_t e_(t+l)
        self._white = self._diagonals(self.u, (self.lags == 0) * float(m), lambda v: v)
        self._cache: dict[float, Array] = {}

    def _diagonals(self, su: Array, g: Array, cov: Callable[[Array], Array]) -> Array:
        """Lag sums of ``C K S K C`` (``K = I - U U^T``, ``C`` the mean's removal) for the covariance ``S``: ``su = S U``,
        ``g`` the lag sums of ``S``, ``cov`` applies it."""
        u, e, lags = self.u, self.e, self.lags
        cc = np.fft.irfft((self._fu * np.fft.rfft(su, self.n2, axis=0)).sum(axis=1), self.n2)
        cross = cc[lags] + cc[(self.n2 - lags) % self.n2]  # sum_t u_t . (S u)_(t+l) and its mirror
        kske = self._k(cov(self._k(e)))
        d = g - cross + np.einsum("jk,ljk->l", u.T @ su, self.x)
        return d - 2.0 * self._esum(kske) + float(e @ kske) * self.ee

    def _diagonals_ar(self, phi: float) -> Array:
        """Lag sums of ``C K Phi K C`` (``Phi_ts = phi^|t - s|``)."""
        g = (self.m - self.lags) * phi**self.lags
        return self._diagonals(ar1_product(self.u, phi), g, lambda v: ar1_product(v, phi))

    def _k(self, v: Array) -> Array:
        return v - self.u @ (self.u.T @ v)

    def _esum(self, w: Array) -> Array:
        """Half of ``sum_t e_t w_(t+l) + sum_t w_t e_(t+l)`` at the lags (the caller doubles it)."""
        tail = np.r_[np.cumsum(w[::-1])[::-1], 0.0]  # tail[l] = sum_(t >= l) w_t
        head = np.r_[0.0, np.cumsum(w)]  # head[k] = sum_(t < k) w_t
        return 0.5 * (tail[self.lags] + head[self.m - self.lags]) / math.sqrt(self.m)

    def parts(self, phi: float) -> tuple[Array, Array]:
        """Lag sums (lag 0 first) of the white and the AR(1) ``phi`` part (both unit variance)."""
        got = self._cache.get(phi)
        if got is None:
            got = self._cache[phi] = self._diagonals_ar(phi)
        return self._white, got

    def expected(self, c: float, phi: float) -> Array:
        """The expected autocorrelation at the lags of unit white plus AR(1) noise ``(c, phi)``."""
        dw, da = self.parts(phi)
        d = (1.0 - c) * dw + c * da
        return d[1:] / d[0]


def ar1_product(v: Array, phi: float) -> Array:
    """``Phi v`` with ``Phi_ts = phi^|t - s|`` (along the first axis; the AR(1) correlation matrix, unit variance):
    a forward and a backward AR(1) filter, O(n) where the matrix would be O(n^2)."""
    fwd = lfilter([1.0], [1.0, -phi], v, axis=0)
    bwd = lfilter([1.0], [1.0, -phi], v[::-1], axis=0)[::-1]
    return fwd + bwd - v


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
