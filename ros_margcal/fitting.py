"""Ellipsoid fitting: from raw readings of a constant-norm field to a ``Calibration``.

Model (``calibration.py``): a raw reading is ``v = W^-1 h + b + e`` with ``|h| = n``, so a fit seeks the
offset ``b`` and the matrix ``W`` that make every calibrated norm ``|W (v_i - b)|`` equal to ``n``.
One entry point, ``fit(points, model, method, norm, loss)``; models and the methods that serve them:

============  =====================  ===================================================================
method        models                 what it solves
============  =====================  ===================================================================
``sphere``    eye                    Gietzelt 2013 step 1 (Eqs. 5-12), linear sphere fit
``lin_auto``  eye, diag              Gietzelt 2013 LinAutoCalibration, steps 1 and 2 (Eqs. 5-17)
``lm``        eye, diag, sym         Camps 2009 Levenberg-Marquardt on the norm residual (Eqs. 2, 4-7)
``algebraic`` sym                    general quadric least squares (Merayo 2000 / MgnCalibration)
``mvee``      sym                    Khachiyan minimum-volume enclosing ellipsoid (Bonnet 2009)
============  =====================  ===================================================================

**Sphere (Gietzelt Eqs. 5-12).** ``|v_i - o|^2 = r^2`` (5) is linear in ``A = |o|^2 - r^2`` and
``(B, C, D) = -2 o`` (7a-d): ``A + B v_x + C v_y + D v_z = E_i = -|v_i|^2`` (8, 9). The least-squares
normal equations (10, 11) give ``o`` and ``r = sqrt(|o|^2 - A)`` (12). The data are shifted by their
mean and scaled first (the fit is translation invariant), which keeps Eq. 11 well conditioned.

**LinAutoCalibration (Gietzelt Eqs. 13-17).** With ``o`` from the sphere step, ``X_i = (v_x - o_x)^2``
etc. (14a-c) and ``t = 1/s^2`` (15a-c), Eq. 1 becomes ``t_x X_i + t_y Y_i + t_z Z_i = 1`` (13); its
normal equations (16, 17) give the radii ``s``, hence ``W = n diag(1/s)``. It is exact only when the
true ellipsoid is a sphere (step 1 assumes equal radii); with unequal radii ``o`` is biased.

**Levenberg-Marquardt (Camps Eqs. 4-7).** Camps minimise ``S(p) = sum e_p(t)^2`` (7) over the
offset and the gain matrix, linearising ``e_{p+q} = e_p + J q`` (4, 5) and solving
``(J^T J + lambda D) q = -J^T e`` (Marquardt's damping, with ``D = diag(J^T J)``). We use the norm
residual ``r_i = |W d_i| - n`` with ``d_i = v_i - b`` (the square root of Camps' Eq. 2/7 residual,
whose noise is nearly homoscedastic, so the least-squares solution is close to maximum likelihood).
With ``y_i = W d_i`` and ``u_i = y_i / |y_i|`` the analytic Jacobian is

    dr_i/db = -u_i^T W,   dr_i/dW_jj = u_ij d_ij,   dr_i/dW_jk = u_ij d_ik + u_ik d_ij  (j != k),

for the 9 parameters of the symmetric model (Camps Eq. 6, ``W = alpha^-1``), the 6 of the diagonal
model (Camps Eq. 1) and ``dr_i/dk = |d_i|`` for ``W = k I``. The start is LinAutoCalibration, or
Campolo's rule (Gietzelt Eq. 4: centre = mean, ``r`` = mean distance) with ``init="campolo"``.
The compact numpy LM below is, at N = 1000 (sym), about as fast as scipy's MINPACK ``lm`` with the
same analytic Jacobian and about 3x faster than scipy's ``trf``; it has an explicit stopping rule
(relative step 1e-8) and hands back the final J for the covariance. Robust losses (scipy's
``soft_l1``, ``huber``, ``cauchy``: cost ``sum f^2 rho((r_i / f)^2)``) run in the same LM as
iteratively reweighted least squares with weights ``rho'((r_i / f)^2)``.

**Bias correction.** The noise sits in the points, not in the residual, so the least-squares solution
carries an O(sigma^2) bias that does not shrink with N (noisy norms are inflated by about
``sigma^2 / n``, and the Jacobian is correlated with the noise). After the plain-loss fit, ``lm``
estimates this bias from the fit itself and subtracts it (``_bias_correction``); at N = 1000 and 2 %
noise this brings the RMSE of the gains from about 1.15 to 1.0 times the Cramér-Rao bound.

**Algebraic (Merayo).** On shifted, scaled data, ``v^T M v + 2 g^T v = 1`` is linear in the six
entries of the symmetric ``M`` and the three of ``g``. Then ``o = -M^-1 g`` and
``(v - o)^T A (v - o) = 1`` with ``A = M / (1 + o^T M o)`` (Gietzelt Eq. 2); ``A`` must be positive
definite (an ellipsoid), and ``W = n A^(1/2)``.

**MVEE (Khachiyan, Todd & Yildirim 2007).** Weights ``u`` on the lifted points ``q_i = (v_i, 1)``;
each step moves weight towards the point with the largest ``q_i^T X^-1 q_i`` (``X = Q diag(u) Q^T``),
with Todd-Yildirim drop steps, and a Newton solve of the optimality conditions once the support is small; then
``c = sum u_i v_i`` and ``A = (V diag(u) V^T - c c^T)^-1 / 3``. It stops at an optimality gap of 1e-11, or
accepts a gap <= 1e-4 when the first-order steps stall after ``200 max_iter`` steps (far below the noise).
It encloses the noise, so its radii are biased outwards by about the noise amplitude.

**Scale.** A given ``norm`` fixes the scale of ``W``. With ``norm=None`` the shape is fitted with the
scale-free relative residual ``|W d_i| / n0 - 1`` (``n0`` from the start value), and the result is
scaled so that ``det(W) = 1`` (W keeps raw units); ``norm`` is then the estimated field radius.

**Uncertainty.** ``covariance = s^2 (J^T J)^-1`` with ``s^2 = sum r_i^2 / (N - P)`` and ``J`` the
norm-residual Jacobian at the solution, over ``parameter_names`` (with ``norm=None`` it is mapped to
the det(W) = 1 parameters plus ``norm``, rank P). For ``sphere``, ``lin_auto`` and ``algebraic`` it
is the same Gauss-Newton covariance evaluated at their solution: cheap, but it describes an efficient
estimator, so it understates their spread when their estimates are less efficient (see the bench).
``mvee`` is not a least-squares estimator and reports no covariance. Robust fits use the loss-weighted
Jacobian ``sqrt(rho') J`` and a MAD estimate of ``s``; their default ``f_scale`` is two MAD-sigmas of the residuals,
re-estimated after each robust solve until it settles (the start may be pulled by the outliers).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .calibration import MODELS, Calibration, FitStats
from .errors import ConfigError, ConvergenceError, DegenerateDataError, as_points

__all__ = ["LOSSES", "METHODS", "SUPPORTED", "fit", "parameter_names", "residuals"]

_log = logging.getLogger(__name__)

Array = NDArray[np.float64]
ResJac = Callable[[Array], tuple[Array, Array]]

METHODS = ("sphere", "lin_auto", "lm", "algebraic", "mvee")
LOSSES = ("linear", "soft_l1", "huber", "cauchy")
SUPPORTED: dict[str, tuple[str, ...]] = {
    "sphere": ("eye",),
    "lin_auto": ("eye", "diag"),
    "lm": ("eye", "diag", "sym"),
    "algebraic": ("sym",),
    "mvee": ("sym",),
}
"""Models each method can produce."""

_N_PARAMS = {"eye": 4, "diag": 6, "sym": 9}
_B_NAMES = ("b_x", "b_y", "b_z")
_W_NAMES = {"eye": ("w",), "diag": ("w_xx", "w_yy", "w_zz"), "sym": ("w_xx", "w_yy", "w_zz", "w_xy", "w_xz", "w_yz")}
_OFF = ((0, 1), (0, 2), (1, 2))
_OFF_J, _OFF_K = np.array([0, 0, 1]), np.array([1, 2, 2])
_COPLANAR_RTOL = 1e-6
_MVEE_ACCEPT = 1e-4  # optimality gap accepted when Khachiyan stalls on a degenerate support
_F_SCALE_SIGMAS = 2.0  # default robust scale, in MAD-sigmas of the residuals


def residuals(cal: Calibration, points: ArrayLike) -> Array:
    """Norm residuals ``|W (v - b)| - norm`` of ``points`` under ``cal`` (output units)."""
    return cal.norm_error(as_points(points))


def parameter_names(model: str, scale_free: bool) -> tuple[str, ...]:
    """Names of the fitted parameters, in covariance order (``norm`` last when it is estimated)."""
    if scale_free:
        return (*_B_NAMES, *(_W_NAMES[model] if model != "eye" else ()), "norm")
    return _B_NAMES + _W_NAMES[model]


# -- parameter vectors <-> (b, W) ----------------------------------------------------------------


def _unpack(theta: Array, model: str) -> tuple[Array, Array]:
    b = theta[:3]
    if model == "sym":
        w = theta[3:]
        mat = np.array([[w[0], w[3], w[4]], [w[3], w[1], w[5]], [w[4], w[5], w[2]]])
    elif model == "diag":
        mat = np.diag(theta[3:6])
    else:
        mat = theta[3] * np.eye(3)
    return b, mat


def _pack(b: Array, mat: Array, model: str) -> Array:
    if model == "sym":
        w = [mat[0, 0], mat[1, 1], mat[2, 2], mat[0, 1], mat[0, 2], mat[1, 2]]
    elif model == "diag":
        w = [mat[0, 0], mat[1, 1], mat[2, 2]]
    else:
        w = [float(np.trace(mat)) / 3.0]
    return np.concatenate([b, np.asarray(w, dtype=np.float64)])


def _resjac(z: Array, theta: Array, model: str, n: float) -> tuple[Array, Array]:
    """Residuals ``r_i = |W d_i| - n`` and the transposed analytic Jacobian (P, N) (Camps Eqs. 4-5)."""
    b, mat = _unpack(theta, model)
    d = z - b[:, None]
    y = mat @ d  # W d_i as columns
    rho = np.sqrt(np.einsum("in,in->n", y, y))
    u = y / np.maximum(rho, 1e-300)
    jt = np.empty((theta.size, z.shape[1]))
    np.matmul(-mat, u, out=jt[:3])  # dr/db = -u^T W (W symmetric)
    if model == "eye":
        np.divide(rho, theta[3], out=jt[3])  # dr/dk = |d|
    else:
        np.multiply(u, d, out=jt[3:6])  # dr/dW_jj = u_j d_j
        if model == "sym":  # dr/dW_jk = u_j d_k + u_k d_j for (j, k) = (x, y), (x, z), (y, z)
            np.multiply(u[_OFF_J], d[_OFF_K], out=jt[6:9])
            jt[6:9] += u[_OFF_K] * d[_OFF_J]
    return rho - n, jt


# -- checks ---------------------------------------------------------------------------------------


def _as_points_fast(points: ArrayLike) -> Array:
    if isinstance(points, np.ndarray) and points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == 3:
        if points.shape[0] > 0 and math.isfinite(float(points.sum())):
            return points
    return as_points(points, "points")  # the careful path: raises InputError with the details


def _check_geometry(z: Array, scatter: Array, scale: float, n_params: int) -> None:
    """Too few, identical, collinear or coplanar points -> DegenerateDataError (singular values of centred points)."""
    n = z.shape[1]
    if n < n_params:
        msg = f"points: {n} given but this model has {n_params} parameters; collect at least {n_params} (better 10x more)"
        raise DegenerateDataError(msg)
    sv = np.sqrt(np.clip(np.linalg.eigvalsh(scatter), 0.0, None))  # ascending
    if sv[2] <= 1e-12 * scale:
        msg = f"points: all {n} points are identical (spread {sv[2]:.3g}); rotate the sensor through many directions"
        raise DegenerateDataError(msg)
    if sv[1] <= _COPLANAR_RTOL * sv[2]:
        msg = f"points are collinear (singular values {sv[::-1].tolist()}); rotate the sensor about more than one axis"
        raise DegenerateDataError(msg)
    if sv[0] <= _COPLANAR_RTOL * sv[2]:
        msg = (
            f"points are coplanar (smallest/largest singular value {sv[0] / sv[2]:.2g}); "
            "an ellipsoid needs directions out of one plane, rotate about another axis"
        )
        raise DegenerateDataError(msg)


def _check_options(model: str, method: str, norm: float | None, loss: str, f_scale: float | None, max_iter: int) -> None:
    if model not in MODELS:
        msg = f"model must be one of {MODELS}, got {model!r}"
        raise ConfigError(msg)
    if method not in METHODS:
        msg = f"method must be one of {METHODS}, got {method!r}"
        raise ConfigError(msg)
    if model not in SUPPORTED[method]:
        msg = f"method {method!r} cannot fit model {model!r}; it supports {SUPPORTED[method]} (method 'lm' fits any model)"
        raise ConfigError(msg)
    if loss not in LOSSES:
        msg = f"loss must be one of {LOSSES}, got {loss!r}"
        raise ConfigError(msg)
    if loss != "linear" and method != "lm":
        msg = f"robust loss {loss!r} needs method 'lm' (method {method!r} is a closed-form fit)"
        raise ConfigError(msg)
    if norm is not None and not (isinstance(norm, int | float | np.floating) and math.isfinite(norm) and norm > 0):
        msg = f"norm must be a positive finite number or None (estimate it), got {norm!r}"
        raise ConfigError(msg)
    if f_scale is not None and not (math.isfinite(f_scale) and f_scale > 0):
        msg = f"f_scale must be a positive finite number, got {f_scale!r}"
        raise ConfigError(msg)
    if isinstance(max_iter, bool) or not isinstance(max_iter, int | np.integer) or max_iter < 1:
        msg = f"max_iter must be a positive integer, got {max_iter!r}"
        raise ConfigError(msg)


# -- closed-form fits (on centred data z, unit RMS radius; return b and W with |W (z - b)| ~ 1) -----


def _sphere(z: Array) -> tuple[Array, float]:
    """Gietzelt step 1, Eqs. 5-12: centre ``o`` and radius ``r`` of the best sphere."""
    n = z.shape[1]
    e = -(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])  # E_i, Eq. 8
    a1 = np.empty((4, n))  # rows (1, v_x, v_y, v_z) of Eq. 9
    a1[0] = 1.0
    a1[1:] = z
    sol = np.linalg.solve(a1 @ a1.T, a1 @ e)  # normal equations (Eq. 11) of Eq. 10
    o = -0.5 * sol[1:]  # Eq. 7b-d
    r2 = float(o @ o - sol[0])  # Eq. 12
    if not r2 > 0:
        msg = "sphere fit found no real radius (|o|^2 - A <= 0); the points do not lie on a closed surface"
        raise DegenerateDataError(msg)
    return o, math.sqrt(r2)


def _lin_auto(z: Array) -> tuple[Array, Array]:
    """Gietzelt LinAutoCalibration, Eqs. 13-17: centre ``o`` (step 1) and radii ``s`` (step 2)."""
    o, _ = _sphere(z)
    xyz = z - o[:, None]
    xyz *= xyz  # X_i, Y_i, Z_i, Eq. 14a-c
    t = np.linalg.solve(xyz @ xyz.T, xyz.sum(axis=1))  # Eq. 17
    if (t <= 0).any():
        msg = f"LinAutoCalibration step 2 found t = 1/s^2 <= 0 ({t.tolist()}): not an ellipsoid; cover more directions"
        raise DegenerateDataError(msg)
    return o, 1.0 / np.sqrt(t)  # s from t, Eq. 15a-c


def _algebraic(z: Array) -> tuple[Array, Array]:
    """General quadric ``z^T M z + 2 g^T z = 1`` by least squares -> centre ``o`` and ``A`` (Gietzelt Eq. 2)."""
    x, y, w = z
    d = np.stack([x * x, y * y, w * w, 2 * x * y, 2 * x * w, 2 * y * w, 2 * x, 2 * y, 2 * w])
    try:
        p = np.linalg.solve(d @ d.T, d.sum(axis=1))
    except np.linalg.LinAlgError as exc:
        msg = "algebraic fit: the quadric is not determined by these points (singular normal matrix); cover more directions"
        raise DegenerateDataError(msg) from exc
    mq = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    o = -np.linalg.solve(mq, p[6:9])
    k = 1.0 + float(o @ mq @ o)
    ev = np.linalg.eigvalsh(mq / k) if k > 0 else np.array([-1.0])
    if ev.min() <= 0:
        msg = f"algebraic fit: the quadric is not an ellipsoid (eigenvalues {np.round(ev, 6).tolist()}); check for outliers"
        raise DegenerateDataError(msg)
    return o, mq / k


def _mvee(z: Array, tol: float, max_iter: int) -> tuple[Array, Array, int]:
    """Khachiyan's MVEE with Todd-Yildirim drop steps: centre and ``A`` with ``(z-c)^T A (z-c) <= 1``."""
    n, dim = z.shape[1], 3
    q = np.vstack([z, np.ones(n)])  # lifted points q_i = (z_i, 1), (4, n)
    u = np.full(n, 1.0 / n)
    xinv = np.linalg.inv((q * u) @ q.T)
    mdist = np.einsum("in,ij,jn->n", q, xinv, q)  # q_i^T X^-1 q_i
    it = 0
    while it < max_iter:
        it += 1
        if it % 100 == 0:  # refresh (rank-one updates accumulate rounding error) and try to finish by Newton
            polished = _mvee_newton(q, u, tol)
            if polished is not None:
                u = polished
                break
            xinv = np.linalg.inv((q * u) @ q.T)
            mdist = np.einsum("in,ij,jn->n", q, xinv, q)
        j = int(np.argmax(mdist))
        mp = np.where(u > 0, mdist, np.inf)
        k = int(np.argmin(mp))
        up, down = mdist[j] - (dim + 1), (dim + 1) - mp[k]
        if max(up, down) <= tol * (dim + 1):
            break
        if up >= down:  # Khachiyan step towards the farthest point
            i, tau = j, up / ((dim + 1) * (mdist[j] - 1))
        else:  # Todd-Yildirim drop step away from the nearest supported point
            i = k
            tau = max(-down / ((dim + 1) * (mp[k] - 1)), -u[k] / (1 - u[k]))
        xq = xinv @ q[:, i]
        zq = xq @ q  # q_l^T X^-1 q_i for all l
        den = 1 - tau + tau * mdist[i]
        xinv = (xinv - (tau / den) * np.outer(xq, xq)) / (1 - tau)  # Sherman-Morrison update of X^-1
        mdist = (mdist - (tau / den) * zq * zq) / (1 - tau)
        u *= 1 - tau
        u[i] = max(u[i] + tau, 0.0)
    if it >= max_iter and max(up, down) > _MVEE_ACCEPT * (dim + 1):
        msg = f"mvee did not converge in {max_iter} iterations (optimality gap {max(up, down) / (dim + 1):.2g}); use method 'lm'"
        raise ConvergenceError(msg)
    c = z @ u
    a = np.linalg.inv((z * u) @ z.T - np.outer(c, c)) / dim
    return c, a, it


