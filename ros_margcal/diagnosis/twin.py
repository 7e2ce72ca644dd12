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
rest noise, takes the twin's noise from the best fit's residual; ``Twin.skipped`` says why. A recording that
moves fast between samples (a vibrating or fast-turning platform: a few degrees per sample), whose second
differences measure the motion, skips the ``rest_noise`` stage too, keeps its directions unsmoothed and takes
the white noise from first differences of the fit's residual (``_white_noise``).

``Twin.features(effects, seed)`` simulates the twin (``simulation.simulate`` with the recording's
timestamps and temperature, optionally with effects from the registry) and returns its stage
features; ``Twin.spread`` gives the baseline's mean and spread over several seeds, the yardstick of
every gap.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.errors import DegenerateDataError, InputError, MargCalError, as_points
from ..model.fitting import fit
from ..sim.effects import check_effects, sensor_model
from ..sim.simulation import simulate
from .baseline_noise import ar1_noise, estimate_slow_noise, shaped_truth
from .changes import OffsetChange
from .fit_checks import IllConditionedFit, checked_sym, lm_diag, sym_fit
from .stages import StageFeatures, residual_noise, rest_noise, stage_features
from .twin_fits import (
    CHANGE_EVIDENCE,
    MAX_ITER,
    MIN_SAMPLES,
    StaticRecording,
    _change_message,
    _closed_form_fits,
    _located_change,
    _segment_fits,
    smooth_directions,
    static_reason,
)

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
FAST_MOTION_RATIO = 1.5
"""Ratio of the readings' noise (second differences) to the fit residual's (first differences) above which the
motion between samples, not the noise, sets the second differences (``_white_noise``; a smooth recording: 0.8-1.05,
attitude steps of a few degrees per sample: 2-18)."""
FAST_MOTION_MIN_STEP_DEG = 1.0
"""Median angle between consecutive samples below which the motion is never taken for the second differences'
noise (a 0.4 degree step: a band of tilts at 50 Hz, whose clipped readings can fool the ratio)."""
MAX_STEP_DEG = 10.0
"""Median angle between consecutive samples above which a recording has no time continuity: its rest
noise cannot be measured from second differences and its directions are not smoothed."""
_SHAPE_ITER = 200
_SLOW_TAU_SPREAD = 2.0


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
        raw = self.simulate_raw(dict(key[0]), seed)
        out = stage_features(self.t, raw, self.temp, self.sub, validator=self.validator, norm=self.norm,
                             skip=frozenset(self.skipped), closed_form=self.closed_form)
        self._cache[key] = out
        return out

    def simulate_raw(self, effects: dict[str, float] | None, seed: int) -> Array:
        """Raw readings (n, 3) of the twin simulated with ``effects`` on ``np.random.default_rng(seed)``
        (what ``features`` measures).

        Raises:
            InputError: the simulation gives non-finite readings.
        """
        key = (tuple(sorted((k, float(v)) for k, v in (effects or {}).items() if v > 0)), int(seed))
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
        return np.asarray(raw, dtype=np.float64)

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


def _white_noise(pts: Array, h: Array, raw_radius: float, norm: float, step: float) -> tuple[float, str]:
    """The recording's white noise (fraction of the field radius) and, when fast motion inflates the second
    differences of the readings, why the ``rest_noise`` stage is left out (else "").

    Second differences (``stages.rest_noise``) hold the motion between samples too: a platform that turns or
    vibrates by a few degrees per sample adds several percent of the field. The first differences of the fit's
    norm residual (``stages.residual_noise``) do not see the motion; when the readings' estimate exceeds
    ``FAST_MOTION_RATIO`` times it and the sensor turns by ``FAST_MOTION_MIN_STEP_DEG`` or more per sample (median
    ``step``; slower motion cannot set the second differences), the residual's is the noise.
    """
    from_readings = rest_noise(pts) / raw_radius
    if step < FAST_MOTION_MIN_STEP_DEG:
        return from_readings, ""
    from_residual = residual_noise(np.linalg.norm(h, axis=1) / norm - 1.0)
    if not from_readings > FAST_MOTION_RATIO * from_residual:
        return from_readings, ""
    why = (f"fast motion: second differences of the readings give a noise of {100 * from_readings:.3g} % of the "
           f"field, the fit's residual {100 * from_residual:.3g} % (more than {FAST_MOTION_RATIO:g} times less): "
           "they measure the motion between samples, so the twin's noise is the residual's and its directions "
           "are the recording's own, unsmoothed")
    return from_residual, why


