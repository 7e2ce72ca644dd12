"""Change detection of the streaming calibrator: has the sensor changed, or was the calibration only poor?

While calibrated, each sample's relative norm error under the calibration is kept for the last
``recent_samples``. When the median over the last ``change_window`` samples has stayed above
``change_threshold`` for ``change_min_duration_s``, a change is suspected (a hard-iron jump, a drift).
It is declared only against the no-change hypothesis: one calibration refitted on the buffer and the
whole recent window (``_no_change``); when that explains both within the tolerance, it is installed
instead. A declared change rebuilds the buffer from the samples since its onset, and the next validated
fit describes the new sensor. ``ChangeDetection`` is a part of ``calibrator.SensorCalibrator`` (a mixin:
it uses the calibrator's state and ``_install``, ``_set_state``).
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from ..model.calibration import Calibration
from ..model.fitting import fit
from .config import guard_rails
from .status import Event, EventKind, State, pct

__all__ = ["ChangeDetection"]

log = logging.getLogger("ros_margcal.stream.calibrator")  # one logger name for the calibrator's messages

Array = NDArray[np.float64]

_NOISE_FLOOR = 0.005
"""Smallest no-change tolerance, relative (quantisation and rounding of a very clean fit)."""


class ChangeDetection:
    """Change detection of a ``SensorCalibrator`` (see the module docstring)."""

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
        single, hypotheses = self._no_change(first_bad, med)
        if single is not None:  # one calibration explains the buffer and the window: not a change
            self._install(single)
            self.fits_accepted += 1
            self._last_rejection = ""
            msg = f"no sensor change at t={onset:.2f} s: {hypotheses}; recalibrated"
            log.info("%s: %s", self.sensor, msg)
            return [Event(EventKind.CALIBRATED, t, self.sensor, msg, single)]
        self._changed = True
        self._change_onset = onset
        self.changes += 1
        self._suspect_since = None
        pts = np.array(self._recent_v)[first_bad:]
        tt = times[first_bad:]
        self._buffer.clear()
        cal = self._cal
        self._buffer.set_center(np.zeros(3) if cal is None else cal.offset, 1.0 if cal is None else cal.raw_radius)
        for ti, p in zip(tt, pts, strict=True):
            self._buffer.push(float(ti), p)
        self._since_eval = len(self._buffer)
        self._predicted = None
        msg = (f"sensor changed at t={onset:.2f} s: median residual {pct(med)} > {pct(cfg.change_threshold)} "
               f"for {t - onset:.1f} s; {hypotheses}; recollecting")
        log.info("%s: %s", self.sensor, msg)
        self._last_reason = msg
        events = [Event(EventKind.CHANGED, t, self.sensor, msg)]
        return events + self._set_state(State.COLLECTING, t)

    def _no_change(self, first_bad: int, med: float) -> tuple[Calibration | None, str]:
        """Test a declared change against the no-change hypothesis: ``(calibration, text)`` when one explains all.

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
        post = window[first_bad:]
        old_text = f"old calibration: median {pct(med)} since the onset"
        try:
            cal = fit(np.concatenate([buf, window]), model=cfg.model, method=cfg.method, norm=cfg.reference_norm,
                      loss=cfg.loss, init="lin_auto", max_iter=cfg.max_iter, sensor=self.sensor, unit=cfg.unit)
            cal = cal.replace(stamp=self._t)
            reason = guard_rails(cal, cfg, post, None)
        except (ValueError, ArithmeticError) as exc:
            return None, f"{old_text}; one calibration for the buffer and the window could not be fitted ({exc})"

        def median(c: Calibration, pts: Array) -> float:
            return float(np.median(np.abs(c.norm_error(pts)) / c.norm)) if len(pts) else 0.0

        single_post, single_buf, old_buf = median(cal, post), median(cal, buf), median(old, buf)
        tol = min(cfg.change_threshold, max(2.0 * old_buf, _NOISE_FLOOR))
        text = (f"{old_text}, {pct(old_buf)} on the buffer; one calibration refitted on the {len(buf)} buffered and "
                f"{len(window)} recent samples: median {pct(single_post)} since the onset, {pct(single_buf)} on the "
                f"buffer (tolerance {pct(tol)}: twice the old calibration's on the buffer)")
        if reason:
            return None, f"{text}, refused: {reason}"
        if single_post <= tol and single_buf <= tol:
            return cal, text
        return None, text
