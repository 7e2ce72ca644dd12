"""Observability-aware fitting: the calibration as a maximum a posteriori estimate with a prior.

A robot seldom turns its sensor through every direction: a ground robot turns in yaw, so its data fix
the horizontal hard iron and the 2-D soft iron and say almost nothing of the vertical terms. A plain
least-squares fit of the 9-parameter model (``fitting.fit``) is then ill-posed and wanders; here the
fit starts from what is already known and updates only what the data determine.

**Model.** ``theta = (b_x, b_y, b_z, w_xx, w_yy, w_zz, w_xy, w_xz, w_yz)`` (``fitting_core``'s symmetric
parameter vector) with the reference norm ``n`` (fixed unless ``norm_rel_std``, below), and the *geometric*
residual

    r_i(theta) = (|W d_i| - n) / |W u_i|,   d_i = v_i - b,  u_i = W d_i / |W d_i|,

the norm residual of Camps et al. 2009 (Eqs. 2, 4-7) divided by its gradient in the raw reading
(``fitting_geometric``: why, and its exact Jacobian), with white noise of standard deviation ``sigma``, and
a Gaussian prior ``theta ~ N(theta_0, P_0)``.

**Estimate.** The MAP estimate minimises

    S(theta) = sum_i r_i(theta)^2 / sigma^2 + (theta - theta_0)^T P_0^-1 (theta - theta_0),

solved as the stacked least-squares problem ``[r / sigma; L^T (theta - theta_0)]`` (``L L^T = P_0^-1``)
by Levenberg-Marquardt on the normal equations (``_lm``) with the exact Jacobian of ``r``. Starts (unless one is given,
e.g. a stream's previous solution): the centres of a sphere of the prior's radius through the data (two on
a ring, where the vertical centre is fixed by the norm only up to its sign), and the prior unless the data
determine that centre (an LM run from a far prior offset then only crawls to the same optimum); the
lowest posterior cost wins, every start judged at the lowest sigma found. ``sigma`` is re-estimated
from the residuals (MAD) between solves unless given. The
posterior covariance is ``P = H^-1`` with ``H = J^T J / sigma^2 + P_0^-1`` at the solution (the information
form of the Gauss-Newton step).

**Norm.** By default ``n`` is the prior's and held fixed. With ``norm_rel_std > 0`` it is a tenth parameter
with the prior ``N(prior.norm, (norm_rel_std prior.norm)^2)``, estimated with the others
; the returned calibration has the estimated norm and the covariance of the nine
parameters marginal over it: the data reduce the norm's uncertainty where they determine it (a tumble,
a steep band) and leave the prior's on a ring, where the vertical offset follows the norm.

**What was updated.** For each parameter the data's share of the information is
``1 - P_kk / P0_kk``; a parameter whose posterior variance fell below ``UPDATED_VARIANCE_RATIO`` of its
prior variance (its standard deviation at least halved) counts as *updated*, the others as *from the
prior*: they keep the prior's value up to the coupling with the updated ones, and its uncertainty.

**Coloured noise.** Real sensors drift slowly (1/f noise); the weakly determined terms (the vertical
cross terms of near-level data, fed by slow tilt) soak it up. For points in time order
(``time_ordered=True``) the residual noise is modelled as white plus AR(1) (``fitting_noise``: the
residuals' autocorrelation ``rho_l = c phi^l``, ``l >= 1``, matched to what residuals show of such noise once the
fit took its share along the parameters' directions, ``fitting_noise`` **Absorbed noise**; white when ``c phi`` is
below 0.1), and the fit is then repeated as generalised least squares: residuals and Jacobian pass
through the filter ``F`` that whitens that noise (``fitting_noise.whitener``), ``S`` becomes
``|F r|^2 / s_e^2 + prior`` with ``s_e`` the noise of the whitened residuals, and the posterior is
``(J^T F^T F J / s_e^2 + P_0^-1)^-1``. This is the efficient estimate under that noise, not only an honest
covariance: a direction fed by fast changes (yaw) is judged as before, one fed by slow changes (tilt)
no longer follows the slow noise. (Before, the fit was unweighted and only its covariance allowed for
the coloured noise, by the sandwich ``A B^-1 A``, ``A = J^T J``, ``B = J^T Sigma J``.)
Averaging the samples down to the series' rate (rather than keeping every k-th) divides the white part
by ``sqrt(k)`` and leaves the slow part, which this model then accounts for.
``scripts/study_ground_robot.py`` measures how well the result predicts the heading error on the
independent generator.

**Block means.** A stream's series holds the mean of each short block of samples; with each block's
spread (``spread``) a point is fitted to the norm its mean should have (``fitting_geometric``).

**Gyro.** With the body rates of consecutive raw samples (``gyro``: ``fitting_gyro``'s blocks) the turn
the gyro measured must turn the calibrated field: those residuals join the norm residuals at their own
noise (MAD, re-estimated with ``sigma``), with the gyro's bias and scale errors as six more parameters
(prior sd ``GYRO_BIAS_STD``, ``gyro_scale_std``) marginalised out of the covariance. A ring then determines
the vertical terms too, as far as the gyro's scale on its horizontal axes is known. A
gyro that at the solution accounts for less than ``MIN_EXPLAINED`` of the field's turning (another frame)
is dropped and the fit redone without it; so is one whose rates, re-ordered or with an axis negated, would explain
the turning far better (``fitting_gyro.frame_check``: ``PriorFit.gyro_frame`` names that order, the IMU's frame
flipped or rotated against the magnetometer's).

**Prior.** The last accepted calibration with its covariance (inflated by ``inflate`` so the data can
move it), or, with none, ``broad_prior``: zero offset and identity matrix scaled to the data's mean
radius, with standard deviations ``BROAD_OFFSET_STD`` times the norm for the offset and
``BROAD_MATRIX_STD`` (relative) for the matrix entries. The offset's is a bound, not a measurement: wide
enough for any real hard iron (ArduPilot accepts offsets up to 1 800 mG, about 4 field norms). The
matrix's 0.1 (one sigma of 10 % soft iron, scale and cross-axis error together) is the scale real
sensors show: on the five full-sphere magnetometer recordings of physical sensors the project was checked
against, the vertical gain differs from the horizontal ones by +16.5 % (HMC5883L), -10.2 % (LSM9DS1),
+4.2 %, +1.8 % and 0.0 %, RMS 8.8 %, and cross terms reach 4.3 % (``scripts/study_real_recordings.py
--soft-iron``). It keeps the unobserved directions finite, and where the data leave them to it (the
vertical gain and offset of a ring) the predicted error at tilts not seen is this prior's: right for
sensors like those, conservative for a few per cent of soft iron (the independent generator's
default: the ground-robot heading error at +-30 deg is a third of the predicted p95 there).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import dposv

from .calibration import Calibration, FitStats
from .errors import ConvergenceError, DegenerateDataError, InputError, as_points
from .fitting_core import mad_sigma, pack, parameter_names, resjac, unpack
from .fitting_geometric import geometric, norm_spreads
from .fitting_gyro import (
    GYRO_BIAS_STD,
    GYRO_SCALE_STD,
    MIN_EXPLAINED,
    UNIT_NAMES,
    GyroBlocks,
    GyroTerm,
    explained,
    frame_check,
)
from .fitting_level import LevelTerm
from .fitting_noise import Whitener, noise_model_steps, whitener
from .steps import Steps, drained

__all__ = ["BROAD_MATRIX_STD", "BROAD_OFFSET_STD", "UPDATED_VARIANCE_RATIO", "Linearised", "PriorFit", "broad_prior",
           "fit_with_prior", "fit_with_prior_steps", "linearised_at", "posterior_at"]

Array = NDArray[np.float64]

NAMES = parameter_names("sym", scale_free=False)
BROAD_OFFSET_STD = 5.0
"""Prior standard deviation of each offset component without a previous calibration, in field norms."""
BROAD_MATRIX_STD = 0.1
"""Prior standard deviation of each matrix entry without a previous calibration, relative to its scale."""
UPDATED_VARIANCE_RATIO = 0.25
"""A parameter is *updated* by the data when its posterior variance is below this share of the prior's."""
Term = GyroTerm | LevelTerm
_MIN_SIGMA_REL = 1e-6
_LM_FTOL = 1e-9
_LM_XTOL = 1e-10
_LM_LAM_MAX = 1e12
_LM_STEP_EVALS = 20  # evaluations per step of a solve (a 1500-point ring: about 9 ms)


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
        residual_sigma: the noise of the residuals at the solution (MAD): ``sigma`` when it was estimated;
            with a given ``sigma``, the check that it still fits the data (and the next fit's ``sigma``).
        gyro_explained: with gyro blocks, the share of the field's change within them the gyro accounts for
            at the solution (``fitting_gyro.explained``; nan without); below ``MIN_EXPLAINED`` the gyro was
            not used (``gyro_used``) and the fit is the magnetometer's alone.
        gyro_used: the gyro blocks are part of the fit.
        gyro_frame: another axis order or sign of the rates, or another unit, that explains the field's turning far
            better (``fitting_gyro.frame_check``, e.g. ``"(x, y, -z)"``): the gyro was then not used; "" otherwise.
        gyro_frame_shares: with ``gyro_frame``, the share of the turning it explains and the rates' own (no bias or
            scale error fitted, at the calibration it was judged at); nan otherwise.
        level: the level pseudo-observation was part of the fit (``fit_with_prior(level=True)``, ``fitting_level``).
        gyro_bias: their estimated bias, rad/s, and gyro_scale: their scale errors (zeros when not used).
    """

    calibration: Calibration
    prior: Calibration
    updated: tuple[str, ...]
    from_prior: tuple[str, ...]
    data_share: dict[str, float]
    sigma: float
    iterations: int
    residual_sigma: float = math.nan
    gyro_explained: float = math.nan
    gyro_used: bool = False
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_frame: str = ""
    gyro_frame_shares: tuple[float, float] = (math.nan, math.nan)
    level: bool = False

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
                   max_iter: int = 200, stamp: float = 0.0, time_ordered: bool = False,
                   norm_rel_std: float = 0.0, start: Calibration | None = None,
                   spread: ArrayLike | None = None, gyro: GyroBlocks | None = None,
                   gyro_scale_std: float = GYRO_SCALE_STD, level: bool = False) -> PriorFit:
    """MAP fit of the symmetric model to ``points`` (N, 3) given a prior calibration (module docstring): the steps of
    ``fit_with_prior_steps`` run to the end."""
    return drained(fit_with_prior_steps(points, prior, sigma=sigma, inflate=inflate, max_iter=max_iter, stamp=stamp,
                                        time_ordered=time_ordered, norm_rel_std=norm_rel_std, start=start,
                                        spread=spread, gyro=gyro, gyro_scale_std=gyro_scale_std, level=level))


def fit_with_prior_steps(points: ArrayLike, prior: Calibration, *, sigma: float | None = None, inflate: float = 1.0,
                         max_iter: int = 200, stamp: float = 0.0, time_ordered: bool = False,
                         norm_rel_std: float = 0.0, start: Calibration | None = None,
                         spread: ArrayLike | None = None, gyro: GyroBlocks | None = None,
                         gyro_scale_std: float = GYRO_SCALE_STD, level: bool = False) -> Steps[PriorFit]:
    """MAP fit of the symmetric model to ``points`` (N, 3) given a prior calibration (module docstring), in steps of
    one Levenberg-Marquardt solve or half a noise model each (a stream spreads them over several samples: ``steps``).

    Args:
        points: raw readings.
        prior: the prior, with a covariance over the sym parameters (``broad_prior`` or a previous fit).
        sigma: noise std of the raw readings, raw units (None: estimated from the residuals, MAD, between
            three solves per start; given, one solve per start: a stream's previous fit on the same kind of
            data knows it, and the estimate barely depends on it).
        inflate: factor on the prior covariance (> 1 lets the data move an old calibration further).
        max_iter: Levenberg-Marquardt iterations at most per solve.
        stamp: the stamp of the returned calibration.
        time_ordered: the points are a time series: coloured residual noise is modelled, and the fit is
            weighted by it (generalised least squares) and its covariance allows for it.
        norm_rel_std: relative standard deviation of ``prior.norm`` (0, the default: the norm is known and held
            fixed); above 0 the norm is a tenth parameter with that prior, estimated with the others, and the
            covariance is marginal over it (module docstring).
        start: a calibration to start from instead of the default starts (one solve): a stream's previous
            fit on most of the same data, which already won over the default starts.
        spread: per point, when the points are block means, the mean squared distance of the block's raw
            samples from their mean (raw units squared): each point is fitted to the norm it should have
            (module docstring, **Block means**). None: single samples.
        gyro: blocks of consecutive raw samples with the body rates (``fitting_gyro``): their residuals join
            the fit, with the gyro's bias and scale errors as six more parameters (prior sd ``GYRO_BIAS_STD``
            and ``gyro_scale_std``), weighed by their own noise (MAD); the covariance is marginal over them.
            When at the solution the gyro accounts for less than ``MIN_EXPLAINED`` of the field's change, the
            fit is redone without it.
        gyro_scale_std: the prior standard deviation of each gyro scale error (``fitting_gyro.GYRO_SCALE_STD``).
        level: without gyro blocks (or when they are dropped), the plane of the calibrated points is held level within
            ``fitting_level.LEVEL_TILT_STD_DEG`` (a near-level ring: ``fitting_level``).

    Raises:
        InputError: bad points, prior or argument; DegenerateDataError: fewer than 3 points;
        ConvergenceError: no start led to a finite solution.
    """
    pts = as_points(points, "points")
    if len(pts) < 3:
        msg = f"need at least 3 points, got {len(pts)}"
        raise DegenerateDataError(msg)
    if not (math.isfinite(inflate) and inflate > 0):
        msg = f"inflate must be a positive finite number, got {inflate!r}"
        raise InputError(msg)
    if not (math.isfinite(norm_rel_std) and norm_rel_std >= 0):
        msg = f"norm_rel_std must be a non-negative finite number, got {norm_rel_std!r}"
        raise InputError(msg)
    if sigma is not None and not (math.isfinite(sigma) and sigma > 0):
        msg = f"sigma must be a positive finite number, got {sigma!r}"
        raise InputError(msg)
    if not (math.isfinite(gyro_scale_std) and gyro_scale_std >= 1e-9):  # its inverse square enters the information
        msg = f"gyro_scale_std must be a finite number of at least 1e-9, got {gyro_scale_std!r}"
        raise InputError(msg)
    n0 = float(prior.norm)
    sp = norm_spreads(spread, len(pts), prior.matrix, n0)
    theta0, info0 = _prior_parts(prior, inflate)
    if norm_rel_std > 0:  # the norm joins the parameters: theta = (b, W entries, n)
        theta0 = np.r_[theta0, n0]
        info0 = np.pad(info0, (0, 1))
        info0[9, 9] = 1.0 / (norm_rel_std * n0) ** 2
    chol = np.linalg.cholesky(info0).T  # chol^T chol = P_0^-1
    z = np.ascontiguousarray(pts.T)
    floor = _MIN_SIGMA_REL * prior.raw_radius
    if start is not None:
        th = pack(np.asarray(start.offset, dtype=np.float64), np.asarray(start.matrix, dtype=np.float64), "sym")
        starts = [np.r_[th, float(start.norm)] if theta0.size == 10 else th]  # a Calibration is finite
    else:
        starts = _starts(pts, theta0, prior.raw_radius)
    term: Term | None = None
    if gyro is not None and len(gyro):
        at = theta0.size  # the gyro's bias and scale errors follow the calibration's parameters (and the norm)
        theta0, info0 = np.r_[theta0, np.zeros(6)], np.pad(info0, (0, 6))
        info0[at:, at:] = np.diag([GYRO_BIAS_STD**-2] * 3 + [gyro_scale_std**-2] * 3)
        chol = np.linalg.cholesky(info0).T
        starts = [np.r_[th, np.zeros(6)] for th in starts]
        term = GyroTerm(gyro, 1.0, at)
    elif level:  # two pseudo-observations, no parameters of their own
        term = LevelTerm(pts, 1.0, theta0.size)
    theta, s, iters = yield from _best_solve(z, starts, theta0, info0, chol, n0, sigma, floor, max_iter, sp, term)
    r, jt_geo = geometric(z, _geo(theta, term), n0, sp)
    if time_ordered:
        yield
    model = (yield from noise_model_steps(r, _absorbed(jt_geo, info0, s))) if time_ordered else None
    white = None if model is None else whitener(model)  # coloured: generalised least squares (module docstring)
    s_w = s if white is None else max(mad_sigma(white(r)), floor)
    if white is not None or term is not None:  # one more solve: weighted, and the gyro at its own noise
        if term is not None:
            term.reweigh(theta, s_w, floor)
        yield
        theta, k = yield from _lm(z, theta, theta0, info0, n0, s_w, max_iter, sp, white, term)
        if not np.all(np.isfinite(theta)):
            msg = "MAP fit found no finite solution"
            raise ConvergenceError(msg)
        iters += k
    share_g = math.nan
    if isinstance(term, GyroTerm):
        share_g = explained(term.blocks, term.residuals(theta)[0])
        frame, *shares = frame_check(term.blocks, *unpack(theta[:9], "sym"))
        # a gyro that explains the turn is kept, whatever another axis order would explain on top (a car's small roll
        # and pitch rates leave x and y nearly interchangeable): only a gyro below MIN_EXPLAINED is judged by the frame
        if not share_g >= MIN_EXPLAINED and start is not None:
            # a given start (a stream's previous solution) may be the ring's mirror centre, where a right gyro
            # turns the field the wrong way: every default start once more before the gyro is blamed
            yield
            again = yield from fit_with_prior_steps(points, prior, sigma=sigma, inflate=inflate, max_iter=max_iter,
                                                    stamp=stamp, time_ordered=time_ordered, norm_rel_std=norm_rel_std,
                                                    spread=spread, gyro=gyro, gyro_scale_std=gyro_scale_std, level=level)
            if again.gyro_used:
                return again
        if not share_g >= MIN_EXPLAINED:  # rate and reading in different frames: the magnetometer alone
            # held level only when the gyro is known to be in another frame (named): a gyro in the right frame that
            # does not explain the turn yet (a few blocks) must not let the level assumption publish for it
            yield
            alone = yield from fit_with_prior_steps(points, prior, sigma=sigma, inflate=inflate, max_iter=max_iter,
                                                    stamp=stamp, time_ordered=time_ordered, norm_rel_std=norm_rel_std,
                                                    start=start, spread=spread, level=level and bool(frame))
            # the frame judged again at the magnetometer's own solution, which the wrong rates did not pull; a unit
            # error found at the gyro's solution stands when that one finds none (a real car's near-level ring: its
            # own solution was no ellipse of a field, under which no rate explains the turning)
            again, *again_shares = frame_check(term.blocks, alone.calibration.offset, alone.calibration.matrix)
            if again or frame not in UNIT_NAMES:
                frame, shares = again, again_shares
            return dataclasses.replace(alone, gyro_explained=share_g, gyro_frame=frame,
                                       gyro_frame_shares=(shares[0], shares[1]) if frame else (math.nan, math.nan))
    r = geometric(z, _geo(theta, term), n0, sp)[0]
    if isinstance(term, LevelTerm):  # the ring's slopes scatter too: in the covariance only (fitting_level)
        term.weight = term.covariance_weight()
    _, jt = _residuals(z, theta, n0, sp, white, term)
    data_info = jt @ jt.T / (s_w * s_w)
    post = np.linalg.inv(data_info + info0)[:9, :9]
    post = 0.5 * (post + post.T)
    prior_var = np.diag(np.linalg.inv(info0))[:9]
    share = 1.0 - np.clip(np.diag(post) / prior_var, 0.0, 1.0)
    updated = tuple(nm for nm, sh in zip(NAMES, share, strict=True) if sh >= 1.0 - UPDATED_VARIANCE_RATIO)
    n = float(theta[9]) if norm_rel_std > 0 else n0
    b, mat = unpack(theta[:9], "sym")
    rn, _ = resjac(z, theta[:9], "sym", n)
    rms = float(np.sqrt(np.mean(rn * rn)))
    stats = FitStats(n_points=len(pts), rms=rms, rms_relative=rms / n, max_abs=float(np.max(np.abs(rn))),
                     iterations=iters, converged=True, cost=float(np.sum(r * r)))
    cal = Calibration(b, mat, norm=n, model="sym", method="map", sensor=prior.sensor, unit=prior.unit, stats=stats,
                      covariance=post, parameter_names=NAMES, stamp=stamp)
    return PriorFit(calibration=cal, prior=prior, updated=updated,
                    from_prior=tuple(nm for nm in NAMES if nm not in updated),
                    data_share=dict(zip(NAMES, share.tolist(), strict=True)), sigma=s, iterations=iters,
                    residual_sigma=s if sigma is None else max(mad_sigma(r), floor), gyro_explained=share_g,
                    gyro_used=isinstance(term, GyroTerm), level=isinstance(term, LevelTerm),
                    **_gyro_estimates(theta, term))


def _gyro_estimates(theta: Array, term: Term | None) -> dict[str, tuple[float, ...]]:
    """The gyro's bias and scale errors of a fit with gyro blocks (zeros without)."""
    if not isinstance(term, GyroTerm):
        return {"gyro_bias": (0.0, 0.0, 0.0), "gyro_scale": (0.0, 0.0, 0.0)}
    return {"gyro_bias": tuple(float(x) for x in theta[term.at:term.at + 3]),
            "gyro_scale": tuple(float(x) for x in theta[term.at + 3:term.at + 6])}


