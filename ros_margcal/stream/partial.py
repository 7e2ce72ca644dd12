"""The calibrator's side of the partial calibration: its time series, its jobs, what the status shows.

``PartialCalibration`` is a mixin of ``evaluation.Evaluation`` (and so of ``SensorCalibrator``); the
estimate and the decision live in ``observable`` (see its docstring). Here:

- the decimated time series of the samples that reach the buffer stage (the accelerometer's: the
  gate's still means): the mean of each ``partial_period_s`` and its spread, the last ``partial_samples`` of them,
  fed from the sample path;
- for the magnetometer, the last ``gyro_samples`` samples with the rate pushed with them (a sample without
  one is kept as a gap), cut into blocks of ``gyro_block_s`` for the gyro-aided fit
  (``model.fitting_gyro``) of a series fit; the status says what share of the field's turning the gyro
  accounted for, and that it was not used when too little (the gyro and magnetometer not in one frame);
- the prior: the last *full* calibration accepted or loaded (with a covariance over the symmetric
  parameters; a full fit gets one from ``observable.heading_figures``), else the broad prior;
- the early fit on rich motion (``observable``): before the first calibration, on the recent samples
  (``recent_samples``, all of them while uncalibrated) while the series is shorter than ``min_points``, also
  after an early calibration whose ±30° figure is above ``early_heading_p95_deg`` (``_early_open``);
- when a partial fit is due: the full validator refused, ``partial_fit`` is on, there is no
  calibration, a sensor change is pending, or the current one is partial; and the series grew since
  the last attempt by a quarter (``PARTIAL_GROWTH``), or by what that attempt's refusal asks for (up to
  doubling, ``PARTIAL_GROWTH_MAX``: a heading error 3x its limit or a third of the azimuths turned
  through is not retried after a few more samples; a published partial calibration is refitted once the
  series grew by half, ``REFIT_GROWTH``), which overrides the skip
  rule's back-off (a ground robot's buffer stops changing, its series does not);
- a declared sensor change drops the series points and gyro rows from before its onset (``_drop_before_change``);
- the noise of the last series fit's residuals and its solution, given to the next series fit (one solve
  from that one start instead of three from each of two or three); the early fits take the last early
  fit's noise as given whatever their residuals say (they still carry the model's misfit, and against the
  broad prior the noise barely moves the estimate; the covariance of time-ordered data comes from the
  residuals themselves);
- the status fields: ``partial``, ``updated_parameters``, ``prior_parameters``, the predicted heading
  p95 level and at ±30° (also for a full magnetometer calibration), the tilt seen.
- the magnetometer's mounting against the IMU (``model.mounting``): with gyro blocks, each series fit (and a full
  fit whose job carries ``gyro_rows``: ``_full_mounting``) estimates which of the 24 axis-aligned rotations turns
  the calibrated field into the Imu's frame and the misalignment left, with its sd; the status names it and what to
  fix (``mounting`` fields). With ``calibrate_into_imu_frame`` (option, off by default) a decided rotation ``q``
  turns the readings of the series and the gyro rows from then on (those kept too: ``_turn_readings``; a signed
  permutation, exact), so the series fits run in the IMU's axes: the gyro's rates explain the turning (no "gyro not
  used"), the ring is judged about the IMU's z, and the published calibration is ``R W' q`` with offset ``q^T b'``
  (``_published``): its output is the field in the IMU's frame.

The accelerometer's partial fit is never published (a heading figure does not judge it): its status
says which parameters the poses seen determine and which need more poses (a level ground robot: the
z terms only).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.fitting import RUNAWAY_AXIS_RATIO
from ..model.fitting_geometric import block_means
from ..model.fitting_gyro import MIN_EXPLAINED, UNIT_NAMES, GyroBlocks, frame_advice, gyro_blocks, turning_share
from ..model.fitting_level import LEVEL_TILT_STD_DEG, circle_centre
from ..model.heading import format_bound
from ..model.mounting import Mounting, find_mounting_steps, into_imu_frame, turned
from ..model.steps import Steps
from .config import STATIC_SPREAD, PipelineConfig, relative_spread
from .observable import (
    AZIMUTH_SECTORS,
    SIGMA_REUSE_TOLERANCE,
    SYM_NAMES,
    HeadingFigures,
    PartialResult,
    azimuth_sector,
    azimuth_sectors,
    heading_figures,
    partial_fit_steps,
    ring_centre,
)

__all__ = ["PartialCalibration"]

Array = NDArray[np.float64]


def _level_note(res: PartialResult) -> str:
    """What a fit that held a near-level ring's plane level adds to the messages (``model.fitting_level``)."""
    if not res.level:
        return ""
    return (f"; near-level ring: its plane taken as level (the sensor's z axis vertical on average within "
            f"{LEVEL_TILT_STD_DEG:g} deg; a mounting tilt is not seen: set near_level_tilt_deg=0 for a tilted mount): the "
            "level heading is the data's, the tilted one the prior's")


