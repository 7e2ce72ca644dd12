"""What every fit shares: parameter vectors, the norm residual and its Jacobian, checks, the result.

The fits work on centred, scaled points ``z = (v - m) / sc`` (shape (3, N), unit RMS radius), with
the parameter vector ``theta = (b, W entries)`` of ``parameter_names`` and ``|W (z_i - b)| ~ n``.
``prepare`` checks the points once (shape, finiteness, geometry), ``finish`` maps a solution and its
Gauss-Newton covariance ``s^2 (J^T J)^-1`` (``fitting`` module docstring) back to raw units and builds
the ``Calibration``; the small 3x3 systems are solved in closed form (a LAPACK call costs more).

Products ``a b^T`` of wide (P, N) rows (the scatter ``z z^T``, normal matrices ``J J^T``) go through
``gram``: numpy sends ``a @ a.T`` to BLAS ``syrk``, which OpenBLAS runs 3-6x slower than ``gemm`` for
these shapes, and a copy to avoid it costs a pass; scipy's ``dgemm`` on the transposed (Fortran-ordered)
views needs neither (N = 1000, P = 6: 2.5 us against 9.6 us for ``syrk``; N = 100: 0.8 against 1.4 us).
One exception, ``X X^T`` in ``fitting_linear.lin_auto`` (Eq. 17), stays numpy's ``syrk``: lm starts from
that solution, and gemm's different rounding would move lm's result within its stopping tolerance.
The per-call overhead matters at N = 100 (a fit takes tens of microseconds), so the small results
(the mean in ``prepare``, ``finish``, the closed-form 3x3 solves) are computed on Python floats, not numpy
scalars, and the largest residual of a fit is BLAS ``idamax`` (one call, not numpy's abs and max).
"""

from __future__ import annotations

import math
import time
from typing import cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.blas import dgemm
from scipy.linalg.lapack import dposv

from .calibration import Calibration, FitStats
from .errors import ConvergenceError, DegenerateDataError, as_points

__all__ = [
    "N_PARAMS", "OFF", "Prepared", "abs_model", "check_geometry", "check_singular", "finish", "gn_covariance",
    "gram", "mad_sigma", "pack", "parameter_names", "prepare", "raw_scale", "resjac", "solve_spd3", "unpack"
]

Array = NDArray[np.float64]

N_PARAMS = {"eye": 4, "diag": 6, "sym": 9}
OFF = ((0, 1), (0, 2), (1, 2))
_B_NAMES = ("b_x", "b_y", "b_z")
_W_NAMES = {"eye": ("w",), "diag": ("w_xx", "w_yy", "w_zz"), "sym": ("w_xx", "w_yy", "w_zz", "w_xy", "w_xz", "w_yz")}
_OFF_J, _OFF_K = np.array([0, 0, 1]), np.array([1, 2, 2])
_F64 = np.dtype(np.float64)
_COPLANAR_RTOL = 1e-6
_MAX_COND = 1e10  # condition of a fitted W beyond which the fit is called singular
_SINGULAR_MSG = "the normal equations are singular: the points do not determine the fit; cover more directions"


def parameter_names(model: str, scale_free: bool) -> tuple[str, ...]:
    """Names of the fitted parameters, in covariance order (``norm`` last when it is estimated)."""
    if scale_free:
        return (*_B_NAMES, *(_W_NAMES[model] if model != "eye" else ()), "norm")
    return _B_NAMES + _W_NAMES[model]


def gram(a: Array, b: Array | None = None) -> Array:
    """``a b^T`` (default ``a a^T``) of C-ordered rows (P, N) and (Q, N), as a Fortran-ordered (P, Q) array.

    BLAS ``dgemm`` on ``a.T``, ``b.T`` (Fortran-ordered views: no copy), not numpy's ``syrk`` (module docstring).
    """
    return cast(Array, dgemm(1.0, a.T, (a if b is None else b).T, trans_a=1))


# -- parameter vectors <-> (b, W) ----------------------------------------------------------------


def unpack(theta: Array, model: str) -> tuple[Array, Array]:
    """``(b, W)`` of a parameter vector."""
    b = theta[:3]
    if model == "sym":
        w = theta[3:]
        mat = np.array([[w[0], w[3], w[4]], [w[3], w[1], w[5]], [w[4], w[5], w[2]]])
    elif model == "diag":
        mat = np.diag(theta[3:6])
    else:
        mat = theta[3] * np.eye(3)
    return b, mat


