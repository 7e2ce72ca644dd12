"""Ellipsoid fitting: exact recovery, statistical efficiency, robust losses, and every bad-input path."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.cli import calibrate as calibrate_cli
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.calibration_file import calibration_from_yaml, calibration_to_yaml, load_calibrations
from ros_margcal.model.errors import ConfigError, ConvergenceError, DegenerateDataError, InputError, MargCalError
from ros_margcal.model.fitting import METHODS, SUPPORTED, fit, residuals
from ros_margcal.model.fitting_core import check_geometry, check_singular, gn_covariance, gram, solve_spd3

Array = np.ndarray


def unit_vectors(rng: np.random.Generator, n: int) -> Array:
    """Uniform random directions, (n, 3)."""
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def truth_for(model: str) -> Calibration:
    """A magnetometer-like truth of the given model kind (raw in µT, norm 48)."""
    b = np.array([12.0, -7.5, 30.0])
    w = {
        "eye": 1.05 * np.eye(3),
        "diag": np.diag([1.08, 0.93, 1.01]),
        "sym": np.array([[1.08, 0.04, -0.02], [0.04, 0.93, 0.03], [-0.02, 0.03, 1.01]]),
    }[model]
    return Calibration(b, w, norm=48.0, model=model)


def raw_points(truth: Calibration, rng: np.random.Generator, n: int, noise: float = 0.0) -> Array:
    """Raw readings of ``n`` random directions with isotropic raw noise of ``noise`` x the raw radius."""
    raw = truth.inverse_apply(truth.norm * unit_vectors(rng, n))
    radius = truth.norm / np.cbrt(np.linalg.det(truth.matrix))
    return raw + noise * radius * rng.normal(size=raw.shape)


def shape(cal: Calibration) -> Array:
    """W normalised to det 1 (what a scale-free fit can recover)."""
    return cal.matrix / np.cbrt(np.linalg.det(cal.matrix))


def crb(truth: Calibration, raw_clean: Array, sigma_raw: float) -> Array:
    """Cramér-Rao bound of (b, w_xx, w_yy, w_zz, w_xy, w_xz, w_yz) for the sym model with known norm."""
    d = raw_clean - truth.offset
    y = d @ truth.matrix.T
    u = y / np.linalg.norm(y, axis=1, keepdims=True)
    off = ((0, 1), (0, 2), (1, 2))
    g = np.column_stack([-(u @ truth.matrix), u * d, *[u[:, j] * d[:, k] + u[:, k] * d[:, j] for j, k in off]])
    var = sigma_raw**2 * np.sum((u @ truth.matrix) ** 2, axis=1)  # sigma^2 |W^T u_i|^2
    return np.linalg.inv(g.T @ (g / var[:, None]))


CASES = [(method, model) for method in METHODS for model in SUPPORTED[method]]


@pytest.mark.parametrize(("method", "model"), CASES)
@pytest.mark.parametrize("norm_given", [True, False])
def test_noiseless_recovery(method: str, model: str, norm_given: bool, rng: np.random.Generator) -> None:
    """Every method recovers every truth its model can represent to 1e-9 relative (lin_auto/sphere: spheres)."""
    truth = truth_for("eye" if method in ("sphere", "lin_auto") else model)
    raw = raw_points(truth, rng, 200)
    cal = fit(raw, model=model, method=method, norm=truth.norm if norm_given else None)
    scale = truth.norm / np.cbrt(np.linalg.det(truth.matrix))
    np.testing.assert_allclose(cal.offset, truth.offset, rtol=0, atol=1e-9 * scale)
    if norm_given:
        np.testing.assert_allclose(cal.matrix, truth.matrix, rtol=0, atol=1e-9)
        assert cal.norm == truth.norm
    else:
        np.testing.assert_allclose(cal.matrix, shape(truth), rtol=0, atol=1e-9)
        assert np.linalg.det(cal.matrix) == pytest.approx(1.0, abs=1e-12)
        assert cal.norm == pytest.approx(scale, rel=1e-9)
    assert cal.stats is not None and cal.stats.rms < 1e-9 * cal.norm
    assert cal.model == model and cal.method == method
    np.testing.assert_allclose(residuals(cal, raw), cal.norm_error(raw))


def test_lin_auto_is_approximate_on_unequal_radii(rng: np.random.Generator) -> None:
    """Gietzelt Sec. 3.5: LinAutoCalibration stays within about 1 % on unequal radii; lm is exact."""
    truth = truth_for("diag")
    raw = raw_points(truth, rng, 300)
    lin = fit(raw, model="diag", method="lin_auto", norm=truth.norm)
    assert 1e-6 < np.abs(lin.norm_error(raw)).max() / truth.norm < 0.01
    exact = fit(raw, model="diag", method="lm", norm=truth.norm)
    np.testing.assert_allclose(exact.matrix, truth.matrix, atol=1e-9)


def test_noisy_lm_within_crb(rng: np.random.Generator) -> None:
    """A noisy sym fit lies within 4 Cramér-Rao sigmas per parameter; its covariance matches the bound."""
    truth = truth_for("sym")
    clean = truth.inverse_apply(truth.norm * unit_vectors(rng, 500))
    sigma_raw = 0.01 * truth.norm / np.cbrt(np.linalg.det(truth.matrix))
    raw = clean + sigma_raw * rng.normal(size=clean.shape)
    cal = fit(raw, model="sym", method="lm", norm=truth.norm)
    bound = crb(truth, clean, sigma_raw)
    w = cal.matrix
    est = np.r_[cal.offset, np.diag(w), w[0, 1], w[0, 2], w[1, 2]]
    tw = truth.matrix
    true = np.r_[truth.offset, np.diag(tw), tw[0, 1], tw[0, 2], tw[1, 2]]
    z = (est - true) / np.sqrt(np.diag(bound))
    assert np.all(np.abs(z) < 4.0), z
    assert cal.covariance is not None
    ratio = np.sqrt(np.diag(cal.covariance) / np.diag(bound))
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    assert cal.parameter_names == ("b_x", "b_y", "b_z", "w_xx", "w_yy", "w_zz", "w_xy", "w_xz", "w_yz")
    assert cal.stats is not None and cal.stats.rms_relative == pytest.approx(0.01, rel=0.15)


@pytest.mark.parametrize(("method", "model"), [("lm", "sym"), ("lm", "diag"), ("lin_auto", "diag"), ("algebraic", "sym")])
def test_reported_covariance_matches_spread(method: str, model: str) -> None:
    """Over repeated noisy fits the scatter of each parameter is near the reported sigma (norm estimated)."""
    rng = np.random.default_rng(7)
    truth = truth_for("eye" if method == "lin_auto" else model)
    est, sig = [], []
    for _ in range(60):
        cal = fit(raw_points(truth, rng, 300, noise=0.01), model=model, method=method, norm=None)
        assert cal.covariance is not None and cal.parameter_names[-1] == "norm"
        est.append(np.r_[cal.offset, cal.norm])
        sig.append(np.sqrt(np.diag(cal.covariance))[[0, 1, 2, -1]])
    ratio = np.std(est, axis=0) / np.mean(sig, axis=0)
    assert np.all((ratio > 0.65) & (ratio < 1.5)), ratio


def gauss_newton_covariance(cal: Calibration, raw: Array) -> Array:
    """Reference ``s^2 (J^T J)^-1`` over (b, w_xx, w_yy, w_zz) of a diag calibration with given norm."""
    d = raw - cal.offset
    y = d @ cal.matrix.T
    rho = np.linalg.norm(y, axis=1)
    u = y / rho[:, None]
    j = np.column_stack([-(u @ cal.matrix), u * d])
    r = rho - cal.norm
    return float(r @ r) / (raw.shape[0] - 6) * np.linalg.inv(j.T @ j)


@pytest.mark.parametrize("n", [7, 100, 3000])
def test_lin_auto_covariance_is_the_gauss_newton_one(n: int, rng: np.random.Generator) -> None:
    """lin_auto's covariance, formed from its own rows, equals s^2 (J^T J)^-1 of the norm residual at its solution."""
    truth = truth_for("diag")
    raw = raw_points(truth, rng, n, noise=0.01)
    cal = fit(raw, model="diag", method="lin_auto", norm=truth.norm)
    assert cal.covariance is not None and cal.parameter_names == ("b_x", "b_y", "b_z", "w_xx", "w_yy", "w_zz")
    np.testing.assert_allclose(cal.covariance, gauss_newton_covariance(cal, raw), rtol=1e-8, atol=0)
    assert cal.stats is not None
    np.testing.assert_allclose(cal.stats.rms, np.sqrt(np.mean(cal.norm_error(raw) ** 2)), rtol=1e-12)
    assert not cal.covariance.flags.writeable and not cal.matrix.flags.writeable and not cal.offset.flags.writeable


