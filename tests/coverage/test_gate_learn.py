"""The inactivity gate that learns the sensor's rest noise (``learn=True``): widens within the cap, never from a move."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ros_margcal.coverage.gate import LEARN_CAP, GyroAidedGate, InactivityGate
from ros_margcal.stream.calibrator import SensorCalibrator
from ros_margcal.stream.config import PipelineConfig

G = 9.80665


def _rest(noise: float, seconds: float = 30.0, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * 100)) / 100.0
    f = Rotation.random(random_state=seed).apply([0.0, 0.0, G])
    return t, f + rng.normal(scale=noise * G, size=(t.size, 3))


def _emitted(gate: InactivityGate | GyroAidedGate, t: np.ndarray, xyz: np.ndarray, gyro: bool = False) -> int:
    n = 0
    for ti, v in zip(t, xyz, strict=True):
        n += gate.push(ti, v, np.zeros(3) if gyro else None) is not None
    return n


@pytest.mark.parametrize("noise", [4e-3, 6e-3])
def test_a_noisy_sensor_at_rest_is_still_only_with_learning(noise: float) -> None:
    """White rest noise of 4e-3 and 6e-3 g per axis: Gietzelt's fixed 3e-3 finds nothing, the learning gate finds it."""
    t, xyz = _rest(noise)
    fixed, learnt = InactivityGate(), InactivityGate(learn=True)
    assert _emitted(fixed, t, xyz) == 0
    assert _emitted(learnt, t, xyz) >= 10
    cv, axis = learnt.thresholds
    assert noise < axis <= LEARN_CAP and 3e-3 <= cv <= LEARN_CAP
    assert "learnt from" in learnt.learnt and f"{axis:.2g}" in learnt.learnt


def test_a_slow_rotation_teaches_nothing() -> None:
    """A 0.5 deg/s rotation with 1e-3 g noise (window spread about 4e-3, within the cap) is not rest-like: its spread
    is far above its white noise, so the thresholds stay and nothing is emitted."""
    rng = np.random.default_rng(6)
    t = np.arange(6000) / 100.0
    rot = Rotation.from_rotvec(np.outer(np.radians(0.5) * t, [1.0, 0.3, 0.0]) / np.hypot(1.0, 0.3))
    xyz = rot.apply([0.0, 0.0, G]) + rng.normal(scale=1e-3 * G, size=(t.size, 3))
    gate = InactivityGate(learn=True)
    assert _emitted(gate, t, xyz) == 0
    assert gate.thresholds == (3e-3, 3e-3) and gate.learnt == ""


def test_noise_beyond_the_cap_is_never_learnt() -> None:
    """2e-2 g of noise (a running engine, a shaken part) is beyond the cap: the gate keeps Gietzelt's thresholds."""
    t, xyz = _rest(2e-2)
    gate = InactivityGate(learn=True)
    assert _emitted(gate, t, xyz) == 0
    assert gate.thresholds == (3e-3, 3e-3)


def test_learning_is_off_unless_asked_and_survives_a_reset() -> None:
    """``InactivityGate()`` is Gietzelt's; a learnt floor is the sensor's and outlives ``reset``."""
    t, xyz = _rest(5e-3)
    plain = InactivityGate()
    _emitted(plain, t, xyz)
    assert plain.thresholds == (3e-3, 3e-3)
    gate = InactivityGate(learn=True)
    _emitted(gate, t, xyz)
    widened = gate.thresholds
    gate.reset()
    assert gate.thresholds == widened and widened[1] > 3e-3


def test_the_gyro_aided_gate_learns_too() -> None:
    """With a still gyro on every sample the 1 s gate learns the same noise."""
    t, xyz = _rest(5e-3)
    gate = GyroAidedGate(learn=True)
    assert _emitted(gate, t, xyz, gyro=True) >= 10
    assert gate.thresholds[1] > 3e-3 and gate.learnt


def test_the_status_quotes_the_thresholds_and_how_to_raise_them() -> None:
    """No still sample yet: the status gives the last window against the thresholds in use and names the option."""
    rng = np.random.default_rng(7)
    cal = SensorCalibrator("accel", PipelineConfig.for_sensor("accel", "g"))
    for i in range(1000):
        cal.push(i / 100.0, np.array([0.0, 0.0, 1.0]) + rng.normal(scale=0.05, size=3))
    msg = cal.status().message
    assert "vs 0.003, axis spread" in msg and "vs 0.003)" in msg, msg
    assert "--set gate_cv_threshold=" in msg and "accel.gate_cv_threshold" in msg
    off = SensorCalibrator("accel", PipelineConfig.for_sensor("accel", "g", gate_learn_noise=False))
    assert off._gate.plain.learn is False
