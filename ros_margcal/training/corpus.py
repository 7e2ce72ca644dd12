"""Labelled calibration sets from the simulator, to train and evaluate the validators.

Each set is one simulated calibration attempt (Olivares et al. 2013, §4, pre-processing steps):

1. a random true sensor (``simulation.random_sensor``: magnetometer or accelerometer, random offset,
   gains and symmetric cross terms), a random noise level and a random coverage pattern with random
   parameters and size (caps of any size, bands, partial great circles, the axis ellipses of Fig. 7,
   random walks, a few static poses, uniform with few or many points);
2. the ellipsoid fit of the set (``fitting.fit``, model ``sym``, scale-free: ``norm=None``);
3. the *label*: the calibration error of that fit on a uniform held-out test set of the same sensor
   (noiseless directions, so the label is the calibration error, not the test noise), the RMS of
   ``|W (v - b)| / norm - 1``; a set whose fit fails gets ``FAILED_ERROR``;
4. the *features*: the coverage indicators (``coverage.compute_indicators``: raw A–D and the
   normalised ones) plus the proposed information indicator E (``information_indicator``), about
   the centre and radius of a linear sphere fit of the set — what the node (``stream.calibrator``) uses
   before it has a calibration — and the baseline scores of ``baselines.baseline_scores`` given the
   set's own ellipsoid fit.

A second label serves the diagnosis (``diagnosis.downstream``), which retrains the validator with an
effect and compares its prediction with the error *measured* on a recording, where no truth exists:
with ``make_set(recording=k)`` the set is every ``k``-th sample of a simulated recording and its label
is ``recording_error``, the error against that recording's best fit — the measured error's definition.

Choices, documented: the noise std is log-uniform in 0.1–0.5 % of the norm (consumer MEMS
magnetometers, accelerometers after the inactivity gate); sets hold 40–600 samples; the fit is the
plain least-squares ``lm`` (the node's robust loss changes no label here — the simulator adds no
outliers — and costs nine times more); magnetometers and accelerometers are mixed, so the raw
indicators C and D (raw units, tesla vs m/s²) are not comparable across sets, unlike in the paper's
single-sensor data — the normalised ones are.

Every set ``i`` of a corpus with seed ``s`` draws from ``np.random.default_rng([s, i])``, so a corpus
is reproducible, any set can be regenerated alone, and sets are independent of the corpus size.
``group = i % 2`` splits the corpus into the paper's "dataset 1" and "dataset 2" for the
train-on-one / test-on-the-other protocol.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, TextIO

import numpy as np
from numpy.typing import NDArray

from ..coverage.indicators import compute_indicators, information_indicator
from ..model.calibration import Calibration
from ..model.errors import CalibrationFileError, ConfigError, MargCalError
from ..model.fitting import fit
from ..sim.simulation import EFFECTS, directions, random_sensor, simulate
from ..validation.baselines import BASELINES, baseline_scores
from .labels import label_error, recording_error, reference_readings

__all__ = [
    "FAILED_ERROR", "FEATURES", "Corpus", "build_corpus", "information_indicator", "label_error", "make_set",
    "recording_error", "reference_readings"
]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

FEATURES: tuple[str, ...] = ("b_frac", "c_norm", "d_norm", "e_info", "e_total", "A", "B", "C", "D")
"""Feature columns: the normalised indicators, the proposed information indicators (``e_info``, and
``e_total`` = e_info + log10 n), then the raw indicators A–D of the paper."""


FAILED_ERROR = 1.0
"""Label of a set whose fit raised (degenerate or non-converged): 100 % error, certainly ill."""


@dataclass
class Corpus:
    """Labelled calibration sets, one row per set.

    Attributes:
        features: (n, len(feature_names)) indicator values.
        error: (n,) calibration error of each set's fit on held-out data (RMS relative norm error).
        baselines: (n, len(baseline_names)) raw baseline scores.
        pattern: (n,) coverage pattern name of each set.
        kind: (n,) "mag" or "accel".
        n_points: (n,) samples in each set.
        noise: (n,) noise std as a fraction of the norm.
        group: (n,) 0 or 1, the half of the train/test swap.
        meta: how the corpus was made (seed, size, options).
    """

    features: Array
    error: Array
    baselines: Array
    pattern: NDArray[np.str_]
    kind: NDArray[np.str_]
    n_points: NDArray[np.int64]
    noise: Array
    group: NDArray[np.int64]
    feature_names: tuple[str, ...] = FEATURES
    baseline_names: tuple[str, ...] = tuple(BASELINES)
    meta: dict[str, Any] = field(default_factory=dict)

    FORMAT_VERSION: ClassVar[int] = 1

    def __len__(self) -> int:
        return int(self.error.shape[0])

    def column(self, name: str) -> Array:
        """One feature or baseline column by name."""
        if name in self.feature_names:
            return self.features[:, self.feature_names.index(name)]
        if name in self.baseline_names:
            return self.baselines[:, self.baseline_names.index(name)]
        msg = f"no column {name!r}; features {self.feature_names}, baselines {self.baseline_names}"
        raise ConfigError(msg)

    def matrix(self, names: tuple[str, ...] | list[str]) -> Array:
        """Feature rows (n, len(names)) for a validator with these inputs."""
        return np.column_stack([self.column(n) for n in names])

    def good(self, max_error: float) -> NDArray[np.bool_]:
        """The positive class: sets whose calibration error is below ``max_error``."""
        return self.error < max_error

    def subset(self, mask: NDArray[np.bool_] | NDArray[np.intp]) -> Corpus:
        """The sets selected by a boolean mask or index array."""
        return dataclasses.replace(
            self, features=self.features[mask], error=self.error[mask], baselines=self.baselines[mask],
            pattern=self.pattern[mask], kind=self.kind[mask], n_points=self.n_points[mask],
            noise=self.noise[mask], group=self.group[mask], meta=dict(self.meta),
        )

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the corpus as a compressed ``.npz`` (no pickles)."""
        p = Path(path)
        meta = {k: str(v) for k, v in self.meta.items()}
        np.savez_compressed(
            p, format_version=np.int64(self.FORMAT_VERSION), features=self.features, error=self.error,
            baselines=self.baselines, pattern=self.pattern.astype(str), kind=self.kind.astype(str),
            n_points=self.n_points, noise=self.noise, group=self.group,
            feature_names=np.array(self.feature_names), baseline_names=np.array(self.baseline_names),
            meta_keys=np.array(list(meta), dtype=str), meta_values=np.array(list(meta.values()), dtype=str),
        )
        return p if p.suffix == ".npz" else p.with_name(p.name + ".npz")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Corpus:
        """Read a corpus written by ``save``; CalibrationFileError if corrupt or newer."""
        p = Path(path)
        try:
            with np.load(p, allow_pickle=False) as z:
                version = int(z["format_version"])
                if version > cls.FORMAT_VERSION:
                    msg = f"{p}: corpus format_version {version} is newer than this ros_margcal reads ({cls.FORMAT_VERSION})"
                    raise CalibrationFileError(msg)
                c = cls(
                    features=z["features"], error=z["error"], baselines=z["baselines"], pattern=z["pattern"],
                    kind=z["kind"], n_points=z["n_points"], noise=z["noise"], group=z["group"],
                    feature_names=tuple(str(s) for s in z["feature_names"]),
                    baseline_names=tuple(str(s) for s in z["baseline_names"]),
                    meta=dict(zip(z["meta_keys"].tolist(), z["meta_values"].tolist(), strict=True)),
                )
        except CalibrationFileError:
            raise
        except (OSError, KeyError, ValueError) as exc:
            msg = f"{p}: not a readable corpus file ({type(exc).__name__}: {exc})"
            raise CalibrationFileError(msg) from exc
        n = len(c)
        if c.features.shape != (n, len(c.feature_names)) or c.baselines.shape != (n, len(c.baseline_names)):
            msg = f"{p}: corrupt corpus (column shapes disagree)"
            raise CalibrationFileError(msg)
        return c


