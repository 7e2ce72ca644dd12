"""Azimuth coverage on the field actually turned (issue 25 item 2): about the ring's centre, not the origin."""

from __future__ import annotations

import numpy as np

from ros_margcal.model.calibration import Calibration
from ros_margcal.stream.observable import azimuth_coverage, ring_centre, ring_tilt_deg


def _ring(n: int = 400, tilt_deg: float = 1.0) -> np.ndarray:
    """A level ring of 24 uT horizontal, 41.6 uT vertical field (tesla), wobbling by ``tilt_deg``."""
    psi = np.linspace(0.0, 6.0 * np.pi, n)
    a = np.radians(tilt_deg) * np.sin(0.37 * psi)
    return np.c_[24e-6 * np.cos(psi), 24e-6 * np.sin(psi), -41.6e-6 + 24e-6 * np.sin(a) * np.cos(psi)]


def test_a_ring_whose_centre_the_calibration_misses_is_still_turned_through() -> None:
    """An offset 30 uT off in x puts the origin outside the calibrated ring: about the origin the field turned
    through a third of the azimuths; about the ring's centre, all of them."""
    ring = _ring()
    off = Calibration(np.array([-30e-6, 0.0, 0.0]), np.eye(3), norm=48e-6)
    h = off.apply(ring)
    assert abs(ring_centre(h)[0] - 30e-6) < 1e-7
    origin = len(np.unique(np.floor((np.arctan2(h[:, 1], h[:, 0]) + np.pi) / (2 * np.pi) * 36))) / 36
    assert origin < 0.4
    assert azimuth_coverage(off, ring) == 1.0


def test_a_cone_about_another_axis_is_no_ring_about_z() -> None:
    """A sensor waved in a cone about x: a ring too, but about x; its azimuths are judged about the origin."""
    psi = np.linspace(0.0, 2.0 * np.pi, 300)
    cone = 48e-6 * np.c_[np.full_like(psi, np.cos(0.5)), np.sin(0.5) * np.cos(psi), np.sin(0.5) * np.sin(psi)]
    ident = Calibration(np.zeros(3), np.eye(3), norm=48e-6)
    assert ring_centre(cone) == (0.0, 0.0)
    assert azimuth_coverage(ident, cone) < 0.5


def test_ring_tilt_tells_a_near_level_ring_from_a_band() -> None:
    assert ring_tilt_deg(_ring(tilt_deg=1.0)) < 2.5 < ring_tilt_deg(_ring(tilt_deg=8.0))
    assert ring_tilt_deg(_ring()[:3]) == float("inf")
