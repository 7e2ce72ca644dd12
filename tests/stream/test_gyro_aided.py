"""The magnetometer calibrator with a gyro rate pushed with each sample (``gyro_aided``), on a ground robot of
the independent generator (tests/independent: no code shared with the package). Figures over many seeds:
``scripts/bench_ground_robot.py --gyro``."""

from __future__ import annotations

import math
import re
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator

GEN: ModuleType = INDEPENDENT


def _feed(cal: SensorCalibrator, rec: dict[str, Any], gyro: np.ndarray | None) -> list[Any]:
    out = []
    rates = [None] * len(rec["t"]) if gyro is None else gyro.tolist()
    for t, v, g in zip(rec["t"].tolist(), rec["xyz"].tolist(), rates, strict=True):
        out += [e for e in cal.push(t, v, g) if e.kind is EventKind.CALIBRATED]
    return out


@pytest.fixture(scope="module")
def ring() -> dict[str, Any]:
    return GEN.generate("mag", "ground", duration_s=150.0, rate_hz=50.0, seed=22, tilt_deg=5.0,
                        symmetric_soft_iron=True, hard_iron_mag=30e-6)


@pytest.fixture(scope="module")
def alone(ring: dict[str, Any]) -> tuple[SensorCalibrator, list[Any]]:
    cal = SensorCalibrator("mag")
    return cal, _feed(cal, ring, None)


def _p95(rec: dict[str, Any], c: Any, tilt: float) -> float:
    return float(GEN.heading_p95(c.matrix, c.offset, rec["truth"], tilt_deg=tilt))


def test_with_a_gyro_a_ring_determines_every_parameter(ring: dict[str, Any], alone: tuple[SensorCalibrator, list[Any]]) -> None:
    cal = SensorCalibrator("mag")
    events = _feed(cal, ring, ring["gyro"])
    st = cal.status()
    assert events and st.gyro_explained is not None and st.gyro_explained > 0.99, st.message
    assert "w_zz" in st.updated_parameters and st.prior_parameters == (), st.message
    assert "gyro-aided" in st.message
    ref = alone[0].status()
    assert "w_zz" in ref.prior_parameters and ref.gyro_explained is None and "gyro" not in ref.message
    c, c0 = cal.calibration, alone[0].calibration
    assert _p95(ring, c, 30.0) < 0.3 * _p95(ring, c0, 30.0)
    assert _p95(ring, c, 0.0) < 0.5
    # the predicted figures follow: the 30 deg one is the data's now, not the broad prior's
    assert st.heading_p95_tilt30_deg is not None and ref.heading_p95_tilt30_deg is not None
    # predicted too (the offset's slow noise, model.heading.with_offset_noise, adds the same to both: 0.31 here)
    assert st.heading_p95_tilt30_deg < 0.4 * ref.heading_p95_tilt30_deg
    assert 0.5 < st.heading_p95_tilt30_deg / _p95(ring, c, 30.0) < 4.0


@pytest.mark.parametrize("how", ["axes swapped", "x/y swapped", "deg/s", "converted twice"])
def test_a_gyro_in_another_frame_changes_nothing_and_says_so(ring: dict[str, Any], alone: tuple[SensorCalibrator, list[Any]],
                                                             how: str) -> None:
    cal = SensorCalibrator("mag")
    rates = {"axes swapped": ring["gyro"][:, [1, 0, 2]] * [1.0, -1.0, 1.0], "x/y swapped": ring["gyro"][:, [1, 0, 2]],
             "deg/s": np.degrees(ring["gyro"]), "converted twice": np.radians(ring["gyro"])}[how]
    events = _feed(cal, ring, rates)
    st = cal.status()
    assert st.gyro_explained is not None
    assert "gyro not used" in st.message
    if how == "converted twice":  # a real VN-100 log's rates (fitting_gyro.UNIT_ERRORS)
        assert "57.3x larger: the rates converted from deg/s to rad/s twice?" in st.message, st.message
        own, named = map(int, re.search(r"accounts for (-?\d+) % of the field's turning as it comes, (-?\d+) % taken",
                                        st.message).groups())
        assert own < 10 and named > 90, st.message  # both without a bias fitted (a bias absorbs a constant turn rate)
    elif how != "deg/s":  # the rates' true order is named (fitting_gyro.frame_check)
        name = "(-y, x, z)" if how == "axes swapped" else "(y, x, z)"
        assert f"{name} of the IMU's axes" in st.message and "flipped or rotated" in st.message, st.message
    else:  # deg/s: no order or sign explains it, the unit does (fitting_gyro.UNIT_ERRORS), and the mounting is not judged
        assert "57.3x smaller: the rates in deg/s, not rad/s" in st.message and "mounting" not in st.message, st.message
    assert [e.t for e in events] == [e.t for e in alone[1]]
    np.testing.assert_array_equal(cal.calibration.offset, alone[0].calibration.offset)


