"""Which effect: fit each registry effect's magnitude so the twin matches the recording, then rank.

For an effect ``e`` and a magnitude ``m`` the twin is simulated with ``effects={e: m}`` on the same
seeds as the baseline (common random numbers: the simulator draws each effect's randomness from its
own generator, so changing ``m`` only rescales it). The gap of the recording against the mean of
those twins, measured with the *baseline's* spread (``stages.stage_gaps``), is a function of ``m``;
the overall gap is the RMS of the stage gaps. The magnitude is found by a 1-D search: a log-spaced
grid over the effect's ``magnitude_range`` then a golden-section refinement (in ``log m``) around the
best grid point. When the best grid point is the top of the range and the effect has a ``limit``, the
grid is extended upwards (up to just below the limit) until the gap rises again: the twin's own sensor
is fitted to the recording, so a strong effect that distorts that fit (clipping pulls the fitted
ellipsoid in) may need a larger magnitude in the twin than the recording's truth had. Effects without
a limit keep their range (beyond it they would only stand in for other effects at unphysical sizes).
``shrink = 1 - gap_after / gap_before`` is the share of the gap the effect removes.
The leading effects are then evaluated once more at their fitted magnitudes on every seed of the
baseline's spread (``rank_effects(refine_seeds=...)``), so that two effects that both remove most of
the gap are compared on more twins than the search used. An effect of another group whose shrink is
within ``CLOSE_MARGIN`` of the top one's is then weighed against it on the features that separate
their twins only (``separate_close_calls``): a time effect has to beat a static one, or a drift a
temperature effect, on the evidence that tells them apart, not on the size both reproduce. The top
effect's magnitude is finally re-fitted on those seeds (``_refine_magnitude``), since the search's few
seeds are the same for every recording. One offset step (``hard_iron_jump``) against an offset that changes
otherwise (a drift, bursts) is decided on the offset's time course (``separate_step_from_walk``, called by
``core.diagnose`` once the groups are known): how much of the residual one split explains, on the recording
against the twins of each.

Effects with ``observable=False`` (misalignment) cannot change a norm-based recording and are not
fitted but listed as unobservable; effects sharing a ``group`` (non-orthogonality and symmetric soft
iron: the same ellipsoid family) are reported together as equivalent, and so are bias drift and
temperature on a recording without a temperature column (``effective_group``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..sim.simulation import EFFECTS, Effect
from .changes import step_evidence
from .stages import stage_floor, stage_gaps
from .twin import FIT_ERRORS, Baseline, Twin, mean_features

__all__ = [
    "CLOSE_MARGIN", "DRIFT_GROUP", "PLAIN_GROUPS", "STEP_EFFECT", "STEP_MARGIN", "EffectFit", "applicable_effects",
    "effective_group", "equivalent_groups", "fit_effect", "gap_with", "overall_gap", "rank_effects", "separate_close_calls",
    "separate_step_from_walk"
]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

_GRID = 7
_GOLDEN_STEPS = 6
_LOW_DECADES = 3.0  # the grid starts this many decades below the top of the magnitude range
_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0
_N_REFINE = 3
_MAX_WIDEN = 2.0
CLOSE_MARGIN = 0.05
"""Shrink margin within which another group's effect is a close call to the top one (``separate_close_calls``)."""
_SEPARATED = 2.0  # a feature separates two effects when their twins' means are this many pooled spreads apart
_REFINE_DECADES = 0.1  # half-width of the top effect's magnitude re-fit on every seed of the spread
PLAIN_GROUPS = ("ellipsoid_shape",)
"""Groups named first in a close call that no feature separates (``separate_close_calls``): the ellipsoid
is the model every calibration fits and the commonest sensor error; a non-ellipsoidal effect (a cubic
non-linearity, which on a band of directions an ellipsoid mimics) is named over it only when the data show it."""
DRIFT_GROUP = "slow_drift"
"""Group of ``bias_drift`` and ``temperature`` on a recording without a temperature column."""
_DRIFT_MEMBERS = ("bias_drift", "temperature")
STEP_EFFECT = "hard_iron_jump"
"""The effect whose offset steps once (``separate_step_from_walk``)."""
STEP_MARGIN = 0.15
"""Shrink margin within which ``STEP_EFFECT`` and an offset that changes otherwise (a drift, bursts) are weighed on
the step evidence (``separate_step_from_walk``). Wider than ``CLOSE_MARGIN``: on part of the sphere (a band of
tilts) the shrinks of these effects are measured on the search's few seeds only and move by about this much with
the draws of the effect's direction and time."""
_STEP_FLOOR = 0.05  # spread floor of the step evidence, decades of the share one split leaves
_MIN_LEFT = 1e-4  # smallest share one split leaves (a noise-free step)



