"""The cost of the sample path, counted (never timed): deferred evaluation and skipped re-evaluations.

- Deferred mode (the node's): ``push`` never fits; ``run_pending`` after each ``push`` gives exactly
  the calibrations of the inline mode (the replay's); a fit whose data went stale is dropped.
- Skipping evaluations on unchanged data: a ground robot's motion (yaw turns, small tilt: never
  calibrates) calls the validator a bounded number of times per 10 000 samples, on the independent
  generator of ``tests/independent`` and on the package's simulator; a tumble calibrates at the same
  moment as with an evaluation at every cadence point.
Timing targets belong in ``margcal bench pipeline``, not here.
"""

from __future__ import annotations

import threading
from typing import Any

import margcal_independent_generator as gen  # loaded once by tests/conftest.py
import numpy as np
import pytest

import ros_margcal.stream.evaluation as calibrator_module
from ros_margcal.sim import simulation as sim
from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator


class CountingValidator:
    """The shipped validator, counting its calls."""

    def __init__(self) -> None:
        self.inner = SensorCalibrator("mag").validator
        self.threshold = self.inner.threshold
        self.calls = 0

    def predict_indicators(self, ind: Any) -> float:
        self.calls += 1
        return self.inner.predict_indicators(ind)


def _feed(cal: SensorCalibrator, t: Any, xyz: Any, gyro: Any = None, *, deferred: bool = False) -> list[tuple[float, Any]]:
    """Push every sample (running the pending evaluation after each in deferred mode); the CALIBRATED events."""
    out = []
    g = [None] * len(t) if gyro is None else gyro
    for ti, v, w in zip(np.asarray(t).tolist(), np.asarray(xyz), g, strict=True):
        events = cal.push(ti, v, w)
        if deferred:
            assert not events or all(e.kind is not EventKind.CALIBRATED for e in events)
            events = events + cal.run_pending()
        out += [(e.t, e.calibration) for e in events if e.kind is EventKind.CALIBRATED]
    return out


@pytest.fixture(scope="module")
def tumble() -> sim.Recording:
    truth = sim.random_sensor(np.random.default_rng(21), "mag")
    return sim.magnetometer_stream(truth, 120.0, 50.0, np.random.default_rng(22), motion="tumble")


@pytest.fixture(scope="module")
def imu() -> sim.Recording:
    truth = sim.random_sensor(np.random.default_rng(23), "accel")
    return sim.tumbling(truth, 120.0, 100.0, np.random.default_rng(24))


@pytest.mark.parametrize("kind", ["mag", "accel"])
def test_deferred_mode_gives_the_inline_calibrations(kind: str, tumble: sim.Recording, imu: sim.Recording) -> None:
    rec = tumble if kind == "mag" else imu
    gyro = rec.gyro if kind == "accel" else None
    inline = _feed(SensorCalibrator(kind), rec.t, rec.raw, gyro)
    deferred_cal = SensorCalibrator(kind)
    deferred_cal.defer_evaluation = True
    deferred = _feed(deferred_cal, rec.t, rec.raw, gyro, deferred=True)
    assert len(inline) >= 2
    assert [t for t, _ in deferred] == [t for t, _ in inline]
    for (_, a), (_, b) in zip(deferred, inline, strict=True):
        np.testing.assert_array_equal(a.offset, b.offset)
        np.testing.assert_array_equal(a.matrix, b.matrix)


def test_push_never_fits_in_deferred_mode(tumble: sim.Recording, monkeypatch: pytest.MonkeyPatch) -> None:
    cal = SensorCalibrator("mag")
    cal.defer_evaluation = True
    real_fit = calibrator_module.fit
    in_push = [False]
    calls = {"push": 0, "pending": 0}

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls["push" if in_push[0] else "pending"] += 1
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(calibrator_module, "fit", counted)
    for t, v in zip(tumble.t.tolist(), tumble.raw, strict=True):
        in_push[0] = True
        cal.push(t, v)
        in_push[0] = False
        if cal.pending and int(t) % 5 == 0:  # the worker runs now and then, not after each sample
            cal.run_pending()
    assert calls["push"] == 0
    assert calls["pending"] >= 1 and cal.calibration is not None