class PartialCalibration:
    """Time series, prior and status of the partial calibration (a mixin: see the module docstring)."""

    EARLY_CLOSE = 3.0
    """Uncalibrated, with an early fit's predicted heading error within this factor of its limit, the
    evaluation cadence is ``early_interval_s`` and half ``refit_every``: the stopping rule is the
    covariance's, checked often while it is about to pass."""
    CLOSE_FALL = 0.05
    """Uncalibrated, a *series* fit refused on a heading figure within ``EARLY_CLOSE`` of its limit is retried after one
    more series point when its figure fell by at least this share since the last such fit, else after twice the
    points the last retry waited for (up to ``CLOSE_MAX_POINTS``): a ring's figure often stalls for seconds (its
    tilt seen moves it too), and retried at every evaluation a ±20° band cost a fit every half second for 15 s."""
    CLOSE_MAX_POINTS = 32
    """... (about 6 s of series points at the default ``partial_period_s``)."""
    EARLY_POINTS = 100
    """An early fit takes the recent samples as at most this many block means (a tumble's first seconds at
    50 Hz: blocks of up to 5 samples, 0.1 s): the same information for white noise, a fifth of the work."""
    REFIT_GROWTH = 0.5
    """A published partial calibration is refitted once the series grew by this share (its heading error
    falls by about a fifth meanwhile; refitting at every quarter cost twice the fits for little)."""
    REFIT_GROWTH_MAX = 4.0
    """A refit of a full series (``partial_samples`` points) refused for predicting no smaller heading error than the
    current calibration doubles the wait for the next, from ``REFIT_GROWTH`` up to this share of the series (20 min at
    the defaults): it sees as much data as the current one did, and on a ring such refits, every 75 s, were refused
    nine times in ten at about 25 ms each (a sensor change is the change detector's, not the refits')."""
    MOUNT_GROWTH = 1.0
    """A decided mounting is estimated again once the series count grew by this share (tens of ms each: not at
    every series fit); an undecided one at every series fit with gyro blocks."""
    GYRO_SPARSE_S = 0.1
    """Magnetometer samples further apart than this (median) may leave a fast turn between them unsampled: a "gyro not
    used" says so before asking about frames (a real 1.9 Hz log of fast turns between rests explained -12 %; a smooth
    ground robot's yaw at 2 Hz is still 99 % explained)."""
    MOST_EXPLAINED = 0.7
    """A gyro not used that still explains this share of the turning in its own frame is not asked about its frame
    first (``_gyro_doubt``): the rest is more likely the field than the rates."""
    GYRO_MIN_BLOCKS = 20
    """Fewest gyro blocks (complete, with a rate on every sample) for the gyro to join a series fit."""
    WATCH_RAW_POINTS = 10
    """Under an azimuth watch whose refused fit is no sensor's ellipsoid (``W``, or its horizontal block, with axes more
    than ``RUNAWAY_AXIS_RATIO`` apart), the new series points' raw x, y are also checked every this many points
    (``_raw_turned``): a real car's 50 s of straight driving gave a fit with gains 2.1 and 0.16, under which its circles
    later covered 18 of 36 sectors while the raw readings covered 36. A sane refused fit is watched as before (a real
    QMC5883L turned by hand: its raw x, y circle while its calibrated azimuths do not, and the fits it would add moved
    its calibrations)."""
    CHORD_GAP, CHORD_SPREAD = 2.5, 10.0
    """An early fit leaves out a block of the recent samples across a stamp step above ``CHORD_GAP`` times the median
    step whose spread is above ``CHORD_SPREAD`` times the median block's (``_early_blocks``)."""
    EARLY_SPAN_S = 10.0
    """An early fit takes the recent samples (``recent_samples``), or the last this many seconds of samples when they
    are more, up to twice as many (``_early_window``): at 100 Hz the 500 recent samples hold 5 s of a tumble, and early
    fits of 5 s stayed in 5-6 of the 12 regions (first good 9-10 s on two tuning seeds, 6-6.5 s at 50 Hz)."""
    EARLY_MAX_ITER = 50
    """Evaluations per solve of an early fit (a start that needs more crawls along a wrong valley)."""
    SPLIT_FACTOR = 5.0
    """Uncalibrated, a series fit whose residual noise is above this many times the smallest a fit of this stream's
    turning readings left (``_turned``) is not of one sensor: the series keeps its newer half (``_split_series``). A
    20 uT hard-iron step on a ground robot 20-40 s into the stream, before its first calibration, left 10-20x and
    blocked calibration for 300 s (until the old sensor's part left the series)."""
    PARTIAL_GROWTH = 0.25
    """A new partial fit is due once the series received this share of its length in new samples ..."""
    PARTIAL_GROWTH_MAX = 1.0
    """... or, after a fit refused on its predicted heading error ``h`` > limit ``L``, the share ``h / L - 1``
    (clipped to [PARTIAL_GROWTH, this]) at which an error falling as 1/samples would pass (it falls as
    1/sqrt(samples) at worst; on a ground robot about as 1/samples, as turns and tilt wobble add up); after
    one refused on the azimuths turned through, ``a`` < ``A``, the share ``A / a - 1`` (turning adds azimuths
    about linearly in time), or sooner: the refused fit's calibration watches the azimuth of each new series
    point, and the fit is due as soon as they fill ``A`` (a robot that drove straight and then turns
    completes its turns in seconds, not in proportion to the time it drove). A fit far from passing is
    not retried after a few more samples (each costs tens of ms). Early fits (the first seconds, on the
    recent samples) refused on their heading figure keep the quarter: a tumble's coverage, and with it the
    heading figure, improves much faster than that."""
    sensor: str
    config: PipelineConfig
    _cal: Calibration | None
    _changed: bool
    _recent_v: Any
    _recent_t: Any
    _early_v: Any  # filled by the calibrator while ``_cal is None or _early_installed``
    _early_t: Any
    _buffer: Any

    def _partial_reset(self) -> None:
        cfg = self.config
        self._series: deque[tuple[float, float, float, float]] = deque(maxlen=cfg.partial_samples)  # mean, spread
        self._series_times: deque[float] = deque(maxlen=cfg.partial_samples)  # when each point was made
        self._series_t = -math.inf
        self._series_acc = [0.0, 0.0, 0.0, 0.0, 0.0]  # sums of x, y, z, x^2 + y^2 + z^2, the count
        self._series_count = 0
        self._series_at_attempt = -1
        self._series_len_at_attempt = 0
        self._partial: PartialResult | None = None  # the last accepted partial fit (its status fields)
        self._partial_note = ""  # why the last partial fit was not published
        self._figures: HeadingFigures | None = None
        self._prior: Calibration | None = None
        self._early_close = False  # the last early fit's predicted heading error was within EARLY_CLOSE x its limit
        self._close_seen: float | None = None  # the last close series fit's figure, uncalibrated (CLOSE_FALL) ...
        self._close_wait = 1  # ... and the series points the next one waits for
        self._early_installed = False  # the current calibration is an early fit's (``_early_open``)
        self._partial_growth = self.PARTIAL_GROWTH  # share of the series to wait for before the next partial fit
        self._refit_wait = self.REFIT_GROWTH  # the next wait after a full series' refit that was no better (doubles)
        self._early_sigma: float | None = None  # the residual noise of the last early fit
        self._sigma_floor = math.inf  # the smallest residual noise a fit of this stream left (``SPLIT_FACTOR``)
        self._partial_sigma: float | None = None  # the residual noise of the last fit on the series ...
        self._partial_start: Calibration | None = None  # ... and its solution, the next one's start
        self._az_watch: tuple[Any, ...] | None = None  # after an azimuth refusal: its W rows x, y, offset, ring centre
        self._az_seen: set[int] = set()  # ... and the sectors the series visited under it
        self._az_raw: list[tuple[float, float]] | None = None  # ... and, under no sensor's ellipsoid, the new points' raw x, y
        self._gyro_buf: deque[tuple[float, ...]] = deque(maxlen=cfg.gyro_samples)  # t, x, y, z, rate (nan: none)
        self._gyro_share = math.nan  # the last series fit's share of the field's turning the gyro accounted for
        self._gyro_short = ""  # ... or: it had rates, but too few complete blocks of them (why: ``_short_why``)
        self._gyro_frame = ""  # ... or: the rates re-ordered or with an axis negated explained it far better
        self._gyro_frame_shares = (math.nan, math.nan)  # ... and how much: that frame, the rates' own (no bias fitted)
        self._mounting: Mounting | None = None  # the last series fit's mounting against the IMU (model.mounting)
        self._mount_applied: Array | None = None  # calibrate_into_imu_frame: the rotation q the readings are turned by ...
        self._turn_axes = (0, 1.0, 1, 1.0, 2, 1.0)  # ... as (axis, sign) of each turned axis: v'_i = sign v[axis]
        self._mount_at = 0  # the series count at the last mounting estimate
        self._mount_rows = 0  # the gyro rows at the last mounting estimate (a full fit's: ``_full_mount_due``)

    def _cadence(self) -> tuple[int, float]:
        """(samples, seconds) between evaluations, never fewer than ``refit_every // 2`` samples (the
        calibrator's sample path tests that bound before calling this): ``recheck_interval_s`` while calibrated by the full
        path, else ``refit_min_interval_s`` (also under a MAP calibration, so the full path takes over as
        soon as it would have), shortened while an early fit is close (``EARLY_CLOSE``). One microsecond
        less, so stamps that went through sec/nanosec (the node) give the cadence of float stamps (replay)."""
        cfg = self.config
        if self._cal is not None and not self._changed and self._partial is None:
            every, interval = cfg.refit_every, cfg.recheck_interval_s
        elif self._early_close and cfg.early_fit and cfg.partial_fit and self._early_open():  # the call last (per sample)
            every, interval = max(1, cfg.refit_every // 2), min(cfg.refit_min_interval_s, cfg.early_interval_s)
        else:
            every, interval = cfg.refit_every, cfg.refit_min_interval_s
        interval -= 1e-6
        return every, interval if interval > 0.0 else 0.0  # max(0.0, interval) without the call (once per sample)

    def _partial_noise(self, job: dict[str, Any]) -> None:
        """Remember the noise of a series fit's residuals and its solution for the next series fit: a solution
        published, or refused only for its heading error (not for its guard rails, nor for the azimuths seen: a fit of 10 s
        at rest and 2 s of a ring was refused on them, and from its solution, as the only start, the ring's later fits
        stayed in a wrong valley for minutes; ``tests/stream/test_rest_at_start.py``)."""
        res: PartialResult | None = job.get("result")
        if res is not None and math.isfinite(res.sigma) and res.sigma > 0 and self._turned(job.get("series")):
            self._sigma_floor = min(self._sigma_floor, res.sigma)
        if res is not None and job.get("early") and math.isfinite(res.sigma) and res.sigma > 0:
            self._early_sigma = res.sigma
        if res is not None and not job.get("early") and res.calibration is not None:
            self._gyro_share = res.gyro_explained
            self._gyro_frame, self._gyro_frame_shares = res.gyro_frame, res.gyro_frame_shares
            self._gyro_short = job.get("gyro_short") or ""
        if res is not None and not job.get("early") and job.get("prior") is self._prior:
            sound = res.calibration is not None and (not res.reason or res.over_limit is not None)
            self._partial_start = res.calibration if sound else None
            if math.isfinite(res.sigma) and res.sigma > 0:
                self._partial_sigma = res.sigma
        if res is not None and not job.get("early") and res.calibration is not None:
            self._mount_note(job.get("mounting"))  # last: a new turn of the readings drops the start just kept

    def _partial_close(self, job: dict[str, Any]) -> None:
        self._partial_noise(job)
        self._az_watch = None
        res: PartialResult | None = job.get("result")
        if res is not None and not job.get("early") and self._cal is None and self._split_series(res):
            return
        cfg = self.config
        limit = max(cfg.early_heading_p95_deg, cfg.max_heading_p95_deg)
        self._early_close = res is not None and res.heading_seen_deg <= self.EARLY_CLOSE * limit
        if res is not None and res.over_limit is None and res.heading_seen_deg <= limit and not job.get("early"):
            self._early_close = False  # refused on its guard rails: more data, not the early cadence (it had retried a
            # series fit at every evaluation for minutes, uncalibrated)
        self._close_backoff(res if (self._early_close and res is not None and res.over_limit and not job.get("early")
                                    and self._early_open()) else None)
        grow = self.PARTIAL_GROWTH  # also for an early fit's heading refusal: a tumble's figure falls fast
        if res is not None and res.over_limit and not job.get("early") and math.isfinite(res.heading_seen_deg):
            grow = res.heading_seen_deg / res.over_limit - 1.0
        elif res is not None and not res.over_limit and 0.0 < res.azimuth < cfg.partial_min_azimuth:
            grow = cfg.partial_min_azimuth / res.azimuth - 1.0  # turning adds azimuths about linearly in time
            if not job.get("early") and job.get("mount_applied") is self._mount_applied:  # (an early fit's quarter
                self._watch_azimuths(res.calibration, job.get("series"))  # comes in seconds; a new turn: other axes)
        self._partial_growth = min(max(grow, self.PARTIAL_GROWTH), self.PARTIAL_GROWTH_MAX)
        if res is not None and res.not_better and len(job.get("series", ())) >= (self._series.maxlen or 0):
            # a full series: a refit sees as much as the current calibration's did, so it is tried ever more rarely
            self._refit_wait = min(2.0 * self._refit_wait, self.REFIT_GROWTH_MAX)
            self._partial_growth = self._refit_wait
        # the series points that came while the fit ran in steps (evaluation.py), watched as if from its snapshot
        since = min(self._series_count - job.get("series_count", self._series_count), len(self._series))
        for px, py, pz, _ in itertools.islice(self._series, len(self._series) - since, None):
            if self._az_watch is None:
                break
            self._watch_point(px, py, pz)

    @staticmethod
    def _turned(series: Array | None) -> bool:
        """The fit's points turned (``STATIC_SPREAD``): only such a fit's residual noise is a floor for ``SPLIT_FACTOR``;
        an early fit of a still start sees the quantisation alone (a real IMU at rest, 0.13 counts, then 0.79 when it
        turned: the series' older half, two of its three turns, dropped as of another sensor)."""
        return series is not None and len(series) > 2 and relative_spread(np.asarray(series)) >= STATIC_SPREAD

    def _close_backoff(self, res: PartialResult | None) -> None:
        """After a close series fit refused on its heading figure (``res``; None after any other fit): the series
        points the next one waits for (``CLOSE_FALL``)."""
        prev, self._close_seen = self._close_seen, None if res is None else res.heading_seen_deg
        if res is None or prev is None or res.heading_seen_deg <= (1.0 - self.CLOSE_FALL) * prev:
            self._close_wait = 1
        else:
            self._close_wait = min(2 * self._close_wait, self.CLOSE_MAX_POINTS)

    def _watch_azimuths(self, cal: Calibration | None, series: Array | None) -> None:
        """After a fit refused on the azimuths turned through: watch the new series points' azimuths under
        its calibration (``PARTIAL_GROWTH_MAX``)."""
        if cal is None or series is None or not len(series):
            return
        w, b = np.asarray(cal.matrix, dtype=np.float64), np.asarray(cal.offset, dtype=np.float64)
        centre = ring_centre(cal.apply(series))  # the azimuths about the ring's centre, as the fit judged them
        self._az_seen = set(azimuth_sectors(cal, series, centre).tolist())
        self._az_watch = (*w[0].tolist(), *w[1].tolist(), *b.tolist(), *centre)
        axes = [np.linalg.svd(m, compute_uv=False) for m in (w, w[:2, :2])]
        self._az_raw = [] if any(not sv[-1] * RUNAWAY_AXIS_RATIO >= sv[0] for sv in axes) else None

    def _watch_point(self, x: float, y: float, z: float) -> None:
        """One new series point under the azimuth watch: once the sectors seen reach ``partial_min_azimuth``,
        the next partial fit is due at once."""
        assert self._az_watch is not None
        a, b, c, d, e, f, bx, by, bz, cx, cy = self._az_watch
        dx, dy, dz = x - bx, y - by, z - bz
        self._az_seen.add(azimuth_sector(a * dx + b * dy + c * dz - cx, d * dx + e * dy + f * dz - cy))
        need = self.config.partial_min_azimuth * AZIMUTH_SECTORS
        raw = self._az_raw
        if raw is not None:
            raw.append((x, y))
        if len(self._az_seen) >= need or (raw is not None and len(raw) % self.WATCH_RAW_POINTS == 0
                                          and _raw_turned(raw, need)):
            self._az_watch = None
            self._partial_growth = 0.0

    def _series_push(self, t: float, x: float, y: float, z: float) -> None:
        """One more sample: the series receives the mean of the samples of each ``partial_period_s``
        (averaging, not picking every k-th, divides the white noise by sqrt(k)) and their spread, the mean
        squared distance from that mean (the fit corrects the mean's shrinkage on a turn by it:
        ``model.fitting_geometric``). From raw sums: even a still sensor's spread, its white noise (about
        ``1e-5`` of the squared norm), is far above the ``1e-16`` of it that float64 loses."""
        acc = self._series_acc
        acc[0] += x
        acc[1] += y
        acc[2] += z
        acc[3] += x * x + y * y + z * z
        acc[4] += 1.0
        if t - self._series_t < self.config.partial_period_s - 1e-6:  # 1 us: stamps through sec/nanosec
            return
        self._series_t = t
        k = acc[4]
        if self._mount_applied is not None:  # sums of the raw readings; their mean turned (the spread is the same)
            acc[0], acc[1], acc[2] = self._turn(acc[0], acc[1], acc[2])
        px, py, pz = acc[0] / k, acc[1] / k, acc[2] / k
        self._series.append((px, py, pz, max(acc[3] / k - px * px - py * py - pz * pz, 0.0)))
        self._series_times.append(t)
        self._series_acc = [0.0, 0.0, 0.0, 0.0, 0.0]
        self._series_count += 1
        if self._az_watch is not None:
            self._watch_point(px, py, pz)

    def _gyro_push(self, t: float, x: float, y: float, z: float, g: tuple[float, float, float] | None) -> None:
        """One more magnetometer sample for the gyro-aided fit: with its rate, or as a gap once a rate was seen."""
        if self._mount_applied is not None:
            x, y, z = self._turn(x, y, z)
        if g is not None:
            self._gyro_buf.append((t, x, y, z, g[0], g[1], g[2]))
        elif self._gyro_buf:
            self._gyro_buf.append((t, x, y, z, math.nan, math.nan, math.nan))

    def _gyro_blocks(self, rows: list[tuple[float, ...]], cfg: PipelineConfig) -> Any:
        """The gyro blocks of ``rows`` (``_gyro_buf``'s), ``cfg.gyro_block_s`` long; None when too few (off-lock,
        so the job's options, not the calibrator's)."""
        if len(rows) < self.GYRO_MIN_BLOCKS * 2:  # a block holds two samples at least
            return None
        # the rows' floats read in one pass (np.array of 15 000 tuples: 1.5x the time)
        arr = np.fromiter(itertools.chain.from_iterable(rows), np.float64, count=7 * len(rows)).reshape(-1, 7)
        step = float(np.median(np.diff(arr[:, 0])))
        k = max(2, round(cfg.gyro_block_s / step)) if step > 0 else 2
        blocks = gyro_blocks(arr[:, 0], arr[:, 1:4], arr[:, 4:7], k)
        return blocks if len(blocks) >= self.GYRO_MIN_BLOCKS else None

    def _short_why(self, rows: list[tuple[float, ...]], cfg: PipelineConfig) -> str:
        """Why ``rows`` made too few gyro blocks: samples without a rate (the Imu messages not paired), else a span too
        short, else steps in the stamps that broke the blocks (a CSV with a rate on every row was told to check its
        Imu messages' frame_id)."""
        missing = sum(1 for r in rows if r[4] != r[4])  # NaN: no rate
        if missing:
            return (f"{missing} of the last {len(rows)} samples without one: an Imu message within 20 ms of each "
                    "MagneticField one, same frame_id?")
        span = rows[-1][0] - rows[0][0]
        if span < self.GYRO_MIN_BLOCKS * cfg.gyro_block_s:
            return f"rates over {span:.1f} s so far"
        return "the stamps step unevenly: a block with a step far above the median is left out"

    def _series_points(self) -> tuple[Array, Array]:
        """The series: block means (N, 3) and their spreads (N,)."""
        arr = np.array(self._series, dtype=np.float64).reshape(-1, 4)
        return arr[:, :3], arr[:, 3]

    def _partial_wanted(self) -> bool:
        """The full validator refused: is a partial fit worth a try now (module docstring)?"""
        cfg = self.config
        early = cfg.early_fit and self._early_open() and len(self._recent_v) >= cfg.min_points
        if not cfg.partial_fit or (len(self._series) < cfg.min_points and not early):
            return False
        if not (self._cal is None or self._changed or self._partial is not None):
            return False
        grown = self._series_count - self._series_at_attempt
        if early and self._early_close:  # about to pass: the cadence (early_interval_s) decides, not the growth
            return self._series_at_attempt < 0 or grown >= self._close_wait  # (1 but on a stalled ring: CLOSE_FALL)
        return self._series_at_attempt < 0 or grown >= max(1, self._partial_growth * self._series_len_at_attempt)

    def _early_open(self) -> bool:
        """May an early fit run: uncalibrated, or the current calibration an early fit's whose ±30° figure is above
        ``early_heading_p95_deg`` (a ring's first seconds, published on the figure at the tilt seen: the tumble that
        follows would otherwise wait for the full path)?"""
        if self._cal is None:
            return True
        p = self._partial
        if not (self._early_installed and p is not None and not self._changed):
            return False
        if len(self._series) >= self.config.min_points:
            return False  # the series fits take over (a ring's early fit: its ±30° figure stays the prior's)
        return not (p.figures is not None and p.figures.tilt30_deg <= self.config.early_heading_p95_deg)

    def _early_window(self) -> tuple[Array, list[tuple[float, float, float]]]:
        """The samples an early fit takes (``EARLY_SPAN_S``): their stamps and readings."""
        t = np.fromiter(self._early_t, dtype=np.float64, count=len(self._early_t))
        n = len(self._recent_v)
        if len(t) > n and len(t) == len(self._early_v):
            n = max(n, len(t) - int(np.searchsorted(t, t[-1] - self.EARLY_SPAN_S + 1e-3)))  # (1 ms: 500 at 50 Hz)
        n = min(n, len(t), len(self._early_v))
        return t[len(t) - n:], list(itertools.islice(self._early_v, len(self._early_v) - n, None))

    def _early_blocks(self) -> tuple[Array, Array]:
        """The recent samples as block means of ``EARLY_POINTS`` at most, without a chord: a block across a gap in the
        stamps (samples dropped between: saturated, out of range) whose spread is above ``CHORD_SPREAD`` times the
        median block's. Its mean lies well inside the sphere, which its spread corrects only for a round one (a
        quarter of a tumble's samples dropped as saturated gave an early fit 1.9 deg off at 30 deg for its 1.0 deg
        figure). Both conditions: a still sensor's blocks spread as much as all its samples, and a real recording's
        stamps may come in bursts."""
        t, v = self._early_window()
        k = -(-len(v) // self.EARLY_POINTS)
        series, spread = block_means(v, k)
        if k < 2 or len(spread) < 3 or len(t) != len(v):
            return series, spread
        dt = np.diff(t[len(t) % k:].reshape(-1, k), axis=1)
        chord = (dt.max(axis=1) > self.CHORD_GAP * float(np.median(np.diff(t)))) & (
            spread > self.CHORD_SPREAD * float(np.median(spread)))
        return (series, spread) if not chord.any() else (series[~chord], spread[~chord])

    def _partial_job(self, job: dict[str, Any]) -> dict[str, Any]:
        """Turn a fit job into a partial one (the series and the prior join the snapshot)."""
        self._series_at_attempt = self._series_count
        self._series_len_at_attempt = len(self._series)
        cur = self._partial if (self._cal is not None and not self._changed) else None
        series, spread = self._series_points()
        early = len(series) < self.config.min_points
        if early:  # the recent samples until the series is long enough, as block means of EARLY_POINTS at most
            series, spread = self._early_blocks()
            series = series if self._mount_applied is None else series @ self._mount_applied.T
        rows = [] if early or not self._gyro_buf else list(self._gyro_buf)  # a copy of references: cheap
        return {**job, "partial": True, "series": series, "series_count": self._series_count, "spread": spread,
                "prior": self._prior, "early": early,
                "gyro_rows": rows, "gyro_seen": bool(self._gyro_buf), "mount_applied": self._mount_applied,
                "mount_prev": None if self._mount_due() else self._mounting,
                "sigma": self._early_sigma if early else self._partial_sigma,
                "start": None if (early or self._changed) else self._partial_start,  # a sensor change: every start
                "current_heading": None if cur is None else cur.heading_seen_deg,
                "current_tilt": None if cur is None else cur.tilt_seen_deg}

    def _partial_steps(self, job: dict[str, Any]) -> Steps[tuple[Calibration | None, str]]:
        """The partial fit of a job and its verdict, in steps (``observable.partial_fit_steps``; the mounting one more)."""
        gyro = self._gyro_blocks(job["gyro_rows"], job["config"]) if job["gyro_rows"] else None
        if gyro is not None:
            yield
        job["gyro_short"] = self._short_why(job["gyro_rows"], job["config"]) if job["gyro_rows"] and gyro is None else ""
        q = job.get("mount_applied")  # calibrate_into_imu_frame: the series and rows are turned by q, so is the rest
        prior, current, recent = job["prior"], job["current"], job["recent"]
        if q is not None:
            prior = None if prior is None else turned(prior, q)
            current = None if current is None else turned(current, q)
            recent = np.asarray(recent, dtype=np.float64) @ q.T
        res = yield from partial_fit_steps(
            job["series"], prior, job["config"], spread=job["spread"], recent=recent, gyro=gyro, current=current,
            stamp=job["t"], sensor=self.sensor, current_heading=job["current_heading"],
            current_tilt=job.get("current_tilt"), sigma=job["sigma"],
            max_iter=self.EARLY_MAX_ITER if job["early"] else job["config"].max_iter, start=job["start"],
            sigma_tolerance=math.inf if job["early"] else SIGMA_REUSE_TOLERANCE,
            level_ok=gyro is not None or not job["gyro_seen"], early=job["early"])
        job["result"] = res
        found, prev = None, job.get("mount_prev")
        if prev is not None:  # decided, and not due again: as it was, on the readings as turned now
            found = prev if q is None else prev.after_turn(q.T)
        elif gyro is not None and res.calibration is not None and not job["early"]:
            yield
            found = yield from _mounting(gyro, res.calibration, job["config"])
            job["mounting"] = found if q is None else found.after_turn(q)
        if res.reason or res.calibration is None:
            return None, res.reason or "partial fit failed"
        return _published(res.calibration, found, q, job["config"]), ""

    def _turn(self, x: float, y: float, z: float) -> tuple[float, float, float]:
        """A reading turned by ``_mount_applied`` (an axis-aligned rotation: a signed permutation)."""
        v = (x, y, z)
        i, si, j, sj, k, sk = self._turn_axes
        return si * v[i], sj * v[j], sk * v[k]

    def _mount_due(self) -> bool:
        """Is the mounting to be estimated again (``MOUNT_GROWTH``)?"""
        m = self._mounting
        return m is None or m.rotation is None or self._series_count >= (1.0 + self.MOUNT_GROWTH) * self._mount_at

    def _full_mount_due(self) -> bool:
        """Is a full fit to estimate the mounting (gyro rows seen and grown since the last estimate: by a quarter while
        undecided, doubled once decided)? A full fit runs at every evaluation; an estimate costs tens of ms, and one
        that stays undecided (rates of another body, "none fits") must not cost them at every evaluation."""
        m, n = self._mounting, len(self._gyro_buf)
        growth = 0.25 if m is None or m.rotation is None else self.MOUNT_GROWTH
        return n > 0 and (m is None or n >= (1.0 + growth) * self._mount_rows)

    def _mount_note(self, mount: Mounting | None) -> None:
        """Keep a series fit's mounting; with ``calibrate_into_imu_frame``, a decided rotation turns the readings of the
        next series fits (``_turn_readings``)."""
        if mount is None:
            return
        self._mounting, self._mount_at, self._mount_rows = mount, self._series_count, len(self._gyro_buf)
        q = self._mount_applied
        if self.config.calibrate_into_imu_frame and mount.rotation is not None and (
                q is None or not np.allclose(mount.rotation, q)):
            self._turn_readings(mount.rotation)

    def _split_series(self, res: PartialResult) -> bool:
        """A refused series fit, uncalibrated, whose residual noise is over ``SPLIT_FACTOR`` times the stream's smallest:
        keep the series' newer half (and the gyro rows and buffered samples since: the full path's fits of a mixed
        buffer failed their guard rails too), a fit due at once; False (nothing done) otherwise."""
        n, cfg = len(self._series), self.config
        floor = self._sigma_floor  # (this fit's own sigma is in it: the test is against the fits before it too)
        if not (self.sensor == "mag" and math.isfinite(res.sigma) and res.sigma > self.SPLIT_FACTOR * floor
                and n >= 2 * cfg.min_points):
            return False  # (an accelerometer's gate means: a few poses fit exactly, more show the model's error)
        cut = self._series_times[n - n // 2] - cfg.partial_period_s  # the kept points' samples came after this
        self._drop_before_change(cut)
        self._buffer.discard_before(cut)
        self._partial_note = (f"{self._partial_note}; its residual noise {res.sigma / floor:.0f}x the smallest a fit of "
                              "this stream left: not one sensor (a hard-iron step?), the series' older half dropped")
        return True

    def _drop_before_change(self, onset: float) -> None:
        """A declared sensor change at ``onset``: the series points and gyro rows from before it go, and a series fit
        is due once the series is long enough again. Kept, the series fit after a 20 uT step on a ground robot mixed
        220 s of the old sensor with 70 s of the new, failed, and was not retried for minutes; the gyro rows, read
        through the new calibration, turn the field wrongly (the built-in example's mounting was "not determined:
        the best explains 62 %")."""
        while self._gyro_buf and self._gyro_buf[0][0] < onset:
            self._gyro_buf.popleft()
        start = onset + self.config.partial_period_s  # a point made then holds samples since the onset only
        for _ in range(sum(1 for s in self._series_times if s < start)):  # the two are appended together
            self._series.popleft()
            self._series_times.popleft()
        self._series_at_attempt, self._series_len_at_attempt = -1, 0
        self._partial_growth, self._partial_start, self._az_watch = self.PARTIAL_GROWTH, None, None
        self._close_seen, self._close_wait, self._refit_wait = None, 1, self.REFIT_GROWTH

    def _turn_readings(self, q: Array) -> None:
        """From now on the series and the gyro rows hold readings turned by ``q`` into the IMU's axes (their rates are
        the IMU's already): the ones kept are turned too; the last solution, in the old axes, is no start."""
        dq = q if self._mount_applied is None else q @ self._mount_applied.T
        self._mount_applied = q
        cols = [int(np.argmax(np.abs(row))) for row in q]
        self._turn_axes = (cols[0], float(q[0, cols[0]]), cols[1], float(q[1, cols[1]]), cols[2], float(q[2, cols[2]]))
        if self._series:
            arr = np.array(self._series, dtype=np.float64)
            arr[:, :3] = arr[:, :3] @ dq.T
            self._series = deque(map(tuple, arr.tolist()), maxlen=self._series.maxlen)
        if self._gyro_buf:
            arr = np.array(self._gyro_buf, dtype=np.float64)
            arr[:, 1:4] = arr[:, 1:4] @ dq.T
            self._gyro_buf = deque(map(tuple, arr.tolist()), maxlen=self._gyro_buf.maxlen)
        self._partial_start, self._az_watch = None, None

    def _full_figures(self, job: dict[str, Any], cal: Calibration) -> None:
        """A full magnetometer fit: its heading figures and its symmetric covariance (the next prior), off-lock (of the
        fit in the magnetometer's frame when ``_full_mounting`` turned the one to publish)."""
        if self.sensor == "mag":
            job["figures"] = heading_figures(job.get("mag_frame_cal", cal), job["points"], job["config"])

    def _full_mounting(self, job: dict[str, Any], cal: Calibration) -> Steps[Calibration]:
        """A full magnetometer fit with the job's gyro rows (``gyro_rows``, as the partial job's): the mounting under it
        (``job["mounting"]``) and, with ``calibrate_into_imu_frame`` and a decided rotation, the calibration to publish,
        in the IMU's frame (the fit itself kept as ``job["mag_frame_cal"]``), off-lock."""
        rows, cfg = job.get("gyro_rows"), job["config"]
        gyro = self._gyro_blocks(rows, cfg) if self.sensor == "mag" and rows else None
        if gyro is None:  # no estimate this time (throttled, ``_full_mount_due``): a decided one still turns it
            kept: Mounting | None = job.get("mounting_kept")
            if not cfg.calibrate_into_imu_frame or kept is None or kept.rotation is None:
                return cal
            job["mag_frame_cal"] = cal
            return into_imu_frame(cal, kept)
        q = job.get("mount_applied")  # the rows' readings are turned by q: so is the calibration judged on them
        found = yield from _mounting(gyro, cal if q is None else turned(cal, q), cfg)
        job["mounting"] = found if q is None else found.after_turn(q)
        mount: Mounting = job["mounting"]
        if not cfg.calibrate_into_imu_frame or mount.rotation is None:
            return cal
        job["mag_frame_cal"] = cal
        return into_imu_frame(cal, mount)

    def _partial_installed(self, job: dict[str, Any], cal: Calibration) -> str:
        """Bookkeeping after ``job``'s calibration was installed; the words the CALIBRATED event adds."""
        if job.get("partial"):
            self._partial_noise(job)
            res: PartialResult = job["result"]
            self._partial, self._partial_note = res, ""
            self._early_installed = bool(job.get("early"))
            self._early_close = self._early_installed  # refined at the early cadence while it is open (_early_open)
            self._partial_growth = self._refit_wait = self.REFIT_GROWTH  # a refit once the series grew by this share
            self._figures = res.figures
            return (f"; partial: updated {','.join(res.updated) or 'none'}, from the {res.prior_kind} prior "
                    f"{','.join(res.from_prior) or 'none'}; heading p95 {format_bound(res.heading_seen_deg)} at the tilt seen "
                    f"({res.tilt_seen_deg:.1f} deg){_level_note(res)}")
        self._partial, self._partial_note, self._early_installed = None, "", False
        if job.get("mounting") is not None:
            self._mount_note(job["mounting"])
        got = job.get("figures")
        if got is not None:
            figs, cov_cal = got
            self._figures = figs
            self._prior = cov_cal
        else:
            self._figures = None
        return ""

    def _set_prior(self, cal: Calibration | None) -> None:
        """A loaded calibration becomes the prior when it carries a covariance over the symmetric parameters."""
        ok = cal is not None and cal.covariance is not None and tuple(cal.parameter_names) == SYM_NAMES
        self._prior = cal if ok else None

    def _partial_message(self) -> str:
        """What the status message adds about the partial calibration and the heading figures."""
        out = ""
        p = self._partial
        if p is not None and self._cal is not None:
            out += f"; partial: updated {','.join(p.updated)}, from prior {','.join(p.from_prior) or 'none'}{_level_note(p)}"
        f = self._figures
        if f is not None and self._cal is not None:
            out += (f"; heading p95 {format_bound(f.level_deg)} level, {format_bound(f.tilt30_deg)} at 30 deg tilt "
                    f"(predicted 95 % bound; typical {format_bound(f.level_typical_deg)} / "
                    f"{format_bound(f.tilt30_typical_deg)}; {f.inclination_deg:.3g} deg field inclination)")
            out += f" ({f.vertical_note})" if f.vertical_note else ""
        g = self._gyro_share if self._gyro_applies() else math.nan
        mount = self._mounting  # the last estimate, of a series fit or a full one (``_full_mounting``)
        if math.isfinite(g) and self._gyro_frame:
            named, own = self._gyro_frame_shares  # both without a bias or scale fitted (the fit's share, g, with them)
            out += (f"; gyro not used: the rate accounts for {turning_share(own, 0)} as it comes, "
                    f"{100 * named:.0f} % {frame_advice(self._gyro_frame)}")
        elif math.isfinite(g):  # 89.7 %, not "90 % < 90 %"; "none" for a negative share (turning_share)
            out += (f"; gyro-aided: the rate accounts for {turning_share(g)}" if g >= MIN_EXPLAINED
                    else f"; gyro not used: the rate accounts for {turning_share(g)}"
                         f"{f' < {100 * MIN_EXPLAINED:.0f} %' if g >= 0.0 else ''} ({self._gyro_doubt(g)})")
        elif self._gyro_short and self._gyro_applies():
            out += (f"; gyro not used: fewer than {self.GYRO_MIN_BLOCKS} blocks of {self.config.gyro_block_s:g} s with a "
                    f"rate on every sample ({self._gyro_short})")
        if mount is not None and not (math.isfinite(g) and self._gyro_frame in UNIT_NAMES):  # a rate's unit first
            note = mount.message(into_imu=self._mount_applied is not None)
            out += f"; {note}" if note else ""
        if self.config.calibrate_into_imu_frame and self._mount_applied is None and self._cal is not None:
            out += ("; in the magnetometer's own frame until its mounting against the IMU is decided "
                    "(mag.calibrate_into_imu_frame)")
        if self._partial_note:
            out += f"; {self._partial_note}"
        return out

    def _gyro_doubt(self, share: float) -> str:
        """Why a gyro may not explain the turning (``share`` of it): samples too far apart to integrate its rate
        (``GYRO_SPARSE_S``), else the frames or the timing; with most of it explained in its own frame
        (``MOST_EXPLAINED``), a field that changes along the path first (a ring with 3 uT of wander: 89-90 %)."""
        t = np.fromiter((r[0] for r in self._gyro_buf), dtype=np.float64, count=len(self._gyro_buf))
        step = float(np.median(np.diff(t))) if len(t) > 2 else 0.0
        frames = "are the IMU and magnetometer in one frame, in step?"
        if share >= self.MOST_EXPLAINED:
            frames = ("most of it in the rates' own frame: a field that changes along the path (iron near the route), "
                      "or the IMU and magnetometer out of step?")
        if step > self.GYRO_SPARSE_S:
            return f"samples {step:.2g} s apart: a rate integrated over that long misses a fast turn; else {frames}"
        return frames

    def _gyro_applies(self) -> bool:
        """The gyro's share speaks of the calibration in use (a partial one) or of the fits refused while there
        is none; a full calibration did without it."""
        return self._cal is None or self._partial is not None

    def _partial_fields(self) -> dict[str, Any]:
        """The Status fields of the partial calibration and the heading figures."""
        p, f, cal = self._partial, self._figures, self._cal
        return {
            "partial": p is not None and cal is not None and bool(p.from_prior),
            "updated_parameters": tuple(p.updated) if (p is not None and cal is not None) else (),
            "prior_parameters": tuple(p.from_prior) if (p is not None and cal is not None) else (),
            "heading_p95_level_deg": None if (f is None or cal is None or not math.isfinite(f.level_deg)) else f.level_deg,
            "heading_p95_tilt30_deg": None if (f is None or cal is None or not math.isfinite(f.tilt30_deg)) else f.tilt30_deg,
            "heading_typical_level_deg": None if (f is None or cal is None or not math.isfinite(f.level_typical_deg))
            else f.level_typical_deg,
            "heading_typical_tilt30_deg": None if (f is None or cal is None or not math.isfinite(f.tilt30_typical_deg))
            else f.tilt30_typical_deg,
            "heading_inclination_deg": None if (f is None or cal is None) else f.inclination_deg,
            "tilt_seen_deg": None if (p is None or cal is None) else p.tilt_seen_deg,
            "gyro_explained": self._gyro_share if (math.isfinite(self._gyro_share) and self._gyro_applies()) else None,
            **_mount_fields(self._mounting),
        }


def _mounting(blocks: GyroBlocks, cal: Calibration, cfg: PipelineConfig) -> Steps[Mounting]:
    """The mounting under a series fit's calibration (its covariance when over the symmetric parameters), in steps."""
    cov = cal.covariance if tuple(cal.parameter_names) == SYM_NAMES else None
    return find_mounting_steps(blocks, cal.offset, cal.matrix, cov, gyro_scale_std=cfg.gyro_scale_std)


def _published(cal: Calibration, found: Mounting | None, q: Array | None, cfg: PipelineConfig) -> Calibration:
    """The calibration to publish from a series fit's ``cal`` on readings turned by ``q`` (None: as they come): with
    ``calibrate_into_imu_frame``, its output in the IMU's frame, ``R W' q`` (``R`` the rotation ``found`` on the turned
    readings, the identity while undecided; ``into_imu_frame``), the offset ``q^T b'`` of the raw readings."""
    if not cfg.calibrate_into_imu_frame:
        return cal
    if found is not None and found.rotation is not None:
        cal = into_imu_frame(cal, found)
    if q is None:
        return cal
    return cal.replace(offset=q.T @ np.asarray(cal.offset, dtype=np.float64),
                       matrix=np.asarray(cal.matrix, dtype=np.float64) @ q, covariance=None, parameter_names=())


def _mount_fields(m: Mounting | None) -> dict[str, Any]:
    """The Status fields of the mounting (``model.mounting``)."""
    if m is None or m.rotation is None:
        return {"mounting": "" if m is None else ("mirrored: " + m.mirror if m.mirror else "not determined")}
    return {"mounting": m.name, "mounting_misalignment_deg": m.misalignment_deg,
            "mounting_misalignment_sd_deg": m.misalignment_sd_deg}


RAW_RING_SPREAD = 0.3
"""``_raw_turned``: the points' distances from their circle's centre within this share of their median (a ring traced,
not a blob: a still sensor's noise about a centre near it spreads by about half its median distance)."""


def _raw_turned(xy: list[tuple[float, float]], need: float) -> bool:
    """The raw horizontal readings ``xy`` went round a circle (``circle_centre``) through ``need`` of the
    ``AZIMUTH_SECTORS`` azimuth sectors, tracing it (``RAW_RING_SPREAD``): a watched ring's retry is due whatever
    the refused fit's calibration made of it."""
    pts = np.asarray(xy, dtype=np.float64)
    cx, cy = circle_centre(pts)
    dx, dy = pts[:, 0] - cx, pts[:, 1] - cy
    r = np.hypot(dx, dy)
    med = float(np.median(r))
    if not (med > 0 and float(np.median(np.abs(r - med))) <= RAW_RING_SPREAD * med):
        return False
    sectors = np.floor((np.arctan2(dy, dx) + math.pi) / (2.0 * math.pi) * AZIMUTH_SECTORS).astype(int) % AZIMUTH_SECTORS
    return len(np.unique(sectors)) >= need
