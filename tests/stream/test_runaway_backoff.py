"""A full fit that runs away is retried ever more rarely (``Evaluation.RUNAWAY_MAX_WAIT_S``), counted, never timed.

A real QMC5883L (2.6 % noise, the validator satisfied by half the sphere) ran away at every 1 s evaluation for 44 s,
~15 ms a fit: 57 us a sample over its 455 s, now 34. Here the fit is made to run away for the first 40 s of an
independent tumble, then to work: far fewer attempts, and a calibration within the back-off's wait once it works.
"""

from __future__ import annotations

import itertools
from typing import Any

import margcal_independent_generator as gen  # loaded once by tests/conftest.py
import pytest

import ros_margcal.stream.evaluation as evaluation
from ros_margcal.model.errors import RunawayError
from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator

BROKEN_UNTIL_S = 40.0


def _run(monkeypatch: pytest.MonkeyPatch) -> tuple[list[float], list[float]]:
    """The stamps of the full fits tried and of the calibrations published."""
    rec = gen.generate("mag", motion="tumble", duration_s=70.0, rate_hz=50.0, seed=7, hard_iron_mag=30e-6)
    real_fit = evaluation.fit
    now = {"t": 0.0}
    tried: list[float] = []

    def fit(*args: Any, **kwargs: Any) -> Any:
        tried.append(now["t"])
        if now["t"] < BROKEN_UNTIL_S:
            raise RunawayError("lm did not converge: it ran away to no sensor's ellipsoid (axes 20 times apart)")
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(evaluation, "fit", fit)
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", early_fit=False, partial_fit=False))
    published = []
    for t, v in zip(rec["t"].tolist(), rec["xyz"].tolist(), strict=True):
        now["t"] = t
        published += [e.t for e in cal.push(t, v, None) if e.kind is EventKind.CALIBRATED]
    return tried, published


def test_a_fit_that_keeps_running_away_is_retried_ever_more_rarely(monkeypatch: pytest.MonkeyPatch) -> None:
    tried, published = _run(monkeypatch)
    broken = [t for t in tried if t < BROKEN_UNTIL_S]
    assert len(broken) >= 3, tried
    gaps = [b - a for a, b in itertools.pairwise(broken)]
    assert max(gaps) <= evaluation.Evaluation.RUNAWAY_MAX_WAIT_S + 1.5, gaps  # retried, at most the longest wait apart
    # at the 1 s cadence they were one a second from the first: 1 + 2 + 4 + 8 + 8 ... s apart now
    assert len(broken) <= (BROKEN_UNTIL_S - broken[0]) / 4.0, broken
    assert published, tried
    assert published[0] - BROKEN_UNTIL_S <= evaluation.Evaluation.RUNAWAY_MAX_WAIT_S + 2.0, (published, tried)