# -- one set ---------------------------------------------------------------------------------------


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _random_pattern(rng: np.random.Generator, n_min: int, n_max: int) -> tuple[str, int, dict[str, Any]]:
    """A coverage pattern with random parameters and a random size (log-uniform in [n_min, n_max])."""
    axis = tuple(rng.normal(size=3))
    n = round(_log_uniform(rng, n_min, n_max))
    # weights favour the partial patterns whose verdict is hard; uniform sets cover the good end
    names = ("uniform", "few_uniform", "cap", "band", "great_circle", "axis_ellipses", "random_walk")
    pattern = str(rng.choice(names, p=(0.16, 0.10, 0.22, 0.16, 0.12, 0.08, 0.16)))
    params: dict[str, Any] = {}
    if pattern == "few_uniform":
        params = {"k": int(rng.integers(3, 25)), "jitter_deg": float(rng.uniform(0.5, 15.0))}
    elif pattern == "cap":
        params = {"half_angle_deg": float(rng.uniform(10.0, 180.0)), "axis": axis}
    elif pattern == "band":
        lo = float(rng.uniform(-90.0, 60.0))
        params = {"lat_min_deg": lo, "lat_max_deg": float(rng.uniform(lo + 5.0, 90.0)), "axis": axis}
    elif pattern == "great_circle":
        params = {"arc_deg": float(rng.uniform(45.0, 360.0)), "n_circles": int(rng.integers(1, 6))}
    elif pattern == "axis_ellipses":
        params = {"jitter_deg": float(rng.uniform(0.0, 20.0))}
    elif pattern == "random_walk":
        params = {"step_deg": _log_uniform(rng, 0.5, 20.0)}
    return pattern, n, params


