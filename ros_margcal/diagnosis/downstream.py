"""Downstream: what the diagnosed effect does to the validator's predicted calibration error.

``validator_errors`` measures, on a calibration set drawn from a recording, the validator's predicted
error and the measured one (the ``validator`` stage of ``stages`` uses it too). ``compare_validators``
retrains the validator on simulated sets with an effect (and, as a control, without it) and compares
the three predictions with the measured error; ``validator_downstream`` runs it on a diagnosis with
the effect it found.

Apples to apples: the measured error is the error of the set's fit against the recording's best fit
over all its samples (there is no truth on a real recording); the simulated sets the validator is
retrained on are labelled the same way (``corpus.make_set(recording=k)``: every ``k``-th sample of a
simulated recording with the effect and the recording's noise, against that recording's best fit), by
the same function (``corpus.recording_error``).
"""

from __future__ import annotations

import inspect
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..coverage.indicators import Indicators, compute_indicators
from ..model.calibration import Calibration
from ..model.fitting import fit
from ..training.corpus import build_corpus
from ..training.labels import recording_error
from ..validation.fuzzy import FuzzyValidator

__all__ = ["N_SET", "compare_validators", "retrain_validator", "validator_errors"]

Array = NDArray[np.float64]

N_SET = 300
"""Samples of the calibration set drawn (evenly spaced) from the recording."""
_TINY = 1e-12


def validator_errors(points: Array, reference: Calibration, validator: object) -> tuple[float, float]:
    """Predicted and measured calibration error of a calibration set drawn from a recording.

    The validator predicts from the coverage indicators of ``points`` (about the centre and radius of
    a linear sphere fit, as the node does before its first calibration). The measured error is
    ``corpus.recording_error``, the label of ``corpus.make_set(recording=k)``: with the recording's best
    fit on all samples, ``reference``, standing in for the unknown truth, the RMS of
    ``|W (v - b)| / n - 1`` of the ``sym`` fit of ``points`` over fixed uniform directions
    ``v = reference.inverse_apply(n_ref u)``.

    Returns:
        (predicted, measured), both as fractions of the norm.
    """
    predicted = _predict(validator, _set_indicators(points))
    cal = fit(points, model="sym", method="lm", norm=None)
    return predicted, recording_error(cal, reference)


def _set_indicators(points: Array) -> Indicators:
    """Coverage indicators of a calibration set about its linear sphere fit (the node's frame before a calibration)."""
    sph = fit(points, model="eye", method="sphere", norm=None)
    return compute_indicators(points, sph.offset, float(sph.norm))


def _predict(validator: object, ind: Indicators) -> float:
    return float(validator.predict_indicators(ind))  # type: ignore[attr-defined]


def retrain_validator(validator: object, n_sets: int, seed: int, effects: dict[str, float] | None, *,
                      duration_s: float, recording: int, noise: float | None = None,
                      kind: str | None = None) -> tuple[object, dict[str, Any]]:
    """A validator like ``validator`` (inputs, partition, target, training options from its metadata)
    trained on ``n_sets`` simulated sets with ``effects``, labelled as sets drawn from a recording
    (``corpus.make_set(recording=recording)``), each spread over ``duration_s``, with white noise
    ``noise`` (fraction of the field radius; None: the corpus' random range) on a ``kind`` sensor
    (None: mixed). Returns it and a summary of its corpus."""

    options: dict[str, Any] = {"effects": effects or None, "duration_s": duration_s, "recording": recording,
                               "kind": kind}
    if noise is not None:
        options["noise_range"] = (noise, noise)
    built = build_corpus(n_sets, seed, **options)
    inputs = tuple(getattr(validator, "inputs", ("c_norm", "d_norm")))
    n_mf = getattr(validator, "n_mf", 10)
    n_mf = tuple(int(k) for k in np.atleast_1d(n_mf)) if np.ndim(n_mf) else int(n_mf)
    ctor: dict[str, Any] = {k: getattr(validator, k) for k in ("target", "max_error") if hasattr(validator, k)}
    meta = dict(getattr(validator, "metadata", {}) or {})
    accepted = inspect.signature(FuzzyValidator.fit).parameters
    kw = {k: meta[k] for k in ("repeats", "l_rate", "consequents", "ridge", "max_fpr") if k in meta and k in accepted}
    out = FuzzyValidator(inputs=inputs, n_mf=n_mf, **ctor)
    trained = out.fit(built.matrix(list(inputs)), built.error, seed=seed, **kw)
    ok = built.error < 1.0
    summary = {"n_sets": n_sets, "n_failed": int(built.meta["n_failed"]), "corpus_seed": seed,
               "effects": dict(effects or {}), "duration_s": duration_s, "recording": recording, "noise": noise,
               "kind": kind, "median_label": float(np.median(built.error[ok])) if ok.any() else float("nan")}
    return trained, summary


