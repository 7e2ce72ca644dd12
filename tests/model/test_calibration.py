"""The calibration value: apply/inverse, the papers' parametrisations, YAML round trip, file errors."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ros_margcal.model.calibration import Calibration, FitStats
from ros_margcal.model.calibration_file import calibration_from_yaml, calibration_to_yaml, load_calibrations, save_calibrations
from ros_margcal.model.errors import CalibrationFileError, InputError, MargCalError, as_points


def test_apply_one_and_many(true_cal: Calibration, rng: np.random.Generator) -> None:
    """apply works on one sample and on arrays, and inverse_apply undoes it."""
    h = rng.normal(size=(50, 3))
    raw = true_cal.inverse_apply(h)
    np.testing.assert_allclose(true_cal.apply(raw), h, atol=1e-12)
    np.testing.assert_allclose(true_cal.apply(raw[0]), h[0], atol=1e-12)
    np.testing.assert_allclose(true_cal.apply(raw), (raw - true_cal.offset) @ true_cal.matrix.T)


def test_norm_error_zero_on_the_ellipsoid(true_cal: Calibration, rng: np.random.Generator) -> None:
    """Raw points made from vectors of the reference norm have zero norm error."""
    u = rng.normal(size=(20, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    raw = true_cal.inverse_apply(true_cal.norm * u)
    np.testing.assert_allclose(true_cal.norm_error(raw), 0.0, atol=1e-10)
    assert true_cal.norm_error(raw + 5.0).std() > 1.0


def test_gietzelt_parametrisation() -> None:
    """Gietzelt Eq. 1: a point on the ellipsoid with centre o and radii s maps to the norm."""
    cal = Calibration.from_gietzelt([2300, 2300, 2300], [500, 300, 500], norm=1.0)
    np.testing.assert_allclose(cal.norm_error([[2800, 2300, 2300], [2300, 2000, 2300]]), 0.0, atol=1e-15)
    assert cal.model == "diag"


def test_quadric_parametrisation(true_cal: Calibration) -> None:
    """Gietzelt Eq. 2: the quadric A = (W/norm)^T (W/norm) gives back the symmetric W."""
    w = true_cal.matrix / true_cal.norm
    cal = Calibration.from_quadric(true_cal.offset, w.T @ w, norm=true_cal.norm)
    np.testing.assert_allclose(cal.matrix, true_cal.matrix, rtol=1e-12)


def test_camps_round_trip() -> None:
    """Camps Eq. 6: V = alpha h + beta; to_camps gives back alpha, beta and s_ij."""
    alpha, beta, s = [7.2019, 7.4019, 7.6285], [0.19002, 0.2237, 0.2347], [0.01711, 0.1421, -0.0494]
    cal = Calibration.from_camps(alpha, beta, s, norm=0.47)
    h = np.array([0.1, -0.2, 0.4])
    gain = np.array([[alpha[0], s[0], s[1]], [s[0], alpha[1], s[2]], [s[1], s[2], alpha[2]]])
    np.testing.assert_allclose(cal.apply(gain @ h + beta), h, atol=1e-12)
    a2, b2, s2 = cal.to_camps()
    np.testing.assert_allclose(np.r_[a2, b2, s2], np.r_[alpha, beta, s], rtol=1e-12)


def test_yaml_round_trip_keeps_everything(tmp_path: Path, true_cal: Calibration) -> None:
    """save/load keeps offset, matrix, norm, stats, covariance and names, and leaves no temp file."""
    names = ("b_x", "b_y", "b_z")
    cal = true_cal.replace(
        stats=FitStats(n_points=100, rms=0.1, max_abs=0.3, rms_relative=0.002, iterations=7),
        covariance=np.diag([1e-4, 2e-4, 3e-4]),
        parameter_names=names,
        method="lm",
        stamp=12.5,
    )
    path = save_calibrations(tmp_path / "cal.yaml", {"mag": cal, "accel": Calibration.identity(9.80665)})
    assert [p.name for p in tmp_path.iterdir()] == ["cal.yaml"]
    assert path.stat().st_mode & 0o044, "a calibration file must be readable by other users (params file)"
    back = load_calibrations(path)
    assert set(back) == {"mag", "accel"}
    assert back["mag"].allclose(cal, rtol=0, atol=0)
    assert back["mag"].stats == cal.stats
    assert back["mag"].parameter_std() == pytest.approx({"b_x": 1e-2, "b_y": np.sqrt(2e-4), "b_z": np.sqrt(3e-4)})
    doc = yaml.safe_load(path.read_text())
    assert doc["margcal"]["ros__parameters"]["calibration"]["mag"]["format_version"] == 2
    assert all(isinstance(x, float) for x in doc["margcal"]["ros__parameters"]["calibration"]["mag"]["matrix"])


@settings(max_examples=50, deadline=None)
@given(
    offset=arrays(np.float64, 3, elements=st.floats(-1e3, 1e3)),
    diag=arrays(np.float64, 3, elements=st.floats(0.2, 5.0)),
    off=arrays(np.float64, 3, elements=st.floats(-0.05, 0.05)),
    norm=st.floats(1e-6, 1e5),
)
def test_yaml_text_round_trip_is_exact(offset: np.ndarray, diag: np.ndarray, off: np.ndarray, norm: float) -> None:
    """Any calibration survives to_yaml_text/from_yaml_text bit for bit."""
    w = np.diag(diag)
    w[0, 1] = w[1, 0] = off[0] * diag.min()
    w[0, 2] = w[2, 0] = off[1] * diag.min()
    w[1, 2] = w[2, 1] = off[2] * diag.min()
    cal = Calibration(offset, w, norm, sensor="mag")
    back = calibration_from_yaml(calibration_to_yaml(cal))
    assert back.allclose(cal, rtol=0, atol=0)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("{not yaml: [", "not valid YAML"),
        ("- 1\n- 2\n", "not a ros__parameters"),
        ("margcal:\n  ros__parameters:\n    other: 1\n", "no '<node>: ros__parameters: calibration:'"),
        ("n:\n  ros__parameters:\n    calibration:\n      mag: {offset: [0, 0, 0]}\n", "no integer format_version"),
        (
            "n:\n  ros__parameters:\n    calibration:\n      mag: {format_version: 99, offset: [0, 0, 0]}\n",
            "newer than this ros_margcal",
        ),
        (
            "n:\n  ros__parameters:\n    calibration:\n      mag: {format_version: 1, offset: [0, 0], matrix: [1, 0, 0, 0, 1, 0, 0, 0, 1], norm: 1.0}\n",
            "malformed",
        ),
        (
            "n:\n  ros__parameters:\n    calibration:\n      mag: {format_version: 1, offset: [0, 0, 0], matrix: [0, 0, 0, 0, 0, 0, 0, 0, 0], norm: 1.0}\n",
            "malformed",
        ),
    ],
)
def test_bad_files_are_refused(tmp_path: Path, text: str, match: str) -> None:
    """Corrupt, foreign, newer and malformed files raise CalibrationFileError naming the problem."""
    p = tmp_path / "cal.yaml"
    p.write_text(text)
    with pytest.raises(CalibrationFileError, match=match):
        load_calibrations(p)


def test_missing_file_is_refused(tmp_path: Path) -> None:
    """A file that does not exist is a CalibrationFileError, not an OSError."""
    with pytest.raises(CalibrationFileError, match="cannot read"):
        load_calibrations(tmp_path / "absent.yaml")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"offset": [0.0, 0.0], "matrix": np.eye(3)}, "offset must have 3"),
        ({"offset": [0.0, np.nan, 0.0], "matrix": np.eye(3)}, "offset must be finite"),
        ({"offset": np.zeros(3), "matrix": np.eye(2)}, "3x3"),
        ({"offset": np.zeros(3), "matrix": np.zeros((3, 3))}, "invertible"),
        ({"offset": np.zeros(3), "matrix": np.eye(3), "norm": -1.0}, "positive"),
        ({"offset": np.zeros(3), "matrix": np.eye(3), "model": "full"}, "model must be one of"),
        ({"offset": np.zeros(3), "matrix": np.eye(3), "covariance": np.eye(2), "parameter_names": ("a",)}, "1x1"),
    ],
)
def test_bad_values_are_refused(kwargs: dict, match: str) -> None:
    """Invalid calibration values raise InputError (a MargCalError and a ValueError)."""
    with pytest.raises(InputError, match=match):
        Calibration(**kwargs)


@pytest.mark.parametrize(("smallest", "ok"), [(1e-3, True), (1e-11, True), (1e-13, False), (0.0, False)])
def test_near_singular_matrix(smallest: float, ok: bool) -> None:
    """The invertibility check (closed-form 1-norm condition, limit 1e12) accepts or refuses by conditioning."""
    rot = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    matrix = (rot * np.array([1.0, 0.5, smallest])) @ rot.T
    if ok:
        assert Calibration(np.zeros(3), matrix).matrix.shape == (3, 3)
    else:
        with pytest.raises(InputError, match="invertible"):
            Calibration(np.zeros(3), matrix)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, (3, 3), elements=st.floats(-1e6, 1e6)), st.integers(-8, 8))
def test_condition_matches_numpy(matrix: np.ndarray, exponent: int) -> None:
    """The closed-form 1-norm condition number equals numpy's, at any scale."""
    from ros_margcal.model.calibration import _condition_1

    m = matrix * 10.0**exponent
    expected = np.linalg.cond(m, 1) if np.linalg.matrix_rank(m) == 3 else np.inf
    got = _condition_1(m)
    if np.isfinite(expected) and expected < 1e6:
        assert got == pytest.approx(expected, rel=1e-6)
    elif not np.isfinite(expected):
        assert got > 1e12 or not np.isfinite(got)


