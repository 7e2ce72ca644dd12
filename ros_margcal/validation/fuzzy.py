"""Validators of calibration sets: single-indicator thresholding and the zero-order TSK fuzzy system.

Olivares et al. 2013 (§3.2–§4) decide whether a set of raw samples is well enough distributed over
the sphere for an ellipsoid fit. Two validators are built here, both trained on labelled sets
(``ros_margcal.training.corpus``) whose label is the calibration error of the fit made from the set.

*Positive class.* A set is *good* (valid, the paper's ζ = 1) when its calibration error is below
``max_error`` (the paper's ε_max). We use 1 % RMS relative norm error (``DEFAULT_MAX_ERROR``): the
paper's ε_max ≈ 0.027 G of 0.432 G is ≈ 6 %, but that includes the sensor noise of the test points;
our label is measured on noiseless held-out directions, so it is the calibration error alone, and
1 % of the field norm corresponds to direction errors of roughly 0.6°, the order of what a good
consumer magnetometer calibration achieves. Sensitivity = good sets accepted / good sets;
specificity = ill sets rejected / ill sets; "ill sets accepted" = 1 − specificity.

*Single-indicator thresholding* (§3.2, Eq. 13): ``IF I_i >= alpha_i THEN valid`` (``<=`` for
indicator B, the count of empty bins); alpha_i by grid search for the best AUC (§4). As in Tables 1–2,
the "AUC" of one threshold is the area under the two-segment ROC through that operating point,
(sensitivity + specificity) / 2; the threshold-free AUC of the indicator is reported beside it.

*Fuzzy validator* (§3.3, Eqs. 16–23): a zero-order TSK system with a complete rule base over M
inputs, n triangular membership functions (MFs) per input forming a complete partition (so the
denominator of Eq. 17 is 1), product t-norm, output the predicted error. Training:

- the training error is ``ε_train = ε_calib − F~`` (Eq. 18) and the cost ``J = Σ_k (F − F~)²``
  (Eq. 19);
- consequents start at zero and follow the reward/penalty rule, Eq. 21, with C = 1 (Eq. 22):
  ``ΔR_i = C · α_i(x_k) · (F(x_k) − F~(x_k))`` where ``α_i`` is the firing strength (Eq. 20);
- interior MF centres follow the saturated gradient step of Eq. 23:
  ``Δc = −η · (∂J/∂c) / (|∂J/∂c| + l)`` with η half the distance to the neighbour on the side the
  centre moves to, so centres never cross and the partition stays complete and ordered; the first
  and last centres stay at the ends of the input interval;
- the data are presented ``repeats`` times (the paper repeats its ~50 sets ten times), shuffled with
  a seeded generator.

Both rules are applied online, one sample at a time, as in the adaptive systems the paper cites.
Inputs are scaled to [0, 1] by the training range (values outside are clipped), and ``l`` defaults
to 10 in those units: a small ``l`` makes every sample move a centre by almost η, and the
partition jitters instead of settling (measured: higher withheld error than fixed centres).
Deviation from the paper, documented: the system learns ``log10`` of the error (``target="log"``,
the default) because simulated errors span four decades and a least-squares fit on the raw error
would be dominated by the worst sets; the prediction is turned back into an error, so the output and
the threshold are in error units as in the paper. ``target="linear"`` reproduces the paper exactly.
After training, the threshold on the predicted error is chosen by grid search as in §4, under a
cap on the fraction of ill training sets accepted (``max_fpr``, default ``DEFAULT_MAX_FPR``).
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model.calibration_file import read_small_text
from ..model.errors import CalibrationFileError, ConfigError, InputError
from .roc import OperatingPoint, operating_point
from .threshold import _LOG_FLOOR, DEFAULT_MAX_ERROR, DEFAULT_MAX_FPR, _features, _row_from

__all__ = ["INDICATOR_NAMES", "MAX_FILE_BYTES", "MAX_MF", "MAX_RULES", "FuzzyValidator"]

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

MAX_MF = 64
"""Most membership functions per input (the trained validators use 4-10)."""
MAX_RULES = 100_000
"""Most rules (the product of ``n_mf``): a file asking for 1e9 x 1e9 allocated 7 TiB."""
MAX_FILE_BYTES = 16 * 1024 * 1024
"""Largest validator file read (``MAX_RULES`` consequents as JSON are about 2 MB)."""
INDICATOR_NAMES = ("A", "B", "C", "D", "b_frac", "c_norm", "d_norm", "n_points", "radius", "e_info", "e_total")
"""The inputs a validator read from a file may take: the coverage indicators the calibrator computes
(``coverage.indicators.Indicators``' fields and ``e_total``; a layer above this one, so named here)."""

class FuzzyValidator:
    """Zero-order TSK fuzzy system predicting the calibration error from coverage indicators.

    Args:
        inputs: feature names, one per input (default the normalised indicators C and D).
        n_mf: triangular MFs per input (an int for all inputs, or one per input), at least 2.
        target: ``"log"`` (learn log10 of the error; default) or ``"linear"`` (the paper).
        max_error: error below which a set is good; sets the class labels for the threshold search.
    """

    FORMAT_VERSION: ClassVar[int] = 1
    KIND: ClassVar[str] = "ros_margcal.FuzzyValidator"

    def __init__(self, inputs: Sequence[str] = ("c_norm", "d_norm"), n_mf: int | Sequence[int] = 10, *,
                 target: str = "log", max_error: float = DEFAULT_MAX_ERROR) -> None:
        self.inputs = tuple(str(s) for s in inputs)
        m = len(self.inputs)
        if m == 0:
            msg = "FuzzyValidator needs at least one input"
            raise ConfigError(msg)
        n = [int(n_mf)] * m if isinstance(n_mf, int | np.integer) else [int(k) for k in n_mf]
        if len(n) != m or min(n) < 2 or max(n) > MAX_MF or math.prod(n) > MAX_RULES:
            msg = (f"n_mf must be one int in [2, {MAX_MF}] or one per input ({m}), at most {MAX_RULES} rules in all, "
                   f"got {n_mf!r}")
            raise ConfigError(msg)
        if target not in ("log", "linear"):
            msg = f"target must be 'log' or 'linear', got {target!r}"
            raise ConfigError(msg)
        if not (math.isfinite(max_error) and max_error > 0):
            msg = f"max_error must be a finite number > 0, got {max_error}"
            raise ConfigError(msg)
        self.n_mf = tuple(n)
        self.target = target
        self.max_error = float(max_error)
        self.lo = np.zeros(m)
        self.hi = np.ones(m)
        # centres in the unit interval of each input (x scaled by lo/hi); equidistant to start
        self.centers: list[Array] = [np.linspace(0.0, 1.0, k) for k in self.n_mf]
        self.consequents: Array = np.zeros(self.n_mf)
        self.threshold: float | None = None
        self.metadata: dict[str, Any] = {}
        self._corners = list(itertools.product((0, 1), repeat=m))

    # ---- the fuzzy system (Eq. 17 with a complete partition) ------------------------------------

    def _scale(self, x: Array) -> Array:
        span = np.where(self.hi > self.lo, self.hi - self.lo, 1.0)
        return np.clip((x - self.lo) / span, 0.0, 1.0)

    def _locate(self, xs: Array) -> tuple[NDArray[np.intp], Array]:
        """Segment index j and position u in [0, 1] of each scaled input between centres j and j+1."""
        n, m = xs.shape
        j = np.empty((n, m), dtype=np.intp)
        u = np.empty((n, m))
        for d, c in enumerate(self.centers):
            jd = np.clip(np.searchsorted(c, xs[:, d], side="right") - 1, 0, c.size - 2)
            width = c[jd + 1] - c[jd]
            j[:, d] = jd
            u[:, d] = np.clip((xs[:, d] - c[jd]) / width, 0.0, 1.0)
        return j, u

    def _active_rules(self, xs: Array) -> list[tuple[NDArray[np.intp], Array]]:
        """The 2^M rules that fire for each row: (flat rule index, firing strength) per corner of the
        row's cell (product t-norm, Eq. 20); every other rule has strength 0 (complete partition)."""
        j, u = self._locate(xs)
        out = []
        for bits in self._corners:
            b = np.asarray(bits)
            out.append((np.ravel_multi_index(tuple((j + b).T), self.n_mf), np.prod(np.where(b == 1, u, 1.0 - u), axis=1)))
        return out

    def _firing(self, xs: Array) -> Array:
        """Firing strength of every rule for every row, (n, number of rules): the least-squares design."""
        a = np.zeros((xs.shape[0], self.consequents.size))
        rows = np.arange(xs.shape[0])
        for idx, w in self._active_rules(xs):
            np.add.at(a, (rows, idx), w)
        return a

    def _raw_output(self, xs: Array) -> Array:
        """Eq. 17: sum of consequents weighted by firing strengths (a complete partition: they sum to 1)."""
        r = self.consequents.ravel()
        return sum((w * r[idx] for idx, w in self._active_rules(xs)), np.zeros(xs.shape[0]))

    def _to_target(self, error: Array) -> Array:
        return np.log10(np.maximum(error, _LOG_FLOOR)) if self.target == "log" else error

    def _from_target(self, z: Array) -> Array:
        return np.power(10.0, z) if self.target == "log" else z

    def predict(self, x: ArrayLike) -> Array:
        """Predicted calibration error (RMS relative norm error) of each set, (n,)."""
        xs = self._scale(_features(x, len(self.inputs)))
        return self._from_target(self._raw_output(xs))

    def predict_indicators(self, indicators: Any) -> float:
        """Predicted error of one set from an ``Indicators`` object or a name -> value mapping."""
        return float(self.predict(_row_from(indicators, self.inputs))[0])

    def accept(self, x: ArrayLike) -> NDArray[np.bool_]:
        """Valid when the predicted error is at most the tuned threshold."""
        if self.threshold is None:
            msg = "FuzzyValidator has no threshold: call fit() or tune_threshold() first"
            raise ConfigError(msg)
        return self.predict(x) <= self.threshold

    def consequent_bounds(self) -> tuple[float, float]:
        """Smallest and largest prediction the system can make (a convex mix of consequents)."""
        r = self._from_target(np.array([self.consequents.min(), self.consequents.max()]))
        return float(r[0]), float(r[1])

    # ---- training (Eqs. 18–23) -----------------------------------------------------------------

    def fit(self, x: ArrayLike, error: ArrayLike, *, repeats: int = 10, l_rate: float = 10.0,
            seed: int = 0, max_fpr: float | None = DEFAULT_MAX_FPR, train_centers: bool = True,
            consequents: str = "paper", ridge: float = 1e-3) -> FuzzyValidator:
        """Train on feature rows ``x`` (n, M) labelled with calibration errors ``error`` (n,).

        Args:
            repeats: passes over the data (the paper presents its sets ten times).
            l_rate: the learning parameter ``l`` of Eq. 23 (in units of the gradient of the squared
                error w.r.t. a centre in the unit-scaled input); larger = smaller centre steps.
            seed: seed of the generator that shuffles each pass.
            max_fpr: cap on ill sets accepted when the threshold is tuned afterwards (None: no cap).
            train_centers: False keeps the equidistant partition (consequents only).
            consequents: ``"paper"`` keeps the consequents of the online reward/penalty rule
                (Eq. 21); ``"lsq"`` then re-solves them by least squares over the trained
                partition (``_solve_consequents``).
            ridge: weight pulling the least-squares consequents towards the online ones (rules
                that few sets fire stay near their Eq. 21 value).
        """
        xa = _features(x, len(self.inputs))
        err = np.asarray(error, dtype=np.float64).reshape(-1)
        if err.shape[0] != xa.shape[0] or not np.isfinite(err).all() or (err < 0).any():
            msg = f"error must be {xa.shape[0]} finite non-negative values, got shape {err.shape}"
            raise InputError(msg)
        if repeats < 1 or l_rate <= 0 or consequents not in ("paper", "lsq") or not ridge > 0:
            msg = (f"repeats must be >= 1, l_rate > 0, consequents 'paper' or 'lsq' and ridge > 0; "
                   f"got {repeats}, {l_rate}, {consequents!r}, {ridge}")
            raise ConfigError(msg)
        self.lo, self.hi = xa.min(axis=0), xa.max(axis=0)
        self.centers = [np.linspace(0.0, 1.0, k) for k in self.n_mf]
        self.consequents = np.zeros(self.n_mf)
        xs = self._scale(xa)
        z = self._to_target(err)
        rng = np.random.default_rng(seed)
        for _ in range(repeats):
            for k in rng.permutation(xs.shape[0]):
                self._step(xs[k], float(z[k]), l_rate, train_centers)
        if consequents == "lsq":
            self._solve_consequents(xs, z, ridge)
        self.tune_threshold(xa, err, max_fpr=max_fpr)
        self.metadata.update({"n_train": int(xa.shape[0]), "repeats": int(repeats), "l_rate": float(l_rate),
                              "seed": int(seed), "max_fpr": max_fpr, "consequents": consequents})
        if consequents == "lsq":
            self.metadata["ridge"] = float(ridge)
        return self

    def _solve_consequents(self, xs: Array, z: Array, ridge: float) -> None:
        """Minimise Eq. 19's cost over all consequents at once, the partition fixed.

        The zero-order TSK output is linear in its consequents, so ``min_R |A R - z|² + ridge |R - R0|²``
        (``A`` the firing strengths, ``R0`` the online Eq. 21 result) is one linear solve. The online
        rule with C = 1 is a per-sample LMS step that never settles: its final consequents remember
        the last few sets of the last pass (measured: withheld AUC moves by ±0.005 with the number
        of passes). Deviation from the paper, opt-in (``consequents="lsq"``), as in ANFIS's hybrid
        learning.
        """
        a = self._firing(xs)
        r0 = self.consequents.ravel()
        lhs = a.T @ a + ridge * np.eye(r0.size)
        self.consequents = np.linalg.solve(lhs, a.T @ z + ridge * r0).reshape(self.n_mf)

    def _step(self, x: Array, z: float, l_rate: float, train_centers: bool) -> None:
        m = x.size
        j, u = self._locate(x.reshape(1, m))
        j, u = j[0], u[0]
        idx, weights = [], []
        for bits in self._corners:
            b = np.asarray(bits)
            idx.append(tuple(j + b))
            weights.append(float(np.prod(np.where(b == 1, u, 1.0 - u))))
        r = np.array([self.consequents[i] for i in idx])
        w = np.asarray(weights)
        e = z - float(w @ r)  # Eq. 18: epsilon_train = eps_calib - F~ (per-sample term of J, Eq. 19)
        # Eq. 21 with C = 1 (Eq. 22): reward/penalty in proportion to the firing strength (Eq. 20)
        for i, wi in zip(idx, w, strict=True):
            self.consequents[i] += wi * e
        if not train_centers:
            return
        for d in range(m):
            c = self.centers[d]
            jd = int(j[d])
            width = c[jd + 1] - c[jd]
            # dF/du_d = G_1 - G_0, the other inputs' weights folded into G
            g1 = g0 = 0.0
            for bits, rk in zip(self._corners, r, strict=True):
                other = self._other_weight(bits, u, d)
                if bits[d]:
                    g1 += rk * other
                else:
                    g0 += rk * other
            df_du = g1 - g0
            # du/dc_j = (u - 1) / width, du/dc_{j+1} = -u / width; dJ/dc = -2 e dF/dc
            for ci, du_dc in ((jd, (u[d] - 1.0) / width), (jd + 1, -u[d] / width)):
                if ci == 0 or ci == c.size - 1:
                    continue  # first and last centres are fixed at the interval ends
                grad = -2.0 * e * df_du * du_dc
                # Eq. 23: eta is half the distance to the neighbour on the side the centre moves to
                eta = (c[ci] - c[ci - 1]) / 2.0 if grad >= 0 else (c[ci + 1] - c[ci]) / 2.0
                c[ci] -= eta * grad / (abs(grad) + l_rate)  # Eq. 23, saturated below eta

    def _other_weight(self, bits: tuple[int, ...], u: Array, d: int) -> float:
        w = 1.0
        for dd, bb in enumerate(bits):
            if dd != d:
                w *= u[dd] if bb else 1.0 - u[dd]
        return w

    def tune_threshold(self, x: ArrayLike, error: ArrayLike, *, max_fpr: float | None = DEFAULT_MAX_FPR) -> OperatingPoint:
        """Grid search of the threshold on the predicted error (§4), under the ``max_fpr`` cap."""
        good = np.asarray(error, dtype=np.float64).reshape(-1) < self.max_error
        pred = self.predict(x)
        op = operating_point(-pred, good, max_fpr=max_fpr)
        self.threshold = -op.threshold
        return OperatingPoint(self.threshold, op.sensitivity, op.specificity)

    # ---- persistence ----------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description with kind and format version."""
        return {
            "kind": self.KIND,
            "format_version": self.FORMAT_VERSION,
            "inputs": list(self.inputs),
            "n_mf": list(self.n_mf),
            "target": self.target,
            "max_error": self.max_error,
            "input_low": self.lo.tolist(),
            "input_high": self.hi.tolist(),
            "centers": [c.tolist() for c in self.centers],
            "consequents": self.consequents.tolist(),
            "threshold": self.threshold,
            "metadata": self.metadata,
        }

    @classmethod
    def from_dict(cls, d: Any, where: str = "validator") -> FuzzyValidator:
        """Inverse of ``to_dict``; CalibrationFileError on an unknown kind, newer version or bad shapes."""
        if not isinstance(d, Mapping) or d.get("kind") != cls.KIND:
            msg = f"{where}: not a ros_margcal fuzzy validator (kind {d.get('kind') if isinstance(d, Mapping) else None!r})"
            raise CalibrationFileError(msg)
        version = d.get("format_version")
        if not isinstance(version, int) or version < 1:
            msg = f"{where}: missing or invalid format_version {version!r}"
            raise CalibrationFileError(msg)
        if version > cls.FORMAT_VERSION:
            msg = (f"{where}: format_version {version} is newer than this ros_margcal reads "
                   f"({cls.FORMAT_VERSION}); upgrade ros_margcal or retrain the validator")
            raise CalibrationFileError(msg)
        try:
            v = cls(d["inputs"], d["n_mf"], target=d.get("target", "log"), max_error=float(d["max_error"]))
            v.lo = np.asarray(d["input_low"], dtype=np.float64)
            v.hi = np.asarray(d["input_high"], dtype=np.float64)
            v.centers = [np.asarray(c, dtype=np.float64) for c in d["centers"]]
            v.consequents = np.asarray(d["consequents"], dtype=np.float64)
            thr = d.get("threshold")
            v.threshold = None if thr is None else float(thr)
            v.metadata = dict(d.get("metadata") or {})
        except (KeyError, TypeError, ValueError, ConfigError) as exc:
            msg = f"{where}: corrupt validator ({type(exc).__name__}: {exc})"
            raise CalibrationFileError(msg) from exc
        unknown = [k for k in v.inputs if k not in INDICATOR_NAMES]
        if unknown:
            msg = f"{where}: corrupt validator (inputs {unknown} are no coverage indicators: {', '.join(INDICATOR_NAMES)})"
            raise CalibrationFileError(msg)
        if v.threshold is not None and not (math.isfinite(v.threshold) and v.threshold > 0):
            msg = f"{where}: corrupt validator (threshold {v.threshold!r}: a predicted error must be finite and > 0)"
            raise CalibrationFileError(msg)
        m = len(v.inputs)
        ok = (v.lo.shape == (m,) and v.hi.shape == (m,) and len(v.centers) == m
              and bool(np.all(np.isfinite(v.lo) & np.isfinite(v.hi) & (v.lo < v.hi)))
              and all(c.shape == (k,) for c, k in zip(v.centers, v.n_mf, strict=True))
              and v.consequents.shape == v.n_mf and np.isfinite(v.consequents).all()
              and all(np.all(np.diff(c) > 0) and c[0] == 0.0 and c[-1] == 1.0 for c in v.centers))
        if not ok:
            msg = f"{where}: corrupt validator (shapes, input ranges or centres inconsistent with inputs and n_mf)"
            raise CalibrationFileError(msg)
        return v

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the validator as JSON (atomically: temp file + rename)."""
        p = Path(path)
        tmp = p.with_name(p.name + ".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, p)
        return p

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> FuzzyValidator:
        """Read a validator written by ``save``; CalibrationFileError when it cannot be trusted."""
        p = Path(path)
        text = read_small_text(p, str(p), "validator file", MAX_FILE_BYTES)  # never a FIFO or a device: they hung the node
        try:
            d = json.loads(text)
        except ValueError as exc:
            msg = f"{p}: validator file is not valid JSON: {exc}"
            raise CalibrationFileError(msg) from exc
        except RecursionError:
            msg = f"{p}: validator file is nested too deeply to be a validator"
            raise CalibrationFileError(msg) from None
        return cls.from_dict(d, where=str(p))