def _indicator_frame(points: Array) -> tuple[Array, float]:
    """Centre and radius the indicators are normalised with: a linear sphere fit, as the node does
    before its first calibration (``stream.calibrator``); the mean and mean distance if even that fails."""
    try:
        sph = fit(points, model="eye", method="sphere", norm=None)
        if math.isfinite(sph.norm) and sph.norm > 0:
            return sph.offset, float(sph.norm)
    except MargCalError:
        pass
    center = points.mean(axis=0)
    return center, float(np.linalg.norm(points - center, axis=1).mean()) or 1.0


_READOUT_RANDOM = ("noise", "quantization")
_STATIC_EFFECTS = frozenset(name for name, e in EFFECTS.items() if not e.varying and name not in _READOUT_RANDOM)
"""Effects that are a property of the sensor (the same at every instant, not random read-out): the
sensor that defines the label of a set with effects (without ``recording``) carries them."""


def _reference_points(truth: Calibration, dirs: Array, rng: np.random.Generator, static: dict[str, float]) -> Array:
    """The label's test points for a sensor with the static effects ``static``: the noiseless readings
    of ``dirs`` with the effects, replaced by their best ellipsoid (``sym`` fit) read at the same
    directions. Falls back to the readings themselves when they cannot be fitted."""
    raw = simulate(truth, dirs, noise=0.0, rng=rng, effects=static).raw
    try:
        ref = fit(raw, model="sym", method="lm", norm=None)
    except MargCalError as exc:
        log.debug("label reference with %s not fitted (%s): using the readings", static, exc)
        return raw
    return reference_readings(ref, dirs / np.linalg.norm(dirs, axis=1, keepdims=True))


def _recording_times(n: int, k: int, duration_s: float | None) -> Array:
    """Times of a recording holding each of ``n`` set directions for ``k`` samples: the set (every
    ``k``-th sample) is spread evenly over ``duration_s`` (1 s apart when None)."""
    dt = 1.0 if duration_s is None or n < 2 else duration_s / (n - 1)
    out: Array = np.arange(n * k) * (dt / k)
    return out