def _best_solve(z: Array, starts: list[Array], theta0: Array, info0: Array, chol: Array, n0: float,
                sigma: float | None, floor: float, max_iter: int, sp: Array | None,
                term: Term | None = None) -> Steps[tuple[Array, float, int]]:
    """The unweighted MAP solve from each start; the lowest posterior cost wins, every start judged at the
    lowest noise found: theta, sigma, evaluations (in steps: ``_solve``).

    Raises:
        ConvergenceError: no start led to a finite solution.
    """
    sols = []
    for i, th_start in enumerate(starts):
        if i:
            yield
        try:
            sols.append((yield from _solve(z, th_start, theta0, info0, n0, sigma, floor, max_iter, sp, term)))
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            continue
    if not sols:
        msg = "MAP fit found no finite solution from any start"
        raise ConvergenceError(msg)
    s_ref = min(sol[1] for sol in sols)
    best = min(sols, key=lambda sol: _cost(z, sol[0], theta0, chol, n0, s_ref, sp, term))
    if term is not None:
        term.reweigh(best[0], s_ref, floor)
    return best


def _starts(pts: Array, theta0: Array, radius: float) -> list[Array]:
    """The prior's matrix about each centre of a radius-``radius`` sphere through the data, and the prior
    itself unless the data determine that centre (a cap or more: the sphere's centre lies in the optimum's
    valley, and an LM run from a far prior offset crawls for its whole budget to reach it)."""
    centres, determined = _sphere_centres(pts, radius)
    starts = [] if determined else [theta0]
    for c in centres:
        th = theta0.copy()
        th[:3] = c
        starts.append(th)
    return starts


