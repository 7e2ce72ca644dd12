"""Hostile input to SensorCalibrator.push: it never raises, counts every sample once, survives stamp
glitches and clock restarts, ignores a broken gyro, and calibrates on good data afterwards."""

from __future__ import annotations

import math
from collections.abc import Iterator
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from ros_margcal.model.calibration import Calibration
from ros_margcal.sim import simulation as sim
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.config import PipelineConfig
from ros_margcal.stream.intake import MAX_GYRO_RAD_S
from ros_margcal.stream.status import EventKind, State
from ros_margcal.validation.shipped import FallbackValidator


class _RaisingLen:
    """An object whose len() raises something unusual."""

    def __len__(self) -> int:
        raise RuntimeError("no length")


class _RaisingItem:
    """Three long, but indexing raises."""

    def __len__(self) -> int:
        return 3

    def __getitem__(self, i: int) -> float:
        raise KeyError(i)


def _infinite() -> object:
    """A generator that never ends (must not be iterated)."""

    def gen() -> Iterator[float]:
        while True:
            yield 1.0

    return gen()


HOSTILE: list[object] = [
    None, True, False, 0, 1.5, "abc", "1.0 2.0 3.0", b"xyz", {"x": 1.0, "y": 2.0, "z": 3.0}, {0: 1.0, 1: 2.0, 2: 3.0},
    [], [1.0], [1.0, 2.0], [1.0, 2.0, 3.0, 4.0], [[1.0, 2.0, 3.0]], [[1.0], [2.0], [3.0]], [1.0, "2", 3.0],
    [True, 1.0, 0.0], [None, 1.0, 0.0], [10**400, 0.0, 0.0], [1.0, -(10**400), 0.0], [1 + 2j, 0.0, 0.0],
    np.array(["1", "2", "3"]), np.array([1 + 0j, 2, 3]), np.array([True, False, True]), np.zeros((3, 3)),
    np.array([]), np.array(1.0), np.array([None, None, None]), np.array(["2020-01-01"] * 3, dtype="datetime64[D]"),
    {1.0, 2.0, 3.0}, _RaisingLen(), _RaisingItem(), _infinite(), object(), Fraction(10**400, 3), float("nan"),
]
"""Things that are not three usable real numbers (as xyz, stamp and gyro)."""


@pytest.fixture(scope="module")
def tumbling_mag() -> sim.Recording:
    """60 s of a tumbling magnetometer at 50 Hz; its true sensor (``.truth``) has a large hard iron."""
    truth = sim.random_sensor(np.random.default_rng(11), "mag")
    return sim.magnetometer_stream(truth, 60.0, 50.0, np.random.default_rng(12), motion="tumble")


@pytest.fixture(scope="module")
def tumbling_imu() -> tuple[Calibration, sim.Recording]:
    """200 s of a tumbling IMU with still periods, 100 Hz, with its gyro."""
    rng = np.random.default_rng(21)
    truth = sim.random_sensor(rng, "accel")
    return truth, sim.tumbling(truth, 200.0, 100.0, rng)


def _accounted(cal: SensorCalibrator) -> bool:
    st_ = cal.status()
    return (cal.seen == cal.passed + sum(cal.dropped.values()) and st_.samples_seen == cal.seen
            and st_.samples_passed + st_.samples_rejected == st_.samples_seen)


# -- item 1: push never raises ---------------------------------------------------------------------