def test_trusted_constructor_freezes_and_checks_fields() -> None:
    """The fit's fast constructor gives the same value as the checked one, frozen, and refuses unknown fields."""
    offset, matrix = np.array([1.0, 2.0, 3.0]), np.diag([1.0, 2.0, 3.0])
    fast = Calibration._trusted(offset=offset, matrix=matrix, norm=2.0, model="diag")
    assert fast.allclose(Calibration(offset, matrix, 2.0, model="diag"), rtol=0)
    assert not fast.offset.flags.writeable and fast.stats is None and fast.parameter_names == ()
    assert vars(fast) == vars(Calibration(offset, matrix, 2.0, model="diag")) | {"offset": offset, "matrix": matrix}
    with pytest.raises(TypeError, match="unexpected keyword argument 'bogus'"):
        Calibration._trusted(offset=offset, matrix=matrix, bogus=1)  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="missing 1 required keyword-only argument: 'matrix'"):
        Calibration._trusted(offset=offset)  # type: ignore[call-arg]


def test_trusted_constructor_keywords_are_the_fields() -> None:
    """``_trusted`` spells out every dataclass field with its default: a new field must be added there too."""
    params = inspect.signature(Calibration._trusted).parameters
    fields = dataclasses.fields(Calibration)
    assert list(params) == [f.name for f in fields]
    assert all(p.kind is inspect.Parameter.KEYWORD_ONLY for p in params.values())
    for f in fields:
        expected = inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default
        assert params[f.name].default == expected, f.name