def _mvee_newton(q: Array, u: Array, tol: float) -> Array | None:
    """Finish the MVEE on the current support: Newton on ``q_i^T X(u)^-1 q_i = d + 1`` (optimality).

    Points whose weight Newton drives to zero leave the support; None when this does not settle.
    """
    dim1 = q.shape[0]
    sup = np.flatnonzero(u > 1e-9 * u.max())
    if sup.size > 6 * dim1:
        return None  # support not yet identified; keep taking Khachiyan steps
    us = u[sup].copy()
    for _ in range(40):
        qs = q[:, sup]
        xinv = np.linalg.inv((qs * us) @ qs.T)
        g = qs.T @ xinv @ qs
        f = np.diag(g) - dim1
        if np.abs(f).max() <= 1e-3 * tol:
            break
        step = np.linalg.lstsq(g * g, f, rcond=None)[0]  # d f_i / d u_k = -(q_i^T X^-1 q_k)^2
        new = us + step
        keep = new > 0
        if not keep.all():  # an active-set step: drop the points Newton wants to leave
            if keep.sum() < dim1:
                return None
            sup, us = sup[keep], us[keep] / us[keep].sum()
            continue
        us = new
    else:
        return None
    out = np.zeros_like(u)
    out[sup] = us / us.sum()
    mdist = np.einsum("in,ij,jn->n", q, np.linalg.inv((q * out) @ q.T), q)
    return out if mdist.max() <= dim1 * (1 + tol) else None


