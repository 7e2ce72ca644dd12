"""Why a batch fit failed, and what can still be fitted: ``margcal calibrate``'s answer to "did not converge".

The plain fit of ``fitting.fit`` (norm residual, every parameter free) stops with a ``ConvergenceError``
or runs away (a huge flat ellipsoid) on data that do not determine the model. ``rescue`` looks for the
reason, in this order, and acts on it:

1. *static*: the readings stay within ``STATIC_SPREAD`` of their mean norm (RMS distance from their
   mean): they fix the field norm and nothing else. Nothing is fitted (``Rescue.refused``).
2. *a change*: ``diagnosis.changes.locate_offset_change`` finds an offset step (a magnet attached
   mid-way) in the recording, else in its first or last two thirds (attached, then removed): each side is
   fitted on its own (plain fit, or the prior fit when that side alone is partial), and a side whose fit
   is refused or leaves a residual above the limit is searched and split once more, else fitted without the
   static runs at its ends when that fit passes (a rest somewhere else, the magnet taken off while still:
   ``_trimmed``); every stretch's calibration is returned.
3. *partial coverage* (a hemisphere, a ring, a few great circles): ``fitting_prior.fit_with_prior``
   from ``broad_prior`` fits what the directions determine and keeps the rest at the prior, saying
   which parameters are which.

Before any fit, ``screen`` takes out readings no fit should see, counted and said: *absurd* ones
(a component beyond ``MAX_READING``: no sensor reads that in any unit, and the fit's squares of it
overflow) and *spikes*, a robust pre-filter on the norm about a robust centre: a reading more than
``SPIKE_GAP`` times as far from the coordinate-wise median of the readings as every reading of the bulk,
when such far readings are at most ``SPIKE_SHARE`` of them. The field moves continuously over an
ellipsoid, so its readings leave no such gap; a bit error or a bus fault does (the streaming calibrator's
intake and spike filter drop the same samples). One sample 20 field norms away otherwise decides the
least-squares fit (it does not converge, and the rescue below then fits the spike).

A result is *implausible* when ``stream.config.plausibility`` says so (field norm outside the Earth
field or gravity in a known unit, parameter uncertainty, offset limit, axis gains): the same limits
the online calibrator applies before it publishes. A plausible fit whose residual exceeds the online
limit (``residual_note``) is only searched for an offset change (``change_only``): without one the
high residual is motion or disturbance, and the plain fit stands with a warning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..diagnosis.changes import OffsetChange, locate_offset_change
from ..model.calibration import Calibration
from ..model.errors import ConvergenceError, DegenerateDataError, InputError
from ..model.fitting import fit
from ..model.fitting_prior import PriorFit, broad_prior, fit_with_prior
from ..model.heading import UNDETERMINED_DEG, format_bound, heading_p95_quantile, heading_p95_typical
from ..recordings import MAX_STAMP_S
from ..stream.config import STATIC_SPREAD, PipelineConfig, plausibility, relative_spread, relative_std, residual_limit
from ..stream.observable import (
    DEFAULT_INCLINATION_DEG,
    NEAR_LEVEL_NORM_REL_STD,
    HeadingFigures,
    ring_figures,
    ring_tilt_deg,
)

__all__ = [
    "HEADING_DETERMINED_DEG", "MAX_READING", "MIN_SCALE", "SPIKE_GAP", "SPIKE_SHARE", "STATIC_SPREAD", "Part",
    "Rescue", "Screen", "check",
    "config_for", "figures_text", "heading_text", "inclination_of", "reading_scale", "rescue", "rests_apart", "screen"
]

MAX_READING = 1e100
"""Largest |component| of a reading the batch fit takes, raw units: far beyond any sensor in any unit
(counts, nT), far below where the fit's squares and products overflow."""
MIN_SCALE = 1e-100
"""Smallest scale of the readings (``reading_scale``) the batch fit takes: below it their squares underflow."""
SPIKE_GAP = 3.0
"""A spike is more than this many times as far from the readings' median as every reading of the bulk."""
SPIKE_SHARE = 0.02
"""At most this share of the readings (at least one) are spikes; more far readings are data, not glitches."""

