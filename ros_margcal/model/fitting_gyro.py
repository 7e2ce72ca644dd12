"""Gyro-aided magnetometer fitting: the rotation a gyro measured must turn the calibrated field with it.

The norm of the calibrated reading ``c = W (v - b)`` says nothing of the directions a robot never turns
through: a ground robot turning in yaw leaves the vertical gain, offset and (half of) the vertical cross
terms to the prior (``fitting_prior``). A gyro does. A field constant in the world frame, seen by a
sensor turning at the body rate ``omega``, obeys ``dc/dt = -omega x c``; in raw units, over a block of
consecutive samples ``v_0 .. v_m`` (trapezoid rule on each step ``j``: ``vbar_j``, ``omegabar_j`` the means
of samples ``j`` and ``j + 1``, ``theta_j = omegabar_j dt_j``; the true rate is ``(1 + kappa) omega - beta``
with the gyro's bias ``beta`` and scale errors ``kappa`` per axis, written below for ``kappa = 0``: with it,
``theta_j`` becomes ``(1 + kappa) theta_j``, ``S`` and ``Theta`` likewise)

    v_m - v_0 = -W^-1 sum_j (theta_j - beta dt_j) x W (vbar_j - b).

The block's residual is ``r = (v_m - v_0) + W^-1 u`` with ``u = sum_j (theta_j - beta dt_j) x W (vbar_j - b)``,
written in raw units so that its noise (two samples' white noise and the gyro's) does not depend on ``W``:
the residual ``W (v_m - v_0) + u`` would reward shrinking ``W`` along its noisy directions. ``u`` needs per block
only sums: ``S = sum_j theta_j vbar_j^T``, ``Theta = sum_j theta_j``, ``P = sum_j dt_j vbar_j``, ``T = sum_j dt_j``:

    u = axial(W S^T) - (Theta - T beta) x W b - beta x W P,    axial(N) = (N_zy - N_yz, N_xz - N_zx, N_yx - N_xy).

Blocks do not share samples, so their residuals are independent. Their noise is that of the two end
samples whatever the block's length, while the turn grows with it: long blocks weigh more (the stream's
``gyro_block_s`` is 1 s; the trapezoid rule on each sample step keeps the integral exact to second order).
The rate and the reading must be in one frame (a magnetometer and a gyro on different chips may not be):
``explained`` measures how much of the field's change the gyro accounts for, and a fit that finds too
little (``MIN_EXPLAINED``: swapped axes, a rate in deg/s) is not trusted. A magnetometer turned by a degree
or two against the IMU passes that check; the fit then pulls the calibration toward the IMU's frame as far
as a symmetric matrix can, which is the frame tilt compensation uses (the IMU's attitude): on the
independent generator with 1-3 deg of such misalignment (5 deg ring, seeds 11 and 13, a throwaway run)
the level heading p95 was 1.10 / 0.81, 2.10 / 1.66, 3.10 / 2.53 deg with the gyro against 1.65 / 1.72, 2.66 /
3.34, 3.67 / 5.09 deg without, at or below the best a symmetric calibration can reach. ``model.mounting``
estimates the rotation between the two frames from these blocks instead (which of the 24 axis-aligned rotations,
then the misalignment left, with ``frame_shares`` and ``rotated_blocks``), so that a magnetometer turned by 90 or
180 deg is named and can be calibrated into the IMU's frame.

On a robot turning in yaw with 5 deg of roll and pitch (the
independent generator of ``tests/independent``, 300 s, two tuning seeds, batch MAP fits, a throwaway
study) the level heading p95 went from 0.80 / 0.44 deg to 0.05 / 0.09 deg and at +-30 deg from 3.3 / 1.5 deg
to 0.12 / 0.19 deg with 1 s blocks (0.26 / 0.16 and 0.53 / 0.67 deg with 0.2 s blocks);
``scripts/bench_ground_robot.py --gyro`` measures the stream.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError
from .fitting_core import mad_sigma, unpack

__all__ = ["FRAME_BETTER", "GYRO_BIAS_STD", "GYRO_SCALE_STD", "MIN_EXPLAINED", "NAMED_MIN_SHARE",
           "SIGNED_PERMUTATIONS", "UNIT_ERRORS", "UNIT_NAMES", "GyroBlocks", "GyroTerm", "axial", "explained",
           "frame_advice", "frame_check", "frame_name", "frame_shares", "gyro_blocks", "gyro_residuals", "named_better",
           "rotated_blocks", "skew", "turning_share"]

Array = NDArray[np.float64]

GYRO_BIAS_STD = 0.05
"""Prior standard deviation of each gyro bias component, rad/s (about 3 deg/s: a MEMS gyro's turn-on bias)."""
GYRO_SCALE_STD = 0.02
"""Default prior standard deviation of each gyro scale error (MEMS gyro sensitivity tolerances: about
0.5-3 %). On a ring the yaw axis's is fixed by the turns; the horizontal axes' trade off against the
vertical gain (the wobble's rate scale against the field's vertical response), so this prior bounds what the
gyro can say at tilts not seen: on a 5 deg ring (two seeds, a throwaway run) a 3 % scale error on every axis,
unmodelled, left the level heading p95 at 0.07-0.11 deg but put it 2.3-2.8 deg off at 30 deg against a
predicted 0.6; with this prior the prediction there is 2.2-2.4 deg whatever the error (measured 0.4-0.5 deg
for a perfect gyro, 1.8-2.9 for 3 %)."""
MIN_EXPLAINED = 0.9
"""Least share of the field's change within blocks that the gyro must account for at a fit's solution; less
means the rate and the reading are not in one frame (or not in step), and the gyro is not used."""
FRAME_BETTER = 0.5
"""``frame_check``: another axis order or sign of the gyro is named (and the gyro not used) when it leaves at most
this share of the field's change unexplained that the gyro's own frame leaves."""
_GAP = 3.0  # a step longer than this many median steps ends a block: the samples are not consecutive
_E = [np.array(m, dtype=np.float64) for m in (  # d W / d (w_xx, w_yy, w_zz, w_xy, w_xz, w_yz)
    [[1, 0, 0], [0, 0, 0], [0, 0, 0]], [[0, 0, 0], [0, 1, 0], [0, 0, 0]], [[0, 0, 0], [0, 0, 0], [0, 0, 1]],
    [[0, 1, 0], [1, 0, 0], [0, 0, 0]], [[0, 0, 1], [0, 0, 0], [1, 0, 0]], [[0, 0, 0], [0, 0, 1], [0, 1, 0]])]
_E_STACK = np.stack(_E)
_E_STACK_T = _E_STACK.transpose(0, 2, 1)


@dataclass(frozen=True)
class GyroBlocks:
    """Per block of consecutive samples: ``d`` = v_m - v_0 (N, 3), ``theta`` = sum theta (N, 3), ``p`` = sum
    dt vbar (N, 3), ``t`` = sum dt (N,) (module docstring) and, in place of ``S = sum theta vbar^T``,
    ``ax[m, k]`` = axial(E_m S^T E_kk) for W's six basis matrices and the three gyro axes (6, 3, N, 3),
    computed once (``_axial_basis``); ``s`` = S itself (N, 3, 3) for ``frame_check``; ``s_dot`` = sum (omega_j+1 -
    omega_j) vbar_j^T (N, 3, 3) and ``theta_dot`` = omega_m - omega_0 (N, 3), what S and Theta gain per second of a
    time offset of the rates (``model.mounting``: the rate at ``t + tau``, first order in ``tau``)."""

    d: Array
    theta: Array
    p: Array
    t: Array
    ax: Array
    s: Array
    s_dot: Array
    theta_dot: Array

    def __len__(self) -> int:
        return len(self.t)


def gyro_blocks(t: ArrayLike, xyz: ArrayLike, gyro: ArrayLike, k: int) -> GyroBlocks:
    """The block sums of samples in time order (stamps (N,), raw readings and body rates in rad/s (N, 3)),
    ``k`` samples a block; a block holding a non-finite value (a sample without a rate: NaN), or a step
    longer than ``_GAP`` median steps or not increasing, is dropped.

    Raises:
        InputError: mismatched arrays, ``k`` < 2.
    """
    tt = np.asarray(t, dtype=np.float64).reshape(-1)
    v = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(gyro, dtype=np.float64).reshape(-1, 3)
    if not (len(tt) == len(v) == len(w)) or k < 2:
        msg = f"gyro blocks need stamps, readings and rates of one length and k >= 2, got {len(tt)}, {len(v)}, {len(w)}, k={k}"
        raise InputError(msg)
    nb = len(tt) // k
    empty = GyroBlocks(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((6, 3, 0, 3)),
                       np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
    if nb == 0:
        return empty
    n = nb * k
    tb, vb, wb = tt[:n].reshape(nb, k), v[:n].reshape(nb, k, 3), w[:n].reshape(nb, k, 3)
    finite = np.isfinite(tb).all(axis=1) & np.isfinite(vb).all(axis=(1, 2)) & np.isfinite(wb).all(axis=(1, 2))
    dt = np.diff(tb, axis=1)
    med = float(np.median(dt[finite])) if finite.any() else 0.0
    keep = finite & np.all(dt > 0, axis=1) & np.all(dt <= _GAP * med, axis=1) if med > 0 else np.zeros(nb, dtype=bool)
    if not keep.any():
        return empty
    tb, vb, wb, dt = tb[keep], vb[keep], wb[keep], dt[keep]
    vbar = 0.5 * (vb[:, 1:] + vb[:, :-1])
    th = 0.5 * (wb[:, 1:] + wb[:, :-1]) * dt[..., None]
    s = np.einsum("nji,njk->nik", th, vbar)
    dw = np.diff(wb, axis=1)
    return GyroBlocks(d=vb[:, -1] - vb[:, 0], theta=th.sum(axis=1), p=np.einsum("nj,nji->ni", dt, vbar),
                      t=dt.sum(axis=1), ax=_axial_basis(s), s=s, s_dot=np.einsum("nji,njk->nik", dw, vbar),
                      theta_dot=wb[:, -1] - wb[:, 0])


def axial(m: Array) -> Array:
    """``axial(N)`` of each (3, 3) ``N`` of ``m`` (..., 3, 3): ``(N_zy - N_yz, N_xz - N_zx, N_yx - N_xy)``, so that
    ``sum_j theta_j x (W vbar_j) = axial(W S^T)``."""
    return np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], axis=-1)


