"""The magnetometer's mounting against the IMU: which of the 24 axis-aligned rotations, then the small rest.

A gyro measures the body's turn in the IMU's frame; a calibration ``h = W (v - b)`` gives the field in the
magnetometer's (its calibrated) frame. With ``h_imu = R h`` the rate in that frame is ``R^T omega``, and the
gyro-aided residual of ``fitting_gyro`` (a turn the gyro measured must turn the calibrated field) holds for
the true ``R`` only. So, from the gyro blocks and a calibration held fixed (full or partial):

1. **Axis-aligned rotation.** Every signed permutation ``m = R^T`` of the rates is scored by the share of the
   field's change it explains (``fitting_gyro.frame_shares``); the best proper rotation (det +1), and those of the
   ``REFINE`` best that leave at most ``RIVAL`` times its unexplained share, are each refined by least squares
   (below) so that neither a few degrees of misalignment nor the gyro's errors decide between them. Each refined
   rotation is snapped to its nearest axis-aligned one (a start 90 deg off often ends at the true one); the best is
   decided when its residual sum beats the best *other* axis-aligned rotation's (refined, or as it comes when every
   start ended at the best: an upper bound) by ``DECIDE_CHI2`` noise variances (a likelihood-ratio test), with
   ``MIN_BLOCKS`` blocks at least, and explains at least ``fitting_gyro.MIN_EXPLAINED`` of the field's change (else
   "none fits"). A mirror image (det -1) that explains far more than every rotation (``fitting_gyro.FRAME_BETTER``)
   is a wiring or sign fault, not a mounting, and is named as such.
2. **Misalignment.** ``R = R0 exp([delta]x)``: Gauss-Newton on the three small angles ``delta`` (magnetometer frame,
   radians), the gyro's bias and scale errors (priors ``GYRO_BIAS_STD``, ``gyro_scale_std``) and the rates' time
   offset against the readings (``TIME_OFFSET_STD``), with the residual's exact Jacobian (``_lean``: the calibration
   held, linear in the rates' map, so no per-rotation block basis); its covariance (or, when larger, the
   jackknife's over runs of time, ``JACKKNIFE_CHUNKS``), with the calibration's own propagated when it carries one
   over the symmetric parameters (``d delta / d theta``), is the misalignment's;
   ``delta`` has a broad prior (``MISALIGN_STD``) so that an angle the motion does not determine shows as an sd of
   that size instead of a singular matrix.

**What a motion determines.** A turn about one axis ``a`` (a ground robot in yaw) fixes which of the
magnetometer's axes lies along ``a``, ``R^T a``, and nothing about a turn of the magnetometer about ``a``:
``R`` and ``Q_a R`` (``Q_a`` a turn about ``a``) give the same rate along that axis. A few degrees of roll and
pitch do tell the horizontal axes apart, given time; until the test decides, the result names the turn axis
and the magnetometer's axis along it (``Mounting.message``) instead of guessing the rest. A tumble
determines all three.

**Figures** (``scripts/bench_mounting.py``, independent generator, gyro with 3 % scale errors, 60 s at 50 Hz,
calibrations from the magnetometer alone): on fresh seeds (51: the 24 rotations x 0, 2, 5 deg; 400-439: one case
each) every rotation was found, none wrong at any time, decided at the first look (20 s); the misalignment's error
was 0.04 deg median (0.10 worst) on a tumble and 0.5 deg (1.1) on a ground robot at 5 deg tilt, 1.16-1.18 and
0.99-1.02 times the predicted sd (rms over components). With the jackknife (seeds 600-639, run once): a tumble 1.06
times (1.30 without it, the same seeds), a ground robot 1.01 (1.04). 25-40 ms an estimate at 300 blocks.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .calibration import Calibration
from .errors import DegenerateDataError, InputError
from .fitting_core import mad_sigma, pack, parameter_names, unpack
from .fitting_gyro import (
    FRAME_BETTER,
    GYRO_BIAS_STD,
    GYRO_SCALE_STD,
    MIN_EXPLAINED,
    SIGNED_PERMUTATIONS,
    UNIT_ERRORS,
    GyroBlocks,
    axial,
    explained,
    frame_advice,
    frame_shares,
    gyro_residuals,
    named_better,
    rotated_blocks,
    skew,
    turning_share,
)
from .fitting_jackknife import grouped_jackknife
from .steps import Steps, drained

__all__ = ["DECIDE_CHI2", "JACKKNIFE_CHUNKS", "MIN_BLOCKS", "MISALIGN_STD", "REFINE", "RIVAL", "ROTATIONS", "SINGLE_AXIS",
           "TIME_OFFSET_STD", "UP_AXES", "Mounting", "axis_angle", "find_mounting", "find_mounting_steps", "into_imu_frame",
           "rotation_name", "rotvec", "turned", "up_rotation"]

Array = NDArray[np.float64]

ROTATIONS = tuple(m.T for m in SIGNED_PERMUTATIONS if np.linalg.det(m) > 0)
"""The 24 axis-aligned rotations ``R`` (``h_imu = R h_mag``), the identity first."""
_MIRRORS = tuple(m.T for m in SIGNED_PERMUTATIONS if np.linalg.det(m) < 0)
DECIDE_CHI2 = 50.0
"""Least increase of the residual sum, in noise variances, from the best axis-aligned rotation to the best other
one for the rotation to be decided (a likelihood-ratio statistic; chosen on the tuning seeds of
``scripts/bench_mounting.py``: the blocks' residuals are not quite Gaussian, so well above chi-square's 5 sigma)."""
MISALIGN_STD = math.radians(10.0)
"""Prior sd of each misalignment angle, rad: bounds an angle the motion does not determine."""
TIME_OFFSET_STD = 0.02
"""Prior sd of the time offset between the rates and the readings, s: the stream pairs each reading with the Imu rate
nearest in stamp within 20 ms, and a driver's stamp may lag its sample by a filter's delay. Estimated with the rest,
so that its effect on a fast turn (a tumble) is not taken for misalignment: on the independent generator (whose
rates are held from each sample to the next, half a sample ahead of the trapezoid rule here) without it the errors
of a tumble's misalignment were 1.9-2.5 times their predicted sd."""
MIN_BLOCKS = 20
"""Fewest gyro blocks for an estimate: the stream's ``GYRO_MIN_BLOCKS`` (with 5, on held-out seeds 200-239 of
``scripts/bench_mounting.py --honesty``, 2 of 40 ground robots were decided wrong at 5 s, right later)."""
REFINE = 4
"""How many of the best-scoring axis-aligned rotations are refined by least squares."""
RIVAL = 30.0
"""A rotation is refined as a rival of the best-scoring one when, taken as it comes, it leaves at most this many times
the field's change unexplained that the best one leaves (a few degrees of misalignment and the gyro's errors leave
both about the same; an axis 90 deg off leaves far more, unless the body never turned about the other axes)."""
SINGLE_AXIS = 0.97
"""The turns are about one axis when that axis carries at least this share of ``sum theta theta^T``."""
JACKKNIFE_CHUNKS = 10
"""Runs of time the jackknife leaves out in turn (``_jackknife``): the misalignment's sd is the larger of the least
squares' and the jackknife's. Without it a tumble's errors were 1.29 times their sd (rms over components, seeds 100-139
of ``scripts/bench_mounting.py --honesty``): the blocks' residuals share a slow part their noise estimate does not
see. No factor: the jackknife's variance is an unbiased estimate, and an sd (not a 95 % bound) is what is shown."""
_ITER = 10
_TOL = 1e-4  # rad: a smaller step of the turn ends the refinement (0.006 deg, a tenth of the best sd seen)