def _sqrt_pd(a: Array) -> Array:
    ev, vec = np.linalg.eigh(0.5 * (a + a.T))
    return (vec * np.sqrt(ev)) @ vec.T


def _abs_model(theta: Array, model: str) -> tuple[Array, float]:
    """The positive-definite W with the same norms ``|W d|`` (removes the sign ambiguity of lm), and cond(W)."""
    if model != "sym":
        w = np.abs(theta[3:])
        return (theta if (theta[3:] > 0).all() else np.concatenate([theta[:3], w])), float(w.max() / max(w.min(), 1e-300))
    b, mat = _unpack(theta, model)
    ev, vec = np.linalg.eigh(mat)
    aev = np.abs(ev)
    cond = float(aev.max() / max(aev.min(), 1e-300))
    if ev.min() > 0:
        return theta, cond
    return _pack(b, (vec * aev) @ vec.T, model), cond


# -- Levenberg-Marquardt ------------------------------------------------------------------------


def _rho(loss: str, zz: Array) -> tuple[Array, Array]:
    """scipy's robust loss ``rho(z)`` and ``rho'(z)`` of ``z = (r / f_scale)^2``."""
    if loss == "soft_l1":
        t = np.sqrt(1.0 + zz)
        return 2.0 * (t - 1.0), 1.0 / t
    if loss == "huber":
        big = zz > 1.0
        sq = np.sqrt(np.where(big, zz, 1.0))
        return np.where(big, 2.0 * sq - 1.0, zz), np.where(big, 1.0 / sq, 1.0)
    if loss == "cauchy":
        return np.log1p(zz), 1.0 / (1.0 + zz)
    return zz, np.ones_like(zz)