def skew(c: Array) -> Array:
    """``K`` with ``a @ K = a x c`` for rows ``a`` (N, 3)."""
    return np.array([[0.0, c[2], -c[1]], [-c[2], 0.0, c[0]], [c[1], -c[0], 0.0]]).T


_SKEW_E = np.stack([skew(e) for e in np.eye(3)])  # skew(e_i): skew(c) = sum_i c_i _SKEW_E[i]


def _axial_basis(s: Array) -> Array:
    """``axial(E_m S^T E_kk)`` of each block (6, 3, N, 3): ``axial(W S^T diag(1 + kappa))`` is linear in W's
    entries and in the gyro scale errors, so a residual evaluation needs contractions, no (N, 3, 3) product.
    ``S^T E_kk`` keeps only column k, row k of S (the gyro's axis k): ``axial(c e_k^T) = e_k x c`` with ``c = E_m s_k``."""
    out = np.empty((6, 3, len(s), 3))
    es = np.einsum("mij,nkj->mkni", _E_STACK, s)  # E_m s_k for every m, k: (6, 3, N, 3)
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3  # e_k x c = (.., c_j at i with +, c_i at j with -) cyclically
        out[:, k, :, k] = 0.0
        out[:, k, :, i] = -es[:, k, :, j]
        out[:, k, :, j] = es[:, k, :, i]
    return out


