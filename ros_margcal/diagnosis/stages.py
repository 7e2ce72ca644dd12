"""Stage metrics of the sim-to-real gap: one feature vector per stage, computed the same way on a
recording and on its simulated twin.

Every stage turns a recording into a few numbers (mostly ``log10`` of a size, so ratios become
differences); ``stage_gaps`` then puts the recording against several seeds of the twin on one common
scale, a z-score ``z = (f_rec - mean_twin) / max(sd_twin, floor)``, where the floor (in the
feature's own units, e.g. 0.02 decades = 5 %) keeps a deterministic twin feature from turning a
negligible difference into an infinite gap. A stage's gap is the RMS of its features' z-scores.

The stages, in the order a sample meets them:

``rest_noise``
    white noise std from second differences, ``d2 = v[i+1] - 2 v[i] + v[i-1]`` (std ``sqrt(6) s``),
    trimmed at the 95th percentile of ``|d2|`` (so bursts, jumps and the gaps between still stretches
    do not count) — the rotation itself adds only ``R (w dt)^2`` to ``d2``, far below the noise at 50-300 Hz.
``quantisation``
    distinct values per axis relative to the sample count, consecutive repeats per axis, and
    repeats of all three axes at once (a sample-and-hold read-out).
``clipping``
    share of samples sitting exactly at an axis' extreme value (saturation).
``residual_size``
    RMS of the relative norm residual ``|W (v - b)| / n - 1`` of the baseline (``diag``) fit and of
    the best (``sym``) fit.
``residual_direction``
    power of the ``diag`` residual per spherical-harmonic degree ``l = 1..4`` (least squares on the
    real harmonics ``Y_lm`` up to ``l = 4``): cross-axis terms show at ``l = 2``, cubic
    non-linearity at ``l = 4``, offsets left over at ``l = 1``.
``residual_cubic``
    whether a cubic term per axis of the whole reading (offset included: ``k_i v_i^3``, an ADC's non-linearity)
    explains the best (``sym``) fit's residual beyond that fit's own parameters (``cubic.cubic_feature``): a Wald
    test of the three cubic terms with the residual's own noise model, white plus slow (AR(1)) noise seen along
    the directions, so it is chi-square with 3 degrees of freedom without a cubic whatever the noise's colour;
    the feature is its normal score, N(0, 1) without a cubic. Its regressors are fixed functions of the
    direction, evaluated on the fitted ellipsoid (not on the noisy readings). On a band of tilts the ellipsoid
    mimics most of a cubic and the harmonic powers of ``residual_direction`` (25 coefficients, which slow noise
    fills as well) hide what is left; this matched three-term test does not. A residual that varies in time
    (drift, a step) counts as slow noise: it widens the test, it does not pass for a cubic.
``residual_time``
    the residual explained by ``cos(pi k tau) Y_lm(d)`` (``tau`` = time scaled to [0, 1]) beyond the
    static ``Y_lm`` (l <= 2; nested least squares): for ``k = 1, 2`` first on the degree-1 harmonics
    (an offset that moves: drift), then on degrees 0 and 2 (gains that move: a temperature
    coefficient), then ``k = 3..5`` on ``l <= 2`` (the ripple of a warm-up); the lag-1
    autocorrelation of what the direction fit leaves (bursts); one offset step against smooth drift;
    and, when the recording has a temperature column, the share of the time variation
    ``(T - mean T) Y_lm(d)`` explains and the share the time terms explain beyond it (the residual
    follows the temperature, not just any slow trend).
``residual_tails``
    the 99.9th and 99th percentiles of ``|r|`` and the plain std against the MAD sigma, and the
    quantile skewness ``(q99 + q01 - 2 q50) / (q99 - q01)``.
``validator``
    ``log10(measured / predicted)`` calibration error of a 300-sample calibration set taken from the
    recording, the measured error against the recording's best fit (see ``validator_errors``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import sph_harm_y

from ..model.errors import MargCalError
from ..model.fitting import fit
from .cubic import NULL_SD, cubic_feature
from .downstream import N_SET, validator_errors
from .fit_checks import lm_diag, sym_fit

__all__ = [
    "STAGES", "STAGE_FLOORS", "StageFeatures", "clipped_shares", "residual_noise", "rest_noise", "sh_basis", "sh_power",
    "stage_features", "stage_floor", "stage_gaps"
]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

STAGES: tuple[str, ...] = (
    "rest_noise", "quantisation", "clipping", "residual_size", "residual_direction", "residual_cubic", "residual_time",
    "residual_tails", "validator",
)
"""The stages, in the order a sample meets them."""

# spread floors per stage feature, in the feature's own unit (decades for log10 features)
STAGE_FLOORS: dict[str, tuple[float, ...]] = {
    "rest_noise": (0.02,),
    "quantisation": (0.02, 0.01, 0.005),
    "clipping": (0.002,),
    "residual_size": (0.01, 0.01),
    "residual_direction": (0.05, 0.05, 0.05, 0.05),
    "residual_cubic": (NULL_SD,),  # a normal score: its own spread without a cubic
    "residual_time": (0.05, 0.05, 0.05, 0.03, 0.1, 0.05, 0.05),
    "residual_tails": (0.03, 0.02, 0.02, 0.03),
    "validator": (0.05,),
}
_TRIM_STD = 0.8711  # std of a standard normal truncated at its two-sided 95 % quantile (±1.960)
_L_MAX = 4
_K_TIME = 5
_N_STEPS = 81
_TINY = 1e-12
_MAX_ITER = 400  # LM iterations: strong effects make the ellipsoid fit converge slowly


def stage_floor(name: str, shape: tuple[int, ...]) -> Array:
    """The spread floors of stage ``name`` (``STAGE_FLOORS``) as an array of a feature's ``shape``."""
    return np.resize(np.asarray(STAGE_FLOORS[name], dtype=np.float64), shape)


