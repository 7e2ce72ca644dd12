"""Partial calibration: calibrate what the motion makes observable, and say how good it is elsewhere.

A ground robot turns its magnetometer in yaw with a few degrees of roll and pitch: its samples fill
a ring or a narrow band of the field sphere, the fuzzy validator (which judges a full 9-parameter
fit) predicts an error of ~100 % and the plain fit is never run. This module is the other path.

**Estimate.** ``fitting_prior.fit_with_prior``: a maximum a posteriori fit of the symmetric model with
a prior. The prior is the last *full* calibration the calibrator accepted (or loaded), with its
covariance inflated by ``prior_inflate`` so the data can move it; without one, the documented broad
prior of ``fitting_prior.broad_prior`` (zero offset, identity matrix, offset std ``5`` field norms,
matrix std ``0.1``). The data are a time series of the magnetometer averaged down to one sample per
``partial_period_s`` (the last ``partial_samples`` of them, 300 s at the defaults): the direction
buffer keeps only ``per_bin`` samples per bin, ~170 on a ring, too few to average the noise; in time
order, the fit's covariance allows for coloured noise. The field norm is ``reference_norm`` when
configured, else the prior's, else the radius of a linear sphere fit to the series. A configured or
prior norm is held fixed; one estimated from the series is a tenth parameter of the MAP fit with a prior
sd of ``NORM_REL_STD`` (5 %, ``fit_with_prior(norm_rel_std=...)``): the data narrow it where they determine
it (a tumble, a steep band) and leave it on a ring, where the vertical offset follows the norm, and the
covariance of the nine parameters is marginal over it (the published calibration carries the estimated norm). The information
matrix tells which parameter directions the data determine: a parameter whose posterior variance fell
below a quarter of its prior variance is *updated*, the others *come from the prior* (their value
and uncertainty). A yaw-only robot thus gets its horizontal hard iron and 2-D soft iron from turning
and keeps the vertical terms it had.

**Decision.** The figure that matters is the heading error of what is used at the attitudes the robot
has: ``model.heading.heading_p95_quantile`` from the posterior covariance (with the slow noise the offset
absorbs, ``with_offset_noise``), at the *tilt seen* (half the 2.5-97.5
percentile spread of the calibrated field's elevation over the series: roll and pitch of ``±a`` move the
elevation by up to ``±a``) and the field inclination seen (``heading.inclination_deg``, z axis up on
average; a band tilted past ``INFER_INCLINATION_MAX_TILT_DEG`` takes 60°). A partial calibration is published when
that figure is at most ``max_heading_p95_deg`` and the
guard rails (``config.guard_rails`` without the parameter-uncertainty check, which the heading figure
replaces: the prior-held parameters are uncertain by construction) pass, and the data are a ring or band
(tilt seen at most ``partial_max_tilt_deg``, 45° by default: richer motion is the full path's) turned
about the body z axis (the calibrated field visits at least ``partial_min_azimuth`` of 36 azimuth
sectors, 90 % by default, counted about the centre of the ring it traces, ``ring_centre``: a fit whose offset
misses that centre still sees the turns the field made): the heading figures assume z up, and a cap about another axis (a sensor
waved about one pose) would be judged at the wrong attitudes. These cheap checks come first: a fit they
refuse costs no norm-uncertainty fit and no heading figures. An early fit (the recent samples, before the
series is long enough) of readings that turned (``config.STATIC_SPREAD``) and leave any ring's plane
(``ring_tilt_deg``), both it and its tilt seen past a ring's (``INFER_INCLINATION_MAX_TILT_DEG``), that fails the
azimuths is judged as rich motion's instead, at ±30° on ``early_heading_p95_deg``: a tumble's first seconds turn
about no one axis, and the azimuth rule held their fits back to 7.5-10 s where the 30° figure passed at 4-6 s
(``scripts/bench_speed.py``). Readings at rest (a car's first seconds, parked) or near a plane (a ground robot's first
seconds) keep the rule, and so do the series fits: its refusal sets how long the next fit waits
(``partial._partial_close``) and starts the azimuth watch a ring's next fit waits on (``partial._az_watch``).

**Near-level rings.** A ring whose raw readings leave its plane by at most ``near_level_tilt_deg``
(``ring_tilt_deg``: a car, a robot on a floor) leaves the tilt of the calibrated frame to the prior's cross
terms, and the level heading with it. Without a usable gyro the fit then holds the ring's plane level
(``fit_with_prior(level=True)``, ``model.fitting_level``: the sensor's z axis vertical on average), from every
default start, with a wider norm prior (``NEAR_LEVEL_NORM_REL_STD``); the status says so. The level figure is
then the data's (with the assumption's floor, weighed with the fitted vertical field), the ±30° ones not
determined: held level, the offset along the ring's axis comes
from the norm's prior and the readings' small wobble, which a mounting wobble or a field that changes along the path
makes as well as a tilt does (a real robot's spins in place, an LSM303DLHC, two recordings of one robot fitted by the
stream and by ``margcal calibrate``, read -46, -24, -11 and -9 deg of inclination, each fit's offset along the axis
2-3 uT in sd, the fits 20 uT apart; -46 deg came with a 30 deg bound of 16 deg, -24 with 7.6), unless the field is
given (``reference_norm``, a position's model field). The level figure weighs the uncertainty of the ring's plane
with the vertical field, so it holds at the fitted vertical only, and the status says so: the robot's first spin,
0.77 deg level at its fitted -11 deg, is 3.15 deg by ``margcal calibrate --lat 40 --lon -75`` (65 deg; its place
unknown). Moving only the figures' vertical to 60 deg was tried: on the independent generator's car it made the level
bound miss (87.5 % and 93.1 % covered for 100 %); not kept. A sensor mounted tilted on
the vehicle is calibrated in the vehicle's level frame, which no magnetometer can tell from its own (3.5 deg of
roll: 5-8 deg of heading at level on the independent generator's car): ``near_level_tilt_deg`` 0 turns the
assumption off for such a mount, and a gyro in the magnetometer's frame makes it unnecessary.

**Early fit on rich motion** (``early_fit``). Before the first calibration, the same MAP fit on richer
data (a tumble's first seconds, on the recent samples while the series is short) is
published when its predicted heading p95 at ±30° tilt is at most ``early_heading_p95_deg`` (1°), or at most
``max_heading_p95_deg`` (2.5°, the standard of every partial fit) once its directions fill more than half the sphere
(``RICH_REGIONS``: over a part, a real sensor's fit extrapolates what its bound cannot see): the covariance says when
the data suffice, instead of the validator's coverage rule and a fixed cadence.
An early fit of the first seconds that was still a ring or band (tilted at most ``partial_max_tilt_deg``, its
directions in fewer than ``RICH_REGIONS`` regions) is published on its figure at the tilt seen, as any partial fit;
while the ±30° figure of such an early calibration
exceeds ``early_heading_p95_deg`` and the series is short, early fits go on, each replacing it when its figure is
lower (as any partial refit; one of motion tilted past a ring's is judged on its ±30° figure, as above): a tumble
that began flat otherwise kept its first calibration, 1.4° off at 30°, until the full path's fit at 9 s.
The full path then runs as before; its fits replace the early one without the not-worse check against
it (``partial.PartialCalibration``), so the later calibrations are the full path's.
A refit replaces a partial
calibration when its predicted heading figure at the tilt seen is lower (instead of the not-worse check
on the last few seconds' residual, which noise decides as often as the data); a refit whose data show more tilt
is judged at the tilt the current calibration was judged at (like with like: more tilt alone raises the figure, and
a ±20° band's refit on 50 % more data was refused for it); one whose newest points misfit far more than the rest
(``TAIL_FACTOR``) is refused first: its series straddles a change not declared yet. The level and ±30° figures go
into the status, so a user sees that a calibration good when level is poor once the robot tilts past
what it covered. They are computed when first read (``HeadingFigures``: a few ms each, the posterior's draws):
a ring's fit is judged on the figure at the tilt seen alone, so a refused refit pays for no other figure, and an
installed one's are computed by the first status that shows them (the same values: the draws are fixed).

**Accelerometer.** The same fit runs on the gate's still samples, only to say which parameters the
poses seen determine (a level ground robot: the z offset and gain); it is never published, as no
heading figure judges it.

**Full calibrations.** ``heading_figures`` gives the same two figures for a calibration of the full
path (``fitting.fit``): the MAP problem from the broad prior on the buffer at the fit's own norm,
linearised at the full fit (``fitting_prior.posterior_at``: one Jacobian, no second fit), supplies a
covariance over the symmetric parameters (the published calibration is the full fit's, unchanged), times
``UNORDERED_SD_FACTOR``; or, when it predicts a larger level error, the delete-a-region jackknife covariance
(``fitting_jackknife``, with ``t_factor`` for its degrees of freedom), which sees what the model misses.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.errors import DegenerateDataError, InputError, MargCalError
from ..model.fitting_core import parameter_names
from ..model.fitting_gyro import GyroBlocks
from ..model.fitting_jackknife import REGIONS, jackknife_at, region_of, t_factor
from ..model.fitting_level import circle_centre
from ..model.fitting_prior import broad_prior, fit_with_prior_steps, posterior_at
from ..model.heading import (
    UNORDERED_SD_FACTOR,
    attitudes,
    format_bound,
    heading_p95_quantile,
    heading_p95_typical,
    heading_std_deg,
    inclination_deg,
    inflated,
    with_offset_noise,
)
from ..model.mounting import Mounting
from ..model.steps import Steps, drained
from .config import (
    STATIC_SPREAD,
    STILL_SPREAD,
    PipelineConfig,
    apart,
    guard_rails,
    readings_for,
    relative_spread,
    relative_std,
    rms_relative,
)

__all__ = ["AZIMUTH_SECTORS", "DEFAULT_INCLINATION_DEG", "NEAR_LEVEL_NORM_REL_STD", "NEAR_LEVEL_TILT_DEG", "RING_AXIS_MAX_DEG",
           "RING_FLAT", "SIGMA_REUSE_TOLERANCE", "HeadingFigures", "PartialResult", "azimuth_coverage", "azimuth_sector",
           "azimuth_sectors", "heading_figures", "partial_fit", "partial_fit_steps", "regions_seen", "ring_centre",
           "ring_figures", "ring_tilt_deg", "side_axis", "sphere_radius", "tilt_seen_deg"]

Array = NDArray[np.float64]

SYM_NAMES = parameter_names("sym", scale_free=False)
NORM_REL_STD = 0.05
"""Relative std of a field norm estimated from partial data (the sphere through a band; 3-15 % off on
the independent generator's ground robot at 60 s, within 5 % at 300 s)."""
NEAR_LEVEL_TILT_DEG = 2.5
"""The default of ``PipelineConfig.near_level_tilt_deg``: a ring whose readings leave its plane by at most this
tilt (``ring_tilt_deg``) is near-level: without a gyro the fit holds its plane level
(``fitting_prior.fit_with_prior(level=True)``, ``model.fitting_level``); 0 turns the level term off."""
NEAR_LEVEL_NORM_REL_STD = 0.3
"""Relative std of a field norm estimated from a near-level ring: the sphere through a flat ring is barely
determined (the independent generator's car at +-0.2 deg: 25-28 uT for 48). (Its prior at the middle of the
unit's plausible range instead, 37 uT, made a tuning seed's fit settle off the ring: not used.)"""
SIGMA_REUSE_TOLERANCE = 0.3
"""A previous fit's noise is kept when the residuals at the new solution agree with it within this share."""
DEFAULT_INCLINATION_DEG = 60.0
"""Field inclination assumed for the heading figures of a full calibration (mid latitudes) unless configured."""
INFER_INCLINATION_MAX_TILT_DEG = 10.0
"""A partial fit's figures take the inclination its data show (``heading.inclination_deg``: z up on average) only
when their tilt seen is at most this; else ``DEFAULT_INCLINATION_DEG``. A z axis tilted by ``a`` lowers the field's
mean vertical share by about ``1 - cos a``, and over few turns its tilt toward the field does not average out: on the
independent generator's ±20° band 44-58° for 60°, where the bound then missed the error at the true field's."""


TAIL_POINTS, TAIL_FACTOR = 10, 4.0
"""A refit of a published partial calibration whose RMS residual over the newest ``TAIL_POINTS`` series points (2 s at
the defaults) is above ``TAIL_FACTOR`` times that over the rest is refused: the newest samples are not of the sensor
the rest are (a change the detector has not declared yet). A ground robot's refit 2.5 s after a 20 uT step, whose
residuals stayed under the detector's threshold (3-5.7 %), read 11x, took the step for tilt and was published 57 deg
off the sensor after the step (5 deg off the one before); the independent generator's refits on rings: at most
2.4x (90 of them, tuning seeds; 2.1x over 101 on others). Checked first: a series that straddles a change makes
no refit."""
RICH_REGIONS = 7
"""A fit of motion tilted past a ring's is published at ``max_heading_p95_deg`` (the standard of every partial fit)
when its calibrated directions fill at least this many of the 12 regions of ``fitting_jackknife.REGIONS`` (3 points
each): more than half the sphere, over which the ellipsoid interpolates; else at ``early_heading_p95_deg``. A real
sensor is not one ellipsoid everywhere: the sunsided HMC5883L's fit of its first 18.5 s (5 regions) is 3.5 deg at 30
deg from the whole recording's, and the stream's fit of them, published at 2.5 deg with a 2.24 deg bound, missed it;
the independent generator's tumbles fill 7-8 regions when their bound first reaches 2.5 deg (``regions_seen``).
A fit whose directions fill this many is also rich motion, whatever its tilt seen: a ring or band fills 4 (the
independent generator's ground robots, bands and car), and a tumble whose tilt seen stayed at 45 deg was refused as a
ring that had turned through 72 % of the azimuths while it filled 7-9 regions. A ring tilted at most
``INFER_INCLINATION_MAX_TILT_DEG`` is not, however many it crosses: a level circle of directions crosses 8 of them at 30
deg of elevation (a ground robot near the magnetic equator: its refits were refused as "not a ring or band"), and a
ring held level whose fit put the field at -46 deg crossed 8 too."""
REGION_MIN_POINTS = 3
"""Fewest points for ``regions_seen`` to count a region as seen (one stray point is no coverage)."""


def regions_seen(cal: Calibration, raw: Array) -> int:
    """How many of the 12 regions of ``fitting_jackknife.REGIONS`` (about 63 deg across) hold at least
    ``REGION_MIN_POINTS`` of ``raw``'s calibrated directions."""
    counts = np.bincount(region_of(raw, cal), minlength=len(REGIONS))
    return int(np.count_nonzero(counts >= REGION_MIN_POINTS))


@dataclass(frozen=True, eq=False)
class HeadingFigures:
    """Predicted heading error (p95, degrees) of a magnetometer calibration, level and at ±30° tilt: the 95 %
    bound (``level_deg``, ``tilt30_deg``, the publication rules' figure) and the typical figure, the p95 it most
    likely measures (``*_typical_deg``, ``heading.heading_p95_typical`` of ``calibration``, the one with the
    covariance). Each costs a few ms (the posterior's draws): computed when first read, then kept, so a partial fit
    refused on the figure at the tilt seen pays for no other (the figures are deterministic: the same whenever read)."""

    inclination_deg: float
    calibration: Calibration
    vertical_note: str = ""
    """Non-empty when a ring fit's vertical is not the data's (held level, or fitted within ``HORIZONTAL_FIELD_DEG`` of
    horizontal, without the field given: ``_vertical_note``): the ±30° figures are then not determined, and this says
    why."""

    @cached_property
    def level_deg(self) -> float:
        return self._figure(heading_p95_quantile, 0.0)

    @cached_property
    def tilt30_deg(self) -> float:
        return math.nan if self.vertical_note else self._figure(heading_p95_quantile, 30.0)

    @cached_property
    def level_typical_deg(self) -> float:
        return self._figure(heading_p95_typical, 0.0)

    @cached_property
    def tilt30_typical_deg(self) -> float:
        return math.nan if self.vertical_note else self._figure(heading_p95_typical, 30.0)

    def _figure(self, how: Callable[..., float], tilt: float) -> float:
        """One figure, NaN ("not determined") when it cannot be computed: read by a status, it must not raise."""
        try:
            return how(self.calibration, tilt_deg=tilt, inclination=self.inclination_deg)
        except (MargCalError, ValueError, ArithmeticError):
            return math.nan


@dataclass(frozen=True)
class PartialResult:
    """A partial (MAP) fit and its verdict.

    Attributes:
        calibration: the MAP estimate (posterior covariance attached), or None when the fit failed.
        updated: parameters the data determined; from_prior: those kept from the prior.
        prior_kind: ``"broad"`` (no previous calibration) or ``"previous"``.
        tilt_seen_deg: the tilt range of the data; heading_seen_deg: the predicted heading p95 there.
        figures: level and ±30° figures.
        reason: why it must not be published ("" when it may).
        over_limit: the refusal was the predicted heading error above this limit (degrees), else None.
        azimuth: share of the azimuth sectors the calibrated field visited (nan when not computed).
        sigma: the noise of the fit's residuals (nan when it failed): the next fit on the same kind of data
            may take it as given (``partial_fit(sigma=...)``).
        gyro_explained: with gyro blocks, the share of the field's turning the gyro accounted for (nan: none).
        gyro_used: the gyro was part of the fit (it accounted for at least ``fitting_gyro.MIN_EXPLAINED``).
        gyro_frame: the axis order or signs of the rates that would explain the field's turning far better
            (``fitting_prior.PriorFit.gyro_frame``, e.g. ``"(x, y, -z)"``); "" when none; gyro_frame_shares: the share
            of the turning it explains and the rates' own (``PriorFit.gyro_frame_shares``).
        level: the fit held the ring's plane level (a near-level ring without a usable gyro).
        mounting: with gyro blocks, the magnetometer's rotation against the IMU found from them under this fit's
            calibration (``model.mounting.find_mounting``; set by ``partial.PartialCalibration``), else None.
        not_better: a refit refused only for predicting no smaller heading error than the current calibration.
    """

    calibration: Calibration | None
    updated: tuple[str, ...]
    from_prior: tuple[str, ...]
    prior_kind: str
    tilt_seen_deg: float
    heading_seen_deg: float
    figures: HeadingFigures | None
    reason: str
    over_limit: float | None = None
    azimuth: float = math.nan
    sigma: float = math.nan
    gyro_explained: float = math.nan
    gyro_used: bool = False
    gyro_frame: str = ""
    level: bool = False
    mounting: Mounting | None = None
    gyro_frame_shares: tuple[float, float] = (math.nan, math.nan)
    not_better: bool = False


def sphere_radius(points: Array) -> float:
    """Radius of the linear least-squares sphere through ``points`` (nan when degenerate)."""
    a = np.c_[2.0 * points, np.ones(len(points))]
    sol, *_ = np.linalg.lstsq(a, (points * points).sum(axis=1), rcond=None)
    c = sol[:3]
    r2 = float(sol[3] + c @ c)
    return math.sqrt(r2) if math.isfinite(r2) and r2 > 0 else math.nan


def ring_tilt_deg(raw: Array) -> float:
    """How far raw readings leave the plane of their ring, as a tilt (degrees): ``atan(sqrt(2) s_3 / sqrt(s_1 s_2))``
    of their principal spreads ``s_1 >= s_2 >= s_3``, about twice the tilt's standard deviation on a ring (the
    independent generator at 60 deg inclination: 1.1-1.3 for a car whose tilt varies by +-1.5 deg, 3.2-3.3 for a
    ground robot's +-5 deg); from the readings alone, before any fit. Inf for fewer than 4 readings."""
    if len(raw) < 4:
        return math.inf
    sv = np.linalg.svd(raw - raw.mean(axis=0), compute_uv=False)
    return math.degrees(math.atan2(math.sqrt(2.0) * sv[2], math.sqrt(sv[0] * sv[1])))


def tilt_seen_deg(cal: Calibration, raw: Array) -> float:
    """Tilt range of the data (degrees): half the 2.5-97.5 percentile spread of the calibrated elevation."""
    h = cal.apply(raw)
    el = np.degrees(np.arcsin(np.clip(h[:, 2] / np.linalg.norm(h, axis=1), -1.0, 1.0)))
    lo, hi = np.percentile(el, [2.5, 97.5])
    return float(0.5 * (hi - lo))


UNHELD_TILT_FACTOR = 2.0
"""A ring fit refused on its heading figure whose tilt seen is above this many times the ring's own thickness
(``ring_tilt_deg``), not held level, says so: the fit tilted the ring, the data did not (a real car's ring 6.7 deg
thick, ``near_level_tilt_deg`` 2.5, read as 24 deg of tilt and 84 deg of heading error)."""


STEEP_FIELD_DEG = 65.0
"""A ring's fit refused on its heading figure, without the gyro, where its field dips at least this much says that a
gyro would help: the horizontal field is weak there and a tilt leaks ``tan(inclination)`` times its size into the
heading (the independent generator's ±5 deg ground robot, seeds 3-4: first calibration at 65 deg 76-87 s, at 70 deg
294 s or none in 300 s, at 75 deg none; with its gyro 24-50 s at all three, worst level 0.3-0.8 deg)."""


HORIZONTAL_FIELD_DEG = 15.0
"""A ring's fit, without a given field (``reference_norm``, ``heading_inclination_deg``) or the gyro, that puts the
field within this many degrees of horizontal (the inclination inferred from its own data) has its ±30° figures not
determined: a flat ring whose readings wander out of its plane (a field that changes along the path, as on a real
car) is fitted with its z offset where the calibrated field is horizontal and the norm does not see the wander, and
the covariance calls that vertical determined: the independent generator's +-1 deg ground robot with 1 uT of such
wander, seeds 1-3, read 5-7 deg of inclination and a 30 deg bound of 3.6-4.0 deg for a true 90.5-91.5 deg (its level
heading right: 0.51-0.84 deg for 1.2-1.5). The Earth's field is that flat only within about 8 deg of the magnetic
equator, where the figures need the field given anyway."""


AZIMUTH_SECTORS = 36
"""Azimuth sectors (about the body z axis) of ``azimuth_coverage``."""


RING_FLAT = 0.25
"""``ring_centre``: calibrated readings whose thickness (smallest principal spread) is at most this share of
their width (the middle one) form a ring ..."""
RING_AXIS_MAX_DEG = 30.0
"""... when its axis lies within this angle of the body z axis (a sensor waved in a cone about another axis
traces a ring too, about that axis: not a vehicle's turns)."""


def ring_centre(h: Array) -> tuple[float, float]:
    """The centre (x, y) of the ring that calibrated readings ``h`` (N, 3) trace about the body z axis (a circle
    through their horizontal parts, linear least squares); (0, 0) when they are no flat ring about z (a band,
    a tumble, a cone about another axis) or the circle is degenerate. A calibration whose offset misses the
    ring's centre (a wrong vertical offset leaking through a cross term) still sees the azimuths the field
    actually turned through: about this centre, not about the origin."""
    if len(h) < 4:
        return 0.0, 0.0
    _, sv, vt = np.linalg.svd(h - h.mean(axis=0), full_matrices=False)
    if not (sv[2] <= RING_FLAT * sv[1] and abs(vt[2, 2]) >= math.cos(math.radians(RING_AXIS_MAX_DEG))):
        return 0.0, 0.0
    return circle_centre(h[:, :2])


def side_axis(raw: Array) -> str:
    """``"x"`` or ``"y"`` when raw readings trace a flat ring (``RING_FLAT``) about that axis of the sensor (within
    ``RING_AXIS_MAX_DEG``), else "": a magnetometer mounted on its side on a turning vehicle, or one waved in a cone
    about that axis; the ring rules and heading figures take z as up (``up_axis`` turns the readings)."""
    if len(raw) < 10:
        return ""
    _, sv, vt = np.linalg.svd(raw - raw.mean(axis=0), full_matrices=False)
    if not sv[2] <= RING_FLAT * sv[1]:
        return ""
    k = int(np.argmax(np.abs(vt[2])))
    return "xy"[k] if k < 2 and abs(vt[2, k]) >= math.cos(math.radians(RING_AXIS_MAX_DEG)) else ""


def azimuth_sectors(cal: Calibration, raw: Array, centre: tuple[float, float] | None = None) -> Array:
    """The azimuth sector (0 .. ``AZIMUTH_SECTORS - 1``) of each calibrated reading about ``centre`` (default:
    ``ring_centre`` of the readings; see ``azimuth_sector``)."""
    h = cal.apply(raw)
    cx, cy = ring_centre(h) if centre is None else centre
    az = np.arctan2(h[:, 1] - cy, h[:, 0] - cx)
    return np.floor((az + math.pi) / (2.0 * math.pi) * AZIMUTH_SECTORS).astype(int) % AZIMUTH_SECTORS


def azimuth_sector(hx: float, hy: float) -> int:
    """The azimuth sector of one calibrated reading's horizontal part: ``azimuth_sectors`` for one sample
    without numpy's per-call cost (the stream's per-sample path)."""
    return int((math.atan2(hy, hx) + math.pi) / (2.0 * math.pi) * AZIMUTH_SECTORS) % AZIMUTH_SECTORS


def azimuth_coverage(cal: Calibration, raw: Array) -> float:
    """Share of the ``AZIMUTH_SECTORS`` azimuth sectors (about the body z axis, about the ring's centre:
    ``ring_centre``) that the calibrated field visits."""
    return len(np.unique(azimuth_sectors(cal, raw))) / AZIMUTH_SECTORS


def _inclination(cfg: PipelineConfig, cal: Calibration, raw: Array | None) -> float:
    if cfg.heading_inclination_deg is not None:
        return float(cfg.heading_inclination_deg)
    return inclination_deg(cal, raw) if raw is not None else DEFAULT_INCLINATION_DEG


def _poses_note(cal: Calibration, updated: tuple[str, ...], sensor: str, max_std: float) -> str:
    """What an accelerometer's poses determine, by the guard rails' standard (``max_parameter_std``, not only what
    the data took from the prior), and the readings the least determined of the others needs (``readings_for``):
    ten real poses with no pose between x and y left ``w_xy`` 4 % uncertain while every parameter was "updated"."""
    rel = relative_std(cal)
    firm = [n for n in SYM_NAMES if n in updated and rel.get(n, math.inf) <= max_std]
    loose = [n for n in SYM_NAMES if n not in firm]
    note = f"partial fit (not published for the {sensor}): the poses seen determine {', '.join(firm) or 'no parameter'}; "
    if not loose:
        return note + "none need more poses"
    worst = max(loose, key=lambda n: rel.get(n, math.inf))
    sd = rel.get(worst, math.inf)
    shown = f"std {100 * sd:.3g} % > {100 * max_std:.3g} %" if math.isfinite(sd) else "not determined"
    verb = "needs" if len(loose) == 1 else "need"
    return note + f"{', '.join(loose)} {verb} more poses ({worst}, {shown}: {readings_for(worst, sensor)})"


def _figures(cal: Calibration, inc: float, vertical_note: str = "") -> HeadingFigures:
    """The figures of ``cal``, each computed when first read (``HeadingFigures``); the covariance checked now."""
    if cal.covariance is None or tuple(cal.parameter_names) != SYM_NAMES:
        msg = f"heading figures need a covariance over {SYM_NAMES}"
        raise InputError(msg)
    return HeadingFigures(inc, cal, vertical_note)


def _vertical_note(cfg: PipelineConfig, inc: float, gyro_used: bool, held: bool = False) -> str:
    """Why a ring's ±30° figures are not determined (``HORIZONTAL_FIELD_DEG``; ``held``: its plane held level,
    module docstring, **Near-level rings**), or ""."""
    if cfg.reference_norm or cfg.heading_inclination_deg is not None or gyro_used:
        return ""
    if held:
        return (f"the ring held level, the field's vertical ({inc:.3g} deg inclination) is the norm prior's, which a flat "
                "ring cannot tell from a field that changes along the path: the 30 deg figures are not determined, the "
                "level one holds at that vertical only; give the field (--lat/--lon, reference_norm)")
    if not abs(inc) < HORIZONTAL_FIELD_DEG:
        return ""
    return (f"the fit puts the field {inc:.3g} deg from horizontal, which a flat ring cannot tell from a field that "
            "changes along the path: the 30 deg figures are not determined; give the field (--lat/--lon, reference_norm)")


def _fit_figures(cal: Calibration, raw: Array, cfg: PipelineConfig, sigma: float | None, tilt: float, *, rich: bool,
                 gyro_used: bool, held: bool) -> HeadingFigures:
    """A partial fit's heading figures: at the inclination its readings ``raw`` show when it is a ring tilted at most
    ``INFER_INCLINATION_MAX_TILT_DEG`` ("z up on average"; else the default or the given one), with the offset part of
    slow noise of residual noise ``sigma`` (``with_offset_noise``: longer than the series, the offset absorbs it and no
    residual shows it), a ring's ±30° ones not determined when its vertical is not the data's (``_vertical_note``)."""
    inc = _inclination(cfg, cal, None if rich or not tilt <= INFER_INCLINATION_MAX_TILT_DEG else raw)
    bounded = with_offset_noise(cal, sigma) if sigma is not None and math.isfinite(sigma) and sigma >= 0 else cal
    return _figures(bounded, inc, "" if rich else _vertical_note(cfg, inc, gyro_used, held=held))


def ring_figures(cal: Calibration, raw: Array, cfg: PipelineConfig, sigma: float = math.nan) -> HeadingFigures:
    """The heading figures of a ring's fit held level without a gyro, as ``partial_fit_steps`` makes them
    (``_fit_figures``): for ``margcal calibrate``'s fit of a near-level ring."""
    return _fit_figures(cal, raw, cfg, sigma, tilt_seen_deg(cal, raw), rich=False, gyro_used=False, held=True)


def _own_frame(cal: Calibration) -> Calibration:
    """A calibration turned into another frame (``W = R S``, ``mag.calibrate_into_imu_frame``) as the symmetric fit it
    came from, ``S`` (the polar factor): the figures are the fit's, in the sensor's own frame, as for a fit published
    turned; the symmetric model's covariance is read at ``S`` (at ``R S`` it was 46 deg where 0.3 deg was right)."""
    w = np.asarray(cal.matrix, dtype=np.float64)
    if np.allclose(w, w.T, rtol=0.0, atol=1e-9 * float(np.max(np.abs(w)))):
        return cal
    _, sv, vt = np.linalg.svd(w)
    return cal.replace(matrix=vt.T @ np.diag(sv) @ vt, covariance=None, parameter_names=())


def _jackknifed(points: Array, cal: Calibration, prior: Calibration) -> Calibration | None:
    """``cal`` with its jackknife covariance for a 95 % bound (``fitting_jackknife``: times ``t_factor``), None when
    the samples fill too few regions for one."""
    try:
        jack, dof = jackknife_at(points, cal, prior)
    except DegenerateDataError:
        return None
    return inflated(jack, t_factor(dof))


def _wider(a: Calibration, b: Calibration | None, inc: float) -> Calibration:
    """Of two covariances of one calibration, the one that predicts the larger level heading error (the largest
    first-order sd over yaw: cheap, and the bound's order); ``a`` when there is no ``b``."""
    if b is None:
        return a
    level = attitudes(0.0)
    sd_a = float(np.max(heading_std_deg(a, level, inclination=inc)))
    sd_b = float(np.max(heading_std_deg(b, level, inclination=inc)))
    return b if sd_b > sd_a or not math.isfinite(sd_b) else a


def heading_figures(cal: Calibration, points: Array, cfg: PipelineConfig) -> tuple[HeadingFigures, Calibration] | None:
    """Level and ±30° heading figures of a full-path calibration, and the calibration with a covariance over
    the symmetric parameters (module docstring); None when not computable."""
    try:
        cal = _own_frame(cal)
        cov_cal = cal
        inc = DEFAULT_INCLINATION_DEG if cfg.heading_inclination_deg is None else float(cfg.heading_inclination_deg)
        if cal.covariance is None or tuple(cal.parameter_names) != SYM_NAMES:
            # the buffer has no time order: its slow noise counts as independent samples and the covariance is too
            # small (model.heading: UNORDERED_SD_FACTOR, chosen on the bound benchmark's tuning seeds); what the
            # model misses the jackknife sees (model.fitting_jackknife): the wider of the two
            prior = broad_prior(points, cal.norm)
            cov_cal = _wider(inflated(posterior_at(points, cal, prior), UNORDERED_SD_FACTOR), _jackknifed(points, cal, prior),
                             inc)
        return _figures(cov_cal, inc), cov_cal
    except (MargCalError, ValueError, ArithmeticError):
        return None


def partial_fit(series: Array, prior: Calibration | None, cfg: PipelineConfig, **kwargs: Any) -> PartialResult:
    """The MAP fit of ``series`` (time-ordered raw samples) from ``prior`` and its verdict: ``partial_fit_steps`` run
    to the end (the same arguments)."""
    return drained(partial_fit_steps(series, prior, cfg, **kwargs))


def _tail_misfit(cal: Calibration, series: Array) -> float:
    """RMS relative residual of ``cal`` over the newest ``TAIL_POINTS`` of ``series`` over that of the rest (0 when the
    series is shorter than four tails or the rest fits exactly)."""
    pts = np.asarray(series, dtype=np.float64)
    if len(pts) < 4 * TAIL_POINTS:
        return 0.0
    rest = rms_relative(cal, pts[:-TAIL_POINTS])
    return rms_relative(cal, pts[-TAIL_POINTS:]) / rest if rest > 0 else 0.0


def partial_fit_steps(series: Array, prior: Calibration | None, cfg: PipelineConfig, *, recent: Array,
                      spread: Array | None = None,
                      current: Calibration | None, stamp: float, sensor: str,
                      current_heading: float | None = None, current_tilt: float | None = None,
                      sigma: float | None = None, max_iter: int = 200,
                      start: Calibration | None = None, sigma_tolerance: float = SIGMA_REUSE_TOLERANCE,
                      gyro: GyroBlocks | None = None, level_ok: bool = True, early: bool = False) -> Steps[PartialResult]:
    """The MAP fit of ``series`` (time-ordered raw samples) from ``prior`` and its verdict (module docstring), in the
    steps of ``fitting_prior.fit_with_prior_steps`` and one for the heading figures.

    ``sigma``: the residual noise of the previous fit on the same kind of data, taken as given (one solve
    per start instead of three: ~5x cheaper) unless the residuals at the solution disagree by more than
    ``sigma_tolerance``, when the fit is repeated with the noise estimated. ``max_iter``: evaluations
    per solve (an early fit's start that needs more is in a flat, wrong valley: another start wins).
    ``start``: the previous fit on the same series, the one start of the MAP fit (``fit_with_prior``).
    ``current_heading``, ``current_tilt``: the current partial calibration's predicted heading p95 and the tilt it was
    judged at; a ring's refit is compared with it at that tilt (module docstring).
    ``spread``: when ``series`` holds block means, each block's spread (``fit_with_prior(spread=...)``).
    ``gyro``: blocks of the raw samples with their rates (``fit_with_prior(gyro=...)``). ``level_ok``: a near-level
    ring without gyro blocks may be held level (false while a gyro's rates arrive but fill too few blocks yet:
    the gyro, not the assumption, should decide; a mounting tilt makes the assumption publish 5-8 deg). ``early``: an
    early fit refining the current calibration (an early fit's), which may publish on rich motion as without one."""
    kind = "previous" if prior is not None else "broad"
    try:
        if prior is not None and (prior.covariance is None or tuple(prior.parameter_names) != SYM_NAMES):
            prior = None
            kind = "broad"
        if sensor == "mag" and relative_spread(np.asarray(series)[:, :3]) < STILL_SPREAD:  # noise about one reading
            return PartialResult(None, (), SYM_NAMES, kind, math.nan, math.inf, None,
                                 "partial fit: none (the readings have not turned)")
        # a near-level ring without a usable gyro: the level term (model.fitting_level), from every default start
        # (a previous solution may sit in the flat ring's valley of a large norm and a nearly vertical field)
        thick = ring_tilt_deg(series) if sensor == "mag" else math.inf
        level = level_ok and thick <= cfg.near_level_tilt_deg
        norm = cfg.reference_norm or (prior.norm if prior is not None else sphere_radius(series))
        if not (math.isfinite(norm) and norm > 0):
            return PartialResult(None, (), SYM_NAMES, kind, math.nan, math.inf, None, "no field norm from the data")
        if prior is None:
            prior = broad_prior(series, norm, sensor=sensor, unit=cfg.unit)
            inflate = 1.0
        else:
            inflate = cfg.prior_inflate
        # an estimated norm is a tenth parameter with its own uncertainty (module docstring)
        norm_std = (NEAR_LEVEL_NORM_REL_STD if level else NORM_REL_STD) if (
            sensor == "mag" and not cfg.reference_norm and kind == "broad") else 0.0
        for noise in (sigma, None) if sigma is not None else (None,):
            if noise is None and sigma is not None:
                yield
            pf = yield from fit_with_prior_steps(series, prior, inflate=inflate, stamp=stamp, time_ordered=True,
                                                 norm_rel_std=norm_std, sigma=noise, max_iter=max_iter,
                                                 start=None if level else start, spread=spread, gyro=gyro,
                                                 gyro_scale_std=cfg.gyro_scale_std, level=level)
            if noise is None or abs(pf.residual_sigma / noise - 1.0) <= sigma_tolerance:
                break  # the given noise fits the residuals (else: again with the noise estimated)
        cal = pf.calibration
        if sensor != "mag":
            return PartialResult(cal, pf.updated, pf.from_prior, kind, math.nan, math.inf, None,
                                 _poses_note(cal, pf.updated, sensor, cfg.max_parameter_std), sigma=pf.residual_sigma)
        tilt = tilt_seen_deg(cal, series)
        # a ring or band fills 4 of the 12 regions at 60 deg of inclination, a tumble's first seconds 7 and more however
        # far its tilt goes; a ring (tilted at most INFER_INCLINATION_MAX_TILT_DEG) is never rich (RICH_REGIONS)
        regions = regions_seen(cal, series)
        rich = not tilt <= cfg.partial_max_tilt_deg or (regions >= RICH_REGIONS and tilt > INFER_INCLINATION_MAX_TILT_DEG)
        # the cheap verdicts first: a fit they refuse needs no norm uncertainty and no heading figures
        if rich and not (cfg.early_fit and (current is None or early)):
            shown, limit = apart(tilt, cfg.partial_max_tilt_deg)
            what = (f"the data are tilted up to {shown} deg > {limit} deg" if tilt > cfg.partial_max_tilt_deg else
                    f"the directions fill {regions} of {len(REGIONS)} regions of the sphere >= {RICH_REGIONS}")
            return PartialResult(cal, pf.updated, pf.from_prior, kind, tilt, math.inf, None,
                                 f"partial fit: {what}, not a ring or band: the full path decides", sigma=pf.residual_sigma,
                                 gyro_explained=pf.gyro_explained, gyro_used=pf.gyro_used, gyro_frame=pf.gyro_frame,
                                 gyro_frame_shares=pf.gyro_frame_shares,
                                 level=pf.level)
        azimuth = azimuth_coverage(cal, series)
        # an early fit of turning readings off any ring's plane, tilted past a ring's but turned through too few
        # azimuths for a band (a tumble's first seconds): judged as rich motion's, at 30 deg (module docstring, **Decision**)
        arc = ""
        if (not rich and not azimuth >= cfg.partial_min_azimuth and early and cfg.early_fit
                and min(tilt, thick) > INFER_INCLINATION_MAX_TILT_DEG
                and relative_spread(np.asarray(series)[:, :3]) >= STATIC_SPREAD):
            rich, arc = True, (f"the field turned through {100 * azimuth:.0f} % of the azimuths about the body z axis < "
                               f"{100 * cfg.partial_min_azimuth:.0f} % (not a ground robot's turns), judged as rich motion: ")
        if not rich and not azimuth >= cfg.partial_min_azimuth:
            return PartialResult(cal, pf.updated, pf.from_prior, kind, tilt, math.inf, None,
                                 f"partial fit: the field turned through {100 * azimuth:.0f} % of the azimuths about the "
                                 f"body z axis < {100 * cfg.partial_min_azimuth:.0f} %: not a ground robot's turns",
                                 azimuth=azimuth, sigma=pf.residual_sigma, gyro_explained=pf.gyro_explained,
                                 gyro_used=pf.gyro_used, gyro_frame=pf.gyro_frame,
                                 gyro_frame_shares=pf.gyro_frame_shares, level=pf.level)
        yield  # the heading figures next
        figs = _fit_figures(cal, series, cfg, pf.residual_sigma, tilt, rich=rich, gyro_used=pf.gyro_used, held=pf.level)
        bounded, inc = figs.calibration, figs.inclination_deg
        seen = figs.tilt30_deg if rich else heading_p95_quantile(bounded, tilt_deg=tilt, inclination=inc)
        like = seen  # the refit's figure at the tilt the current calibration was judged at (like with like)
        if (not rich and current_heading is not None and current_tilt is not None and tilt > current_tilt
                and not seen < current_heading):
            yield
            like = heading_p95_quantile(bounded, tilt_deg=current_tilt, inclination=inc)
    except (MargCalError, ValueError, ArithmeticError) as exc:
        return PartialResult(None, (), SYM_NAMES, kind, math.nan, math.inf, None, f"partial fit failed: {exc}")
    limit, part = cfg.max_heading_p95_deg, ""
    if rich:  # over more than half the sphere the partial standard, else the early one (RICH_REGIONS)
        limit = max(cfg.early_heading_p95_deg, limit) if regions >= RICH_REGIONS else cfg.early_heading_p95_deg
        part = "" if regions >= RICH_REGIONS else f" (directions in {regions} of {len(REGIONS)} regions < {RICH_REGIONS})"
    reason, over, not_better = "", None, False
    if current_heading is not None and (tail := _tail_misfit(cal, series)) > TAIL_FACTOR:
        reason = (f"partial refit: its residual over the newest {TAIL_POINTS} series points is {tail:.1f}x that over "
                  "the rest: they are not of the same sensor (a change the detector has not declared yet?)")
    elif not seen <= limit:
        where = f"at 30 deg tilt{part}" if rich else f"at the tilt seen ({tilt:.1f} deg)"
        reason = (f"partial fit: {arc}predicted heading error p95 {where} {format_bound(seen)} > {limit:g} deg"
                  if math.isfinite(seen) else f"partial fit: {arc}predicted heading error {where} not determined (no finite "
                  "covariance)")
        over = limit
        if not rich and level_ok and cfg.near_level_tilt_deg < thick < tilt / UNHELD_TILT_FACTOR:
            reason += (f" (the readings leave their ring's plane by {thick:.1f} deg, this fit tilts it {tilt:.1f} deg: "
                       f"the vertical is not determined; a ring flatter than mag.near_level_tilt_deg = "
                       f"{cfg.near_level_tilt_deg:g} deg is held level, a field disturbed along the path thickens it)")
        elif not rich and not pf.level and not pf.gyro_used and abs(inc) >= STEEP_FIELD_DEG:
            reason += (f" (the field dips {abs(inc):.0f} deg: a tilt weighs {math.tan(math.radians(abs(inc))):.1f}x its "
                       "size in the heading, and the ring's own tilts must fix the vertical terms; with the Imu's rates "
                       "such a ring calibrates sooner)")
    elif current_heading is not None and not like < current_heading:
        at = "" if like is seen else f" ({format_bound(like)} at its {current_tilt:.1f} deg of tilt)"
        reason = (f"partial refit: predicted heading error p95 {format_bound(seen)}{at} not below the current "
                  f"calibration's {format_bound(current_heading)}")
        not_better = True
    else:
        # a partial refit replaces a partial calibration on its predicted heading (above), not on the
        # residual of the last few seconds, which noise decides as often as the data
        rails = guard_rails(cal.replace(covariance=None, parameter_names=()), cfg, recent,
                            None if current_heading is not None else current)
        if rails:
            reason = f"partial fit: {rails}"
    return PartialResult(cal, pf.updated, pf.from_prior, kind, tilt, seen, figs, reason, over, azimuth, pf.residual_sigma,
                         pf.gyro_explained, pf.gyro_used, pf.gyro_frame, pf.level, not_better=not_better,
                         gyro_frame_shares=pf.gyro_frame_shares)