def pack(b: Array, mat: Array, model: str) -> Array:
    """Parameter vector of ``(b, W)`` (the model's entries of W)."""
    if model == "sym":
        w = [mat[0, 0], mat[1, 1], mat[2, 2], mat[0, 1], mat[0, 2], mat[1, 2]]
    elif model == "diag":
        w = [mat[0, 0], mat[1, 1], mat[2, 2]]
    else:
        w = [float(np.trace(mat)) / 3.0]
    return np.concatenate([b, np.asarray(w, dtype=np.float64)])


def resjac(z: Array, theta: Array, model: str, n: float) -> tuple[Array, Array]:
    """Residuals ``r_i = |W d_i| - n`` and the transposed analytic Jacobian (P, N) (Camps Eqs. 4-5)."""
    b, mat = unpack(theta, model)
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


def abs_model(theta: Array, model: str, method: str) -> Array:
    """The positive-definite W with the same norms ``|W d|`` (removes the sign ambiguity of lm).

    Raises:
        ConvergenceError: W is singular (condition above 1e10).
    """
    if model != "sym":
        w = theta[3:].tolist()
        fixed = theta if min(w) > 0 else np.concatenate([theta[:3], np.abs(theta[3:])])
        cond = max(map(abs, w)) / max(min(map(abs, w)), 1e-300)
    else:
        b, mat = unpack(theta, model)
        ev, vec = np.linalg.eigh(mat)
        aev = np.abs(ev)
        cond = float(aev.max() / max(aev.min(), 1e-300))
        fixed = theta if ev.min() > 0 else pack(b, (vec * aev) @ vec.T, model)
    check_singular(cond, method)
    return fixed


def check_singular(cond: float, method: str) -> None:
    """Reject a fitted W whose condition number ``cond`` exceeds 1e10 (ConvergenceError)."""
    if cond > _MAX_COND:
        msg = f"{method} produced a singular matrix (condition {cond:.3g}); cover more directions"
        raise ConvergenceError(msg)


# -- checks ---------------------------------------------------------------------------------------


class Prepared:
    """Centred, scaled points: ``z = (v - m) / sc`` as contiguous rows (3, N) and their scatter ``z z^T``
    (3x3, nested lists of floats: its users work on Python floats)."""

    __slots__ = ("m", "n_points", "sc", "scatter", "z")

    def __init__(self, z: Array, m: Array, sc: float, scatter: list[list[float]]) -> None:
        self.z, self.m, self.sc, self.scatter, self.n_points = z, m, sc, scatter, z.shape[1]