@pytest.mark.parametrize(("method", "model"), CASES)
@pytest.mark.parametrize("n", [6, 9, 200])
def test_stats_are_those_of_the_residuals(method: str, model: str, n: int, rng: np.random.Generator) -> None:
    """``stats.max_abs`` and ``stats.rms`` are the largest and RMS norm residual of the result, with the norm given
    or estimated (the fits take them from their own residual vectors, e.g. BLAS idamax for the largest)."""
    truth = truth_for("sym" if model == "sym" else "diag")
    raw = raw_points(truth, rng, n, noise=0.02)
    for norm in (truth.norm, None):
        try:
            cal = fit(raw, model=model, method=method, norm=norm)
        except MargCalError:  # too few points for this model, or not an ellipsoid from so few
            assert n < 10
            continue
        e = np.abs(cal.norm_error(raw))
        tol = {"rtol": 1e-9, "atol": 1e-12 * cal.norm}  # with N = P the fit is exact: residuals are rounding
        assert cal.stats is not None
        assert n <= 9 or e.max() > tol["atol"]
        np.testing.assert_allclose(cal.stats.max_abs, e.max(), **tol)
        np.testing.assert_allclose(cal.stats.rms, np.sqrt(np.mean(e * e)), **tol)


def test_lin_auto_with_as_many_points_as_parameters_has_no_covariance(rng: np.random.Generator) -> None:
    """With N = P there is no residual variance: the fit still returns stats, but no covariance."""
    truth = truth_for("eye")
    cal = fit(raw_points(truth, rng, 6), model="diag", method="lin_auto", norm=truth.norm)
    assert cal.covariance is None and cal.parameter_names == () and cal.stats is not None


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    log_ratios=st.lists(st.floats(-9.0, 0.0), min_size=2, max_size=2),
)
def test_geometry_check_matches_singular_values(seed: int, log_ratios: list[float]) -> None:
    """The geometry check (closed-form fast path or eigensolver) rejects exactly the scatters with a
    singular-value ratio <= 1e-6, whatever their orientation."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    sv = np.array([1.0, 10 ** log_ratios[0], 10 ** log_ratios[1]]) * 7.0
    scatter = (q * sv**2) @ q.T
    ratio = np.sort(sv)[:2] / sv.max()
    if ratio.min() <= 0.5e-6:
        with pytest.raises(DegenerateDataError, match=r"coplanar|collinear"):
            check_geometry(100, scatter, 1.0, 9)
    elif ratio.min() >= 2e-6:
        check_geometry(100, scatter, 1.0, 9)


def test_closed_form_solve_matches_lapack_and_rejects_singular(rng: np.random.Generator) -> None:
    """The 3x3 Cholesky solve agrees with numpy and refuses a singular normal matrix with DegenerateDataError."""
    a = rng.normal(size=(3, 8))
    spd, b = a @ a.T, rng.normal(size=3)
    np.testing.assert_allclose(solve_spd3(spd, b), np.linalg.solve(spd, b), rtol=1e-12)
    with pytest.raises(DegenerateDataError, match="normal equations are singular"):
        solve_spd3(np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0]), b)


@pytest.mark.parametrize("p", [6, 9, 10])
def test_gn_covariance_is_the_scaled_inverse_and_none_when_singular(p: int, rng: np.random.Generator) -> None:
    """The Cholesky-based covariance equals s^2 inv(J^T J) and is None for a rank-deficient J^T J."""
    jt = rng.normal(size=(p, 50)) * rng.uniform(0.1, 10.0, size=(p, 1))
    cov = gn_covariance(jt @ jt.T, 0.25)
    assert cov is not None
    np.testing.assert_allclose(cov, 0.25 * np.linalg.inv(jt @ jt.T), rtol=1e-10, atol=0)
    jt[-1] = 0.0  # a parameter the residuals do not depend on: singular normal matrix
    assert gn_covariance(jt @ jt.T, 0.25) is None


def test_gram_is_the_product_of_the_rows(rng: np.random.Generator) -> None:
    """gram(a, b) = a b^T and gram(a) = a a^T (BLAS gemm on the transposed views), for wide and narrow rows."""
    for n in (5, 100, 3000):
        a, b = rng.normal(size=(6, n)), rng.normal(size=(3, n))
        np.testing.assert_allclose(gram(a), a @ a.T, rtol=1e-12, atol=1e-12 * n)
        np.testing.assert_allclose(gram(a, b), a @ b.T, rtol=1e-12, atol=1e-12 * n)
        assert gram(a[:, ::2]).shape == (6, 6)  # a non-contiguous view is copied, not misread
        np.testing.assert_allclose(gram(a[:, ::2]), a[:, ::2] @ a[:, ::2].T, rtol=1e-12, atol=1e-12 * n)


def test_gn_covariance_scale_maps_units(rng: np.random.Generator) -> None:
    """With a scale vector e the covariance is s^2 diag(e) (J^T J)^-1 diag(e) (signs included)."""
    jt = rng.normal(size=(6, 50))
    e = [2.0, -0.5, 3.0, 0.1, -7.0, 1.0]
    cov = gn_covariance(gram(jt), 0.3, e)
    assert cov is not None
    np.testing.assert_allclose(cov, 0.3 * np.diag(e) @ np.linalg.inv(jt @ jt.T) @ np.diag(e), rtol=1e-10, atol=0)


def test_singular_matrix_check() -> None:
    """A fitted W with condition above 1e10 is a ConvergenceError naming the method; below it passes."""
    check_singular(9e9, "lin_auto")
    with pytest.raises(ConvergenceError, match="lin_auto produced a singular matrix"):
        check_singular(2e10, "lin_auto")


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    offset=st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
    log_gain=st.lists(st.floats(-0.4, 0.4), min_size=3, max_size=3),
    skew=st.lists(st.floats(-0.1, 0.1), min_size=3, max_size=3),
    norm=st.floats(1e-6, 1e4),
)
def test_property_calibrated_norms_match(
    seed: int, offset: list[float], log_gain: list[float], skew: list[float], norm: float
) -> None:
    """On noiseless data of any well-conditioned truth, calibrated norms equal the reference norm."""
    g = np.exp(log_gain)
    w = np.diag(g) + np.array([[0, skew[0], skew[1]], [skew[0], 0, skew[2]], [skew[1], skew[2], 0]]) * g.min()
    truth = Calibration(np.array(offset), w * norm / 50.0, norm=norm)  # raw radius about 50
    raw = raw_points(truth, np.random.default_rng(seed), 60)
    cal = fit(raw, model="sym", method="lm", norm=norm)
    np.testing.assert_allclose(np.linalg.norm(cal.apply(raw), axis=1), norm, rtol=1e-8)
    free = fit(raw, model="sym", method="lm")
    assert np.abs(free.norm_error(raw)).max() < 1e-8 * free.norm


@pytest.mark.parametrize("loss", ["soft_l1", "huber", "cauchy"])
def test_robust_loss_beats_linear_with_outliers(loss: str, rng: np.random.Generator) -> None:
    """With 15 % of samples under a magnetic disturbance (+25 µT along x), a robust loss finds the offset far better."""
    truth = truth_for("sym")
    raw = raw_points(truth, rng, 400, noise=0.005)
    bad = rng.choice(400, size=60, replace=False)
    raw[bad] += np.linalg.solve(truth.matrix, [25.0, 0.0, 0.0])
    plain = fit(raw, model="sym", method="lm", norm=truth.norm)
    robust = fit(raw, model="sym", method="lm", norm=truth.norm, loss=loss)
    err_plain = np.linalg.norm(plain.offset - truth.offset)
    err_robust = np.linalg.norm(robust.offset - truth.offset)
    assert err_robust < err_plain / 3, (err_robust, err_plain)
    assert np.abs(robust.matrix - truth.matrix).max() < 0.01
    assert robust.covariance is not None and np.all(np.diag(robust.covariance) > 0)
    given_scale = fit(raw, model="sym", method="lm", norm=None, loss=loss, f_scale=0.5)
    np.testing.assert_allclose(given_scale.offset, truth.offset, atol=0.2)


@pytest.mark.parametrize("init", ["campolo", "lin_auto", "calibration"])
def test_lm_starts_agree(init: str, rng: np.random.Generator) -> None:
    """Campolo's rule, LinAutoCalibration and a given Calibration all lead lm to the same optimum."""
    truth = truth_for("sym")
    raw = raw_points(truth, rng, 200, noise=0.01)
    start: str | Calibration = Calibration.identity(norm=48.0) if init == "calibration" else init
    ref = fit(raw, method="lm", norm=48.0)
    cal = fit(raw, method="lm", norm=48.0, init=start)
    assert cal.allclose(ref, rtol=1e-6, atol=1e-8)


