"""The simulated twin of a recording: same directions and timestamps, the simulator's baseline model.

From the recording's own fits (``fitting.fit`` on an evenly spaced subsample):

- the *directions* come from the best fit (``sym``, or ``diag`` when ``sym`` does not converge, e.g. on a
  heavily clipped recording): ``d_i = W (v_i - b) / |W (v_i - b)|``, smoothed along time
  (``smooth_directions``) so the twin does not inherit the recording's noise;
- the *twin's true sensor* is the baseline model, offset + gains (the ``diag`` fit);
- the *noise* is white, at the recording's rest-noise level (``stages.rest_noise``, or a level the
  caller measured at rest, e.g. from a static recording of the same sensor).

A recording without time continuity (consecutive samples more than ``MAX_STEP_DEG`` apart, e.g. a
coverage pattern written with made-up timestamps) keeps its directions unsmoothed, skips the
``rest_noise`` stage (second differences would measure the motion) and, unless the caller gives the
rest noise, takes the twin's noise from the best fit's residual; ``Twin.skipped`` says why.

``Twin.features(effects, seed)`` simulates the twin (``simulation.simulate`` with the recording's
timestamps and temperature, optionally with effects from the registry) and returns its stage
features; ``Twin.spread`` gives the baseline's mean and spread over several seeds, the yardstick of
every gap.
"""

from __future__ import annotations

import itertools
import logging
import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.signal import savgol_filter

from ..model.calibration import Calibration
from ..model.errors import DegenerateDataError, InputError, MargCalError, as_points
from ..model.fitting import fit
from ..sim.effects import check_effects, sensor_model
from ..sim.simulation import simulate
from .baseline_noise import ar1_noise, estimate_slow_noise, shaped_truth
from .changes import OffsetChange, locate_offset_change, moving_mask
from .stages import StageFeatures, rest_noise, stage_features

__all__ = [
    "CHANGE_EVIDENCE", "FIT_ERRORS", "MAX_STEP_DEG", "Baseline", "Twin", "build_twin", "mean_features",
    "median_step_deg", "smooth_directions", "subsample"
]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

FIT_ERRORS = (MargCalError, np.linalg.LinAlgError, ValueError, FloatingPointError, ZeroDivisionError)
"""What a twin simulation or fit may raise on odd data; caught so that a diagnosis always gives a verdict."""
DEFAULT_N_FIT = 6000
"""Samples the fitting stages use (evenly spaced in time); the read-out stages use every sample."""
MIN_SAMPLES = 50
SMOOTH_WINDOW = 31
"""Samples of the direction smoothing window (0.3 s at 100 Hz)."""
MAX_STEP_DEG = 10.0
"""Median angle between consecutive samples above which a recording has no time continuity: its rest
noise cannot be measured from second differences and its directions are not smoothed."""
_MAX_ITER = 400
_SHAPE_ITER = 200
CHANGE_EVIDENCE = 0.3
"""Share of the single fit's residual an offset change must remove beyond what the best split removes on
the no-change twin (``_change_survives_twin``)."""
_SLOW_TAU_SPREAD = 2.0
_GUARD = 0.05
"""Share of the moving span left out on either side of an offset change when its sides are fitted."""


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


def median_step_deg(h: Array) -> float:
    """Median angle between consecutive vectors of ``h`` (n, 3), degrees: small for a time series of a
    turning sensor, ~90 for directions in random order (e.g. a coverage pattern without time)."""
    if h.shape[0] < 2:
        return 0.0
    a, b = h[:-1], h[1:]
    cos = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
    return float(np.degrees(np.median(np.arccos(np.clip(cos, -1.0, 1.0)))))


def subsample(n: int, n_fit: int) -> NDArray[np.intp]:
    """Evenly spaced indices, at most ``n_fit`` of ``n`` (all when n <= n_fit)."""
    if n <= n_fit:
        return np.arange(n, dtype=np.intp)
    return np.unique(np.linspace(0, n - 1, n_fit).round().astype(np.intp))