def _sphere_centres(pts: Array, radius: float) -> tuple[list[Array], bool]:
    """Centres ``c`` of ``|v - c| = radius`` through the points: linear in ``(c, |c|^2)``; on data that leave
    one direction free (a ring) the constraint ``u = |c|^2`` gives the two centres along it."""
    a = np.c_[2.0 * pts, -np.ones(len(pts))]
    y = np.einsum("ij,ij->i", pts, pts) - radius * radius
    scale = np.abs(a).max(axis=0)
    scale[scale == 0] = 1.0
    u, sv, vt = np.linalg.svd(a / scale, full_matrices=False)
    if not np.all(np.isfinite(sv)) or sv[0] <= 0:
        return [], False
    if sv[-1] > 1e-3 * sv[0]:
        return [(vt.T @ ((u.T @ y) / sv) / scale)[:3]], True
    x0 = vt[:3].T @ ((u[:, :3].T @ y) / sv[:3]) / scale
    w = vt[3] / scale
    qa, qb, qc = w[:3] @ w[:3], 2.0 * x0[:3] @ w[:3] - w[3], x0[:3] @ x0[:3] - x0[3]
    disc = qb * qb - 4.0 * qa * qc
    ts = [-qb / (2.0 * qa)] if disc < 0 else [(-qb + sg * math.sqrt(disc)) / (2.0 * qa) for sg in (1.0, -1.0)]
    return [x0[:3] + t * w[:3] for t in ts], False


