"""Labelled calibration sets for training and scoring validators (simulated, seeded).

``corpus.build_corpus`` draws sets from the simulator, fits them and labels each with its error
(``labels``) against the truth or, for recordings, against the recording's best fit.
Depends on ``sim``, ``coverage``, ``model`` and ``validation.baselines``; nothing online imports it.
"""

from __future__ import annotations

from .corpus import FAILED_ERROR, FEATURES, Corpus, build_corpus, make_set
from .labels import MEASURE_DIRS, label_error, recording_error, reference_readings

__all__ = [
    "FAILED_ERROR", "FEATURES", "MEASURE_DIRS", "Corpus", "build_corpus", "label_error", "make_set",
    "recording_error", "reference_readings"
]
