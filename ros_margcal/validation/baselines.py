"""Coverage gates that other calibration systems use, as continuous scores for ROC comparison.

Each gate below is re-implemented from the public description or source of the system it is named
after, and turned into a continuous score so an ROC/AUC can be computed on the same labelled sets
as the validators of ``ros_margcal.validation``. Each also has the fixed threshold its system uses,
so its own operating point can be reported.

- **MotionCal** (PJRC, ``quality_surface_gap_error``): the unit sphere is split into 100 regions of
  roughly equal area — a polar cap above 78.52° latitude, 15 sectors in each temperate zone
  (42.84°–78.52°), 34 sectors in each tropical zone (0°–42.84°), and the south counterparts. Every
  region with no sample adds 1.0 to the error, one sample 0.2, two samples 0.01. The result is a
  percentage of sphere surface "missing" (0 = full coverage); MotionCal accepts below 15.
- **Android** (the background magnetometer calibration ``mag_cal``, AOSP context hub and Chromium EC):
  before fitting, the covariance of the buffered samples is eigen-decomposed and the fit is only
  attempted if ``max eigenvalue / min eigenvalue`` stays under a limit (15 in the context hub code,
  25 in Chromium EC) and the eigenvalue magnitude is plausible. The ratio is the score (1 = isotropic).
- **ArduPilot** (``CompassCalibrator``): the fit is accepted when its *fitness* — the RMS of the
  sphere/ellipsoid residuals over the samples — is below a fixed tolerance (``COMPASS_CAL_FIT``,
  16 mGauss by default, ≈ 3 % of a 0.5 G field). The score here is that RMS relative to the fitted
  norm, so it is unit-free.
- **NXP** (Freescale/NXP sensor fusion, ``magnetic.c``): samples go into a 14 × 28 buffer indexed by
  equal-angle bins of atan(x/z) (14 bins) and atan(y/z) (14 bins, plus 14 when x < 0); the
  10-parameter calibration needs 150 filled bins (``MINMEASUREMENTS10CAL``). The score is the
  number of filled bins, here of the samples relative to the given centre.

Lower is better for the first three, higher for NXP; ``BASELINES[name].higher_is_better`` says so.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model.calibration import Calibration
from ..model.errors import DegenerateDataError, as_points, as_vector3

__all__ = [
    "BASELINES", "Baseline", "android_eigen_ratio", "ardupilot_fitness", "baseline_scores", "motioncal_gap_error",
    "motioncal_region", "nxp_bin_fill"
]

Array = NDArray[np.float64]

_CAP_LAT = 1.37046  # 78.52 deg: one polar region of the 100 (MotionCal)
_TEMPERATE_LAT = 0.74776  # 42.84 deg: 15 temperate sectors above, 34 tropical below


def _centred(points: ArrayLike, center: ArrayLike | None, matrix: ArrayLike | None) -> Array:
    p = as_points(points, "points")
    if center is not None:
        p = p - as_vector3(center, "center")
    if matrix is not None:
        p = p @ np.asarray(matrix, dtype=np.float64).T
    return p


def motioncal_region(directions: ArrayLike) -> NDArray[np.intp]:
    """MotionCal's region (0–99) of each vector: caps, 15 temperate and 34 tropical sectors."""
    p = as_points(directions, "directions")
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    lon = np.arctan2(y, x) + np.pi  # 0 .. 2 pi
    lat = np.pi / 2.0 - np.arctan2(np.hypot(x, y), z)  # -pi/2 .. pi/2
    temperate = np.clip(np.floor(lon * 15.0 / (2.0 * np.pi)), 0, 14).astype(np.intp)
    tropical = np.clip(np.floor(lon * 34.0 / (2.0 * np.pi)), 0, 33).astype(np.intp)
    region = np.where(lat >= 0.0, tropical + 16, tropical + 50)
    region = np.where(lat > _TEMPERATE_LAT, temperate + 1, region)
    region = np.where(lat < -_TEMPERATE_LAT, temperate + 84, region)
    region = np.where(lat > _CAP_LAT, 0, region)
    region = np.where(lat < -_CAP_LAT, 99, region)
    return region.astype(np.intp)