def _lm(
    fun: ResJac, x0: Array, max_iter: int, xtol: float = 1e-8, loss: str = "linear", f_scale: float = 1.0
) -> tuple[Array, Array, Array, Array, int]:
    """Compact Levenberg-Marquardt, ``(J^T J + lambda diag(J^T J)) q = -J^T r`` (Camps Sec. 4, Marquardt 1963).

    A robust loss minimises ``sum f^2 rho((r_i / f)^2)`` by reweighting: each step solves the weighted
    system with ``w_i = rho'((r_i / f)^2)`` (iteratively reweighted least squares, damped the same way).
    Returns the solution, residuals, transposed Jacobian, the weights at the solution, and iterations.
    """
    f2 = f_scale * f_scale

    def evaluate(x: Array) -> tuple[Array, Array, float, Array]:
        r, jt = fun(x)
        if loss == "linear":
            return r, jt, float(r @ r), np.ones_like(r)
        rho, w = _rho(loss, r * r / f2)
        return r, jt, f2 * float(rho.sum()), w

    x = x0.copy()
    r, jt, cost, w = evaluate(x)
    jw = jt * w
    a, g = jw @ jt.T, jw @ r
    lam, nu = 1e-4, 2.0
    for it in range(1, max_iter + 1):
        dg = np.maximum(np.diag(a), 1e-300)
        step = np.linalg.solve(a + np.diag(lam * dg), -g)
        x_new = x + step
        r_new, jt_new, cost_new, w_new = evaluate(x_new)
        if cost_new <= cost:  # accept (NaN compares False)
            pred = float(step @ (lam * dg * step - g))  # decrease predicted by the (weighted) linearisation
            ratio = (cost - cost_new) / pred if pred > 0 else 0.0
            small = bool(np.all(np.abs(step) <= xtol * (np.abs(x) + xtol)))
            gain = cost - cost_new
            x, r, jt, cost, w = x_new, r_new, jt_new, cost_new, w_new
            jw = jt * w
            a, g = jw @ jt.T, jw @ r
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
            nu = 2.0
            if small or gain <= 1e-14 * cost or cost == 0.0:
                return x, r, jt, w, it
        else:
            lam *= nu
            nu *= 2.0
            if lam > 1e12:  # no step decreases the cost: a minimum to machine precision
                return x, r, jt, w, it
    what = "lm" if loss == "linear" else f"lm with loss {loss!r}"
    msg = f"{what} did not converge in {max_iter} iterations (cost {cost:.4g}); raise max_iter or check the data for outliers"
    raise ConvergenceError(msg)