@dataclass(frozen=True)
class Mounting:
    """The magnetometer's rotation against the IMU (module docstring).

    Attributes:
        rotation: the axis-aligned rotation ``R0`` (``h_imu = R0 h_mag``) when decided, else None.
        name: its description, e.g. ``"x->-y, y->x, z->z (90 deg about -z)"`` ("" when undecided).
        misalignment: the small rotation vector ``delta`` (rad, magnetometer frame; ``R = R0 exp([delta]x)``).
        covariance: its covariance (3, 3), rad^2.
        explained: share of the field's change explained under the refined rotation.
        chi2: the likelihood-ratio statistic against the best other axis-aligned rotation.
        runner_up: that rotation's name.
        mirror: a mirror image explaining far more than every rotation ("" when none): a wiring or sign fault.
        turn_axis: the IMU axis the body turned about alone ("" when the turns span more than one axis).
        reason: why nothing was decided ("" when decided).
        time_offset_s: the rates' time offset against the readings fitted with it (``TIME_OFFSET_STD``), s.
    """

    rotation: Array | None
    name: str
    misalignment: Array = field(default_factory=lambda: np.full(3, np.nan))
    covariance: Array = field(default_factory=lambda: np.full((3, 3), np.nan))
    explained: float = math.nan
    chi2: float = math.nan
    runner_up: str = ""
    mirror: str = ""
    turn_axis: str = ""
    reason: str = ""
    time_offset_s: float = math.nan

    @property
    def full_rotation(self) -> Array | None:
        """``R = R0 exp([delta]x)``, the whole rotation from the calibrated frame to the IMU's (None: undecided)."""
        return None if self.rotation is None else self.rotation @ rotvec(self.misalignment)

    @property
    def misalignment_deg(self) -> float:
        """The misalignment's angle, degrees."""
        return math.degrees(float(np.linalg.norm(self.misalignment)))

    @property
    def misalignment_sd_deg(self) -> float:
        """Its predicted sd, degrees: ``sqrt(trace(covariance))``, the rms of the angle's error."""
        return math.degrees(math.sqrt(max(float(np.trace(self.covariance)), 0.0)))

    @property
    def identity(self) -> bool:
        """The magnetometer is mounted in the IMU's axes."""
        return self.rotation is not None and bool(np.allclose(self.rotation, np.eye(3)))

    def message(self, imu_frame: str = "", mag_frame: str = "", *, into_imu: bool = False) -> str:
        """What a status says, with the frame_ids to fix when known ("" when there is nothing to say); ``into_imu``:
        the calibration is published in the IMU's frame (``into_imu_frame``)."""
        imu = f"imu frame '{imu_frame}'" if imu_frame else "the Imu messages' frame"
        if self.mirror:
            return (f"magnetometer axes mirrored against {imu} ({self.mirror}, a left-handed frame): a wiring or sign "
                    "fault in the driver, not a mounting rotation")
        if self.rotation is None:
            return f"mounting against {imu} not determined: {self.reason}" if self.reason else ""
        mis = f"misalignment {self.misalignment_deg:.2f} deg +- {self.misalignment_sd_deg:.2f} deg"
        if self.identity:
            return f"magnetometer in the axes of {imu}, {mis}"
        if into_imu:
            return (f"magnetometer mounted rotated against {imu}: {self.name}, {mis}: calibrated into the IMU's frame "
                    "(mag.calibrate_into_imu_frame)")
        pair = (f"'{mag_frame}' and '{imu_frame}'" if mag_frame and imu_frame
                else "the MagneticField and Imu messages' frame_ids (the node's status: hardware_id, imu_frame_id)")
        return (f"magnetometer mounted rotated against {imu}: {self.name}, {mis}: fix the static transform between "
                f"{pair} or set mag.calibrate_into_imu_frame")

    def after_turn(self, q: Array) -> Mounting:
        """This mounting found on readings turned by ``q`` (``v' = q v``, an axis-aligned rotation already applied), as
        one of the readings themselves: ``h_imu = R exp([delta]x) q h = (R q) exp([q^T delta]x) h``."""
        if self.rotation is None:
            return self
        r = self.rotation @ q
        return dataclasses.replace(self, rotation=r, name=rotation_name(r), misalignment=q.T @ self.misalignment,
                                   covariance=q.T @ self.covariance @ q)