def gyro_residuals(blocks: GyroBlocks, b: Array, mat: Array, beta: Array, kappa: Array) -> tuple[Array, Array]:
    """Residuals (3N,: x, y, z of each block in turn, raw units) and their transposed Jacobian (15, 3N) over
    ``(b_x, b_y, b_z, w_xx, w_yy, w_zz, w_xy, w_xz, w_yz, beta_x, beta_y, beta_z, kappa_x, kappa_y, kappa_z)``
    (module docstring; the rate is ``(1 + kappa) omega - beta``, ``kappa`` the gyro's scale errors per axis).
    Cross products are row products with ``skew`` matrices, each group of Jacobian rows one stacked product:
    a fit evaluates this tens of times, and on a few hundred blocks numpy's per-call cost is most of it."""
    winv_t = np.linalg.inv(mat).T
    sc = 1.0 + kappa
    a = blocks.theta * sc - blocks.t[:, None] * beta  # Theta' - T beta
    w6 = np.array([mat[0, 0], mat[1, 1], mat[2, 2], mat[0, 1], mat[0, 2], mat[1, 2]])
    ax_w = np.einsum("k,mkni->mni", sc, blocks.ax)  # (6, N, 3): axial(E_m S'^T)
    beta_k = skew(beta)
    k_wb = skew(mat @ b)  # row k: e_k x W b
    u = np.tensordot(w6, ax_w, 1) - a @ k_wb + blocks.p @ (mat.T @ beta_k)  # beta x y = -y @ skew(beta)
    g = u @ winv_t  # W^-1 u
    r = blocks.d + g
    jt = np.empty((15, len(blocks), 3))
    jt[0:3] = a @ -np.tensordot(mat.T, _SKEW_E, 1)  # d u / d b_i = -(Theta' - T beta) x W e_i
    # d u / d W[e] = axial(e S'^T) - a x e b - beta x e P; dr = W^-1 (du - e g)
    jt[3:9] = (ax_w - a @ np.tensordot(_E_STACK @ b, _SKEW_E, 1) + blocks.p @ (_E_STACK_T @ beta_k)
               - g @ _E_STACK_T)
    jt[9:12] = ((blocks.p - blocks.t[:, None] * b) @ mat.T) @ _SKEW_E  # d u / d beta_i = [W (P - T b)] x e_i
    # d u / d kappa_k = axial(W S^T E_kk) - Theta_k e_k x W b
    jt[12:15] = np.tensordot(w6, blocks.ax, 1) - blocks.theta.T[:, :, None] * k_wb[:, None, :]
    return r.reshape(-1), (jt.reshape(-1, 3) @ winv_t).reshape(15, -1)


