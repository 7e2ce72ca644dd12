"""A sensor change that undoes an earlier one (a payload taken off again) brings the calibration of before back
at once (``change.py`` ``_check_known``); a change to a third state does not.

On the independent generator (tests/independent: no code shared with the package): a 20 uT hard-iron step at
``T_ON`` that is taken off again at ``T_OFF`` (offsets A, B, A), or replaced by another one (A, B, C).
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

from ros_margcal.stream.calibrator import EventKind, PipelineConfig, SensorCalibrator
from ros_margcal.stream.change import ChangeDetection

GEN: ModuleType = INDEPENDENT
T_ON, T_OFF = 40.0, 80.0
LATENCY_S = 5.5  # the detector's change_min_duration_s and a window: the old calibration is current until then


def _recording(motion: str, seed: int, third: bool, **kw: Any) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """The recording and the true offsets after ``T_OFF`` (A again, or a third C) and between (B)."""
    rec = GEN.generate("mag", motion, seed=seed, rate_hz=50.0, hard_iron_mag=30e-6, symmetric_soft_iron=True,
                       effect="hard_iron_jump", magnitude=20e-6 / 48e-6, t_jump=T_ON, **kw)
    tr = rec["truth"]
    step = tr["offset_after"] - tr["offset"]
    late = rec["t"] >= T_OFF
    after = tr["offset"].copy()
    if third:  # a 20 uT step at right angles to the first
        other = np.cross(step, [0.0, 0.0, 1.0])
        after = after + other / np.linalg.norm(other) * np.linalg.norm(step)
    rec["xyz"][late] += after - tr["offset_after"]
    return rec, tr["offset_after"], after


def _run(rec: dict[str, Any], after: np.ndarray, tilt: float, t_off: float = T_OFF) -> list[tuple[float, float, str]]:
    """(time, heading p95 at ``tilt`` against the truth after ``t_off``, message) of each calibration published
    once the detector could have seen the second change."""
    tr = {**rec["truth"], "offset": after}
    cal = SensorCalibrator("mag", PipelineConfig.for_sensor("mag"))
    out = []
    for t, v in zip(rec["t"].tolist(), rec["xyz"], strict=True):
        for e in cal.push(t, v):
            if e.kind is EventKind.CALIBRATED and t >= t_off + LATENCY_S:
                c = e.calibration
                out.append((t, GEN.heading_p95(c.matrix, c.offset, tr, tilt), e.message))
    return out


def test_a_tumble_gets_its_calibration_back_when_the_step_is_taken_off() -> None:
    """Back within 3 s of the change's declaration (T_OFF + 5 s), 0.1 deg at 30 deg (before: recollected, 91.5 s)."""
    rec, _, after = _recording("tumble", 1, third=False, duration_s=120.0)
    cals = _run(rec, after, 30.0)
    assert cals and "sensor changed back" in cals[0][2]
    assert cals[0][0] <= T_OFF + 8.0
    assert max(err for _, err, _ in cals) <= 1.0


def test_a_ground_robot_gets_its_calibration_back_after_a_turn(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without a gyro the ground robot recollected for 40 s (seed 1, the step off at 300 s); now back within 25 s,
    20 s sooner at least, and as good as its old calibration (0.9 deg at 5 deg tilt)."""
    rec = GEN.generate("mag", "ground", seed=1, rate_hz=50.0, hard_iron_mag=30e-6, symmetric_soft_iron=True,
                       effect="hard_iron_jump", magnitude=20e-6 / 48e-6, t_jump=150.0, duration_s=400.0, tilt_deg=5.0)
    tr = rec["truth"]
    rec["xyz"][rec["t"] >= 300.0] -= tr["offset_after"] - tr["offset"]
    cals = _run(rec, tr["offset"], 5.0, 300.0)
    assert cals and "sensor changed back" in cals[0][2]
    assert cals[0][0] <= 300.0 + 25.0
    assert max(err for _, err, _ in cals) <= 2.0
    monkeypatch.setattr(ChangeDetection, "KNOWN_MAX", 0)  # the rule off: recollecting takes a minute
    before = _run(rec, tr["offset"], 5.0, 300.0)
    assert before and before[0][0] > cals[0][0] + 20.0 and "changed back" not in before[0][2]


@pytest.mark.parametrize("seed", [1, 2])
def test_a_third_sensor_state_is_not_taken_for_an_old_one(seed: int) -> None:
    """A, B, then C (another 20 uT step): no calibration of before comes back; what is published fits C."""
    rec, _, after = _recording("tumble", seed, third=True, duration_s=120.0)
    cals = _run(rec, after, 30.0)
    assert cals
    assert not any("changed back" in m for _, _, m in cals)
    assert max(err for _, err, _ in cals) <= 2.0
