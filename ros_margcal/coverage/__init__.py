"""Where a sample goes after the message: the inactivity gate, the direction buffer and its indicators.

``gate.InactivityGate`` keeps quasi-static accelerometer samples (Gietzelt et al. 2013, §2.4),
``gate.GyroAidedGate`` with a 1 s window when a gyro reading comes with the sample;
``buffer.DirectionBuffer`` keeps a bounded number of samples per direction and updates the coverage
indicators A-D (Olivares et al. 2013, §3.1, Eqs. 9-12, in ``indicators``) incrementally, with an
incremental convex hull (``hull``) for D. Depends on ``model`` only.
"""

from __future__ import annotations

from .buffer import DirectionBuffer
from .gate import GyroAidedGate, InactivityGate
from .hull import IncrementalHull
from .indicators import HIST_BINS, Indicators, compute_indicators, information_indicator

__all__ = [
    "HIST_BINS", "DirectionBuffer", "GyroAidedGate", "InactivityGate", "IncrementalHull", "Indicators",
    "compute_indicators", "information_indicator"
]
