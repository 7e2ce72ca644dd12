"""ROC curves, AUC and operating points of a score against a binary truth (Olivares et al. 2013, §4).

Shared by the validators (``validation``) and their evaluation (``margcal evaluate-validator``),
which compares them with the baselines' gates on the same sets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model.errors import ConfigError, InputError

__all__ = ["OperatingPoint", "auc", "evaluate_threshold", "operating_point", "roc_auc", "roc_curve"]

Array = NDArray[np.float64]


def _as_labels(score: ArrayLike, positive: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
    s = np.asarray(score, dtype=np.float64).reshape(-1)
    p = np.asarray(positive).reshape(-1).astype(bool)
    if s.shape != p.shape:
        msg = f"score and positive must have the same length, got {s.shape[0]} and {p.shape[0]}"
        raise InputError(msg)
    if not np.isfinite(s).all():
        msg = "score holds NaN or Inf; drop those sets first"
        raise InputError(msg)
    return s, p


def roc_curve(score: ArrayLike, positive: ArrayLike) -> tuple[Array, Array, Array]:
    """ROC of "accept when score >= t" over every distinct threshold t.

    Args:
        score: (n,) continuous score, higher = more likely good.
        positive: (n,) bool, the true class (good set).

    Returns:
        ``(fpr, tpr, thresholds)``, starting at (0, 0) with threshold +inf and ending at (1, 1).
    """
    s, p = _as_labels(score, positive)
    n_pos, n_neg = int(p.sum()), int((~p).sum())
    order = np.argsort(-s, kind="mergesort")
    s, p = s[order], p[order]
    last = np.r_[np.flatnonzero(np.diff(s) != 0), s.size - 1] if s.size else np.array([], dtype=int)
    tp = np.cumsum(p)[last]
    fp = np.cumsum(~p)[last]
    tpr = np.r_[0.0, tp / n_pos] if n_pos else np.r_[0.0, np.zeros(last.size)]
    fpr = np.r_[0.0, fp / n_neg] if n_neg else np.r_[0.0, np.zeros(last.size)]
    return fpr, tpr, np.r_[np.inf, s[last]]


def auc(fpr: ArrayLike, tpr: ArrayLike) -> float:
    """Area under a ROC curve given by its points (trapezoid rule)."""
    x = np.asarray(fpr, dtype=np.float64)
    y = np.asarray(tpr, dtype=np.float64)
    return float(np.sum(np.diff(x) * (y[1:] + y[:-1]) / 2.0))


def roc_auc(score: ArrayLike, positive: ArrayLike) -> float:
    """Threshold-free AUC: P(score of a good set > score of an ill set), ties counted half.

    Raises:
        InputError: when one class is empty (the AUC is undefined).
    """
    s, p = _as_labels(score, positive)
    n_pos, n_neg = int(p.sum()), int((~p).sum())
    if n_pos == 0 or n_neg == 0:
        msg = f"AUC needs both classes, got {n_pos} good and {n_neg} ill sets"
        raise InputError(msg)
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(s.size)
    sorted_s = s[order]
    # average ranks over ties (Mann–Whitney U)
    _, first, counts = np.unique(sorted_s, return_index=True, return_counts=True)
    avg = first + (counts - 1) / 2.0 + 1.0
    ranks[order] = np.repeat(avg, counts)
    u = ranks[p].sum() - n_pos * (n_pos + 1) / 2.0
    return float(u / (n_pos * n_neg))


@dataclass(frozen=True)
class OperatingPoint:
    """One threshold and what it does: accept when ``score >= threshold``."""

    threshold: float
    sensitivity: float
    specificity: float

    @property
    def auc(self) -> float:
        """The paper's single-threshold "AUC": area under the ROC through this point (Tables 1–3)."""
        return (self.sensitivity + self.specificity) / 2.0

    @property
    def ill_accepted(self) -> float:
        """Fraction of ill sets accepted (false-positive rate)."""
        return 1.0 - self.specificity


def _rates(accept: NDArray[np.bool_], p: NDArray[np.bool_]) -> tuple[float, float]:
    n_pos, n_neg = int(p.sum()), int((~p).sum())
    sens = float((accept & p).sum() / n_pos) if n_pos else float("nan")
    spec = float((~accept & ~p).sum() / n_neg) if n_neg else float("nan")
    return sens, spec


def evaluate_threshold(score: ArrayLike, positive: ArrayLike, threshold: float) -> OperatingPoint:
    """Sensitivity and specificity of "accept when score >= threshold" on labelled sets."""
    s, p = _as_labels(score, positive)
    sens, spec = _rates(s >= threshold, p)
    return OperatingPoint(float(threshold), sens, spec)


def operating_point(score: ArrayLike, positive: ArrayLike, *, max_fpr: float | None = None) -> OperatingPoint:
    """Grid search of the threshold (§4): best (sensitivity + specificity) / 2.

    The grid is every midpoint between consecutive distinct scores plus both ends, so the search is
    exhaustive. With ``max_fpr`` only thresholds accepting at most that fraction of ill sets are
    eligible (the strictest threshold always is). Ties go to the higher specificity.
    """
    s, p = _as_labels(score, positive)
    if max_fpr is not None and not 0.0 <= max_fpr <= 1.0:
        msg = f"max_fpr must be in [0, 1], got {max_fpr}"
        raise ConfigError(msg)
    u = np.unique(s)
    if u.size == 0:
        msg = "operating_point needs at least one scored set"
        raise InputError(msg)
    grid = np.r_[u[0] - 1.0, (u[1:] + u[:-1]) / 2.0, u[-1] + 1.0]
    acc = s[None, :] >= grid[:, None]
    n_pos, n_neg = max(int(p.sum()), 1), max(int((~p).sum()), 1)
    sens = (acc & p).sum(axis=1) / n_pos
    spec = (~acc & ~p).sum(axis=1) / n_neg
    value = sens + spec
    if max_fpr is not None:
        value = np.where(1.0 - spec <= max_fpr + 1e-12, value, -np.inf)
    best = np.flatnonzero(value == value.max())
    i = int(best[np.argmax(spec[best])])
    nan = float("nan")
    return OperatingPoint(float(grid[i]), float(sens[i]) if p.any() else nan, float(spec[i]) if (~p).any() else nan)