@pytest.mark.parametrize("sensor", ["mag", "accel"])
def test_hostile_objects_are_dropped_never_raised(sensor: str) -> None:
    """Every hostile object as xyz, as stamp and as gyro: push returns, and the sample is counted once."""
    good = [0.0, 0.0, 9.8] if sensor == "accel" else [3e-5, 1e-5, -2e-5]
    as_xyz, as_stamp, as_gyro = (SensorCalibrator(sensor, validator=FallbackValidator()) for _ in range(3))
    for k, obj in enumerate(HOSTILE):
        assert as_xyz.push(0.1 * k, obj) == []
        as_stamp.push(obj, good)
        as_gyro.push(0.1 * k, good, obj)  # a bad gyro never costs the sample
    for cal in (as_xyz, as_stamp, as_gyro):
        assert cal.seen == len(HOSTILE) and _accounted(cal)
    d = as_xyz.dropped
    assert d["wrong_size"] + d["nonfinite"] == len(HOSTILE) and as_xyz.passed == 0
    numbers = [o for o in HOSTILE if type(o) in (int, float)]  # 0, 1.5, nan are stamps (nan a non-finite one)
    assert as_stamp.passed == 2 and as_stamp.dropped["bad_stamp"] == len(HOSTILE) - len(numbers) - 1
    assert as_stamp.dropped["nonfinite"] == 2  # nan, and the Fraction beyond the float range
    assert as_gyro.passed == len(HOSTILE)
    if sensor == "accel":
        assert as_gyro.status().gyro_ignored == len(HOSTILE) - 1  # None is "no gyro", not a bad one


def test_ints_beyond_the_float_range_are_nonfinite() -> None:
    """A Python int beyond the float range in xyz or t is a non-finite sample (it raised OverflowError)."""
    cal = SensorCalibrator("accel", validator=FallbackValidator())
    cal.push(1.0, [10**400, 0, 0])
    cal.push(10**400, [0.0, 0.0, 9.8])
    cal.push(2.0, [0, 0, -(10**309)], [0.0, 0.0, 0.0])
    cal.push(3.0, [0.0, 0.0, 9.8], [10**400, 0, 0])
    assert cal.dropped["nonfinite"] == 3
    assert cal.passed == 1 and cal.status().gyro_ignored == 1
    assert _accounted(cal)


def test_numbers_of_any_numeric_type_are_samples() -> None:
    """ints, numpy scalars, float32 arrays, int arrays, tuples, an (1, 3) array: all good samples."""
    cal = SensorCalibrator("accel", validator=FallbackValidator())
    vs = [(0, 0, 10), [np.float32(0.1), np.int16(0), 9.8], np.array([0.0, 0.1, 9.8], dtype=np.float32),
          np.array([0, 1, 10]), np.array([[0.2, 0.0, 9.8]]), [Fraction(1, 10), 0.0, 9.8]]
    for k, v in enumerate(vs):
        cal.push(k, v, np.zeros(3, dtype=np.float32))
    assert cal.passed == len(vs) and sum(cal.dropped.values()) == 0


# -- item 2: stamps --------------------------------------------------------------------------------


def _feed(cal: SensorCalibrator, t: np.ndarray, raw: np.ndarray, gyro: np.ndarray | None = None) -> list:
    events: list = []
    for k, (ti, v) in enumerate(zip(t.tolist(), raw, strict=True)):
        events += cal.push(ti, v, None if gyro is None else gyro[k])
    return events


@pytest.mark.parametrize("jump", [3600.0, 1e9, -3600.0])
def test_a_lone_stamp_glitch_is_dropped_once(tumbling_mag: sim.Recording, jump: float) -> None:
    """One sample an hour or 1e9 s ahead (or an hour late) is dropped once; the good samples after it go on."""
    rec = tumbling_mag
    cal = SensorCalibrator("mag")
    _feed(cal, rec.t[:2000], rec.raw[:2000])
    assert cal.calibration is not None
    cal.push(float(rec.t[1999]) + jump, rec.raw[2000])
    events = _feed(cal, rec.t[2001:], rec.raw[2001:])
    d = cal.dropped
    assert d["stamp_jump" if jump > 0 else "backwards_stamp"] == 1
    assert sum(d.values()) == 1 and cal.passed == len(rec) - 1
    assert cal.status().time_base_resets == 0 and not any(e.kind is EventKind.TIME_BASE for e in events)
    assert "restarted" not in cal.status().message