def test_bad_rates_are_ignored_and_counted_never_the_samples(ring: dict[str, Any],
                                                             alone: tuple[SensorCalibrator, list[Any]]) -> None:
    rates = ring["gyro"].copy()
    rates[::197] = np.nan  # sparse: a block holding one is dropped (1 s blocks: about half of them here)
    rates[3::211] = 1e9
    cal = SensorCalibrator("mag")
    events = _feed(cal, ring, rates)
    st = cal.status()
    bad = int(np.sum(~np.isfinite(rates).all(axis=1) | (np.linalg.norm(np.nan_to_num(rates, nan=0.0), axis=1) > 100)))
    assert st.gyro_ignored == bad and st.samples_passed == alone[0].status().samples_passed
    assert f"{bad} of {st.samples_seen} samples' gyro rates ignored" in st.message, st.message
    assert events and st.gyro_explained is not None and st.gyro_explained > 0.99  # the blocks without a gap remain


def test_gyro_aided_off_is_the_magnetometer_alone(ring: dict[str, Any], alone: tuple[SensorCalibrator, list[Any]]) -> None:
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", gyro_aided=False))
    events = _feed(cal, ring, ring["gyro"])
    assert cal.status().gyro_explained is None and cal.status().gyro_ignored == 0
    assert [e.t for e in events] == [e.t for e in alone[1]]


def test_a_restarted_time_base_empties_the_rates() -> None:
    cal = SensorCalibrator("mag")
    for k in range(200):
        cal.push(100.0 + 0.02 * k, [20e-6, 0.0, 40e-6], [0.0, 0.0, 0.1])
    assert len(cal._gyro_buf) == 200
    for k in range(20):  # stamps restart near zero and go on
        cal.push(0.02 * k, [20e-6, 0.0, 40e-6], [0.0, 0.0, 0.1])
    assert cal.status().time_base_resets == 1
    assert 0 < len(cal._gyro_buf) <= 20
    assert math.isfinite(cal._gyro_buf[-1][0])


def test_a_bag_replay_pairs_each_magnetometer_message_with_the_imu_rate(ring: dict[str, Any], tmp_path: Any) -> None:
    """As the node does: a MagneticField message takes the latest Imu rate of the same frame within 20 ms."""
    from ros_margcal.recordings.bag import write_bag
    from ros_margcal.recordings.recording import Recording
    from ros_margcal.stream.replay import replay

    t = ring["t"][:4000]
    mag = Recording(t=t, raw=ring["xyz"][:4000], sensor="mag", unit="T")
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1)) + np.random.default_rng(4).normal(0.0, 0.02, (len(t), 3))
    imu = Recording(t=t + 0.005, raw=acc, gyro=ring["gyro"][:4000], sensor="accel", unit="m/s^2")
    bag = write_bag(tmp_path / "ring.mcap", {"imu/mag": mag, "imu/data_raw": imu})
    out = replay(bag, progress=False, status_every=0.0)
    st = out["calibrators"]["mag"].status()
    assert st.samples_passed == 4000 and st.gyro_ignored == 0
    assert st.gyro_explained is not None and st.gyro_explained > 0.99, st.message


def test_a_magnetometer_turned_against_the_imu_is_pulled_toward_its_frame() -> None:
    """Magnetometer axes 2 deg off the IMU's (the generator's misalignment effect; tilt compensation uses
    the IMU's attitude): a symmetric calibration cannot undo a rotation, and the magnetometer alone keeps it;
    the gyro pulls the calibration toward the IMU's frame as far as a symmetric matrix can, so the heading
    is no worse than the best a symmetric calibration can reach (the generator's floor), and better than alone."""
    rec = GEN.generate("mag", "ground", duration_s=150.0, rate_hz=50.0, seed=22, tilt_deg=5.0, symmetric_soft_iron=True,
                       hard_iron_mag=30e-6, effect="misalignment", magnitude=2.0)
    floor = rec["truth"]["heading_floor_deg"]["level"]
    alone, aided = SensorCalibrator("mag"), SensorCalibrator("mag")
    _feed(alone, rec, None)
    _feed(aided, rec, rec["gyro"])
    assert aided.status().gyro_explained is not None and aided.status().gyro_explained > 0.99
    level_aided, level_alone = _p95(rec, aided.calibration, 0.0), _p95(rec, alone.calibration, 0.0)
    assert level_aided < level_alone
    assert level_aided < 1.2 * floor


def test_a_gyro_with_scale_errors_keeps_the_level_heading_and_an_honest_tilted_figure(ring: dict[str, Any]) -> None:
    """An uncalibrated MEMS gyro reads 1-3 % off: the yaw axis's error is fitted (the turns fix it) and the
    others' is in the prior (``gyro_scale_std``), so the level heading stays good and the 30 deg prediction
    covers what that error does."""
    cal = SensorCalibrator("mag")
    _feed(cal, ring, ring["gyro"] * [1.03, 0.97, 1.03])
    st = cal.status()
    assert st.gyro_explained is not None and st.gyro_explained > 0.99
    assert _p95(ring, cal.calibration, 0.0) < 0.5
    assert st.heading_p95_tilt30_deg is not None and _p95(ring, cal.calibration, 30.0) < 2.0 * st.heading_p95_tilt30_deg


