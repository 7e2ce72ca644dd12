"""Observability-aware fitting: the calibration as a maximum a posteriori estimate with a prior.

A robot seldom turns its sensor through every direction: a ground robot turns in yaw, so its data fix
the horizontal hard iron and the 2-D soft iron and say almost nothing of the vertical terms. A plain
least-squares fit of the 9-parameter model (``fitting.fit``) is then ill-posed and wanders; here the
fit starts from what is already known and updates only what the data determine.

**Model.** ``theta = (b_x, b_y, b_z, w_xx, w_yy, w_zz, w_xy, w_xz, w_yz)`` (``fitting_core``'s symmetric
parameter vector) with the reference norm ``n`` fixed, and the *geometric* residual

    r_i(theta) = (|W d_i| - n) / |W u_i|,   d_i = v_i - b,  u_i = W d_i / |W d_i|,

the norm residual of Camps et al. 2009 (Eqs. 2, 4-7) divided by its gradient in the raw reading, i.e.
the first-order distance of ``v_i`` from the ellipsoid in raw units, with white noise of standard
deviation ``sigma``, and a Gaussian prior ``theta ~ N(theta_0, P_0)``. The division matters on partial
coverage: the plain norm residual can be made small by flattening the ellipsoid across the data (a
cap or a ring of yaw-only data is fitted by a huge, flat ellipsoid far away whose gradient is small,
so its norm residuals are far below the noise), while the geometric residual cannot.

**Estimate.** The MAP estimate minimises

    S(theta) = sum_i r_i(theta)^2 / sigma^2 + (theta - theta_0)^T P_0^-1 (theta - theta_0),

solved as the stacked least-squares problem ``[r / sigma; L^T (theta - theta_0)]`` (``L L^T = P_0^-1``)
by MINPACK's Levenberg-Marquardt (scipy), with the Jacobian ``J_i = (dr_i^norm / d theta) / |W u_i|``
(the gradient's own change is second order at the solution), from the prior and from the centres of a
sphere of the prior's radius through the data (two on a ring, where the vertical centre is fixed by the
norm only up to its sign); the lowest posterior cost wins. ``sigma`` is re-estimated from the residuals
(MAD) between solves unless given. The posterior covariance is ``P = H^-1`` with
``H = J^T J / sigma^2 + P_0^-1`` at the solution (the information form of the Gauss-Newton step).

**What was updated.** For each parameter the data's share of the information is
``1 - P_kk / P0_kk``; a parameter whose posterior variance fell below ``UPDATED_VARIANCE_RATIO`` of its
prior variance (its standard deviation at least halved) counts as *updated*, the others as *from the
prior*: they keep the prior's value up to the coupling with the updated ones, and its uncertainty.

**Coloured noise.** Real sensors drift slowly (1/f noise); the weakly determined terms (the vertical
offset of near-level data) soak it up, and a white-noise covariance then understates their error several
times. For points in time order (``time_ordered=True``) the data information is the Newey-West
(heteroscedasticity and autocorrelation consistent) sandwich ``I_d = A S^-1 A`` with ``A = J^T J`` and
``S = sum_l w_l sum_i J_i r_i r_(i+l) J_(i+l)^T`` (Bartlett weights ``w_l = 1 - l / (L + 1)``, ``L`` the lag
at which the residual autocorrelation falls below 0.05): a direction fed by fast changes (yaw) keeps its
information, one fed by slow changes (tilt) loses what the slow noise can fake. The posterior is then
``(I_d + P_0^-1)^-1``. ``scripts/study_ground_robot.py`` measures how well the result predicts the heading
error on the independent generator.

**Prior.** The last accepted calibration with its covariance (inflated by ``inflate`` so the data can
move it), or, with none, ``broad_prior``: zero offset and identity matrix scaled to the data's mean
radius, with standard deviations ``BROAD_OFFSET_STD`` times the norm for the offset and
``BROAD_MATRIX_STD`` (relative) for the matrix entries: wide enough for any real hard and soft iron
(ArduPilot accepts offsets up to 1 800 mG, about 4 field norms), narrow enough to keep the unobserved
directions finite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from .calibration import Calibration, FitStats
from .errors import ConvergenceError, DegenerateDataError, InputError, as_points
from .fitting_core import mad_sigma, pack, parameter_names, resjac, unpack

__all__ = ["BROAD_MATRIX_STD", "BROAD_OFFSET_STD", "UPDATED_VARIANCE_RATIO", "PriorFit", "broad_prior", "fit_with_prior",
           "posterior_at"]

Array = NDArray[np.float64]

NAMES = parameter_names("sym", scale_free=False)
BROAD_OFFSET_STD = 5.0
"""Prior standard deviation of each offset component without a previous calibration, in field norms."""
BROAD_MATRIX_STD = 0.1
"""Prior standard deviation of each matrix entry without a previous calibration, relative to its scale."""
UPDATED_VARIANCE_RATIO = 0.25
"""A parameter is *updated* by the data when its posterior variance is below this share of the prior's."""
_MIN_SIGMA_REL = 1e-6