def test_a_first_sample_from_the_future_does_not_block_the_stream(tumbling_mag: sim.Recording) -> None:
    """The very first sample 1e9 s ahead: the good stream behind it becomes the time base and calibrates."""
    rec = tumbling_mag
    cal = SensorCalibrator("mag")
    cal.push(1e9, rec.raw[0])
    _feed(cal, rec.t, rec.raw)
    assert cal.calibration is not None
    assert np.linalg.norm(cal.calibration.offset - tumbling_mag.truth.offset) < 0.02 * tumbling_mag.truth.norm
    assert cal.status().time_base_resets == 1
    assert cal.dropped["backwards_stamp"] == cal.config.new_time_base_after - 1


def test_a_restarted_clock_is_a_new_time_base(tumbling_mag: sim.Recording) -> None:
    """A driver restart: 15 s stamped around 1000 s, then the stamps start again at 0 and never reach
    1000 s. All of it was backwards_stamp; now it is a new time base, said in the status, and calibrates."""
    rec = tumbling_mag
    split = 750
    cal = SensorCalibrator("mag")
    _feed(cal, rec.t[:split] + 1000.0, rec.raw[:split])
    assert cal.calibration is None
    events = _feed(cal, rec.t[split:] - rec.t[split], rec.raw[split:])
    base = [e for e in events if e.kind is EventKind.TIME_BASE]
    assert len(base) == 1 and "new time base" in base[0].message
    assert cal.calibration is not None
    assert np.linalg.norm(cal.calibration.offset - tumbling_mag.truth.offset) < 0.02 * tumbling_mag.truth.norm
    assert not any(e.kind is EventKind.CHANGED for e in events)
    st_ = cal.status()
    assert st_.time_base_resets == 1 and "stamps restarted 1x" in st_.message
    assert dict(st_.values())["time_base_resets"] == "1" and st_.to_dict()["time_base_resets"] == 1
    assert cal.dropped["backwards_stamp"] == cal.config.new_time_base_after - 1
    assert _accounted(cal)


def test_a_bag_replayed_in_a_loop_keeps_calibrating(tumbling_mag: sim.Recording) -> None:
    """Three loops of one bag: each restart is a new time base; the refits go on in every loop and the
    calibration stays right, its age counted on the new time base (as if the loops were one stream)."""
    rec = tumbling_mag
    cal = SensorCalibrator("mag")
    calibrated_in_loop = []
    for _ in range(3):
        events = _feed(cal, rec.t, rec.raw)
        calibrated_in_loop.append(sum(e.kind is EventKind.CALIBRATED or e.kind is EventKind.REJECTED for e in events))
    assert all(n > 0 for n in calibrated_in_loop)
    assert cal.status().time_base_resets == 2
    assert not any(e.kind is EventKind.CHANGED for e in events)
    assert cal.calibration is not None and cal.state is State.CALIBRATED
    assert np.linalg.norm(cal.calibration.offset - tumbling_mag.truth.offset) < 0.02 * tumbling_mag.truth.norm
    assert 0.0 < cal.status().age < 120.0


def test_a_sustained_forward_jump_is_a_new_time_base(tumbling_mag: sim.Recording) -> None:
    """Stamps that move 1e9 s ahead and stay there: a new time base after a few samples, nothing else lost."""
    rec = tumbling_mag
    cal = SensorCalibrator("mag")
    t = rec.t.copy()
    t[1500:] += 1e9
    _feed(cal, t, rec.raw)
    assert cal.status().time_base_resets == 1
    assert cal.dropped["stamp_jump"] == cal.config.new_time_base_after - 1
    assert sum(cal.dropped.values()) == cal.config.new_time_base_after - 1
    assert cal.calibration is not None