def test_result_serialises(rng: np.random.Generator) -> None:
    """A fitted Calibration (stats and covariance included) survives the YAML round trip."""
    cal = fit(raw_points(truth_for("sym"), rng, 100, noise=0.01), sensor="mag", unit="uT")
    back = calibration_from_yaml(calibration_to_yaml(cal), sensor="mag")
    assert back.allclose(cal) and back.parameter_names == cal.parameter_names and back.stats == cal.stats


def test_mvee_reports_no_covariance_and_encloses(rng: np.random.Generator) -> None:
    """MVEE encloses every point (norm error <= 0) and, not being least squares, gives no covariance."""
    raw = raw_points(truth_for("sym"), rng, 100, noise=0.01)
    cal = fit(raw, method="mvee", norm=1.0)
    assert cal.covariance is None and cal.parameter_names == ()
    assert cal.norm_error(raw).max() < 1e-6


def _sphere(n: int = 50) -> Array:
    return 40.0 * unit_vectors(np.random.default_rng(3), n) + 5.0


def _bad_points(kind: str) -> Array:
    t = np.linspace(0, 2 * np.pi, 40)
    if kind == "few":
        return _sphere(5)
    if kind == "nan":
        p = _sphere()
        p[7, 1] = np.nan
        return p
    if kind == "inf":
        p = _sphere()
        p[3, 2] = np.inf
        return p
    if kind == "shape":
        return _sphere()[:, :2]
    if kind == "coplanar":
        return np.column_stack([40 * np.cos(t), 40 * np.sin(t), np.full_like(t, 3.0)])
    if kind == "collinear":
        return np.column_stack([t, 2 * t, -t]) + 1.0
    if kind == "identical":
        return np.tile([1.0, 2.0, 3.0], (30, 1))
    if kind == "text":
        return np.array([["a", "b", "c"]] * 10)
    raise AssertionError(kind)