def _solve(z: Array, start: Array, theta0: Array, info0: Array, n: float, sigma: float | None, floor: float,
           max_iter: int, sp: Array | None = None, term: Term | None = None) -> Steps[tuple[Array, float, int]]:
    """One MAP solve from ``start`` (sigma, and the gyro's weight, re-estimated between rounds unless sigma
    is given): theta, sigma, evaluations; a step per round."""
    theta, iters = start.copy(), 0
    s = sigma
    for round_ in range(1 if sigma is not None else 3):
        if round_:
            yield
        if sigma is None:
            s = max(mad_sigma(geometric(z, _geo(theta, term), n, sp)[0]), floor)
        assert s is not None
        if term is not None:
            term.reweigh(theta, s, floor)
        theta, k = yield from _lm(z, theta, theta0, info0, n, s, max_iter, sp, None, term)
        iters += k
        if not np.all(np.isfinite(theta)):
            msg = "non-finite solution"
            raise ValueError(msg)
    assert s is not None
    return theta, s, iters


def _lm(z: Array, theta: Array, theta0: Array, info0: Array, n: float, s: float, max_iter: int,
        sp: Array | None = None, white: Whitener | None = None, term: Term | None = None) -> Steps[tuple[Array, int]]:
    """Levenberg-Marquardt on ``S(theta)`` through its normal equations: ``(H + lam diag H) step = -g`` with
    ``H = J^T J / s^2 + P_0^-1`` (10 x 10 at most), one residual-and-Jacobian evaluation per trial, the damping
    updated from the ratio of the actual to the predicted decrease (Nielsen's rule); stops when a step
    lowers (or its quadratic model promises to lower) ``S`` by less than ``_LM_FTOL`` of it, or moves
    ``theta`` by less than ``_LM_XTOL`` of its size. (MINPACK's QR of the stacked (N + P) x P system gave the
    same solutions at several times the cost.) ``white``: residuals and Jacobian pass through this filter
    (generalised least squares; ``s`` is then the whitened residuals' noise); ``term``: the gyro's residuals join.
    In steps of ``_LM_STEP_EVALS`` evaluations (``steps``)."""
    w = 1.0 / (s * s)
    r, jt = _residuals(z, theta, n, sp, white, term)
    dp = theta - theta0
    cost = w * float(r @ r) + float(dp @ info0 @ dp)
    lam, nu, evals = 1e-3, 2.0, 1
    h = g = None
    while evals < max_iter:
        if h is None:
            h = w * (jt @ jt.T) + info0
            g = w * (jt @ r) + info0 @ dp
        assert g is not None
        _, x, info = dposv(h + lam * np.diag(np.diag(h)), g)  # Cholesky: the damped H is positive definite
        if info != 0 or not np.all(np.isfinite(x)):
            lam, nu = lam * nu, 2.0 * nu
            if lam > _LM_LAM_MAX:
                break
            continue
        step = -x
        pred = -2.0 * float(g @ step) - float(step @ h @ step)
        if pred <= _LM_FTOL * cost or float(np.linalg.norm(step)) <= _LM_XTOL * (float(np.linalg.norm(theta)) + _LM_XTOL):
            break  # the quadratic model promises (next to) nothing: converged, no evaluation spent on it
        cand = theta + step
        if evals % _LM_STEP_EVALS == 0:
            yield
        r2, jt2 = _residuals(z, cand, n, sp, white, term)
        evals += 1
        dp2 = cand - theta0
        cost2 = w * float(r2 @ r2) + float(dp2 @ info0 @ dp2)
        if math.isfinite(cost2) and cost2 < cost:
            rho = (cost - cost2) / pred
            done = cost - cost2 <= _LM_FTOL * cost
            theta, r, jt, dp, cost, h = cand, r2, jt2, dp2, cost2, None
            lam, nu = lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 2.0
            if done:
                break
        else:
            lam, nu = lam * nu, 2.0 * nu
            if lam > _LM_LAM_MAX:
                break
    return theta, evals


