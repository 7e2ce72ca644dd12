"""Downstream: what the diagnosed effect does to the validator's predicted calibration error.

``validator_errors`` measures, on a calibration set drawn from a recording, the validator's predicted
error and the measured one (the ``validator`` stage of ``stages`` uses it too); ``validator_downstream``
retrains the validator on simulated sets with the diagnosed effect (and, as a control, without it) and
compares the predictions.
"""

from __future__ import annotations

import inspect
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..coverage import compute_indicators
from ..errors import MargCalError
from ..fitting import fit

if TYPE_CHECKING:
    from .core import Diagnosis

__all__ = ["validator_downstream", "validator_errors"]

Array = NDArray[np.float64]

_N_REFERENCE_DIRS = 400


def _uniform_dirs() -> Array:
    u = np.random.default_rng(20261121).normal(size=(_N_REFERENCE_DIRS, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


_UNIFORM = _uniform_dirs()


def validator_errors(points: Array, reference: Calibration, validator: object) -> tuple[float, float]:
    """Predicted and measured calibration error of a calibration set drawn from a recording.

    The validator predicts from the coverage indicators of ``points`` (about the centre and radius of
    a linear sphere fit, as the node does before its first calibration). The measured error is the
    corpus label (``corpus.make_set``) with the recording's best fit on all samples, ``reference``,
    standing in for the unknown truth: the RMS of ``|W (v - b)| / n - 1`` of the ``sym`` fit of
    ``points`` over fixed uniform directions ``v = reference.inverse_apply(n_ref u)``.

    Returns:
        (predicted, measured), both as fractions of the norm.
    """
    sph = fit(points, model="eye", method="sphere", norm=None)
    ind = compute_indicators(points, sph.offset, float(sph.norm))
    predicted = float(validator.predict_indicators(ind))  # type: ignore[attr-defined]
    cal = fit(points, model="sym", method="lm", norm=None)
    raw_u = reference.inverse_apply(_UNIFORM * reference.norm)
    rel = np.linalg.norm(cal.apply(raw_u), axis=1) / cal.norm - 1.0
    return predicted, float(np.sqrt(np.mean(rel**2)))



def _retrain(validator: object, n_sets: int, seed: int, effects: dict[str, float] | None, duration_s: float) -> object:
    """A validator like ``validator`` (inputs, partition, training options from its metadata) trained
    on ``n_sets`` simulated sets with ``effects``, each spread over ``duration_s`` like the recording's."""
    from .. import corpus  # local: the corpus pulls in the baselines, only needed here
    from ..validation import FuzzyValidator

    built = corpus.build_corpus(n_sets, seed, effects=effects, duration_s=duration_s if effects else None)
    inputs = tuple(getattr(validator, "inputs", ("c_norm", "d_norm")))
    n_mf = getattr(validator, "n_mf", 10)
    n_mf = tuple(int(k) for k in np.atleast_1d(n_mf)) if np.ndim(n_mf) else int(n_mf)
    meta = dict(getattr(validator, "metadata", {}) or {})
    accepted = inspect.signature(FuzzyValidator.fit).parameters
    kw = {k: meta[k] for k in ("repeats", "l_rate", "consequents", "ridge", "max_fpr") if k in meta and k in accepted}
    out = FuzzyValidator(inputs=inputs, n_mf=n_mf)
    return out.fit(built.matrix(list(inputs)), built.error, seed=seed, **kw)


def validator_downstream(diag: Diagnosis, validator: object | None, *, n_sets: int = 400, seed: int = 0) -> dict[str, Any]:
    """What the chosen effect does to the validator: predicted error before and after retraining.

    The validator's prediction on a 300-sample set of the recording is compared with the measured
    error (``stages.validator_errors``): ``before`` is ``validator`` itself; ``after`` is the same
    kind of validator retrained on ``n_sets`` simulated sets *with* the effect at its fitted magnitude
    (``corpus.build_corpus(effects=...)``), and ``control`` retrained on as many sets *without* it, so
    the change the effect makes is not confused with the change a smaller training corpus makes.
    ``log_error_*`` is ``|log10(measured / predicted)|`` (0 is a perfect prediction).
    """
    twin = diag.twin
    if validator is None or twin is None:
        return {"available": False, "reason": "no validator"}
    pts = twin.raw[twin.sub]
    pick = np.linspace(0, len(pts) - 1, min(300, len(pts))).astype(np.intp)
    try:
        predicted, measured = validator_errors(pts[pick], twin.best, validator)
    except MargCalError as exc:
        return {"available": False, "reason": f"validator stage failed: {exc}"}

    def log_error(pred: float) -> float:
        return abs(math.log10(max(measured, 1e-12) / max(pred, 1e-12)))

    out: dict[str, Any] = {"predicted_before": predicted, "measured": measured, "log_error_before": log_error(predicted)}
    best = diag.best
    if diag.cause == "none" or best is None:
        out.update(available=True, predicted_after=predicted, log_error_after=log_error(predicted),
                   note="cause is none: no retraining")
        return out
    try:
        span = float(twin.t[twin.sub][-1] - twin.t[twin.sub][0])  # the 300-sample set spans the whole recording
        with_effect = _retrain(validator, n_sets, seed, {best.name: best.magnitude}, span)
        control = _retrain(validator, n_sets, seed, None, span)
        predicted_after, _ = validator_errors(pts[pick], twin.best, with_effect)
        predicted_control, _ = validator_errors(pts[pick], twin.best, control)
    except MargCalError as exc:
        return {**out, "available": False, "reason": f"retraining failed: {exc}"}
    out.update(available=True, effect=best.name, magnitude=best.magnitude, n_sets=n_sets,
               predicted_after=predicted_after, predicted_control=predicted_control,
               error_ratio_before=measured / max(predicted, 1e-12),
               error_ratio_after=measured / max(predicted_after, 1e-12),
               log_error_after=log_error(predicted_after), log_error_control=log_error(predicted_control))
    return out
