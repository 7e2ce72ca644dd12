"""The magnetometer's spike filter (``intake.SpikeFilter``, issue 26 item 11) on hand-made streams."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ros_margcal.stream.intake import Sample, SpikeFilter


def _stream(n: int = 60, step: float = 0.5e-6) -> list[Sample]:
    """A field of 50 µT turning slowly about z: ``step`` tesla between samples, 50 Hz."""
    r = 50e-6
    out: list[Sample] = []
    for k in range(n):
        a = k * step / r
        out.append((0.02 * k, r * math.cos(a) + 20e-6, r * math.sin(a), 10e-6, None))
    return out


def _run(samples: list[Sample]) -> tuple[list[float], int, SpikeFilter]:
    f = SpikeFilter()
    handed: list[float] = []
    spikes = 0
    for s in samples:
        out, n = f.push(s)
        handed += [o[0] for o in out]
        spikes += n
    return handed, spikes, f


def _far(s: Sample, x: float = 1e-3) -> Sample:
    return (s[0], x, -x, x, s[4])


@pytest.mark.parametrize("at", [[0], [1], [2], [10], [10, 11], [10, 11, 12], [10, 30]])
def test_spikes_are_dropped_and_the_rest_handed_on_in_order(at: list[int]) -> None:
    """Spikes anywhere (the first sample too, up to three in a row): dropped; every other sample handed on, in order."""
    samples = _stream()
    for i in at:
        samples[i] = _far(samples[i])
    handed, spikes, f = _run(samples)
    assert spikes == len(at)
    assert handed == [s[0] for k, s in enumerate(samples) if k not in at][: len(handed)]
    assert len(handed) + f.pending + spikes == len(samples)


def test_a_longer_excursion_and_a_jump_are_handed_on() -> None:
    """Four far samples in a row (more than ``HOLD``) and a step that stays: nothing dropped, held at most ``HOLD``."""
    samples = _stream()
    for i in range(10, 14):
        samples[i] = _far(samples[i])
    handed, spikes, _ = _run(samples)
    assert spikes == 0 and len(handed) == len(samples)
    jump = [(t, x + 30e-6, y, z, g) if k >= 20 else (t, x, y, z, g) for k, (t, x, y, z, g) in enumerate(_stream())]
    f = SpikeFilter()
    most_held = 0
    handed = []
    for s in jump:
        out, n = f.push(s)
        assert n == 0
        handed += out
        most_held = max(most_held, f.pending)
    assert most_held <= SpikeFilter.HOLD and [s[0] for s in handed] == [s[0] for s in jump][: len(handed)]


def test_a_quantised_sensor_at_rest_has_no_spikes() -> None:
    """Counts at rest toggling by one count (or not at all): no step is far, nothing is held."""
    rng = np.random.default_rng(3)
    base = np.array([400.0, -120.0, 310.0])
    samples = [(0.02 * k, *(base + rng.integers(-1, 2, 3) * (rng.random(3) < 0.2)).tolist(), None) for k in range(500)]
    handed, spikes, f = _run(samples)  # type: ignore[arg-type]
    assert spikes == 0 and f.pending <= 2 and len(handed) >= 498


def test_flush_hands_on_what_is_held() -> None:
    """``flush`` returns the held samples (the first two of a stream, or an excursion), the filter then holds none."""
    f = SpikeFilter()
    samples = _stream(2)
    assert f.push(samples[0]) == ([], 0) and f.push(samples[1]) == ([], 0) and f.pending == 2
    assert f.flush() == samples and f.pending == 0