@dataclass(frozen=True)
class PriorFit:
    """A MAP fit: the calibration (posterior covariance attached) and which parameters the data set.

    Attributes:
        calibration: the estimate; ``covariance`` is the posterior over ``parameter_names``.
        prior: the prior calibration (its covariance the prior's).
        updated: names of the parameters the data determine.
        from_prior: names of the parameters that keep the prior (up to coupling).
        data_share: per parameter, ``1 - posterior variance / prior variance`` (0: prior only, 1: data only).
        sigma: the residual noise used to weigh the data against the prior.
        iterations: Levenberg-Marquardt iterations.
    """

    calibration: Calibration
    prior: Calibration
    updated: tuple[str, ...]
    from_prior: tuple[str, ...]
    data_share: dict[str, float]
    sigma: float
    iterations: int

    @property
    def partial(self) -> bool:
        """True when some parameters come from the prior."""
        return bool(self.from_prior)


def broad_prior(points: ArrayLike, norm: float, *, sensor: str = "", unit: str = "") -> Calibration:
    """The documented prior without a previous calibration: zero offset, isotropic matrix, broad covariance.

    The matrix is ``k I``: ``k = 1`` when the raw readings are in the unit of ``norm`` (the node's SI
    convention; detected as a data half-extent within ``1/5..5`` norms), else ``n / r`` with ``r`` the
    half-extent of the data along its widest axis (raw counts): a ring of yaw-only data has a radius of
    only the horizontal field, so no radius estimate is trusted where the unit already says the scale.
    """
    pts = as_points(points, "points")
    if not (math.isfinite(norm) and norm > 0):
        msg = f"norm must be a positive finite number, got {norm!r}"
        raise InputError(msg)
    centred = pts - pts.mean(axis=0)
    r = 0.5 * float(np.ptp(centred @ np.linalg.svd(centred, full_matrices=False)[2][0])) if len(pts) > 1 else 0.0
    k = 1.0 if r <= 0 or 0.2 <= norm / r <= 5.0 else norm / r
    std = np.r_[np.full(3, BROAD_OFFSET_STD * norm / k), np.full(6, BROAD_MATRIX_STD * k)]
    return Calibration(np.zeros(3), k * np.eye(3), norm=norm, model="sym", method="prior", sensor=sensor, unit=unit,
                       covariance=np.diag(std * std), parameter_names=NAMES)


def _prior_parts(prior: Calibration, inflate: float) -> tuple[Array, Array]:
    """``theta_0`` and the prior information matrix ``P_0^-1`` of a prior calibration."""
    theta0 = pack(prior.offset, prior.matrix, "sym")
    if prior.covariance is None or tuple(prior.parameter_names) != NAMES:
        msg = f"the prior needs a covariance over {NAMES} (use broad_prior or a sym fit)"
        raise InputError(msg)
    cov = np.asarray(prior.covariance, dtype=np.float64) * inflate
    cov = 0.5 * (cov + cov.T)
    w, v = np.linalg.eigh(cov)
    if not np.all(np.isfinite(w)) or w.max() <= 0:
        msg = "the prior covariance is not finite and positive"
        raise InputError(msg)
    w = np.maximum(w, w.max() * 1e-12)
    return theta0, (v / w) @ v.T


