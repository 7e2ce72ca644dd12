"""Closed-form and enclosing ellipsoid fits: sphere, LinAutoCalibration, algebraic quadric, MVEE.

All work on centred points ``z`` (3, N) of unit RMS radius (``fitting_core.prepare``) and return the
centre ``o`` and the shape in ``z`` units; ``fitting.fit`` turns them into a ``Calibration``.

**Sphere (Gietzelt Eqs. 5-12).** ``|v_i - o|^2 = r^2`` (5) is linear in ``A = |o|^2 - r^2`` and
``(B, C, D) = -2 o`` (7a-d): ``A + B v_x + C v_y + D v_z = E_i = -|v_i|^2`` (8, 9). The least-squares
normal equations (10, 11) give ``o`` and ``r = sqrt(|o|^2 - A)`` (12). On centred data (``sum z_i = 0``)
the normal matrix of Eq. 11 is block diagonal, ``[[N, 0], [0, z z^T]]``: ``A = sum E_i / N`` and
``(B, C, D) = (z z^T)^-1 z E``, with the scatter ``z z^T`` the geometry check has already formed.

**LinAutoCalibration (Gietzelt Eqs. 13-17).** With ``o`` from the sphere step, ``X_i = (v_x - o_x)^2``
etc. (14a-c) and ``t = 1/s^2`` (15a-c), Eq. 1 becomes ``t_x X_i + t_y Y_i + t_z Z_i = 1`` (13); its
normal equations (16, 17) give the radii ``s``, hence ``W = n diag(1/s)``. It is exact only when the
true ellipsoid is a sphere (step 1 assumes equal radii); with unequal radii ``o`` is biased.
``lin_auto_fit`` also returns the residuals and the Gauss-Newton covariance from the rows it already
holds: for diagonal ``W`` with ``d_i = z_i - o`` and ``rho_i = |W d_i|``, the Jacobian rows are
``dr_i/db_j = -w_j^2 d_ij / rho_i`` and ``dr_i/dw_j = w_j X_ij / rho_i`` (Camps Eqs. 4-5), so
``J^T J = D (K K^T) D`` with ``K = [d; X] / rho`` and ``D = diag(-w^2, w)``.

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
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.blas import idamax

from .errors import ConvergenceError, DegenerateDataError
from .fitting_core import check_singular, gn_covariance, gram, solve_spd3

__all__ = ["algebraic", "lin_auto", "lin_auto_fit", "mvee", "sphere", "sqrt_pd"]

Array = NDArray[np.float64]

_MVEE_ACCEPT = 1e-4  # optimality gap accepted when Khachiyan stalls on a degenerate support


def sphere(z: Array, scatter: list[list[float]], scratch: Array | None = None) -> tuple[Array, float]:
    """Gietzelt step 1, Eqs. 5-12: centre ``o`` and radius ``r`` of the best sphere (``scatter = z z^T``
    as nested lists, ``fitting_core.Prepared``).

    ``scratch``, if given, is a (3, N) buffer it may overwrite (saves an allocation).
    """
    o, r2 = _sphere_centre(z, scatter, scratch)
    return np.array(o), math.sqrt(r2)


def _sphere_centre(z: Array, s: list[list[float]], scratch: Array | None) -> tuple[list[float], float]:
    """Centre and squared radius of the sphere fit from the scatter ``s`` as nested lists (no numpy scalars).

    One pass: the third moments ``sum_i z_ij z_ik^2`` give ``z E'`` with ``E'_i = |z_i|^2 = -E_i`` (Eq. 8),
    and on centred data of unit RMS radius ``sum_i |z_i|^2 = tr(z z^T)`` gives ``A`` without a pass.
    """
    sq = np.multiply(z, z, out=scratch)
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = gram(z, sq).tolist()  # sum_i z_ij z_ik^2
    bx, by, bz = solve_spd3(s, [a0 + a1 + a2, b0 + b1 + b2, c0 + c1 + c2])  # -(B, C, D), Eq. 11 (block diagonal)
    o = [0.5 * bx, 0.5 * by, 0.5 * bz]  # o = -(B, C, D) / 2, Eq. 7b-d
    r2 = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + (s[0][0] + s[1][1] + s[2][2]) / z.shape[1]  # Eq. 12
    if not r2 > 0:
        msg = "sphere fit found no real radius (|o|^2 - A <= 0); the points do not lie on a closed surface"
        raise DegenerateDataError(msg)
    return o, r2


def lin_auto(z: Array, scatter: list[list[float]]) -> tuple[Array, list[float], Array]:
    """Gietzelt LinAutoCalibration, Eqs. 13-17: centre ``o`` (step 1), ``t = 1/s^2`` (step 2), and the rows.

    ``scatter = z z^T`` as nested lists. The rows are ``[d; X]`` (6, N): ``d_i = z_i - o`` and its squares
    ``X_i, Y_i, Z_i`` (Eq. 14a-c).
    """
    n_pts = z.shape[1]
    rows = np.empty((6, n_pts))
    d, xyz = rows[:3], rows[3:]
    s = scatter
    o, _ = _sphere_centre(z, s, xyz)
    oa = np.array(o)
    np.subtract(z, oa[:, None], out=d)
    np.multiply(d, d, out=xyz)  # X_i, Y_i, Z_i, Eq. 14a-c
    # right-hand side of Eq. 17: sum_i X_i = sum_i (z_ix - o_x)^2 = scatter_xx + N o_x^2 (centred z)
    rhs = [s[0][0] + n_pts * o[0] * o[0], s[1][1] + n_pts * o[1] * o[1], s[2][2] + n_pts * o[2] * o[2]]
    t = solve_spd3(xyz @ xyz.T, rhs)  # Eq. 17 (numpy's syrk, not gram: lm starts here and keeps its rounding)
    if min(t) <= 0:
        msg = f"LinAutoCalibration step 2 found t = 1/s^2 <= 0 ({t}): not an ellipsoid; cover more directions"
        raise DegenerateDataError(msg)
    return oa, t, rows


def lin_auto_fit(
    z: Array, scatter: list[list[float]], n: float, sc: float
) -> tuple[list[float], float, float, Array | None]:  # fmt: skip
    """LinAutoCalibration (diag model) with its residual statistics and Gauss-Newton covariance (module docstring).

    ``scatter = z z^T`` as nested lists and ``sc`` the scale of ``z`` (``fitting_core.prepare``): the
    covariance comes out in raw units.

    Returns:
        ``theta = (o, w)`` as a list, with ``W = diag(w) = n diag(1/s)`` (Eq. 15a-c); ``r^T r`` and
        ``max |r_i|`` of the residuals ``r_i = |W d_i| - n``; ``s^2 (J^T J)^-1`` in raw units (None when
        there are no more points than the 6 parameters).

    Raises:
        ConvergenceError: W is singular (condition above 1e10, as ``fitting_core.abs_model``).
    """
    n_pts = z.shape[1]
    o, t, rows = lin_auto(z, scatter)
    tx, ty, tz = t
    w = [n * math.sqrt(tx), n * math.sqrt(ty), n * math.sqrt(tz)]  # > 0: lin_auto checked t > 0
    check_singular(max(w) / max(min(w), 1e-300), "lin_auto")
    w2 = [n * n * tx, n * n * ty, n * n * tz]
    rho = np.dot(w2, rows[3:])  # (np.dot takes the list as it is: no array built first)
    np.sqrt(rho, out=rho)  # |W d_i| = sqrt(sum_j w_j^2 X_ij) for diagonal W
    theta = o.tolist() + w
    if n_pts <= 6:
        r = rho - n
        return theta, float(r @ r), abs(float(r[idamax(r)])), None
    np.maximum(rho, 1e-300, out=rho)  # a point at the centre (d_i = 0): K_i = 0 below, not 0 / 0
    rows /= rho  # K = [d; X] / rho
    r = np.subtract(rho, n, out=rho)  # the residuals, in place (rho is not needed any more)
    rr = float(r @ r)  # and max |r_i| below by BLAS idamax: one call, not a min and a max
    # J^T J = D (K K^T) D with D = diag(-w^2, w), so s^2 (J^T J)^-1 = s^2 D^-1 (K K^T)^-1 D^-1: D joins the
    # scaling to raw units (fitting_core.raw_scale) in gn_covariance, with no pass over the (6, N) rows
    scale = [-sc / w2[0], -sc / w2[1], -sc / w2[2], 1.0 / (sc * w[0]), 1.0 / (sc * w[1]), 1.0 / (sc * w[2])]
    return theta, rr, abs(float(r[idamax(r)])), gn_covariance(gram(rows), rr / (n_pts - 6), scale)


def algebraic(z: Array) -> tuple[Array, Array]:
    """General quadric ``z^T M z + 2 g^T z = 1`` by least squares -> centre ``o`` and ``A`` (Gietzelt Eq. 2)."""
    x, y, w = z
    d = np.stack([x * x, y * y, w * w, 2 * x * y, 2 * x * w, 2 * y * w, 2 * x, 2 * y, 2 * w])
    try:
        p = np.linalg.solve(gram(d), d.sum(axis=1))
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


def mvee(z: Array, tol: float, max_iter: int) -> tuple[Array, Array, int]:
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


def sqrt_pd(a: Array) -> Array:
    """Symmetric square root of a positive-definite matrix (``W = A^(1/2)``, Gietzelt Eq. 2); NaN entries,
    without a runtime warning, when ``A`` is not positive definite (the points fit no ellipsoid: the caller's
    finite check refuses the fit)."""
    ev, vec = np.linalg.eigh(0.5 * (a + a.T))
    with np.errstate(invalid="ignore"):
        return (vec * np.sqrt(ev)) @ vec.T
