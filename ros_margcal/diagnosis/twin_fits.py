"""The calibration a twin is built from: the fits of a recording, or of the two sides of an offset change.

``build_twin`` (``twin``) needs one calibration that describes the recording: the ``sym`` fit, or, when
``lm`` does not converge, the closed-form fits (``_closed_form_fits``: strong clipping or non-linearity),
or the fits of the two sides of a located offset change (``_segment_fits``, a magnet attached mid-way).
A located change must beat the no-change twin (``_change_survives_twin``): the recording's
one-shape-two-centres drop must exceed, by ``CHANGE_EVIDENCE``, the drop a twin simulated without a change
shows. ``smooth_directions`` gives the directions every twin is simulated along.

A static recording (the sensor never moved: one direction plus noise) has no twin: any ellipsoid fits
a cloud of noise, and the effects fitted to it would name a confident cause for what is noise alone.
``static_reason`` tells it apart before any fit, and ``build_twin`` refuses it (``StaticRecording``).
"""

from __future__ import annotations

import itertools
import logging

import numpy as np
from numpy.typing import NDArray
from scipy.signal import savgol_filter

from ..model.calibration import Calibration
from ..model.errors import DegenerateDataError, MargCalError
from ..model.fitting import fit
from ..sim.simulation import simulate
from .changes import OffsetChange, locate_offset_change, moving_mask
from .fit_checks import checked_sym, lm_diag
from .stages import rest_noise

__all__ = [
    "CHANGE_EVIDENCE", "MAX_ITER", "MIN_SAMPLES", "SMOOTH_WINDOW", "STATIC_NOISE_SHARE", "STATIC_SPREAD",
    "StaticRecording", "smooth_directions", "static_reason"
]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

MIN_SAMPLES = 50
"""Fewest samples a side of an offset change (or a recording) needs to be fitted."""
SMOOTH_WINDOW = 31
"""Samples of the direction smoothing window (0.3 s at 100 Hz)."""
MAX_ITER = 400
"""Levenberg-Marquardt iterations of the twin's fits."""
CHANGE_EVIDENCE = 0.3
"""Share of the single fit's residual an offset change must remove beyond what the best split removes on
the no-change twin (``_change_survives_twin``)."""
_GUARD = 0.05
"""Share of the moving span left out on either side of an offset change when its sides are fitted."""
STATIC_SPREAD = 3.0
"""Largest spread of the readings (the std along their widest axis), in multiples of their white noise, of a
static recording: about 1 for noise alone (real static HMC5883L and MPU6050 logs: 1.1-1.4), more than 10 for
any recording that turns (60-480 on the real ones, 12 on a sparse one of 1600 samples)."""
STATIC_NOISE_SHARE = 0.05
"""Largest white noise (from second differences) of a static recording, as a share of the mean reading's
norm (real static logs: 0.3-0.5 %). A set whose samples are out of time order (a shuffled coverage pattern)
has "noise" of the size of its spread, about the field itself, and is not static."""


class StaticRecording(DegenerateDataError):
    """The recording is static: the sensor did not move, so it has no twin (``static_reason``)."""


