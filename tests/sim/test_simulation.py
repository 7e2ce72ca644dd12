"""Tests of the simulator: true sensors, coverage patterns, effects, motion time series."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import ConfigError, InputError
from ros_margcal.sim.simulation import (
    EFFECTS,
    GRAVITY,
    PATTERNS,
    HardIronJump,
    OffsetDrift,
    directions,
    magnetometer_stream,
    random_sensor,
    simulate,
    tumbling,
    tumbling_motion,
)

SEED = 20261121


def _rng(seed: int = SEED) -> np.random.Generator:
    return np.random.default_rng(seed)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _quadric_residual(points: np.ndarray) -> float:
    """Smallest singular value of the general-quadric design matrix, relative: ~0 iff on one ellipsoid."""
    p = points / np.abs(points).max()
    x, y, z = p.T
    d = np.column_stack([x * x, y * y, z * z, x * y, x * z, y * z, x, y, z, np.ones_like(x)])
    s = np.linalg.svd(d, compute_uv=False)
    return float(s[-1] / s[0])


def _sensor_for(name: str) -> str:
    return "mag" if "mag" in EFFECTS[name].sensors else "accel"


# -- random_sensor ---------------------------------------------------------------------------------


def test_random_mag_sensor_is_realistic() -> None:
    """A magnetometer truth: 50 µT norm, hard iron up to 3x the field, gains ±5 %, cross terms ±2 %."""
    for seed in range(20):
        cal = random_sensor(_rng(seed), "mag")
        gain = np.linalg.inv(cal.matrix)
        assert cal.norm == pytest.approx(50e-6)
        assert cal.sensor == "mag" and cal.unit == "T" and cal.model == "sym"
        assert np.linalg.norm(cal.offset) <= 3 * cal.norm + 1e-18
        assert np.all(np.abs(np.diag(gain) - 1) <= 0.05 + 1e-12)
        assert np.all(np.abs(gain - np.diag(np.diag(gain))) <= 0.02 + 1e-12)
        np.testing.assert_allclose(cal.matrix, cal.matrix.T, atol=1e-15)


def test_random_accel_sensor_is_realistic() -> None:
    """An accelerometer truth: norm 9.80665 m/s², offsets 0.1-0.5 m/s² per axis."""
    for seed in range(20):
        cal = random_sensor(_rng(seed), "accel")
        assert cal.norm == GRAVITY and cal.unit == "m/s^2"
        assert np.all((np.abs(cal.offset) >= 0.09) & (np.abs(cal.offset) <= 0.5))


@pytest.mark.parametrize("model", ["eye", "diag"])
def test_random_sensor_models(model: str) -> None:
    """'eye' has no gains, 'diag' no cross terms."""
    cal = random_sensor(_rng(), "mag", model=model)
    assert cal.model == model
    assert np.count_nonzero(cal.matrix - np.diag(np.diag(cal.matrix))) == 0
    if model == "eye":
        np.testing.assert_array_equal(cal.matrix, np.eye(3))


@pytest.mark.parametrize(("kwargs", "match"), [({"kind": "gyro"}, "kind"), ({"model": "full"}, "model")])
def test_random_sensor_rejects_bad_options(kwargs: dict[str, str], match: str) -> None:
    """Unknown sensor kinds and models are refused."""
    with pytest.raises(ConfigError, match=match):
        random_sensor(_rng(), **kwargs)


# -- directions ------------------------------------------------------------------------------------


@pytest.mark.parametrize("pattern", PATTERNS)
def test_patterns_are_unit_vectors_and_deterministic(pattern: str) -> None:
    """Every pattern gives (n, 3) unit vectors, the same for the same seed."""
    a = directions(pattern, 301, _rng())
    b = directions(pattern, 301, _rng())
    assert a.shape == (301, 3)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, directions(pattern, 301, _rng(SEED + 1)))


def test_uniform_is_uniform() -> None:
    """Uniform directions have mean ~0 and second moment ~I/3."""
    d = directions("uniform", 20000, _rng())
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=0.02)
    np.testing.assert_allclose(d.T @ d / len(d), np.eye(3) / 3, atol=0.01)


@pytest.mark.parametrize(("half", "axis"), [(10.0, (0, 0, 1)), (60.0, (1, -2, 0.5)), (150.0, (0, 0, -1))])
def test_cap_respects_half_angle_and_axis(half: float, axis: tuple[float, float, float]) -> None:
    """Cap points lie within the half-angle of the axis and reach close to it."""
    d = directions("cap", 5000, _rng(), half_angle_deg=half, axis=axis)
    ang = _angle_deg(d, np.asarray(axis, dtype=float))
    assert ang.max() <= half + 1e-9
    assert ang.max() > half - 2.0
    # equal-area: the median angle splits the cap's area in half
    expected = np.degrees(np.arccos((1 + np.cos(np.radians(half))) / 2))
    assert np.median(ang) == pytest.approx(expected, abs=0.03 * half + 0.5)


def test_band_respects_latitudes() -> None:
    """Band points have latitudes between the bounds about the axis."""
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    d = directions("band", 4000, _rng(), lat_min_deg=10.0, lat_max_deg=35.0, axis=axis)
    lat = np.degrees(np.arcsin(d @ axis))
    assert lat.min() >= 10.0 - 1e-9 and lat.max() <= 35.0 + 1e-9
    assert lat.min() < 11.0 and lat.max() > 34.0


def test_great_circle_lies_on_circles_within_the_arc() -> None:
    """One great circle: coplanar through the origin, spanning at most arc_deg."""
    d = directions("great_circle", 500, _rng(), arc_deg=90.0)
    assert np.linalg.svd(d, compute_uv=False)[-1] < 1e-10
    normal = np.linalg.svd(d)[2][-1]
    u = d[0]
    v = np.cross(normal, u)
    ang = np.degrees(np.arctan2(d @ v, d @ u))
    span = np.ptp(np.unwrap(np.radians(np.sort(ang))))
    assert np.degrees(span) <= 90.0 + 1e-6
    three = directions("great_circle", 600, _rng(), n_circles=3)
    for k in range(3):
        assert np.linalg.svd(three[k::3], compute_uv=False)[-1] < 1e-10


def test_axis_ellipses_lie_on_three_orthogonal_circles() -> None:
    """Olivares Fig. 7: every point has one zero coordinate; a third of the points on each plane."""
    d = directions("axis_ellipses", 300, _rng())
    zero = np.abs(d) < 1e-12
    assert np.all(zero.sum(axis=1) >= 1)
    counts = zero.sum(axis=0)
    np.testing.assert_array_equal(counts, [100, 100, 100])
    for k in range(3):  # each circle is covered all round
        on = d[zero[:, k]]
        others = [i for i in range(3) if i != k]
        ang = np.degrees(np.arctan2(on[:, others[1]], on[:, others[0]]))
        assert np.histogram(ang, bins=8, range=(-180, 180))[0].min() > 0


def test_random_walk_step_size() -> None:
    """Consecutive random-walk directions are about step_deg apart."""
    d = directions("random_walk", 3000, _rng(), step_deg=3.0)
    steps = _angle_deg(d[1:], d[:-1])
    assert np.sqrt(np.mean(steps**2)) == pytest.approx(3.0, rel=0.1)


def test_few_uniform_clusters() -> None:
    """few_uniform: k poses, each sample within a few jitter widths of its pose."""
    d = directions("few_uniform", 600, _rng(), k=4, jitter_deg=1.0)
    for k in range(4):
        group = d[k::4]
        centre = group.mean(axis=0)
        assert _angle_deg(group, centre).max() < 6.0


@pytest.mark.parametrize(
    ("pattern", "params", "match"),
    [
        ("spiral", {}, "unknown pattern"),
        ("cap", {"half_angle_deg": 0.0}, "half_angle_deg"),
        ("cap", {"radius": 1.0}, "takes"),
        ("band", {"lat_min_deg": 30.0, "lat_max_deg": 10.0}, "band needs"),
        ("great_circle", {"arc_deg": 0.0}, "great_circle needs"),
        ("few_uniform", {"k": 0}, "k must be"),
        ("cap", {"axis": (0.0, 0.0, 0.0)}, "non-zero"),
    ],
)
def test_directions_rejects_bad_parameters(pattern: str, params: dict[str, object], match: str) -> None:
    """Bad patterns and parameters raise ConfigError naming the problem."""
    with pytest.raises(ConfigError, match=match):
        directions(pattern, 10, _rng(), **params)


# -- simulate --------------------------------------------------------------------------------------


def test_noiseless_data_lie_on_the_true_ellipsoid(true_cal: Calibration) -> None:
    """truth.apply(raw) has the reference norm exactly, and equals the true field."""
    rec = simulate(true_cal, directions("uniform", 500, _rng()), rng=_rng())
    np.testing.assert_allclose(true_cal.norm_error(rec.raw), 0.0, atol=1e-10)
    np.testing.assert_allclose(true_cal.apply(rec.raw), rec.true_field, atol=1e-10)
    assert rec.raw.shape == (500, 3) and rec.t.shape == (500,)
    np.testing.assert_array_equal(rec.t, np.arange(500.0))


def test_noise_level_is_a_fraction_of_the_norm(true_cal: Calibration) -> None:
    """With noise=1 % the calibrated norm scatters by ~1 % of the norm."""
    rec = simulate(true_cal, directions("uniform", 20000, _rng()), noise=0.01, rng=_rng())
    err = true_cal.norm_error(rec.raw)
    radius_raw = true_cal.norm / abs(np.linalg.det(true_cal.matrix)) ** (1 / 3)
    expected = 0.01 * radius_raw * abs(np.linalg.det(true_cal.matrix)) ** (1 / 3)
    assert np.std(err) == pytest.approx(expected, rel=0.05)
    assert abs(np.mean(err)) < 0.05 * expected


def test_simulate_is_deterministic(true_cal: Calibration) -> None:
    """Same seed, same data (with every applicable effect on); another seed, other data."""
    dirs = directions("uniform", 200, _rng())
    effects = {n: e.default_magnitude for n, e in EFFECTS.items() if "mag" in e.sensors}
    a = simulate(true_cal, dirs, noise=0.01, rng=_rng(), effects=effects)
    b = simulate(true_cal, dirs, noise=0.01, rng=_rng(), effects=effects)
    c = simulate(true_cal, dirs, noise=0.01, rng=_rng(1), effects=effects)
    np.testing.assert_array_equal(a.raw, b.raw)
    assert not np.array_equal(a.raw, c.raw)


def _pair(name: str, magnitude: float, n: int = 2000, noise: float = 0.0):
    truth = random_sensor(_rng(3), _sensor_for(name))
    dirs = directions("uniform", n, _rng(4))
    t = np.arange(n) * 0.1
    base = simulate(truth, dirs, noise=noise, rng=_rng(5), t=t)
    rec = simulate(truth, dirs, noise=noise, rng=_rng(5), t=t, effects={name: magnitude})
    return truth, base, rec


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_magnitude_zero_changes_nothing(name: str) -> None:
    """Every effect at magnitude 0 reproduces the effect-free data bit for bit."""
    _, base, rec = _pair(name, 0.0, noise=0.01)
    np.testing.assert_array_equal(rec.raw, base.raw)


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_effect_grows_monotonically_with_magnitude(name: str) -> None:
    """The change an effect makes grows with its magnitude across its search range."""
    lo, hi = EFFECTS[name].magnitude_range
    sizes = []
    for m in np.linspace(lo, hi, 6)[1:]:
        truth, base, rec = _pair(name, float(m), noise=0.01)
        sizes.append(float(np.sqrt(np.mean((rec.raw - base.raw) ** 2))) / truth.norm)
    assert sizes[0] > 0
    assert all(b > a for a, b in itertools.pairwise(sizes)), sizes


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_calibration_residual_grows_with_magnitude(name: str) -> None:
    """What a norm-based calibration sees (the truth's norm residual) grows over the search range;
    misalignment alone leaves it untouched (it is unobservable)."""
    lo, hi = EFFECTS[name].magnitude_range
    rms = []
    for m in np.linspace(lo, hi, 6):
        truth, _, rec = _pair(name, float(m), n=3000, noise=0.005)
        rms.append(float(np.sqrt(np.mean(truth.norm_error(rec.raw) ** 2)) / truth.norm))
    if EFFECTS[name].observable:
        assert all(b > a for a, b in itertools.pairwise(rms)), rms
    else:
        np.testing.assert_allclose(rms, rms[0], rtol=3e-3)  # only the noise projection moves


def test_registry_is_complete_and_consistent() -> None:
    """The effects of DESIGN.md are all there, with sane metadata."""
    expected = {"noise", "quantization", "nonorthogonality", "soft_iron", "misalignment", "bias_drift",
                "temperature", "disturbance", "motion_leak", "saturation", "nonlinearity"}
    assert expected <= set(EFFECTS)
    assert EFFECTS["nonorthogonality"].group == EFFECTS["soft_iron"].group == "ellipsoid_shape"
    assert not EFFECTS["misalignment"].observable
    assert sum(not e.observable for e in EFFECTS.values()) == 1
    for e in EFFECTS.values():
        lo, hi = e.magnitude_range
        assert lo == 0.0 < e.default_magnitude <= hi < e.limit
        assert set(e.sensors) <= {"mag", "accel"} and e.description and e.magnitude_unit


def test_misalignment_keeps_the_norm_and_rotates_by_the_magnitude() -> None:
    """Misalignment is invisible to the norm and rotates every vector by exactly m degrees."""
    truth, _, rec = _pair("misalignment", 3.0)
    np.testing.assert_allclose(truth.norm_error(rec.raw), 0.0, atol=1e-9 * truth.norm)
    ang = _angle_deg(truth.apply(rec.raw), rec.true_field)
    assert ang.max() <= 3.0 + 1e-6 and ang.max() > 2.9


@pytest.mark.parametrize("name", ["soft_iron", "nonorthogonality"])
def test_shape_effects_keep_an_ellipsoid(name: str) -> None:
    """Soft iron and skewed axes change the norm but the data stay on one ellipsoid (same family)."""
    truth, _, rec = _pair(name, EFFECTS[name].default_magnitude * 2)
    assert np.std(truth.norm_error(rec.raw)) > 1e-3 * truth.norm
    assert _quadric_residual(rec.raw) < 1e-9


def test_nonlinearity_leaves_the_ellipsoid() -> None:
    """A cubic term of the whole reading cannot be absorbed by any ellipsoid, and deviates by ~m at the
    largest reading (offset included: an ADC sees the raw value)."""
    truth, base, rec = _pair("nonlinearity", 0.02)
    assert _quadric_residual(rec.raw) > 1e-5
    dev = np.abs(rec.raw - base.raw).max(axis=0)
    r_full = np.abs(truth.offset) + truth.norm * np.linalg.norm(np.linalg.inv(truth.matrix), axis=1)
    assert np.all(dev <= 0.02 * r_full * 1.0001)
    assert np.all(dev > 0.02 * r_full * 0.3)


def test_nonlinearity_of_an_offset_reading_is_quadratic_in_the_field() -> None:
    """With an offset the cubic term of the raw reading has a part even in the field (3 m c b u^2 / r^2),
    which a cubic of the offset-free reading lacks: opposite directions no longer mirror about b."""
    truth = random_sensor(_rng(3), "mag")
    dirs = directions("uniform", 500, _rng(4))
    both = np.vstack([dirs, -dirs])
    rec = simulate(truth, both, noise=0.0, rng=_rng(5), effects={"nonlinearity": 0.05}).raw
    even = 0.5 * (rec[:500] + rec[500:]) - truth.offset  # the part even in the field, offset removed
    spread = np.ptp(even, axis=0)  # a constant (b^3 term) is an offset; the u^2 term varies with direction
    u_axis = truth.norm * np.linalg.norm(np.linalg.inv(truth.matrix), axis=1)
    r_full = np.abs(truth.offset) + u_axis
    expected = 0.05 * 3 * np.abs(truth.offset) * u_axis**2 / r_full**2  # |c| in [0.5, 1]
    assert np.all(spread > 0.3 * expected)
    assert np.all(spread < 1.05 * expected)


def test_quantization_rounds_to_the_lsb() -> None:
    """Quantised readings are integer multiples of the LSB step."""
    truth, _, rec = _pair("quantization", 0.004, noise=0.01)
    step = 0.004 * truth.norm / abs(np.linalg.det(truth.matrix)) ** (1 / 3)
    np.testing.assert_allclose(rec.raw / step, np.round(rec.raw / step), atol=1e-6)


def test_saturation_clips_at_the_full_scale() -> None:
    """Readings are clipped at (1 - m) of the largest clean reading; some are clipped."""
    _, base, rec = _pair("saturation", 0.2)
    full = 0.8 * np.max(np.abs(base.raw))  # the largest clean reading of the recording
    assert np.abs(rec.raw).max() == pytest.approx(full)
    changed = np.any(rec.raw != base.raw, axis=1)
    assert 0 < changed.sum() < len(changed)
    np.testing.assert_allclose(np.abs(rec.raw[changed]).max(axis=1), full)


def test_bias_drift_moves_only_the_offset() -> None:
    """Under bias drift the data are exact for the recorded time-varying offset."""
    truth, _, rec = _pair("bias_drift", 0.05)
    assert rec.true_offset is not None
    moved = np.linalg.norm(rec.true_offset[-1] - truth.offset) / truth.norm
    assert moved > 0.05  # 200 s at 5 %/min drifts by ~0.17 of the norm
    h = (rec.raw - rec.true_offset) @ truth.matrix.T
    np.testing.assert_allclose(np.linalg.norm(h, axis=1), truth.norm, rtol=1e-9)


def test_temperature_effect_follows_the_temperature() -> None:
    """The norm error follows the temperature; a constant temperature changes nothing."""
    truth, base, rec = _pair("temperature", 0.005)
    assert rec.temp is not None and rec.temp.max() - rec.temp.min() > 10
    n = len(base)
    flat = simulate(truth, base.true_field, rng=_rng(5), t=base.t, effects={"temperature": 0.005},
                    temperature=np.full(n, 31.0))
    np.testing.assert_allclose(flat.raw, base.raw, rtol=0, atol=1e-15 * truth.norm)
    ramp = np.linspace(10.0, 40.0, n)
    hot = simulate(truth, base.true_field, rng=_rng(5), t=base.t, effects={"temperature": 0.005}, temperature=ramp)
    np.testing.assert_array_equal(hot.temp, ramp)
    shift = np.linalg.norm(hot.raw - base.raw, axis=1)
    assert np.corrcoef(shift, np.abs(ramp - ramp.mean()))[0, 1] > 0.7


def test_hard_iron_jump_steps_the_offset_once() -> None:
    """The offset steps once, in the middle half of the recording, by magnitude x field radius."""
    truth, base, rec = _pair("hard_iron_jump", 0.2)
    assert rec.true_offset is not None
    step = np.linalg.norm(rec.true_offset - truth.offset, axis=1)
    r_raw = truth.norm / abs(np.linalg.det(truth.matrix)) ** (1.0 / 3.0)
    moved = step > 0
    first = int(np.argmax(moved))
    assert moved[first:].all() and not moved[:first].any()  # one step, kept to the end
    assert 0.25 <= (base.t[first] - base.t[0]) / (base.t[-1] - base.t[0]) <= 0.75
    np.testing.assert_allclose(step[moved], 0.2 * r_raw, rtol=1e-9)
    np.testing.assert_allclose(rec.raw - base.raw, rec.true_offset - truth.offset, atol=1e-12 * truth.norm)


def test_hard_iron_jump_is_magnetometer_only() -> None:
    """A hard-iron jump is a magnetic effect: an accelerometer refuses it."""
    acc = random_sensor(_rng(2), "accel")
    with pytest.raises(ConfigError, match="applies to"):
        simulate(acc, directions("uniform", 10, _rng()), rng=_rng(), effects={"hard_iron_jump": 0.1})


@pytest.mark.parametrize(("name", "share"), [("disturbance", 0.05), ("motion_leak", 0.2)])
def test_bursts_touch_about_their_share_of_samples(name: str, share: float) -> None:
    """Disturbances / leaked motion hit about their documented share of the time, in windows."""
    _, base, rec = _pair(name, EFFECTS[name].default_magnitude, n=6000)
    changed = np.any(rec.raw != base.raw, axis=1)
    assert share * 0.4 < changed.mean() < share * 2.0
    runs = np.count_nonzero(np.diff(changed.astype(int)) == 1)
    assert runs < changed.sum() / 2  # contiguous windows, not scattered samples


def test_noise_effect_adds_white_noise() -> None:
    """The noise effect adds white noise of std m x norm."""
    truth, base, rec = _pair("noise", 0.02, n=20000)
    radius = truth.norm / abs(np.linalg.det(truth.matrix)) ** (1 / 3)
    assert np.std(rec.raw - base.raw) == pytest.approx(0.02 * radius, rel=0.03)


@pytest.mark.parametrize(
    ("effects", "error", "match"),
    [
        ({"wobble": 1.0}, ConfigError, "unknown effect"),
        ({"noise": -0.1}, ConfigError, "magnitude"),
        ({"noise": float("nan")}, ConfigError, "magnitude"),
        ({"saturation": 1.0}, ConfigError, "magnitude"),
        ({"motion_leak": 0.1}, ConfigError, "applies to"),
    ],
)
def test_simulate_rejects_bad_effects(true_cal: Calibration, effects: dict[str, float], error: type, match: str) -> None:
    """Unknown effects, bad magnitudes and effects of another sensor are refused."""
    with pytest.raises(error, match=match):
        simulate(true_cal, directions("uniform", 10, _rng()), rng=_rng(), effects=effects)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"dirs": np.zeros((5, 3))}, InputError, "zero vectors"),
        ({"dirs": np.ones((5, 2))}, InputError, "shape"),
        ({"t": np.arange(4.0)}, InputError, "one time per direction"),
        ({"t": np.array([0.0, 2.0, 1.0, 3.0, 4.0])}, InputError, "non-decreasing"),
        ({"temperature": np.ones(3)}, InputError, "temperature"),
        ({"noise": -1.0}, ConfigError, "noise"),
    ],
)
def test_simulate_rejects_bad_input(true_cal: Calibration, kwargs: dict[str, object], error: type, match: str) -> None:
    """Bad directions, times, temperatures and noise are refused with a clear message."""
    args: dict[str, object] = {"dirs": directions("uniform", 5, _rng())}
    args.update(kwargs)
    dirs = args.pop("dirs")
    with pytest.raises(error, match=match):
        simulate(true_cal, dirs, rng=_rng(), **args)  # type: ignore[arg-type]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(["mag", "accel"]),
       pattern=st.sampled_from(PATTERNS), noise=st.floats(0.0, 0.02))
def test_property_truth_recovers_the_norm(seed: int, kind: str, pattern: str, noise: float) -> None:
    """For any sensor and pattern, the truth calibrates the raw data to the norm up to the noise."""
    rng = np.random.default_rng(seed)
    truth = random_sensor(rng, kind)
    rec = simulate(truth, directions(pattern, 200, rng), noise=noise, rng=rng)
    err = truth.norm_error(rec.raw) / truth.norm
    assert np.sqrt(np.mean(err**2)) <= 1.5 * noise * 1.06 + 1e-12


# -- motion time series ----------------------------------------------------------------------------


def test_tumbling_still_periods_and_motion() -> None:
    """Tumbling: still samples read gravity with zero rate; moves have rate and linear acceleration."""
    truth = random_sensor(_rng(1), "accel")
    rec = tumbling(truth, 120.0, 100.0, _rng(2), still_fraction=0.6, noise=0.0, gyro_noise=0.0)
    assert len(rec) == 12000 and rec.gyro is not None and rec.still is not None
    assert 0.5 < rec.still.mean() < 0.7
    f = np.linalg.norm(rec.true_field, axis=1)
    np.testing.assert_allclose(f[rec.still], GRAVITY, rtol=1e-12)
    np.testing.assert_allclose(rec.gyro[rec.still], 0.0, atol=1e-12)
    assert np.abs(f[~rec.still] - GRAVITY).max() > 0.3
    assert np.linalg.norm(rec.gyro[~rec.still], axis=1).max() > 0.5
    np.testing.assert_allclose(truth.norm_error(rec.raw[rec.still]), 0.0, atol=1e-9)
    # smooth: the gravity direction moves by less than 2 degrees per sample at 100 Hz
    assert _angle_deg(rec.true_field[1:], rec.true_field[:-1]).max() < 2.0
    # the rest orientations cover the sphere
    rest = rec.true_field[rec.still] / GRAVITY
    assert np.all(rest.max(axis=0) > 0.6) and np.all(rest.min(axis=0) < -0.6)


def test_tumbling_gyro_integrates_to_the_orientation_change() -> None:
    """The gyro is the body rate: integrating it reproduces the motion's orientation change."""
    mot = tumbling_motion(30.0, 200.0, _rng(7))
    dt = np.diff(mot.t)
    rel = (mot.rot[:-1].inv() * mot.rot[1:]).as_rotvec()
    mid = 0.5 * (mot.gyro[1:] + mot.gyro[:-1]) * dt[:, None]
    np.testing.assert_allclose(rel, mid, atol=2e-4)


def test_tumbling_is_deterministic() -> None:
    """Same seed, same tumbling series."""
    truth = random_sensor(_rng(1), "accel")
    a = tumbling(truth, 20.0, 50.0, _rng(9))
    b = tumbling(truth, 20.0, 50.0, _rng(9))
    np.testing.assert_array_equal(a.raw, b.raw)
    np.testing.assert_array_equal(a.gyro, b.gyro)


def test_magnetometer_stream_jump_and_drift() -> None:
    """A hard-iron jump changes the true offset at its time; drift moves it linearly."""
    truth = random_sensor(_rng(1), "mag")
    delta = (30e-6, -10e-6, 5e-6)
    rec = magnetometer_stream(truth, 120.0, 20.0, _rng(2), noise=0.0,
                              events=[HardIronJump(60.0, delta), OffsetDrift((1e-7, 0.0, 0.0), start=90.0)])
    before, after = rec.t < 60.0, rec.t >= 60.0
    assert rec.truth_at(10.0).allclose(truth)
    np.testing.assert_allclose(rec.truth_at(80.0).offset, truth.offset + delta)
    np.testing.assert_allclose(rec.truth_at(100.0).offset, truth.offset + delta + np.array([1e-6, 0, 0]), rtol=1e-3)
    np.testing.assert_allclose(truth.norm_error(rec.raw[before]), 0.0, atol=1e-12)
    assert np.abs(truth.norm_error(rec.raw[after])).mean() > 0.1 * truth.norm
    for i in (0, 1300, 1900, 2399):
        assert abs(rec.truth_at(rec.t[i]).norm_error(rec.raw[i])[0]) < 1e-12


@pytest.mark.parametrize("motion", ["smooth", "tumble"])
def test_magnetometer_stream_covers_the_sphere(motion: str) -> None:
    """Within two minutes the body-frame field visits directions all round the sphere."""
    truth = random_sensor(_rng(1), "mag")
    rec = magnetometer_stream(truth, 120.0, 20.0, _rng(2), motion=motion)
    d = rec.true_field / truth.norm
    assert np.all(d.max(axis=0) > 0.8) and np.all(d.min(axis=0) < -0.8)
    assert _angle_deg(d[1:], d[:-1]).max() < 10.0


def test_shared_motion_makes_a_consistent_imu() -> None:
    """Accelerometer and magnetometer can share one motion: at rest the angle gravity-field is fixed."""
    mot = tumbling_motion(60.0, 100.0, _rng(3))
    acc = tumbling(random_sensor(_rng(4), "accel"), 60.0, 100.0, _rng(5), motion=mot, noise=0.0)
    mag = magnetometer_stream(random_sensor(_rng(6), "mag"), 60.0, 50.0, _rng(7), motion=mot, noise=0.0)
    still = mag.still
    assert still is not None and still.any()
    g = acc.true_field[::2][still]
    ang = _angle_deg(g, mag.true_field[still])
    np.testing.assert_allclose(ang, 90.0 + 60.0, atol=1e-6)  # up vs a field 60° below the horizon


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: tumbling(random_sensor(_rng(), "accel"), -1.0, 100.0, _rng()), "duration_s"),
        (lambda: tumbling(random_sensor(_rng(), "accel"), 10.0, 100.0, _rng(), still_fraction=0.0), "still_fraction"),
        (lambda: magnetometer_stream(random_sensor(_rng(), "mag"), 10.0, 10.0, _rng(), motion="spin"), "motion"),
    ],
)
def test_time_series_reject_bad_options(call: object, match: str) -> None:
    """Bad durations, fractions and motions are refused."""
    with pytest.raises(ConfigError, match=match):
        call()  # type: ignore[operator]
