"""Hostile streams, issue 26 item 10: a slow hard-iron drift is followed.

0.05 field norms a minute from t = 60 s on a 300 s tumble: the buffer kept minutes of samples, so each recheck's
refit described their mean offset and the published calibrations fell behind (max norm error against the truth
in force 12-18 % by the end), each passing the guard rails. A stale calibration is now re-centred on the samples
since its fit (``change.ChangeDetection``): no published calibration after the drift starts is off by 5 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from ros_margcal.model.calibration import Calibration
from ros_margcal.sim import simulation as sim
from ros_margcal.sim.motion import OffsetDrift
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.status import EventKind

_U = np.random.default_rng(0).normal(size=(2000, 3))
DIRECTIONS = _U / np.linalg.norm(_U, axis=1, keepdims=True)
"""Field directions over the whole sphere, for the norm error of a calibration."""


def _norm_error(cal: Calibration, truth: Calibration, offset: np.ndarray) -> float:
    """Largest relative norm error of ``cal`` over all field directions, the true offset being ``offset``."""
    raw = offset + np.linalg.solve(truth.matrix, (DIRECTIONS * truth.norm).T).T
    return float(np.max(np.abs(np.linalg.norm(cal.apply(raw), axis=1) / cal.norm - 1.0)))


def _drifting(seed: int, stop: float | None = None) -> sim.Recording:
    truth = sim.random_sensor(np.random.default_rng(seed), "mag")
    d = np.random.default_rng(seed + 100).normal(size=3)
    rate = tuple((d / np.linalg.norm(d) * 0.05 * truth.norm / 60.0).tolist())
    events = [OffsetDrift(rate=rate, start=60.0)]
    if stop is not None:
        events.append(OffsetDrift(rate=tuple(-r for r in rate), start=stop))
    return sim.magnetometer_stream(truth, 300.0, 50.0, np.random.default_rng(seed + 1), motion="tumble", events=events)


def _published(rec: sim.Recording) -> tuple[list[tuple[float, float, str]], SensorCalibrator]:
    cal = SensorCalibrator("mag")
    offsets = np.broadcast_to(rec.truth.offset, rec.raw.shape) if rec.true_offset is None else rec.true_offset
    out = []
    for k, (t, v) in enumerate(zip(rec.t.tolist(), rec.raw, strict=True)):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED:
                out.append((t, _norm_error(e.calibration, rec.truth, offsets[k]), e.message))
    return out, cal


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_slow_hard_iron_drift_is_followed(seed: int) -> None:
    """Every calibration published after the drift starts is within 5 % (before: up to 14-18 %), and re-centring
    published some of them."""
    rows, cal = _published(_drifting(seed))
    after = [(t, err) for t, err, _ in rows if t >= 60.0]
    assert len(after) >= 4
    assert max(err for _, err in after) < 0.05, after
    assert any("re-centred" in m for _, _, m in rows) and cal.changes == 0


def test_a_drift_that_stops_leaves_an_accurate_calibration() -> None:
    """The drift stops at 180 s: the calibrations stay within 5 % and the last one fits the sensor as it is now."""
    rec = _drifting(1, stop=180.0)
    rows, cal = _published(rec)
    assert max(err for t, err, _ in rows if t >= 60.0) < 0.05
    assert cal.calibration is not None
    assert _norm_error(cal.calibration, rec.truth, rec.true_offset[-1]) < 0.02


def test_a_sensor_that_does_not_drift_is_never_re_centred() -> None:
    """A clean 300 s tumble: the rechecks refit as before, none is a re-centring, the last is within 1 %."""
    truth = sim.random_sensor(np.random.default_rng(4), "mag")
    rec = sim.magnetometer_stream(truth, 300.0, 50.0, np.random.default_rng(5), motion="tumble")
    rows, cal = _published(rec)
    assert len(rows) >= 4 and not any("re-centred" in m for _, _, m in rows)
    assert cal.calibration is not None and _norm_error(cal.calibration, truth, truth.offset) < 0.01
