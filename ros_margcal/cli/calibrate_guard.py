"""The stream's guard rails for ``margcal calibrate``: what the online calibrator would not publish is not written.

A batch fit (plain, per side of an offset change, or with the prior) is refused when its residual RMS exceeds
``max_residual`` (as the stream's ``guard_rails``: one ellipsoid does not explain the readings), when
``stream.config.plausibility`` refuses it (field norm implausible in a known unit, parameter uncertainty, offset
beyond the limit, axis gains), and a magnetometer's also when its predicted heading error p95, level
(``model.heading``, at the configured inclination: a position's model field, else 60°), exceeds
``max_heading_p95_deg`` or cannot be determined; a magnetometer's prior fit (partial by design) is judged by that
figure instead of the uncertainty of its prior terms. The command then exits ``EXIT_REFUSED`` without writing;
``--force`` writes it, with ``forced`` and the reason in the calibration's ``method`` (the file's free-form field;
the node shows it) and in the JSON.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..model.calibration import FORCED, Calibration
from ..model.errors import InputError
from ..model.heading import format_bound, heading_p95_quantile
from ..stream.config import PipelineConfig, plausibility
from .fit_rescue import HEADING_DETERMINED_DEG, inclination_of, residual_note

__all__ = ["EXIT_REFUSED", "forced", "norm_source", "refusal"]

EXIT_REFUSED = 4
"""Exit code when a calibration was fitted but the guard rails refuse it (nothing written)."""
_NO_STD_LIMIT = 10.0  # the largest max_parameter_std (FIELD_SPECS): a partial fit's prior terms are not judged by it


def _heading(cal: Calibration, cfg: PipelineConfig, level: float | None = None) -> str:
    """Why the predicted level heading error (``level`` when given: a ring held level, at its own field's inclination)
    refuses ``cal`` ("" when within the limit or not computable)."""
    try:
        if level is None:
            level = heading_p95_quantile(cal, tilt_deg=0.0, inclination=inclination_of(cfg))
    except (InputError, ValueError, np.linalg.LinAlgError):
        return ""  # no covariance over the symmetric model (diag, eye, mvee): plausibility judged it
    if not (math.isfinite(level) and level <= HEADING_DETERMINED_DEG):
        return "predicted heading error not determined (the data leave the horizontal terms free)"
    if level > cfg.max_heading_p95_deg:
        return (f"predicted heading error p95 {format_bound(level)} level > limit {cfg.max_heading_p95_deg:.3g} deg "
                "(max_heading_p95_deg)")
    return ""


def refusal(cal: Calibration, cfg: PipelineConfig | None, noise: float = 0.0, level: float | None = None) -> str:
    """Why the stream would not publish ``cal`` (module docstring), "" when it would; ``noise``: the sensor's white
    noise in raw units (``stream.config.white_noise``), which widens the residual limit as in the stream; ``level``:
    the predicted level heading p95 when it is not the one at the configured inclination (``fit_rescue.Part.figures``).

    A magnetometer's prior (MAP) fit is partial by design: as in the stream, its predicted heading error
    judges it, not the uncertainty of the terms it keeps from the prior.
    """
    if cfg is None:
        return ""
    n = cal.stats.n_points if cal.stats is not None else None
    if n is not None and n < cfg.min_points:  # the stream's first check: a fit of 10 samples had 0.09 % residual at 0.5 % noise
        return (f"{n} samples < min_points {cfg.min_points}: too few to fit the model and judge the fit (its residual "
                "falls below the noise); record more")
    high = residual_note(cal, cfg, noise)
    if high:
        cause = ("iron or a magnet moving near the sensor, or a change not located" if cfg.sensor == "mag" else
                 "linear acceleration: the sensor moved while sampled; record still poses")
        return f"{high} (max_residual; {cause})"
    partial = cfg.sensor == "mag" and cal.method.startswith("map")
    why = plausibility(cal, replace(cfg, max_parameter_std=_NO_STD_LIMIT) if partial else cfg)
    if why:
        return why
    return _heading(cal, cfg, level) if cfg.sensor == "mag" else ""


def forced(cal: Calibration, why: str) -> Calibration:
    """``cal`` marked as written past the guard rails: ``method`` says forced and why."""
    return cal.replace(method=f"{cal.method} {FORCED}: {why}")


def norm_source(std: dict[str, float], fixed: str) -> str:
    """Where the printed norm comes from: the data (with its std), else ``fixed`` (--norm, gravity, the radius)."""
    return f" +- {std['norm']:.2g} (the data)" if "norm" in std else f" ({fixed}, fixed)"
