"""Fitting benchmark: Gietzelt's Table 4, efficiency against the Cramér-Rao bound, and speed.

Run ``margcal bench fitting [--quick]`` or ``python scripts/bench_fitting.py [--quick]``. Every ratio
is measured in the same run. Sections:

1. Gietzelt et al. 2013, Table 4: ellipsoid o = 2300, s = (500, 500, 500), 100 training and 100 test
   points with a +-1 % jitter (read here as a uniform radial factor 1 + U(-0.01, 0.01)), 10 passes,
   every method beside the paper's column for the corresponding algorithm.
2. Monte Carlo of the fits against the Cramér-Rao bound (CRB). Raw noise is isotropic Gaussian with
   standard deviation sigma; to first order the norm residual of point i is ``u_i^T W e_i`` with
   ``u_i`` the unit calibrated direction, so it carries the information of a Gaussian with standard
   deviation ``sigma |W^T u_i|``. The Fisher matrix at the true parameters is therefore
   ``F = sum_i g_i g_i^T / (sigma^2 |W^T u_i|^2)`` with ``g_i = dr_i/dtheta`` (the fit's analytic
   Jacobian at the noiseless points) and ``CRB = F^-1``, averaged over the runs' direction sets.
   Reported: per-parameter RMSE / sqrt(CRB) (1.0 = efficient).
3. Median fit time per method at N = 100, 1000, 10000 as ratios to lin_auto.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np
from scipy.optimize import least_squares

from ..model.calibration import Calibration
from ..model.fitting import fit

__all__ = [
    "DIAG_TRUTH_W", "METHOD_ROWS", "NAMES", "OFF", "PAPER_TABLE4", "SYM_TRUTH_W", "crb", "crb_study", "main",
    "params_of", "speed", "table4", "unit_vectors"
]

Array = np.ndarray

PAPER_TABLE4: dict[str, list[tuple[float, float]]] = {  # (mean, std) of s_x, s_y, s_z, o_x, o_y, o_z
    "LinMinVarEstimate": [(499.81, 0.62), (500.08, 0.36), (500.12, 0.38), (2299.95, 0.31), (2300.01, 0.43), (2299.90, 0.12)],
    "NonLinear": [(499.83, 0.62), (500.11, 0.36), (500.14, 0.38), (2299.95, 0.31), (2300.01, 0.42), (2299.90, 0.12)],
    "LsqNonLinear": [(499.77, 0.62), (500.04, 0.35), (500.07, 0.38), (2299.95, 0.32), (2300.01, 0.43), (2299.90, 0.12)],
    "MgnCalibration*": [(499.90, 0.59), (500.01, 0.54), (499.82, 0.45), (2299.98, 0.30), (2299.99, 0.44), (2299.92, 0.14)],
    "MinVolEllipse*": [(490.45, 7.01), (483.13, 9.01), (525.66, 6.22), (2303.07, 6.15), (2301.35, 12.34), (2297.66, 11.93)],
    "LinAutoCalibration": [(499.83, 0.61), (500.11, 0.34), (500.14, 0.38), (2299.99, 0.39), (2299.99, 0.39), (2299.91, 0.12)],
}

# label, method, model, init, the paper's column it corresponds to
METHOD_ROWS: list[tuple[str, str, str, str | None, str | None]] = [
    ("sphere", "sphere", "eye", None, None),
    ("lin_auto", "lin_auto", "diag", None, "LinAutoCalibration"),
    ("lm diag", "lm", "diag", None, "NonLinear"),
    ("lm diag campolo", "lm", "diag", "campolo", "LsqNonLinear"),
    ("lm sym", "lm", "sym", None, None),
    ("algebraic", "algebraic", "sym", None, "MgnCalibration*"),
    ("mvee", "mvee", "sym", None, "MinVolEllipse*"),
]

SYM_TRUTH_W = np.array([[1.08, 0.04, -0.02], [0.04, 0.93, 0.03], [-0.02, 0.03, 1.01]])
DIAG_TRUTH_W = np.diag([1.08, 0.93, 1.01])
OFF = ((0, 1), (0, 2), (1, 2))
NAMES = {
    "sym": ["b_x", "b_y", "b_z", "w_xx", "w_yy", "w_zz", "w_xy", "w_xz", "w_yz"],
    "diag": ["b_x", "b_y", "b_z", "w_xx", "w_yy", "w_zz"],
}


def unit_vectors(rng: np.random.Generator, n: int) -> Array:
    """Uniform random directions, (n, 3)."""
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def params_of(cal: Calibration, model: str) -> Array:
    """(b, W entries) in the order of ``NAMES[model]``."""
    w = cal.matrix
    extra = [w[0, 1], w[0, 2], w[1, 2]] if model == "sym" else []
    return np.r_[cal.offset, np.diag(w), extra]


def crb(truth: Calibration, clean: Array, sigma_raw: float, model: str) -> Array:
    """Cramér-Rao bound of ``params_of`` for known norm, isotropic raw noise ``sigma_raw`` (module doc)."""
    d = clean - truth.offset
    y = d @ truth.matrix.T
    u = y / np.linalg.norm(y, axis=1, keepdims=True)
    wtu = u @ truth.matrix  # (W^T u_i)^T; also -dr/db
    cols = [-wtu, u * d]
    if model == "sym":
        cols += [np.column_stack([u[:, j] * d[:, k] + u[:, k] * d[:, j] for j, k in OFF])]
    g = np.column_stack(cols)
    var = sigma_raw**2 * np.einsum("ij,ij->i", wtu, wtu)
    return np.linalg.inv(g.T @ (g / var[:, None]))


# -- 1. Gietzelt Table 4 -------------------------------------------------------------------------


def table4(passes: int, seed: int) -> None:
    """Gietzelt Table 4: s and o per method, mean +- std over passes, beside the paper."""
    o, s = np.full(3, 2300.0), np.full(3, 500.0)
    rng = np.random.default_rng(seed)
    est: dict[str, list[Array]] = {row[0]: [] for row in METHOD_ROWS}
    test_norm: dict[str, list[Array]] = {row[0]: [] for row in METHOD_ROWS}
    for _ in range(passes):
        pts = o + s * unit_vectors(rng, 200) * (1.0 + rng.uniform(-0.01, 0.01, size=(200, 1)))
        train, test = pts[:100], pts[100:]
        for label, method, model, init, _col in METHOD_ROWS:
            cal = fit(train, model=model, method=method, norm=1.0, init=init)
            est[label].append(np.r_[1.0 / np.diag(cal.matrix), cal.offset])  # s from diag(W) (paper: diag of U)
            test_norm[label].append(np.linalg.norm(cal.apply(test), axis=1))
    print(f"\n== 1. Gietzelt 2013 Table 4: o = 2300, s = 500, +-1 % jitter, 100 train / 100 test, {passes} passes ==")
    print("   each cell: mean +- std over passes; second line: the paper's corresponding column (* = diag of U)")
    head = "".join(f"{n:>17}" for n in ("s_x", "s_y", "s_z", "o_x", "o_y", "o_z"))
    print(f"{'method':<32}{head}   test |v_cal| (1 g)")
    print(f"{'true value':<32}" + "".join(f"{v:>17.2f}" for v in (500, 500, 500, 2300, 2300, 2300)))
    for label, _method, _model, _init, col in METHOD_ROWS:
        e = np.array(est[label])
        tn = np.concatenate(test_norm[label])
        cells = "".join(f"{m:>9.2f} +-{sd:5.2f}" for m, sd in zip(e.mean(axis=0), e.std(axis=0, ddof=1), strict=True))
        print(f"{label:<32}{cells}   {tn.mean():.4f} +- {tn.std():.4f}")
        if col is not None:
            paper = "".join(f"{m:>9.2f} +-{sd:5.2f}" for m, sd in PAPER_TABLE4[col])
            print(f"{'  paper ' + col:<32}{paper}")
    for col in ("LinMinVarEstimate",):
        paper = "".join(f"{m:>9.2f} +-{sd:5.2f}" for m, sd in PAPER_TABLE4[col])
        print(f"{'  paper ' + col + ' (no twin)':<32}{paper}")


# -- 2. accuracy against the Cramér-Rao bound ------------------------------------------------------


def crb_study(runs: int, mvee_runs: int, seed: int, sizes: tuple[int, ...]) -> dict[tuple[int, float], Array]:
    """RMSE / sqrt(CRB) per parameter for lm sym (the target) and the other methods; returns lm sym ratios."""
    print(f"\n== 2. Accuracy vs the Cramér-Rao bound: RMSE / sqrt(CRB) per parameter, {runs} Monte Carlo runs ==")
    print("   truth: norm 48, b = (12, -7.5, 30), W sym (gains 0.93-1.08, cross terms 0.02-0.04); norm known;")
    print("   raw noise isotropic Gaussian, sigma = noise x raw radius; 1.00 = efficient; target lm sym <= 1.15 for N >= 100")
    rows = [
        ("lm sym", "lm", "sym", runs),
        ("algebraic", "algebraic", "sym", runs),
        ("mvee", "mvee", "sym", mvee_runs),
        ("lm diag", "lm", "diag", runs),
        ("lin_auto", "lin_auto", "diag", runs),
    ]
    print(f"{'N':>5} {'noise':>6} {'method':<10} {'runs':>5} " + "".join(f"{n:>7}" for n in NAMES["sym"]) + f"{'max':>8}")
    out: dict[tuple[int, float], Array] = {}
    for n in sizes:
        for noise in (0.005, 0.02):
            for label, method, model, nrun in rows:
                if method == "mvee" and n > 100 and nrun < 30:
                    continue
                truth = Calibration(np.array([12.0, -7.5, 30.0]), SYM_TRUTH_W if model == "sym" else DIAG_TRUTH_W, norm=48.0)
                sigma = noise * truth.norm / np.cbrt(np.linalg.det(truth.matrix))
                rng = np.random.default_rng([seed, n, int(noise * 1e4)])
                err, bounds = [], []
                for _ in range(nrun):
                    clean = truth.inverse_apply(truth.norm * unit_vectors(rng, n))
                    raw = clean + sigma * rng.normal(size=clean.shape)
                    cal = fit(raw, model=model, method=method, norm=truth.norm)
                    err.append(params_of(cal, model) - params_of(truth, model))
                    bounds.append(np.diag(crb(truth, clean, sigma, model)))
                ratio = np.sqrt(np.mean(np.square(err), axis=0) / np.mean(bounds, axis=0))
                if label == "lm sym":
                    out[(n, noise)] = ratio
                cells = "".join(f"{r:>7.3f}" for r in ratio) + " " * 7 * (9 - ratio.size)
                truth_kind = "" if model == "sym" else "  (diag truth, diag CRB)"
                print(f"{n:>5} {noise * 100:>5.1f}% {label:<10} {nrun:>5} {cells}{ratio.max():>8.3f}{truth_kind}")
    return out


# -- 3. speed -------------------------------------------------------------------------------------


def _generic_scipy_lm(points: Array) -> Array:
    """Reference: a generic solver as in Gietzelt's NonLinear/LsqNonLinear (finite-difference Jacobian)."""
    o = points.mean(axis=0)
    r = float(np.mean(np.linalg.norm(points - o, axis=1)))  # Campolo's start, Gietzelt Eq. 4

    def res(p: Array) -> Array:
        w = np.array([[p[3], p[6], p[7]], [p[6], p[4], p[8]], [p[7], p[8], p[5]]])
        return np.linalg.norm((points - p[:3]) @ w, axis=1) - 1.0

    return least_squares(res, np.r_[o, np.full(3, 1 / r), np.zeros(3)], method="lm").x