@dataclass
class EffectFit:
    """One effect fitted to a recording.

    Attributes:
        name: registry name.
        group: equivalence group (same group: cannot be told apart).
        magnitude: fitted magnitude (``unit``); 0 when no magnitude helps.
        unit: the magnitude's unit.
        gap_before: overall gap of the baseline twin.
        gap_after: overall gap with the effect at ``magnitude``.
        shrink: ``1 - gap_after / gap_before`` (0 when there is no gap).
        stages_after: stage -> gap with the effect.
        curve: (magnitude, gap) pairs evaluated by the search.
        n_seeds: twin seeds behind ``gap_after`` and ``shrink``.
    """

    name: str
    group: str
    magnitude: float
    unit: str
    gap_before: float
    gap_after: float
    shrink: float
    stages_after: dict[str, float] = field(default_factory=dict)
    curve: list[tuple[float, float]] = field(default_factory=list)
    n_seeds: int = 0


def overall_gap(stages: dict[str, float]) -> float:
    """The overall gap: RMS of the stage gaps."""
    if not stages:
        return 0.0
    return float(math.sqrt(sum(g * g for g in stages.values()) / len(stages)))


def applicable_effects(sensor: str) -> tuple[list[Effect], list[Effect]]:
    """(observable, unobservable) registry effects that apply to ``sensor``."""
    eff = [e for e in EFFECTS.values() if not sensor or sensor in e.sensors]
    return [e for e in eff if e.observable], [e for e in eff if not e.observable]


def effective_group(effect: Effect, has_temperature: bool) -> str:
    """The group ``effect`` falls in for a recording: its registry group, except that without a
    temperature column ``temperature`` and ``bias_drift`` are one group, ``DRIFT_GROUP``.

    Without the temperature the time course of a temperature effect is unknown (the twin can only
    assume a warm-up curve), so what the data show is a slow change of the offset (and gains) in
    time — a drift — and naming temperature as its cause would be a guess. With the column, the
    residual either follows the temperature or it does not, and the two are told apart.
    """
    if not has_temperature and effect.name in _DRIFT_MEMBERS:
        return DRIFT_GROUP
    return effect.group


def equivalent_groups(effects: list[Effect], has_temperature: bool = True) -> list[dict[str, object]]:
    """Groups of two or more applicable effects that the data cannot tell apart."""
    groups: dict[str, list[str]] = {}
    for e in effects:
        groups.setdefault(effective_group(e, has_temperature), []).append(e.name)
    return [{"group": g, "effects": sorted(names)} for g, names in sorted(groups.items()) if len(names) > 1]


def gap_with(twin: Twin, base: Baseline, effect: str, m: float, seeds: tuple[int, ...], *,
             own_spread: bool = False) -> tuple[float, dict[str, float]]:
    """Overall and stage gaps of the recording against the twins with ``{effect: m}`` on ``seeds``,
    on the baseline's spread, or with ``own_spread`` on the larger of it and the effect twins' own."""
    got = [twin.try_features({effect: m}, s) for s in seeds]
    feats = [f for f in got if f is not None]
    if not feats:
        return math.inf, {}
    mean, sd = mean_features(feats)
    if not (own_spread and len(feats) > 2):
        stages = stage_gaps(twin.features_rec.values, mean, base.sd)
        return overall_gap(stages), stages
    # Gaussian negative log-likelihood per feature, z^2 + 2 log(s / s_base): a wider spread lowers z but
    # costs its log, so an effect cannot win by being vague
    # a feature undefined for the twins (NaN spread: a fit that failed on every seed) is not widened and
    # costs nothing, as ``stage_gaps`` leaves its z-score out
    wide = {}
    for k, v in sd.items():
        if k in base.sd and base.sd[k].shape == v.shape:
            ref = np.fmax(base.sd[k], stage_floor(k, v.shape))
            own = np.where(np.isfinite(v), v, base.sd[k])
            wide[k] = np.fmin(np.fmax(own, base.sd[k]), _MAX_WIDEN * ref)  # a few seeds: not far wider
    stages = stage_gaps(twin.features_rec.values, mean, wide)
    for name in list(stages):
        floor = stage_floor(name, wide[name].shape)
        pen = 2.0 * np.log(np.fmax(wide[name], floor) / np.fmax(base.sd[name], floor))
        stages[name] = float(np.sqrt(stages[name] ** 2 + float(np.mean(pen))))
    return overall_gap(stages), stages