@pytest.mark.parametrize(
    ("kind", "error", "match"),
    [
        ("few", DegenerateDataError, r"5 given but this model has 9 parameters"),
        ("nan", InputError, r"NaN or Inf.*row 7"),
        ("inf", InputError, r"NaN or Inf.*row 3"),
        ("shape", InputError, r"shape \(n, 3\)"),
        ("coplanar", DegenerateDataError, r"coplanar"),
        ("collinear", DegenerateDataError, r"collinear"),
        ("identical", DegenerateDataError, r"identical"),
        ("text", InputError, r"numeric"),
    ],
)
@pytest.mark.parametrize("method", ["lm", "algebraic"])
def test_bad_points(kind: str, error: type[MargCalError], match: str, method: str) -> None:
    """Bad point sets raise the specific error with a message saying what was wrong."""
    with pytest.raises(error, match=match):
        fit(_bad_points(kind), model="sym", method=method)


def test_not_an_ellipsoid() -> None:
    """Points on a hyperboloid make the algebraic quadric indefinite: DegenerateDataError."""
    rng = np.random.default_rng(5)
    s, phi = rng.uniform(-1.5, 1.5, 200), rng.uniform(0, 2 * np.pi, 200)
    raw = np.column_stack([np.cosh(s) * np.cos(phi), np.cosh(s) * np.sin(phi), np.sinh(s)]) * 30.0
    with pytest.raises(DegenerateDataError, match="not an ellipsoid"):
        fit(raw, method="algebraic")