def mean_features(items: list[StageFeatures]) -> tuple[dict[str, Array], dict[str, Array]]:
    """Mean and sample std (ddof=1; zeros for one item) of the stage features over twin seeds."""
    names = set(items[0].values)
    for it in items[1:]:
        names &= set(it.values)
    mean, sd = {}, {}
    for name in names:
        stack = np.array([it.values[name] for it in items])
        with warnings.catch_warnings():  # a feature that is NaN for every seed stays NaN (its gap is then 0)
            warnings.simplefilter("ignore", RuntimeWarning)
            mean[name] = np.nanmean(stack, axis=0)
            sd[name] = np.nanstd(stack, axis=0, ddof=1) if len(items) > 1 else np.zeros(stack.shape[1])
    return mean, sd


@dataclass
class Baseline:
    """The effect-free twin over several seeds: the yardstick of every gap.

    Attributes:
        seeds: the seeds simulated.
        features: their stage features.
        mean: stage -> mean features over ``seeds[:n_mean]`` (the seeds effects are compared on).
        sd: stage -> spread over all seeds.
    """

    seeds: tuple[int, ...]
    features: list[StageFeatures]
    mean: dict[str, Array]
    sd: dict[str, Array]


@dataclass
class Twin:
    """A recording's simulated twin (see the module docstring).

    Attributes:
        t: times (n,), seconds.
        raw: the recording's raw readings (n, 3).
        temp: its temperature (n,) or None.
        sub: indices of the fitting subsample.
        truth: the twin's true sensor (baseline model: the ``diag`` fit of the recording).
        best: the recording's best (``sym``, else ``diag``) fit, which gives the directions.
        dirs: (n, 3) unit directions.
        noise: white noise std, fraction of the field radius.
        sensor: "mag" or "accel".
        norm: the reference norm given by the user, or None (estimated).
        validator: the validator of the ``validator`` stage, or None.
        features_rec: the recording's own stage features.
        skipped: stage -> why it is left out for this recording (e.g. no time continuity).
        change: the offset change found when no single calibration fits the recording (then ``truth``
            and ``best`` are the fits of the side with more motion, the directions come from each
            side's own fit, and the stage features use the closed-form ``lin_auto`` fit in place of
            ``lm``, for the recording and the twin alike), else None.
        closed_form: the stage features use the closed-form ``lin_auto`` fit (an offset change, or a
            recording ``lm`` does not converge on: strong clipping or non-linearity), twin and recording alike.
        slow_noise: (std as a fraction of the field radius, correlation time in s) of the slow (AR(1),
            Gauss-Markov) noise the twin adds to the white noise (``estimate_slow_noise``); std 0: none.
        noise_measured: ``noise`` was measured on the recording (not given by the caller): a twin with
            the ``quantization`` effect then takes the rounding's share out of it.
    """

    t: Array
    raw: Array
    temp: Array | None
    sub: NDArray[np.intp]
    truth: Calibration
    best: Calibration
    dirs: Array
    noise: float
    sensor: str
    norm: float | None
    validator: object | None
    features_rec: StageFeatures
    skipped: dict[str, str] = field(default_factory=dict)
    change: OffsetChange | None = None
    closed_form: bool = False
    slow_noise: tuple[float, float] = (0.0, 1.0)
    noise_measured: bool = False
    _cache: dict[tuple[tuple[tuple[str, float], ...], int], StageFeatures] = field(default_factory=dict, repr=False)

    def features(self, effects: dict[str, float] | None, seed: int) -> StageFeatures:
        """Stage features of the twin simulated with ``effects`` on ``np.random.default_rng(seed)``."""
        key = (tuple(sorted((k, float(v)) for k, v in (effects or {}).items() if v > 0)), int(seed))
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        rng = np.random.default_rng(seed)
        noise = self.noise
        lsb = dict(key[0]).get("quantization", 0.0)
        if self.noise_measured and lsb > 0:  # the measured rest noise holds the rounding's own (LSB^2 / 12)
            noise = math.sqrt(max(noise**2 - lsb**2 / 12.0, 0.1 * noise**2))
        if self.slow_noise[0] > 0:  # an offset that wanders, before the read-out (quantisation, clipping)
            # the correlation time is known only roughly: the seeds spread it over a factor of four, so the
            # baseline's spread holds that uncertainty too
            tau = self.slow_noise[1] * _SLOW_TAU_SPREAD ** ((int(seed) % 3) - 1)
            slow = ar1_noise(self.t, self.slow_noise[0] * self.truth.raw_radius, tau,
                             np.random.default_rng([int(seed), 1001]))
            raw = sensor_model(self.truth, self.dirs * self.truth.norm, self.t, rng, noise,
                               check_effects(dict(key[0]), self.truth.sensor), self.temp, extra_offset=slow)[0]
        else:
            raw = simulate(self.truth, self.dirs, noise=noise, rng=rng, t=self.t, effects=dict(key[0]),
                           temperature=self.temp).raw
        if not np.isfinite(raw).all():
            msg = f"the simulator produced non-finite readings for effects {dict(key[0])}"
            raise InputError(msg)
        out = stage_features(self.t, raw, self.temp, self.sub, validator=self.validator, norm=self.norm,
                             skip=frozenset(self.skipped), closed_form=self.closed_form)
        self._cache[key] = out
        return out

    def try_features(self, effects: dict[str, float] | None, seed: int) -> StageFeatures | None:
        """``features``, or None when the twin with these effects cannot be fitted (a strong effect)."""
        try:
            return self.features(effects, seed)
        except FIT_ERRORS as exc:
            log.debug("twin with %s, seed %d: %s", effects, seed, exc)
            return None

    def spread(self, n_seeds: int = 6) -> Baseline:
        """The baseline twin over seeds ``0 .. n_seeds-1``.

        When ``lm`` does not converge on a baseline twin (its features would be missing for one seed),
        the recording and its twins are measured with the closed-form fit instead (``closed_form``).
        """
        seeds = tuple(range(max(2, n_seeds)))
        try:
            feats = [self.features(None, s) for s in seeds]
        except MargCalError as exc:
            if self.closed_form:
                raise DegenerateDataError(self._unusable(exc)) from exc
            log.info("a baseline twin cannot be fitted by lm (%s): closed-form fits for recording and twins", exc)
            self.closed_form = True
            self._cache.clear()
            try:
                self.features_rec = stage_features(self.t, self.raw, self.temp, self.sub, validator=self.validator,
                                                   norm=self.norm, skip=frozenset(self.skipped), closed_form=True)
                feats = [self.features(None, s) for s in seeds]
            except MargCalError as exc2:
                raise DegenerateDataError(self._unusable(exc2)) from exc2
        mean, sd = mean_features(feats)
        return Baseline(seeds=seeds, features=feats, mean=mean, sd=sd)

    def _unusable(self, exc: Exception) -> str:
        return (f"the baseline twin cannot be fitted ({exc}); the recording's directions or noise level "
                f"(rest noise {self.noise:.3g} of the field radius) do not make a usable twin")


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
        diag = fit(pts[idx], model="diag", method="lm", norm=norm, sensor=sensor, max_iter=_MAX_ITER)
    except MargCalError:
        inner = locate_offset_change(times[idx], pts[idx]) if depth > 0 else None
        if inner is None:
            diag = fit(pts[idx], model="diag", method="lin_auto", norm=norm, sensor=sensor)
            try:
                return fit(pts[idx], model="sym", method="lin_auto", norm=norm), diag
            except MargCalError:
                return diag, diag
        ti = times[idx]
        span = float(np.ptp(ti))
        parts = [idx[ti < inner.t - _GUARD * span], idx[ti > inner.t + _GUARD * span]]
        return _side_fit(times, pts, max(parts, key=len), norm, sensor, depth - 1)
    try:
        sym = fit(pts[idx], model="sym", method="lm", norm=norm, max_iter=_MAX_ITER)
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
    null = locate_offset_change(ts, raw0, min_drop=0.0, min_shared_drop=0.0)
    null_drop = null.shared_drop if null is not None else 0.0
    log.debug("offset change: shared drop %.3f against the no-change twin's %.3f", change.shared_drop, null_drop)
    return change.shared_drop > null_drop + CHANGE_EVIDENCE


