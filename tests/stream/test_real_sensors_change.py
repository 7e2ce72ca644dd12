"""A magnetometer back at its start pose is no sensor change; a hard-iron jump at that pose still is."""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from ros_margcal.model.calibration import Calibration
from ros_margcal.stream.calibrator import SensorCalibrator, State
from ros_margcal.stream.config import PipelineConfig
from ros_margcal.stream.status import EventKind

RATE = 50.0
W = np.array([[1.08, 0.04, -0.02], [0.04, 0.93, 0.03], [-0.02, 0.03, 1.01]])
TRUTH = Calibration(np.array([12.0, -7.5, 30.0]), W, norm=48.0, sensor="mag", unit="uT")


def _stream(seed: int, *, local: float = 1.06, jump: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Rest 20 s at P0 (field along body +z, scaled by ``local``: a desk's iron), turn 120 s through the sphere outside
    a 30° cap about P0, rest 40 s at P0 again (the same place); ``jump``: a hard iron of that many field norms then."""
    rng = np.random.default_rng(seed)
    n_rest, n_turn = int(20 * RATE), int(120 * RATE)
    d = np.array([1.0, 0.0, -0.2]) / np.hypot(1.0, 0.2)
    dirs: list[np.ndarray] = []
    while len(dirs) < n_turn:  # a wandering direction at 25 deg/s that never enters the cap
        axis = np.cross(d, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        for _ in range(int(RATE * rng.uniform(1, 3))):
            nd = Rotation.from_rotvec(axis * np.radians(25.0) / RATE).apply(d)
            if nd[2] > np.cos(np.radians(30.0)):
                break
            d = nd
            dirs.append(d)
    p0 = np.array([0.0, 0.0, local])
    body = 48.0 * np.concatenate([np.tile(p0, (n_rest, 1)), np.array(dirs[:n_turn]), np.tile(p0, (2 * n_rest, 1))])
    raw = TRUTH.inverse_apply(body) + rng.normal(scale=0.003 * 48.0 / np.sqrt(3), size=body.shape)
    raw[n_rest + n_turn:] += jump * 48.0 * np.array([0.0, 0.6, 0.8])
    return np.arange(len(raw)) / RATE, raw


def _run(t: np.ndarray, raw: np.ndarray) -> tuple[SensorCalibrator, list]:
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag", "uT"))
    events = []
    for ti, v in zip(t, raw, strict=True):
        events += cal.push(float(ti), v)
    return cal, events


def test_the_start_pose_returned_to_is_no_change() -> None:
    """The first calibrations missed the start pose by 5.7 % (fitted mostly elsewhere); back there, no change is
    declared (before the fix: "sensor changed at t=140.00 s", one refit leaving 0.65 % > 0.5 % on the buffer)."""
    start = time.perf_counter()
    cal, events = _run(*_stream(2))
    assert not any(e.kind is EventKind.CHANGED for e in events), [e.message for e in events if e.kind is EventKind.CHANGED]
    assert cal.changes == 0 and cal.state is State.CALIBRATED
    assert any("missed before the onset too" in e.message for e in events)
    assert time.perf_counter() - start < 30.0


def test_a_hard_iron_jump_at_the_start_pose_is_a_change() -> None:
    """The same stream without the desk's iron and with a 0.15 field-norm hard iron at the return: a change."""
    _, events = _run(*_stream(2, local=1.0, jump=0.15))
    assert any(e.kind is EventKind.CHANGED for e in events)