def test_non_convergence(rng: np.random.Generator) -> None:
    """An iteration limit too small for the data raises ConvergenceError, for plain and robust loss."""
    raw = raw_points(truth_for("sym"), rng, 200, noise=0.02)
    with pytest.raises(ConvergenceError, match="did not converge in 1 iterations"):
        fit(raw, method="lm", init="campolo", max_iter=1)
    with pytest.raises(ConvergenceError, match="did not converge"):
        fit(raw, method="lm", init="campolo", loss="huber", f_scale=0.1, max_iter=1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"method": "sphere", "model": "sym"}, r"method 'sphere' cannot fit model 'sym'; it supports \('eye',\)"),
        ({"method": "lin_auto", "model": "sym"}, r"cannot fit model 'sym'"),
        ({"method": "algebraic", "model": "diag"}, r"cannot fit model 'diag'"),
        ({"method": "mvee", "model": "eye"}, r"cannot fit model 'eye'"),
        ({"method": "newton"}, r"method must be one of"),
        ({"model": "full"}, r"model must be one of"),
        ({"loss": "l1"}, r"loss must be one of"),
        ({"method": "lin_auto", "model": "diag", "loss": "huber"}, r"robust loss 'huber' needs method 'lm'"),
        ({"norm": -1.0}, r"norm must be a positive"),
        ({"norm": float("nan")}, r"norm must be a positive"),
        ({"f_scale": 0.0}, r"f_scale must be a positive"),
        ({"max_iter": 0}, r"max_iter must be a positive integer"),
        ({"method": "algebraic", "init": "campolo"}, r"init only applies to method 'lm'"),
        ({"init": "guess"}, r"init must be 'lin_auto', 'campolo' or a Calibration"),
    ],
)
def test_bad_options(kwargs: dict[str, object], match: str) -> None:
    """Unknown or unsupported option combinations raise ConfigError naming the problem."""
    with pytest.raises(ConfigError, match=match):
        fit(_sphere(), **kwargs)  # type: ignore[arg-type]