@dataclass
class StageFeatures:
    """The feature vectors of one recording, stage name -> 1-D array, plus what the plots need.

    Attributes:
        values: stage name -> features (stages that do not apply are absent).
        residual: relative norm residual of the ``diag`` fit on the fitting subsample.
        dirs: unit directions of the fitting subsample (from the ``diag`` calibration).
        t: times of the fitting subsample, seconds.
        rest_noise: white noise std, fraction of the field radius.
    """

    values: dict[str, Array]
    residual: Array
    dirs: Array
    t: Array
    rest_noise: float


def _log10(x: float) -> float:
    return math.log10(max(float(x), _TINY))


def rest_noise(raw: Array) -> float:
    """White noise std per axis (raw units, RMS over the axes) from trimmed second differences."""
    if raw.shape[0] < 5:
        return 0.0
    d2 = raw[2:] - 2.0 * raw[1:-1] + raw[:-2]
    out = []
    for a in range(3):
        col = np.abs(d2[:, a])
        keep = col[col <= np.quantile(col, 0.95)]
        out.append(float(np.sqrt(np.mean(keep**2))) / math.sqrt(6.0) / _TRIM_STD)
    return float(np.sqrt(np.mean(np.square(out))))


def residual_noise(r: Array) -> float:
    """White noise std, fraction of the field radius, from trimmed first differences of a fit's norm
    residual ``r`` in time order: the motion between samples does not enter (the residual of a fitted
    sensor barely depends on the direction), where it does enter second differences of the readings."""
    if r.size < 5:
        return 0.0
    d1 = np.abs(np.diff(r))
    keep = d1[d1 <= np.quantile(d1, 0.95)]
    return float(np.sqrt(np.mean(keep**2))) / math.sqrt(2.0) / _TRIM_STD


def _readout_features(raw: Array) -> dict[str, Array]:
    n = raw.shape[0]
    uniq, rep = [], []
    same = np.diff(raw, axis=0) == 0
    for a in range(3):
        col = raw[:, a]
        uniq.append(np.unique(col).size / n)
        rep.append(float(same[:, a].mean()))
    return {
        "quantisation": np.array([_log10(float(np.mean(uniq))), float(np.mean(rep)), float(same.all(axis=1).mean())]),
        "clipping": np.array([float(np.mean(clipped_shares(raw)))]),
    }


def clipped_shares(raw: Array) -> Array:
    """Per axis, the share of samples sitting exactly at the axis' largest or smallest reading (clipping)."""
    return np.array([float(np.mean((col == col.max()) | (col == col.min()))) for col in raw.T])


