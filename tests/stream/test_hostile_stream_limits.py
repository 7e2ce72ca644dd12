"""Hostile streams, issue 26 item 13: magnitude limits learnt in a unit without a known scale (counts).

The limits were learnt once, from the first 20 samples: a sensor that read ~2 counts before it was configured,
then ~640, had every real reading dropped for the whole recording, and the status advised an option
(``mag.max_magnitude``) that neither the replay nor the node has. Now the limits are relearnt when nearly
every sample falls outside them for a while (not while a calibration's field lies within them, nor from
samples that do not turn), with a status that says so; and a bad stretch after a good start, which the
change detector took for a sensor change, is withdrawn once the calibration explains the samples again.
Recordings of the independent generator (``tests/independent``), in counts of 0.075 µT (~640 in 48 µT).
"""

from __future__ import annotations

import margcal_independent_generator as gen  # loaded once by tests/conftest.py
import numpy as np
import pytest

from ros_margcal.model.calibration import Calibration
from ros_margcal.stream.calibrator import PipelineConfig, SensorCalibrator
from ros_margcal.stream.status import EventKind, State

LSB = 0.075e-6
"""Tesla per count: a 48 µT field reads about 640 counts."""


def _recording(seed: int) -> dict:
    return gen.generate("mag", "tumble", 60.0, 50.0, seed=seed, unit="counts", lsb=LSB)


def _unconfigured(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` readings of a sensor not yet configured: a few counts of noise about zero."""
    return np.round(rng.normal(0.0, 1.2, (n, 3)))


def _run(xyz: np.ndarray, t: np.ndarray, calibration: Calibration | None = None) -> tuple[SensorCalibrator, list]:
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", unit="counts"), calibration=calibration)
    events = []
    for ti, v in zip(t.tolist(), xyz, strict=True):
        events += cal.push(ti, v)
    return cal, events


def _first(events: list, after: float = 0.0) -> float | None:
    return next((e.t for e in events if e.kind is EventKind.CALIBRATED and e.t >= after), None)


def _offset_error(cal: SensorCalibrator, rec: dict) -> float:
    assert cal.calibration is not None
    return float(np.linalg.norm(cal.calibration.offset - rec["truth"]["offset"]) / rec["truth"]["norm"])


@pytest.mark.parametrize("seed", [0, 1])
def test_limits_learnt_from_a_bad_start_are_relearnt(seed: int) -> None:
    """20 readings of ~2 counts, then the real ones: the limits are relearnt after 2 s of drops and it calibrates
    (before: all 2980 real readings dropped, never calibrated); the status says the limits were relearnt."""
    rec = _recording(seed)
    xyz = rec["xyz"].copy()
    xyz[:20] = _unconfigured(np.random.default_rng(seed), 20)
    cal, events = _run(xyz, rec["t"])
    first = _first(events)
    assert first is not None and first < 15.0
    assert cal.state is State.CALIBRATED and _offset_error(cal, rec) < 0.01
    assert 0 < cal.dropped["magnitude"] < 150
    msg = cal.status().message
    assert "relearnt at t=" in msg and "outside the limits" in msg and "learnt before" in msg


def test_the_drops_before_the_relearning_name_no_missing_option() -> None:
    """While the real readings are dropped, the status names the learnt limit and that it will be relearnt,
    not an option the replay and the node lack (before: 'raise mag.max_magnitude')."""
    rec = _recording(0)
    xyz = rec["xyz"][:70].copy()
    xyz[:20] = _unconfigured(np.random.default_rng(0), 20)
    cal, _ = _run(xyz, rec["t"][:70])
    msg = cal.status().message
    assert "50 of 70 samples dropped" in msg and "(learnt)" in msg
    assert "max_magnitude" not in msg and "the limits are relearnt once 90% of the last 100 samples fall outside" in msg


def test_a_loaded_calibration_outside_the_limits_lets_them_be_relearnt() -> None:
    """A calibration loaded from file, then a bad start: the limits do not hold its field, so they are relearnt."""
    rec = _recording(1)
    truth = rec["truth"]
    loaded = Calibration(truth["offset"], truth["W_sym"], truth["norm"], sensor="mag", unit="counts")
    xyz = rec["xyz"].copy()
    xyz[:20] = _unconfigured(np.random.default_rng(1), 20)
    cal, _ = _run(xyz, rec["t"], calibration=loaded)
    assert cal.dropped["magnitude"] < 150 and "relearnt at t=" in cal.status().message


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_bad_stretch_after_a_good_start_passes(seed: int) -> None:
    """Calibrated, then 10 s of ~2 counts (within the learnt limits: a change while it lasts), then real readings
    again: the change is withdrawn and the calibration kept (before: 'collecting after a sensor change' to the end,
    every refit refused on its residual)."""
    rec = _recording(seed)
    xyz = rec["xyz"].copy()
    xyz[500:1000] = _unconfigured(np.random.default_rng(seed), 500)
    cal, events = _run(xyz, rec["t"])
    assert any(e.kind is EventKind.CHANGED for e in events)
    back = [e for e in events if e.kind is EventKind.CALIBRATED and "no sensor change after all" in e.message]
    assert back and back[0].t < 30.0
    assert cal.state is State.CALIBRATED and not cal.status().message.startswith("collecting")
    assert _offset_error(cal, rec) < 0.01


@pytest.mark.parametrize("start", [500, 50])
def test_a_saturated_stretch_is_dropped_not_learnt(start: int) -> None:
    """10 s of readings on the rails (32767 on every axis, beyond 20 x the learnt median), calibrated or not yet:
    dropped as magnitude, the limits not relearnt from samples that do not turn, calibrated within 60 s."""
    rec = _recording(2)
    xyz = rec["xyz"].copy()
    xyz[start:start + 500] = 32767.0
    cal, events = _run(xyz, rec["t"])
    assert cal.dropped["magnitude"] == 500 and "relearnt" not in cal.status().message
    first = _first(events, after=(start + 500) / 50.0)
    assert cal.state is State.CALIBRATED and (start == 500 or (first is not None and first < 60.0))
    assert _offset_error(cal, rec) < 0.01


def test_clean_counts_are_never_relearnt() -> None:
    """A clean recording in counts: the limits learnt from the first samples hold to the end."""
    rec = _recording(3)
    cal, _ = _run(rec["xyz"], rec["t"])
    msg = cal.status().message
    assert cal.state is State.CALIBRATED and "learnt from the first 20 samples" in msg and "relearnt" not in msg
    assert sum(cal.dropped.values()) == 0


def test_a_still_magnetometer_in_counts_claims_no_coverage_and_no_turning() -> None:
    """A still HMC5883L in raw counts (a real one: 1079 +- 1 counts, 0.13 % spread) had "38 % coverage" and "partial
    fit: the field turned through 50 % of the azimuths" beside "the sensor has not turned": its noise had been taken for
    a sphere (the direction bins centred inside it) and for a ring (config.STILL_SPREAD)."""
    rng = np.random.default_rng(71)
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", "counts"))
    for k in range(600):
        cal.push(0.1 * k, np.round(np.array([-430.0, 650.0, -750.0]) + rng.normal(scale=0.8, size=3)))
    st = cal.status()
    assert st.state is State.COLLECTING and "the sensor has not turned" in st.message, st.message
    assert "azimuths" not in st.message and "partial fit: none (the readings have not turned)" in st.message, st.message
    assert st.coverage < 0.05, (st.coverage, st.message)
