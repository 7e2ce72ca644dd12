"""Issue 27 item 4 (the whole command within 20 s with the other core busy): the stages' least squares stay off
LAPACK's threaded drivers, which run 100 times slower when the other core is busy, and give what lstsq gives;
``--no-plots`` writes the report without matplotlib's figures."""

from __future__ import annotations

from pathlib import Path

import margcal_independent_generator as gen  # loaded once by tests/conftest.py
import numpy as np

from ros_margcal.diagnosis import diagnose, write_report
from ros_margcal.diagnosis.cubic import _pinv_solve, cubic_wald
from ros_margcal.diagnosis.stages import _step_feature, sh_basis
from ros_margcal.model.fitting import fit
from ros_margcal.recordings.recording import Recording


def test_pinv_solve_projects_as_lstsq_with_collinear_columns() -> None:
    """Exactly collinear columns (as the ellipsoid's scale and the constant) are dropped as lstsq drops them: the
    same projection (seeded)."""
    rng = np.random.default_rng(4)
    x = rng.normal(size=(500, 6))
    x = np.hstack([x, (x[:, 0] + 2 * x[:, 1])[:, None]])
    x /= np.sqrt(np.mean(x**2, axis=0))
    r = rng.normal(size=500)
    ours = x @ _pinv_solve(x.T @ x, x.T @ r)
    theirs = x @ np.linalg.lstsq(x, r, rcond=None)[0]
    np.testing.assert_allclose(ours, theirs, atol=1e-9)


def _recording(effect: str = "none", motion: str = "band") -> dict:
    return gen.generate("mag", motion, 20.0, 50.0, 3, effect=effect, magnitude=gen.DEFAULT_MAGNITUDE.get(effect, 0.0))


def _lstsq_cubic(pts: np.ndarray, cal) -> float:
    """The cubic test's statistic with white noise only as lstsq computes it, what the cubic terms explain over the
    noise variance the full fit leaves (the reference the normal equations must match)."""
    w, b = np.asarray(cal.matrix), np.asarray(cal.offset)
    v = pts - b
    h = v @ w.T
    lengths = np.linalg.norm(h, axis=1)
    r = lengths / float(cal.norm) - 1.0
    u = h / lengths[:, None]
    v = v / (1.0 + r)[:, None]
    grad = u @ w
    pairs = [(a, c) for a in range(3) for c in range(a, 3)]
    cols = [grad, np.ones((r.size, 1))] + [(u[:, a] * v[:, c] + u[:, c] * v[:, a])[:, None] for a, c in pairs]
    full = v + b
    x1 = np.hstack([*cols, grad * (full / np.max(np.abs(full))) ** 3])
    x1 = x1 / np.sqrt(np.mean(x1**2, axis=0))
    f0 = x1[:, :-3] @ np.linalg.lstsq(x1[:, :-3], r, rcond=None)[0]
    f1 = x1 @ np.linalg.lstsq(x1, r, rcond=None)[0]
    left = r - f1
    return float(np.sum((f1 - f0) ** 2) / np.mean((left - left.mean()) ** 2))


def test_cubic_feature_matches_lstsq_on_a_band_with_a_cubic() -> None:
    """On a band (the ellipsoid mimics most of a cubic: nearly collinear columns) and on a clean tumble the Wald
    statistic without a time span (white noise only) is lstsq's to 1e-6."""
    for effect, motion in (("nonlinearity", "band"), ("none", "tumble")):
        pts = _recording(effect, motion)["xyz"]
        cal = fit(pts, model="sym", method="algebraic", norm=4.8e-5)
        ref = _lstsq_cubic(pts, cal)
        ours = cubic_wald(pts, cal, np.zeros(len(pts)))
        assert abs(ours - ref) <= 1e-6 * max(ref, 1.0), f"{effect} {motion}: {ours:.9g} against lstsq's {ref:.9g}"


def _step(effect: str) -> float:
    rec = _recording(effect)
    cal = fit(rec["xyz"], model="diag", method="lin_auto", norm=4.8e-5)
    h = cal.apply(rec["xyz"])
    r = np.linalg.norm(h, axis=1) / 4.8e-5 - 1.0
    basis = sh_basis(h / np.linalg.norm(h, axis=1)[:, None])
    tau = (rec["t"] - rec["t"][0]) / np.ptp(rec["t"])
    static, offset = basis[:, :9], basis[:, 1:4]
    slow_off = np.hstack([static] + [np.cos(np.pi * k * tau)[:, None] * offset for k in (1, 2)])
    return _step_feature(r, static, slow_off, tau, offset)


def test_step_feature_from_the_small_eigen_decomposition_tells_a_step_from_a_drift() -> None:
    """The step evidence (its orthonormal basis now from the 15 x 15 normal matrix): a jump reads negative, a
    random-walk drift positive (on a band, seeded)."""
    jump, drift = _step("hard_iron_jump"), _step("bias_drift")
    assert jump < -0.5 < 0.0 < drift, f"jump {jump:.4g}, drift {drift:.4g}"


def test_report_without_plots_has_its_tables_and_no_figure(tmp_path: Path) -> None:
    """``plots=False`` (``margcal diagnose --no-plots``): the same tables, no PNG; with plots, three."""
    rec = _recording("none", "tumble")
    d = diagnose(Recording(t=rec["t"], raw=rec["xyz"], sensor="mag"), sensor="mag", norm=4.8e-5, quick=True, n_fit=600)
    _, bare = write_report(d, tmp_path / "bare", plots=False)
    _, full = write_report(d, tmp_path / "full")
    bare_html, full_html = bare.read_text(), full.read_text()
    assert "data:image/png" not in bare_html and full_html.count("data:image/png") == 3
    assert "Which: effects ranked" in bare_html
