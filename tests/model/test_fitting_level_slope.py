"""The slope standard error of a near-level ring (model/fitting_level.py ``slope_std``, ``turns``,
``covariance_weight``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ros_margcal.model.fitting_level import LevelTerm, slope_std, turns


def _ring(tilt: np.ndarray) -> np.ndarray:
    """Unit horizontal field turned 10 times, vertical -1.5, each point's frame tilted by ``tilt`` (rad) toward it."""
    psi = np.linspace(0.0, 20.0 * np.pi, len(tilt), endpoint=False)
    return np.c_[np.cos(psi), np.sin(psi), -1.5 + np.sin(tilt)]


def _ar1(rng: np.random.Generator, n: int, rho: float, sd: float) -> np.ndarray:
    e = rng.normal(0.0, sd * math.sqrt(1.0 - rho**2), n)
    out = np.empty(n)
    out[0] = rng.normal(0.0, sd)
    for k in range(1, n):
        out[k] = rho * out[k - 1] + e[k]
    return out


def test_a_flat_ring_has_no_slope_error() -> None:
    assert slope_std(_ring(np.zeros(400))) < 1e-12
    assert slope_std(_ring(np.zeros(5))) == 0.0  # too few points to say


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_slowly_wandering_tilt_leaves_a_larger_error_than_a_white_one(seed: int) -> None:
    """Same tilt spread (0.6 deg): correlated over ~50 points the slope is far less certain than white."""
    rng = np.random.default_rng(seed)
    white = slope_std(_ring(np.radians(rng.normal(0.0, 0.6, 1500))))
    slow = slope_std(_ring(np.radians(_ar1(rng, 1500, 0.98, 0.6))))
    assert 0.0 < white < slow
    assert math.degrees(white) < 0.05 < math.degrees(slow) < 1.0


def test_the_covariance_weight_adds_the_slope_error_to_the_assumption() -> None:
    rng = np.random.default_rng(4)
    flat, rough = LevelTerm(_ring(np.zeros(1500)), 2.0, 9), LevelTerm(_ring(np.radians(_ar1(rng, 1500, 0.98, 0.6))), 2.0, 9)
    assert flat.covariance_weight() == pytest.approx(2.0 / math.sqrt(1.0 + 1.0 / 10.0**2), rel=1e-4)  # ten turns' mean tilt
    assert rough.covariance_weight() < 2.0 and rough.weight == 2.0  # the fit's weight is left alone


def test_turns_counts_the_azimuth_both_ways_and_not_the_noise() -> None:
    rng = np.random.default_rng(5)
    there = np.linspace(0.0, 3.0 * np.pi, 300)
    psi = np.r_[there, there[::-1]]  # one and a half turns left, then back: three turns of azimuth
    pts = np.c_[4.0 + np.cos(psi), -2.0 + np.sin(psi), np.zeros(len(psi))] + rng.normal(0.0, 0.02, (len(psi), 3))
    assert turns(pts) == pytest.approx(3.0, abs=0.1)
    quarter = np.linspace(0.0, 0.5 * np.pi, 4000)  # 4000 noisy samples over a quarter turn: no more than that
    pts = np.c_[np.cos(quarter), np.sin(quarter), np.zeros(4000)] + rng.normal(0.0, 0.02, (4000, 3))
    assert turns(pts) == pytest.approx(0.25, abs=0.05)


def test_the_first_turn_claims_less_than_many() -> None:
    """One turn's mean tilt is the turn's own roll: the weight falls by sqrt(2) (module docstring)."""
    one = LevelTerm(_ring(np.zeros(1500))[:150], 2.0, 9)  # the first of the ten turns
    assert one.covariance_weight() == pytest.approx(2.0 / math.sqrt(2.0), rel=0.02)