def test_lm_bias_correction_removes_gain_bias() -> None:
    """At 2 % noise and N = 1000 the gains are unbiased (plain LS shrinks them by about 0.5 CRB sigma)."""
    rng = np.random.default_rng(11)
    truth = truth_for("sym")
    sigma_raw = 0.02 * truth.norm / np.cbrt(np.linalg.det(truth.matrix))
    zs = []
    for _ in range(40):
        clean = truth.inverse_apply(truth.norm * unit_vectors(rng, 1000))
        cal = fit(clean + sigma_raw * rng.normal(size=clean.shape), method="lm", norm=truth.norm)
        sd = np.sqrt(np.diag(crb(truth, clean, sigma_raw)))[3:6]
        zs.append((np.diag(cal.matrix) - np.diag(truth.matrix)) / sd)
    assert abs(float(np.mean(zs))) < 0.3, np.mean(zs, axis=0)


def test_cli_calibrate(tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]) -> None:
    """``margcal calibrate`` fits a CSV, prints parameters with uncertainties, writes YAML and JSON."""
    truth = truth_for("sym")
    raw = raw_points(truth, rng, 300, noise=0.005)
    csv = tmp_path / "mag.csv"
    csv.write_text(
        "t,x,y,z\n" + "".join(f"{i * 0.1},{x:.17g},{y:.17g},{z:.17g}\n" for i, (x, y, z) in enumerate(raw)), encoding="utf-8"
    )
    parser = argparse.ArgumentParser()
    calibrate_cli.register(parser.add_subparsers())
    out, js = tmp_path / "cal.yaml", tmp_path / "fit.json"
    args = parser.parse_args(["calibrate", str(csv), "--sensor", "mag", "--norm", "48", "-o", str(out), "--json", str(js)])
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "offset x" in text and "+-" in text and "residual" in text
    cal = load_calibrations(out)["mag"]
    np.testing.assert_allclose(cal.offset, truth.offset, atol=0.2)
    d = json.loads(js.read_text(encoding="utf-8"))
    assert d["model"] == "sym" and set(d["std"]) >= {"b_x", "w_yz"} and d["stats"]["n_points"] == 300