def _residuals(z: Array, theta: Array, n: float, sp: Array | None, white: Whitener | None,
               term: Term | None = None) -> tuple[Array, Array]:
    """``fitting_geometric.geometric``, through the whitening filter when one is given, and the gyro's
    residuals after them, brought to the same noise (``GyroTerm.weight``)."""
    r, jt = geometric(z, _geo(theta, term), n, sp)
    if white is not None:
        r, jt = white(r), white(jt)
    if term is None:
        return r, jt
    rg, jg = term.residuals(theta)
    full = np.zeros((theta.size, r.size + rg.size))
    full[:term.at, :r.size] = jt
    full[:9, r.size:] = term.weight * jg[:9]
    full[term.at:, r.size:] = term.weight * jg[9:]
    return np.concatenate([r, term.weight * rg]), full


def _absorbed(jt: Array, info0: Array, s: float) -> Array:
    """``U`` (m, p) with ``U U^T = J (J^T J + s^2 P_0^-1)^-1 J^T``: the share of the noise the MAP fit took into its
    parameters (``fitting_noise``, **Absorbed noise**), ``jt`` the transposed Jacobian of the geometric residuals."""
    p = len(jt)
    a = jt @ jt.T + s * s * info0[:p, :p]
    try:
        low = np.linalg.cholesky(0.5 * (a + a.T))
    except np.linalg.LinAlgError:
        return np.zeros((jt.shape[1], 0))
    return np.linalg.solve(low, jt).T