def _log_error(measured: float, predicted: float) -> float:
    """``|log10(measured / predicted)|``: 0 is a perfect prediction, 1 a factor of ten."""
    return abs(math.log10(max(measured, _TINY) / max(predicted, _TINY)))


def compare_validators(points: Array, reference: Calibration, validator: object, effects: dict[str, float] | None,
                       *, span_s: float, recording: int, noise: float | None = None, kind: str | None = None,
                       n_sets: int = 400, seed: int = 0) -> dict[str, Any]:
    """Predicted error of a recording's calibration set by three validators, against the measured error.

    ``original`` is ``validator``; ``with_effect`` the same kind of validator retrained on ``n_sets``
    simulated sets with ``effects``, ``control`` on as many sets without effects (same seed, so the same
    sensors, patterns and noise), so the change the effect makes is not confused with the change the
    retraining corpus makes. Both corpora are labelled as the measured error is defined (sets drawn
    from a recording ``recording`` times denser, spread over ``span_s``, at the recording's ``noise``,
    of its sensor ``kind``). Without ``effects``: ``original`` only.

    Args:
        points: the calibration set, raw readings (n, 3).
        reference: the recording's best (``sym``) fit on all samples.
        validator: a trained ``FuzzyValidator``.
        effects: ``{name: magnitude}`` to retrain with, or None.
        span_s: time span of the set on the recording, seconds.
        recording: samples of the recording's best fit per sample of the set (>= 2).
        noise: white noise std of the recording, fraction of the field radius (None: the corpus range).
        kind: "mag" or "accel" (None: mixed).
        n_sets, seed: size and seed of each retraining corpus.

    Returns:
        ``measured``, ``n_points``, ``span_s``, ``recording``, ``noise`` and ``validators``: name ->
        ``{"predicted", "measured", "log_error", "ratio"}`` (ratio = measured / predicted, log_error =
        ``|log10(ratio)|``) plus ``n_sets`` (None for the original) and, for the retrained ones, their
        corpus (``n_failed``, ``corpus_seed``, ``effects``, ``duration_s``, ``median_label``, ...).

    Raises:
        MargCalError: the set cannot be fitted or a corpus cannot be built.
    """
    predicted, measured = validator_errors(points, reference, validator)
    models: dict[str, tuple[object, dict[str, Any]]] = {"original": (validator, {"n_sets": None})}
    if effects:
        opts: dict[str, Any] = {"duration_s": span_s, "recording": recording, "noise": noise, "kind": kind}
        models["with_effect"] = retrain_validator(validator, n_sets, seed, effects, **opts)
        models["control"] = retrain_validator(validator, n_sets, seed, None, **opts)
    table: dict[str, dict[str, Any]] = {}
    ind = _set_indicators(points) if effects else None  # the retrained models predict from the same indicators
    for name, (model, summary) in models.items():
        pred = predicted if ind is None or model is validator else _predict(model, ind)
        table[name] = {"predicted": pred, "measured": measured, "log_error": _log_error(measured, pred),
                       "ratio": measured / max(pred, _TINY), **summary}
    return {"measured": measured, "n_points": len(points), "span_s": float(span_s), "recording": recording,
            "noise": noise, "validators": table}