def test_an_imu_restart_resets_the_gate_and_calibrates(tumbling_imu: tuple[Calibration, sim.Recording]) -> None:
    """Accelerometer: 40 s on a clock at 5000 s, then a restart at 0 s: the gate starts again on the new
    time base and the still samples after the restart calibrate."""
    truth, rec = tumbling_imu
    split = 4000
    cal = SensorCalibrator("accel")
    _feed(cal, rec.t[:split] + 5000.0, rec.raw[:split], rec.gyro[:split])
    kept = cal.kept
    _feed(cal, rec.t[split:] - rec.t[split], rec.raw[split:], rec.gyro[split:])
    assert cal.kept > kept + 10
    assert cal.calibration is not None
    assert np.linalg.norm(cal.calibration.offset - truth.offset) < 0.01 * truth.norm
    assert cal.status().time_base_resets == 1
    assert _accounted(cal)


def test_reconfigure_reaches_the_intake() -> None:
    """New options apply to the input checks at once (a lower max_rate_hz makes bursts of what passed)."""
    cal = SensorCalibrator("mag", validator=FallbackValidator())
    v = [3e-5, 1e-5, -2e-5]
    for k in range(10):
        cal.push(0.01 * k, v)
    cal.reconfigure(PipelineConfig.for_sensor("mag", max_rate_hz=10.0))
    for k in range(10, 20):
        cal.push(0.01 * k, v)
    assert cal.passed == 11 and cal.dropped["burst"] == 9


# -- item 3: a broken gyro -------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [1e160, math.inf, 2.0 * MAX_GYRO_RAD_S])
def test_an_absurd_gyro_is_ignored_not_the_samples(tumbling_imu: tuple[Calibration, sim.Recording], bad: float) -> None:
    """A finite but huge gyro (1e160) overflowed in the gate, which dropped every sample silently; now the
    gyro is ignored (counted), the gate judges stillness from the accelerometer alone, and it calibrates."""
    truth, rec = tumbling_imu
    cal = SensorCalibrator("accel")
    _feed(cal, rec.t, rec.raw, np.full_like(rec.gyro, bad))
    assert cal.calibration is not None
    assert np.linalg.norm(cal.calibration.offset - truth.offset) < 0.01 * truth.norm
    assert cal.status().gyro_ignored == len(rec)
    assert _accounted(cal)


def test_a_stream_of_drops_says_so_in_the_status() -> None:
    """When every sample so far was dropped, the status names the reason instead of 'waiting for samples'."""
    cal = SensorCalibrator("accel", validator=FallbackValidator())
    for k in range(10):
        cal.push(0.01 * k, [0.0, 0.0, 1e6])
    msg = cal.status().message
    assert "every sample dropped" in msg and "magnitude" in msg


def test_a_few_pose_readings_say_how_many_are_buffered(tumbling_mag: sim.Recording) -> None:
    """24 readings (a cave-survey device's calibration shots: fewer than one evaluation's ``refit_every``) said
    'waiting for samples' while 13 of them were buffered: the status counts them before any evaluation."""
    cal = SensorCalibrator("mag")
    _feed(cal, tumbling_mag.t[:24], tumbling_mag.raw[:24])
    n = len(cal.buffer)
    assert 0 < n <= 24
    assert f"collecting: {n} samples buffered, need {cal.config.min_points}" in cal.status().message


# -- item 4: every sample counted once -------------------------------------------------------------


def test_outliers_are_counted_once(tumbling_mag: sim.Recording) -> None:
    """Outliers (field disturbances after calibration) are dropped, not also passed: seen == passed + dropped."""
    cal = SensorCalibrator("mag")
    _feed(cal, tumbling_mag.t, tumbling_mag.raw)
    noisy = sim.magnetometer_stream(tumbling_mag.truth, 60.0, 50.0, np.random.default_rng(61), motion="tumble",
                                    effects={"disturbance": 0.5})
    _feed(cal, noisy.t + tumbling_mag.t[-1] + 0.02, noisy.raw)
    assert cal.dropped["outlier"] > 0
    assert cal.passed == 2 * len(tumbling_mag) - cal.dropped["outlier"]
    assert _accounted(cal)