def sh_basis(dirs: Array, l_max: int = _L_MAX) -> Array:
    """Real spherical harmonics ``Y_lm`` (orthonormal on the sphere) at unit ``dirs``, (n, (l_max+1)^2)."""
    theta = np.arccos(np.clip(dirs[:, 2], -1.0, 1.0))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    # every (l, |m|) in one call, each once (+m and -m share it): the same values, half the time
    pairs = [(ell, m) for ell in range(l_max + 1) for m in range(ell + 1)]
    degree, order = (np.array(x)[:, None] for x in zip(*pairs, strict=True))
    table = dict(zip(pairs, sph_harm_y(degree, order, theta[None, :], phi[None, :]), strict=True))
    cols = []
    for ell in range(l_max + 1):
        for m in range(-ell, ell + 1):
            y = table[(ell, abs(m))]
            if m == 0:
                cols.append(y.real)
            elif m > 0:
                cols.append(math.sqrt(2.0) * (-1) ** m * y.real)
            else:
                cols.append(math.sqrt(2.0) * (-1) ** m * y.imag)
    return np.column_stack(cols)


def sh_power(residual: Array, basis: Array, l_max: int = _L_MAX) -> tuple[Array, Array]:
    """Least-squares harmonic coefficients of ``residual`` and its RMS amplitude per degree ``l`` on the samples.

    The amplitude of degree ``l`` is the RMS over the samples of what the degrees up to ``l`` explain beyond
    those up to ``l - 1`` (nested least squares). On directions that cover the sphere it is the RMS over
    the sphere of the degree-l part, ``sqrt(sum_m c_lm^2 / 4 pi)``; on part of it (a band of tilts) the
    harmonics are far from orthogonal and the coefficients, extrapolated to directions never seen, blow
    up by orders of magnitude, while what each degree adds on the samples stays what the data show.

    Returns:
        (coefficients ((l_max+1)^2,), amplitude (l_max+1,)).
    """
    coef = _lstsq(basis, residual)
    prev = np.zeros_like(residual)
    amp = np.zeros(l_max + 1)
    for ell in range(l_max + 1):
        cur = basis @ coef if ell == l_max else _explained(residual, basis[:, :(ell + 1) ** 2])
        amp[ell] = math.sqrt(float(np.mean((cur - prev) ** 2)))
        prev = cur
    return coef, amp


def _lstsq(x: Array, r: Array) -> Array:
    """Least-squares coefficients by the (lightly ridged) normal equations: fast for tall, thin ``x``."""
    g = x.T @ x
    g[np.diag_indices_from(g)] += 1e-9 * max(float(np.trace(g)) / g.shape[0], _TINY)
    out: Array = np.asarray(np.linalg.solve(g, x.T @ r), dtype=np.float64)
    return out


def _explained(r: Array, x: Array) -> Array:
    """The least-squares fit of ``r`` on the columns of ``x``."""
    return x @ _lstsq(x, r)


def _time_features(r: Array, basis: Array, t: Array, temp: Array | None, r_dir: Array) -> Array:
    """Residual explained by time modulation of ``Y_lm`` (l <= 2) beyond the static harmonics.

    Nested least-squares fits (so collinear columns cannot inflate a later term): the slow (k = 1, 2)
    modulation of the degree-1 harmonics first — an offset that moves (drift) —, then of degrees 0 and
    2 — gains that move (a temperature coefficient changes gains as well as the offset) —, then the
    faster k = 3..5; the lag-1 autocorrelation of what the direction fit leaves (bursts); offset step
    against smooth drift (``_step_feature``); with a temperature column, what ``(T - mean T) Y_lm``
    (l <= 2) explains beyond the static harmonics, and what all the time terms still explain beyond
    the static harmonics and the temperature terms, both relative to what the time terms explain
    beyond the static harmonics: a residual that follows the temperature leaves the time terms
    (almost) nothing, a drift that merely trends with it (a random walk, a linear course against a
    warm-up curve) leaves them its own course. The other sizes but the first are taken relative to
    the first (differences of log10 RMS). All relative sizes describe the *shape* of the change in
    time, which does not depend on how strong it is, so a twin whose effect is a little too weak or
    strong still matches them.
    """
    span = float(t[-1] - t[0]) if t.size > 1 else 1.0
    tau = (t - t[0]) / (span if span > 0 else 1.0)
    static = basis[:, :9]
    mods = [np.cos(math.pi * k * tau)[:, None] for k in range(1, _K_TIME + 1)]
    offset_cols = basis[:, 1:4]
    gain_cols = basis[:, [0, 4, 5, 6, 7, 8]]
    slow_off = np.hstack([static] + [mods[k] * offset_cols for k in (0, 1)])
    slow = np.hstack([slow_off] + [mods[k] * gain_cols for k in (0, 1)])
    full = np.hstack([slow] + [mods[k] * static for k in range(2, _K_TIME)])
    f0, f_off, f1, f2 = (_explained(r, x) for x in (static, slow_off, slow, full))
    left = r - r_dir
    left = left - left.mean()
    den = float(left @ left)
    acf = float(left[1:] @ left[:-1]) / den if den > 0 else 0.0
    off = _rms_log(f_off - f0)
    feats = [off, _rms_log(f1 - f_off) - off, _rms_log(f2 - f1) - off, acf,
             _step_feature(r, static, slow_off, tau, offset_cols)]
    if temp is not None and np.ptp(temp) > 0:
        z = ((temp - temp.mean()) / temp.std())[:, None]
        ft = _explained(r, np.hstack([static, z * static]))
        ftf = _explained(r, np.hstack([full, z * static]))
        varying = _rms_log(f2 - f0)  # the whole time variation the time terms find
        feats += [_rms_log(ft - f0) - varying, _rms_log(ftf - ft) - varying]
    return np.array(feats)