def turned(cal: Calibration, q: Array) -> Calibration:
    """``cal`` for readings turned by the rotation ``q`` (``v' = q v``): ``b' = q b``, ``W' = q W q^T`` (its output
    turned by ``q`` too: the same norms), the covariance over the symmetric parameters (and the norm, when it is
    the last) carried over; a covariance over other parameters is dropped (it would describe the unturned ones)."""
    b, w = np.asarray(cal.offset, dtype=np.float64), np.asarray(cal.matrix, dtype=np.float64)
    cov, names = cal.covariance, tuple(cal.parameter_names)
    if cov is not None and names in (parameter_names("sym", scale_free=False), parameter_names("sym", scale_free=True)):
        cols = [pack(q @ bi, q @ wi @ q.T, "sym") for bi, wi in (unpack(e, "sym") for e in np.eye(9))]
        t = np.eye(len(names))
        t[:9, :9] = np.array(cols).T  # the parameters' linear map (the norm's row and column: itself)
        cov = t @ np.asarray(cov, dtype=np.float64) @ t.T
    elif cov is not None:
        cov, names = None, ()
    return cal.replace(offset=q @ b, matrix=q @ w @ q.T, covariance=cov, parameter_names=names)


UP_AXES = ("z", "+z", "-z", "x", "+x", "-x", "y", "+y", "-y")
"""The admitted ``up_axis`` values: the magnetometer's axis that points up when the vehicle is level."""