@dataclass
class GyroTerm:
    """The gyro blocks of a MAP fit (``fitting_prior``), the weight that brings their residuals' noise to the
    norm residuals' (``s / s_g``, ``s_g`` their MAD noise, re-estimated with ``s``), and where the gyro's bias
    and scale errors start in the fit's parameter vector."""

    blocks: GyroBlocks
    weight: float
    at: int

    def residuals(self, theta: Array) -> tuple[Array, Array]:
        """``gyro_residuals`` at the fit's parameters ``theta`` (the symmetric model's nine first)."""
        b, mat = unpack(theta[:9], "sym")
        return gyro_residuals(self.blocks, b, mat, theta[self.at:self.at + 3], theta[self.at + 3:self.at + 6])

    def reweigh(self, theta: Array, s: float, floor: float) -> None:
        """Bring the gyro residuals' noise at ``theta`` to ``s`` (at least ``floor``)."""
        self.weight = s / max(mad_sigma(self.residuals(theta)[0]), floor)


def explained(blocks: GyroBlocks, r: Array) -> float:
    """Share of the field's change within the blocks that the gyro accounts for, given the residuals ``r``
    at a solution: ``1 - sum r^2 / sum |d|^2`` (1: all of it; nan without change)."""
    total = float(np.sum(blocks.d * blocks.d))
    return 1.0 - float(np.sum(np.square(r))) / total if total > 0 else float("nan")


def turning_share(share: float, digits: int = 1) -> str:
    """``share`` (``explained``) as a status says it: "97.7 % of the field's turning", or for a negative share (a rate
    that predicts far more turning than the field shows) "none of the field's turning (misfit 55x the turning)":
    rates 57.3x too large read "-304702 %", a figure nobody can use."""
    if not share < 0.0:
        return f"{100 * share:.{digits}f} % of the field's turning"
    k = math.sqrt(1.0 - share)
    return f"none of the field's turning (misfit {k:.{0 if k >= 10.0 else 1}f}x the turning)"


def _signed_permutations() -> list[Array]:
    """The 48 signed permutation matrices (the 24 axis-aligned rotations and their mirror images), the
    identity first, then by how many axes they change (the simplest description of a frame wins a tie)."""
    out = []
    for perm in ((0, 1, 2), (1, 0, 2), (0, 2, 1), (2, 1, 0), (1, 2, 0), (2, 0, 1)):
        for signs in np.ndindex(2, 2, 2):
            m = np.zeros((3, 3))
            m[[0, 1, 2], list(perm)] = [1.0 - 2.0 * sg for sg in signs]
            out.append(m)
    return sorted(out, key=lambda m: int(np.sum(m != np.eye(3))))


_FRAMES = _signed_permutations()
SIGNED_PERMUTATIONS = tuple(_FRAMES)
"""The 48 signed permutation matrices, the identity first (``_signed_permutations``)."""


def frame_name(m: Array) -> str:
    """``(x, y, -z)``: the gyro's axes that give the magnetometer frame's x, y and z rates under ``m``."""
    return "(" + ", ".join(("-" if row[np.argmax(np.abs(row))] < 0 else "") + "xyz"[int(np.argmax(np.abs(row)))]
                           for row in m) + ")"