def _mad_sigma(r: Array) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def _start(z: Array, model: str, init: str | Calibration | None, m: Array, sc: float) -> Array:
    """Start of lm with ``|W (z - b)| ~ 1``: LinAutoCalibration, Campolo's rule or a given Calibration."""
    if isinstance(init, Calibration):
        mat = init.matrix * (sc / init.norm)
        return _pack((init.offset - m) / sc, 0.5 * (mat + mat.T), model)
    if init not in (None, "lin_auto", "campolo"):
        msg = f"init must be 'lin_auto', 'campolo' or a Calibration, got {init!r}"
        raise ConfigError(msg)
    if init != "campolo":
        try:
            if model == "eye":
                o, r = _sphere(z)
                return np.append(o, 1.0 / r)
            o, s = _lin_auto(z)
            return _pack(o, np.diag(1.0 / s), model)
        except (DegenerateDataError, np.linalg.LinAlgError):
            _log.debug("lin_auto start failed; using Campolo's rule")
    r = float(np.mean(np.sqrt(np.einsum("in,in->n", z, z))))  # Campolo: centre = mean (0 here), Gietzelt Eq. 4
    return _pack(np.zeros(3), np.eye(3) / r, model)


def _bias_correction(z: Array, theta: Array, model: str, r: Array, jt: Array, n: float) -> Array | None:
    """Second-order bias of the least-squares solution, removed after the fit (errors in the points).

    With ``v_i = v0_i + e_i``, ``e_i ~ N(0, s^2 I)``, the residual is ``r_i = c_i + a_i^T e_i + ...`` with
    ``a_i = W^T u_i`` and the norm inflation ``c_i = (tr S - u_i^T S u_i) / (2 n)``, ``S = s^2 W W^T``;
    the Jacobian row is ``g_i + G_i e_i``. The normal equations ``sum r_i g_i(e) = 0`` then have the
    expectation ``E F = sum_i c_i g_i + s^2 G_i a_i`` at the truth, so ``E[theta_hat - theta] =
    -(J^T J)^-1 E F`` (an O(s^2) bias that does not shrink with N). ``G_i a_i`` is a directional
    derivative of the Jacobian, taken by moving the points along ``a_i``; ``s^2`` comes from the
    residuals, whose variance is ``s^2 |W^T u_i|^2``.
    """
    nobs, npar = r.size, theta.size
    if nobs <= npar or not float(r @ r) > 0:
        return None
    b, mat = _unpack(theta, model)
    y = mat @ (z - b[:, None])
    u = y / np.maximum(np.sqrt(np.einsum("in,in->n", y, y)), 1e-300)
    a = mat @ u  # W^T u_i (W symmetric)
    g = np.einsum("in,in->n", a, a)  # |W^T u_i|^2
    s2 = float(r @ r) / float(g.sum()) * nobs / (nobs - npar)
    c = s2 * (float(np.sum(mat * mat)) - g) / (2.0 * n)
    h = 1e-4  # z has unit RMS radius
    jt_h = _resjac(z + h * a, theta, model, n)[1]
    ef = jt @ c + (s2 / h) * (jt_h - jt).sum(axis=1)
    try:
        return np.linalg.solve(jt @ jt.T, ef)
    except np.linalg.LinAlgError:
        return None