def _shape_fit(pts: Array, truth: Calibration, norm: float | None) -> Calibration | None:
    """The ``sym`` fit of a recording measured with the closed form (``truth``, its ``lin_auto`` diag fit, fits no
    cross terms): ``lm`` started from it, or where that does not converge (or ends off the optimum, ``checked_sym``)
    the algebraic fit; None when neither fits. It gives the cross terms of the sensor's shape and the residual the
    noise is measured on."""
    try:
        return checked_sym(fit(pts, model="sym", method="lm", norm=norm, init=truth, max_iter=_SHAPE_ITER), pts, norm)
    except MargCalError:
        return sym_fit(pts, norm, closed_form=True)


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
        StaticRecording: (a DegenerateDataError) the sensor did not move (``twin_fits.static_reason``).
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
    static = static_reason(pts)
    if static:
        raise StaticRecording(static)
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
        truth = lm_diag(pts[sub], norm, sensor=sensor, max_iter=MAX_ITER)
        try:
            best = checked_sym(fit(pts[sub], model="sym", method="lm", norm=norm, max_iter=MAX_ITER), pts[sub], norm)
        except MargCalError as exc_sym:
            change, searched = _located_change(times, pts, sub, norm, sensor), True
            if change is not None:
                raise
            # no offset step (e.g. a heavily clipped recording): the baseline fit gives the directions
            log.info("the sym fit does not converge (%s): directions from the diag fit", exc_sym)
            best = truth
        h = best.apply(pts)
    except MargCalError as exc:
        if not searched and not isinstance(exc, IllConditionedFit):  # an ill-conditioned fit is no sign of a change
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
    # a closed-form twin's best is the diag fit, whose residual holds the sensor's shape: the noise is measured on
    # its sym fit, as it is on the best fit when lm converges, and the directions are taken from it
    shape = _shape_fit(pts[sub], truth, norm) if change is None and closed_form and best is truth else None
    noise_fit = best if shape is None else shape
    if shape is not None:
        h = shape.apply(pts)
    step = median_step_deg(h)
    skipped: dict[str, str] = {}
    if unfitted:
        skipped["offset_change"] = unfitted
    if np.ptp(times) <= 0:
        skipped["residual_time"] = "the recording has no time span (all timestamps equal)"
    white = _white_noise(pts, h, truth.raw_radius, noise_fit.norm, step) if step <= MAX_STEP_DEG else None
    if white is not None and white[1]:
        skipped["rest_noise"] = white[1]
        lengths = np.linalg.norm(h, axis=1, keepdims=True)
        dirs = h / np.where(lengths > 0, lengths, 1.0)
    elif step > MAX_STEP_DEG:
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
        if white is None:
            rms = best.stats.rms_relative if best.stats is not None else 0.0
            noise = float(rms) * best.raw_radius / r_raw
        else:
            noise = white[0]
    else:
        if not (math.isfinite(rest_noise_raw) and rest_noise_raw >= 0):
            msg = f"rest noise must be a non-negative std in raw units, got {rest_noise_raw!r}"
            raise InputError(msg)
        noise = float(rest_noise_raw) / r_raw
    if not (math.isfinite(shape_tolerance) and shape_tolerance >= 0):
        msg = f"shape tolerance must be a non-negative fraction, got {shape_tolerance!r}"
        raise InputError(msg)
    if change is None and closed_form and shape_tolerance > 0 and best is truth:
        if shape is not None:  # lin_auto fits no cross terms: those of its sym fit (``_shape_fit``)
            truth = shaped_truth(truth, shape, shape_tolerance, cross_only=True)
    elif change is None:  # a best fitted before the features needed the closed form: its cross terms only
        truth = shaped_truth(truth, best, shape_tolerance, cross_only=closed_form)
    slow = (0.0, 1.0)
    if rest_noise_raw is None and white is not None and noise_fit.stats is not None:
        # a rest noise the caller measured (a static recording) is the sensor's whole noise model
        r_best = np.linalg.norm(noise_fit.apply(pts[sub]), axis=1) / noise_fit.norm - 1.0
        # measured, not the caller's: extra white noise is no slow noise
        slow = estimate_slow_noise(times[sub], r_best, white[0], dirs[sub])
    truth = truth.replace(sensor=sensor, method="twin")
    log.debug("twin: %d samples (%d fitted), radius %.4g raw units, noise %.3g of it", n, sub.size, r_raw, noise)
    for name, why in skipped.items():
        log.debug("stage %s skipped: %s", name, why)
    return Twin(t=times, raw=pts, temp=tmp, sub=sub, truth=truth, best=best, dirs=dirs, noise=noise, sensor=sensor,
                norm=norm, validator=validator, features_rec=features_rec, skipped=skipped, change=change,
                closed_form=closed_form, slow_noise=slow, noise_measured=rest_noise_raw is None)
