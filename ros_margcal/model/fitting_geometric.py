"""The geometric residual of the MAP fit, its exact Jacobian, and block means fitted to their own norm.

**Residual.** With ``theta = (b_x, b_y, b_z, w_xx, w_yy, w_zz, w_xy, w_xz, w_yz)`` (``fitting_core``'s
symmetric parameter vector) and the reference norm ``n``:

    r_i(theta) = (|W d_i| - n) / |W u_i|,   d_i = v_i - b,  u_i = W d_i / |W d_i|,

the norm residual of Camps et al. 2009 (Eqs. 2, 4-7) divided by its gradient in the raw reading, i.e.
the first-order distance of ``v_i`` from the ellipsoid in raw units. The division matters on partial
coverage: the plain norm residual can be made small by flattening the ellipsoid across the data (a
cap or a ring of yaw-only data is fitted by a huge, flat ellipsoid far away whose gradient is small,
so its norm residuals are far below the noise), while the geometric residual cannot.

**Jacobian** (exact): writing ``y = W d``, ``q = W y``, ``r = (|y| - n) |y| / |q|`` and
``dr = alpha (y . dy) - beta (q . dq)`` with ``alpha = (2|y| - n) / (|y| |q|)``, ``beta = r / |q|^2``; for the
norm as a tenth parameter ``dr / dn = -|y| / |q|``. (Dropping the derivative of ``1 / |W u|`` is not
harmless: Levenberg-Marquardt then stops where ``J^T r = 0`` for the wrong ``J``, an ``O(sigma^2)`` bias per
point that does not average out; on a ring it moved the weakly determined terms by several sigmas, more
the more points.)

**Block means.** A stream's series holds the mean of each short block of samples. While the sensor
turns, a block's samples lie on an arc and their mean inside the ellipsoid: exactly,
``|W d_mean|^2 = n^2 - mean_i |W (d_i - d_mean)|^2`` when every ``|W d_i| = n``. Given each block's spread
``s = mean_i |v_i - v_mean|^2`` (``spread``), a point is fitted to the norm ``sqrt(n^2 - k^2 s)`` (``k`` the
prior's matrix scale: ``W`` is ``k I`` up to a few per cent, and the correction itself is small). Ignored,
the shrinkage follows the turn and tilt rates: on the ground-robot generator at 20 deg tilt (blocks of
0.2 s, spreads up to 3 uT rms) it put the heading error at 30 deg near 2 deg; corrected, 0.4 deg.
Each point's norm is then ``n_i = sqrt(n^2 - s_i')`` with ``s_i' = k^2 s_i`` (``norm_spreads``), and
``dr / dn = -(|y| / |q|) n / n_i``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError
from .fitting_core import unpack

__all__ = ["block_means", "geometric", "norm_spreads"]

Array = NDArray[np.float64]

_OFF_J, _OFF_K = [0, 0, 1], [1, 2, 2]  # (x, y), (x, z), (y, z): the off-diagonal entries of W


def block_means(xyz: ArrayLike, k: int) -> tuple[Array, Array]:
    """Means of consecutive blocks of ``k`` samples (the first ``len % k`` dropped) and each block's spread,
    the mean squared distance of its samples from their mean: (N, 3) and (N,)."""
    pts = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    blocks = pts[len(pts) % k:].reshape(-1, k, 3)
    means = blocks.mean(axis=1)
    dev = blocks - means[:, None]
    return means, np.einsum("ijk,ijk->i", dev, dev) / k


def norm_spreads(spread: ArrayLike | None, m: int, matrix: ArrayLike, n0: float) -> Array | None:
    """The block spreads in calibrated units squared (``k^2 spread``, ``k`` the mean diagonal of ``matrix``, the
    prior's), at most three quarters of the squared norm ``n0^2`` (module docstring); None for single samples.

    Raises:
        InputError: not ``m`` finite non-negative numbers.
    """
    if spread is None:
        return None
    sp = np.asarray(spread, dtype=np.float64).reshape(-1)
    if sp.size != m or not np.all(np.isfinite(sp)) or np.any(sp < 0):
        msg = f"spread must hold {m} finite non-negative numbers, one per point"
        raise InputError(msg)
    k = float(np.mean(np.abs(np.diag(np.asarray(matrix, dtype=np.float64)))))
    return np.minimum(k * k * sp, 0.75 * n0 * n0)


def geometric(z: Array, theta: Array, n: float, sp: Array | None = None) -> tuple[Array, Array]:
    """Geometric residuals (raw units) of the points ``z`` (3, N) and their exact transposed Jacobian (P, N)
    (module docstring); a tenth parameter is the norm (which then replaces ``n``); ``sp``: block spreads
    (``norm_spreads``), each point's norm then ``sqrt(n^2 - sp)``."""
    b, mat = unpack(theta[:9], "sym")
    n_given = float(theta[9]) if theta.size == 10 else n
    n = n_given if sp is None else np.sqrt(np.maximum(n_given * n_given - sp, 0.25 * n_given * n_given))
    d = z - b[:, None]
    y = mat @ d  # W d
    q = mat @ y  # W^2 d: |W u| = |q| / |y|
    a = mat @ q
    rho = np.sqrt(np.einsum("in,in->n", y, y))
    qn = np.maximum(np.sqrt(np.einsum("in,in->n", q, q)), 1e-300)
    r = (rho - n) * rho / qn
    alpha = (2.0 * rho - n) / (np.maximum(rho, 1e-300) * qn)  # dr = alpha (y . dy) - beta (q . dq)
    beta = r / (qn * qn)
    jt = np.empty((theta.size, z.shape[1]))
    jt[:3] = beta * (mat @ a) - alpha * q
    jt[3:6] = alpha * y * d - beta * (q * y + a * d)
    jk, kk = _OFF_J, _OFF_K
    jt[6:9] = (alpha * (y[jk] * d[kk] + y[kk] * d[jk])
               - beta * (q[jk] * y[kk] + q[kk] * y[jk] + a[jk] * d[kk] + a[kk] * d[jk]))
    if theta.size == 10:
        jt[9] = -rho / qn if sp is None else -(rho / qn) * (n_given / n)
    return r, jt
