"""Ellipsoid fitting: from raw readings of a constant-norm field to a ``Calibration``.

Model (``calibration.py``): a raw reading is ``v = W^-1 h + b + e`` with ``|h| = n``, so a fit seeks the
offset ``b`` and the matrix ``W`` that make every calibrated norm ``|W (v_i - b)|`` equal to ``n``.
One entry point, ``fit(points, model, method, norm, loss)``; models and the methods that serve them
(the closed-form and enclosing fits live in ``fitting_linear``, the shared pieces in ``fitting_core``):

============  =====================  ===================================================================
method        models                 what it solves
============  =====================  ===================================================================
``sphere``    eye                    Gietzelt 2013 step 1 (Eqs. 5-12), linear sphere fit
``lin_auto``  eye, diag              Gietzelt 2013 LinAutoCalibration, steps 1 and 2 (Eqs. 5-17)
``lm``        eye, diag, sym         Camps 2009 Levenberg-Marquardt on the norm residual (Eqs. 2, 4-7)
``algebraic`` sym                    general quadric least squares (Merayo 2000 / MgnCalibration)
``mvee``      sym                    Khachiyan minimum-volume enclosing ellipsoid (Bonnet 2009)
============  =====================  ===================================================================

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

**Scale.** A given ``norm`` fixes the scale of ``W``. With ``norm=None`` the shape is fitted with the
scale-free relative residual ``|W d_i| / n0 - 1`` (``n0`` from the start value), and the result is
scaled so that ``det(W) = 1`` (W keeps raw units); ``norm`` is then the estimated field radius.

**Uncertainty.** ``covariance = s^2 (J^T J)^-1`` with ``s^2 = sum r_i^2 / (N - P)`` and ``J`` the
norm-residual Jacobian at the solution, over ``parameter_names`` (with ``norm=None`` it is mapped to
the det(W) = 1 parameters plus ``norm``, rank P). For ``sphere``, ``lin_auto`` and ``algebraic`` it
is the same Gauss-Newton covariance evaluated at their solution (``lin_auto`` forms ``J`` from the rows
``d_i``, ``X_i`` it already holds, ``fitting_linear.lin_auto_fit``): cheap, but it describes an efficient
estimator, so it understates their spread when their estimates are less efficient (see the bench).
``mvee`` is not a least-squares estimator and reports no covariance. Robust fits use the loss-weighted
Jacobian ``sqrt(rho') J`` and a MAD estimate of ``s``; their default ``f_scale`` is two MAD-sigmas of the residuals,
re-estimated after each robust solve until it settles (the start may be pulled by the outliers).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.blas import idamax

from .calibration import MODELS, Calibration
from .errors import ConfigError, ConvergenceError, DegenerateDataError, RunawayError, as_points
from .fitting_core import (
    N_PARAMS,
    Prepared,
    abs_model,
    finish,
    gn_covariance,
    gram,
    mad_sigma,
    pack,
    parameter_names,
    prepare,
    raw_scale,
    resjac,
    unpack,
)
from .fitting_linear import algebraic, lin_auto, lin_auto_fit, mvee, sphere, sqrt_pd

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

_F_SCALE_SIGMAS = 2.0  # default robust scale, in MAD-sigmas of the residuals
_REAL, _INT = (int, float, np.floating), (int, np.integer)  # accepted types of norm and max_iter


def residuals(cal: Calibration, points: ArrayLike) -> Array:
    """Norm residuals ``|W (v - b)| - norm`` of ``points`` under ``cal`` (output units)."""
    return cal.norm_error(as_points(points))


# -- checks ---------------------------------------------------------------------------------------


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
    if norm is not None and not (isinstance(norm, _REAL) and math.isfinite(norm) and norm > 0):
        msg = f"norm must be a positive finite number or None (estimate it), got {norm!r}"
        raise ConfigError(msg)
    if f_scale is not None and not (math.isfinite(f_scale) and f_scale > 0):
        msg = f"f_scale must be a positive finite number, got {f_scale!r}"
        raise ConfigError(msg)
    if isinstance(max_iter, bool) or not isinstance(max_iter, _INT) or max_iter < 1:
        msg = f"max_iter must be a positive integer, got {max_iter!r}"
        raise ConfigError(msg)


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


RUNAWAY_AXIS_RATIO = 5.0
"""A fit out of iterations whose ``W`` has axes further apart than this is running away, not converging slowly: soft
iron leaves real sensors' axes within 1.5 of each other."""

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
    msg = (f"{what} did not converge in {max_iter} iterations (cost {cost:.4g}); raise max_iter "
           "(replay/calibrate: --set max_iter=...) or check the data for outliers")
    raise _OutOfIterations(msg, x)


