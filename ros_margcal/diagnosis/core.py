"""One diagnosis: where the sim-to-real gap lies, which effect causes it, how far it shrinks.

``diagnose(recording, sensor=...)`` builds the twin (``twin.build_twin``), measures the baseline's own
spread over seeds, puts the recording against it stage by stage (``stages.stage_gaps``), fits every
observable effect of the registry (``ranking.rank_effects``) and decides:

- ``where``: the stage with the largest gap;
- ``cause``: ``"none"`` when the recording is within the baseline's spread (every stage gap below
  ``NONE_GAP``, or a marginal gap that only a far-below-typical effect closes, ``MARGINAL_SIZE``),
  else the effect whose fitted magnitude removes the largest share of the gap (when an
  effect of another group comes within ``ranking.CLOSE_MARGIN`` of it, the one the recording is closer
  to on the features that separate the two, ``ranking.separate_close_calls``) — or
  its group's name when the group holds several applicable effects (``ellipsoid_shape``, and
  ``slow_drift`` = bias drift or temperature on a recording without a temperature column: they
  cannot be told apart, so no guess is made between them); ``"unexplained"`` when the gap is clear but no
  effect removes ``MIN_SHRINK`` of it;
- ``shrink``: the share of the overall gap that effect removes, and the stage gaps after it.

A recording that no single calibration fits because its offset steps (a magnet attached in
mid-recording) gets its twin from the fit of one side of the step (``twin.Twin.change``,
``Diagnosis.offset_change``), so the ranking can name ``hard_iron_jump``; the located step ranks
``hard_iron_jump`` first when it removes within ``CHANGE_MARGIN`` of the top effect's share. Whether the offset
stepped once or drifted (``hard_iron_jump`` against ``STEP_RIVALS`` and the drift group, shrinks within
``ranking.STEP_MARGIN``) is then decided on how well one split explains the recording against the twins of the
two (``ranking.separate_step_from_walk``): on a band of tilts the shrinks of the two do not tell them apart.

A recording whose clock goes back (a logger restart) is taken in file order, each part's times continued
after the part before (``file_order_times``, ``Diagnosis.time_restarts``): sorted by time its parts would
interleave.

``diagnose_holdout`` fits on the first part of a recording (the named cause's magnitude, given ``effect``) and
measures the shrink on the rest. ``validator_downstream`` adds the validator's view. All three report their steps
to one ``progress`` callback (``progress.CommandProgress``: one bar for the whole command).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.errors import ConfigError, InputError
from ..sim.simulation import EFFECTS
from .downstream import N_SET, compare_validators
from .inputs import check_options, recording_arrays
from .progress import HOLDOUT_STEPS, diagnosis_steps
from .ranking import (
    DRIFT_GROUP,
    EffectFit,
    applicable_effects,
    effective_group,
    equivalent_groups,
    fit_effect,
    gap_with,
    overall_gap,
    rank_effects,
    separate_step_from_walk,
)
from .stages import clipped_shares, stage_gaps
from .twin import DEFAULT_N_FIT, FIT_ERRORS, Baseline, Twin, build_twin, mean_features
from .twin_fits import MIN_SAMPLES, StaticRecording, static_reason

__all__ = ["NONE_GAP", "Diagnosis", "diagnose", "diagnose_holdout", "validator_downstream"]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

NONE_GAP = 2.5
"""Largest stage gap (RMS of its z-scores) below which a recording is within the baseline's own spread."""
MIN_SHRINK = 0.3
"""Share of the gap an effect must remove to be named; a marginal gap (< 2 NONE_GAP) that no effect
explains counts as the baseline's spread (``none``), a larger one is ``unexplained``."""


MARGINAL_SIZE = 0.4
"""A marginal gap (< 2 NONE_GAP) that only an effect below this share of its typical (default) magnitude
closes counts as the baseline's spread (``none``): a twin's noise model (its slow noise above all) is
itself uncertain by that much."""
CLIPPED_SHARE = 0.2
"""Share of samples at an axis' extreme reading that is clipping beyond doubt (``_no_twin``)."""
QUICK_N_FIT = 2000
"""Fitting samples of a ``quick`` diagnosis."""

