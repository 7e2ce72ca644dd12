"""Fits in steps (``stream.evaluation``, ``model.steps``): no single push runs a whole partial fit.

Inline, a fit runs one step a push: a Levenberg-Marquardt solve, half a noise model, one mounting refinement. Before,
a ground robot's partial fit with the gyro ran its solves, its noise model and its mounting estimate in one push (up
to 84 ms in ``scripts/bench_speed.py``). The calibrations are those of a whole fit (deferred mode runs fits whole:
``test_cost.py::test_deferred_mode_gives_the_inline_calibrations``). The independent generator's ground robot, seeded.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

import ros_margcal.model.fitting_noise as noise_module
import ros_margcal.model.fitting_prior as prior_module
import ros_margcal.model.mounting as mounting_module
from ros_margcal.model.steps import drained
from ros_margcal.stream.calibrator import EventKind, SensorCalibrator


@pytest.fixture(scope="module")
def ring() -> dict[str, Any]:
    return INDEPENDENT.generate("mag", "ground", duration_s=120.0, rate_hz=50.0, seed=23, tilt_deg=5.0,
                                symmetric_soft_iron=True, hard_iron_mag=30e-6)


def _count(monkeypatch: pytest.MonkeyPatch, module: Any, name: str, counter: Counter[str]) -> None:
    real = getattr(module, name)

    def counted(*args: Any, **kwargs: Any) -> Any:
        counter[name] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)


def test_no_push_runs_two_solves_or_a_solve_and_a_mounting(ring: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    work: Counter[str] = Counter()
    _count(monkeypatch, prior_module, "_lm", work)  # a MAP solve
    _count(monkeypatch, noise_module, "Absorbed", work)  # a noise model with the absorbed share
    _count(monkeypatch, mounting_module, "_refine", work)  # one rotation of a mounting estimate
    cal = SensorCalibrator("mag")
    per_push: list[Counter[str]] = []
    published = 0
    for t, v, g in zip(ring["t"].tolist(), ring["xyz"], ring["gyro"], strict=True):
        work.clear()
        published += sum(e.kind is EventKind.CALIBRATED for e in cal.push(t, v, g))
        per_push.append(Counter(work))
    assert published >= 1 and cal.status().gyro_explained is not None
    assert sum(c["_lm"] for c in per_push) > 20 and sum(c["_refine"] for c in per_push) > 2  # the work was done
    assert max(c["_lm"] for c in per_push) == 1
    assert max(c["_refine"] for c in per_push) == 1
    assert not any(c["_lm"] and (c["_refine"] or c["Absorbed"]) for c in per_push)


def test_a_forced_refit_replaces_a_fit_in_progress(ring: dict[str, Any]) -> None:
    cal = SensorCalibrator("mag")
    for t, v, g in zip(ring["t"].tolist(), ring["xyz"], ring["gyro"], strict=True):
        cal.push(t, v, g)
        if cal._sliced is not None and t > 30.0:
            break
    assert cal._sliced is not None
    cal.refit()
    assert cal._sliced is None  # run whole, now; the one in progress (older data) dropped


def test_finish_fit_ends_the_fit_in_progress_as_its_steps_would(ring: dict[str, Any]) -> None:
    """At a recording's end (replay) the fit in progress runs to its end: the same events as stepping it out."""
    a, b = SensorCalibrator("mag"), SensorCalibrator("mag")
    for t, v, g in zip(ring["t"].tolist(), ring["xyz"], ring["gyro"], strict=True):
        a.push(t, v, g)
        b.push(t, v, g)
        if a._sliced is not None and t > 40.0:
            break
    flushed = a.finish_fit()
    assert a._sliced is None and a.finish_fit() == []
    stepped = []
    for _ in range(1000):
        if b._sliced is None:
            break
        stepped += b._fit_step()
    assert [(e.kind, e.t, e.message) for e in flushed] == [(e.kind, e.t, e.message) for e in stepped]


def test_drained_runs_the_steps_and_returns_the_result() -> None:
    def steps() -> Any:
        yield
        yield
        return np.pi

    assert drained(steps()) == np.pi