def test_run_pending_with_a_lock_and_a_stale_fit(tumble: sim.Recording) -> None:
    """Under a lock the fit runs outside it; a reset between validation and install drops the fit."""
    cal = SensorCalibrator("mag")
    cal.defer_evaluation = True
    lock = threading.Lock()
    for t, v in zip(tumble.t.tolist(), tumble.raw, strict=True):
        with lock:
            cal.push(t, v)
        cal.run_pending(lock)
        assert not lock.locked()
    assert cal.calibration is not None and not cal.pending

    class ResettingLock:
        """Resets the calibrator when the fit's result is about to be installed (the second acquire)."""

        def __init__(self) -> None:
            self.n = 0

        def acquire(self) -> None:
            self.n += 1
            if self.n == 2:
                cal.reset()

        def release(self) -> None:
            pass

    fresh = SensorCalibrator("mag")
    fresh.defer_evaluation = True
    cal = fresh
    for t, v in zip(tumble.t.tolist(), tumble.raw, strict=True):
        cal.push(t, v)
        if cal.pending:
            pending_before = cal.fits_accepted + cal.fits_rejected
            events = cal.run_pending(ResettingLock())
            if cal.seen == 0:  # the fit ran and the reset came first: nothing installed, nothing reported
                assert events == [] or all(e.kind is not EventKind.CALIBRATED for e in events)
                assert cal.calibration is None and cal.fits_accepted + cal.fits_rejected == pending_before
                return
    pytest.fail("no fit was attempted")


FULL_ONLY = PipelineConfig.for_sensor("mag", partial_fit=False)
"""The full path alone: the partial calibration (tests/stream/test_ground_robot.py) calibrates a ground robot."""


def _ground_generator(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rec = gen.generate("mag", "ground", duration_s=300.0, rate_hz=100.0, seed=seed)
    return rec["t"], rec["xyz"]


def _without_skipping(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(SensorCalibrator, "_unchanged", lambda self, t, interval: False)


@pytest.mark.parametrize("seed", [1, 2])
def test_ground_robot_validator_calls_are_bounded(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Yaw turns with a few degrees of tilt never calibrate (the full path alone: ``partial_fit`` off); the
    validator is not asked again and again."""
    t, xyz = _ground_generator(seed)
    val = CountingValidator()
    cal = SensorCalibrator("mag", FULL_ONLY, validator=val)
    assert _feed(cal, t, xyz) == []
    per_10k = val.calls * 1e4 / len(t)
    assert per_10k <= 15.0, f"{val.calls} validator calls in {len(t)} samples"
    # the cadence alone (every refit_every samples and refit_min_interval_s) asks about once a second
    _without_skipping(monkeypatch)
    ref = CountingValidator()
    assert _feed(SensorCalibrator("mag", FULL_ONLY, validator=ref), t, xyz) == []
    assert ref.calls >= 5 * val.calls


def test_ground_robot_on_the_simulator() -> None:
    """The same with the package's simulator: a yaw-turning Motion with small tilt."""
    from ros_margcal.bench.pipeline import ground_motion

    rng = np.random.default_rng(31)
    truth = sim.random_sensor(rng, "mag")
    rec = sim.magnetometer_stream(truth, 300.0, 100.0, rng, motion=ground_motion(300.0, 100.0, rng))
    val = CountingValidator()
    assert _feed(SensorCalibrator("mag", FULL_ONLY, validator=val), rec.t, rec.raw) == []
    assert val.calls * 1e4 / len(rec) <= 15.0


@pytest.mark.parametrize("motion", ["tumble", "smooth"])
def test_rich_motion_calibrates_as_soon_as_without_skipping(motion: str, monkeypatch: pytest.MonkeyPatch) -> None:
    truth = sim.random_sensor(np.random.default_rng(41), "mag")
    rec = sim.magnetometer_stream(truth, 90.0, 50.0, np.random.default_rng(42), motion=motion)
    first = _feed(SensorCalibrator("mag"), rec.t, rec.raw)
    _without_skipping(monkeypatch)
    every = _feed(SensorCalibrator("mag"), rec.t, rec.raw)
    assert first and every
    assert first[0][0] == every[0][0]
    np.testing.assert_array_equal(first[0][1].offset, every[0][1].offset)


def test_a_worker_thread_beside_the_sample_path(tumble: sim.Recording) -> None:
    """The node's arrangement without rclpy: pushes under the lock on one thread, run_pending on another."""
    cal = SensorCalibrator("mag")
    cal.defer_evaluation = True
    lock = threading.Lock()
    done = threading.Event()
    errors: list[BaseException] = []
    calibrated: list[Any] = []

    def worker() -> None:
        try:
            while not done.is_set() or cal.pending:
                calibrated.extend(e for e in cal.run_pending(lock) if e.kind is EventKind.CALIBRATED)
                done.wait(0.002)
        except BaseException as exc:
            errors.append(exc)

    thread = threading.Thread(target=worker)
    thread.start()
    try:
        for t, v in zip(tumble.t.tolist(), tumble.raw, strict=True):
            with lock:
                cal.push(t, v)
    finally:
        done.set()
        thread.join(timeout=60.0)
    assert not thread.is_alive() and not errors
    assert calibrated and cal.calibration is calibrated[-1].calibration
    assert np.linalg.norm(cal.calibration.offset - tumble.truth.offset) < 0.02 * tumble.truth.norm
