"""A refit whose newest samples are not of the sensor the rest are is refused (``observable.TAIL_FACTOR``).

A hard-iron step whose residuals stay under the change detector's threshold for a few seconds left a ground robot's
refit, started 2.5 s after it, with 12 of its 763 series points from after the step: the fit took them for tilt and
was published 57 deg off (``scripts/bench_ground_robot.py``, the step taken off again, tuning seed 3). Here on the
independent generator's ground robot (tests/independent), its series made as the calibrator makes it (means of
0.2 s), the refit is fitted directly: refused with a step's points at its end, not without them.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

from ros_margcal.model.fitting_geometric import block_means
from ros_margcal.stream.config import PipelineConfig
from ros_margcal.stream.observable import TAIL_FACTOR, TAIL_POINTS, _tail_misfit, partial_fit

T_JUMP = 147.5


@pytest.fixture(scope="module")
def ground() -> dict[str, Any]:
    """A ground robot whose hard iron steps by 2 uT (4 % of the field: under the detector's 5 %) at ``T_JUMP``."""
    rec = INDEPENDENT.generate("mag", "ground", duration_s=150.0, rate_hz=50.0, seed=3, tilt_deg=5.0,
                               symmetric_soft_iron=True, hard_iron_mag=30e-6)
    rec["xyz"] = np.asarray(rec["xyz"], dtype=np.float64)
    rec["xyz"][rec["t"] >= T_JUMP] += [2e-6, 0.0, 0.0]
    return rec


def _series(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The calibrator's series: means of 10 samples (0.2 s at 50 Hz) and their spread."""
    k = 10
    n = len(xyz) // k * k
    return block_means(xyz[:n].tolist(), k)


def _refit(xyz: np.ndarray, cfg: PipelineConfig) -> Any:
    """A published partial calibration on the first 100 s, then the refit on ``xyz``."""
    first, spread = _series(xyz[:5000])
    cur = partial_fit(first, None, cfg, spread=spread, recent=xyz[4960:5000], current=None, stamp=100.0, sensor="mag")
    assert cur.calibration is not None and not cur.reason, cur.reason
    series, spread = _series(xyz)
    return partial_fit(series, None, cfg, spread=spread, recent=xyz[-40:], current=cur.calibration, stamp=150.0,
                       sensor="mag", current_heading=cur.heading_seen_deg, current_tilt=cur.tilt_seen_deg,
                       start=cur.calibration, sigma=cur.sigma), series  # from the last solution, as the calibrator


def test_a_refit_with_a_step_at_its_end_is_refused(ground: dict[str, Any]) -> None:
    cfg = PipelineConfig.for_sensor("mag")
    xyz = np.asarray(ground["xyz"], dtype=np.float64)
    stepped, series = _refit(xyz, cfg)
    assert stepped.calibration is not None
    assert "newest" in stepped.reason, stepped.reason
    assert _tail_misfit(stepped.calibration, series) > TAIL_FACTOR
    # the same refit on the samples before the step: no such refusal (its tail fits as the rest)
    before, series = _refit(xyz[ground["t"] < T_JUMP], cfg)
    assert before.calibration is not None and "newest" not in before.reason
    assert _tail_misfit(before.calibration, series) < 2.0


def test_the_tail_misfit_needs_four_tails() -> None:
    cfg = PipelineConfig.for_sensor("mag")
    from ros_margcal.model.calibration import Calibration
    cal = Calibration.identity(norm=1.0)
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(4 * TAIL_POINTS - 1, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    assert _tail_misfit(cal, pts) == 0.0
    pts = np.vstack([pts * (1.0 + 1e-3 * rng.normal(size=(len(pts), 1))), 1.05 * pts[:TAIL_POINTS]])
    assert _tail_misfit(cal, pts) > TAIL_FACTOR
    assert cfg.partial_period_s * TAIL_POINTS == pytest.approx(2.0)