def fit_effect(twin: Twin, base: Baseline, effect: Effect, *, seeds: tuple[int, ...] = (0, 1, 2), grid_points: int = _GRID,
               golden_steps: int = _GOLDEN_STEPS) -> EffectFit:
    """Fit ``effect``'s magnitude to the recording (grid of ``grid_points`` + ``golden_steps`` of golden
    section in log magnitude)."""
    before_stages = stage_gaps(twin.features_rec.values, mean_features([twin.features(None, s) for s in seeds])[0],
                               base.sd)
    before = overall_gap(before_stages)
    hi = float(effect.magnitude_range[1])
    if math.isfinite(effect.limit):
        hi = min(hi, 0.95 * effect.limit)
    log_hi = math.log10(hi)
    curve: dict[float, tuple[float, dict[str, float]]] = {}

    def evaluate(log_m: float) -> float:
        m = 10.0**log_m
        if m not in curve:
            curve[m] = gap_with(twin, base, effect.name, m, seeds)
        return curve[m][0]

    grid = np.linspace(log_hi - _LOW_DECADES, log_hi, max(3, grid_points))
    values = [evaluate(float(x)) for x in grid]
    j = int(np.argmin(values))
    step = float(grid[1] - grid[0])
    log_top = math.log10(0.95 * effect.limit) if math.isfinite(effect.limit) else log_hi
    while j == len(grid) - 1 and log_hi + 1e-9 < log_top:  # best at the top: the range is too narrow for this twin
        log_hi = min(log_hi + step, log_top)
        grid = np.append(grid, log_hi)
        values.append(evaluate(log_hi))
        j = int(np.argmin(values))
    a, b = float(grid[j]) - step, min(float(grid[j]) + step, log_hi)
    c, d = b - _INV_PHI * (b - a), a + _INV_PHI * (b - a)
    fc, fd = evaluate(c), evaluate(d)
    for _ in range(golden_steps):
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - _INV_PHI * (b - a)
            fc = evaluate(c)
        else:
            a, c, fc = c, d, fd
            d = a + _INV_PHI * (b - a)
            fd = evaluate(d)
    m_best = min(curve, key=lambda k: curve[k][0])
    after, stages_after = curve[m_best]
    if after >= before:
        m_best, after, stages_after = 0.0, before, before_stages
    shrink = 1.0 - after / before if before > 0 else 0.0
    log.debug("effect %s: magnitude %.4g, gap %.3g -> %.3g", effect.name, m_best, before, after)
    return EffectFit(name=effect.name, group=effect.group, magnitude=m_best, unit=effect.magnitude_unit,
                     gap_before=before, gap_after=after, shrink=shrink, stages_after=stages_after,
                     curve=sorted((m, g[0]) for m, g in curve.items()), n_seeds=len(seeds))


def rank_effects(twin: Twin, base: Baseline, effects: list[Effect], *, seeds: tuple[int, ...] = (0, 1, 2),
                 progress: object | None = None, refine_seeds: tuple[int, ...] = (), n_refine: int = _N_REFINE,
                 quick: bool = False) -> list[EffectFit]:
    """Fit every effect and sort by shrink (largest first).

    With ``refine_seeds`` (e.g. every seed of the baseline's spread), the ``n_refine`` leading
    effects are evaluated again at their fitted magnitude on those seeds before the final order, on
    the larger of the baseline's spread and the effect twins' own (``own_spread``): an effect's random
    draws (a direction, gain signs, burst times) differ between the recording and any twin and move
    the features more than the noise does, so two effects that both explain most of the gap (a drift
    and a warm-up) are compared on what their draws allow. The magnitude search itself stays on the
    baseline's spread (with the effect's own spread it would favour the strong, widely spread
    magnitudes). ``quick`` searches a coarser grid with fewer golden-section steps.
    """
    fits = []
    search = {"grid_points": 5, "golden_steps": 3} if quick else {}
    for i, e in enumerate(effects):
        try:
            fits.append(fit_effect(twin, base, e, seeds=seeds, **search))
        except FIT_ERRORS as exc:  # one effect that cannot be simulated or fitted must not lose the ranking
            log.info("effect %s left out of the ranking: %s", e.name, exc)
        if callable(progress):
            progress(i + 1, len(effects), e.name)
    fits.sort(key=lambda f: (-f.shrink, f.gap_after))
    if len(refine_seeds) > len(seeds):
        before = overall_gap(stage_gaps(twin.features_rec.values,
                                        mean_features([twin.features(None, s) for s in refine_seeds])[0], base.sd))
        for f in fits[:n_refine]:
            if f.magnitude <= 0 or f.gap_before <= 0:
                continue
            gap, stages = gap_with(twin, base, f.name, f.magnitude, refine_seeds, own_spread=True)
            if math.isfinite(gap) and before > 0:
                f.gap_before, f.gap_after, f.stages_after = before, gap, stages
                f.shrink = max(0.0, 1.0 - gap / before)
                f.n_seeds = len(refine_seeds)
    fits.sort(key=lambda f: (-f.shrink, f.gap_after))
    if len(refine_seeds) > len(seeds):  # decided on more twins than the search used
        fits = separate_close_calls(twin, fits, refine_seeds)
        if fits and fits[0].magnitude > 0 and fits[0].n_seeds == len(refine_seeds):
            _refine_magnitude(twin, base, fits[0], refine_seeds)
    return fits