def frame_shares(blocks: GyroBlocks, offset: ArrayLike, matrix: ArrayLike, frames: list[Array]) -> list[float]:
    """``explained`` under the calibration ``(offset, matrix)`` of the rates taken as ``m omega`` for each ``m`` of
    ``frames`` (no bias or scale error): ``S' = m S``, ``Theta' = Theta m^T``, vectorised over blocks."""
    b = np.asarray(offset, dtype=np.float64)
    w = np.asarray(matrix, dtype=np.float64)
    if not frames:
        return []
    winv_t, k_wb = np.linalg.inv(w).T, skew(w @ b)
    st = w @ blocks.s.transpose(0, 2, 1)
    mt = np.stack(frames).transpose(0, 2, 1)  # every frame at once (F, 3, 3): one batched product, not F of them
    r = blocks.d + (axial(st[None] @ mt[:, None]) - blocks.theta @ (mt @ k_wb)) @ winv_t  # (F, N, 3)
    return [explained(blocks, rf) for rf in r]


def rotated_blocks(blocks: GyroBlocks, m: ArrayLike) -> GyroBlocks:
    """The blocks with the rates taken as ``m omega`` (a gyro whose frame is rotated against the magnetometer's:
    ``m`` maps the gyro's axes to the magnetometer's); the readings' sums are unchanged."""
    mm = np.asarray(m, dtype=np.float64)
    s = np.einsum("ij,njk->nik", mm, blocks.s)
    return GyroBlocks(d=blocks.d, theta=blocks.theta @ mm.T, p=blocks.p, t=blocks.t, ax=_axial_basis(s), s=s,
                      s_dot=np.einsum("ij,njk->nik", mm, blocks.s_dot), theta_dot=blocks.theta_dot @ mm.T)


NAMED_MIN_SHARE = 0.5
"""``frame_check`` names another frame or unit only when it explains at least this share of the field's turning: a real
log with samples 0.52 s apart, whose own rates explained -1941x, had "57.3x smaller" named at -91 % (far better
than its own, explaining nothing)."""
UNIT_ERRORS = ((180.0 / math.pi, "57.3x larger"), (math.pi / 180.0, "57.3x smaller"))
"""Rates in the wrong unit, as ``frame_check`` names them: the factor that explains them, and its name (a real
VN-100 log had its rad/s converted from deg/s twice: 57.3x too small, its own frame explained 3 % of a car's turns,
the rates taken 57.3x larger 76 %; a rate in deg/s published as rad/s is 57.3x too large)."""
UNIT_NAMES = frozenset(name for _, name in UNIT_ERRORS)
"""``frame_check``'s names of a rate in the wrong unit."""
_CHECKED = _FRAMES + [f * np.eye(3) for f, _ in UNIT_ERRORS]
_CHECKED_NAMES = [frame_name(m) for m in _FRAMES] + [name for _, name in UNIT_ERRORS]
"""What ``frame_check`` scores (the 48 signed axis orders, then the units) and their names."""


def frame_check(blocks: GyroBlocks, offset: ArrayLike, matrix: ArrayLike) -> tuple[str, float, float]:
    """Does another axis order or sign of the gyro, or another unit, explain the field's turning under the calibration
    ``(offset, matrix)`` far better than its own frame? Each of the 48 signed permutations ``m`` of the rate (``m
    omega``, no bias or scale error), and the rate in its own axes times each factor of ``UNIT_ERRORS``, is scored by
    ``explained``; the best is returned when its unexplained share is at most ``FRAME_BETTER`` of the gyro's own
    frame's: (its name, e.g. ``"(x, y, -z)"`` or ``"57.3x larger"``, its share, the own frame's share), else ``("",
    nan, own share)``. Vectorised over blocks: microseconds per frame."""
    if not len(blocks):
        return "", float("nan"), float("nan")
    shares = frame_shares(blocks, offset, matrix, _CHECKED)
    own = shares[0]
    if not np.isfinite(shares).any():
        return "", float("nan"), own
    k = int(np.nanargmax(shares))
    if k == 0 or not named_better(shares[k], own):
        return "", float("nan"), own
    return _CHECKED_NAMES[k], shares[k], own


def named_better(share: float, own: float) -> bool:
    """Is another frame or unit that explains ``share`` of the turning worth naming against the rates' own ``own``:
    at most ``FRAME_BETTER`` of the own frame's unexplained share left, and at least ``NAMED_MIN_SHARE`` explained."""
    return (1.0 - share) <= FRAME_BETTER * (1.0 - own) and share >= NAMED_MIN_SHARE


def frame_advice(name: str) -> str:
    """What a ``frame_check`` name tells the user to check: the IMU's frame, or the rates' unit."""
    if name == UNIT_ERRORS[0][1]:
        return f"taken {name}: the rates converted from deg/s to rad/s twice?"
    if name == UNIT_ERRORS[1][1]:
        return f"taken {name}: the rates in deg/s, not rad/s (REP-103)?"
    return f"taken as {name} of the IMU's axes: IMU frame flipped or rotated against the magnetometer?"
