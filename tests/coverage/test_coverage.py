"""Tests of the direction buffer and the coverage indicators A–D (Olivares et al. 2013, §3.1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.coverage.buffer import DirectionBuffer
from ros_margcal.coverage.indicators import HIST_BINS, Indicators, compute_indicators
from ros_margcal.model.errors import ConfigError, InputError
from ros_margcal.sim.simulation import directions

try:
    from ros_margcal.sim.simulation import directions as _sim_directions
except ImportError:  # pragma: no cover - the simulator is another module of the package
    _sim_directions = None


def _uniform(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _axis_ellipses(n: int, rng: np.random.Generator) -> np.ndarray:
    """Points on the three great circles about x, y and z (Olivares Fig. 7, ill-distributed set)."""
    if _sim_directions is not None:
        return _sim_directions("axis_ellipses", n, rng)
    ang = rng.uniform(0, 2 * np.pi, n)
    axis = np.arange(n) % 3
    out = np.zeros((n, 3))
    for k in range(3):
        i, j = [m for m in range(3) if m != k]
        sel = axis == k
        out[sel, i] = np.cos(ang[sel])
        out[sel, j] = np.sin(ang[sel])
    return out


def _same(a: Indicators, b: Indicators) -> None:
    assert a.n_points == b.n_points
    assert a.B == b.B
    assert a.A == pytest.approx(b.A, rel=1e-9, abs=1e-9)
    assert a.C == pytest.approx(b.C, rel=1e-12, abs=1e-12)
    assert a.D == pytest.approx(b.D, rel=1e-7, abs=1e-9 * max(1.0, b.C) ** 3)
    assert a.radius == pytest.approx(b.radius, rel=1e-9)
    assert 10**a.e_info == pytest.approx(10**b.e_info, rel=1e-6, abs=1e-9)


def test_indicators_of_the_six_axis_points() -> None:
    """Six points at ±r on the axes: A, B, C, D by hand (octahedron volume 4/3 r³)."""
    r = 2.0
    c = np.array([1.0, -3.0, 0.5])
    pts = c + r * np.vstack([np.eye(3), -np.eye(3)])
    ind = compute_indicators(pts, c, r)
    assert ind.C == pytest.approx(6 * r)
    assert ind.c_norm == pytest.approx(1.0)
    assert ind.D == pytest.approx(4.0 / 3.0 * r**3)
    assert ind.d_norm == pytest.approx(1.0 / math.pi)
    # theta = [0, 0, 90, 0, 0, -90] -> IQR 0; phi = [0, 90, 0, 180, -90, 0] -> Q1 0, Q3 67.5
    assert ind.A == pytest.approx(67.5)
    # theta occupies bins {0, 18, 35}, phi occupies {9, 18, 27, 35} of 36
    assert ind.B == (HIST_BINS - 3) + (HIST_BINS - 4)
    assert ind.b_frac == pytest.approx(ind.B / (2 * HIST_BINS))


def test_indicator_b_matches_numpy_histograms(rng: np.random.Generator) -> None:
    """B equals the empty-bin count of numpy histograms of theta and phi (Eq. 11)."""
    d = _uniform(40, rng) * [1.0, 1.0, 0.3]
    ind = compute_indicators(d, None, 1.0, hist_bins=24)
    theta = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
    phi = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    ht, _ = np.histogram(theta, bins=24, range=(-90, 90))
    hp, _ = np.histogram(phi, bins=24, range=(-180, 180))
    assert ind.B == int((ht == 0).sum() + (hp == 0).sum())
    assert ind.B > 0


def test_degenerate_sets_have_zero_volume() -> None:
    """Fewer than four or coplanar points give D = 0, not an exception."""
    assert compute_indicators([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]]).D == 0.0
    flat = np.array([[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0.5, 0.5, 0]])
    assert compute_indicators(flat).D == 0.0


def test_fig7_axis_ellipses_close_in_c_apart_in_d(rng: np.random.Generator) -> None:
    """Olivares Fig. 7: same-size well-distributed and axis-ellipses sets have close C but distant D."""
    n, c, r = 400, np.array([120.0, -40.0, 300.0]), 250.0
    well = c + r * _uniform(n, rng) + rng.normal(scale=1.0, size=(n, 3))
    ill = c + r * _axis_ellipses(n, rng) + rng.normal(scale=1.0, size=(n, 3))
    iw, ii = compute_indicators(well, c, r), compute_indicators(ill, c, r)
    print(f"Fig. 7: C_well={iw.C:.1f} C_ill={ii.C:.1f}  D_well={iw.D:.4g} D_ill={ii.D:.4g}")
    assert abs(ii.C / iw.C - 1.0) < 0.05
    assert ii.D / iw.D < 0.88
    assert (1.0 - ii.D / iw.D) > 3.0 * abs(1.0 - ii.C / iw.C)


def test_buffer_indicators_match_batch_on_a_stream(rng: np.random.Generator) -> None:
    """After thousands of inserts and evictions the live indicators equal the batch reference."""
    c, r = np.array([10.0, -5.0, 3.0]), 50.0
    buf = DirectionBuffer(n_bins=60, per_bin=5, center=c, radius=r, min_interval_s=0.0)
    pts = c + r * _uniform(3000, rng) + rng.normal(scale=0.5, size=(3000, 3))
    for i, p in enumerate(pts):
        assert buf.push(0.01 * i, p)
    assert len(buf) == buf.capacity == buf.n_bins * 5
    assert buf.stats()["evicted"] == 3000 - buf.capacity
    _same(buf.indicators(), compute_indicators(buf.points(), c, r))


def test_memory_is_bounded_and_newest_replaces_oldest() -> None:
    """One direction offered forever keeps exactly ``per_bin`` samples, the newest ones."""
    buf = DirectionBuffer(n_bins=50, per_bin=4, min_interval_s=0.0)
    for i in range(1000):
        buf.push(float(i), [1.0, 0.0, 0.001 * (i % 7)])
    assert len(buf) == 4
    assert buf.times().tolist() == [996.0, 997.0, 998.0, 999.0]
    assert sum(buf.bin_counts()) == 4


def test_min_interval_refuses_dense_samples() -> None:
    """A bin takes at most one sample per ``min_interval_s``; a jump back in time is accepted."""
    buf = DirectionBuffer(min_interval_s=0.5)
    kept = [buf.push(0.01 * i, [1.0, 0.0, 0.0]) for i in range(200)]
    assert sum(kept) == 4  # t = 0, 0.5, 1.0, 1.5
    assert buf.stats()["refused"] == 196
    assert buf.push(-100.0, [1.0, 0.0, 0.0])


@pytest.mark.parametrize(
    "sample",
    [[np.nan, 0.0, 1.0], [np.inf, 0.0, 1.0], [1.0, 2.0], None, "abc", [[1.0, 2.0, 3.0]]],
)
def test_bad_samples_are_counted_not_raised(sample: object) -> None:
    """Non-finite or malformed samples never raise; they are counted as invalid."""
    buf = DirectionBuffer()
    assert buf.push(0.0, sample) is False  # type: ignore[arg-type]
    assert buf.stats()["invalid"] == 1
    assert len(buf) == 0
    assert buf.push(float("nan"), [1.0, 0.0, 0.0]) is False


def test_equal_area_bins(rng: np.random.Generator) -> None:
    """Uniform directions fill the equal-area bins evenly (chi-square near its mean)."""
    buf = DirectionBuffer(n_bins=100)
    d = _uniform(200_000, rng)
    idx = np.array([buf.bin_of(v) for v in d[:20_000]])
    counts = np.bincount(idx, minlength=buf.n_bins)
    expected = idx.size / buf.n_bins
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert buf.n_bins == buf.n_bands * buf.n_sectors
    assert abs(buf.n_bins - 100) <= 5
    assert chi2 < buf.n_bins + 5 * math.sqrt(2 * buf.n_bins)


def test_set_center_rebins_and_keeps_newest() -> None:
    """Moving the centre re-bins; a bin that overflows keeps its newest samples."""
    buf = DirectionBuffer(n_bins=400, per_bin=3, min_interval_s=0.0)
    true_c = np.array([5.0, 0.0, 0.0])
    heights = np.linspace(0.5, 20.0, 8)  # one ray from true_c: eight azimuths seen from the origin
    for i, h in enumerate(heights):
        assert buf.push(float(i), [5.0, h, 0.0])
    assert len(buf) == 8
    buf.set_center(true_c, 10.0)
    assert len(buf) == 3
    assert buf.times().tolist() == [5.0, 6.0, 7.0]
    assert buf.stats()["rebins"] == 1
    assert buf.stats()["evicted"] == 5
    assert buf.bin_counts()[buf.bin_of([5.0, 1.0, 0.0])] == 3
    _same(buf.indicators(), compute_indicators(buf.points(), true_c, 10.0))


def test_set_center_bins_agree_with_bin_of(rng: np.random.Generator) -> None:
    """After a move every sample sits in the bin ``bin_of`` gives about the new centre."""
    true_c, r = np.array([30.0, 0.0, 0.0]), 10.0
    buf = DirectionBuffer(n_bins=40, per_bin=3, min_interval_s=0.0)
    for i, p in enumerate(true_c + r * _uniform(400, rng)):
        buf.push(float(i), p)
    assert buf.coverage() < 0.3  # seen from the origin the sphere is a small cap
    buf.set_center(true_c, r)
    expected = np.bincount([buf.bin_of(p) for p in buf.points()], minlength=buf.n_bins)
    assert buf.bin_counts() == expected.tolist()
    for i, p in enumerate(true_c + r * _uniform(400, rng)):
        buf.push(400.0 + i, p)
    assert buf.coverage() > 0.9
    _same(buf.indicators(), compute_indicators(buf.points(), true_c, r))
    assert buf.indicators().c_norm == pytest.approx(1.0, abs=0.05)


def test_radius_defaults_to_mean_distance(rng: np.random.Generator) -> None:
    """Without a fitted radius the normalisation uses the mean distance from the centre."""
    buf = DirectionBuffer(min_interval_s=0.0)
    for i, p in enumerate(3.0 * _uniform(300, rng)):
        buf.push(float(i), p)
    ind = buf.indicators()
    assert ind.radius == pytest.approx(3.0)
    _same(ind, compute_indicators(buf.points(), None, None))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_bins": 0}, "n_bins"),
        ({"per_bin": 0}, "per_bin"),
        ({"min_interval_s": -1.0}, "min_interval_s"),
        ({"hist_bins": 0}, "hist_bins"),
    ],
)
def test_bad_buffer_options(kwargs: dict[str, float], match: str) -> None:
    """Out-of-range options raise ConfigError naming the option."""
    with pytest.raises(ConfigError, match=match):
        DirectionBuffer(**kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("points", "center", "radius", "match"),
    [
        ([[np.nan, 0.0, 0.0]], None, 1.0, "NaN"),
        ([[1.0, 2.0]], None, 1.0, "shape"),
        ([[1.0, 2.0, 3.0]], [0.0, 0.0], 1.0, "center"),
        ([[1.0, 2.0, 3.0]], None, -1.0, "radius"),
    ],
)
def test_bad_batch_input(points: object, center: object, radius: float, match: str) -> None:
    """The batch reference validates its input with InputError."""
    with pytest.raises(InputError, match=match):
        compute_indicators(points, center, radius)  # type: ignore[arg-type]


_OPS = st.lists(
    st.one_of(
        st.tuples(st.just("gauss"), st.integers(0, 2**31 - 1)),
        st.tuples(st.just("lattice"), st.integers(0, 2**31 - 1)),
        st.tuples(st.just("repeat"), st.integers(0, 10_000)),
        st.tuples(st.just("center"), st.integers(0, 2**31 - 1)),
    ),
    min_size=1,
    max_size=120,
)


@settings(max_examples=60, deadline=None)
@given(ops=_OPS, per_bin=st.integers(1, 4), n_bins=st.sampled_from([4, 12, 30]), hist_bins=st.sampled_from([5, 36]))
def test_incremental_equals_batch(ops: list[tuple[str, int]], per_bin: int, n_bins: int, hist_bins: int) -> None:
    """After any sequence of inserts, evictions and re-binnings the incremental indicators equal the batch ones."""
    buf = DirectionBuffer(n_bins=n_bins, per_bin=per_bin, min_interval_s=0.0, hist_bins=hist_bins)
    seen: list[np.ndarray] = []
    for k, (op, arg) in enumerate(ops):
        rng = np.random.default_rng(arg)
        if op == "gauss":
            p = rng.normal(size=3) * 5.0 + [2.0, -1.0, 0.5]
        elif op == "lattice":  # exact duplicates and coplanar runs
            p = rng.integers(-2, 3, size=3).astype(float)
        elif op == "repeat" and seen:
            p = seen[arg % len(seen)]
        elif op == "center":
            buf.set_center(rng.normal(size=3), float(rng.uniform(0.5, 5.0)))
            continue
        else:
            continue
        seen.append(p)
        buf.push(float(k), p)
        assert len(buf) <= buf.capacity
    if len(buf) == 0:
        assert buf.indicators().n_points == 0
        return
    ref = compute_indicators(buf.points(), buf.center, buf.radius, hist_bins=hist_bins)
    _same(buf.indicators(), ref)


def test_e_total_counts_samples_e_info_does_not(rng: np.random.Generator) -> None:
    """Uniform sets of 60 and 6000 samples have the same per-sample information (e_info near 0) but
    e_total, the information of the whole set, differs by two decades; as_dict carries it."""
    small = compute_indicators(directions("uniform", 60, rng), np.zeros(3), 1.0)
    large = compute_indicators(directions("uniform", 6000, rng), np.zeros(3), 1.0)
    assert abs(small.e_info) < 0.5 and abs(large.e_info) < 0.05
    assert large.e_total - small.e_total == pytest.approx(2.0 + large.e_info - small.e_info, abs=1e-12)
    assert small.as_dict()["e_total"] == pytest.approx(small.e_info + np.log10(60))