def fit_with_prior(points: ArrayLike, prior: Calibration, *, sigma: float | None = None, inflate: float = 1.0,
                   max_iter: int = 200, stamp: float = 0.0, time_ordered: bool = False) -> PriorFit:
    """MAP fit of the symmetric model to ``points`` (N, 3) given a prior calibration (module docstring).

    Args:
        points: raw readings.
        prior: the prior, with a covariance over the sym parameters (``broad_prior`` or a previous fit).
        sigma: noise std of the raw readings, raw units (None: estimated from the residuals, MAD).
        inflate: factor on the prior covariance (> 1 lets the data move an old calibration further).
        max_iter: Levenberg-Marquardt iterations at most per solve.
        stamp: the stamp of the returned calibration.
        time_ordered: the points are a time series: the covariance allows for coloured noise.

    Raises:
        InputError: bad points or prior; DegenerateDataError: fewer than 3 points;
        ConvergenceError: no start led to a finite solution.
    """
    pts = as_points(points, "points")
    if len(pts) < 3:
        msg = f"need at least 3 points, got {len(pts)}"
        raise DegenerateDataError(msg)
    if not (math.isfinite(inflate) and inflate > 0):
        msg = f"inflate must be a positive finite number, got {inflate!r}"
        raise InputError(msg)
    if sigma is not None and not (math.isfinite(sigma) and sigma > 0):
        msg = f"sigma must be a positive finite number, got {sigma!r}"
        raise InputError(msg)
    n = float(prior.norm)
    theta0, info0 = _prior_parts(prior, inflate)
    chol = np.linalg.cholesky(info0).T  # chol^T chol = P_0^-1
    z = np.ascontiguousarray(pts.T)
    floor = _MIN_SIGMA_REL * prior.raw_radius
    best: tuple[float, Array, float, int] | None = None
    for start in _starts(pts, theta0, prior.raw_radius):
        try:
            sol = _solve(z, start, theta0, chol, n, sigma, floor, max_iter)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            continue
        if best is None or sol[0] < best[0]:
            best = sol
    if best is None:
        msg = "MAP fit found no finite solution from any start"
        raise ConvergenceError(msg)
    _, theta, s, iters = best
    r, jt = _geometric(z, theta, n)
    data_info = _hac_information(jt, r) if time_ordered else jt @ jt.T / (s * s)
    post = np.linalg.inv(data_info + info0)
    post = 0.5 * (post + post.T)
    prior_var = np.diag(np.linalg.inv(info0))
    share = 1.0 - np.clip(np.diag(post) / prior_var, 0.0, 1.0)
    updated = tuple(nm for nm, sh in zip(NAMES, share, strict=True) if sh >= 1.0 - UPDATED_VARIANCE_RATIO)
    b, mat = unpack(theta, "sym")
    rn, _ = resjac(z, theta, "sym", n)
    rms = float(np.sqrt(np.mean(rn * rn)))
    stats = FitStats(n_points=len(pts), rms=rms, rms_relative=rms / n, max_abs=float(np.max(np.abs(rn))),
                     iterations=iters, converged=True, cost=float(np.sum(r * r)))
    cal = Calibration(b, mat, norm=n, model="sym", method="map", sensor=prior.sensor, unit=prior.unit, stats=stats,
                      covariance=post, parameter_names=NAMES, stamp=stamp)
    return PriorFit(calibration=cal, prior=prior, updated=updated,
                    from_prior=tuple(nm for nm in NAMES if nm not in updated),
                    data_share=dict(zip(NAMES, share.tolist(), strict=True)), sigma=s, iterations=iters)


def _geometric(z: Array, theta: Array, n: float) -> tuple[Array, Array]:
    """Geometric residuals (raw units) and their transposed Jacobian (9, N) (module docstring)."""
    r, jt = resjac(z, theta, "sym", n)
    b, mat = unpack(theta, "sym")
    y = mat @ (z - b[:, None])
    u = y / np.maximum(np.sqrt(np.einsum("in,in->n", y, y)), 1e-300)
    g = 1.0 / np.maximum(np.sqrt(np.einsum("in,in->n", mat @ u, mat @ u)), 1e-300)
    return r * g, jt * g