def separate_close_calls(twin: Twin, fits: list[EffectFit], seeds: tuple[int, ...], *,
                         margin: float = CLOSE_MARGIN) -> list[EffectFit]:
    """Order the top effect against a close call (another group, shrink within ``margin``) by the
    features that separate the two.

    Two effects that both remove most of the gap agree on most features (the size of the residual,
    say), and on those the comparison is a coin toss between their random draws. The features where
    their twins disagree — the means more than ``_SEPARATED`` pooled spreads apart (spread floored
    by ``STAGE_FLOORS``), e.g. whether the residual follows the temperature column or only a trend
    in time — decide: the effect whose twins the recording is closer to on them (sum of squared
    z-scores) goes first. Without such features the order by shrink stands, but for an effect of
    ``PLAIN_GROUPS`` (the ellipsoid), which then goes first.
    """
    if len(fits) < 2:
        return fits
    top = fits[0]
    rec = twin.features_rec.values
    for i, other in enumerate(fits[1:], start=1):
        if other.group == top.group or other.shrink < top.shrink - margin or min(other.magnitude, top.magnitude) <= 0:
            continue
        if other.n_seeds != len(seeds) or top.n_seeds != len(seeds):  # compared on the seeds both were refined on
            continue
        fa = [x for x in (twin.try_features({top.name: top.magnitude}, s) for s in seeds) if x is not None]
        fb = [x for x in (twin.try_features({other.name: other.magnitude}, s) for s in seeds) if x is not None]
        if len(fa) < 2 or len(fb) < 2:
            continue
        (ma, sa), (mb, sb) = mean_features(fa), mean_features(fb)
        score_a = score_b = 0.0
        n_sep = 0
        for k in ma:
            if k not in mb or k not in rec or ma[k].shape != rec[k].shape or mb[k].shape != rec[k].shape:
                continue
            floor = stage_floor(k, rec[k].shape)
            spread = np.maximum(np.sqrt(0.5 * (sa[k] ** 2 + sb[k] ** 2)), floor)
            sep = np.abs(ma[k] - mb[k]) > _SEPARATED * spread
            sep &= np.isfinite(ma[k]) & np.isfinite(mb[k]) & np.isfinite(rec[k])
            if sep.any():
                n_sep += int(sep.sum())
                score_a += float(np.sum(((rec[k] - ma[k]) / spread)[sep] ** 2))
                score_b += float(np.sum(((rec[k] - mb[k]) / spread)[sep] ** 2))
        if n_sep and score_b < score_a:
            log.debug("close call: %s before %s on %d separating features (%.3g < %.3g)",
                      other.name, top.name, n_sep, score_b, score_a)
            return [other, *fits[:i], *fits[i + 1:]]
        if not n_sep and other.group in PLAIN_GROUPS and top.group not in PLAIN_GROUPS:
            log.debug("close call: %s before %s, no feature separates them (the plainer model)", other.name, top.name)
            return [other, *fits[:i], *fits[i + 1:]]
    return fits