def prepare(points: ArrayLike, n_params: int) -> Prepared:
    """Validate the points once (shape, finiteness, geometry) and centre and scale them.

    Raises:
        InputError: wrong shape, NaN or Inf.
        DegenerateDataError: too few, identical, collinear or coplanar points.
    """
    v = points if isinstance(points, np.ndarray) else None
    fast = v is not None and v.dtype == _F64 and v.ndim == 2 and v.shape[1] == 3 and v.shape[0] > 0
    if v is None or not fast:
        v = as_points(points, "points")  # the careful path: raises InputError with the details
    n_pts = v.shape[0]
    z: Array = np.array(v.T, order="C")  # (3, N): contiguous rows make every pass cheap
    s0, s1, s2 = np.add.reduce(z, axis=1).tolist()
    mean = [s0 / n_pts, s1 / n_pts, s2 / n_pts]  # on Python floats: the same IEEE division, less overhead
    if fast and not math.isfinite(s0 + s1 + s2):  # a NaN or Inf makes its row sum non-finite
        as_points(points, "points")  # the careful path: raises InputError with the details
    m = np.array(mean)
    z -= m[:, None]  # centred: the fits are translation invariant
    s = gram(z).tolist()  # z z^T
    sc2 = (s[0][0] + s[1][1] + s[2][2]) / n_pts
    sc = math.sqrt(sc2)
    check_geometry(n_pts, s, max(abs(mean[0]), abs(mean[1]), abs(mean[2]), sc, 1e-300), n_params)
    z *= 1.0 / sc  # unit RMS radius: well-conditioned normal equations (Gietzelt Eqs. 11, 17)
    (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = s
    scatter = [[s00 / sc2, s01 / sc2, s02 / sc2], [s10 / sc2, s11 / sc2, s12 / sc2], [s20 / sc2, s21 / sc2, s22 / sc2]]
    return Prepared(z, m, sc, scatter)


def check_geometry(n: int, scatter: Array | list[list[float]], scale: float, n_params: int) -> None:
    """Too few, identical, collinear or coplanar points -> DegenerateDataError (singular values of centred
    points; ``scatter`` is their 3x3 scatter, an array or nested lists)."""
    if n < n_params:
        msg = f"points: {n} given but this model has {n_params} parameters; collect at least {n_params} (better 10x more)"
        raise DegenerateDataError(msg)
    if _clearly_solid(scatter, scale):
        return
    sv = np.sqrt(np.clip(np.linalg.eigvalsh(np.asarray(scatter)), 0.0, None))  # ascending
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


def _clearly_solid(scatter: Array | list[list[float]], scale: float) -> bool:
    """True when the invariants of the scatter prove every singular-value ratio above 1e-5 (no eigensolver).

    With eigenvalues ``l0 <= l1 <= l2``: ``tr >= l2``, ``c2 = sum of principal 2x2 minors`` lies in
    ``[l1 l2, 3 l1 l2]`` and ``det = l0 l1 l2``, so ``l1 / l2 >= c2 / (3 tr^2)`` and ``l0 / l2 >= det / (c2 tr)``.
    The bounds are used only far above rounding; anything closer goes to ``np.linalg.eigvalsh``.
    """
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = scatter.tolist() if isinstance(scatter, np.ndarray) else scatter
    tr = a00 + a11 + a22
    c2 = a00 * a11 - a01 * a01 + a00 * a22 - a02 * a02 + a11 * a22 - a12 * a12
    det = a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02) + a02 * (a01 * a12 - a11 * a02)
    return tr > 3e-24 * scale * scale and c2 > 3e-10 * tr * tr and det > 1e-10 * c2 * tr and det > 1e-12 * tr * tr * tr