HEADING_DETERMINED_DEG = UNDETERMINED_DEG
"""A predicted heading error p95 beyond this (or not finite) is printed as not determined, not as 9845001 deg."""
RESCUE_SHARED_DROP = 0.5
"""Evidence an offset change needs here: one shape with two centres removing half the single fit's
residual. Lower than the diagnosis's ``changes.MIN_SHARED_DROP`` (0.65), which searches every recording:
here the search runs only after the plain fit failed or left a residual above the online limit, and each
side must then fit on its own (BROAD 32, a magnet attached 1 cm away, removes 0.58)."""
STATIC_WINDOW_S = 1.0
"""``_static_ends``: the static runs at a stretch's ends are found in windows this long."""
_LOCATE_POINTS = 6000
"""The change search runs on an evenly spaced subsample of at most this many points (as the diagnosis)."""


def _locate_once(t: Array, points: Array) -> OffsetChange | None:
    """``locate_offset_change`` on an evenly spaced subsample, with the rescue's evidence threshold."""
    pick = np.linspace(0, len(points) - 1, min(_LOCATE_POINTS, len(points))).astype(np.intp)
    return locate_offset_change(np.asarray(t)[pick], np.asarray(points)[pick], min_shared_drop=RESCUE_SHARED_DROP)


def _locate(t: Array, points: Array) -> OffsetChange | None:
    """An offset change in ``points``: the best single split of all of them, else of their first or last two
    thirds (a magnet attached and later removed: no single split of the whole explains A-B-A, one of a window
    holding one change does; the stretch beyond it is split in turn by ``_segment``)."""
    found = _locate_once(t, points)
    if found is not None or len(points) < 3 * _MIN_POINTS:
        return found
    n = len(points)
    windows = [_locate_once(t[a:b], points[a:b]) for a, b in ((0, 2 * n // 3), (n // 3, n))]
    return max((c for c in windows if c is not None), key=lambda c: c.shared_drop, default=None)

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

_MIN_POINTS = 10  # fewer samples than this are not fitted at all
_PRIOR_POINTS = 6000  # the prior fit runs on at most this many evenly spaced samples


def _distances(points: Array, centre: Array) -> Array:
    """|v_i - centre| without overflow (hypot) for any finite readings (inf beyond the float range)."""
    d = points - centre
    with np.errstate(over="ignore"):
        return np.asarray(np.hypot(np.hypot(d[:, 0], d[:, 1]), d[:, 2]), dtype=np.float64)


def _spikes(points: Array) -> Mask:
    """The readings beyond the largest gap ``SPIKE_GAP`` among the ``SPIKE_SHARE`` farthest from the median."""
    n = len(points)
    out = np.zeros(n, dtype=bool)
    if n < _MIN_POINTS:
        return out
    d = _distances(points, np.median(points, axis=0))
    order = np.argsort(d)[::-1]
    far = d[order]
    m = max(1, int(SPIKE_SHARE * n))
    with np.errstate(invalid="ignore", over="ignore"):
        gaps = np.flatnonzero(far[:m] > SPIKE_GAP * far[1 : m + 1])
    if gaps.size:
        out[order[: gaps[-1] + 1]] = True
    return out


@dataclass(frozen=True)
class Screen:
    """What ``screen`` kept (``keep``, a mask over the readings) and why it dropped the others."""

    keep: Mask
    absurd: int
    spikes: int
    farthest: float = 0.0
    bulk: float = 0.0

    @property
    def dropped(self) -> dict[str, int]:
        """Readings dropped per reason (only the reasons that dropped any)."""
        return {k: v for k, v in (("absurd", self.absurd), ("spike", self.spikes)) if v}

    def text(self, unit: str = "") -> str:
        """One line saying what was dropped, "" when nothing was."""
        u = f" {unit}" if unit else ""
        parts = []
        if self.absurd:
            parts.append(f"{self.absurd} absurd (a component beyond {MAX_READING:g}, not a reading in any unit)")
        if self.spikes:
            parts.append(f"{self.spikes} spike(s) up to {self.farthest:.4g}{u} from the readings' median, more than "
                         f"{SPIKE_GAP:g} x the farthest of the other readings ({self.bulk:.4g}{u})")
        if not parts:
            return ""
        return (f"dropped {self.absurd + self.spikes} of {len(self.keep)} readings before the fit: {'; '.join(parts)}"
                + ("; --keep-spikes fits the spikes" if self.spikes else ""))


def screen(points: Array, *, spikes: bool = True) -> Screen:
    """The readings a batch fit should see (module docstring): absurd ones out, then spikes (unless ``spikes`` is
    False)."""
    pts = np.asarray(points, dtype=np.float64)
    keep = np.all(np.abs(pts) <= MAX_READING, axis=1) if pts.size else np.ones(len(pts), dtype=bool)
    n_absurd = int((~keep).sum())
    if not spikes:
        return Screen(keep, n_absurd, 0)
    idx = np.flatnonzero(keep)
    spike = _spikes(pts[idx])
    if not spike.any():
        return Screen(keep, n_absurd, 0)
    d = _distances(pts[idx], np.median(pts[idx], axis=0))
    keep = keep.copy()
    keep[idx[spike]] = False
    return Screen(keep, n_absurd, int(spike.sum()), float(d[spike].max()), float(d[~spike].max()))


def reading_scale(points: Array) -> float:
    """The scale of the readings, raw units: the larger of their median norm and their median distance from
    their median (about the field's radius for any recording that turns; 0 for none)."""
    pts = np.asarray(points, dtype=np.float64)
    if not len(pts):
        return 0.0
    zero = np.zeros(3)
    return max(float(np.median(_distances(pts, zero))), float(np.median(_distances(pts, np.median(pts, axis=0)))))


@dataclass(frozen=True)
class Part:
    """One calibration of the rescue: its samples, the fit, and the prior fit's bookkeeping if one was used."""

    label: str
    calibration: Calibration | None
    n_points: int
    prior_fit: PriorFit | None = None
    note: str = ""
    figures: HeadingFigures | None = None
    """A near-level ring's fit held level (``_prior_fit``): its heading figures as the stream makes them
    (``observable.ring_figures``: at the inclination of its own field, the ±30° ones possibly not determined)."""


@dataclass(frozen=True)
class Rescue:
    """What ``rescue`` found: the reason (``kind``: static, change, partial), the parts fitted, the text."""

    kind: str
    reason: str
    parts: tuple[Part, ...] = ()
    change: OffsetChange | None = None
    lines: list[str] = field(default_factory=list)

    @property
    def refused(self) -> bool:
        """Nothing was fitted (a static recording)."""
        return not any(p.calibration is not None for p in self.parts)


def config_for(sensor: str, unit: str, **overrides: Any) -> PipelineConfig:
    """The online calibrator's limits for ``sensor`` in ``unit`` (an empty or unknown unit: no field-strength check),
    with ``overrides`` (``--set``)."""
    return PipelineConfig.for_sensor(sensor, unit or "raw", **overrides)


def check(cal: Calibration, cfg: PipelineConfig | None) -> str:
    """Why ``cal`` is implausible ("" when it is not, or when there is no configuration to judge it).

    ``stream.config.plausibility``: the field norm in a known unit, the parameter uncertainty, the
    offset and the axis gains.
    """
    return "" if cfg is None else plausibility(cal, cfg)


def residual_note(cal: Calibration, cfg: PipelineConfig | None, noise: float = 0.0) -> str:
    """"" unless the residual exceeds the online calibrator's limit (``max_residual``, 5 % of the field for the
    magnetometer, or wider for a sensor whose white ``noise``, raw units, is larger: ``stream.config.residual_limit``)."""
    st = cal.stats
    if cfg is None or st is None:
        return ""
    limit, why = residual_limit(cal, cfg, noise)
    if st.rms_relative <= limit:
        return ""
    return (f"residual RMS {100 * st.rms_relative:.3g} % > limit {100 * limit:.3g} %{why}: "
            "one calibration does not explain the recording")


def _norm_guess(points: Array) -> float:
    """A field norm for the prior: the algebraic sphere fit's radius, else the half-extent of the data."""
    centred = points - points.mean(axis=0)
    half = 0.5 * float(np.ptp(centred @ np.linalg.svd(centred, full_matrices=False)[2][0]))
    a = np.c_[2.0 * points, np.ones(len(points))]
    sol, *_ = np.linalg.lstsq(a, (points * points).sum(axis=1), rcond=None)
    r2 = float(sol[3] + sol[:3] @ sol[:3])
    r = math.sqrt(r2) if math.isfinite(r2) and r2 > 0 else 0.0
    return r if 0.5 * half <= r <= 2.0 * half else max(half, 1e-300)


def _sphere_centre(points: Array) -> Array | None:
    a = np.c_[2.0 * points, np.ones(len(points))]
    sol, *_ = np.linalg.lstsq(a, (points * points).sum(axis=1), rcond=None)
    return sol[:3] if np.isfinite(sol).all() else None


def _prior_part(label: str, points: Array, norm: float | None, sensor: str, unit: str, stamp: float,
                cfg: PipelineConfig | None, note: str = "") -> Part:
    """The prior fit of ``points`` as a ``Part``, with the stream's heading figures when it held a ring level."""
    pf = _prior_fit(points, norm, sensor, unit, stamp, cfg)
    figs = None
    if pf.level and cfg is not None:
        figs = ring_figures(pf.calibration, points[:: max(1, len(points) // _PRIOR_POINTS)], cfg, pf.residual_sigma)
    return Part(label, pf.calibration, len(points), pf, note=note, figures=figs)


def _prior_fit(points: Array, norm: float | None, sensor: str, unit: str, stamp: float,
               cfg: PipelineConfig | None = None) -> PriorFit:
    """The MAP fit from ``broad_prior`` and from the same prior moved to the sphere-fit centre; the lower residual wins.

    The broad prior is centred on zero offset; a hard iron of a field norm or more (a magnet) puts the
    data's ellipsoid far from it and the fit can end in a poor minimum, which the second prior avoids.
    A magnetometer's ring flatter than ``cfg.near_level_tilt_deg`` (``observable.ring_tilt_deg``) is held level, with
    the wider norm prior, as the stream holds it (``observable``, **Near-level rings**): fitted free, a real robot's
    spin in place 1.6 deg thick took cross terms of 0.25 from its wobble and came 6-18 deg p95 off the level heading
    of a 2-D ellipse fit of its ring, where the stream's level fit came within 0.1-0.3 deg.
    """
    step = max(1, len(points) // _PRIOR_POINTS)
    pts = points[::step]
    level = sensor == "mag" and cfg is not None and ring_tilt_deg(pts) <= cfg.near_level_tilt_deg
    norm_std = NEAR_LEVEL_NORM_REL_STD if level and norm is None else 0.0
    prior = broad_prior(pts, norm if norm is not None else _norm_guess(pts), sensor=sensor, unit=unit)
    priors = [prior]
    centre = _sphere_centre(pts)
    if centre is not None:
        priors.append(prior.replace(offset=centre))
    best: PriorFit | None = None
    for pr in priors:
        try:
            pf = fit_with_prior(pts, pr, time_ordered=True, stamp=stamp, level=level, norm_rel_std=norm_std)
        except ConvergenceError:
            continue
        st, bst = pf.calibration.stats, None if best is None else best.calibration.stats
        if best is None or (st is not None and bst is not None and st.rms_relative < bst.rms_relative):
            best = pf
    if best is None:
        msg = "the prior fit found no finite solution"
        raise ConvergenceError(msg)
    return best


def _span(t: Array) -> str:
    return f"{float(t[0]):.1f} to {float(t[-1]):.1f} s" if len(t) else "empty"


def _plain_fit(t: Array, points: Array, kw: dict[str, object]) -> tuple[Calibration | None, str, str]:
    """The plain fit of a stretch (stamped with its end), why it is refused (the fit's error or the plausibility
    check) and, when it is not, whether its residual is above the limit (``residual_note``); "" for none."""
    cfg = kw["cfg"]
    try:
        cal = fit(points, model=str(kw["model"]), method="lm", norm=kw["norm"], loss=str(kw["loss"]),  # type: ignore[arg-type]
                  sensor=str(kw["sensor"]), unit=str(kw["unit"])).replace(stamp=float(t[-1]) if len(t) else 0.0)
    except (ConvergenceError, DegenerateDataError) as exc:
        return None, str(exc), ""
    why = check(cal, cfg)  # type: ignore[arg-type]
    return cal, why, "" if why else residual_note(cal, cfg, float(kw.get("noise", 0.0)))  # type: ignore[arg-type]


def _static_ends(t: Array, points: Array) -> tuple[int, int]:
    """``(lo, hi)``: the stretch without its static runs at either end (``STATIC_WINDOW_S`` windows whose readings stay
    within ``STATIC_SPREAD`` of their mean; a window of fewer than 3 readings counts as turning)."""
    tc = np.clip(t, -MAX_STAMP_S, MAX_STAMP_S)  # a stray 1e23 stamp: a finite window index, no cast warning
    w = np.floor((tc - tc[0]) / STATIC_WINDOW_S).astype(np.intp)
    _, starts = np.unique(w, return_index=True)
    ends = np.r_[starts[1:], len(t)]
    turning = [b - a < 3 or relative_spread(points[a:b]) >= STATIC_SPREAD for a, b in zip(starts, ends, strict=True)]
    if not any(turning):
        return 0, 0
    i, j = turning.index(True), len(turning) - 1 - turning[::-1].index(True)
    lo, hi = int(starts[i]), int(ends[j])
    # into the windows where the sensor came to rest or started: the readings as near the rest's mean as its own
    if lo > 0:
        lo = _rest_edge(points, lo, range(lo, hi))
    if hi < len(points):
        hi = _rest_edge(points, hi - 1, range(hi - 1, lo - 1, -1), tail=True)
    return lo, hi


def _rest_edge(points: Array, edge: int, walk: range, tail: bool = False) -> int:
    """The first reading of ``walk`` (from the turning side's edge toward it) farther from the rest's mean than 3x the
    rest's RMS spread (at least 1e-9 of its norm): the rest, ``points[:edge]`` (``tail``: ``points[edge + 1:]``), ends
    there."""
    rest = points[edge + 1:] if tail else points[:edge]
    mean = rest.mean(axis=0)
    reach = max(3.0 * float(np.sqrt(np.mean(np.sum((rest - mean) ** 2, axis=1)))), 1e-9 * float(np.linalg.norm(mean)))
    for k in walk:
        if float(np.linalg.norm(points[k] - mean)) > reach:
            return k + 1 if tail else k
    return walk.stop + 1 if tail else walk.stop


def _turning_fit(t: Array, points: Array, kw: dict[str, object]) -> tuple[int, int, Calibration] | None:
    """``(lo, hi, calibration)``: the plain fit of the stretch without the static runs at its ends
    (``_static_ends``), when there are such runs and that fit passes; None otherwise."""
    lo, hi = _static_ends(t, points)
    if (lo == 0 and hi == len(points)) or hi - lo < _MIN_POINTS:
        return None
    cal, why, high = _plain_fit(t[lo:hi], points[lo:hi], kw)
    return None if cal is None or why or high else (lo, hi, cal)


def _trimmed(t: Array, points: Array, failure: str, kw: dict[str, object]) -> list[Part] | None:
    """A stretch whose fit was refused, without the static runs at its ends, when that fits and passes (module
    docstring); None otherwise. A still sensor somewhere else (a table with iron in it, the magnet taken off while it
    rests) is one direction no change search can split off (a static side visits no azimuths) and a few thousand
    samples of it outweigh the turning ones."""
    got = _turning_fit(t, points, kw)
    if got is None:
        return None
    lo, hi, cal = got
    note = f"static: no calibration (the fit with it was refused: {failure})"
    return ([Part(_span(t[:lo]), None, lo, note=note)] if lo else []) + [Part(_span(t[lo:hi]), cal, hi - lo)] + (
        [Part(_span(t[hi:]), None, len(t) - hi, note=note)] if hi < len(t) else [])


def rests_apart(t: Array, points: Array, *, model: str, norm: float | None, loss: str, sensor: str, unit: str,
                cfg: PipelineConfig, noise: float = 0.0) -> tuple[Calibration, str] | None:
    """A plausible fit of a recording whose rest at an end sits in another field: the fit without that rest, and what
    was left out; None when no rest at the ends is off the field the sensor turned in by more than the stream's
    ``change_threshold`` and twice the turning part's median (median relative residuals), or the fit without it is
    refused.

    A sensor put down on a table with iron in it (or near a laptop) reads a field other than the one it turned in;
    thousands of readings of that one direction pull the whole-file fit toward it: two of twelve public recordings
    (6 % and 9 % off; their fits 1.9-2.5 deg from their turning part's) where the stream said "sensor changed"."""
    kw: dict[str, object] = {"model": model, "norm": norm, "loss": loss, "sensor": sensor, "unit": unit, "cfg": cfg,
                             "noise": noise}
    got = _turning_fit(t, points, kw)
    if got is None:
        return None
    lo, hi, turning = got
    # beyond the change threshold and twice the turning part's own median (its noise: the stream's no-change tolerance)
    limit = max(cfg.change_threshold, 2.0 * turning.median_relative_error(points[lo:hi]))
    head, tail = turning.median_relative_error(points[:lo]), turning.median_relative_error(points[hi:])
    keep_lo = 0 if head <= limit else lo
    keep_hi = len(points) if tail <= limit else hi
    if keep_lo == 0 and keep_hi == len(points):
        return None
    if (keep_lo, keep_hi) != (lo, hi):  # one rest apart, the other in the same field: keep that one
        turning, why, high = _plain_fit(t[keep_lo:keep_hi], points[keep_lo:keep_hi], kw)
        if turning is None or why or high:
            return None
    gone = [(a, b, r) for a, b, r in ((0, keep_lo, head), (keep_hi, len(points), tail)) if b > a]
    text = " and ".join(f"the rest at {_span(t[a:b])} ({b - a} readings), {100 * r:.1f} % off the field the sensor "
                        "turned in" for a, b, r in gone)
    text += f" (the limit: {100 * limit:.2g} %, the change threshold or twice the turning part's median)"
    return turning, f"left out {text}: a disturbed field where it rested (iron, a magnet)? --no-rescue keeps it"


def _segment(t: Array, points: Array, label: str, depth: int, kw: dict[str, object]) -> list[Part]:
    """The calibrations of one stretch: nothing if static, the plain fit, a further split, or the prior fit."""
    n = len(points)
    unit = str(kw["unit"])
    stamp = float(t[-1]) if len(t) else 0.0
    spread = relative_spread(points) if n else 0.0
    if n < _MIN_POINTS or spread < STATIC_SPREAD:
        return [Part(label, None, n, note=f"static ({100 * spread:.2g} % spread): no calibration")]
    cal, why, high = _plain_fit(t, points, kw)
    if not why and not high:
        return [Part(label, cal, n)]
    if depth > 0:
        ch = _locate(t, points)
        if ch is not None:
            before = t < ch.t
            kw["changes"].append(ch.t)  # type: ignore[attr-defined]
            return (_segment(t[before], points[before], _span(t[before]), depth - 1, kw)
                    + _segment(t[~before], points[~before], _span(t[~before]), depth - 1, kw))
    trimmed = _trimmed(t, points, why or high, kw)
    if trimmed is not None:
        return trimmed
    if not why:  # a residual above the limit without a change: the plain fit stands
        return [Part(label, cal, n)]
    return [_prior_part(label, points, kw["norm"], str(kw["sensor"]), unit, stamp, kw["cfg"],  # type: ignore[arg-type]
                        note=f"plain fit: {why}; fitted with the prior instead")]


def rescue(t: Array | None, points: Array, *, failure: str, model: str, norm: float | None, loss: str,
           sensor: str, unit: str, cfg: PipelineConfig | None, change_only: bool = False,
           noise: float = 0.0) -> Rescue | None:
    """Diagnose a failed or implausible fit of ``points`` (module docstring) and fit what can be fitted.

    Args:
        t: the sample times (None: no change search).
        points: the raw readings (n, 3) in time order, every component within ``MAX_READING`` (``screen``).
        failure: why the requested fit was not accepted (the error or the plausibility message).
        model, norm, loss, sensor, unit: as for ``fitting.fit``.
        cfg: the limits that judge a fit (``config_for``), None for no plausibility check.
        change_only: the fit itself is plausible, only its residual is high: look for an offset change
            and return None when there is none (motion or disturbances, not a reason to refit).
        noise: the readings' white noise (raw units), which widens the residual limit (``residual_note``).

    Raises:
        InputError: a component of ``points`` beyond ``MAX_READING`` or not finite.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.size and not float(np.max(np.abs(pts))) <= MAX_READING:  # LAPACK may loop for ever on their squares
        msg = f"points: a component beyond {MAX_READING:g} (or not finite); drop such readings first (screen)"
        raise InputError(msg)
    stamp = float(t[-1]) if t is not None and len(t) else 0.0
    u = f" {unit}" if unit else ""
    if change_only:
        return _change(t, pts, failure, model=model, norm=norm, loss=loss, sensor=sensor, unit=unit, cfg=cfg,
                       noise=noise)
    if len(pts) < _MIN_POINTS:
        reason = f"only {len(pts)} samples: too few for any calibration (need {_MIN_POINTS})"
        return Rescue("too few", reason, lines=[f"requested fit: {failure}", reason])
    spread = relative_spread(pts)
    if spread < STATIC_SPREAD:
        level = float(np.median(np.linalg.norm(pts, axis=1)))
        reason = (f"static recording: the {len(pts)} readings stay within {100 * spread:.2g} % of their mean "
                  f"(|v| = {level:.4g}{u}); they determine the field norm only, not the offset or the matrix")
        what = ("hold the sensor still in several poses, each axis pointing up and down" if sensor == "accel" else
                "turn the sensor through all directions")
        return Rescue("static", reason, lines=[f"requested fit: {failure}", reason, f"no calibration fitted: {what}"])
    found = _change(t, pts, failure, model=model, norm=norm, loss=loss, sensor=sensor, unit=unit, cfg=cfg,
                    noise=noise)
    if found is not None:
        return found
    part = _prior_part("prior fit", pts, norm, sensor, unit, stamp, cfg)
    pf = part.prior_fit
    assert pf is not None
    max_std = (cfg or PipelineConfig.for_sensor(sensor)).max_parameter_std  # the guard rails' standard
    rel = relative_std(pf.calibration)
    firm = [n for n in pf.updated if rel.get(n, math.inf) <= max_std]
    loose = [n for n in pf.updated if n not in firm]  # narrowed from the prior, not determined: the guard refuses them
    reason = (f"partial coverage: the directions determine {', '.join(firm) or 'no parameter'} (std <= "
              f"{100 * max_std:.3g} %)"
              + (f"; narrow {', '.join(loose)} without determining {'it' if len(loose) == 1 else 'them'}" if loose else "")
              + f"; {', '.join(pf.from_prior) or 'none'} kept from the broad prior ({_prior_text(pf)})")
    lines = [f"requested fit: {failure}", reason]
    if pf.level and cfg is not None:
        lines.append(f"near-level ring: the readings leave their ring's plane by {ring_tilt_deg(pts):.2g} deg <= "
                     f"mag.near_level_tilt_deg = {cfg.near_level_tilt_deg:g} deg: its plane taken as level, as the "
                     "stream takes it (a mounting tilt is not seen: --set mag.near_level_tilt_deg=0 for a tilted mount)")
    return Rescue("partial", reason, (part,), None, lines)


def _prior_text(pf: PriorFit) -> str:
    centred = bool(np.any(pf.prior.offset))
    return f"identity matrix, offset {'at the sphere-fit centre' if centred else 'zero'}, 5 field norms std"


def _change(t: Array | None, pts: Array, failure: str, *, model: str, norm: float | None, loss: str, sensor: str,
            unit: str, cfg: PipelineConfig | None, noise: float = 0.0) -> Rescue | None:
    """The offset-change diagnosis: the stretches between located changes, each fitted; None without a change."""
    u = f" {unit}" if unit else ""
    if t is None or len(t) != len(pts) or len(pts) < _MIN_POINTS:
        return None
    times = np.asarray(t, dtype=np.float64)
    ch = _locate(times, pts)
    if ch is None:
        return None
    before = times < ch.t
    changes: list[float] = [ch.t]
    kw: dict[str, object] = {"model": model, "norm": norm, "loss": loss, "sensor": sensor, "unit": unit, "cfg": cfg,
                             "changes": changes, "noise": noise}
    parts = (*_segment(times[before], pts[before], _span(times[before]), 1, kw),
             *_segment(times[~before], pts[~before], _span(times[~before]), 1, kw))
    more = sorted(changes[1:])
    also = f" (and at {', '.join(f'{c:.2f}' for c in more)} s)" if more else ""
    fitted = sum(1 for p in parts if p.calibration is not None)
    still = f" and {len(parts) - fitted} static stretch(es)" if fitted < len(parts) else ""
    reason = (f"the offset changed at t = {ch.t:.2f} s by {ch.step:.4g}{u} ({100 * ch.relative_step:.3g} % of "
              f"the field; the split removes {100 * ch.drop:.3g} % of one ellipsoid's residual){also}: the "
              f"recording holds {fitted} calibrations{still}, fitted on each stretch")
    return Rescue("change", reason, parts, ch, [f"requested fit: {failure}", reason])


def inclination_of(cfg: PipelineConfig | None) -> float:
    """The inclination of the heading figures: the configured one (a position's model field), else 60° (mid latitudes)."""
    return DEFAULT_INCLINATION_DEG if cfg is None or cfg.heading_inclination_deg is None else cfg.heading_inclination_deg


def figures_text(figs: HeadingFigures) -> str:
    """``heading_text`` of a near-level ring's fit held level (``Part.figures``): at its own field's inclination, the
    ±30° figures not determined (and why) unless the field is given (``observable.ring_figures``)."""
    why = f" ({figs.vertical_note})" if figs.vertical_note else ""
    return (f"predicted heading error p95: {format_bound(figs.level_deg)} level, {format_bound(figs.tilt30_deg)} at 30 "
            f"deg tilt (95 % bound; typical {format_bound(figs.level_typical_deg)} / "
            f"{format_bound(figs.tilt30_typical_deg)}; {figs.inclination_deg:.3g} deg field inclination, the ring held "
            f"level){why}")


def heading_text(cal: Calibration, inclination: float = DEFAULT_INCLINATION_DEG) -> str:
    """Predicted heading error p95 from the covariance, level and at 30° tilt (at ``inclination``, deg), as the 95 %
    bound (``heading.heading_p95_quantile``) and the typical figure (``heading.heading_p95_typical``), or ""; a figure
    that is not determined says so (``heading.format_bound``)."""
    inc = float(inclination)
    try:
        level = heading_p95_quantile(cal, tilt_deg=0.0, inclination=inc)
        tilt = heading_p95_quantile(cal, tilt_deg=30.0, inclination=inc)
        typ_level = heading_p95_typical(cal, tilt_deg=0.0, inclination=inc)
        typ_tilt = heading_p95_typical(cal, tilt_deg=30.0, inclination=inc)
    except (InputError, ValueError, np.linalg.LinAlgError):
        return ""
    if not (math.isfinite(level) and level <= HEADING_DETERMINED_DEG):
        return "predicted heading error p95: not determined (the data leave the horizontal terms free)"
    if not (math.isfinite(tilt) and tilt <= HEADING_DETERMINED_DEG):
        return (f"predicted heading error p95: {format_bound(level)} level (95 % bound; typical {format_bound(typ_level)}); "
                "at 30 deg tilt not determined: the data leave the vertical terms free")
    return (f"predicted heading error p95: {format_bound(level)} level, {format_bound(tilt)} at 30 deg tilt (95 % bound; "
            f"typical {format_bound(typ_level)} / {format_bound(typ_tilt)}; {inc:.3g} deg inclination)")