def make_set(seed: int, index: int, *, n_min: int = 40, n_max: int = 600, noise_range: tuple[float, float] = (1e-3, 5e-3),
             n_test: int = 400, model: str = "sym", method: str = "lm", loss: str = "linear",
             pattern: str | None = None, n: int | None = None, params: dict[str, Any] | None = None,
             effects: dict[str, float] | None = None, duration_s: float | None = None,
             recording: int | None = None, kind: str | None = None) -> dict[str, Any]:
    """Simulate, fit, label and describe set ``index`` of the corpus with ``seed``.

    Two labels. By default the set is a calibration set on its own and the label its fit's error
    against the true sensor (step 3). With ``recording=k`` the set is drawn from a recording, as the
    diagnosis draws one from a real recording (``diagnosis.downstream``): the simulated recording holds
    each of the set's directions for ``k`` samples (so it has the set's coverage and time course, like
    a smooth motion sampled ``k`` times denser), every effect and the noise apply to all its samples,
    the set is every ``k``-th sample, and the label is ``recording_error`` of the set's fit against the
    recording's best fit — exactly what ``diagnosis.downstream.validator_errors`` measures on a real
    recording, where no truth exists. A drift the whole recording shares then stays out of the label;
    noise and what varies between samples of the set (bursts) go in.

    Args:
        seed: corpus seed; index: set number (the set draws from ``default_rng([seed, index])``).
        n_min, n_max: range of the set size (log-uniform).
        noise_range: range of the noise std as a fraction of the norm (log-uniform).
        n_test: held-out uniform directions for the label against the truth.
        model, method, loss: the fit whose error is the label (``fitting.fit``).
        pattern, n, params: force the coverage pattern, size and parameters (else random).
        effects: simulator effects (name -> magnitude) added to the set, those that apply to the
            set's sensor kind. Without ``recording``, the label's sensor carries the static ones
            (``_STATIC_EFFECTS``, with the same random draws as the set: the error is against that
            sensor's best ellipsoid over uniform directions); effects that vary in time and the
            read-out ones stay out of the label. Without effects and ``recording`` the set is exactly
            as before effects existed.
        duration_s: time span of the set (its samples evenly spread over it); None: 1 s apart.
        recording: ``k >= 2``: label the set as drawn from a recording ``k`` times denser (above).
        kind: force the sensor kind ("mag" or "accel"; else 60 % mag).

    Returns:
        A dict with ``features`` (len(FEATURES),), ``error``, ``baselines`` (len(BASELINES),),
        ``pattern``, ``kind``, ``n_points``, ``noise``, ``points``, ``fit`` (None if it failed) and
        ``reference`` (the recording's best fit with ``recording``, else None).

    Raises:
        ConfigError: ``recording`` below 2 or an unknown ``kind``.
    """
    if recording is not None and recording < 2:
        msg = f"recording must be at least 2 (samples of the recording per set sample), got {recording}"
        raise ConfigError(msg)
    if kind not in (None, "mag", "accel"):
        msg = f"kind must be 'mag', 'accel' or None, got {kind!r}"
        raise ConfigError(msg)
    rng = np.random.default_rng([seed, index])
    drawn_kind = "mag" if rng.uniform() < 0.6 else "accel"
    kind = kind or drawn_kind
    truth = random_sensor(rng, kind, model="sym", gain_spread=float(rng.uniform(0.01, 0.2)),
                          skew=float(rng.uniform(0.0, 0.06)))
    noise = _log_uniform(rng, *noise_range)
    rand_pattern, rand_n, rand_params = _random_pattern(rng, n_min, n_max)
    if pattern is None:
        pattern, params = rand_pattern, rand_params
    n = rand_n if n is None else int(n)
    dirs = directions(pattern, n, rng, **(params or {}))
    applied = {k: float(m) for k, m in (effects or {}).items() if kind in EFFECTS[k].sensors and m}
    reference: Calibration | None = None
    if recording is not None:
        t_rec = _recording_times(n, recording, duration_s)
        rec_raw = simulate(truth, np.repeat(dirs, recording, axis=0), noise=noise, rng=rng, t=t_rec,
                           effects=applied or None).raw
        points = rec_raw[::recording]
    else:
        t_set = None if duration_s is None else np.linspace(0.0, duration_s, n)
        label_fx = {k: m for k, m in applied.items() if k in _STATIC_EFFECTS}
        fx_rng = copy.deepcopy(rng) if label_fx else None  # the label's sensor: the same effect draws as the set's
        points = simulate(truth, dirs, noise=noise, rng=rng, t=t_set, effects=applied or None).raw
        test_dirs = directions("uniform", n_test, rng)
        test_raw = simulate(truth, test_dirs, noise=0.0, rng=rng).raw
        if fx_rng is not None:
            test_raw = _reference_points(truth, test_dirs, fx_rng, label_fx)
    cal: Calibration | None
    try:
        cal = fit(points, model=model, method=method, norm=None, loss=loss)
    except MargCalError as exc:
        log.debug("set %d (%s, n=%d): fit failed: %s", index, pattern, n, exc)
        cal = None
    error = FAILED_ERROR
    if cal is not None and recording is None:
        error = label_error(cal, test_raw)
    elif cal is not None:  # the recording's best fit: only needed (and costly) when the set's fit exists
        try:
            reference = fit(rec_raw, model="sym", method="lm", norm=None)
            error = recording_error(cal, reference)
        except MargCalError as exc:
            log.debug("set %d (%s, n=%d): recording not fitted: %s", index, pattern, n, exc)
    if not math.isfinite(error) or error > FAILED_ERROR:
        error = FAILED_ERROR
    center, radius = _indicator_frame(points)
    ind = compute_indicators(points, center, radius)
    feats = np.array([float(getattr(ind, name)) for name in FEATURES])
    if cal is not None:
        base = baseline_scores(points, cal)
        bvals = np.array([base[name] for name in BASELINES])
    else:
        bvals = np.array([np.nan] * len(BASELINES))
    return {"features": feats, "error": error, "baselines": bvals, "pattern": pattern, "kind": kind,
            "n_points": n, "noise": noise, "points": points, "fit": cal, "params": params or {},
            "reference": reference}


