"""How far a fit to samples without time order moves when a region of directions is left out: its jackknife covariance.

A fit's own covariance (``fitting_prior.posterior_at``) holds when the model is right and the noise white. A young
fit on a real sensor is off by more: what the ellipsoid does not model (a shape of its own, a slow drift) is shared
by neighbouring directions, and a fit to part of the sphere carries it into the directions not yet seen. On the
real recordings of ``scripts/bench_heading_bound.py`` the first full fit of an LSM9DS1 after 19 s was 7.9 deg from
the batch fit of the whole recording, where its covariance (with ``heading.UNORDERED_SD_FACTOR``) bounded 5.3 deg.
The delete-a-group jackknife (Efron and Stein 1981; Shao and Tu 1995, ch. 2) measures that spread from the data
themselves, without a model of either.

**Regions.** The calibrated directions ``u = W (v - b) / |W (v - b)|`` are split among the 12 Voronoi cells of the
icosahedron's vertices (about 63 deg across, ``REGIONS``): a region is what a fit extrapolates over when it has not
seen it.

**One Newton step.** Leaving region ``k`` out of the problem linearised at the fit (``fitting_prior.linearised_at``:
information ``H = J^T J / s^2 + P_0^-1``, gradient ``g = J^T r / s^2 + P_0^-1 (theta - theta_0)``) moves the
estimate by ``d_k = -(H - H_k)^-1 (g - g_k)``, ``H_k`` and ``g_k`` the region's shares: no refit (12 solves of 9 x 9).
The covariance is ``(G - 1) / G * sum_k (d_k - mean d)(d_k - mean d)^T`` over the ``G`` regions holding samples.
A region whose removal leaves a parameter to the prior can move it as far as the prior allows: a bound that is
large because the data are thin, which is the point.

**Degrees of freedom.** That covariance is an estimate with ``G - 1`` degrees of freedom. A 95 % bound drawn from
it as from a known normal covariance (``heading.heading_p95_quantile``) is too small by the ratio of the F to the
chi-square quantile; ``t_factor`` is that ratio in standard deviations for a two-dimensional error (the heading
bound's two error directions, ``heading`` module docstring): ``sqrt(nu ((1 - p)^(-2/nu) - 1) / (-2 ln(1 - p)))``,
1.15 for ``nu = 11``, exact for ``F(2, nu)`` (its distribution function is ``1 - (1 + 2 x / nu)^(-nu/2)``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .calibration import Calibration
from .errors import DegenerateDataError, InputError, as_points
from .fitting_prior import NAMES, linearised_at

__all__ = ["MIN_REGIONS", "REGIONS", "grouped_jackknife", "jackknife_at", "region_of", "t_factor"]

Array = NDArray[np.float64]

_PHI = (1.0 + math.sqrt(5.0)) / 2.0
REGIONS: Array = np.array([[0, 1, _PHI], [0, -1, _PHI], [0, 1, -_PHI], [0, -1, -_PHI], [1, _PHI, 0], [-1, _PHI, 0],
                           [1, -_PHI, 0], [-1, -_PHI, 0], [_PHI, 0, 1], [-_PHI, 0, 1], [_PHI, 0, -1], [-_PHI, 0, -1]],
                          dtype=np.float64) / math.sqrt(1.0 + _PHI * _PHI)
"""The icosahedron's 12 vertices (unit vectors): the centres of the regions left out in turn."""
MIN_REGIONS = 3
"""Fewer regions holding samples give no spread worth the name (``DegenerateDataError``)."""


def t_factor(dof: int, p: float = 0.95) -> float:
    """Standard-deviation factor of a ``p`` bound of a two-dimensional error whose covariance was estimated with
    ``dof`` degrees of freedom, against one from a known covariance (module docstring); 1 as ``dof`` grows.

    Raises:
        InputError: ``dof`` below 1 or ``p`` not in (0, 1).
    """
    if not (isinstance(dof, int | np.integer) and dof >= 1) or not 0.0 < p < 1.0:
        msg = f"t_factor needs dof >= 1 and 0 < p < 1, got dof={dof!r}, p={p!r}"
        raise InputError(msg)
    tail = -math.log1p(-p)  # -ln(1 - p)
    return math.sqrt(dof * math.expm1(2.0 * tail / dof) / (2.0 * tail))


def grouped_jackknife(jt: Array, r: Array, sigma: float, info: Array, prior_grad: Array,
                      groups: Array) -> tuple[Array, int]:
    """The delete-a-group jackknife covariance of an estimate from the least squares linearised at it (module
    docstring: one Newton step per group left out), and its degrees of freedom (groups used, minus one).

    ``jt`` (P, N) and ``r`` (N,): the residuals' transposed Jacobian and the residuals, of noise ``sigma``; ``info``
    (P, P): the whole problem's information (data and priors); ``prior_grad`` (P,): the priors' share of the
    gradient; ``groups`` (N,): each residual's group. A group whose removal leaves a singular problem is skipped.

    Raises:
        DegenerateDataError: fewer than two groups could be left out.
    """
    s2 = sigma * sigma
    score = jt * (r / s2)  # each residual's share of the gradient (P, N)
    grad = score.sum(axis=1) + prior_grad
    steps = []
    for k in np.unique(groups):
        mine = groups == k
        jk = jt[:, mine]
        try:
            steps.append(-np.linalg.solve(info - jk @ jk.T / s2, grad - score[:, mine].sum(axis=1)))
        except np.linalg.LinAlgError:
            continue
    if len(steps) < 2:
        msg = f"{len(steps)} group(s) could be left out, the jackknife needs 2"
        raise DegenerateDataError(msg)
    d = np.array(steps)
    d -= d.mean(axis=0)
    g = len(steps)
    cov = (g - 1) / g * (d.T @ d)
    return 0.5 * (cov + cov.T), g - 1


def region_of(points: Array, cal: Calibration) -> NDArray[np.intp]:
    """The region (index into ``REGIONS``) of each of ``points``' calibrated directions: the nearest vertex (the
    length of ``W (v - b)`` does not change it)."""
    w, b = np.asarray(cal.matrix, dtype=np.float64), np.asarray(cal.offset, dtype=np.float64)
    return np.argmax((points - b) @ w.T @ REGIONS.T, axis=1)


def jackknife_at(points: ArrayLike, cal: Calibration, prior: Calibration) -> tuple[Calibration, int]:
    """``cal`` with the delete-a-region jackknife covariance of the MAP problem linearised at it (module docstring),
    and its degrees of freedom (regions holding samples, minus one).

    Raises:
        InputError: bad points or prior; DegenerateDataError: fewer than ``MIN_REGIONS`` regions hold samples.
    """
    pts = as_points(points, "points")
    lin = linearised_at(pts, cal, prior)
    region = region_of(pts, cal)
    if len(np.unique(region)) < MIN_REGIONS:
        msg = (f"the samples fill {len(np.unique(region))} of the {len(REGIONS)} direction regions, the jackknife "
               f"needs {MIN_REGIONS}")
        raise DegenerateDataError(msg)
    info = lin.jt @ lin.jt.T / (lin.sigma * lin.sigma) + lin.info0
    cov, dof = grouped_jackknife(lin.jt, lin.r, lin.sigma, info, lin.info0 @ lin.prior_step, region)
    return cal.replace(covariance=cov, parameter_names=NAMES), dof