def separate_step_from_walk(twin: Twin, fits: list[EffectFit], seeds: tuple[int, ...], rivals: set[str] | frozenset[str],
                            *, margin: float = STEP_MARGIN) -> list[EffectFit]:
    """Order ``STEP_EFFECT`` (one offset step) against a rival whose offset changes otherwise (``rivals``: a
    random-walk drift, a warm-up without its temperature column, bursts) when one of the two leads and the
    other's shrink is within ``margin`` of it, by the time course of the offset.

    A step leaves two flat stretches, a drift keeps moving: the step evidence (``changes.step_evidence``, the
    share of the single ellipsoid fit's residual that one split with one shape and two centres removes) of
    the recording is put against that of the twins of each of the two effects at its fitted magnitude on
    ``seeds``, as ``log10`` of the share the split leaves, each on its twins' own spread (floored by
    ``_STEP_FLOOR``). The order by shrink stands unless the top effect's twins reject the recording (``|z| >
    _SEPARATED``) while the other's do not: a small effect buried in the noise leaves both twins alike, and
    then the time course does not decide. The size of the gap both reproduce does not decide either, nor the
    features the effect's random direction sets on part of the sphere.
    """
    if len(fits) < 2 or fits[0].magnitude <= 0:
        return fits
    top = fits[0]
    wanted = rivals if top.name == STEP_EFFECT else {STEP_EFFECT} if top.name in rivals else set()
    i = next((k for k, f in enumerate(fits[1:], start=1)
              if f.name in wanted and f.magnitude > 0 and f.shrink >= top.shrink - margin), None)
    if i is None:
        return fits
    other = fits[i]
    ts, sub = twin.t[twin.sub], twin.sub
    rec = _share_left(step_evidence(ts, twin.raw[sub]))
    z = []
    for f in (top, other):
        vals = []
        for s in seeds:
            try:
                vals.append(_share_left(step_evidence(ts, twin.simulate_raw({f.name: f.magnitude}, s)[sub])))
            except FIT_ERRORS as exc:
                log.debug("step evidence of %s, seed %d: %s", f.name, s, exc)
        if len(vals) < 2:
            return fits
        mean, spread = float(np.mean(vals)), max(float(np.std(vals, ddof=1)), _STEP_FLOOR)
        z.append((rec - mean) / spread)
        log.debug("step evidence: recording %.3f, %s twins %.3f +- %.3f (z %.2f)", rec, f.name, mean, spread, z[-1])
    if abs(z[0]) > _SEPARATED and abs(z[1]) <= _SEPARATED:
        log.debug("step against walk: %s before %s", other.name, top.name)
        return [other, *fits[:i], *fits[i + 1:]]
    return fits


def _share_left(shared_drop: float) -> float:
    """``log10`` of the share of the residual sum of squares one split leaves (a ratio of sums of squares:
    its spread over twins is multiplicative)."""
    return math.log10(max(1.0 - shared_drop, _MIN_LEFT))


def _refine_magnitude(twin: Twin, base: Baseline, f: EffectFit, seeds: tuple[int, ...]) -> None:
    """Re-fit the magnitude of ``f`` on ``seeds`` (more twins than the search used) by a parabola in
    ``log m`` through the gaps at ``m`` and ``m 10^(+-_REFINE_DECADES)`` (on the baseline's spread, as the
    search); ``f`` takes the new magnitude when it lowers that gap.

    An effect with a large random part (the random walk of ``bias_drift``) gives twins whose size
    varies by tens of percent from draw to draw, and the few search seeds are the same for every
    recording: their mean draw, not the recording, would otherwise set the magnitude.
    """
    x0 = math.log10(f.magnitude)
    effect = EFFECTS[f.name]
    top = 0.95 * effect.limit if math.isfinite(effect.limit) else float(effect.magnitude_range[1])
    x_top = max(math.log10(top), x0)  # the search's domain (a limit-less effect keeps its range)
    d = _REFINE_DECADES
    xs = (x0 - d, x0, x0 + d) if x0 + d <= x_top else (x0 - 2 * d, x0 - d, x0)
    ys = [gap_with(twin, base, f.name, 10.0**x, seeds)[0] for x in xs]
    if not all(math.isfinite(y) for y in ys):
        return
    y0 = ys[xs.index(x0)]
    curv = ys[0] - 2.0 * ys[1] + ys[2]  # the xs are evenly spaced
    if curv <= 0:  # not convex: step to the better end
        x = xs[0] if ys[0] < ys[2] else xs[2]
    else:
        x = xs[1] + 0.5 * d * (ys[0] - ys[2]) / curv
    x = min(max(x, x0 - 2 * d), x0 + 2 * d, x_top)
    if abs(x - x0) < 1e-3:
        return
    if not gap_with(twin, base, f.name, 10.0**x, seeds)[0] < y0:
        return
    gap, stages = gap_with(twin, base, f.name, 10.0**x, seeds, own_spread=True)  # as the ranking measured it
    if math.isfinite(gap):
        f.magnitude, f.gap_after, f.stages_after = 10.0**x, gap, stages
        f.shrink = max(0.0, 1.0 - gap / f.gap_before) if f.gap_before > 0 else 0.0