def _median_time(f: Callable[[], object], repeats: int) -> float:
    f()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def speed(quick: bool, seed: int) -> dict[tuple[str, int], float]:
    """Median fit time per method and N, as ratios to lin_auto."""
    sizes = (100, 1000, 10000)
    reps = {100: 60, 1000: 30, 10000: 8} if quick else {100: 300, 1000: 100, 10000: 20}
    truth = Calibration(np.array([12.0, -7.5, 30.0]), SYM_TRUTH_W, norm=48.0)
    rows = [*METHOD_ROWS, ("lm sym robust huber", "lm", "sym", None, None)]
    times: dict[tuple[str, int], float] = {}
    for n in sizes:
        rng = np.random.default_rng([seed, n])
        raw = truth.inverse_apply(truth.norm * unit_vectors(rng, n)) + 0.005 * 44.0 * rng.normal(size=(n, 3))
        for label, method, model, init, _ in rows:
            loss = "huber" if "huber" in label else "linear"
            r = max(2, reps[n] // 10) if method == "mvee" else reps[n]

            def call(m: str = method, mo: str = model, i: str | None = init, lo: str = loss, pts: Array = raw) -> object:
                return fit(pts, model=mo, method=m, norm=48.0, init=i, loss=lo)

            times[(label, n)] = _median_time(call, r)

        def generic(pts: Array = raw) -> object:
            return _generic_scipy_lm(pts)

        times[("scipy generic lm (FD jac)", n)] = _median_time(generic, max(3, reps[n] // 10))
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    print(f"\n== 3. Speed: median wall time per fit (ms) and ratio to lin_auto (OPENBLAS_NUM_THREADS={threads}) ==")
    labels = [row[0] for row in rows] + ["scipy generic lm (FD jac)"]
    print(f"{'method':<28}" + "".join(f"{f'N={n} ms':>13}{'x lin':>8}" for n in sizes))
    for label in labels:
        cells = "".join(f"{times[(label, n)] * 1e3:>13.3f}{times[(label, n)] / times[('lin_auto', n)]:>8.1f}" for n in sizes)
        print(f"{label:<28}{cells}")
    return times


def main(argv: list[str]) -> int:
    """Run the benchmark; ``--quick`` for a short run. Prints figures; returns 0."""
    parser = argparse.ArgumentParser(prog="margcal bench fitting", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer Monte Carlo runs and repeats (about a minute)")
    parser.add_argument("--runs", type=int, default=None, help="Monte Carlo runs per configuration (default 300, quick 100)")
    parser.add_argument("--seed", type=int, default=2013)
    args = parser.parse_args(argv)
    if args.seed < 0:  # one line, as the CLI's (not numpy's traceback)
        parser.exit(2, f"{parser.prog}: error: --seed must be a non-negative integer, got {args.seed}\n")
    if args.runs is not None and args.runs < 1:  # -3 was a TypeError after a minute, 0 the default
        parser.exit(2, f"{parser.prog}: error: --runs must be at least 1, got {args.runs}\n")
    runs = args.runs or (100 if args.quick else 300)
    mvee_runs = 10 if args.quick else 30
    t0 = time.perf_counter()
    table4(10, args.seed)
    ratios = crb_study(runs, mvee_runs, args.seed, (30, 100, 1000))
    times = speed(args.quick, args.seed)
    print("\n== Summary (all measured in this run) ==")
    worst = max(float(r.max()) for (n, _), r in ratios.items() if n >= 100)
    print(f"lm sym worst RMSE/sqrt(CRB) for N >= 100: {worst:.3f} (target <= 1.15): {'PASS' if worst <= 1.15 else 'FAIL'}")
    for n in (100, 1000, 10000):
        sp = times[("lm sym", n)] / times[("lin_auto", n)]
        sd = times[("lm diag", n)] / times[("lin_auto", n)]
        sg = times[("scipy generic lm (FD jac)", n)] / times[("lin_auto", n)]
        print(
            f"N={n:>5}: lin_auto is {sp:.1f}x faster than lm sym, {sd:.1f}x than lm diag, {sg:.1f}x than a generic scipy LM "
            f"(target >= 10x vs lm: {'PASS' if sp >= 10 else 'FAIL'})"
        )
    ms = times[("lm sym", 1000)] * 1e3
    print(f"lm sym at N=1000: {ms:.3f} ms median (target < 5 ms): {'PASS' if ms < 5 else 'FAIL'}")
    print(f"(bench took {time.perf_counter() - t0:.0f} s)")
    return 0