def test_trusted_fit_stats_equal_the_checked_ones() -> None:
    """``FitStats._trusted`` takes the fields in order and builds an equal, frozen value."""
    params = inspect.signature(FitStats._trusted).parameters
    assert list(params) == [f.name for f in dataclasses.fields(FitStats)]
    values = (100, 0.5, 1.5, 0.01, 3, True, 12.5)
    fast = FitStats._trusted(*values)
    assert fast == FitStats(*values) and hash(fast) == hash(FitStats(*values))
    assert dataclasses.asdict(fast) == dataclasses.asdict(FitStats(*values))
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.rms = 1.0  # type: ignore[misc]


def test_raw_radius_is_the_equal_volume_radius_of_the_raw_ellipsoid() -> None:
    """``raw_radius`` cubed is the product of the raw ellipsoid's semi-axes (``norm`` times the singular values of W^-1)."""
    w = np.array([[2.0, 0.3, 0.0], [0.3, 1.0, 0.1], [0.0, 0.1, 0.5]])
    cal = Calibration(np.array([5.0, -3.0, 1.0]), w, norm=48.0)
    semi_axes = 48.0 * np.linalg.svd(np.linalg.inv(w), compute_uv=False)
    assert cal.raw_radius**3 == pytest.approx(float(np.prod(semi_axes)), rel=1e-12)
    assert Calibration(np.zeros(3), 0.5 * np.eye(3), norm=2.0).raw_radius == pytest.approx(4.0, rel=1e-15)