def test_accelerometer_samples_inside_the_gate_are_passed(tumbling_imu: tuple[Calibration, sim.Recording]) -> None:
    """Samples the gate keeps inside its window count as passed; the identity holds through the gate."""
    _, rec = tumbling_imu
    cal = SensorCalibrator("accel")
    _feed(cal, rec.t[:3000], rec.raw[:3000], rec.gyro[:3000])
    assert cal.passed + cal.dropped["outlier"] == 3000 and cal.kept < 100
    assert _accounted(cal)


# -- property: anything at all -----------------------------------------------------------------------

_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(), st.integers(min_value=10**300, max_value=10**400), st.floats(),
    st.text(max_size=4), st.binary(max_size=4), st.complex_numbers(), st.fractions(), st.decimals(),
)
_objects = st.recursive(_scalars, lambda ch: st.one_of(st.lists(ch, max_size=4), st.tuples(ch, ch, ch),
                                                       st.dictionaries(st.text(max_size=2), ch, max_size=3)),
                        max_leaves=8)
_arrays = hnp.arrays(
    dtype=st.one_of(hnp.integer_dtypes(), hnp.floating_dtypes(), hnp.complex_number_dtypes(), hnp.boolean_dtypes(),
                    hnp.byte_string_dtypes(max_len=3), hnp.unicode_string_dtypes(max_len=3)),
    shape=hnp.array_shapes(min_dims=0, max_dims=2, max_side=4),
)
_anything = st.one_of(_objects, _arrays)
_good_vector = st.just("good")
_push = st.one_of(
    st.tuples(_anything, _anything, _anything),                          # garbage everywhere
    st.tuples(st.floats(allow_nan=True, allow_infinity=True), _good_vector, _anything),  # any stamp, good vector
    st.tuples(st.just("next"), _anything, st.none()),                    # a good stamp, garbage vector
    st.tuples(st.just("next"), _good_vector, _anything),                 # good sample, any gyro
)

_GOOD = {"mag": np.array([3e-5, 1e-5, -2e-5]), "accel": np.array([0.3, -0.2, 9.7])}


@pytest.mark.parametrize("sensor", ["mag", "accel"])
@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(pushes=st.lists(_push, max_size=40))
def test_push_never_raises_and_counts_every_sample_once(sensor: str, pushes: list) -> None:
    """Arbitrary Python objects mixed with good samples: push returns a list, every sample counted once."""
    cal = SensorCalibrator(sensor, validator=FallbackValidator())
    rng = np.random.default_rng(7)
    t = 0.0
    for ts, xyz, gyro in pushes:
        if isinstance(ts, str) and ts == "next":
            t += 0.01
            ts = t
        if isinstance(xyz, str) and xyz == "good":
            xyz = _GOOD[sensor] * (1.0 + 0.01 * rng.normal(size=3))
        assert isinstance(cal.push(ts, xyz, gyro), list)
    assert cal.seen == len(pushes)
    assert _accounted(cal)


# -- never a stuck calibrator ------------------------------------------------------------------------


@pytest.mark.parametrize("sensor", ["mag", "accel"])
def test_calibrates_on_good_data_after_garbage(sensor: str, tumbling_mag: sim.Recording,
                                               tumbling_imu: tuple[Calibration, sim.Recording]) -> None:
    """Garbage first (hostile objects, a far-future and a far-past good sample, a burst, a broken gyro),
    then a good stream with stamps from 0: the calibrator is not stuck, it calibrates."""
    truth, rec = (tumbling_mag.truth, tumbling_mag) if sensor == "mag" else tumbling_imu
    cal = SensorCalibrator(sensor)
    v = rec.raw[0]
    for k, obj in enumerate(HOSTILE):
        cal.push(k, obj, obj)
        cal.push(obj, v, obj)
    cal.push(1e9, v, [1e160, 0.0, 0.0])
    cal.push(-1e9, v)
    for k in range(50):
        cal.push(2e9 + k * 1e-6, v)
    _feed(cal, rec.t, rec.raw, rec.gyro if sensor == "accel" else None)
    assert cal.calibration is not None
    assert np.linalg.norm(cal.calibration.offset - truth.offset) < 0.02 * truth.norm
    assert _accounted(cal)