def static_reason(raw: Array) -> str:
    """Why ``raw`` (n, 3) is a static recording ("static: the sensor did not move ..."), or "" when it moved.

    Static: the readings spread no more than ``STATIC_SPREAD`` times their white noise (second
    differences, ``stages.rest_noise``) along their widest axis, and that noise is at most
    ``STATIC_NOISE_SHARE`` of the mean reading (else the samples are out of time order and the second
    differences measured the motion). Needs no fit: an ellipsoid fitted to a cloud of noise exists.
    """
    pts = np.asarray(raw, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 5:
        return ""
    centred = pts - pts.mean(axis=0)
    spread = float(np.sqrt(max(float(np.linalg.eigvalsh(centred.T @ centred / len(pts))[-1]), 0.0)))
    white = rest_noise(pts)
    level = float(np.linalg.norm(pts.mean(axis=0)))
    one = not np.ptp(pts, axis=0).any()  # one reading throughout (its spread above is rounding, ~1e-19 T)
    if not (one or (spread <= STATIC_SPREAD * white and white <= STATIC_NOISE_SHARE * level)):
        return ""
    ratio = f"spread {spread / white:.1f} times their noise" if white > 0 else "spread no more than their noise"
    return (f"static: the sensor did not move (its readings {'are one value' if one else ratio}, one direction "
            "throughout); a diagnosis needs a recording that turns the sensor through many directions. A static "
            "recording measures the rest noise: pass it as --rest-recording with a recording that turns")


def smooth_directions(h: Array, window: int = SMOOTH_WINDOW, t: Array | None = None) -> Array:
    """Unit directions of calibrated vectors ``h`` (n, 3), their noise smoothed out along time.

    A Savitzky-Golay filter (quadratic, ``window`` samples) keeps the motion and removes most of the
    noise: otherwise the twin would carry the recording's noise in its directions plus its own. With
    times ``t``, stretches separated by a gap (more than 3 median steps, e.g. the moves an inactivity
    gate removed) are smoothed separately.
    """
    h = np.array(h, dtype=np.float64)
    n = h.shape[0]
    cuts = [0, n]
    if t is not None and n > 2:
        dt = np.diff(t)
        med = float(np.median(dt))
        cuts = [0, *(np.flatnonzero(dt > 3 * med) + 1).tolist(), n] if med > 0 else cuts
    for lo, hi in itertools.pairwise(cuts):
        m = hi - lo
        w = min(window, m if m % 2 else m - 1)
        if w >= 5:
            h[lo:hi] = savgol_filter(h[lo:hi], w, 2, axis=0, mode="interp")
    lengths = np.linalg.norm(h, axis=1, keepdims=True)
    return h / np.where(lengths > 0, lengths, 1.0)


def _change_message(change: OffsetChange, exc: Exception) -> str:
    return (f"the recording cannot be fitted ({exc}): it seems to contain an offset change at t \u2248 {change.t:.1f} s "
            f"(a step of {change.step:.3g} raw units, {change.relative_step:.0%} of the field radius; a hard-iron "
            "change such as a magnet attached or moved near the sensor), so no single calibration fits it; "
            f"diagnose the parts before and after t \u2248 {change.t:.1f} s separately")


def _side_fit(
    times: Array, pts: Array, idx: NDArray[np.intp], norm: float | None, sensor: str, depth: int = 1,
) -> tuple[Calibration, Calibration]:
    """Best (``sym``, else ``diag``) and baseline (``diag``) fits of the samples ``idx``; when ``lm``
    does not converge, those of the larger part around their own offset change (``depth`` more levels:
    a magnet attached and removed again makes two changes), else the closed-form ``lin_auto`` fits
    (a side that covers only part of the sphere)."""
    try:
        diag = lm_diag(pts[idx], norm, sensor=sensor, max_iter=MAX_ITER)
    except MargCalError:
        inner = locate_offset_change(times[idx], pts[idx]) if depth > 0 else None
        if inner is None:
            diag = fit(pts[idx], model="diag", method="lin_auto", norm=norm, sensor=sensor)
            return diag, diag  # the directions of a side on part of the sphere: the baseline fit's
        ti = times[idx]
        span = float(np.ptp(ti))
        parts = [idx[ti < inner.t - _GUARD * span], idx[ti > inner.t + _GUARD * span]]
        return _side_fit(times, pts, max(parts, key=len), norm, sensor, depth - 1)
    try:
        sym = checked_sym(fit(pts[idx], model="sym", method="lm", norm=norm, max_iter=MAX_ITER), pts[idx], norm)
    except MargCalError:
        sym = diag
    return sym, diag


def _located_change(
    times: Array, pts: Array, sub: NDArray[np.intp], norm: float | None, sensor: str,
) -> OffsetChange | None:
    """The offset change of the subsample ``sub`` when one is located and beats the no-change twin."""
    change = locate_offset_change(times[sub], pts[sub])
    if change is not None and not _change_survives_twin(times, pts, sub, change, norm, sensor):
        log.info("offset change at t = %.2f s rejected: the no-change twin splits as well", change.t)
        return None
    return change


def _change_survives_twin(
    times: Array, pts: Array, sub: NDArray[np.intp], change: OffsetChange, norm: float | None, sensor: str,
) -> bool:
    """Whether a located offset change beats the no-change twin: the recording's one-shape-two-centres
    drop must exceed, by ``CHANGE_EVIDENCE``, the best split's drop on a twin simulated from one
    closed-form fit of the whole recording (same directions, times and rest noise, no change). A split
    that noise, the turning or the slow noise alone can make fails the test."""
    try:
        cal = fit(pts[sub], model="diag", method="lin_auto", norm=norm, sensor=sensor)
    except MargCalError:
        return True  # no twin to test against: the shared-shape evidence stands
    ts = times[sub]
    dirs = smooth_directions(cal.apply(pts[sub]), t=ts)
    noise = rest_noise(pts) / cal.raw_radius
    raw0 = simulate(cal, dirs, noise=noise, rng=np.random.default_rng(0), t=ts).raw
    null = locate_offset_change(ts, raw0, min_drop=0.0, min_shared_drop=0.0, min_sectors=0)
    null_drop = null.shared_drop if null is not None else 0.0
    log.debug("offset change: shared drop %.3f against the no-change twin's %.3f", change.shared_drop, null_drop)
    return change.shared_drop > null_drop + CHANGE_EVIDENCE


def _closed_form_fits(
    pts: Array, sub: NDArray[np.intp], norm: float | None, sensor: str, exc: Exception,
) -> tuple[Calibration, Calibration, Array]:
    """Best and baseline fits, both the closed-form ``lin_auto`` diag fit (it always gives an answer on a
    recording that turns), used when ``lm`` does not converge and no offset change explains why (a strong
    non-ellipsoidal effect: clipping, a cubic non-linearity; a band of tilts); the calibrated vectors of
    every sample. The algebraic ``sym`` fit is not the best fit here: on part of the sphere it bends its
    shape to what a non-linearity or a drift leaves, and the twin would carry that as its baseline.

    Raises:
        DegenerateDataError: the closed form fails too (e.g. a static recording).
    """
    try:
        truth = fit(pts[sub], model="diag", method="lin_auto", norm=norm, sensor=sensor)
    except MargCalError as exc2:
        msg = (f"the recording cannot be fitted ({exc}; closed form: {exc2}); a diagnosis needs a recording that "
               "turns the sensor through many directions (a static recording only gives rest noise and quantisation)")
        raise DegenerateDataError(msg) from exc2
    log.info("lm does not converge (%s) and no offset change explains it: closed-form fits", exc)
    return truth, truth, truth.apply(pts)


def _segment_fits(
    times: Array, pts: Array, sub: NDArray[np.intp], change: OffsetChange, norm: float | None, sensor: str,
) -> tuple[Calibration, Calibration, Array]:
    """Fits of the two sides of an offset change: the reference side's best and baseline fits, and the
    calibrated vectors (n, 3) of every sample, each side with its own best fit.

    The reference side is the one with more moving samples (``changes.moving_mask``); each side is
    fitted on its moving samples of the subsample only (a still stretch adds one point, possibly with
    the other offset if the change happened while still), leaving out ``_GUARD`` of the moving span on
    either side of the change (``_side_fit``). When the other side cannot be fitted, its vectors use the
    reference side's best fit moved to the other side's centre (``OffsetChange.offset_after``/``before``).

    Raises:
        MargCalError: the reference side cannot be fitted.
    """
    ts = times[sub]
    moving = moving_mask(ts, pts[sub])
    after = ts >= change.t
    span = float(np.ptp(ts[moving])) if moving.any() else 0.0
    clear = np.abs(ts - change.t) > _GUARD * span  # the change is located only roughly
    masks = (~after, after)
    ref = int(np.count_nonzero(after & moving) > np.count_nonzero(~after & moving))
    cals: list[Calibration | None] = [None, None]
    for k in (ref, 1 - ref):
        idx = sub[masks[k] & moving & clear]
        if idx.size < MIN_SAMPLES:
            idx = sub[masks[k]]
        if k == ref:
            best, truth = _side_fit(times, pts, idx, norm, sensor)
            cals[k] = best
            continue
        try:
            cals[k] = _side_fit(times, pts, idx, norm, sensor)[0]
        except MargCalError:
            shift = change.offset_after - change.offset_before
            cals[k] = best.replace(offset=best.offset + (shift if k == 1 else -shift))
    cut = int(np.searchsorted(times, change.t))
    h = np.vstack([cals[0].apply(pts[:cut]), cals[1].apply(pts[cut:])])  # type: ignore[union-attr]
    return best, truth, h
