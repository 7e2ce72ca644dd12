"""The calibrators' worker process (no rclpy): the same calibrations as replay, commands answered, a dead worker
restarted, and the gyro pairing independent of the order the two topics arrive in."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

from ros_margcal.ros.worker import CalibrationWorker, _Calibrators
from ros_margcal.sim import simulation as sim
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.config import PipelineConfig

NAN3 = (math.nan, math.nan, math.nan)


@pytest.fixture(scope="module")
def stream() -> sim.Recording:
    """A tumbling magnetometer, 40 s at 50 Hz, stamped from 1000 s."""
    truth = sim.random_sensor(np.random.default_rng(31), "mag")
    rec = sim.magnetometer_stream(truth, 40.0, 50.0, np.random.default_rng(32), motion="tumble")
    return sim.Recording(t=rec.t + 1000.0, raw=rec.raw, truth=truth)


@pytest.fixture
def worker() -> Iterator[CalibrationWorker]:
    w = CalibrationWorker({"mag": (PipelineConfig.for_sensor("mag"), None)}, None, 0.1)
    try:
        yield w
    finally:
        w.stop()


class Inbox:
    """What the worker sent, gathered by polling."""

    def __init__(self, worker: CalibrationWorker) -> None:
        self.worker = worker
        self.items: list[tuple[Any, ...]] = []

    def wait(self, cond: Callable[[list[tuple[Any, ...]]], bool], timeout_s: float = 20.0) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.items += self.worker.poll()
            if cond(self.items):
                return True
            time.sleep(0.01)
        return False

    def last_status(self) -> Any:
        return next(x[1]["mag"] for x in reversed(self.items) if x[0] == "status")


def _samples(rec: sim.Recording) -> list[tuple[Any, ...]]:
    now = time.monotonic()
    return [("mag", float(t), *map(float, v), *NAN3, "imu_link", now) for t, v in zip(rec.t, rec.raw, strict=True)]


def test_worker_calibrates_as_replay_does(worker: CalibrationWorker, stream: sim.Recording) -> None:
    """Samples sent in batches give, in the worker, exactly the calibration of the pure pipeline."""
    inbox = Inbox(worker)
    batch = _samples(stream)
    for k in range(0, len(batch), 37):
        worker.send(batch[k:k + 37])
    assert inbox.wait(lambda items: any(x[0] == "status" and x[1]["mag"].samples_seen == len(batch) for x in items))
    cals = [x[2] for x in inbox.items if x[0] == "calibration"]
    ref = SensorCalibrator("mag")
    for t, v in zip(stream.t.tolist(), stream.raw, strict=True):
        ref.push(t, v)
    assert ref.calibration is not None and cals and cals[-1].allclose(ref.calibration, rtol=1e-9)
    assert any(x[0] == "event" and x[1].kind.value == "calibrated" for x in inbox.items)


def test_commands_are_answered_in_order(worker: CalibrationWorker, stream: sim.Recording) -> None:
    """refit answers with the validator's reason before data; a reset after samples forgets them."""
    inbox = Inbox(worker)
    rid = worker.request("refit")
    assert inbox.wait(lambda items: any(x[0] == "reply" and x[1] == rid for x in items))
    reply = next(x for x in inbox.items if x[0] == "reply")
    assert reply[2] is False and "need" in reply[3]
    worker.send(_samples(stream)[:500])
    rid = worker.request("reset")
    assert inbox.wait(lambda items: any(x[0] == "reply" and x[1] == rid for x in items))
    k = next(i for i, x in enumerate(inbox.items) if x[0] == "reply" and x[1] == rid)
    assert inbox.wait(lambda items: any(x[0] == "status" for x in items[k:]), 2.0)  # a status follows each answer
    st = inbox.last_status()
    assert st.samples_seen == 0 and st.state.value == "collecting"


def test_a_dead_worker_is_seen_and_restarted(worker: CalibrationWorker) -> None:
    """A killed worker is not alive; restart starts a new process that answers."""
    pid = worker.pid
    worker._proc.kill()
    worker._proc.join(5.0)
    assert not worker.alive
    worker.restart({"mag": (PipelineConfig.for_sensor("mag"), None)})
    assert worker.alive and worker.pid != pid and worker.restarts == 1
    inbox = Inbox(worker)
    rid = worker.request("refit")
    assert inbox.wait(lambda items: any(x[0] == "reply" and x[1] == rid for x in items))


class _Outbox(list):
    def put(self, item: Any) -> None:
        self.append(item)


