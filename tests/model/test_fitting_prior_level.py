"""The level term of a near-level ring (model/fitting_level.py) and the gyro frame check (model/fitting_gyro.py)."""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
import pytest
from conftest import INDEPENDENT

from ros_margcal.model.fitting_core import pack
from ros_margcal.model.fitting_geometric import block_means
from ros_margcal.model.fitting_gyro import frame_check, frame_name, gyro_blocks
from ros_margcal.model.fitting_level import LevelTerm, ring_tilt
from ros_margcal.model.fitting_prior import broad_prior, fit_with_prior

GEN: ModuleType = INDEPENDENT


@pytest.fixture(scope="module")
def flat() -> dict[str, Any]:
    """A car at 40 Hz for 200 s whose tilt stays within 0.2 deg: a ring the norm cannot level (seed 8)."""
    return GEN.generate("mag", "car", duration_s=200.0, rate_hz=40.0, seed=8, tilt_deg=0.2, mount_deg=(0.0, 0.0),
                        symmetric_soft_iron=True, hard_iron_mag=30e-6)


def test_ring_tilt_is_the_tilt_of_the_calibrated_ring() -> None:
    """Points on a ring tilted by 2 deg about x: slope tan(2 deg) of h_z on h_y, none on h_x."""
    psi = np.linspace(0.0, 2.0 * np.pi, 200, endpoint=False)
    a = np.radians(2.0)
    ring = np.c_[np.cos(psi), np.sin(psi) * np.cos(a), np.sin(psi) * np.sin(a) - 1.5]
    theta = pack(np.zeros(3), np.eye(3), "sym")
    np.testing.assert_allclose(ring_tilt(ring, theta), [0.0, np.tan(a)], atol=1e-12)
    r, jt = LevelTerm(ring, 1.0, 9).residuals(theta)
    assert r.shape == (2,) and jt.shape == (9, 2) and abs(jt[7, 0] - 1.0) < 1e-6  # h_z gains w_xz h_x: slope + 1


def test_the_level_term_levels_a_flat_ring(flat: dict[str, Any]) -> None:
    """The norm alone leaves the calibrated frame's tilt to the prior (level heading several degrees off); held
    level, the level heading is the data's, and the predicted bound covers it."""
    pts, sp = block_means(flat["xyz"], 8)
    tr = flat["truth"]
    prior = broad_prior(pts, tr["norm"])
    plain = fit_with_prior(pts, prior, time_ordered=True, spread=sp).calibration
    held = fit_with_prior(pts, prior, time_ordered=True, spread=sp, level=True)
    c = held.calibration
    assert held.level and "w_zz" in held.from_prior
    assert GEN.heading_p95(plain.matrix, plain.offset, tr, 0.0) > 2.0
    assert GEN.heading_p95(c.matrix, c.offset, tr, 0.0) < 1.0


def test_frame_check_names_the_axis_order_that_explains_the_turn() -> None:
    rec = GEN.generate("mag", "ground", duration_s=60.0, rate_hz=50.0, seed=5, tilt_deg=5.0, symmetric_soft_iron=True)
    tr = rec["truth"]
    own = gyro_blocks(rec["t"], rec["xyz"], rec["gyro"], 50)
    assert frame_check(own, tr["offset"], tr["W_sym"])[0] == ""
    for rates, name in ((rec["gyro"] * [1.0, 1.0, -1.0], "(x, y, -z)"), (rec["gyro"][:, [1, 0, 2]], "(y, x, z)"),
                        (rec["gyro"][:, [2, 0, 1]], "(y, z, x)"), (np.radians(rec["gyro"]), "57.3x larger"),
                        (np.degrees(rec["gyro"]), "57.3x smaller")):
        got, share, base = frame_check(gyro_blocks(rec["t"], rec["xyz"], rates, 50), tr["offset"], tr["W_sym"])
        assert got == name and share > 0.95 > base


def test_frame_names() -> None:
    assert frame_name(np.eye(3)) == "(x, y, z)"
    assert frame_name(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])) == "(-y, x, z)"


def test_frame_check_names_nothing_that_explains_little() -> None:
    """A rate 1000x off: its own frame explains -10^6 of the turning, taken 57.3x smaller still -270x: far better, yet
    nothing; no frame or unit is named below ``NAMED_MIN_SHARE`` (a real 2 Hz log got "57.3x smaller" at -91 %)."""
    rec = GEN.generate("mag", "ground", duration_s=60.0, rate_hz=50.0, seed=5, tilt_deg=5.0, symmetric_soft_iron=True)
    tr = rec["truth"]
    got, _, own = frame_check(gyro_blocks(rec["t"], rec["xyz"], rec["gyro"] * 1000.0, 50), tr["offset"], tr["W_sym"])
    assert got == "" and own < -1e5