def test_the_square_root_of_a_matrix_that_is_no_ellipsoid_is_nan_without_a_warning() -> None:
    """The algebraic fit of points on no ellipsoid gives an indefinite A: NaN (refused by the caller's
    finite check), not a RuntimeWarning on the console (the diagnosis benchmark printed several)."""
    import warnings

    from ros_margcal.model.fitting_linear import sqrt_pd

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(sqrt_pd(np.diag([1.0, 1.0, -0.5]))).any()
        np.testing.assert_allclose(sqrt_pd(np.diag([4.0, 9.0, 1.0])), np.diag([2.0, 3.0, 1.0]))


@pytest.mark.parametrize("loss", ["linear", "soft_l1"])
def test_a_fit_that_runs_away_says_more_iterations_will_not_help(loss: str) -> None:
    """A 20 deg cap of the sphere: LM runs away (its axes 24-28x apart at 200 iterations, 1600x at 20000), so the
    error says so instead of asking for more iterations; a good sphere stopped after 2 still asks for them."""
    rng = np.random.default_rng(0)
    th, ph = np.deg2rad(20.0) * np.sqrt(rng.uniform(0, 1, 300)), rng.uniform(0, 2 * np.pi, 300)
    cap = 48.0 * np.c_[np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)] + [10.0, -5.0, 3.0]
    with pytest.raises(ConvergenceError, match="did not converge: it ran away to no sensor's ellipsoid") as got:
        fit(cap + rng.normal(0, 0.5, cap.shape), model="sym", method="lm", loss=loss, max_iter=200)
    assert "raise max_iter" not in str(got.value)
    u = rng.normal(size=(300, 3))
    sphere = 48.0 * u / np.linalg.norm(u, axis=1)[:, None] @ np.diag([1.1, 0.95, 1.0]) + [10.0, -5.0, 3.0]
    with pytest.raises(ConvergenceError, match=r"did not converge in 1 iterations .*raise max_iter"):
        fit(sphere + rng.normal(0, 0.5, sphere.shape), model="sym", method="lm", loss=loss, max_iter=1)