def up_rotation(axis: str) -> Array | None:
    """The rotation ``q`` (a signed permutation, det +1) that turns readings so that the magnetometer's ``axis`` (one of
    ``UP_AXES``) becomes +z: ``q e_axis = e_z``; None for ``"z"`` (nothing to turn). A sensor mounted on its side on a
    ground robot, without a gyro to find its mounting: its ring lies about that axis, and every ring rule and heading
    figure takes z as up (``stream/observable.py``).

    Raises:
        InputError: ``axis`` is not one of ``UP_AXES``.
    """
    if axis not in UP_AXES:
        msg = f"up_axis must be one of {UP_AXES}, got {axis!r}"
        raise InputError(msg)
    if axis.lstrip("+") == "z":
        return None
    up = np.zeros(3)
    up["xyz".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
    first = np.eye(3)[int(np.argmin(np.abs(up)))]  # an axis across it (the first of x, y, z not along it)
    return np.array([first, np.cross(up, first), up])  # rows: x', y' = z' x x', z' = up (right-handed)


def into_imu_frame(cal: Calibration, mounting: Mounting) -> Calibration:
    """``cal`` with its output in the IMU's frame: ``W`` becomes ``R W`` (``R = R0 exp([delta]x)``, the whole rotation);
    the offset stays. Its covariance over the symmetric parameters no longer describes ``R W``: dropped.

    Raises:
        InputError: the mounting is not decided.
    """
    r = mounting.full_rotation
    if r is None:
        msg = f"no mounting rotation decided: {mounting.reason or 'none'}"
        raise InputError(msg)
    return cal.replace(matrix=r @ np.asarray(cal.matrix, dtype=np.float64), covariance=None, parameter_names=())


def rotvec(v: ArrayLike) -> Array:
    """The rotation matrix of a rotation vector (Rodrigues)."""
    w = np.asarray(v, dtype=np.float64)
    a = float(np.linalg.norm(w))
    k = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if a < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + math.sin(a) / a * k + (1.0 - math.cos(a)) / (a * a) * (k @ k)


def axis_angle(r: Array) -> Array:
    """The rotation vector of a rotation matrix (angle up to 180 deg)."""
    c = min(max(0.5 * (float(np.trace(r)) - 1.0), -1.0), 1.0)
    a = math.acos(c)
    if a < 1e-9:
        return np.zeros(3)
    if a > math.pi - 1e-6:  # 180 deg: the axis from R + I
        s = r + np.eye(3)
        col = s[:, int(np.argmax(np.diag(s)))]
        return a * col / np.linalg.norm(col)
    return a / (2.0 * math.sin(a)) * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])


def _axis_name(v: Array) -> str:
    k = int(np.argmax(np.abs(v)))
    return ("-" if v[k] < 0 else "") + "xyz"[k]


def rotation_name(r: Array) -> str:
    """``"x->-y, y->x, z->z (90 deg about -z)"``: where each magnetometer axis points in the IMU's frame."""
    axes = ", ".join(f"{'xyz'[j]}->{_axis_name(r[:, j])}" for j in range(3))
    v = axis_angle(r)
    a = math.degrees(float(np.linalg.norm(v)))
    if a < 1e-6:
        return f"{axes} (the same axes)"
    n = v / np.linalg.norm(v)
    about = _axis_name(n) if np.max(np.abs(n)) > 0.999 else "(" + ", ".join(f"{x:.3f}" for x in n) + ")"
    return f"{axes} ({a:.0f} deg about {about})"


def _nearest(r: Array) -> int:
    """Index of the axis-aligned rotation nearest ``r``."""
    return int(np.argmax([float(np.trace(q.T @ r)) for q in ROTATIONS]))


@dataclass(frozen=True)
class _Refined:
    r: Array
    p: Array
    cost: float
    sigma: float
    info: Array
    jt: Array
    res: Array
    prior_grad: Array  # the priors' share of the gradient at the estimate


