"""``fitting_gyro.frame_shares`` scores every frame in one batched product (issue 28 item 3): the same shares, bit
for bit, as scoring each frame on its own, so the frame check and the mounting decide as before."""

from __future__ import annotations

from types import ModuleType

import numpy as np

from ros_margcal.model.fitting_gyro import SIGNED_PERMUTATIONS, axial, explained, frame_shares, gyro_blocks, skew


def _one_by_one(blocks, b: np.ndarray, w: np.ndarray, frames: list[np.ndarray]) -> list[float]:
    """The per-frame loop the batched product replaced."""
    winv_t, k_wb = np.linalg.inv(w).T, skew(w @ b)
    st = w @ blocks.s.transpose(0, 2, 1)
    return [explained(blocks, blocks.d + (axial(st @ m.T) - blocks.theta @ (m.T @ k_wb)) @ winv_t) for m in frames]


def test_batched_shares_equal_the_loop(independent: ModuleType) -> None:
    """All 48 signed permutations on a tilted ground robot: identical shares, the own frame best by far."""
    rec = independent.generate("mag", "ground", duration_s=40.0, rate_hz=50.0, seed=4, tilt_deg=10.0,
                               symmetric_soft_iron=True, hard_iron_mag=30e-6)
    blocks = gyro_blocks(rec["t"], rec["xyz"], rec["gyro"], 50)
    b, w = rec["truth"]["offset"], rec["truth"]["W_sym"]
    frames = list(SIGNED_PERMUTATIONS)
    got = frame_shares(blocks, b, w, frames)
    assert got == _one_by_one(blocks, b, w, frames)
    assert got[0] > 0.9 and max(got[1:]) < got[0]


def test_no_frames_and_no_turn() -> None:
    """No frame to score: no share; blocks without a change of the field: NaN for each frame (as explained gives)."""
    t = np.arange(200) * 0.02
    blocks = gyro_blocks(t, np.tile([20e-6, 0.0, -40e-6], (200, 1)), np.zeros((200, 3)), 50)
    assert frame_shares(blocks, np.zeros(3), np.eye(3), []) == []
    shares = frame_shares(blocks, np.zeros(3), np.eye(3), list(SIGNED_PERMUTATIONS[:3]))
    assert len(shares) == 3 and all(np.isnan(shares))