def _fit_lm(
    z: Array, model: str, n_int: float, scale_free: bool, loss: str, f_scale: float | None, init: str | Calibration | None,
    max_iter: int, m: Array, sc: float,
) -> tuple[Array, Array, Array, int, Array | None]:  # fmt: skip
    theta0 = _start(z, model, init, m, sc)
    theta0[3:] *= n_int

    def fun(t: Array) -> tuple[Array, Array]:
        return _resjac(z, t, model, n_int)

    if loss == "linear":
        theta, r, jt, _, it = _lm(fun, theta0, max_iter)
        delta = _bias_correction(z, theta, model, r, jt, n_int)
        if delta is not None:
            theta = theta + delta
            r, jt = fun(theta)
        return theta, r, jt, it, None
    # f_scale is in output units; internal residuals are output residuals times c = det(W)^(1/3)
    c0 = float(np.cbrt(np.linalg.det(_unpack(theta0, model)[1]))) / sc if scale_free else 1.0
    if f_scale is not None:
        theta, r, jt, w, it = _lm(fun, theta0, max_iter, loss=loss, f_scale=f_scale * c0)
        return theta, r, jt, it, w
    floor = 1e-9 * n_int  # default: two MAD-sigmas of the residuals, re-estimated until it settles
    scale = max(_F_SCALE_SIGMAS * _mad_sigma(fun(theta0)[0]), floor)
    total = 0
    for _ in range(5):
        theta0, r, jt, w, it = _lm(fun, theta0, max_iter, loss=loss, f_scale=scale)
        total += it
        new_scale = max(_F_SCALE_SIGMAS * _mad_sigma(r), floor)
        if abs(new_scale - scale) <= 0.1 * scale:
            break
        scale = new_scale
    return theta0, r, jt, total, w