class _OutOfIterations(ConvergenceError):
    """``_lm`` ran out of iterations at ``iterate``: ``_ran_away`` tells a runaway from a slow fit."""

    def __init__(self, msg: str, iterate: Array) -> None:
        super().__init__(msg)
        self.iterate = iterate


def _ran_away(exc: ConvergenceError, model: str, what: str) -> ConvergenceError:
    """``exc`` of a fit out of iterations, re-worded when its last iterate is no sensor's ellipsoid (``W`` not positive
    definite, or axes ``RUNAWAY_AXIS_RATIO`` apart): more iterations would not help (a cap of 5-30 deg of the sphere,
    or BROAD's magnet 1 cm from the sensor, run away so)."""
    if not isinstance(exc, _OutOfIterations) or not np.isfinite(exc.iterate).all():
        return exc
    mat = unpack(exc.iterate, model)[1]
    sv = np.linalg.svd(mat, compute_uv=False)
    ratio = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    positive = bool(np.linalg.det(mat) > 0)
    if positive and ratio <= RUNAWAY_AXIS_RATIO:
        return exc
    shape = f"axes {ratio:.3g} times apart" if positive else "W not positive definite"
    return RunawayError(f"{what} did not converge: it ran away to no sensor's ellipsoid ({shape}), more iterations "
                        "will not help; the readings cover too few directions, or lie on no one ellipsoid (a "
                        "magnetometer's: iron or a magnet moving near it)")


def _start(prep: Prepared, model: str, init: str | Calibration | None) -> Array:
    """Start of lm with ``|W (z - b)| ~ 1``: LinAutoCalibration, Campolo's rule or a given Calibration."""
    z, m, sc = prep.z, prep.m, prep.sc
    if isinstance(init, Calibration):
        mat = init.matrix * (sc / init.norm)
        return pack((init.offset - m) / sc, 0.5 * (mat + mat.T), model)
    if init not in (None, "lin_auto", "campolo"):
        msg = f"init must be 'lin_auto', 'campolo' or a Calibration, got {init!r}"
        raise ConfigError(msg)
    if init != "campolo":
        try:
            if model == "eye":
                o, r = sphere(z, prep.scatter)
                return np.append(o, 1.0 / r)
            o, t, _ = lin_auto(z, prep.scatter)
            return pack(o, np.diag(np.sqrt(t)), model)  # W = diag(1/s), s = t^(-1/2) (Eq. 15a-c)
        except (DegenerateDataError, np.linalg.LinAlgError):
            _log.debug("lin_auto start failed; using Campolo's rule")
    r = float(np.mean(np.sqrt(np.einsum("in,in->n", z, z))))  # Campolo: centre = mean (0 here), Gietzelt Eq. 4
    return pack(np.zeros(3), np.eye(3) / r, model)


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
    b, mat = unpack(theta, model)
    y = mat @ (z - b[:, None])
    u = y / np.maximum(np.sqrt(np.einsum("in,in->n", y, y)), 1e-300)
    a = mat @ u  # W^T u_i (W symmetric)
    g = np.einsum("in,in->n", a, a)  # |W^T u_i|^2
    s2 = float(r @ r) / float(g.sum()) * nobs / (nobs - npar)
    c = s2 * (float(np.sum(mat * mat)) - g) / (2.0 * n)
    h = 1e-4  # z has unit RMS radius
    jt_h = resjac(z + h * a, theta, model, n)[1]
    ef = jt @ c + (s2 / h) * (jt_h - jt).sum(axis=1)
    try:
        return np.linalg.solve(gram(jt), ef)
    except np.linalg.LinAlgError:
        return None


