"""The shipped validator: where it is found, how a validator file is loaded, and the fallback rule."""

from __future__ import annotations

import logging
import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.errors import CalibrationFileError, MargCalError
from .fuzzy import FuzzyValidator

__all__ = [
    "FallbackValidator", "default_validator", "default_validator_candidates", "load_default_validator",
    "load_validator"
]

log = logging.getLogger(__name__)
Array = NDArray[np.float64]


def load_validator(path: str | os.PathLike[str]) -> FuzzyValidator:
    """Read a fuzzy validator JSON file (alias of ``FuzzyValidator.load``)."""
    return FuzzyValidator.load(path)


def default_validator_candidates() -> list[Path]:
    """Where the shipped validator (``msg_configs/validator.json``) may be, in search order.

    A colcon or pip install puts ``msg_configs/`` under ``<prefix>/share/ros_margcal/`` (setup.py
    data_files) with the package in ``<prefix>/lib/pythonX.Y/site-packages/ros_margcal``; an editable
    install or a source checkout has it beside the package. The ament index is asked first when
    ``ament_index_python`` is importable (a sourced ROS 2 environment).
    """
    here = Path(__file__).resolve().parents[1]  # the ros_margcal package directory
    found: list[Path] = []
    try:
        # optional dependency: present in a sourced ROS 2 environment only
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        pass
    else:
        try:
            found.append(Path(get_package_share_directory("ros_margcal")) / "msg_configs")
        except (PackageNotFoundError, ValueError, LookupError, OSError):  # OSError: AMENT_PREFIX_PATH unset
            pass
    found.append(here.parent / "msg_configs")
    if len(here.parents) > 3:  # <prefix>/lib/pythonX.Y/site-packages/ros_margcal
        found.append(here.parents[3] / "share" / "ros_margcal" / "msg_configs")
    found.append(Path(sys.prefix) / "share" / "ros_margcal" / "msg_configs")
    return [d / "validator.json" for d in dict.fromkeys(found)]


def load_default_validator() -> FuzzyValidator:
    """The trained validator shipped in ``msg_configs/validator.json`` (``default_validator_candidates``).

    Regenerate it with ``python scripts/train_default_validator.py``.

    Raises:
        CalibrationFileError: when no candidate exists or the file cannot be trusted.
    """
    for path in default_validator_candidates():
        if path.is_file():
            return FuzzyValidator.load(path)
    where = ", ".join(str(p) for p in default_validator_candidates())
    msg = f"the default validator is not installed (looked in {where}); run scripts/train_default_validator.py"
    raise CalibrationFileError(msg)


class FallbackValidator:
    """The documented rule used only when no trained validator is available.

    Single-indicator thresholding on the normalised convex-hull volume D (Olivares §3.2, Eq. 13;
    D is the best single indicator, §5): the "predicted error" is ``threshold * d_ref / d_norm``,
    so the set is accepted exactly when ``d_norm >= d_ref``. ``d_ref = 0.6`` accepts a buffer whose
    hull has 60 % of the volume of the full sphere (a full, evenly covered sphere gives ~0.9-1).
    """

    inputs = ("d_norm",)

    def __init__(self, d_ref: float = 0.6, threshold: float = 0.01) -> None:
        self.d_ref = float(d_ref)
        self.threshold = float(threshold)

    def predict_indicators(self, indicators: Any) -> float:
        """Pseudo error: ``threshold * d_ref / d_norm`` (inf for an empty hull)."""
        d = float(getattr(indicators, "d_norm", 0.0) or 0.0)
        return math.inf if d <= 0 else self.threshold * self.d_ref / d


def default_validator() -> Any:
    """The trained fuzzy validator shipped with the package, or ``FallbackValidator`` (logged)."""
    try:

        v = load_default_validator()
        if getattr(v, "threshold", None) is None:
            msg = "the default validator has no threshold"
            raise CalibrationFileError(msg)
        return v
    except (ImportError, MargCalError) as exc:
        log.warning("trained validator unavailable (%s); using the fallback rule d_norm >= 0.6", exc)
        return FallbackValidator()
