"""The slow half of the streaming calibrator: validation, the fit and its guard rails, when to run them.

``Evaluation`` is the part of ``calibrator.SensorCalibrator`` that decides whether the buffer is good
enough and fits it (steps 4-6 of the calibrator's flow), kept apart from the per-sample path. It runs
inline in ``push`` (replay, and the node's worker process) or, with ``defer_evaluation``, from
``run_pending`` on another thread (``bench/pipeline.py`` measures the per-sample path that way):
the centre update and the validator under the caller's lock, the fit on a snapshot outside it, the
result installed under it again, a fit whose data went stale meanwhile dropped. An evaluation on
materially unchanged data (same bins, nearly the same buffer size and recent residual) is skipped with
an exponential back-off, so a robot that never covers more directions does not pay for the same
refusal over and over; a full fit that ran away (``RunawayError``) is retried after 1, 2, 4, 8 s (``RUNAWAY_MAX_WAIT_S``),
the buffer growing or not. Inline, a full fit's posterior for the heading figures (``posterior_at``: the next
prior) is not computed in the push that installs it but when next needed (``_settle_figures``: the next push,
``status``, or an evaluation right after), so one push pays for the fit or for it, not for both; the figures
themselves (a few ms each: the posterior's draws) are computed when a status first reads them
(``observable.HeadingFigures``). The buffer is
re-binned about a new centre estimate only when the centre moved significantly (``_center_moved``): a ring's
sphere fit leaves its axial component to the noise.

**Fits in steps.** Inline, a fit runs one step a push (``model.steps``: a Levenberg-Marquardt solve, half a noise
model, a mounting estimate), the first in the push after the one whose evaluation started it (the validation, its
indicators' hull, is a step of its own: with a one-step fit and its install on top, a 30-min tumble's longest push was
21 ms), from the snapshot that push took;
no other evaluation starts meanwhile, and the result is installed (or refused) in the push that runs its last step,
with the stamp of the push that started it, unless the data went stale meanwhile (as in deferred mode). So no
single sample pays for a whole fit: the longest push of ``scripts/bench_speed.py`` was a partial fit with the gyro,
its noise model and its mounting in one push (up to 84 ms). The calibration is the same; it is installed a few
samples later (on bench_speed's streams 5-6 pushes at the median, at most 21: 0.4 s at 50 Hz). A forced evaluation
(``refit``) and deferred mode (``run_pending``) run a fit whole.

It uses the calibrator's state (``_buffer``, ``_cal``, ``config``, ``validator``, the recent samples)
and its helpers ``_install``, ``_set_state`` and ``_recent_points``.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.errors import MargCalError, RunawayError
from ..model.fitting import fit
from ..model.steps import Steps, drained
from .config import STILL_SPREAD, PipelineConfig, apart, guard_rails, relative_spread, white_noise
from .observable import side_axis
from .partial import PartialCalibration
from .status import Event, EventKind, State, pct

__all__ = ["Evaluation"]

log = logging.getLogger("ros_margcal.stream.calibrator")  # one logger name for the calibrator's messages

Array = NDArray[np.float64]


class Evaluation(PartialCalibration):
    """Validation, fit and guard rails of a ``SensorCalibrator`` (a mixin: see the module docstring)."""

    # an evaluation on materially unchanged data is skipped (see _unchanged)
    SKIP_SIZE_TOLERANCE = 0.05
    """Relative change of the buffer size within which the data count as unchanged (after a validator
    refusal or while calibrated; after a guard-rail refusal the size must be the same)."""
    SKIP_FAR = 4.0
    """A prediction beyond this many times the threshold ignores the buffer size (only new bins help)."""
    SKIP_RESIDUAL_TOLERANCE = 0.25
    """Relative change of the mean recent residual (plus 0.1 % of the norm) within which data are unchanged."""
    SKIP_MIN_WAIT_S = 1.0
    """First back-off on unchanged data, s (or the cadence interval if longer); it doubles per repeat ..."""
    SKIP_MAX_WAIT_S = 120.0
    """... up to this, s (or the cadence interval if longer)."""
    RUNAWAY_MAX_WAIT_S = 8.0
    """A full fit that ran away (``model.errors.RunawayError``: the readings cover too few directions for the noise, or
    lie on no one ellipsoid) is retried after 1, 2, 4 ... s, at most this, until another verdict: a noisy QMC5883L's
    half sphere ran away at every 1 s evaluation for 44 s, ~15 ms each (``_runaway_wait``)."""
    CENTER_MOVE_TOLERANCE = 0.002
    """A centre estimate that moved less than this share of the radius keeps the old centre (the radius is
    still updated): a 0.2 % move turns a direction by < 0.12 deg, far below a bin's ~20 deg ..."""
    CENTER_MOVE_SIGMAS = 3.0
    """... as does one within this many standard errors of the sphere fit along the move (``_center_moved``)."""
    MIN_SPHERE_SHARE = 0.5
    """A sphere fit whose radius is below this share of the unit's smallest plausible field (``norm_min``) is the
    noise of a sensor that has barely turned, not the field's sphere: the centre stays (a still BROAD recording after
    its magnet: a 1.1 uT sphere about the readings themselves, every direction bin filled, "100 % coverage"); nor
    does one of readings within ``config.STILL_SPREAD`` of their mean, whatever the unit."""
    defer_evaluation: bool = False
    """False (replay, the node's worker process): a due evaluation (centre, validator, fit) runs inside ``push``.
    True: ``push`` only records it and ``run_pending`` runs it, e.g. on a worker thread, so the
    per-message path never pays for a fit. Same results when ``run_pending`` follows each ``push``."""
    _pending: float | None = None
    _last_full: tuple[tuple[Any, ...], tuple[Any, ...]] | None = None  # what the last full evaluation saw
    _full_eval_t: float = -math.inf
    _backoff: int = 0
    _runaways: int = 0  # full fits in a row that ran away (RUNAWAY_MAX_WAIT_S)
    _figures_due: tuple[dict[str, Any], Calibration] | None = None  # an installed full fit whose figures are not read yet
    _sliced: tuple[dict[str, Any], Steps[tuple[Calibration | None, str]]] | None = None
    """Inline, the fit in progress: its job and its remaining steps, one run per push (**Fits in steps**)."""

    def refit(self, t: float | None = None) -> list[Event]:
        """Validate and fit now, ignoring the cadence (the refit service). The validator still decides."""
        return self._evaluate(self._t if t is None else float(t), force=True)

    @property
    def pending(self) -> bool:
        """True when ``push`` recorded an evaluation that ``run_pending`` has not run yet (deferred mode)."""
        return self._pending is not None

    def run_pending(self, lock: Any = None) -> list[Event]:
        """Run the evaluation ``push`` recorded in deferred mode (nothing when none is due); its events.

        With ``lock`` (a ``threading.Lock`` that every other use of this calibrator also holds), the
        centre update and the validator run under it, the fit itself runs outside it on a snapshot of
        the buffer, and the result is installed under it again: a sample callback waits at most for the
        validation, never for the fit, and the calibration is swapped in at once. A fit whose data went
        stale meanwhile (reset, sensor change, another calibration installed) is dropped.
        """
        if lock is not None:
            lock.acquire()
        try:
            t, self._pending = self._pending, None
            if t is None:
                return []
            events, job = self._validate(t, force=False)
        finally:
            if lock is not None:
                lock.release()
        if job is None:
            return events
        result = self._fit_compute(job)
        if lock is not None:
            lock.acquire()
        try:
            return events + self._fit_finish(job, result)
        finally:
            if lock is not None:
                lock.release()

    def _signature(self) -> tuple[tuple[Any, ...], tuple[Any, ...]]:
        """What decides an evaluation's verdict, cheaply: the objects in use (buffer, calibration, options,
        validator) and the values (buffer size and coverage, sensor-change state, mean recent residual)."""
        res = sum(self._recent_r) / len(self._recent_r) if (self._cal is not None and self._recent_r) else 0.0
        buf = self._buffer
        return ((buf, self._cal, self.config, self.validator),
                (len(buf), buf.coverage(), self.changes, self._changed, res))

    def _unchanged(self, t: float, interval: float) -> bool:
        """True when the last full evaluation saw materially the same data and its back-off has not run out.

        Materially the same: the same buffer, calibration, options and validator, the same occupied
        bins and change state, the same buffer size (within ``SKIP_SIZE_TOLERANCE`` after the
        validator refused or while calibrated; exactly after guard rails refused a fit, which a few
        more samples can turn around; any size after a prediction beyond ``SKIP_FAR`` times the
        threshold, which only new directions can bring down) and a mean recent residual
        within ``SKIP_RESIDUAL_TOLERANCE`` (relative, plus 0.1 % of the norm). Such an evaluation is
        repeated only after ``max(interval, SKIP_MIN_WAIT_S) * 2**k`` seconds (at most
        ``max(interval, SKIP_MAX_WAIT_S)``), ``k`` counting the full evaluations in a row on unchanged
        data, so rich motion (new bins, a growing buffer) is evaluated at the usual cadence and motion
        that cannot change the verdict (a ground robot's yaw turns) ever more rarely.
        """
        if self._last_full is None or self._partial_wanted():
            return False
        (objs0, (n0, cov0, ch0, chd0, res0)), (objs, (n, cov, ch, chd, res)) = self._last_full, self._signature()
        if any(x is not y for x, y in zip(objs, objs0, strict=True)) or (cov, ch, chd) != (cov0, ch0, chd0):
            return False
        # a few more samples can turn a fit's guard rails around, seldom the validator's verdict or a
        # recheck, and never a prediction many times the threshold (only new directions can)
        pred, thr = self._predicted, self.threshold
        rejected = pred is not None and not pred <= thr
        if rejected and not pred <= self.SKIP_FAR * thr:
            size_tol = math.inf
        else:
            size_tol = self.SKIP_SIZE_TOLERANCE * n0 if (rejected or (self._cal is not None and not chd)) else 0.0
        if abs(n - n0) > size_tol or abs(res - res0) > self.SKIP_RESIDUAL_TOLERANCE * res0 + 1e-3:
            return False
        wait = min(max(interval, self.SKIP_MIN_WAIT_S) * 2.0**self._backoff, max(interval, self.SKIP_MAX_WAIT_S))
        return t - self._full_eval_t < wait

    def _update_center(self) -> None:
        """Before a calibration (or after a change): the direction bins' centre from a sphere fit of the buffer, kept
        when it barely moved, its radius is no field's or the readings barely spread (``MIN_SPHERE_SHARE``)."""
        if self._cal is not None and not self._changed:
            return
        pts = np.concatenate([self._buffer.points(), self._recent_points()])
        if len(pts) < 10 or relative_spread(pts) < STILL_SPREAD:
            return
        # centre and radius from a linear sphere fit (cheap); the LM fit refines it later
        a = np.c_[2.0 * pts, np.ones(len(pts))]
        y = (pts * pts).sum(axis=1)
        sol, *_ = np.linalg.lstsq(a, y, rcond=None)
        c = sol[:3]
        rad2 = sol[3] + c @ c
        if not (np.isfinite(c).all() and np.isfinite(rad2) and rad2 > 0):
            return
        rad = math.sqrt(rad2)
        if rad < self.MIN_SPHERE_SHARE * self.config.norm_min:
            return
        old = self._buffer.center
        if self._buffer.radius is not None and not self._center_moved(a, y - a @ sol, c - old, rad):
            c = old  # keep the bins: re-binning costs ~2 ms at 1000 samples and would change nothing real
        self._buffer.set_center(c, rad)

    def _center_moved(self, a: Array, res: Array, step: Array, rad: float) -> bool:
        """The sphere fit's centre moved by ``step``: by more than ``CENTER_MOVE_TOLERANCE`` of the radius and
        by more than ``CENTER_MOVE_SIGMAS`` standard errors of the fit along the step (a ring leaves the
        centre's axial component to the noise: it must not re-bin the buffer at every evaluation)."""
        dist = float(np.linalg.norm(step))
        if dist <= self.CENTER_MOVE_TOLERANCE * rad:
            return False
        dof = len(res) - 4
        if dof <= 0:
            return True
        try:
            cov = np.linalg.inv(a.T @ a)[:3, :3] * float(res @ res) / dof
        except np.linalg.LinAlgError:
            return False  # the data do not determine a centre: keep the one the bins use
        u = step / dist
        var = float(u @ cov @ u)
        return not (math.isfinite(var) and dist * dist <= self.CENTER_MOVE_SIGMAS**2 * var)

    def _evaluate(self, t: float, *, force: bool) -> list[Event]:
        """A due (``force``: a requested) evaluation: skipped on unchanged data, recorded when deferring."""
        self._since_eval = 0
        self._last_eval_t = t
        if force:
            self._pending = None
        else:
            interval = self._cadence()[1]
            if self._unchanged(t, interval) or t - self._full_eval_t < self._runaway_wait():
                return []
            if self.defer_evaluation:
                self._pending = t
                return []
        self._sliced = None  # a forced evaluation replaces a fit in progress (its data are older)
        events, job = self._validate(t, force=force)
        if job is None:
            return events
        job["figures_later"] = True  # inline: the figures when next read (module docstring)
        if force:
            return events + self._fit_finish(job, self._fit_compute(job))
        self._sliced = (job, self._fit_steps(job))  # its first step in the next push: not on top of the validation
        return events

    def _runaway_wait(self) -> float:
        """Seconds before a full evaluation after ``_runaways`` fits in a row ran away (0 after none or one)."""
        return 0.0 if self._runaways < 2 else min(2.0 ** (self._runaways - 1), self.RUNAWAY_MAX_WAIT_S)

    def finish_fit(self) -> list[Event]:
        """Run the fit in progress (**Fits in steps**) to its end now, its events: at the end of a recording, whose
        last samples would otherwise leave it unfinished (``replay``)."""
        if self._sliced is None:
            return []
        job, steps = self._sliced
        self._sliced = None
        return self._fit_finish(job, drained(steps))

    def _fit_step(self) -> list[Event]:
        """One step of the fit in progress (``_sliced``: module docstring, **Fits in steps**); its events when it ends."""
        assert self._sliced is not None
        job, steps = self._sliced
        try:
            next(steps)
        except StopIteration as done:
            self._sliced = None
            return self._fit_finish(job, done.value)
        return []

    def _validate(self, t: float, *, force: bool) -> tuple[list[Event], dict[str, Any] | None]:
        """Centre, indicators and the validator's verdict: the events, and the fit to run (or None)."""
        cfg = self.config
        self._settle_figures()  # the last fit's figures are its prior for a partial fit (if no push came between)
        if not force:
            self._backoff = self._backoff + 1 if self._unchanged(t, math.inf) else 0
            self._full_eval_t = t
        self._update_center()
        stale = self._stale()  # a drift (change.py): the offset is refitted on the fresh samples
        self._last_full = self._signature()
        if not force and self._drift_hold(stale):
            return [], None
        n = len(self._buffer)
        if n < cfg.min_points:
            self._predicted = None
            self._last_reason = f"{n} samples buffered, need {cfg.min_points}"
            events = [Event(EventKind.REJECTED, t, self.sensor, f"not fitted: {self._last_reason}")] if force else []
            if stale:
                return events, self._drift_job(self._fit_job(t), full=False)
            return events, (self._partial_job(self._fit_job(t)) if self._partial_wanted() else None)
        self._indicators = self._buffer.indicators()
        try:
            pred = float(self.validator.predict_indicators(self._indicators))
        except MargCalError as exc:
            pred = math.inf
            log.warning("%s: validator failed: %s", self.sensor, exc)
        self._predicted = pred
        thr = self.threshold
        if not pred <= thr:
            shown = pct(pred) if pred <= 1.0 else "over 100 % (not determined)"  # the validator extrapolates
            todo = ("hold the sensor still in poses not yet covered" if self.sensor == "accel" else
                    "turn the sensor through the directions not yet covered")
            self._last_reason = f"{pct(self.coverage)} coverage, predicted error {shown} > {pct(thr)}: {todo}"
            events = [Event(EventKind.REJECTED, t, self.sensor, f"not fitted: {self._last_reason}")] if force else []
            if self._cal is None or self._changed:
                events += self._set_state(State.COLLECTING, t)
            if stale:
                return events, self._drift_job(self._fit_job(t), full=False)
            if self._partial_wanted():  # what the motion makes observable (stream/observable.py)
                return events, self._partial_job(self._fit_job(t))
            return events, None
        events = []
        if self._cal is None or self._changed:
            events += self._set_state(State.READY, t)
        return events, self._drift_job(self._fit_job(t), full=not self._drifting()) if stale else self._fit_job(t)

    @property
    def threshold(self) -> float:
        """The predicted-error threshold in use (config override or the validator's)."""
        if self.config.max_predicted_error is not None:
            return self.config.max_predicted_error
        thr = getattr(self.validator, "threshold", None)
        return float(thr) if thr is not None else 0.01

    @property
    def coverage(self) -> float:
        """Fraction of direction bins holding at least one sample (0..1)."""
        return float(self._buffer.coverage())

    def _fit_job(self, t: float) -> dict[str, Any]:
        """A snapshot of what the fit needs (the fit itself may then run without the lock)."""
        rows = list(self._gyro_buf) if self.sensor == "mag" and self._full_mount_due() else []  # the mounting (partial.py)
        return {"t": t, "points": self._buffer.points(), "recent": self._judge_points(), "current": self._cal,
                "noise": white_noise(np.array(self._recent_v, dtype=np.float64)),  # the residual limit (config.py)
                "config": self.config, "buffer": self._buffer, "changes": self.changes,
                "current_is_map": self._cal is not None and self._partial is not None,
                "gyro_rows": rows, "mount_applied": self._mount_applied, "mounting_kept": self._mounting}

    def _fit_compute(self, job: dict[str, Any]) -> tuple[Calibration | None, str]:
        """The fit and its guard rails on a snapshot: (calibration, "") or (None, the reason)."""
        return drained(self._fit_steps(job))

    def _fit_steps(self, job: dict[str, Any]) -> Steps[tuple[Calibration | None, str]]:
        """``_fit_compute`` in steps (module docstring, **Fits in steps**)."""
        if job.get("partial"):
            return (yield from self._partial_steps(job))
        if job.get("drift"):  # a stale calibration (change.py): re-centred, or refitted if that fits the fresh data better
            got = self._drift_compute(job)
            if job["full"]:
                yield
                got = self._drift_choice(job, got, (yield from self._full_steps(job)))
        else:
            got = yield from self._full_steps(job)
        reason = self._misses_recent(job, got[0])
        return (None, reason) if reason else got

    def _misses_recent(self, job: dict[str, Any], cal: Calibration | None) -> str:
        """Why a recheck's calibration must not replace the current one although it passed the guard rails: its
        median residual on the recent samples is beyond ``change_threshold`` ("" when within, or no recheck).

        Not worse than the current calibration is no yardstick when both miss the recent samples: after a hard-iron
        jump the samples since are outliers, never buffered, so a recheck refitted (or re-centred) the buffer of
        before the jump and published it, 49 deg off, until the change detector declared the change 8 s later."""
        cfg = self.config
        recent = job["recent"]
        if cal is None or job["current"] is None or len(recent) < cfg.change_window:
            return ""
        med = cal.median_relative_error(recent)
        if med <= cfg.change_threshold:
            return ""
        got, limit = apart(100 * med, 100 * cfg.change_threshold)
        return (f"median residual {got} % on the last {len(recent)} samples > the change threshold {limit} %: "
                "the sensor may have changed (the change detector decides)")

    def _full_steps(self, job: dict[str, Any]) -> Steps[tuple[Calibration | None, str]]:
        """The full fit of the buffer and its guard rails (a step), then the mounting under it (another)."""
        cfg: PipelineConfig = job["config"]
        pts = job["points"]
        try:
            scale = None
            if cfg.f_scale_rel is not None:
                ref = cfg.reference_norm or float(np.median(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))
                scale = cfg.f_scale_rel * ref
            cal = fit(pts, model=cfg.model, method=cfg.method, norm=cfg.reference_norm, loss=cfg.loss,
                      f_scale=scale, max_iter=cfg.max_iter, sensor=self.sensor, unit=cfg.unit)
            cal = cal.replace(stamp=job["t"])
            # a MAP calibration (partial or early) is no yardstick for the full fit: no not-worse check against it
            reason = guard_rails(cal, cfg, job["recent"], None if job.get("current_is_map") else job["current"],
                                 noise=job.get("noise", 0.0))
        except (ValueError, ArithmeticError) as exc:  # MargCalError is a ValueError, as is LinAlgError
            job["runaway"] = isinstance(exc, RunawayError)
            return None, f"fit failed: {exc}"
        if not reason and job.get("gyro_rows"):
            yield
        if not reason:
            cal = yield from self._full_mounting(job, cal)  # with gyro rows: the mounting, the IMU frame if asked
        if not reason and not job.get("figures_later"):
            self._full_figures(job, cal)
        return (None, reason) if reason else (cal, "")

    def _settle_figures(self) -> None:
        """The heading figures of the full fit installed last, if not computed yet (``figures_later``): on the
        same snapshot the fit saw, so they are those the installing push would have computed."""
        due, self._figures_due = self._figures_due, None
        if due is None or due[1] is not self._cal:
            return
        job, cal = due
        self._full_figures(job, cal)
        got = job.get("figures")
        if got is not None:
            self._figures, self._prior = got

    def _side_hint(self, job: dict[str, Any]) -> str:
        """What a refused partial fit's note adds when its readings trace a ring about the magnetometer's x or y axis
        (``observable.side_axis``) and nothing turns them (no ``up_axis``, no gyro to find the mounting): "" else."""
        if (self.sensor != "mag" or self.config.up_axis.lstrip("+") != "z" or job.get("gyro_seen")
                or job.get("mount_applied") is not None):  # (an accelerometer's poses about x are a pose set's start)
            return ""
        axis = side_axis(np.asarray(job["series"], dtype=np.float64))
        return "" if not axis else (
            f"; the readings trace a ring about the magnetometer's {axis} axis: on a vehicle, a magnetometer mounted on its "
            f"side (set {self.sensor}.up_axis={axis}); in a hand, turn it about its other axes too")

    def _fit_finish(self, job: dict[str, Any], result: tuple[Calibration | None, str]) -> list[Event]:
        """Install the fit (or report its rejection) unless the data it saw went stale meanwhile."""
        t = job["t"]
        if self._buffer is not job["buffer"] or self.changes != job["changes"] or self._cal is not job["current"]:
            log.debug("%s: fit from t=%.2f s dropped: reset, change or new calibration meanwhile", self.sensor, t)
            return []
        cal, reason = result
        self._runaways = self._runaways + 1 if job.get("runaway") else 0
        if cal is None and job.get("partial"):  # not good enough yet: keep collecting, say why
            self._partial_note = reason + self._side_hint(job)
            self._partial_close(job)
            return []
        if cal is None:
            return self._reject(t, reason)
        self._install(cal)
        self._recentred = cal if job.get("recentred") else None
        if self._recentred is not None:
            self._refresh_buffer(job["fitted_at"])
        note = self._partial_installed(job, cal)
        later = job.get("figures_later") and not job.get("partial") and "figures" not in job
        self._figures_due = (job, cal) if later else None
        self._last_full = self._signature()
        self.fits_accepted += 1
        self._last_rejection = ""
        assert cal.stats is not None
        n = len(job["fresh"]) if job.get("recentred") else len(job.get("series", job["points"]))
        msg = (f"calibrated from {n} samples: residual {pct(cal.stats.rms_relative)}, "
               f"offset {np.array2string(cal.offset, precision=4)}{job.get('note', '')}{note}")
        log.debug("%s: %s", self.sensor, msg)
        return [*self._set_state(State.CALIBRATED, t), Event(EventKind.CALIBRATED, t, self.sensor, msg, cal)]

    def _recent_points(self) -> Array:
        pts = np.array(self._recent_v, dtype=np.float64).reshape(-1, 3)
        if self._changed and self._change_onset is not None:
            pts = pts[np.asarray(self._recent_t) >= self._change_onset]
        return pts

    def _reject(self, t: float, reason: str) -> list[Event]:
        self.fits_rejected += 1
        self._last_rejection = reason
        self._last_reason = reason
        log.debug("%s: fit rejected: %s", self.sensor, reason)
        events = [Event(EventKind.REJECTED, t, self.sensor, f"fit rejected: {reason}")]
        if self._cal is None:
            events += self._set_state(State.REJECTED, t)
        elif self._changed:
            events += self._set_state(State.COLLECTING, t)
        return events