def _geo(theta: Array, term: Term | None) -> Array:
    """The parameters of the geometric residual: ``theta`` without the term's (they follow at ``term.at``)."""
    return theta if term is None else theta[:term.at]


def _cost(z: Array, theta: Array, theta0: Array, chol: Array, n: float, s: float, sp: Array | None = None,
          term: Term | None = None) -> float:
    """The posterior cost ``S(theta)`` at noise ``s``."""
    r = _residuals(z, theta, n, sp, None, term)[0] / s
    dp = chol @ (theta - theta0)
    return float(r @ r + dp @ dp)


class Linearised(NamedTuple):
    """The MAP problem linearised at a calibration (``linearised_at``)."""

    r: Array
    """Geometric residuals (N,), raw units."""
    jt: Array
    """Their transposed Jacobian (9, N)."""
    sigma: float
    """The noise: the residuals' MAD unless given."""
    info0: Array
    """The prior's information ``P_0^-1`` (9, 9)."""
    prior_step: Array
    """``theta - theta_0`` (9,): the prior's share of the gradient is ``info0 @ prior_step``."""


def linearised_at(points: ArrayLike, cal: Calibration, prior: Calibration, *, sigma: float | None = None) -> Linearised:
    """The MAP problem linearised at ``cal`` (its symmetric part, at its norm): what ``posterior_at`` and
    ``fitting_jackknife`` build on.

    Raises:
        InputError: bad points or prior; DegenerateDataError: fewer than 3 points.
    """
    pts = as_points(points, "points")
    if len(pts) < 3:
        msg = f"need at least 3 points, got {len(pts)}"
        raise DegenerateDataError(msg)
    theta0, info0 = _prior_parts(prior, 1.0)
    theta = pack(np.asarray(cal.offset, dtype=np.float64), np.asarray(cal.matrix, dtype=np.float64), "sym")
    r, jt = geometric(np.ascontiguousarray(pts.T), theta, float(cal.norm))
    s = sigma if sigma is not None else max(mad_sigma(r), _MIN_SIGMA_REL * prior.raw_radius)
    return Linearised(r, jt, float(s), info0, theta - theta0)


def posterior_at(points: ArrayLike, cal: Calibration, prior: Calibration, *, sigma: float | None = None) -> Calibration:
    """``cal`` with the posterior covariance of the MAP problem linearised at ``cal`` (its symmetric part, at
    its norm): ``P = (J^T J / sigma^2 + P_0^-1)^-1`` from one Jacobian, no iteration. For a calibration
    another fit found (the full path's) whose value is kept and whose heading error is wanted; on data
    that determine every parameter it equals the covariance ``fit_with_prior`` would attach.

    Raises:
        InputError: bad points or prior; DegenerateDataError: fewer than 3 points.
    """
    lin = linearised_at(points, cal, prior, sigma=sigma)
    post = np.linalg.inv(lin.jt @ lin.jt.T / (lin.sigma * lin.sigma) + lin.info0)
    return cal.replace(covariance=0.5 * (post + post.T), parameter_names=NAMES)