@dataclass(frozen=True)
class _Pre:
    """What every evaluation under one calibration shares: ``W S^T`` (N, 3, 3), ``Theta``, ``W P``, ``T``, ``d``,
    ``W^-T``, ``W b`` (``fitting_gyro``'s block sums)."""

    st: Array
    theta: Array
    wp: Array
    t: Array
    d: Array
    winv_t: Array
    wb: Array
    k_wb: Array  # skew(W b): a @ k_wb = a x W b
    st_dot: Array  # W S_dot^T, and Theta_dot: what a time offset of the rates adds per second (GyroBlocks)
    theta_dot: Array


def _pre(blocks: GyroBlocks, b: Array, w: Array) -> _Pre:
    wb = w @ b
    return _Pre(w @ blocks.s.transpose(0, 2, 1), blocks.theta, blocks.p @ w.T, blocks.t, blocks.d, np.linalg.inv(w).T,
                wb, skew(wb), w @ blocks.s_dot.transpose(0, 2, 1), blocks.theta_dot)


def _rate_part(pre: _Pre, a: Array, tau: float = 0.0) -> Array:
    """``axial(W S^T A) - (Theta A) x W b`` (N, 3): the part of ``u`` the rates' map ``A = m^T diag(1 + kappa)`` carries,
    with the rates taken ``tau`` seconds later (``S + tau S_dot``, ``Theta + tau Theta_dot``)."""
    out = axial(pre.st @ a) - pre.theta @ (a @ pre.k_wb)
    return out + tau * _dot_part(pre, a) if tau else out


def _dot_part(pre: _Pre, a: Array) -> Array:
    """``d _rate_part / d tau``."""
    return axial(pre.st_dot @ a) - pre.theta_dot @ (a @ pre.k_wb)


def _lean(pre: _Pre, r: Array, p: Array) -> tuple[Array, Array]:
    """Residuals (3N,) under the rotation ``r`` (rates ``r^T omega``) with the gyro's bias and scale errors and the
    rates' time offset ``p = (beta, kappa, tau)``, and their transposed Jacobian (10, 3N) over a small turn ``eps``
    (``r exp([eps]x)``, so ``d m / d eps_i = -[e_i]x m`` for ``m = r^T``), ``beta``, ``kappa`` and ``tau``:
    ``fitting_gyro.gyro_residuals`` with the calibration held (and ``tau``), which needs no per-rotation block basis."""
    m, beta, sc, tau = r.T, p[:3], 1.0 + p[3:6], float(p[6])
    a = m.T * sc
    u = _rate_part(pre, a, tau) + np.outer(pre.t, np.cross(beta, pre.wb)) + pre.wp @ skew(beta)
    res = (pre.d + u @ pre.winv_t).reshape(-1)
    jt = np.empty((10, len(res)))
    eye = np.eye(3)
    for i in range(3):
        mi = -skew(eye[i]) @ m  # -[e_i]x m (skew(c) = [c]x)
        jt[i] = (_rate_part(pre, mi.T * sc, tau) @ pre.winv_t).reshape(-1)
        jt[3 + i] = ((np.outer(pre.t, np.cross(eye[i], pre.wb)) + pre.wp @ skew(eye[i])) @ pre.winv_t).reshape(-1)
        jt[6 + i] = (_rate_part(pre, np.outer(m.T[:, i], eye[i]), tau) @ pre.winv_t).reshape(-1)
    jt[9] = (_dot_part(pre, a) @ pre.winv_t).reshape(-1)
    return res, jt


def _refine(pre: _Pre, r0: Array, prior_info: Array) -> _Refined:
    """Gauss-Newton on a small turn of ``r0`` and the gyro's bias and scale errors, the calibration held (each step
    a turn ``exp([eps]x)`` on the right); the noise re-estimated (MAD) each step."""
    r, p = r0.copy(), np.zeros(7)
    for _ in range(_ITER):
        res, jt = _lean(pre, r, p)
        s2 = max(mad_sigma(res), 1e-300) ** 2
        x = np.r_[axis_angle(r0.T @ r), p]
        step = np.linalg.solve(jt @ jt.T / s2 + prior_info, -(jt @ res / s2 + prior_info @ x))
        r, p = r @ rotvec(step[:3]), p + step[3:]
        if float(np.max(np.abs(step[:3]))) < _TOL:
            break
    res, jt = _lean(pre, r, p)
    s = max(mad_sigma(res), 1e-300)
    x = np.r_[axis_angle(r0.T @ r), p]
    return _Refined(r, p, float(res @ res), s, jt @ jt.T / (s * s) + prior_info, jt, res, prior_info @ x)