def solve_spd3(a: Array | list[list[float]], b: Array | list[float]) -> list[float]:
    """``A^-1 b`` for a symmetric positive-definite 3x3 ``A`` by Cholesky (closed form, no LAPACK call).

    ``A`` and ``b`` may be arrays or (nested) lists of floats.

    Raises:
        DegenerateDataError: ``A`` is not positive definite (singular normal equations).
    """
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = a.tolist() if isinstance(a, np.ndarray) else a
    b0, b1, b2 = b.tolist() if isinstance(b, np.ndarray) else b
    if not a00 > 0.0:
        raise DegenerateDataError(_SINGULAR_MSG)
    l00 = math.sqrt(a00)
    l10, l20 = a01 / l00, a02 / l00
    d1 = a11 - l10 * l10
    if not d1 > 1e-14 * a11:
        raise DegenerateDataError(_SINGULAR_MSG)
    l11 = math.sqrt(d1)
    l21 = (a12 - l20 * l10) / l11
    d2 = a22 - l20 * l20 - l21 * l21
    if not d2 > 1e-14 * a22:
        raise DegenerateDataError(_SINGULAR_MSG)
    l22 = math.sqrt(d2)
    y0 = b0 / l00  # L y = b
    y1 = (b1 - l10 * y0) / l11
    y2 = (b2 - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22  # L^T x = y
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    return [x0, x1, x2]


# -- uncertainty and the result ---------------------------------------------------------------------


def mad_sigma(r: Array) -> float:
    """Robust standard deviation of ``r``: 1.4826 times the median absolute deviation."""
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def gn_covariance(jtj: Array, sigma2: float, scale: list[float] | None = None) -> Array | None:
    """``s^2 E (J^T J)^-1 E`` with ``E = diag(scale)`` (default the identity), or None when ``J^T J`` is
    not positive definite (singular).

    ``scale`` maps the covariance to other units (``raw_scale``) or undoes a diagonal scaling of ``J``.
    LAPACK's Cholesky solve ``dposv`` against ``s E``: the same inverse as ``np.linalg.inv`` for a symmetric
    positive-definite matrix, at a third of the call overhead for these small matrices; one product
    with ``s E`` from the other side completes it.
    """
    p = jtj.shape[0]
    s = math.sqrt(sigma2)
    diag = np.zeros(p * p)  # s E, flat
    diag[:: p + 1] = [s] * p if scale is None else [s * x for x in scale]
    _, cov, info = dposv(jtj, diag.reshape(p, p))  # s (J^T J)^-1 E, in Fortran order
    if info != 0:
        return None
    cov_t = cov.T  # C-ordered view (cheaper to broadcast over)
    cov_t *= diag[:: p + 1]  # s^2 E (J^T J)^-1 E, symmetric
    return cast(Array, cov)  # float64 in, float64 out


def raw_scale(sc: float, n_par: int) -> list[float]:
    """Factors from internal to raw parameter units: ``b = m + sc b_z`` and ``W = W_z / sc``."""
    return [sc, sc, sc] + [1.0 / sc] * (n_par - 3)


def scale_free_map(w_v: Array, mat_v: Array, model: str, n_int: float) -> tuple[float, Array]:
    """c = det(W)^(1/3) and the Jacobian of (b, W/c, n/c) w.r.t. (b, W) (Jacobi's formula for dc)."""
    c = float(np.cbrt(np.linalg.det(mat_v)))
    winv = np.linalg.inv(mat_v)
    if model == "eye":
        dtr = [float(np.trace(winv))]
    else:
        dtr = [winv[0, 0], winv[1, 1], winv[2, 2]] + ([2 * winv[j, k] for j, k in OFF] if model == "sym" else [])
    dc = (c / 3.0) * np.asarray(dtr)  # dc/dw = c/3 tr(W^-1 dW/dw)
    p = 3 + w_v.size
    rows = p if model == "eye" else p + 1
    t = np.zeros((rows, p))
    t[:3, :3] = np.eye(3)
    if model != "eye":
        t[3:p, 3:] = np.eye(p - 3) / c - np.outer(w_v, dc) / c**2
    t[rows - 1, 3:] = -n_int * dc / c**2
    return c, t


def finish(
    prep: Prepared, theta: list[float], rr: float, max_abs: float, cov: Array | None, *, model: str, method: str,
    n_int: float, scale_free: bool, iterations: int, sensor: str, unit: str,
) -> Calibration:  # fmt: skip
    """The Calibration of an internal solution: back to raw units (``b = m + sc b_z``, ``W = W_z / sc``),
    the scale-free convention when the norm was estimated, residual statistics and covariance.

    ``theta`` is the parameter vector as a list of floats (the small arrays are built from them), ``rr``
    and ``max_abs`` are ``r^T r`` and ``max |r_i|`` of its residuals. ``theta`` must have passed
    ``abs_model`` (W positive definite, not singular) and ``cov`` must be in raw units (``gn_covariance``
    with ``raw_scale``) and new (it is frozen in place): the Calibration is built without re-validating them.
    """
    sc, n_pts = prep.sc, prep.n_points
    m0, m1, m2 = prep.m.tolist()
    b = np.array([m0 + sc * theta[0], m1 + sc * theta[1], m2 + sc * theta[2]])
    w = [x / sc for x in theta[3:]]
    if model == "sym":
        mat = np.array([[w[0], w[3], w[4]], [w[3], w[1], w[5]], [w[4], w[5], w[2]]])
    else:
        mat = np.zeros((3, 3))
        mat[0, 0], mat[1, 1], mat[2, 2] = w if model == "diag" else w * 3
    est_norm = n_int
    if scale_free:
        c, tmap = scale_free_map(np.array(w), mat, model, n_int)
        mat, est_norm, rr, max_abs = mat / c, n_int / c, rr / (c * c), max_abs / c
        if cov is not None:
            cov = tmap @ cov @ tmap.T
    rms = math.sqrt(rr / n_pts)
    stats = FitStats._trusted(n_pts, rms, max_abs, rms / est_norm, int(iterations), True, 0.5 * rr)
    return Calibration._trusted(
        offset=b,
        matrix=mat,
        norm=est_norm,
        model=model,
        method=method,
        sensor=sensor,
        unit=unit,
        stats=stats,
        covariance=cov,
        parameter_names=parameter_names(model, scale_free) if cov is not None else (),
        stamp=time.time(),
    )