def _hac_information(jt: Array, r: Array) -> Array:
    """Newey-West data information ``A S^-1 A`` of time-ordered residuals (module docstring)."""
    a = jt @ jt.T
    rc = r - r.mean()
    var = float(rc @ rc)
    lag = 0
    if var > 0:
        for k in range(1, max(1, len(r) // 10)):
            if float(rc[:-k] @ rc[k:]) / var < 0.05:
                break
            lag = k
    g = jt * r  # score contributions, (P, N)
    s = g @ g.T
    for k in range(1, lag + 1):
        c = g[:, :-k] @ g[:, k:].T
        s += (1.0 - k / (lag + 1.0)) * (c + c.T)
    return a @ np.linalg.solve(s, a)


def _starts(pts: Array, theta0: Array, radius: float) -> list[Array]:
    """The prior, and the prior's matrix about each centre of a radius-``radius`` sphere through the data."""
    starts = [theta0]
    for c in _sphere_centres(pts, radius):
        th = theta0.copy()
        th[:3] = c
        starts.append(th)
    return starts


def _sphere_centres(pts: Array, radius: float) -> list[Array]:
    """Centres ``c`` of ``|v - c| = radius`` through the points: linear in ``(c, |c|^2)``; on data that leave
    one direction free (a ring) the constraint ``u = |c|^2`` gives the two centres along it."""
    a = np.c_[2.0 * pts, -np.ones(len(pts))]
    y = np.einsum("ij,ij->i", pts, pts) - radius * radius
    scale = np.abs(a).max(axis=0)
    scale[scale == 0] = 1.0
    u, sv, vt = np.linalg.svd(a / scale, full_matrices=False)
    if not np.all(np.isfinite(sv)) or sv[0] <= 0:
        return []
    if sv[-1] > 1e-3 * sv[0]:
        return [(vt.T @ ((u.T @ y) / sv) / scale)[:3]]
    x0 = vt[:3].T @ ((u[:, :3].T @ y) / sv[:3]) / scale
    w = vt[3] / scale
    qa, qb, qc = w[:3] @ w[:3], 2.0 * x0[:3] @ w[:3] - w[3], x0[:3] @ x0[:3] - x0[3]
    disc = qb * qb - 4.0 * qa * qc
    ts = [-qb / (2.0 * qa)] if disc < 0 else [(-qb + sg * math.sqrt(disc)) / (2.0 * qa) for sg in (1.0, -1.0)]
    return [x0[:3] + t * w[:3] for t in ts]


def _solve(z: Array, start: Array, theta0: Array, chol: Array, n: float, sigma: float | None, floor: float,
           max_iter: int) -> tuple[float, Array, float, int]:
    """One MAP solve from ``start`` (sigma re-estimated between rounds unless given): cost, theta, sigma, nfev."""
    theta, iters = start.copy(), 0
    s = sigma
    for _ in range(1 if sigma is not None else 3):
        if sigma is None:
            s = max(mad_sigma(_geometric(z, theta, n)[0]), floor)
        assert s is not None
        sc = s

        def fun(th: Array, sc: float = sc) -> Array:
            return np.r_[_geometric(z, th, n)[0] / sc, chol @ (th - theta0)]

        def jac(th: Array, sc: float = sc) -> Array:
            return np.vstack([_geometric(z, th, n)[1].T / sc, chol])

        res = least_squares(fun, theta, jac=jac, method="lm", xtol=1e-10, ftol=1e-10, max_nfev=max_iter)
        theta, iters = res.x, iters + int(res.nfev)
        if not np.all(np.isfinite(theta)):
            msg = "non-finite solution"
            raise ValueError(msg)
    assert s is not None
    r = _geometric(z, theta, n)[0] / s
    dp = chol @ (theta - theta0)
    return float(r @ r + dp @ dp), theta, s, iters


def posterior_at(points: ArrayLike, cal: Calibration, prior: Calibration, *, sigma: float | None = None) -> Calibration:
    """``cal`` with the posterior covariance of the MAP problem linearised at ``cal`` (its symmetric part, at
    its norm): ``P = (J^T J / sigma^2 + P_0^-1)^-1`` from one Jacobian, no iteration. For a calibration
    another fit found (the full path's) whose value is kept and whose heading error is wanted; on data
    that determine every parameter it equals the covariance ``fit_with_prior`` would attach.

    Raises:
        InputError: bad points or prior; DegenerateDataError: fewer than 3 points.
    """
    pts = as_points(points, "points")
    if len(pts) < 3:
        msg = f"need at least 3 points, got {len(pts)}"
        raise DegenerateDataError(msg)
    _, info0 = _prior_parts(prior, 1.0)
    theta = pack(np.asarray(cal.offset, dtype=np.float64), np.asarray(cal.matrix, dtype=np.float64), "sym")
    r, jt = _geometric(np.ascontiguousarray(pts.T), theta, float(cal.norm))
    s = sigma if sigma is not None else max(mad_sigma(r), _MIN_SIGMA_REL * prior.raw_radius)
    post = np.linalg.inv(jt @ jt.T / (s * s) + info0)
    return cal.replace(covariance=0.5 * (post + post.T), parameter_names=NAMES)