def _step_feature(r: Array, static: Array, slow_off: Array, tau: Array, offset_cols: Array) -> float:
    """Whether one offset step or a smooth offset drift explains the time-varying residual better.

    The best change point ``c`` (10-90 % of the span) is the one whose step ``H(tau - c) Y_1m(d)``,
    made orthogonal to the slow offset terms, explains most of what they leave. With ``e2_*`` the mean
    squared residual of the fit on the static harmonics plus: the step (``step``), the slow offset
    terms (``slow``), both (``both``), the feature is ``log10((e2_step - e2_both + eps) / (e2_slow -
    e2_both + eps))``: what the smooth terms add beyond the step over what the step adds beyond them
    — negative for a jump, positive for a drift, about 0 for noise (``eps``: the share of about six
    fitted noise terms, ``6 e2_both / n``).
    """
    g0 = slow_off.T @ slow_off
    g0[np.diag_indices_from(g0)] += 1e-9 * max(float(np.trace(g0)) / g0.shape[0], _TINY)
    # orthonormal columns spanning slow_off, q = slow_off V diag(w)^-1/2 from the small eigen-decomposition of its
    # normal matrix (a triangular solve on the tall matrix runs threaded BLAS steps that wait for a busy core)
    w, v = np.linalg.eigh(g0)
    q = slow_off @ (v / np.sqrt(np.maximum(w, _TINY)))
    left = r - q @ (q.T @ r)
    # every change point at once: the step columns are offset_cols on the samples with tau >= c, so
    # their products with q, themselves and ``left`` are tail sums (tau is non-decreasing)
    start = np.searchsorted(tau, np.linspace(0.1, 0.9, _N_STEPS), side="left")
    start = np.unique(start[start < tau.size])
    if start.size == 0:
        return 0.0

    def tails(a: Array) -> Array:
        return np.cumsum(a[::-1], axis=0)[::-1][start]

    qtx = tails(q[:, :, None] * offset_cols[:, None, :])  # (k, p, 3)
    g = tails(offset_cols[:, :, None] * offset_cols[:, None, :]) - np.einsum("kpi,kpj->kij", qtx, qtx)
    xtl = tails(offset_cols * left[:, None])  # (k, 3); left is orthogonal to q already
    g = g + 1e-9 * np.einsum("kii->k", g)[:, None, None] * np.eye(3) + _TINY * np.eye(3)
    gains = np.einsum("ki,ki->k", xtl, np.linalg.solve(g, xtl[:, :, None])[:, :, 0])
    j = int(np.argmax(gains))
    best = float(gains[j])
    best_x = offset_cols * (np.arange(tau.size) >= start[j])[:, None]
    n = r.size
    e2_slow = float(left @ left) / n
    e2_both = max(e2_slow - best / n, 0.0)
    rs = r - _explained(r, np.hstack([static, best_x]))
    e2_step = float(rs @ rs) / n
    eps = 6.0 * e2_both / n + _TINY
    return math.log10((max(e2_step - e2_both, 0.0) + eps) / (max(e2_slow - e2_both, 0.0) + eps))


def _rms_log(x: Array) -> float:
    return _log10(float(np.sqrt(np.mean(x**2))))


