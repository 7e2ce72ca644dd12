"""Whether a buffer is good enough to fit: validators, their baselines and ROC.

``fuzzy.FuzzyValidator`` is the TSK fuzzy system of Olivares et al. 2016 (Eqs. 17-23) predicting the
calibration error from the indicators; ``threshold`` holds its inputs and the single-indicator
baseline; ``baselines`` the peer systems' gates; ``roc`` the operating points; ``shipped`` finds the
trained model in ``msg_configs/`` (or the documented fallback rule). Depends on ``model``.
"""

from __future__ import annotations

from .baselines import (
    BASELINES, Baseline, android_eigen_ratio, ardupilot_fitness, baseline_scores, motioncal_gap_error,
    motioncal_region, nxp_bin_fill
)
from .fuzzy import FuzzyValidator
from .roc import OperatingPoint, auc, evaluate_threshold, operating_point, roc_auc, roc_curve
from .shipped import (
    FallbackValidator, default_validator, default_validator_candidates, load_default_validator, load_validator
)
from .threshold import DEFAULT_MAX_ERROR, DEFAULT_MAX_FPR, LOWER_IS_BETTER, ThresholdValidator

__all__ = [
    "BASELINES", "DEFAULT_MAX_ERROR", "DEFAULT_MAX_FPR", "LOWER_IS_BETTER", "Baseline", "FallbackValidator",
    "FuzzyValidator", "OperatingPoint", "ThresholdValidator", "android_eigen_ratio", "ardupilot_fitness", "auc",
    "baseline_scores", "default_validator", "default_validator_candidates", "evaluate_threshold",
    "load_default_validator", "load_validator", "motioncal_gap_error", "motioncal_region", "nxp_bin_fill",
    "operating_point", "roc_auc", "roc_curve"
]