def motioncal_gap_error(points: ArrayLike, center: ArrayLike | None = None, matrix: ArrayLike | None = None) -> float:
    """MotionCal surface gap error (0–100, lower is better) of samples around ``center``.

    Args:
        points: (n, 3) raw samples.
        center: offset estimate subtracted first (MotionCal uses its current hard-iron estimate).
        matrix: optional soft-iron matrix applied after centring (MotionCal applies its calibration).
    """
    counts = np.bincount(motioncal_region(_centred(points, center, matrix)), minlength=100)
    return float(np.sum(np.select([counts == 0, counts == 1, counts == 2], [1.0, 0.2, 0.01], 0.0)))


def android_eigen_ratio(points: ArrayLike) -> float:
    """Ratio of the largest to the smallest eigenvalue of the sample covariance (>= 1, lower is better).

    Raises:
        DegenerateDataError: fewer than 4 samples.
    """
    p = as_points(points, "points")
    if p.shape[0] < 4:
        msg = f"the eigenvalue-ratio gate needs at least 4 samples, got {p.shape[0]}"
        raise DegenerateDataError(msg)
    ev = np.linalg.eigvalsh(np.cov(p, rowvar=False, bias=True))
    lo = max(float(ev[0]), 1e-300)
    return float(min(ev[-1] / lo, 1e12))


def ardupilot_fitness(points: ArrayLike, cal: Calibration) -> float:
    """RMS of the fit residuals ``|W (v - b)| - norm`` over the samples, relative to ``cal.norm``."""
    r = cal.norm_error(as_points(points, "points"))
    return float(np.sqrt(np.mean(r**2)) / cal.norm)


def nxp_bin_fill(points: ArrayLike, center: ArrayLike | None = None, n_x: int = 14) -> int:
    """Number of filled bins of NXP's ``n_x`` × ``2 n_x`` magnetometer buffer (higher is better)."""
    p = _centred(points, center, None)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    # equal-angle bins of atan(x/z) and atan(y/z) over (-90, 90) degrees; k += n_x when x < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ax = np.arctan(np.where(z != 0, x / z, np.sign(x) * np.inf))
        ay = np.arctan(np.where(z != 0, y / z, np.sign(y) * np.inf))
    j = np.clip(np.floor((ax / np.pi + 0.5) * n_x), 0, n_x - 1).astype(np.intp)
    k = np.clip(np.floor((ay / np.pi + 0.5) * n_x), 0, n_x - 1).astype(np.intp) + np.where(x < 0, n_x, 0)
    return int(np.unique(j * (2 * n_x) + k).size)


@dataclass(frozen=True)
class Baseline:
    """A peer system's gate: its score, direction and the fixed threshold it uses."""

    name: str
    description: str
    higher_is_better: bool
    default_threshold: float

    def oriented(self, value: ArrayLike) -> Array:
        """Score with higher = better, for ROC/AUC."""
        v = np.asarray(value, dtype=np.float64)
        return v if self.higher_is_better else -v

    def accept(self, value: ArrayLike) -> NDArray[np.bool_]:
        """The system's own verdict at its fixed threshold."""
        v = np.asarray(value, dtype=np.float64)
        return v >= self.default_threshold if self.higher_is_better else v < self.default_threshold


BASELINES: dict[str, Baseline] = {
    "motioncal_gap": Baseline("motioncal_gap", "MotionCal surface gap error over 100 sphere regions", False, 15.0),
    "android_eigen_ratio": Baseline("android_eigen_ratio", "Android mag_cal covariance eigenvalue ratio", False, 15.0),
    "ardupilot_fitness": Baseline("ardupilot_fitness", "ArduPilot RMS fitness of the fit, relative", False, 0.032),
    "nxp_bin_fill": Baseline("nxp_bin_fill", "NXP 14x28 magnetometer buffer bins filled", True, 150.0),
}
"""The baselines scored by ``baseline_scores``, by name."""

_SCORERS: dict[str, Callable[[Array, Calibration], float]] = {
    "motioncal_gap": lambda p, cal: motioncal_gap_error(p, cal.offset, cal.matrix),
    "android_eigen_ratio": lambda p, cal: android_eigen_ratio(p),
    "ardupilot_fitness": ardupilot_fitness,
    "nxp_bin_fill": lambda p, cal: float(nxp_bin_fill(p, cal.offset)),
}


def baseline_scores(points: ArrayLike, cal: Calibration) -> dict[str, float]:
    """Every baseline's raw score of one set, given the calibration fitted from that set.

    The fit supplies what each system would have at that moment: the centre (MotionCal, NXP), the
    soft-iron matrix (MotionCal) and the residuals (ArduPilot).
    """
    p = as_points(points, "points")
    return {name: float(fn(p, cal)) for name, fn in _SCORERS.items()}