JUMP_EFFECT = "hard_iron_jump"
"""The registry effect a located offset step stands for."""
CHANGE_MARGIN = 0.05
"""Shrink margin within which ``JUMP_EFFECT`` is ranked first on a recording with a located offset step."""
STEP_RIVALS = ("bias_drift", "disturbance")
"""Effects whose offset changes in time otherwise than by one step (with the drift group, ``ranking.DRIFT_GROUP``):
weighed against ``JUMP_EFFECT`` on the offset's time course (``ranking.separate_step_from_walk``)."""


@dataclass
class Diagnosis:
    """The result of ``diagnose`` (``to_dict`` gives the JSON of ``margcal diagnose``)."""

    where: str
    cause: str
    cause_effects: list[str]
    shrink: float
    gap_before: float
    gap_after: float
    stages_before: dict[str, float]
    stages_after: dict[str, float]
    effects: list[EffectFit]
    equivalent: list[dict[str, object]]
    unobservable: list[str]
    null_gaps: list[float]
    sensor: str
    n_samples: int
    n_fit: int
    noise: float
    seconds: float
    twin: Twin | None = field(default=None, repr=False)
    baseline: Baseline | None = field(default=None, repr=False)
    downstream: dict[str, Any] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    offset_change: dict[str, float] = field(default_factory=dict)
    time_restarts: list[int] = field(default_factory=list)
    """Samples after which the recording's clock went back (a logger restart): the samples are taken in
    file order, each part's times continued after the part before (``file_order_times``)."""
    has_temperature: bool = False
    """The recording has a temperature column that varies (else ``temperature`` is only a drift's shape)."""
    reason: str = ""
    """Why there is no ranking (the twin could not be built: ``unexplained``, or ``saturation`` read off the
    samples), else empty."""

    @property
    def best(self) -> EffectFit | None:
        """The top-ranked effect fit (None when no effect applies)."""
        return self.effects[0] if self.effects else None

    def close_calls(self, margin: float = 0.05) -> list[str]:
        """Effects of another group whose shrink is within ``margin`` of the top one: data that barely
        separate them (e.g. bias drift and a temperature warm-up when there is no temperature column)."""
        best = self.best
        if best is None or self.cause in ("none", "unexplained"):
            return []
        return [f.name for f in self.effects[1:] if f.group != best.group and f.shrink >= best.shrink - margin]

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict."""
        return {
            "where": self.where,
            "cause": self.cause,
            "cause_effects": self.cause_effects,
            "shrink": self.shrink,
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "none_gap": NONE_GAP,
            "stages": [{"name": k, "gap": v, "gap_after": self.stages_after.get(k, v)} for k, v in self.stages_before.items()],
            "effects": [{"name": f.name, "group": f.group, "magnitude": f.magnitude, "unit": f.unit,
                         "gap_before": f.gap_before, "gap_after": f.gap_after, "shrink": f.shrink, "n_seeds": f.n_seeds,
                         "stages_after": f.stages_after} for f in self.effects],
            "equivalent": self.equivalent,
            "close_calls": self.close_calls(),
            "unobservable": self.unobservable,
            "null_gaps": self.null_gaps,
            "sensor": self.sensor,
            "n_samples": self.n_samples,
            "n_fit": self.n_fit,
            "rest_noise_fraction": self.noise,
            "seconds": self.seconds,
            "downstream": self.downstream,
            "skipped": [{"stage": k, "reason": v} for k, v in self.skipped.items()],
            "offset_change": self.offset_change,
            "reason": self.reason,
            "time_restarts": self.time_restarts,
            "has_temperature": self.has_temperature,
        }


def _null_gaps(base: Baseline) -> list[float]:
    """Leave-one-out gaps of each baseline seed against the others: the gaps the baseline gives itself."""
    out = []
    for k in range(len(base.features)):
        others = [f for i, f in enumerate(base.features) if i != k]
        mean, _ = mean_features(others)
        out.append(overall_gap(stage_gaps(base.features[k].values, mean, base.sd)))
    return out


def _counter(progress: Callable[[int, int, str], None] | None, total: int) -> Callable[[str], None]:
    """``step(name)``: one more step of ``total`` reported to ``progress`` (a no-op without one)."""
    done = [0]

    def step(name: str) -> None:
        done[0] += 1
        if progress is not None:
            progress(min(done[0], total), total, name)

    return step


def _prefer_located_jump(fits: list[EffectFit]) -> list[EffectFit]:
    """Put ``JUMP_EFFECT`` first when its shrink is within ``CHANGE_MARGIN`` of the top one.

    Used when the recording holds a located offset step (``twin.Twin.change``): the step is evidence
    the shrink alone does not weigh, and on such recordings (the stage features then come from the
    closed-form fit) a burst disturbance at its largest magnitude closes nearly as much of the gap.
    """
    top = fits[0].shrink if fits else 0.0
    for i, f in enumerate(fits):
        if f.name == JUMP_EFFECT and i > 0 and f.magnitude > 0 and f.shrink >= top - CHANGE_MARGIN:
            return [f, *fits[:i], *fits[i + 1:]]
    return fits


def _change_dict(twin: Twin) -> dict[str, float]:
    """The offset change that kept one calibration from fitting the recording (empty when none)."""
    c = twin.change
    if c is None:
        return {}
    return {"t": c.t, "step": c.step, "relative_step": c.relative_step, "drop": c.drop}


def diagnose(
    recording: Any,
    *,
    sensor: str | None = None,
    norm: float | None = None,
    rest_noise: float | None = None,
    n_fit: int = DEFAULT_N_FIT,
    n_seeds: int = 3,
    n_spread: int = 6,
    validator: object | None = None,
    shape_tolerance: float = 0.0,
    quick: bool = False,
    progress: Callable[[int, int, str], None] | None = None,
) -> Diagnosis:
    """Diagnose the sim-to-real gap of one recording.

    Args:
        recording: a ``simulation.Recording`` (``io.read_recording`` gives one): ``t``, ``raw``, ``temp``.
        sensor: "mag" or "accel" (default: the recording's own label).
        norm: reference norm of the calibrated vector (None: estimated).
        rest_noise: white noise std at rest in raw units (None: estimated from the recording).
        n_fit: samples for the fitting stages.
        n_seeds: twin seeds averaged per evaluation.
        n_spread: baseline seeds for the spread (>= n_seeds).
        validator: validator of the ``validator`` stage (None: the stage is skipped).
        shape_tolerance: cross-axis terms (off-diagonal entries of W relative to its diagonal) that count
            as the sensor's baseline, not as an ``ellipsoid_shape`` gap (``twin.shaped_truth``; 0: the
            simulator's baseline, offset and gains only). A magnetometer in a vehicle always has some soft
            iron: give the level that is expected and only a larger shape is named.
        quick: fewer fitting samples (at most ``QUICK_N_FIT``) and twin seeds (2 averaged, 4 for the
            spread): about three times faster, a noisier ranking.
        progress: called as ``progress(done, total, step)`` after each step (the twin, the baseline's
            spread, each effect, the decision: ``progress.diagnosis_steps``), e.g. a ``CommandProgress``.

    A recording that makes no usable twin (too short, static, nothing converges) is not refused: its
    cause is ``unexplained`` and ``Diagnosis.reason`` says why (a static one, whose sensor never moved:
    "static: the sensor did not move ...", ``twin_fits.static_reason``, found before any fit). Stages that
    cannot be computed are left out of the gaps (``stages.stage_gaps``) and effects that cannot be fitted
    out of the ranking.

    Raises:
        ConfigError: unknown sensor or bad option (``check_options``).
        InputError: arrays of the wrong shape or with non-finite values (not a recording).
    """
    t0 = time.monotonic()
    check_options(norm=norm, rest_noise=rest_noise, n_fit=n_fit, shape_tolerance=shape_tolerance)
    if quick:
        n_fit, n_seeds, n_spread = min(n_fit, QUICK_N_FIT), min(n_seeds, 2), min(n_spread, 4)
    t, raw, temp, label, restarts = recording_arrays(recording)
    sensor = sensor or label
    if sensor not in ("mag", "accel"):
        msg = f"sensor must be 'mag' or 'accel' (the recording says {label!r}); pass --sensor"
        raise ConfigError(msg)
    step = _counter(progress, diagnosis_steps(sensor))
    if n_seeds < 1 or n_spread < max(2, n_seeds):
        msg = f"need n_seeds >= 1 and n_spread >= max(2, n_seeds), got {n_seeds}, {n_spread}"
        raise ConfigError(msg)
    try:
        twin = build_twin(t, raw, sensor=sensor, temp=temp, norm=norm, rest_noise_raw=rest_noise, n_fit=n_fit,
                          validator=validator, shape_tolerance=shape_tolerance)
        step("twin")
        base = twin.spread(n_spread)
        step("baseline spread")
    except InputError:
        raise
    except FIT_ERRORS as exc:  # a recording that makes no usable twin still gets a verdict, with the reason
        log.info("no twin: %s", exc)
        # a static recording's repeated readings are no clipping: it is static, not saturated (also when its
        # readings are one value throughout, which the fits refuse before they test for a static recording)
        static = isinstance(exc, StaticRecording) or bool(static_reason(raw))
        verdict = _no_twin(sensor, len(t), str(exc), time.monotonic() - t0, None if static else raw)
        verdict.time_restarts = restarts
        return verdict
    seeds = base.seeds[:n_seeds]
    before = stage_gaps(twin.features_rec.values, base.mean, base.sd)  # against every seed of the spread
    gap_before = overall_gap(before)
    observable, hidden = applicable_effects(sensor)
    has_temp = twin.temp is not None and bool(np.ptp(twin.temp) > 0)
    # every seed of the spread re-ranks the leading effects, but not on a closed-form twin (part of the sphere,
    # clipping): there an effect's draws (its direction against the directions seen) set its features more than
    # its size, the mean over more draws moves away from the one draw the recording holds, and the search,
    # which fitted the size on its seeds, decides (its sym feature was NaN there, which skipped this before)
    refine = () if twin.closed_form else base.seeds
    fits = rank_effects(twin, base, observable, seeds=seeds, progress=lambda _d, _t, name: step(name),
                        refine_seeds=refine, quick=quick)
    if twin.change is not None:
        fits = _prefer_located_jump(fits)
    group_of = {e.name: effective_group(e, has_temp) for e in observable}
    for f in fits:
        f.group = group_of[f.name]
    # one offset step against an offset that changes otherwise: decided on the offset's time course
    rivals = frozenset(n for n, g in group_of.items() if g == DRIFT_GROUP or n in STEP_RIVALS)
    fits = separate_step_from_walk(twin, fits, base.seeds, rivals)
    where = max(before, key=lambda k: before[k]) if before else ""
    best = fits[0] if fits else None
    top = max(before.values(), default=0.0)
    members: list[str]
    reason = ""
    if not before or (best is None and top >= NONE_GAP):
        reason = "no stage of the recording could be compared with its twin" if not before else \
            "no effect of the registry could be fitted to the recording"
        cause, members, shrink, after, stages_after = "unexplained", [], 0.0, gap_before, dict(before)
    elif best is None or top < NONE_GAP or best.magnitude == 0.0 or (top < 2 * NONE_GAP and (
            best.shrink < MIN_SHRINK or best.magnitude < MARGINAL_SIZE * EFFECTS[best.name].default_magnitude)):
        cause, members, shrink, after, stages_after = "none", [], 0.0, gap_before, dict(before)
    elif best.shrink < MIN_SHRINK:
        cause, members, shrink, after, stages_after = "unexplained", [], best.shrink, best.gap_after, best.stages_after
    else:
        members = sorted(e.name for e in observable if group_of[e.name] == best.group)
        cause = best.group if len(members) > 1 else best.name
        shrink, after, stages_after = best.shrink, best.gap_after, best.stages_after
    step("decision")
    return Diagnosis(
        where=where, cause=cause, cause_effects=members, shrink=shrink, gap_before=gap_before, gap_after=after,
        stages_before=before, stages_after=stages_after, effects=fits, equivalent=equivalent_groups(observable, has_temp),
        unobservable=[e.name for e in hidden], null_gaps=_null_gaps(base), sensor=sensor, n_samples=len(t),
        n_fit=int(twin.sub.size), noise=twin.noise, seconds=time.monotonic() - t0, twin=twin, baseline=base,
        skipped=dict(twin.skipped), offset_change=_change_dict(twin), reason=reason, time_restarts=restarts,
        has_temperature=has_temp,
    )


def _no_twin(sensor: str, n: int, reason: str, seconds: float, raw: Array | None = None) -> Diagnosis:
    """The verdict on a recording whose twin cannot be built: ``unexplained``, with the reason.

    One exception, read off the samples without a twin: an axis that sits at its extreme reading for at
    least ``CLIPPED_SHARE`` of ``MIN_SAMPLES`` or more samples is clipped (an unclipped reading repeats its
    extreme value about once), and a clipped axis is the likely reason no fit exists (on a band of tilts an
    axis clipped throughout leaves coplanar points): the cause is ``saturation``, and the reason says it
    rests on the read-out alone.
    """
    observable, hidden = applicable_effects(sensor)
    cause, members = "unexplained", []
    shares = clipped_shares(raw) if raw is not None and len(raw) >= MIN_SAMPLES else np.zeros(0)
    if shares.size and float(shares.max()) >= CLIPPED_SHARE and "saturation" in {e.name for e in observable}:
        axis = int(np.argmax(shares))
        cause, members = "saturation", ["saturation"]
        reason = (f"axis {'xyz'[axis]} sits at its extreme reading in {100 * shares[axis]:.0f} % of the samples "
                  f"(clipping), and no twin can be fitted ({reason}): saturation, read off the samples without a twin")
    return Diagnosis(where="clipping" if members else "", cause=cause, cause_effects=members, shrink=0.0,
                     gap_before=math.nan, gap_after=math.nan, stages_before={}, stages_after={}, effects=[],
                     equivalent=equivalent_groups(observable), unobservable=[e.name for e in hidden], null_gaps=[],
                     sensor=sensor, n_samples=n, n_fit=0, noise=math.nan, seconds=seconds, reason=reason)


def diagnose_holdout(recording: Any, *, split: float = 0.5, effect: str | None = None,
                     progress: Callable[[int, int, str], None] | None = None, **options: Any) -> dict[str, Any]:
    """Fit an effect on the first ``split`` of the recording (in time), measure the shrink on the rest.

    With ``effect`` (the cause the whole recording's diagnosis named, ``Diagnosis.best``), only that effect's
    magnitude is fitted on the first part, so the check tests the named cause; without it the first part
    gets its own diagnosis and its top effect is carried over (``fit``). ``progress`` is called after each
    step (``progress.HOLDOUT_STEPS`` with ``effect``).

    Returns:
        A dict with ``effect`` and ``magnitude`` (fitted on the first part), ``fit`` (the first part's
        diagnosis, without ``effect`` only), ``effect_fit`` (the ``EffectFit`` on the first part), and for
        the withheld part its ``gap_before``, ``gap_after`` (that effect and magnitude, not refitted),
        ``shrink`` and per-stage gaps.

    Raises:
        ConfigError: a bad split or an unknown effect; the fit errors of ``twin.FIT_ERRORS`` when a part
            makes no twin.
    """
    check_options(split=split)
    if effect is not None and effect not in EFFECTS:
        msg = f"unknown effect {effect!r} for the withheld part; choose from {sorted(EFFECTS)}"
        raise ConfigError(msg)
    first, second = _split(recording, split)
    sensor = options.get("sensor") or first.sensor
    step = _counter(progress, HOLDOUT_STEPS if effect else diagnosis_steps(sensor) + 1)
    d1: Diagnosis | None = None
    if effect is None:
        d1 = diagnose(first, progress=None if progress is None else lambda _d, _t, name: step(name), **options)
        fitted = None if d1.cause == "none" else d1.best
    else:
        twin1, base1, seeds1 = _part_twin(first, sensor, options)
        step("withheld part: twin of the first part")
        search = {"grid_points": 5, "golden_steps": 3} if options.get("quick") else {}
        fitted = fit_effect(twin1, base1, EFFECTS[effect], seeds=seeds1, **search)
        step(f"withheld part: {effect} fitted")
    twin2, base2, seeds = _part_twin(second, sensor, options)
    before2 = stage_gaps(twin2.features_rec.values, mean_features(base2.features[: len(seeds)])[0], base2.sd)
    gap_before2 = overall_gap(before2)
    if fitted is None or fitted.magnitude <= 0:
        gap_after2, after2 = gap_before2, dict(before2)
    else:
        gap_after2, after2 = gap_with(twin2, base2, fitted.name, fitted.magnitude, seeds)
    step("withheld part: the rest")
    return {"fit": d1, "effect_fit": fitted, "effect": effect if fitted is None else fitted.name,
            "magnitude": 0.0 if fitted is None else fitted.magnitude,
            "gap_before": gap_before2, "gap_after": gap_after2,
            "shrink": 1.0 - gap_after2 / gap_before2 if gap_before2 > 0 else 0.0,
            "stages_before": before2, "stages_after": after2}


def _split(recording: Any, split: float) -> tuple[Any, Any]:
    """The first ``split`` of the recording (in time) and the rest, as recordings (``t``, ``raw``, ``temp``,
    ``sensor``); a restarted clock: the parts in file order (``file_order_times``)."""
    t, raw, temp, label, _ = recording_arrays(recording)
    cut = int(np.searchsorted(t, t[0] + split * (t[-1] - t[0])))
    part = type("Part", (), {})
    first, second = part(), part()
    for obj, sl in ((first, slice(0, cut)), (second, slice(cut, None))):
        obj.t, obj.raw, obj.sensor = t[sl], raw[sl], label
        obj.temp = None if temp is None else temp[sl]
    return first, second


def _part_twin(part: Any, sensor: str, options: dict[str, Any]) -> tuple[Twin, Baseline, tuple[int, ...]]:
    """The twin of one part of a recording, its baseline spread and the seeds effects are compared on, with
    the diagnosis' options (``quick``: fewer fitting samples and seeds, as ``diagnose``)."""
    quick = bool(options.get("quick"))
    n_fit = options.get("n_fit", DEFAULT_N_FIT)
    twin = build_twin(part.t, part.raw, sensor=sensor, temp=part.temp, norm=options.get("norm"),
                      rest_noise_raw=options.get("rest_noise"), n_fit=min(n_fit, QUICK_N_FIT) if quick else n_fit,
                      validator=options.get("validator"), shape_tolerance=options.get("shape_tolerance", 0.0))
    n_spread, n_seeds = options.get("n_spread", 6), options.get("n_seeds", 3)
    base = twin.spread(min(n_spread, 4) if quick else n_spread)
    return twin, base, base.seeds[: min(n_seeds, 2) if quick else n_seeds]


def validator_downstream(diag: Diagnosis, validator: object | None, *, n_sets: int = 400, seed: int = 0,
                         progress: Callable[[int, int, str], None] | None = None) -> dict[str, Any]:
    """What the chosen effect does to the validator: predicted error before and after retraining.

    The validator's prediction on a ``N_SET``-sample set of the recording (evenly spaced over the
    fitting subsample, so it spans the whole recording) is compared with the measured error
    (``validator_errors``, against the best fit of that subsample) by ``compare_validators``:
    ``original``, ``with_effect`` (retrained on ``n_sets`` simulated sets with the effect at its fitted
    magnitude) and ``control`` (as many sets without it), the retraining sets at the twin's noise level
    and labelled like the measured error. The flat keys ``predicted_before`` / ``_after`` / ``_control``
    and ``log_error_*`` (``|log10(measured / predicted)|``, 0 is perfect) repeat the table for the
    summary line. ``progress`` is called once, when it is done (one step of ``progress.command_steps``).
    """
    check_options(n_sets=n_sets)
    step = _counter(progress, 1)
    try:
        return _downstream(diag, validator, n_sets, seed)
    finally:
        step("validator retrained")


def _downstream(diag: Diagnosis, validator: object | None, n_sets: int, seed: int) -> dict[str, Any]:
    """``validator_downstream`` without its progress."""
    twin = diag.twin
    if validator is None or twin is None:
        return {"available": False, "reason": "no validator"}
    pts = twin.raw[twin.sub]
    pick = np.linspace(0, len(pts) - 1, min(N_SET, len(pts))).astype(np.intp)
    ts = twin.t[twin.sub][pick]
    span = float(ts[-1] - ts[0])
    best = diag.best
    retrain = diag.cause != "none" and best is not None
    effects = {best.name: best.magnitude} if retrain and best is not None else None
    noise = float(twin.noise) if math.isfinite(twin.noise) and twin.noise > 0 else None
    kind = twin.sensor if twin.sensor in ("mag", "accel") else None
    try:
        cmp = compare_validators(pts[pick], twin.best, validator, effects, span_s=span,
                                 recording=max(2, round(len(pts) / len(pick))), noise=noise, kind=kind,
                                 n_sets=n_sets, seed=seed)
    except FIT_ERRORS as exc:
        return {"available": False, "reason": f"validator downstream failed: {exc}"}
    v = cmp["validators"]
    out: dict[str, Any] = {"available": True, **cmp, "predicted_before": v["original"]["predicted"],
                           "log_error_before": v["original"]["log_error"]}
    if not retrain or best is None:
        out.update(predicted_after=out["predicted_before"], log_error_after=out["log_error_before"],
                   note="cause is none: no retraining")
        return out
    out.update(effect=best.name, magnitude=best.magnitude, n_sets=n_sets,
               predicted_after=v["with_effect"]["predicted"], predicted_control=v["control"]["predicted"],
               error_ratio_before=v["original"]["ratio"], error_ratio_after=v["with_effect"]["ratio"],
               log_error_after=v["with_effect"]["log_error"], log_error_control=v["control"]["log_error"])
    return out
