"""``DirectionBuffer.discard``: samples found bad after they went in (a saturated axis) leave the buffer, and the
buffer is then what it would be had they never gone in."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.coverage.buffer import DirectionBuffer

CENTRE = np.array([0.2, -0.1, 0.05])


def _buffer(t: np.ndarray, pts: np.ndarray, per_bin: int = 4, min_interval_s: float = 0.0) -> DirectionBuffer:
    buf = DirectionBuffer(n_bins=50, per_bin=per_bin, min_interval_s=min_interval_s, center=CENTRE, radius=1.0)
    for tk, p in zip(t.tolist(), pts.tolist(), strict=True):
        buf.push(tk, p)
    return buf


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 400), share=st.floats(0.0, 1.0),
       per_bin=st.sampled_from([4, 400]), min_interval_s=st.sampled_from([0.0, 0.05]))
def test_discard_leaves_the_buffer_of_the_samples_it_keeps(seed: int, n: int, share: float, per_bin: int,
                                                           min_interval_s: float) -> None:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    pts = CENTRE + d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    t = np.cumsum(rng.uniform(0.01, 0.1, n))
    buf = _buffer(t, pts, per_bin, min_interval_s)
    inside = {tuple(p) for p in buf.points().tolist()}
    bad = {p for p in sorted(inside) if rng.uniform() < share}
    evicted = buf.stats()["evicted"]
    gone = buf.discard(lambda x, y, z: (x, y, z) in bad)
    assert gone == len(bad)
    assert {tuple(p) for p in buf.points().tolist()} == inside - bad
    assert buf.stats()["evicted"] == evicted + gone
    keep = np.array([tuple(p) not in bad for p in pts.tolist()], dtype=bool)
    fresh = _buffer(t[keep], pts[keep], per_bin, min_interval_s)
    # a buffer that never saw the discarded samples holds the same ones, unless those had pushed older samples out
    # of a full bin (gone for good) or kept a later one out of a bin (too soon after them): then the same indicators
    if per_bin == 400 and min_interval_s == 0.0:  # room for all and no bin refusing: always the same samples
        assert {tuple(p) for p in fresh.points().tolist()} == inside - bad
    if {tuple(p) for p in fresh.points().tolist()} == inside - bad:
        a, b = buf.indicators(), fresh.indicators()
        for k in ("A", "B", "C", "D"):
            assert getattr(a, k) == pytest.approx(getattr(b, k), rel=1e-9, abs=1e-12), k


def test_discard_of_nothing_changes_nothing() -> None:
    rng = np.random.default_rng(3)
    d = rng.normal(size=(200, 3))
    pts = d / np.linalg.norm(d, axis=1, keepdims=True)
    buf = _buffer(np.arange(200) * 0.02, pts)
    ind = buf.indicators()
    assert buf.discard(lambda x, y, z: False) == 0
    assert buf.indicators() is ind  # not even re-binned


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 300), cut=st.floats(0.0, 1.0))
def test_discard_before_keeps_exactly_the_samples_from_then_on(seed: int, n: int, cut: float) -> None:
    """``discard_before(t)`` (a sensor that changed before its first calibration): what stays is what was taken at
    ``t`` or later, the rest counted as evicted."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    pts = CENTRE + d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    t = np.cumsum(rng.uniform(0.01, 0.1, n))
    buf = _buffer(t, pts)
    cut_t = float(t[-1]) * cut if n else 0.0
    before = buf.times()
    evicted = buf.stats()["evicted"]
    gone = buf.discard_before(cut_t)
    assert gone == int(np.count_nonzero(before < cut_t))
    assert sorted(buf.times().tolist()) == sorted(before[before >= cut_t].tolist())
    assert buf.stats()["evicted"] == evicted + gone
