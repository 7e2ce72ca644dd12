"""Recordings as real loggers write them: raw counts, a large hard iron, a status that says why.

Made by the independent generator (``tests/independent``), which shares no code with the package;
the real recordings of ``../shared/data/real`` are used where present (skipped cleanly otherwise).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from ros_margcal.model.calibration import Calibration
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.config import PipelineConfig, guard_rails
from ros_margcal.stream.replay import replay
from ros_margcal.stream.status import EventKind, State
from ros_margcal.stream.units import LEARN_SAMPLES, unit_scale

LARGE_HARD_IRON_UT = [150.0, -160.0, 60.0]  # 228 µT in a 39 µT field: the phone-style recording of the issue


def _run(rec: dict, unit: str, **overrides: object) -> tuple[SensorCalibrator, list]:
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", unit, **overrides))
    events = []
    for t, v in zip(rec["t"], rec["xyz"], strict=True):
        events += cal.push(float(t), v)
    return cal, events


def _offset_error(cal: SensorCalibrator, rec: dict) -> float:
    assert cal.calibration is not None
    truth = rec["truth"]
    return float(np.linalg.norm(cal.calibration.offset - truth["offset"]) / truth["norm"])


def test_units_known_and_unknown() -> None:
    """Known units scale (also case-insensitively); counts and friends have no scale."""
    assert unit_scale("mag", "uT") == 1e-6
    assert unit_scale("mag", "Gauss") == 1e-4
    assert unit_scale("accel", "G") == pytest.approx(9.80665)
    assert unit_scale("mag", "counts") is None
    cfg = PipelineConfig.for_sensor("mag", "counts")
    assert cfg.learn_magnitude_samples == LEARN_SAMPLES and cfg.norm_max == np.inf and cfg.max_offset is None
    assert PipelineConfig.for_sensor("mag", "counts", max_magnitude=2000.0).learn_magnitude_samples == 0
    assert PipelineConfig.for_sensor("mag", "uT").max_offset == pytest.approx(1000.0)
    assert PipelineConfig.for_sensor("accel", "counts").reference_norm is None


def test_a_recording_in_counts_calibrates(independent: ModuleType) -> None:
    """Integer counts (about 440 per field) calibrate with --unit counts; the status says how the limits were learnt."""
    rec = independent.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=5, unit="counts")
    assert np.all(rec["xyz"] == np.round(rec["xyz"])) and rec["truth"]["norm"] > 300
    cal, _ = _run(rec, "counts")
    assert cal.state is State.CALIBRATED
    assert _offset_error(cal, rec) < 0.01
    assert cal.dropped["magnitude"] == 0
    msg = cal.status().message
    assert "unit 'counts' has no known scale" in msg and "learnt from the first 20 samples" in msg


def test_counts_read_as_tesla_say_why_every_sample_is_dropped(independent: ModuleType) -> None:
    """The same counts under the default unit T: every sample dropped, the status names |v|, the limit and the hint."""
    rec = independent.generate("mag", "tumble", duration_s=10.0, rate_hz=50.0, seed=5, unit="counts")
    cal, _ = _run(rec, "T")
    st = cal.status()
    n = len(rec["t"])
    assert st.samples_passed == 0 and st.dropped == {"magnitude": n}
    last = float(np.linalg.norm(rec["xyz"][-1]))
    assert f"{n} of {n} samples dropped" in st.message
    assert f"last |v| = {last:.4g} > 0.0014 T" in st.message
    assert "--unit" in st.message and "mag.unit in the node" in st.message and "mag.max_magnitude" in st.message


def test_a_large_hard_iron_calibrates_and_the_old_limit_names_the_offset(independent: ModuleType) -> None:
    """228 µT of hard iron in a 39 µT field (5.8 field norms): within the 1 mT default; a 5-norm limit names the offset."""
    rec = independent.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=5, unit="uT",
                               hard_iron=LARGE_HARD_IRON_UT, field_uT=39.0)
    cal, _ = _run(rec, "uT")
    assert cal.state is State.CALIBRATED and _offset_error(cal, rec) < 0.01
    old, events = _run(rec, "uT", max_offset=None)
    assert old.calibration is None
    rejected = [e.message for e in events if e.kind is EventKind.REJECTED]
    assert rejected and all("offset 2" in m and "field norms) > limit" in m and "fitted [" in m for m in rejected)


def test_a_large_hard_iron_in_counts_calibrates(independent: ModuleType) -> None:
    """Counts and a large hard iron together: 20 field norms is the offset limit without a known unit."""
    rec = independent.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=6, unit="counts",
                               hard_iron=LARGE_HARD_IRON_UT, field_uT=39.0)
    cal, _ = _run(rec, "counts")
    assert cal.state is State.CALIBRATED and _offset_error(cal, rec) < 0.01


def test_the_offset_guard_rail_takes_the_larger_limit() -> None:
    """max(max_offset_ratio x norm, max_offset): 8 norms pass under 1 mT, 30 norms do not."""
    cfg = PipelineConfig.for_sensor("mag")
    base = Calibration(np.zeros(3), np.eye(3), 50e-6, sensor="mag", unit="T")
    assert guard_rails(base.replace(offset=np.array([4e-4, 0.0, 0.0])), cfg, np.empty((0, 3)), None) == ""
    msg = guard_rails(base.replace(offset=np.array([1.5e-3, 0.0, 0.0])), cfg, np.empty((0, 3)), None)
    assert "offset 0.0015 T" in msg and "30 field norms" in msg and "max_offset" in msg


def test_the_accelerometer_gate_status_counts_what_reached_it() -> None:
    """No still window yet: the status says how many samples reached the gate and what it waits for."""
    cal = SensorCalibrator("accel")
    rng = np.random.default_rng(3)
    for k in range(300):
        cal.push(0.01 * k, np.array([0.0, 0.0, 9.8]) + rng.normal(0.0, 1.0, 3))  # shaking: never still
    msg = cal.status().message
    assert "no still sample from the inactivity gate yet: 300 samples reached it" in msg


MAG_FILES = {  # file -> raw unit (README of the real recordings)
    "fhoevi_full_sphere_mag.csv": "counts",
    "sunsided_hmc5883l_full_sphere_mag.csv": "gauss",
    "ck_lsm9ds1_full_sphere_mag.csv": "gauss",
}


@pytest.mark.parametrize("name", sorted(MAG_FILES))
def test_real_full_sphere_recordings_calibrate_in_their_unit(real_recording: Callable[[str], Path], name: str) -> None:
    """Real full-sphere recordings calibrate when replayed in their own unit (counts included)."""
    path = real_recording(name)
    out = replay(path, sensor="mag", unit=MAG_FILES[name], status_every=0.0, progress=False)
    cal = out["calibrators"]["mag"]
    assert cal.state is State.CALIBRATED, cal.status().message
    assert cal.dropped["magnitude"] == 0


def test_real_counts_read_as_tesla_say_why(real_recording: Callable[[str], Path]) -> None:
    """The counts logger replayed without --unit: every sample dropped, and the status says |v|, limit, hint."""
    path = real_recording("fhoevi_full_sphere_mag.csv")
    out = replay(path, sensor="mag", status_every=0.0, progress=False)
    st = out["calibrators"]["mag"].status()
    assert st.samples_passed == 0
    assert f"{st.samples_seen} of {st.samples_seen} samples dropped" in st.message and "set the raw unit" in st.message


# -- a change must be a change ----------------------------------------------------------------------


def test_a_calibration_poor_in_unseen_directions_is_not_a_change(independent: ModuleType) -> None:
    """A loaded calibration 0.15 field norms off in z: the residual rises as new directions come, but one
    refitted calibration explains buffer and window, so no change is declared and the fit is replaced."""
    rec = independent.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=21)
    truth = rec["truth"]
    stale = Calibration(truth["offset"] + np.array([0.0, 0.0, 0.15]) * truth["norm"], truth["W_sym"], truth["norm"],
                        model="sym", sensor="mag", unit="T")
    cal = SensorCalibrator("mag", calibration=stale)
    events = []
    for t, v in zip(rec["t"], rec["xyz"], strict=True):
        events += cal.push(float(t), v)
    assert cal.changes == 0 and not [e for e in events if e.kind is EventKind.CHANGED]
    verdicts = [e.message for e in events if e.kind is EventKind.CALIBRATED and "no sensor change" in e.message]
    assert len(verdicts) == 1
    assert "old calibration: median" in verdicts[0] and "one calibration refitted" in verdicts[0]
    assert _offset_error(cal, rec) < 0.005


def test_the_calibration_refitted_for_no_change_has_its_own_heading_figures(independent: ModuleType) -> None:
    """The calibration "no sensor change" installs is a new fit: the status's heading figures are its own, computed
    on the samples it was fitted on, not those of the calibration it replaced (they were, once)."""
    rec = independent.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=21)
    truth = rec["truth"]
    stale = Calibration(truth["offset"] + np.array([0.0, 0.0, 0.15]) * truth["norm"], truth["W_sym"], truth["norm"],
                        model="sym", sensor="mag", unit="T")
    cal = SensorCalibrator("mag", calibration=stale)
    before = after = None
    for t, v in zip(rec["t"], rec["xyz"], strict=True):
        figures = cal.status().heading_p95_level_deg
        if any(e.kind is EventKind.CALIBRATED and "no sensor change" in e.message for e in cal.push(float(t), v)):
            before, after = figures, cal.status()
            break
    assert after is not None
    assert after.heading_p95_level_deg is not None and after.heading_p95_level_deg != before
    assert 0.0 < after.heading_p95_level_deg < 2.0 and after.heading_p95_tilt30_deg is not None


def test_a_real_hard_iron_step_is_still_a_change_and_says_both_hypotheses(independent: ModuleType) -> None:
    """A hard-iron step of 0.15 field norms: one calibration leaves several times the noise, so it is a change;
    the event names both hypotheses and the next calibration describes the new offset."""
    rec = independent.generate("mag", "tumble", duration_s=120.0, rate_hz=50.0, seed=21, effect="hard_iron_jump",
                               magnitude=0.15)
    cal = SensorCalibrator("mag")
    events = []
    for t, v in zip(rec["t"], rec["xyz"], strict=True):
        events += cal.push(float(t), v)
    changed = [e.message for e in events if e.kind is EventKind.CHANGED]
    assert cal.changes == 1 and len(changed) == 1
    assert "old calibration: median" in changed[0] and "one calibration refitted" in changed[0]
    assert "tolerance" in changed[0]
    assert cal.calibration is not None
    truth = rec["truth"]
    assert np.linalg.norm(cal.calibration.offset - truth["offset_after"]) < 0.01 * truth["norm"]


def test_a_static_magnetometer_says_it_has_not_turned(independent: ModuleType) -> None:
    """A sensor at rest: the status says the samples fix the norm only, instead of a coverage figure alone."""
    rec = independent.generate("mag", "static", duration_s=30.0, rate_hz=50.0, seed=4)
    cal, _ = _run(rec, "T")
    msg = cal.status().message
    assert cal.calibration is None
    assert "the sensor has not turned: the last 500 samples stay within" in msg and "field norm only" in msg
    assert cal.coverage < 0.05, (cal.coverage, msg)  # the noise about one reading is no sphere (it was 100 %)


def test_a_sensor_still_after_a_change_is_not_covered(independent: ModuleType) -> None:
    """A tumble, then (another offset: a sensor change) the sensor at rest: the direction bins are not centred on
    the noise of the still readings (a BROAD recording with its magnet showed "100 % coverage"), and the status
    says the sensor has not turned."""
    moving = independent.generate("mag", "tumble", duration_s=60.0, rate_hz=50.0, seed=31)
    jumped = np.asarray(moving["truth"]["offset"]) * 1e6 + [20.0, -10.0, 10.0]  # µT: 24.5 µT off, half the field
    still = independent.generate("mag", "static", duration_s=40.0, rate_hz=50.0, seed=32, hard_iron=jumped)
    cal = SensorCalibrator("mag")
    for t, v in zip(moving["t"], moving["xyz"], strict=True):
        cal.push(float(t), v)
    assert cal.calibration is not None
    for t, v in zip(still["t"], still["xyz"], strict=True):
        cal.push(60.0 + float(t), v)
    msg = cal.status().message
    assert cal.changes == 1, msg
    assert cal.coverage < 0.05, (cal.coverage, msg)
    assert "the sensor has not turned" in msg


def test_real_still_sensor_after_a_magnet_is_not_called_covered(real_recording: Callable[[str], Path]) -> None:
    """BROAD's magnet at 5 cm (a sensor change at ~132 s) then little turning: the direction bins are not centred on
    the still readings' noise (it read "100.0 % coverage, predicted error 57.8 %: turn the sensor through the
    directions not yet covered"); the status says the sensor has not turned."""
    out = replay(real_recording("broad_36_disturbed_attached_magnet_5cm_mag.csv"), sensor="mag", unit="uT",
                 status_every=0.0, progress=False)
    cal = out["calibrators"]["mag"]
    msg = cal.status().message
    assert cal.changes == 1 and cal.coverage < 0.2, (cal.coverage, msg)
    assert "100.0 % coverage" not in msg and "the sensor has not turned" in msg