def test_median_relative_error_is_the_median_norm_miss() -> None:
    """Readings 2 %, 4 % and 30 % off the norm (and one exact): the median magnitude, 3 %; none: 0."""
    cal = Calibration(np.array([1.0, 2.0, 3.0]), 2.0 * np.eye(3), norm=10.0)
    raw = cal.inverse_apply(np.array([[10.2, 0, 0], [0, -9.6, 0], [0, 0, 13.0], [6.0, 8.0, 0.0]]))
    assert cal.median_relative_error(raw) == pytest.approx(0.03, rel=1e-12)
    assert cal.median_relative_error(np.zeros((0, 3))) == 0.0


def test_rms_radius_is_the_sphere_fit_radius_of_full_coverage() -> None:
    """``rms_radius`` is the radius a least-squares sphere fit finds on readings that cover every direction (what the
    validator's training sets are normalised by); for a round sensor it is ``raw_radius``."""
    w = np.array([[1.5, -0.03, 0.0], [-0.03, 1.0, 0.05], [0.0, 0.05, 0.68]])  # axes 2.2x apart, as a real QMC5883L's
    cal = Calibration(np.array([6200.0, 250.0, 3470.0]), w, norm=1070.0)
    k = np.arange(20000) + 0.5
    polar, azim = np.arccos(1.0 - 2.0 * k / k.size), np.pi * (1.0 + 5.0**0.5) * k
    u = np.c_[np.cos(azim) * np.sin(polar), np.sin(azim) * np.sin(polar), np.cos(polar)]
    raw = cal.inverse_apply(cal.norm * u)
    a = np.c_[2.0 * raw, np.ones(len(raw))]
    sol = np.linalg.lstsq(a, (raw * raw).sum(axis=1), rcond=None)[0]
    sphere = float(np.sqrt(sol[3] + sol[:3] @ sol[:3]))
    assert cal.rms_radius == pytest.approx(sphere, rel=1e-3)
    assert cal.rms_radius > 1.05 * cal.raw_radius  # the equal-volume radius is well below it
    assert Calibration(np.zeros(3), 0.5 * np.eye(3), norm=2.0).rms_radius == pytest.approx(4.0, rel=1e-15)


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, (3, 3), elements=st.floats(-0.4, 0.4)), st.floats(1e-6, 1e3))
def test_rms_radius_is_at_least_the_equal_volume_radius(a: np.ndarray, norm: float) -> None:
    """The quadratic mean of the semi-axes is never below their geometric mean (equal for a round ellipsoid)."""
    cal = Calibration(np.zeros(3), np.eye(3) + 0.5 * (a + a.T), norm=norm)
    assert cal.rms_radius >= cal.raw_radius * (1.0 - 1e-12)


def test_arrays_are_read_only(true_cal: Calibration) -> None:
    """A calibration cannot be corrupted in place through its arrays."""
    with pytest.raises(ValueError, match="read-only"):
        true_cal.offset[0] = 1.0


@pytest.mark.parametrize(
    ("x", "match"),
    [([[1, 2]], r"shape \(n, 3\)"), ([[1, 2, np.inf]], "NaN or Inf"), (np.zeros((0, 3)), "at least 1"), ("abc", "numeric")],
)
def test_as_points_errors(x: object, match: str) -> None:
    """The boundary check names what is wrong with the array."""
    with pytest.raises(MargCalError, match=match):
        as_points(x)