def _turn_axis(blocks: GyroBlocks) -> str:
    """The IMU axis the body turned about alone (``SINGLE_AXIS``), "" when the turns span more."""
    m = blocks.theta.T @ blocks.theta
    vals, vecs = np.linalg.eigh(m)
    if not vals[-1] > 0 or vals[-1] < SINGLE_AXIS * float(np.sum(vals)):
        return ""
    v = vecs[:, -1]
    return _axis_name(v).lstrip("-") if np.max(np.abs(v)) > 0.95 else "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


def _jackknife(best: _Refined) -> Array:
    """The misalignment's delete-a-chunk jackknife covariance (3, 3): the blocks in ``JACKKNIFE_CHUNKS`` runs of time,
    each left out in turn (``fitting_jackknife.grouped_jackknife``, here over time: what the blocks share, a slow
    drift of the rates or of the field, is what the chunks tell apart)."""
    n_blocks = len(best.res) // 3
    chunk = np.repeat(np.minimum(np.arange(n_blocks) * JACKKNIFE_CHUNKS // n_blocks, JACKKNIFE_CHUNKS - 1), 3)
    return grouped_jackknife(best.jt, best.res, best.sigma, best.info, best.prior_grad, chunk)[0][:3, :3]


def _covariance(best: _Refined, blocks: GyroBlocks, b: Array, w: Array, cal_cov: Array | None) -> Array:
    """The misalignment's covariance: the least squares' own or, when its trace is larger, the jackknife's
    (``_jackknife``), plus the calibration's propagated when given (through ``d delta / d theta_cal``, from
    ``gyro_residuals``' Jacobian over the calibration's parameters)."""
    inv = np.linalg.inv(best.info)
    cov = inv[:3, :3]
    try:
        jack = _jackknife(best)
    except DegenerateDataError:  # the priors keep every chunk's problem regular; should they not, the model's stands
        jack = cov
    cov = jack if float(np.trace(jack)) > float(np.trace(cov)) else cov
    if cal_cov is not None:
        jcal = gyro_residuals(rotated_blocks(blocks, best.r.T), b, w, best.p[:3], best.p[3:6])[1][:9]  # tau: 2nd order
        g = -(inv @ (best.jt @ jcal.T))[:3] / (best.sigma * best.sigma)
        cov = cov + g @ cal_cov @ g.T
    return 0.5 * (cov + cov.T)


def _none_fits(blocks: GyroBlocks, b: Array, w: Array, share: float) -> str:
    """Why no axis-aligned rotation fits (the best explains ``share``), naming rates in the wrong unit when one of the
    24 rotations explains the turning with them 57.3x larger or smaller (``fitting_gyro.UNIT_ERRORS``, named as
    ``frame_check`` names them): a tumble's rates converted from deg/s twice read "the best explains 4.7 %" and no more."""
    why = (f"no axis-aligned rotation fits: the best explains {turning_share(share)}"
           + (f" < {100 * MIN_EXPLAINED:.0f} %" if share >= 0.0 else ""))
    cands = [(name, r) for _, name in UNIT_ERRORS for r in ROTATIONS]
    shares = np.asarray(frame_shares(blocks, b, w, [f * r.T for f, _ in UNIT_ERRORS for r in ROTATIONS]))
    if not np.isfinite(shares).any():
        return why
    k = int(np.nanargmax(shares))
    if not named_better(shares[k], share):
        return why
    name, r = cands[k]
    return f"{why}; {100 * shares[k]:.0f} % under {rotation_name(r)}, {frame_advice(name)}"


def find_mounting(blocks: GyroBlocks, offset: ArrayLike, matrix: ArrayLike, covariance: ArrayLike | None = None, *,
                  gyro_scale_std: float = GYRO_SCALE_STD) -> Mounting:
    """The magnetometer's mounting rotation against the IMU from the gyro blocks under the calibration ``(offset,
    matrix)`` (module docstring). ``covariance``: the calibration's over the symmetric parameters (9, 9), or None."""
    return drained(find_mounting_steps(blocks, offset, matrix, covariance, gyro_scale_std=gyro_scale_std))


def find_mounting_steps(blocks: GyroBlocks, offset: ArrayLike, matrix: ArrayLike, covariance: ArrayLike | None = None,
                        *, gyro_scale_std: float = GYRO_SCALE_STD) -> Steps[Mounting]:
    """``find_mounting`` in steps (``steps``): one per rotation refined."""
    b = np.asarray(offset, dtype=np.float64)
    w = np.asarray(matrix, dtype=np.float64)
    if len(blocks) < MIN_BLOCKS or not float(np.sum(blocks.d * blocks.d)) > 0:
        return Mounting(None, "", reason=f"{len(blocks)} gyro blocks with a turn, fewer than {MIN_BLOCKS}")
    turn = _turn_axis(blocks)
    shares = frame_shares(blocks, b, w, [r.T for r in ROTATIONS])
    order = np.argsort(-np.nan_to_num(np.asarray(shares), nan=-np.inf))
    prior_info = np.diag([MISALIGN_STD**-2] * 3 + [GYRO_BIAS_STD**-2] * 3 + [gyro_scale_std**-2] * 3
                         + [TIME_OFFSET_STD**-2])
    pre = _pre(blocks, b, w)
    unexplained = 1.0 - np.asarray(shares)
    tried: dict[int, _Refined] = {}
    refined: list[int] = []
    for k in (int(i) for i in order[:REFINE]):
        if refined and not unexplained[k] <= RIVAL * unexplained[refined[0]]:
            break  # far worse as it comes than the best: no rival (its own cost below stands in)
        if refined:
            yield
        refined.append(k)
        ref = _refine(pre, ROTATIONS[k], prior_info)
        near = _nearest(ref.r)
        if near not in tried or ref.cost < tried[near].cost:
            tried[near] = ref
    ranked = sorted(tried.items(), key=lambda kv: kv[1].cost)
    k_best, best = ranked[0]
    r0 = ROTATIONS[k_best]
    delta = axis_angle(r0.T @ best.r)
    share = explained(blocks, _lean(pre, best.r, best.p)[0])
    cov = _covariance(best, blocks, b, w, None if covariance is None else np.asarray(covariance, dtype=np.float64))
    if len(ranked) > 1:  # the best other axis-aligned rotation the refinement ended at
        k_run, run_cost = ranked[1][0], ranked[1][1].cost
    else:  # every start ended at the best: the best one not refined, at its cost as it comes (an upper bound)
        k_run = next(int(i) for i in order if int(i) not in refined and int(i) != k_best)
        run_cost = unexplained[k_run] * float(np.sum(blocks.d * blocks.d))
    chi2 = (run_cost - best.cost) / best.sigma**2
    runner = rotation_name(ROTATIONS[k_run])
    mirrors = frame_shares(blocks, b, w, [r.T for r in _MIRRORS])
    km = int(np.nanargmax(mirrors)) if np.isfinite(mirrors).any() else -1
    mirror = ""
    if km >= 0 and mirrors[km] >= MIN_EXPLAINED and (1.0 - mirrors[km]) <= FRAME_BETTER * (1.0 - share):
        mirror = ", ".join(f"{'xyz'[j]}->{_axis_name(_MIRRORS[km][:, j])}" for j in range(3))
    common = {"misalignment": delta, "covariance": cov, "explained": share, "chi2": chi2, "runner_up": runner,
              "mirror": mirror, "turn_axis": turn, "time_offset_s": float(best.p[6])}
    if mirror:
        return Mounting(None, "", **common, reason="a mirror image explains the turn: a wiring or sign fault")
    if not share >= MIN_EXPLAINED:
        return Mounting(None, "", **common, reason=_none_fits(blocks, b, w, share))
    if not chi2 >= DECIDE_CHI2:
        along = _axis_name(r0.T[:, "xyz".index(turn)]) if turn in ("x", "y", "z") else ""
        why = (f"the body turned about the imu's {turn} alone: the magnetometer's {along} lies along it, its rotation "
               "about that axis is not determined yet" if along
               else "the turns do not tell the best rotation from the next")
        return Mounting(None, "", **common, reason=(f"{why} ({rotation_name(r0)} against {runner}: chi2 {chi2:.1f} < "
                                                    f"{DECIDE_CHI2:g})"))
    return Mounting(r0, rotation_name(r0), **common)
