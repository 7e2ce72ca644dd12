"""Change detection of the streaming calibrator: has the sensor changed, or was the calibration only poor?

While calibrated, each sample's relative norm error under the calibration is kept for the last
``recent_samples``. When the median over the last ``change_window`` samples has stayed above
``change_threshold`` for ``change_min_duration_s``, a change is suspected (a hard-iron jump, a drift).
It is declared only against the no-change hypothesis: one calibration refitted on the buffer and the
whole recent window (``_no_change``); when that explains both within the tolerance, it is installed
instead. When the buffered samples from before the onset in the same directions (a rest pose returned to) were
missed by the calibration as much (``_missed_before``), the calibration was poor there, not the sensor
changed: no change is declared, the refit tolerance is half ``change_threshold`` (a first calibration from
part of the sphere that missed the start pose by 6 %, where one refit on everything leaves 0.65 %), and
without a passing refit the calibration is kept and a refit is due. A declared change rebuilds the buffer from
the samples since its onset (and the partial fit's series and gyro rows lose what came before it: ``partial.py``), and
the next validated fit describes the new sensor. A change can pass: a bad
stretch of samples (a sensor reset that reads a few counts, a magnet held near it for a while) is a change
while it lasts, and afterwards the old calibration explains the samples again. When, before a new calibration,
the median over the last ``change_window`` samples under the old calibration has stayed within half ``change_threshold`` (a margin
against a change that hovers at the threshold) for ``change_min_duration_s``, and at least ``RETURN_MIN_SAMPLES``
of those samples are ones the change would have missed (an offset step fitted to the samples since the onset
under the old matrix and norm: where a step leaves the norm unchanged, the norm cannot tell), the change is
withdrawn (``_check_return``): the old calibration is current again, the buffer of before the change (its samples
before the onset that it explains: ``_buffer_before``) comes back with the samples since that it explains. Without
this the buffer kept the bad stretch and every refit failed its residual guard rail: the calibrator stayed
"collecting after a sensor change" for good.

A change can also undo an earlier one: a payload or magnet taken off again brings back the sensor of before. Each
declared change keeps the calibration it ended, with its buffer and heading figures (the last ``KNOWN_MAX``); after
a change, before a new calibration, ``_check_known`` looks among them, other than the current one, for one that
explains the samples since the onset (median relative residual within twice its fit residual, at most half
``change_threshold``) where their directions pin the offset (an offset step fitted from it has a standard deviation
of at most ``max_parameter_std`` and stays within three of them): it is reinstated at once, with its buffer and the
samples since that it explains, instead of recollecting (a ground robot took a minute). Not in the IMU's frame
(``calibrate_into_imu_frame`` turns the readings: a kept buffer would be in other axes).

A drift is a change too slow for the detector: a hard iron that moves by 0.05 field norms a minute keeps
the median residual below ``change_threshold`` when the rechecks refit every ``recheck_interval_s``, but
the buffer keeps up to ``per_bin`` samples of each direction for minutes, so each refit described the mean
offset of minutes of data (several per cent behind) and passed every guard rail. On a recheck, a
calibration whose residual grew beyond ``STALE_FACTOR`` times its fit residual and ``STALE_MIN``, on the
recent samples and on the samples since its fit in the directions it was fitted on, is stale
(``_stale``). It is then re-centred (``_drift_compute``): offset and one scale refitted on the buffered
samples of the last ``recheck_interval_s``, the matrix's shape kept (a hard iron moves the offset; four
parameters need far fewer directions than nine). The re-centring must pass the guard rails (not worse
than the current calibration on the recent samples) and, on the first stale recheck, fit the samples since
the calibration better than the full refit (``_drift_choice``: a first calibration only poor where it had
no data also looks stale, and a changed soft iron needs the full refit). Once a re-centring is installed,
each direction bin that received samples since the calibration's fit keeps only those (``_refresh_buffer``;
a bin not seen since keeps its older ones: the coverage stays), and the rechecks only re-centre until
``DRIFT_QUIET`` of them in a row found it fresh (``_drift_hold``); a refit must then also not be worse on
the samples since the re-centring (``_judge_points``).

``ChangeDetection`` is a part of ``calibrator.SensorCalibrator`` (a mixin: it uses the calibrator's state
and ``_install``, ``_set_state``).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.fitting import fit
from ..model.mounting import Mounting, into_imu_frame
from .config import STATIC_SPREAD, guard_rails, relative_spread, rms_relative
from .status import Event, EventKind, State, pct

__all__ = ["ChangeDetection"]

log = logging.getLogger("ros_margcal.stream.calibrator")  # one logger name for the calibrator's messages

Array = NDArray[np.float64]

_NOISE_FLOOR = 0.005
"""Smallest no-change tolerance, relative (quantisation and rounding of a very clean fit)."""


class ChangeDetection:
    """Change detection of a ``SensorCalibrator`` (see the module docstring)."""

    STALE_FACTOR = 2.0
    """While calibrated, a recent residual beyond this many times the calibration's fit residual ..."""
    STALE_MIN = 0.01
    """... and beyond this (relative: noise and the model's error stay within) makes the calibration stale."""
    DRIFT_MIN_POINTS = 12
    """Fewest buffered samples since the calibration's fit for a re-centring refit (four parameters)."""
    DRIFT_QUIET = 2
    """Rechecks in a row that find a re-centred calibration fresh before the full refit runs again."""
    RETURN_MIN_SAMPLES = 10
    """A change is withdrawn only when at least this many recent samples tell the two apart: the old calibration
    explains them (within half ``change_threshold``) and the change, as an offset step fitted to the samples since its
    onset, would miss them by more than ``change_threshold`` (``_check_return``, ``_told_apart``). The norm alone
    cannot tell: a hard-iron step ``db`` leaves it nearly unchanged where the field ``h`` meets
    ``h . db = -|db|^2 / 2``; on a ground robot's ring after a 20 uT step that held for half the headings, and the
    robot driving there for 5 s had the step withdrawn and the old calibration published again, 58 deg off, five times
    in 200 s."""
    RETURN_EVERY_S = 1.0
    """The change's step is fitted at most this often (a few ms) while the residuals say the change passed; and a
    known calibration (``_check_known``) is tried at most this often after a change."""
    KNOWN_MAX = 3
    """Calibrations ended by a declared change that a later change may return to (``_check_known``)."""
    KNOWN_MIN_SAMPLES = 30
    """Fewest buffered samples since a change's onset for ``_check_known`` (and not static: ``STATIC_SPREAD``)."""
    _return_tried = -float("inf")
    _known_tried = -float("inf")
    _known: tuple[tuple[Any, ...], ...] = ()  # (calibration, buffer times, points, partial, figures, prior): oldest first
    _quiet = 0
    # the calibrator's state this mixin uses (set in ``SensorCalibrator.reset``)
    _suspect_since: float | None
    _change_onset: float | None
    _back_since: float | None
    _pre_change: tuple[Any, Any] | None
    _recentred: Calibration | None
    _stale_note: str
    _fit_times: Array
    _fit_points: Array
    _mounting: Mounting | None  # the magnetometer's last mounting estimate (partial.py)
    _mount_applied: Array | None  # calibrate_into_imu_frame: the rotation the readings are turned by (partial.py)
    _sliced: Any  # the fit in progress (evaluation.py)

    def _stale(self) -> bool:
        """On a recheck: has the calibration gone stale (module docstring)?

        Stale means its residual grew where it was fitted: on the recent samples, and on the samples since its fit
        that fell in direction bins holding samples from before (without outliers). A first calibration only poor
        in directions it had no data for can pass this too; ``_drift_choice`` then prefers the full refit. A partial
        or early (MAP) calibration is never stale here: the partial path refits it on its own schedule."""
        cal = self._cal
        if cal is None or self._changed or cal.stats is None or self._partial is not None:
            return False
        limit = max(self.STALE_FACTOR * cal.stats.rms_relative, self.STALE_MIN)
        res = self.residual()
        if res is None or not res > limit:  # the cheap test first: the recent samples
            return False
        buf = self._buffer
        times, pts = buf.times(), buf.points()
        fresh = times >= cal.stamp
        if fresh.all() or not fresh.any():
            return False
        bins = np.array([buf.bin_of(p) for p in pts])
        again = fresh & np.isin(bins, bins[~fresh])
        e = np.abs(cal.norm_error(pts[again])) / cal.norm
        e = e[e <= self.config.outlier_threshold]
        if len(e) < self.DRIFT_MIN_POINTS:
            return False
        stale = float(np.sqrt(np.mean(e * e)))
        if not stale > limit:
            return False
        self._stale_note = (f"the calibration of t={cal.stamp:.2f} s had gone stale (residual {pct(stale)} on the "
                            f"{len(e)} samples since in directions it was fitted on, {pct(cal.stats.rms_relative)} at its fit)")
        return True

    def _refresh_buffer(self, since: float) -> None:
        """A re-centring was installed: direction bins that received samples since ``since`` keep only those (the older
        ones describe the offset before the drift); a bin not seen since keeps its samples (the coverage stays)."""
        buf = self._buffer
        times, pts = buf.times(), buf.points()
        fresh = times >= since
        if fresh.all() or not fresh.any():
            return
        bins = np.array([buf.bin_of(p) for p in pts])
        keep = fresh | ~np.isin(bins, bins[fresh])
        if keep.all():
            return
        self._refill((times[keep], pts[keep]))

    def _refill(self, *parts: tuple[Array, Array], centre: Calibration | None = None) -> None:
        """Empty the buffer (centred on ``centre``'s offset when given) and push ``parts`` (times, points) in order."""
        buf = self._buffer
        buf.clear()
        if centre is not None:
            buf.set_center(centre.offset, centre.rms_radius)  # as _install
        for tt, pp in parts:
            for ti, p in zip(tt.tolist(), pp.tolist(), strict=True):
                buf.push_finite(ti, p[0], p[1], p[2])

    def _explained_since(self, cal: Calibration) -> tuple[Array, Array]:
        """The buffered samples (after a declared change: those since its onset) ``cal`` explains within the outlier
        threshold: what a calibration coming back keeps of them."""
        times, pts = self._buffer.times(), self._buffer.points()
        if not len(pts):
            return times, pts
        keep = np.abs(cal.norm_error(pts)) / cal.norm <= self.config.outlier_threshold
        return times[keep], pts[keep]

    def _drifting(self) -> bool:
        """The current calibration is a re-centring (a drift is on: ``_drift_hold``)."""
        return self._cal is not None and self._recentred is self._cal and not self._changed

    def _drift_hold(self, stale: bool) -> bool:
        """True when a recheck must neither re-centre nor refit: under a re-centring, not stale yet.

        While a drift goes on, the full refit describes the mean offset of samples of different ages in different
        directions (a recheck between two re-centrings published one 5 % off); the rechecks re-centre when stale
        and otherwise wait, until ``DRIFT_QUIET`` of them in a row found the calibration fresh (the drift stopped)."""
        if stale or not self._drifting():
            self._quiet = 0
            return False
        self._quiet += 1
        if self._quiet <= self.DRIFT_QUIET:
            return True
        self._recentred, self._quiet = None, 0
        return False

    def _judge_points(self) -> Array:
        """The samples a refit must not be worse on: the recent ones; under a re-centred calibration (a drift) also the
        buffered ones since its fit, all the directions seen since (a refit on older, drifted samples in other
        directions is no better, but the last seconds' few directions cannot tell)."""
        pts = self._recent_points()
        cal = self._cal
        if cal is None or self._recentred is not cal or self._changed:
            return pts
        times = self._buffer.times()
        return np.concatenate([pts, self._buffer.points()[times >= cal.stamp]])

    def _drift_job(self, job: dict[str, Any], *, full: bool) -> dict[str, Any]:
        """A recheck of a stale calibration: re-centre it first; ``full``: the full refit if that fails (validator passed)."""
        cal = self._cal
        assert cal is not None
        times, pts = self._buffer.times(), self._buffer.points()
        since = max(cal.stamp, job["t"] - self.config.recheck_interval_s)  # a drift moves on: the last recheck's worth
        return {**job, "drift": True, "full": full, "fresh": pts[times >= since], "since": since,
                "fitted_at": cal.stamp, "stale_note": self._stale_note}

    def _drift_compute(self, job: dict[str, Any]) -> tuple[Calibration | None, str]:
        """The current calibration re-centred on the samples since its fit (module docstring); off-lock, on the job."""
        cur: Calibration = job["current"]
        cfg = job["config"]
        pts, recent = job["fresh"], job["recent"]
        head = f"re-centring on the {len(pts)} samples since t={job['since']:.2f} s"
        if len(pts) < self.DRIFT_MIN_POINTS or relative_spread(pts) < STATIC_SPREAD:
            return None, f"{head}: too few directions"
        w0 = np.asarray(cur.matrix, dtype=np.float64)
        try:
            e = fit(pts @ w0.T, model="eye", method="lm", norm=cur.norm, loss=cfg.loss, init="lin_auto",
                    max_iter=cfg.max_iter, sensor=self.sensor, unit=cfg.unit)
        except (ValueError, ArithmeticError) as exc:
            return None, f"{head} failed: {exc}"
        std = e.parameter_std()
        worst = max((std.get(k, 0.0) for k in ("b_x", "b_y", "b_z")), default=0.0) / cur.norm
        if not worst <= cfg.max_parameter_std:
            return None, f"{head}: offset std {pct(worst)} > {pct(cfg.max_parameter_std)}"
        cal = cur.replace(offset=np.linalg.solve(w0, e.offset), matrix=e.matrix @ w0, stats=e.stats, covariance=None,
                          parameter_names=(), stamp=job["t"], method="lm")
        reason = guard_rails(cal, cfg, recent, cur)
        if reason:
            return None, f"{head}: {reason}"
        self._full_figures(job, cal)
        job["note"] = (f"; re-centred: {job['stale_note']}; offset moved by "
                       f"{pct(float(np.linalg.norm(cal.offset - cur.offset)) / cur.raw_radius)} of the field, the matrix kept")
        job["recentred"] = cal
        return cal, ""

    def _drift_choice(self, job: dict[str, Any], recentred: tuple[Calibration | None, str],
                      full: tuple[Calibration | None, str]) -> tuple[Calibration | None, str]:
        """The first recheck of a stale calibration: the re-centring or the full refit, whichever fits the samples
        since its fit better (a drift: the re-centring; a first calibration only poor where it had no data, which
        also looks stale: the full refit on the wider buffer)."""
        a, b = recentred[0], full[0]
        if a is None or (b is not None and rms_relative(b, job["fresh"]) <= rms_relative(a, job["fresh"])):
            job["recentred"], job["note"] = None, ""
            return full if b is not None else (None, f"{full[1]}; {recentred[1]}")
        self._full_figures(job, a)  # the full fit's replaced them
        return recentred

    def _check_change(self, t: float) -> list[Event]:
        """Declare a change when the windowed median residual stays above the threshold long enough."""
        cfg = self.config
        k = cfg.change_window
        if len(self._recent_r) < k:
            return []
        window = list(self._recent_r)[-k:]
        med = float(np.median(window))
        if med <= cfg.change_threshold:
            self._suspect_since = None
            return []
        if self._suspect_since is None:
            # the median of k samples crosses when about half of them are bad: the change began there
            self._suspect_since = self._recent_t[-(k // 2) - 1]
        onset = self._suspect_since
        if t - onset < cfg.change_min_duration_s:
            return []
        times = np.asarray(self._recent_t)
        first_bad = int(np.searchsorted(times, onset))
        # the median puts the onset within a sample or two; samples there that the old calibration
        # still explains were taken before the change and would bias the new fit (one pre-jump sample
        # in 64 moved the offset by 9 % of the norm), so the new buffer starts at the first bad one
        resid = self._recent_r
        while first_bad < len(resid) - 1 and resid[first_bad] <= cfg.change_threshold:
            first_bad += 1
        onset = float(times[first_bad])
        single, hypotheses, fitted = self._no_change(first_bad, med)
        if single is not None:  # one calibration explains the buffer and the window: not a change
            job = {"points": fitted, "config": self.config, "mag_frame_cal": single}
            mount = self._mounting
            if self.config.calibrate_into_imu_frame and mount is not None and mount.rotation is not None:
                single = into_imu_frame(single, mount)  # in the IMU's frame, as the calibration it replaces (partial.py)
            self._install(single)
            # its own heading figures, when next read (evaluation.py ``_settle_figures``): not the old calibration's
            self._partial, self._figures = None, None
            self._figures_due = (job, single) if self.sensor == "mag" else None
            self.fits_accepted += 1
            self._last_rejection = ""
            msg = f"no sensor change at t={onset:.2f} s: {hypotheses}; recalibrated"
            log.debug("%s: %s", self.sensor, msg)
            return [Event(EventKind.CALIBRATED, t, self.sensor, msg, single)]
        if "missed before the onset" in hypotheses:  # the calibration was as poor there before: kept, refit due
            self._suspect_since = None
            self._since_eval = self.config.refit_every
            self._last_eval_t = -float("inf")
            self._last_reason = f"no sensor change at t={onset:.2f} s: {hypotheses}"
            log.debug("%s: %s", self.sensor, self._last_reason)
            return []
        before = self._buffer_before(onset)
        self._remember(before)  # the calibration this change ends, to return to (_check_known)
        self._changed = True
        self._change_onset = onset
        self._known_tried = -float("inf")
        self._drop_before_change(onset)  # the series and gyro rows (partial.py)
        self.changes += 1
        self._suspect_since = None
        self._back_since = None
        self._pre_change = before  # back if the change passes (_check_return)
        pts = np.array(self._recent_v)[first_bad:]
        tt = times[first_bad:]
        self._buffer.clear()
        cal = self._cal
        self._buffer.set_center(np.zeros(3) if cal is None else cal.offset, 1.0 if cal is None else cal.rms_radius)
        for ti, p in zip(tt, pts, strict=True):
            self._buffer.push(float(ti), p)
        self._since_eval = len(self._buffer)
        self._predicted = None
        msg = (f"sensor changed at t={onset:.2f} s: median residual {pct(med)} > {pct(cfg.change_threshold)} "
               f"for {t - onset:.1f} s; {hypotheses}; recollecting")
        log.debug("%s: %s", self.sensor, msg)
        self._last_reason = msg
        events = [Event(EventKind.CHANGED, t, self.sensor, msg)]
        return events + self._set_state(State.COLLECTING, t)

    def _check_return(self, t: float) -> list[Event]:
        """After a declared change: withdraw it when the old calibration explains the samples again (module docstring)."""
        cfg = self.config
        k = cfg.change_window
        resid = self._recent_r
        if len(resid) < k or self._cal is None:
            return []
        med = float(np.median([resid[i] for i in range(len(resid) - k, len(resid))]))
        limit = 0.5 * cfg.change_threshold
        if med > limit:
            self._back_since = None
            return []
        if self._back_since is None:
            self._back_since = self._recent_t[-(k // 2) - 1]  # as for a change: the median crossed half-way in
        back = self._back_since
        if t - back < cfg.change_min_duration_s:
            return []
        if abs(t - self._return_tried) < self.RETURN_EVERY_S:  # abs: stamps that restart after a reset
            return []
        self._return_tried = t
        again = self._told_apart(back)
        if again < self.RETURN_MIN_SAMPLES:
            return []  # explained only where the change shows no norm error: wait (the window grows from ``back``)
        cal, onset = self._cal, self._change_onset
        saved, self._pre_change = self._pre_change, None
        now = self._explained_since(cal)
        events = self._set_state(State.CALIBRATED, t)
        self._install(cal)
        self._refill(saved if saved is not None else (np.zeros(0), np.zeros((0, 3))), now)
        self._since_eval = 0
        msg = (f"no sensor change after all: the change at t={-1.0 if onset is None else onset:.2f} s passed; since "
               f"t={back:.2f} s the calibration explains the samples again (median residual {pct(med)} <= {pct(limit)} "
               f"for {t - back:.1f} s, {again} samples the change would have missed); it is kept, with the buffer of "
               f"before the change and the {len(now[0])} "
               "samples since that it explains")
        log.debug("%s: %s", self.sensor, msg)
        self._last_reason = msg
        return [*events, Event(EventKind.CALIBRATED, t, self.sensor, msg, cal)]

    def _buffer_before(self, onset: float) -> tuple[Array, Array]:
        """A change is declared at ``onset``: the buffer's samples (times, points) from before it that the calibration
        explains within half ``change_threshold`` (the outlier threshold let in samples of the new sensor where the step
        barely moved the norm, and the median finds the onset late: they are not the old sensor's)."""
        times, pts = self._buffer.times(), self._buffer.points()
        cal = self._cal
        if cal is None or not len(pts):
            return times, pts
        ok = (times < onset) & (np.abs(cal.norm_error(pts)) / cal.norm <= 0.5 * self.config.change_threshold)
        return times[ok], pts[ok]

    def _remember(self, before: tuple[Array, Array]) -> None:
        """A change is declared: keep the calibration it ends, its heading figures and its buffer from ``before`` the
        onset (``_buffer_before``) for ``_check_known``."""
        cal = self._cal
        if cal is None or self.KNOWN_MAX < 1:
            return
        entry = (cal, before[0], before[1], self._partial, self._figures, self._prior)
        self._known = (*(k for k in self._known if k[0] is not cal), entry)[-self.KNOWN_MAX:]

    def _check_known(self, t: float) -> list[Event]:
        """After a declared change: reinstate a calibration an earlier change ended when it explains the samples since
        the onset (module docstring); at most every ``RETURN_EVERY_S``."""
        if (abs(t - self._known_tried) < self.RETURN_EVERY_S or self._mount_applied is not None
                or self._sliced is not None):  # a fit in progress ends first (evaluation.py)
            return []
        self._known_tried = t
        pts = self._buffer.points()  # after a declared change: the samples since its onset
        if len(pts) < self.KNOWN_MIN_SAMPLES or relative_spread(pts) < STATIC_SPREAD:
            return []
        for entry in reversed(self._known):
            if entry[0] is not self._cal:
                why = _explains(entry[0], pts, self.config.change_threshold, self.config.max_parameter_std)
                if why:
                    return self._reinstate(t, entry, why)
        return []

    def _reinstate(self, t: float, entry: tuple[Any, ...], why: str) -> list[Event]:
        """Install a known calibration again, with its buffer, heading figures and the samples since that it explains."""
        cal, saved_t, saved_p, partial, figures, prior = entry
        onset = self._change_onset
        now = self._explained_since(cal)
        self._refill((saved_t, saved_p), now, centre=cal)
        events = self._set_state(State.CALIBRATED, t)
        self._install(cal)
        self._fit_times, self._fit_points = saved_t, saved_p  # what it was fitted on (``_missed_before``)
        self._partial, self._figures, self._prior = partial, figures, prior
        self._recentred, self._since_eval, self._last_rejection = None, 0, ""
        msg = (f"sensor changed back: the calibration of t={cal.stamp:.2f} s, which an earlier change ended, explains the "
               f"samples since the change at t={-1.0 if onset is None else onset:.2f} s ({why}); reinstated, with its "
               f"buffer and the {len(now[0])} samples since that it explains")
        log.debug("%s: %s", self.sensor, msg)
        self._last_reason = msg
        return [*events, Event(EventKind.CALIBRATED, t, self.sensor, msg, cal)]

    def _told_apart(self, since: float) -> int:
        """How many recent samples since ``since`` the old calibration explains (within half ``change_threshold``)
        and the change would miss by more than ``change_threshold``: the change taken as the offset step that best
        explains, under the old calibration's matrix and norm, the buffered samples from the onset to ``since`` (after
        a declared change the buffer holds only samples since its onset). With fewer than four of those, every
        sample the old calibration explains counts."""
        cal, buf, cfg = self._cal, self._buffer, self.config
        assert cal is not None
        w, b, n = np.asarray(cal.matrix, dtype=np.float64), np.asarray(cal.offset, dtype=np.float64), cal.norm
        times = buf.times()
        step = _offset_step((buf.points()[times < since] - b) @ w.T, n)
        rt = np.fromiter(self._recent_t, dtype=np.float64, count=len(self._recent_t))
        c = (np.array(self._recent_v, dtype=np.float64).reshape(-1, 3)[rt >= since] - b) @ w.T
        if not len(c):
            return 0
        old = np.abs(np.linalg.norm(c, axis=1) - n) / n <= 0.5 * cfg.change_threshold
        if step is None:  # too few samples since the onset to fit a step (an accelerometer's few still poses)
            return int(np.count_nonzero(old))  # the norm alone decides, as before
        new = np.abs(np.linalg.norm(c - step, axis=1) - n) / n
        return int(np.count_nonzero(old & (new > cfg.change_threshold)))

    def _no_change(self, first_bad: int, med: float) -> tuple[Calibration | None, str, Array]:
        """Test a declared change against the no-change hypothesis: ``(calibration, text, points it was fitted on)``,
        the calibration None unless one explains all.

        One calibration is refitted on the buffer (the directions seen before) and the whole recent
        window (also the samples before the onset). It is *no change* when that fit passes the guard
        rails and leaves, on the samples since the onset, a median relative residual within the
        tolerance, and the same on the buffer. The tolerance is twice the old calibration's median
        residual on the buffer (the noise and model error it shows on the directions it was fitted to;
        at least ``_NOISE_FLOOR``, at most ``change_threshold``). A calibration that was only poor in
        directions not yet seen is then improved instead of thrown away; a real step (a hard iron of
        0.15 field norms leaves about 1.6 % against 0.2 % of noise) is a change. The text states both
        hypotheses either way.
        """
        cfg = self.config
        old = self._cal
        assert old is not None
        window = np.array(self._recent_v, dtype=np.float64).reshape(-1, 3)
        buf = self._buffer.points()
        post, both = window[first_bad:], np.concatenate([buf, window])
        old_text = f"old calibration: median {pct(med)} since the onset"
        try:
            cal = fit(both, model=cfg.model, method=cfg.method, norm=cfg.reference_norm,
                      loss=cfg.loss, max_iter=cfg.max_iter, sensor=self.sensor, unit=cfg.unit)
            cal = cal.replace(stamp=self._t)
            reason = guard_rails(cal, cfg, post, None)
        except (ValueError, ArithmeticError) as exc:
            return None, f"{old_text}; one calibration for the buffer and the window could not be fitted ({exc})", both
        single_post, single_buf = cal.median_relative_error(post), cal.median_relative_error(buf)
        old_buf = old.median_relative_error(buf)
        tol = min(cfg.change_threshold, max(2.0 * old_buf, _NOISE_FLOOR))
        before = self._missed_before(post, float(self._recent_t[first_bad]), med)
        if before:  # the same directions were as poor before the onset: a poor calibration there, not a change
            tol = max(tol, 0.5 * cfg.change_threshold)
        text = (f"{old_text}, {pct(old_buf)} on the buffer{before}; one calibration refitted on the {len(buf)} buffered "
                f"and {len(window)} recent samples: median {pct(single_post)} since the onset, {pct(single_buf)} on the "
                f"buffer (tolerance {pct(tol)}: "
                f"{'half the change threshold' if before else 'twice the old calibration’s on the buffer'})")
        if reason:
            return None, f"{text}, refused: {reason}", both
        return (cal if single_post <= tol and single_buf <= tol else None), text, both

    def _missed_before(self, post: Array, onset: float, med: float) -> str:
        """"; ... missed before the onset ..." when the buffered samples from before the onset in the directions of the
        samples since (a rest pose seen before: the start pose returned to) are off the current calibration by at
        least half the median since the onset: the calibration was poor there, the sensor has not changed ("" else).

        A real change (a hard-iron jump) leaves the earlier samples of those directions explained by the old
        calibration; a first calibration from part of the sphere that missed a pose misses it the same before and after."""
        buf, old = self._buffer, self._cal
        times = np.concatenate([buf.times(), self._fit_times])  # the buffer's bins keep the newest: also what it was fitted on
        pts = np.concatenate([buf.points(), self._fit_points])
        if old is None or not len(pts):
            return ""
        bins = {buf.bin_of(p) for p in post}
        same = (times < onset) & np.array([buf.bin_of(p) in bins for p in pts])
        if np.count_nonzero(same) < 3:
            return ""
        then = old.median_relative_error(pts[same])
        if then < 0.5 * med:
            return ""
        return (f"; the {int(np.count_nonzero(same))} buffered samples from before the onset in the same directions were "
                f"missed before the onset too (median {pct(then)})")


def _explains(cal: Calibration, pts: Array, change_threshold: float, max_std: float) -> str:
    """Why ``cal`` is the sensor of the raw samples ``pts`` ("" when it is not): their median relative residual under
    it within twice its fit residual (at least ``_NOISE_FLOOR``, at most half ``change_threshold``), and an offset step
    fitted from it within three standard deviations of zero, that deviation at most ``max_std`` of the field (the
    directions pin the offset: a few directions lie on the spheres of many offsets)."""
    w, b, n = np.asarray(cal.matrix, dtype=np.float64), np.asarray(cal.offset, dtype=np.float64), cal.norm
    c = (pts - b) @ w.T
    r = np.linalg.norm(c, axis=1)
    rel = np.abs(r - n) / n
    fitted = cal.stats.rms_relative if cal.stats is not None else 0.0
    tol = min(0.5 * change_threshold, max(2.0 * fitted, _NOISE_FLOOR))
    med = float(np.median(rel))
    if not med <= tol or not np.all(r > 0):
        return ""
    jac = c / r[:, None]
    sigma = max(float(np.sqrt(np.mean(rel * rel))), _NOISE_FLOOR / 10.0) * n
    try:
        sd = sigma * float(np.sqrt(np.max(np.linalg.eigvalsh(np.linalg.inv(jac.T @ jac))))) / n
    except np.linalg.LinAlgError:
        return ""
    step = _offset_step(c, n)
    if step is None or not sd <= max_std:
        return ""
    moved = float(np.linalg.norm(step)) / n
    if not moved <= 3.0 * sd:
        return ""
    return (f"median residual {pct(med)} <= {pct(tol)} on {len(pts)} samples; an offset step from it "
            f"{pct(moved)} +- {pct(sd)} of the field")


def _offset_step(c: Array, n: float, iterations: int = 20) -> Array | None:
    """The step ``e`` that puts calibrated readings ``c`` (N, 3) at distance ``n`` from it (Gauss-Newton from 0, the
    old calibration's centre: the nearer of a ring's two mirror solutions); None without enough readings or when it
    runs away."""
    if len(c) < 4 or not n > 0:
        return None
    e = np.zeros(3)
    for _ in range(iterations):
        d = c - e
        r = np.linalg.norm(d, axis=1)
        if not np.all(r > 0):
            return None
        jac = -d / r[:, None]
        delta, *_ = np.linalg.lstsq(jac, n - r, rcond=None)
        e = e + delta
        if not np.all(np.isfinite(e)):
            return None
        if float(np.linalg.norm(delta)) <= 1e-9 * n:
            break
    return e