# -- many sets -------------------------------------------------------------------------------------


def _worst_baselines(values: Array) -> Array:
    """Fill the baseline scores of failed fits with each baseline's worst value in the corpus."""
    out = values.copy()
    for j, name in enumerate(BASELINES):
        col = out[:, j]
        bad = ~np.isfinite(col)
        if bad.any():
            finite = col[~bad]
            if BASELINES[name].higher_is_better:
                col[bad] = finite.min() if finite.size else 0.0
            else:
                col[bad] = finite.max() if finite.size else 1e12
    return out


def build_corpus(n_sets: int, seed: int = 0, *, progress: bool | TextIO = False, **options: Any) -> Corpus:
    """Simulate ``n_sets`` labelled calibration sets (``make_set`` for ``index = 0 .. n_sets-1``).

    Args:
        n_sets: number of sets (>= 2, so both groups of the swap are populated).
        seed: corpus seed.
        progress: True (stderr) or a stream to show a counter on (in place on a terminal, else a line a quarter).
        **options: passed on to ``make_set`` (n_min, n_max, noise_range, n_test, model, method, effects,
            duration_s, recording, kind).
    """
    if n_sets < 2:
        msg = f"n_sets must be >= 2, got {n_sets}"
        raise ConfigError(msg)
    stream = sys.stderr if progress is True else (progress or None)
    # a counter in place on a terminal; a log (no terminal) gets a line a quarter
    live = stream is not None and bool(getattr(stream, "isatty", lambda: False)())
    quarters = {max(1, round(k * n_sets / 4)) for k in (1, 2, 3, 4)}
    rows = []
    t0 = time.monotonic()
    for i in range(n_sets):
        rows.append(make_set(seed, i, **options))
        if stream is not None and (i + 1 == n_sets or ((i + 1) % 25 == 0 if live else i + 1 in quarters)):
            text = f"corpus: {i + 1}/{n_sets} sets, {time.monotonic() - t0:.0f} s"
            print(f"\r{text}" if live else text, end="" if live else "\n", file=stream, flush=True)
    if live:
        print(file=stream)
    n_failed = sum(r["fit"] is None for r in rows)
    meta = {"seed": seed, "n_sets": n_sets, "n_failed": n_failed, **options}
    log.debug("corpus of %d sets (seed %d): %d of them too poor for a fit, labelled as failed calibrations", n_sets,
              seed, n_failed)
    return Corpus(
        features=np.array([r["features"] for r in rows]),
        error=np.array([r["error"] for r in rows]),
        baselines=_worst_baselines(np.array([r["baselines"] for r in rows])),
        pattern=np.array([r["pattern"] for r in rows]),
        kind=np.array([r["kind"] for r in rows]),
        n_points=np.array([r["n_points"] for r in rows], dtype=np.int64),
        noise=np.array([r["noise"] for r in rows]),
        group=np.arange(n_sets, dtype=np.int64) % 2,
        meta=meta,
    )