def _fit_lm(
    prep: Prepared, model: str, n_int: float, scale_free: bool, loss: str, f_scale: float | None,
    init: str | Calibration | None, max_iter: int,
) -> tuple[Array, Array, Array, int, Array | None]:  # fmt: skip
    z, sc = prep.z, prep.sc
    theta0 = _start(prep, model, init)
    theta0[3:] *= n_int

    def fun(t: Array) -> tuple[Array, Array]:
        return resjac(z, t, model, n_int)

    if loss == "linear":
        theta, r, jt, _, it = _lm(fun, theta0, max_iter)
        delta = _bias_correction(z, theta, model, r, jt, n_int)
        if delta is not None:
            theta = theta + delta
            r, jt = fun(theta)
        return theta, r, jt, it, None
    # f_scale is in output units; internal residuals are output residuals times c = det(W)^(1/3)
    c0 = float(np.cbrt(np.linalg.det(unpack(theta0, model)[1]))) / sc if scale_free else 1.0
    if f_scale is not None:
        theta, r, jt, w, it = _lm(fun, theta0, max_iter, loss=loss, f_scale=f_scale * c0)
        return theta, r, jt, it, w
    floor = 1e-9 * n_int  # default: two MAD-sigmas of the residuals, re-estimated until it settles
    scale = max(_F_SCALE_SIGMAS * mad_sigma(fun(theta0)[0]), floor)
    total = 0
    for _ in range(5):
        theta0, r, jt, w, it = _lm(fun, theta0, max_iter, loss=loss, f_scale=scale)
        total += it
        new_scale = max(_F_SCALE_SIGMAS * mad_sigma(r), floor)
        if abs(new_scale - scale) <= 0.1 * scale:
            break
        scale = new_scale
    return theta0, r, jt, total, w


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
    prep = prepare(points, N_PARAMS[model])
    scale_free = norm is None
    n_int = 1.0 if norm is None else float(norm)
    iterations, cov = 0, None
    if method == "lin_auto" and model == "diag":  # residuals and covariance from the rows it already holds
        params, rr, max_abs, cov = lin_auto_fit(prep.z, prep.scatter, n_int, prep.sc)  # a singular W is rejected
    else:
        if method == "lm":
            try:
                theta, r, jt, iterations, robust = _fit_lm(prep, model, n_int, scale_free, loss, f_scale, init, max_iter)
            except ConvergenceError as exc:
                raise _ran_away(exc, model, "lm" if loss == "linear" else f"lm with loss {loss!r}") from exc
            if not np.isfinite(theta).all():
                msg = "lm diverged to non-finite parameters; check the data for outliers or use a robust loss"
                raise ConvergenceError(msg)
        else:
            theta, iterations = _closed_form(prep, model, method, n_int, max_iter)
            robust = None
            r, jt = resjac(prep.z, theta, model, n_int)
        fixed = abs_model(theta, model, method)
        if fixed is not theta:
            theta = fixed
            r, jt = resjac(prep.z, theta, model, n_int)
        rr = float(r @ r)
        if method != "mvee" and prep.n_points > theta.size:
            jw = jt if robust is None else jt * np.sqrt(robust)
            sigma2 = rr / (prep.n_points - theta.size) if robust is None else mad_sigma(r) ** 2
            cov = gn_covariance(gram(jw), sigma2, raw_scale(prep.sc, theta.size))
        params, max_abs = theta.tolist(), abs(float(r[idamax(r)]))  # BLAS: index of the largest |r_i|
    _log.debug("fit %s/%s: n=%d iterations=%d", method, model, prep.n_points, iterations)  # stats: cal.stats
    return finish(
        prep, params, rr, max_abs, cov, model=model, method=method, n_int=n_int, scale_free=scale_free,
        iterations=iterations, sensor=sensor, unit=unit,
    )  # fmt: skip


def _closed_form(prep: Prepared, model: str, method: str, n_int: float, max_iter: int) -> tuple[Array, int]:
    """Parameter vector (and iterations) of ``mvee``, ``algebraic``, or ``sphere`` (also ``lin_auto`` for eye)."""
    z, iterations = prep.z, 0
    if method == "mvee":
        o, a, iterations = mvee(z, 1e-11, 200 * max_iter)
        mat = sqrt_pd(a)
    elif method == "algebraic":
        o, a = algebraic(z)
        mat = sqrt_pd(a)
    else:  # sphere, and lin_auto for the eye model (its step 1)
        o, rad = sphere(z, prep.scatter)
        mat = np.eye(3) / rad
    return pack(o, n_int * mat, model), iterations