def _scale_free_map(w_v: Array, mat_v: Array, model: str, n_int: float) -> tuple[float, Array]:
    """c = det(W)^(1/3) and the Jacobian of (b, W/c, n/c) w.r.t. (b, W) (Jacobi's formula for dc)."""
    c = float(np.cbrt(np.linalg.det(mat_v)))
    winv = np.linalg.inv(mat_v)
    if model == "eye":
        dtr = [float(np.trace(winv))]
    else:
        dtr = [winv[0, 0], winv[1, 1], winv[2, 2]] + ([2 * winv[j, k] for j, k in _OFF] if model == "sym" else [])
    dc = (c / 3.0) * np.asarray(dtr)  # dc/dw = c/3 tr(W^-1 dW/dw)
    p = 3 + w_v.size
    rows = p if model == "eye" else p + 1
    t = np.zeros((rows, p))
    t[:3, :3] = np.eye(3)
    if model != "eye":
        t[3:p, 3:] = np.eye(p - 3) / c - np.outer(w_v, dc) / c**2
    t[rows - 1, 3:] = -n_int * dc / c**2
    return c, t


# -- the entry point -----------------------------------------------------------------------------


def fit(
    points: ArrayLike,
    model: str = "sym",
    method: str = "lm",
    norm: float | None = None,
    loss: str = "linear",
    *,
    f_scale: float | None = None,
    init: str | Calibration | None = None,
    max_iter: int = 100,
    sensor: str = "",
    unit: str = "",
) -> Calibration:
    """Fit offset and matrix so that the calibrated norms of ``points`` equal ``norm``.

    Args:
        points: raw readings, shape (n, 3), finite.
        model: ``"eye"`` (offset + one scale), ``"diag"`` (offset + gains) or ``"sym"`` (offset +
            symmetric matrix).
        method: one of ``METHODS``; ``SUPPORTED`` lists the models each method can fit.
        norm: reference norm of the calibrated vector; ``None`` estimates it and fixes det(W) = 1.
        loss: ``"linear"`` or a robust loss (``soft_l1``, ``huber``, ``cauchy``; method ``lm`` only).
        f_scale: residual (output units) beyond which a robust loss down-weights; default two
            MAD-sigmas of the residuals, re-estimated after each robust fit until it settles.
        init: start of ``lm``: ``"lin_auto"`` (default), ``"campolo"`` (Gietzelt Eq. 4) or a Calibration.
        max_iter: iteration limit of ``lm`` (``mvee`` takes up to 200 times as many cheap steps).
        sensor: copied into the result (``"mag"``, ``"accel"``).
        unit: unit of the calibrated output, copied into the result.

    Returns:
        The Calibration with ``stats``, ``covariance`` and ``parameter_names`` filled
        (``covariance`` is None for ``mvee`` and when there are no more points than parameters).

    Raises:
        ConfigError: unknown or unsupported option combination.
        InputError: points of the wrong shape or with NaN/Inf.
        DegenerateDataError: too few, identical, collinear or coplanar points; not an ellipsoid.
        ConvergenceError: ``lm`` or ``mvee`` did not converge.
    """
    _check_options(model, method, norm, loss, f_scale, max_iter)
    if init is not None and method != "lm":
        msg = f"init only applies to method 'lm', not {method!r}"
        raise ConfigError(msg)
    v = _as_points_fast(points)
    n_pts, n_par = v.shape[0], _N_PARAMS[model]
    z = np.array(v.T, order="C")  # (3, N): contiguous rows make every pass below cheap
    m = z.sum(axis=1) / n_pts
    z -= m[:, None]  # centred: the fits are translation invariant
    scatter = z @ z.T
    sc = math.sqrt(float(scatter[0, 0] + scatter[1, 1] + scatter[2, 2]) / n_pts)
    _check_geometry(z, scatter, max(float(np.abs(m).max()), sc, 1e-300), n_par)
    z *= 1.0 / sc  # unit RMS radius: well-conditioned normal equations (Eqs. 11, 17)
    scale_free = norm is None
    n_int = 1.0 if norm is None else float(norm)
    iterations, robust = 0, None  # robust: the loss weights rho'(z_i) at the solution

    if method == "lm":
        theta, r, jt, iterations, robust = _fit_lm(z, model, n_int, scale_free, loss, f_scale, init, max_iter, m, sc)
        if not np.isfinite(theta).all():
            msg = "lm diverged to non-finite parameters; check the data for outliers or use a robust loss"
            raise ConvergenceError(msg)
    else:
        if method == "mvee":
            o, a, iterations = _mvee(z, 1e-11, 200 * max_iter)
            mat = _sqrt_pd(a)
        elif method == "algebraic":
            o, a = _algebraic(z)
            mat = _sqrt_pd(a)
        elif model == "eye":
            o, rad = _sphere(z)
            mat = np.eye(3) / rad
        else:
            o, s = _lin_auto(z)
            mat = np.diag(1.0 / s)
        theta = _pack(o, n_int * mat, model)
        r, jt = _resjac(z, theta, model, n_int)
    fixed, cond = _abs_model(theta, model)
    if cond > 1e10:
        msg = f"{method} produced a singular matrix (condition {cond:.3g}); cover more directions"
        raise ConvergenceError(msg)
    if fixed is not theta:
        theta = fixed
        r, jt = _resjac(z, theta, model, n_int)

    # back to raw coordinates: b = m + sc b_z, W = W_z / sc
    b_z, mat_z = _unpack(theta, model)
    b, mat_v = m + sc * b_z, mat_z / sc
    w_v = theta[3:] / sc
    cov = None
    if method != "mvee" and n_pts > n_par:
        jw = jt if robust is None else jt * np.sqrt(robust)
        sigma2 = float(r @ r) / (n_pts - n_par) if robust is None else _mad_sigma(r) ** 2
        try:
            cov = sigma2 * np.linalg.inv(jw @ jw.T)
        except np.linalg.LinAlgError:
            cov = None
        if cov is not None:
            dsc = np.concatenate([np.full(3, sc), np.full(n_par - 3, 1.0 / sc)])
            cov *= np.outer(dsc, dsc)
    est_norm, mat = n_int, mat_v
    if scale_free:
        c, tmap = _scale_free_map(w_v, mat_v, model, n_int)
        mat, est_norm, r = mat_v / c, n_int / c, r / c
        if cov is not None:
            cov = tmap @ cov @ tmap.T
    rms = math.sqrt(float(r @ r) / n_pts)
    stats = FitStats(
        n_points=n_pts,
        rms=rms,
        max_abs=float(np.abs(r).max()),
        rms_relative=rms / est_norm,
        iterations=int(iterations),
        converged=True,
        cost=0.5 * float(r @ r),
    )
    _log.debug("fit %s/%s: n=%d rms=%.4g iterations=%d", method, model, n_pts, rms, iterations)
    return Calibration(
        offset=b,
        matrix=mat,
        norm=est_norm,
        model=model,
        method=method,
        sensor=sensor,
        unit=unit,
        stats=stats,
        covariance=None if cov is None else np.asarray(cov, dtype=np.float64),
        parameter_names=parameter_names(model, scale_free) if cov is not None else (),
        stamp=time.time(),
    )
