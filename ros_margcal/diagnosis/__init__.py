"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect causes it, how far it shrinks.

A recording is put against its simulated twin (``twin``: same directions and timestamps, the
simulator's baseline model) stage by stage (``stages``); every effect of the simulator's registry is
fitted to close the gap and ranked by the share it removes (``ranking``); ``core.diagnose`` decides,
``downstream`` retrains the validator with the found effect, ``report`` writes the JSON and HTML;
``changes`` locates an offset step that keeps one calibration from fitting a recording;
``baseline_noise`` gives the twin the recording's slow noise and, within a tolerance, its own shape;
``cubic`` tests an ADC's cubic non-linearity against the residual's own (white and slow) noise;
``inputs`` checks the options and takes a recording in file order (a clock that restarts).
``ros_margcal.bench.diagnosis`` checks it on recordings whose effect is withheld.
"""

from __future__ import annotations

from .changes import OffsetChange, locate_offset_change
from .core import NONE_GAP, Diagnosis, diagnose, diagnose_holdout, validator_downstream
from .inputs import check_options
from .ranking import EffectFit, applicable_effects, equivalent_groups, fit_effect, rank_effects
from .report import summary, write_report
from .stages import STAGES, StageFeatures, rest_noise, stage_features, stage_gaps
from .twin import Twin, build_twin

__all__ = [
    "NONE_GAP", "STAGES", "Diagnosis", "EffectFit", "OffsetChange", "StageFeatures", "Twin", "applicable_effects",
    "build_twin", "check_options", "diagnose", "diagnose_holdout", "equivalent_groups", "fit_effect",
    "locate_offset_change", "rank_effects", "rest_noise", "stage_features", "stage_gaps", "summary",
    "validator_downstream", "write_report"
]