def test_too_few_rates_are_said_not_used(ring: dict[str, Any], alone: tuple[SensorCalibrator, list[Any]]) -> None:
    """An IMU slower than the magnetometer (a rate on one sample in five): no complete block, the status says why."""
    rates: list[Any] = [g if k % 5 == 0 else None for k, g in enumerate(ring["gyro"].tolist())]
    cal = SensorCalibrator("mag")
    events = []
    for t, v, g in zip(ring["t"].tolist(), ring["xyz"].tolist(), rates, strict=True):
        events += [e for e in cal.push(t, v, g) if e.kind is EventKind.CALIBRATED]
    st = cal.status()
    assert st.gyro_explained is None and "gyro not used: fewer than 20 blocks" in st.message, st.message
    assert "samples without one: an Imu message within 20 ms" in st.message, st.message
    assert [e.t for e in events] == [e.t for e in alone[1]]


def test_a_short_recording_with_a_rate_on_every_sample_is_not_asked_about_its_imu_messages(ring: dict[str, Any]) -> None:
    """17 s of a ring with a rate on every row (a real Roomba's 27 s CSV was asked to pair its Imu messages): the
    status says how long the rates go, not that the messages are unpaired."""
    short = {k: ring[k][: 17 * 50] for k in ("t", "xyz", "gyro")}
    cal = SensorCalibrator("mag")
    _feed(cal, short, short["gyro"])
    st = cal.status()
    assert "gyro not used: fewer than 20 blocks of 1 s with a rate on every sample (rates over" in st.message, st.message
    assert "Imu message" not in st.message, st.message


def test_a_sparse_log_that_the_gyro_does_not_explain_says_how_far_apart_its_samples_are() -> None:
    """Samples 0.5 s apart: "gyro not used" names the spacing before the frames (a real 1.9 Hz log of fast turns
    explained -12 %); at 50 Hz it asks about the frames alone."""
    rec = GEN.generate("mag", "ground", duration_s=150.0, rate_hz=50.0, seed=22, tilt_deg=5.0,
                       symmetric_soft_iron=True, hard_iron_mag=30e-6)
    sparse = {k: rec[k][::25] for k in ("t", "xyz", "gyro")}
    cal = SensorCalibrator("mag")
    shuffled = sparse["gyro"][np.random.default_rng(4).permutation(len(sparse["gyro"]))]
    _feed(cal, sparse, shuffled)  # rates no axis order or unit explains: another sample's
    st = cal.status()
    assert st.gyro_explained is not None and "gyro not used" in st.message, st.message
    assert "samples 0.5 s apart" in st.message and "one frame" in st.message, st.message
    cal = SensorCalibrator("mag")
    _feed(cal, sparse, sparse["gyro"])  # a smooth yaw at 2 Hz: still explained
    assert cal.status().gyro_explained > 0.95


def test_a_gyro_that_explains_most_of_a_disturbed_ring_is_not_asked_about_its_frame() -> None:
    """A ring whose field wanders by 3 uT along the path (iron near the route): its right rates explain 89-90 % of the
    turning, under the 90 % a gyro needs; the status names the field first, not the frames (``MOST_EXPLAINED``)."""
    rec = GEN.generate("mag", "ground", duration_s=120.0, rate_hz=40.0, seed=1, tilt_deg=1.0, symmetric_soft_iron=True,
                       hard_iron_mag=30e-6)
    rng = np.random.default_rng(1)
    wander = np.stack([np.convolve(rng.normal(size=len(rec["t"])), np.ones(200) / 200, mode="same") for _ in range(3)], 1)
    xyz = np.asarray(rec["xyz"], dtype=np.float64) + 3e-6 * wander / wander.std(axis=0)
    cal = SensorCalibrator("mag")
    _feed(cal, {"t": rec["t"], "xyz": xyz}, rec["gyro"])
    st = cal.status()
    assert st.gyro_explained is not None and 0.7 <= st.gyro_explained < 0.9, st.message
    assert "gyro not used" in st.message and "a field that changes along the path" in st.message, st.message
    assert "are the IMU and magnetometer in one frame" not in st.message


def test_rates_in_raw_counts_are_named_in_the_status(ring: dict[str, Any]) -> None:
    """A real log's gyro columns in raw counts (mgiurato/IMU-Calibration: a static bias of ~500 counts): every rate is
    above any gyro's range and ignored; the status says so and why, not only the count in its values."""
    cal = SensorCalibrator("mag")
    _feed(cal, ring, ring["gyro"] / 1e-3 + 500.0)  # 1 mrad/s a count, a bias of 500 counts
    st = cal.status()
    assert st.gyro_ignored == len(ring["t"]), st.gyro_ignored
    assert "gyro rates ignored" in st.message and "raw counts need the gyro's scale" in st.message, st.message
    assert "gyro rates ignored" not in SensorCalibrator("mag").status().message