def _closed_form_fits(
    pts: Array, sub: NDArray[np.intp], norm: float | None, sensor: str, exc: Exception,
) -> tuple[Calibration, Calibration, Array]:
    """Best and baseline fits by the closed-form ``lin_auto`` (it always gives an answer on a recording
    that turns), used when ``lm`` does not converge and no offset change explains why (a strong
    non-ellipsoidal effect: clipping, a cubic non-linearity); the calibrated vectors of every sample.

    Raises:
        DegenerateDataError: the closed form fails too (e.g. a static recording).
    """
    try:
        truth = fit(pts[sub], model="diag", method="lin_auto", norm=norm, sensor=sensor)
    except MargCalError as exc2:
        msg = (f"the recording cannot be fitted ({exc}; closed form: {exc2}); a diagnosis needs a recording that "
               "turns the sensor through many directions (a static recording only gives rest noise and quantisation)")
        raise DegenerateDataError(msg) from exc2
    try:
        best = fit(pts[sub], model="sym", method="lin_auto", norm=norm)
    except MargCalError:
        best = truth
    log.info("lm does not converge (%s) and no offset change explains it: closed-form fits", exc)
    return best, truth, best.apply(pts)


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


def build_twin(
    t: Array,
    raw: Array,
    *,
    sensor: str,
    temp: Array | None = None,
    norm: float | None = None,
    rest_noise_raw: float | None = None,
    n_fit: int = DEFAULT_N_FIT,
    validator: object | None = None,
    shape_tolerance: float = 0.0,
) -> Twin:
    """Fit the recording and set up its twin.

    Args:
        t: times (n,), seconds, non-decreasing.
        raw: raw readings (n, 3).
        sensor: "mag" or "accel" (restricts the effects that apply).
        temp: temperature (n,), °C, or None.
        norm: reference norm of the calibrated vector (None: estimated).
        rest_noise_raw: white noise std at rest in raw units (None: estimated from the recording, with its
            slow part, ``baseline_noise.estimate_slow_noise``; given: the whole noise model, white).
        n_fit: samples for the fitting stages.
        validator: validator for the ``validator`` stage (None skips it).
        shape_tolerance: cross-axis terms of the sensor's baseline (``shaped_truth``; 0: offset and gains only).

    Raises:
        InputError: bad shapes, non-finite values, a bad rest noise.
        DegenerateDataError: too few samples, or directions that cannot determine a fit.
    """
    pts = as_points(raw, "raw")
    n = pts.shape[0]
    times = np.asarray(t, dtype=np.float64).reshape(-1)
    if times.shape != (n,) or not np.isfinite(times).all():
        msg = f"t must hold {n} finite times, got shape {times.shape}"
        raise InputError(msg)
    if n < MIN_SAMPLES:
        msg = f"a diagnosis needs at least {MIN_SAMPLES} samples, got {n}"
        raise DegenerateDataError(msg)
    tmp = None if temp is None else np.asarray(temp, dtype=np.float64).reshape(-1)
    if tmp is not None and (tmp.shape != (n,) or not np.isfinite(tmp).all()):
        msg = f"temperature must hold {n} finite values"
        raise InputError(msg)
    sub = subsample(n, n_fit)
    change: OffsetChange | None = None
    unfitted = ""  # an offset change whose sides cannot be fitted: reported, the twin fits the whole
    closed_form = False
    searched = False  # whether the offset change has been searched (it is searched once)
    try:
        truth = fit(pts[sub], model="diag", method="lm", norm=norm, sensor=sensor, max_iter=_MAX_ITER)
        try:
            best = fit(pts[sub], model="sym", method="lm", norm=norm, max_iter=_MAX_ITER)
        except MargCalError as exc_sym:
            change, searched = _located_change(times, pts, sub, norm, sensor), True
            if change is not None:
                raise
            # no offset step (e.g. a heavily clipped recording): the baseline fit gives the directions
            log.info("the sym fit does not converge (%s): directions from the diag fit", exc_sym)
            best = truth
        h = best.apply(pts)
    except MargCalError as exc:
        if not searched:
            change = _located_change(times, pts, sub, norm, sensor)
        if change is not None:
            try:
                best, truth, h = _segment_fits(times, pts, sub, change, norm, sensor)
            except MargCalError as exc2:  # no side fits: one closed-form fit of the whole, the change reported
                log.info("the sides of the offset change cannot be fitted (%s)", exc2)
                best, truth, h = _closed_form_fits(pts, sub, norm, sensor, exc)
                unfitted = _change_message(change, exc)
                change = None
            else:
                log.info("offset change at t = %.2f s (step %.3g of the field radius): the twin is the fit of one "
                         "side", change.t, change.relative_step)
        else:
            best, truth, h = _closed_form_fits(pts, sub, norm, sensor, exc)
        closed_form = True
    step = median_step_deg(h)
    skipped: dict[str, str] = {}
    if unfitted:
        skipped["offset_change"] = unfitted
    if np.ptp(times) <= 0:
        skipped["residual_time"] = "the recording has no time span (all timestamps equal)"
    if step > MAX_STEP_DEG:
        skipped["rest_noise"] = (
            f"no time continuity: consecutive samples point {step:.0f} deg apart (median; a turning sensor "
            f"sampled as a time series moves < {MAX_STEP_DEG:.0f} deg), so second differences measure the motion, "
            "not the noise" + ("" if rest_noise_raw is not None else
                              "; the twin's noise is the best fit's residual (pass the rest noise to test "
                              "the noise effect)"))
        lengths = np.linalg.norm(h, axis=1, keepdims=True)
        dirs = h / np.where(lengths > 0, lengths, 1.0)
    else:
        dirs = smooth_directions(h, t=times)
    try:
        features_rec = stage_features(times, pts, tmp, sub, validator=validator, norm=norm, skip=frozenset(skipped),
                                      closed_form=closed_form)
    except MargCalError as exc:
        if closed_form:
            msg = (f"the recording's stage features cannot be computed ({exc})"
                   + ("" if change is None else f"; {_change_message(change, exc)}"))
            raise DegenerateDataError(msg) from exc
        log.info("the recording's stage features need the closed-form fit (%s)", exc)
        closed_form = True
        features_rec = stage_features(times, pts, tmp, sub, validator=validator, norm=norm, skip=frozenset(skipped),
                                      closed_form=True)
    r_raw = truth.raw_radius
    if rest_noise_raw is None:
        if "rest_noise" in skipped:
            rms = best.stats.rms_relative if best.stats is not None else 0.0
            noise = float(rms) * best.raw_radius / r_raw
        else:
            noise = rest_noise(pts) / r_raw
    else:
        if not (math.isfinite(rest_noise_raw) and rest_noise_raw >= 0):
            msg = f"rest noise must be a non-negative std in raw units, got {rest_noise_raw!r}"
            raise InputError(msg)
        noise = float(rest_noise_raw) / r_raw
    if not (math.isfinite(shape_tolerance) and shape_tolerance >= 0):
        msg = f"shape tolerance must be a non-negative fraction, got {shape_tolerance!r}"
        raise InputError(msg)
    if change is None and closed_form and shape_tolerance > 0 and best is truth:
        try:  # lin_auto fits no cross terms: lm started from the closed form gives them on part of the sphere
            shape = fit(pts[sub], model="sym", method="lm", norm=norm, init=truth, max_iter=_SHAPE_ITER)
            truth = shaped_truth(truth, shape, shape_tolerance, cross_only=True)
        except MargCalError as exc_shape:
            log.info("no cross terms for the twin's shape: %s", exc_shape)
    elif change is None:
        truth = shaped_truth(truth, best, shape_tolerance)
    slow = (0.0, 1.0)
    if rest_noise_raw is None and "rest_noise" not in skipped and best.stats is not None:
        # a rest noise the caller measured (a static recording) is the sensor's whole noise model
        r_best = np.linalg.norm(best.apply(pts[sub]), axis=1) / best.norm - 1.0
        white = rest_noise(pts) / r_raw  # measured, not the caller's: extra white noise is no slow noise
        slow = estimate_slow_noise(times[sub], r_best, white, dirs[sub])
    truth = truth.replace(sensor=sensor, method="twin")
    log.debug("twin: %d samples (%d fitted), radius %.4g raw units, noise %.3g of it", n, sub.size, r_raw, noise)
    for name, why in skipped.items():
        log.debug("stage %s skipped: %s", name, why)
    return Twin(t=times, raw=pts, temp=tmp, sub=sub, truth=truth, best=best, dirs=dirs, noise=noise, sensor=sensor,
                norm=norm, validator=validator, features_rec=features_rec, skipped=skipped, change=change,
                closed_form=closed_form, slow_noise=slow, noise_measured=rest_noise_raw is None)
