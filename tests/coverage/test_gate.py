"""Tests of the inactivity gate (Gietzelt et al. 2013, §2.4, adapted to SI data)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ros_margcal.coverage.gate import InactivityGate
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import ConfigError

G = 9.80665


def _run(gate: InactivityGate, t: np.ndarray, xyz: np.ndarray, gyro: np.ndarray | None = None) -> tuple[np.ndarray, list]:
    """Feed a series; return the per-sample still detection (union of passing windows) and the emissions."""
    det = np.zeros(t.size, dtype=bool)
    out = []
    for i in range(t.size):
        e = gate.push(t[i], xyz[i], None if gyro is None else gyro[i])
        if gate.is_still:
            det[np.searchsorted(t, gate.still_since) : i + 1] = True
        if e is not None:
            out.append((t[i], e))
    return det, out


def _still_series(rng: np.random.Generator, n: int, rate: float = 100.0, noise: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) / rate
    f = Rotation.random(random_state=rng.integers(1 << 31)).apply([0.0, 0.0, G])
    return t, f + rng.normal(scale=noise * G, size=(n, 3))


def test_tumbling_precision_recall_and_norm_error() -> None:
    """On simulated tumbling with rests of 3–8 s: precision >= 0.97, recall >= 0.9, norm error < 3x noise."""
    sim = pytest.importorskip("ros_margcal.sim.simulation")
    rng = np.random.default_rng(11)
    truth = sim.random_sensor(rng, kind="accel")
    noise = 0.002
    motion = sim.tumbling_motion(300.0, 100.0, rng, still_s=(3.0, 8.0))
    rec = sim.tumbling(truth, 300.0, 100.0, rng, motion=motion, noise=noise)
    det, out = _run(InactivityGate(), rec.t, rec.raw)
    hit = det & rec.still
    precision, recall = hit.sum() / det.sum(), hit.sum() / rec.still.sum()
    assert precision >= 0.97, precision
    assert recall >= 0.9, recall
    emitted = np.array([e for _, e in out])
    err = np.linalg.norm(truth.apply(emitted), axis=1) - truth.norm
    floor = noise * truth.norm
    assert np.abs(err).max() < 3 * floor
    edges = np.flatnonzero(np.diff(np.r_[0, rec.still.astype(int), 0]))
    rests = (edges[1::2] - edges[::2]) / 100.0  # rest durations, s
    assert len(out) >= int((rests // 2.0).sum()) - rests.size  # one per full window of each rest, about
    print(f"precision {precision:.4f} recall {recall:.4f} emitted {len(out)} max norm error {np.abs(err).max():.4g} (floor {floor:.4g})")


def test_still_series_emits_one_per_window_and_accurate_mean(rng: np.random.Generator) -> None:
    """Sixty seconds at rest: first emission after one window, then one per window, means near the truth."""
    t, xyz = _still_series(rng, 6000)
    gate = InactivityGate()
    det, out = _run(gate, t, xyz)
    assert det[1:].all()  # sample 0 lies exactly 2 s before the first full window (200 samples): outside it
    times = np.array([ti for ti, _ in out])
    assert 1.99 <= times[0] <= 2.02
    assert np.all(np.diff(times) >= 2.0 - 1e-9)
    assert 28 <= len(out) <= 30
    assert gate.counters["emitted"] == len(out)
    assert gate.counters["stretches"] == 1
    means = np.array([e for _, e in out])
    assert np.abs(np.linalg.norm(means, axis=1) - G).max() < 3 * 0.002 * G / math.sqrt(100)


def test_max_per_stretch_limits_emissions(rng: np.random.Generator) -> None:
    """``max_per_stretch=1``: a long rest gives exactly one sample."""
    t, xyz = _still_series(rng, 3000)
    _, out = _run(InactivityGate(max_per_stretch=1), t, xyz)
    assert len(out) == 1


def test_rotation_at_constant_norm_is_not_still(rng: np.random.Generator) -> None:
    """A slow rotation (5 deg/s) keeps |f| = g, so the norm CV passes; the per-axis spread must reject it."""
    t = np.arange(3000) / 100.0
    rot = Rotation.from_rotvec(np.outer(np.radians(5.0) * t, [1.0, 0.3, 0.0]) / np.hypot(1.0, 0.3))
    xyz = rot.apply([0.0, 0.0, G]) + rng.normal(scale=0.001 * G, size=(t.size, 3))
    gate = InactivityGate()
    det, out = _run(gate, t, xyz)
    assert not det.any()
    assert out == []
    cv, axis = gate.window_stats
    assert cv < gate.cv_threshold < axis


def test_gyro_threshold_rejects_spinning_body(rng: np.random.Generator) -> None:
    """With a gyro threshold, a quiet accelerometer on a body spinning about g is not still."""
    t, xyz = _still_series(rng, 1000)
    gyro = np.tile([0.0, 0.0, 0.5], (t.size, 1))
    _, out = _run(InactivityGate(gyro_threshold=0.1), t, xyz, gyro)
    assert out == []
    _, out = _run(InactivityGate(), t, xyz, gyro)
    assert len(out) > 0


def test_irregular_rate_still_detected(rng: np.random.Generator) -> None:
    """Jittered sample times (20–200 Hz) do not prevent detection: the window is time-based."""
    dt = rng.uniform(0.005, 0.05, size=2000)
    t = np.cumsum(dt)
    f = np.array([1.0, -2.0, 9.5])
    xyz = f / np.linalg.norm(f) * G + rng.normal(scale=0.002 * G, size=(t.size, 3))
    det, out = _run(InactivityGate(), t, xyz)
    assert det[t > t[0] + 2.1].all()
    assert len(out) >= (t[-1] - t[0]) / 2.0 - 2


@pytest.mark.parametrize(
    ("sample", "key"),
    [
        ([np.nan, 0.0, G], "dropped_nonfinite"),
        ([np.inf, 0.0, G], "dropped_nonfinite"),
        ([1.0, 2.0], "dropped_invalid"),
        (None, "dropped_invalid"),
        ("xyz", "dropped_invalid"),
    ],
)
def test_bad_samples_are_counted(rng: np.random.Generator, sample: object, key: str) -> None:
    """Bad samples in the middle of a rest are dropped and counted; the rest is still detected."""
    t, xyz = _still_series(rng, 600)
    gate = InactivityGate()
    for i in range(300):
        gate.push(t[i], xyz[i])
    assert gate.push(t[300], sample) is None  # type: ignore[arg-type]
    assert gate.counters[key] == 1
    for i in range(301, 600):
        gate.push(t[i], xyz[i])
    assert gate.is_still
    assert gate.counters["resets"] == 0


def test_bad_gyro_and_stamp_are_counted(rng: np.random.Generator) -> None:
    """A NaN gyro drops the sample; a NaN stamp is a time drop."""
    gate = InactivityGate(gyro_threshold=0.1)
    assert gate.push(0.0, [0.0, 0.0, G], [np.nan, 0.0, 0.0]) is None
    assert gate.push(float("nan"), [0.0, 0.0, G]) is None
    assert gate.counters["dropped_nonfinite"] == 1
    assert gate.counters["dropped_time"] == 1


def test_repeated_backwards_and_gapped_stamps(rng: np.random.Generator) -> None:
    """Repeated and slightly backwards stamps are dropped; a gap or a big jump back resets the window."""
    t, xyz = _still_series(rng, 400)
    gate = InactivityGate()
    for i in range(300):
        gate.push(t[i], xyz[i])
    assert gate.is_still
    gate.push(t[299], xyz[299])  # repeated
    gate.push(t[299] - 0.5, xyz[299])  # backwards within a window
    assert gate.counters["dropped_time"] == 2
    assert gate.is_still
    gate.push(t[299] + 5.0, xyz[299])  # gap longer than the window
    assert gate.counters["resets"] == 1
    assert not gate.is_still
    gate.push(t[0] - 100.0, xyz[0])  # replay restarted
    assert gate.counters["resets"] == 2


def test_running_sums_do_not_drift(rng: np.random.Generator) -> None:
    """After 20k samples the O(1) window statistics equal a direct computation on the last window."""
    n = 20_000
    t, xyz = _still_series(rng, n)
    xyz = xyz + 1e4  # a large common offset stresses the running sums
    gate = InactivityGate(cv_threshold=1.0, axis_threshold=1.0)
    for i in range(n):
        gate.push(t[i], xyz[i])
    win = xyz[t > t[-1] - 2.0 + 1e-6]  # the last 2 s: 200 samples at 100 Hz
    nrm = np.linalg.norm(win, axis=1)
    cv, axis = gate.window_stats
    assert cv == pytest.approx(nrm.std() / nrm.mean(), rel=1e-6)
    assert axis == pytest.approx(win.std(axis=0).max() / nrm.mean(), rel=1e-6)


def test_raw_accelerometer_through_true_calibration(rng: np.random.Generator) -> None:
    """Raw (offset, scaled) data: emitted means map back to |g| through the true calibration."""
    truth = Calibration(np.array([0.3, -0.2, 0.1]), np.diag([1.02, 0.98, 1.01]), norm=G, sensor="accel")
    t, f = _still_series(rng, 1000)
    raw = truth.inverse_apply(f)
    _, out = _run(InactivityGate(), t, raw)
    assert out
    err = np.linalg.norm(truth.apply(np.array([e for _, e in out])), axis=1) - G
    assert np.abs(err).max() < 3 * 0.002 * G / math.sqrt(100)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"window_s": 0.0}, "window_s"),
        ({"cv_threshold": -1.0}, "cv_threshold"),
        ({"axis_threshold": float("nan")}, "axis_threshold"),
        ({"gyro_threshold": 0.0}, "gyro_threshold"),
        ({"min_still_s": -1.0}, "min_still_s"),
        ({"max_per_stretch": 0}, "max_per_stretch"),
    ],
)
def test_bad_gate_options(kwargs: dict[str, float], match: str) -> None:
    """Out-of-range options raise ConfigError naming the option."""
    with pytest.raises(ConfigError, match=match):
        InactivityGate(**kwargs)  # type: ignore[arg-type]


def test_a_huge_finite_gyro_means_rotating_not_invalid() -> None:
    """A finite gyro whose squared norm overflows (1e160 rad/s) marks the window as rotating; it is
    not a non-finite sample, and the gate emits again once the rates are sane and still."""
    gate = InactivityGate(window_s=1.0, gyro_threshold=0.1)
    g = np.array([0.0, 0.0, 9.81])
    for k in range(50):
        assert gate.push(0.02 * k, g, [1e160, 0.0, 0.0]) is None
    assert gate.counters["dropped_nonfinite"] == 0
    assert gate.push(1.0, g, [math.nan, 0.0, 0.0]) is None
    assert gate.counters["dropped_nonfinite"] == 1
    emitted = [gate.push(1.0 + 0.02 * k, g, [0.0, 0.0, 0.0]) for k in range(200)]
    assert any(e is not None for e in emitted)