def _tail_features(r: Array) -> Array:
    med = float(np.median(r))
    dev = np.abs(r - med)
    sig = max(1.4826 * float(np.median(dev)), _TINY)
    q01, q50, q99 = np.quantile(r, [0.01, 0.5, 0.99])
    skew = float((q99 + q01 - 2 * q50) / max(q99 - q01, _TINY))
    return np.array([_log10(float(np.quantile(dev, 0.999)) / sig), _log10(float(np.quantile(dev, 0.99)) / sig),
                     _log10(float(np.std(r)) / sig), skew])


def stage_features(
    t: Array,
    raw: Array,
    temp: Array | None,
    sub: NDArray[np.intp],
    *,
    validator: object | None = None,
    norm: float | None = None,
    skip: frozenset[str] = frozenset(),
    closed_form: bool = False,
) -> StageFeatures:
    """All stage features of one recording.

    Args:
        t: times (n,), seconds.
        raw: raw readings (n, 3) at the full rate (rest noise and read-out stages use every sample).
        temp: temperature (n,) or None.
        sub: indices of the fitting subsample (the fits and residual stages use these only).
        validator: a validator with ``predict_indicators`` (the ``validator`` stage is skipped if None).
        norm: reference norm passed to the fits (None: estimated, det(W) = 1).
        skip: stages to leave out (e.g. ``rest_noise`` for a recording without time continuity).
        closed_form: fit ``diag`` by the closed-form ``lin_auto`` instead of ``lm`` (a recording with an
            offset change, see ``twin.Twin.change``: ``lm`` may not converge on it, and the recording and
            its twins must be measured alike).

    Raises:
        DegenerateDataError, ConvergenceError: the subsample cannot be fitted (e.g. a static recording).
    """
    pts = raw[sub]
    cal = fit(pts, model="diag", method="lin_auto", norm=norm) if closed_form else lm_diag(pts, norm)
    r_raw = cal.raw_radius
    h = cal.apply(pts)
    lengths = np.linalg.norm(h, axis=1)
    r = lengths / cal.norm - 1.0
    dirs = h / lengths[:, None]
    noise_rel = rest_noise(raw) / r_raw
    values: dict[str, Array] = {"rest_noise": np.array([_log10(noise_rel)])}
    values.update(_readout_features(raw))
    sym = sym_fit(pts, norm, closed_form)
    sym_rms = float(sym.stats.rms_relative) if sym is not None and sym.stats is not None else float("nan")
    values["residual_size"] = np.array([_log10(float(np.sqrt(np.mean(r**2)))), _log10(sym_rms)])
    basis = sh_basis(dirs)
    coef, amp = sh_power(r, basis)
    values["residual_direction"] = np.array([_log10(a) for a in amp[1:]])
    values["residual_cubic"] = np.array([cubic_feature(pts, sym, t[sub])])
    tsub = temp[sub] if temp is not None else None
    if "residual_time" not in skip:
        values["residual_time"] = _time_features(r, basis, t[sub], tsub, basis @ coef)
    values["residual_tails"] = _tail_features(r - basis @ coef)
    if validator is not None and sym is not None and not closed_form:  # its calibration set would not converge either
        pick = np.linspace(0, len(sub) - 1, min(N_SET, len(sub))).astype(np.intp)
        try:
            pred, meas = validator_errors(pts[pick], sym, validator)
            values["validator"] = np.array([_log10(meas / max(pred, _TINY))])
        except MargCalError as exc:
            log.debug("validator stage skipped: %s", exc)
    for name in skip:
        values.pop(name, None)
    return StageFeatures(values=values, residual=r, dirs=dirs, t=t[sub], rest_noise=noise_rel)


def stage_gaps(
    rec: dict[str, Array], twin_mean: dict[str, Array], twin_sd: dict[str, Array]
) -> dict[str, float]:
    """Gap of each stage on the common z scale: RMS over its features of ``(rec - mean) / max(sd, floor)``.

    Stages missing on any side (the recording, the twins' mean or their spread: a stage that could not
    be computed for one of them) are left out.
    """
    out: dict[str, float] = {}
    for name in STAGES:
        if name not in rec or name not in twin_mean or name not in twin_sd:
            continue
        a, m, s = rec[name], twin_mean[name], twin_sd[name]
        if a.shape != m.shape or s.shape != m.shape:
            continue
        floor = stage_floor(name, a.shape)
        z = (a - m) / np.maximum(s, floor)
        z = np.where(np.isfinite(z), z, 0.0)
        out[name] = float(np.sqrt(np.mean(z**2)))
    return out