def test_refit_succeeds_when_every_sensor_ends_calibrated(stream: sim.Recording) -> None:
    """~/refit's answer: success when each sensor holds a calibration afterwards, a fit no better than the
    current one keeping it (said so); failure with the reason while a sensor is uncalibrated."""
    cals = _Calibrators({"mag": (PipelineConfig.for_sensor("mag"), None)}, None, _Outbox())
    ok, text = cals.command("refit", ())
    assert not ok and text.startswith("mag: ") and "need" in text
    cals.samples(_samples(stream))
    time.sleep(0.3)  # the pairing holds a magnetometer sample up to 0.25 s for an Imu rate
    cals.flush()
    assert cals.cals["mag"].calibration is not None
    current = cals.cals["mag"].calibration
    ok, text = cals.command("refit", ())
    assert ok, text
    kept = text.startswith("mag: kept the current calibration")
    assert kept or text.startswith("mag: calibrated"), text
    assert (cals.cals["mag"].calibration is current) == kept  # kept means the very same calibration


def test_gyro_pairing_in_the_worker_ignores_callback_order() -> None:
    """The magnetometer's gyro rows are the same whether each Imu message comes before or after its
    MagneticField message; a magnetometer in a frame of its own takes the only Imu frame's rate (pairing.py)."""
    rows = []
    for mag_first in (False, True):
        cals = _Calibrators({"mag": (PipelineConfig.for_sensor("mag"), None), "accel": (PipelineConfig.for_sensor("accel"), None)},
                            None, _Outbox())
        batch = []
        for k, frame in enumerate(["imu_link"] * 30 + ["mag_link"] * 10):
            t, arrival = 100.0 + 0.02 * k, 0.02 * k
            imu = ("accel", t, 0.0, 0.0, 9.81, 0.0, 0.0, 0.3, "imu_link", arrival)
            mag = ("mag", t + 0.005, 20e-6, 1e-6 * k, 40e-6, *NAN3, frame, arrival)
            batch += [mag, imu] if mag_first else [imu, mag]
        cals.samples(batch)
        cals.command("refit", ())  # releases what is still held
        rows.append(np.array(list(cals.cals["mag"]._gyro_buf)))
    assert rows[0].shape == (40, 7)
    np.testing.assert_array_equal(rows[0], rows[1])
    assert np.allclose(rows[0][:, 4:], [0.0, 0.0, 0.3])


def test_a_calibration_from_the_file_ages_from_the_first_sample(stream: sim.Recording) -> None:
    """A file's calibration is stamped on its recording's clock (here 5 s); the node's samples carry the
    driver's clock (1e9 s): its age counts from the first sample, not 1e9 s."""
    truth = stream.truth.replace(stamp=5.0)
    cals = _Calibrators({"mag": (PipelineConfig.for_sensor("mag"), truth)}, None, _Outbox())
    batch = [("mag", 1e9 + 0.02 * k, *map(float, v), *NAN3, "imu_link", 0.0) for k, v in enumerate(stream.raw[:500])]
    cals.samples(batch)
    cals.command("refit", ())
    st = cals.cals["mag"].status()
    assert st.state.value == "calibrated" and st.age is not None and st.age < 20.0, (st.age, st.message)


def test_a_fit_in_progress_when_the_stream_stops_is_finished(worker: CalibrationWorker) -> None:
    """Fits step with the samples (stream.evaluation, Fits in steps): a stream that stops while one is in progress gets
    its result once the worker has been idle for _IDLE_FINISH_S, the very calibration replay's finish_fit gives."""
    ring = INDEPENDENT.generate("mag", "ground", duration_s=120.0, rate_hz=50.0, seed=23, tilt_deg=5.0,
                                symmetric_soft_iron=True, hard_iron_mag=30e-6)  # partial fits: several steps each
    stream = sim.Recording(t=ring["t"] + 1000.0, raw=ring["xyz"])
    probe, end = SensorCalibrator("mag"), None
    times = stream.t.tolist()
    for t, v in zip(times, stream.raw, strict=True):  # the first fit that calibrates over several pushes
        done = [e for e in probe.push(t, v) if e.kind.value == "calibrated"]
        if done and done[0].t < t:  # stamped with the push that started it
            end = times.index(done[0].t) + 1  # the stream stops in that push
            break
    assert end is not None
    ref = SensorCalibrator("mag")
    for t, v in zip(stream.t[:end].tolist(), stream.raw[:end], strict=True):
        ref.push(t, v)
    assert ref._sliced is not None and ref.calibration is None
    assert any(e.kind.value == "calibrated" for e in ref.finish_fit()) and ref.calibration is not None
    inbox = Inbox(worker)
    worker.send(_samples(sim.Recording(t=stream.t[:end], raw=stream.raw[:end])))
    assert inbox.wait(lambda items: any(x[0] == "calibration" and x[2] is not None for x in items), timeout_s=30.0)
    got = next(x[2] for x in inbox.items if x[0] == "calibration" and x[2] is not None)
    assert got.allclose(ref.calibration, rtol=1e-9)
