"""Tests of ros_margcal.diagnosis.downstream: the validator retrained with a diagnosed effect, and the
corpus label of sets drawn from a recording (``corpus.make_set(recording=k)``) it is trained on."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from ros_margcal.diagnosis.core import validator_downstream
from ros_margcal.diagnosis.downstream import N_SET, compare_validators, validator_errors
from ros_margcal.diagnosis.twin import subsample
from ros_margcal.model.fitting import fit
from ros_margcal.recordings.read import read_recording
from ros_margcal.sim.simulation import magnetometer_stream, random_sensor
from ros_margcal.training.corpus import build_corpus, make_set
from ros_margcal.training.labels import recording_error
from ros_margcal.validation.shipped import load_default_validator


class _Constant:
    """A stand-in validator predicting one value whatever the indicators."""

    def __init__(self, value: float) -> None:
        self.value = value

    def predict_indicators(self, indicators: Any) -> float:
        return self.value


def _label_ratio(effects: dict[str, float], *, recording: int | None, n_sets: int = 40) -> float:
    """Median over well-fitted sets of (label with ``effects``) / (label without), same sets."""
    opts: dict[str, Any] = {"duration_s": 120.0, "recording": recording, "kind": "mag", "noise_range": (3e-3, 3e-3),
                            "n_min": 150, "n_max": 400}
    plain = build_corpus(n_sets, 7, **opts)
    with_fx = build_corpus(n_sets, 7, effects=effects, **opts)
    ok = (plain.error < 0.05) & (with_fx.error < 0.05)
    assert ok.sum() >= n_sets // 3
    return float(np.median(with_fx.error[ok] / plain.error[ok]))


def test_recording_label_is_the_measured_error() -> None:
    """The label of a set drawn from a recording is exactly what ``validator_errors`` measures on that
    set against the recording's best fit (the same function, the same fit)."""
    r = make_set(3, 1, n=200, pattern="uniform", effects={"bias_drift": 0.05}, duration_s=60.0, recording=5, kind="mag")
    assert r["fit"] is not None and r["reference"] is not None
    assert r["error"] == recording_error(r["fit"], r["reference"])
    _, measured = validator_errors(r["points"], r["reference"], _Constant(1e-3))
    assert measured == pytest.approx(r["error"], rel=1e-9)
    # the reference is the recording's fit, not the set's: the label is not zero
    assert r["error"] > 1e-5


def test_recording_set_is_every_kth_sample_of_its_recording() -> None:
    """Without effects the set is the recording's every k-th sample: its points are the set's
    directions read by the true sensor, and the label is the noise-driven error (small, non-zero)."""
    r = make_set(4, 2, n=300, pattern="uniform", recording=4, kind="mag", noise_range=(2e-3, 2e-3))
    assert r["points"].shape == (300, 3)
    assert 1e-5 < r["error"] < 2e-3
    plain = make_set(4, 2, n=300, pattern="uniform", kind="mag", noise_range=(2e-3, 2e-3))
    # the label against the recording's best fit is close to the label against the truth (the
    # recording's fit on 4x the samples is nearly the truth), within the noise of both
    assert 0.5 < r["error"] / plain["error"] < 2.0


def test_drift_shared_by_the_recording_stays_out_of_the_label() -> None:
    """A drift the whole recording shares distorts the set's fit and the recording's best fit alike:
    the recording label barely moves, while the label against the truth grows several-fold (the old
    definition's flaw, cause (a) of the downstream study)."""
    assert _label_ratio({"bias_drift": 0.04}, recording=5) < 1.3
    assert _label_ratio({"bias_drift": 0.04}, recording=None) > 3.0


def test_readout_noise_enters_the_recording_label() -> None:
    """Extra white noise differs between the set and the rest of the recording: it raises the label."""
    assert _label_ratio({"noise": 0.006}, recording=5) > 1.8


def test_compare_validators_table_and_keys() -> None:
    """The table has the three validators with predicted, measured, log_error, ratio and the corpus
    size; log_error is |log10(measured / predicted)|; the original's prediction is the validator's own."""
    rng = np.random.default_rng(11)
    truth = random_sensor(rng, "mag")
    rec = magnetometer_stream(truth, 60.0, 50.0, rng, noise=0.004, effects={"noise": 0.004})
    best = fit(rec.raw, model="sym", method="lm", norm=None)
    pick = np.linspace(0, len(rec.raw) - 1, N_SET).astype(np.intp)
    v = load_default_validator()
    out = compare_validators(rec.raw[pick], best, v, {"noise": 0.004}, span_s=60.0, recording=10, noise=0.004,
                             kind="mag", n_sets=60, seed=2)
    assert set(out) == {"measured", "n_points", "span_s", "recording", "noise", "validators"}
    assert out["n_points"] == N_SET and out["recording"] == 10
    table = out["validators"]
    assert set(table) == {"original", "with_effect", "control"}
    pred0, meas = validator_errors(rec.raw[pick], best, v)
    assert table["original"]["predicted"] == pred0 and out["measured"] == meas
    assert table["original"]["n_sets"] is None
    for name in ("with_effect", "control"):
        row = table[name]
        assert row["n_sets"] == 60 and row["corpus_seed"] == 2 and row["recording"] == 10
        assert row["log_error"] == pytest.approx(abs(math.log10(meas / row["predicted"])))
        assert row["ratio"] == pytest.approx(meas / row["predicted"])
    assert table["with_effect"]["effects"] == {"noise": 0.004} and table["control"]["effects"] == {}
    # the noise effect enters the labels, so the retrained validator predicts a larger error
    assert table["with_effect"]["median_label"] > 1.3 * table["control"]["median_label"]
    assert table["with_effect"]["predicted"] > table["control"]["predicted"]
    assert set(compare_validators(rec.raw[pick], best, v, None, span_s=60.0, recording=10)["validators"]) == {"original"}


def _fake_diagnosis(rec: Any, cause: str, effect: tuple[str, float] | None) -> SimpleNamespace:
    """The parts of a ``Diagnosis`` that ``validator_downstream`` reads."""
    sub = subsample(len(rec.raw), 1200)
    best = fit(rec.raw[sub], model="sym", method="lm", norm=None)
    twin = SimpleNamespace(raw=rec.raw, sub=sub, t=rec.t, best=best, noise=0.004, sensor="mag")
    chosen = None if effect is None else SimpleNamespace(name=effect[0], magnitude=effect[1])
    return SimpleNamespace(twin=twin, best=chosen, cause=cause)


def test_validator_downstream_reports_the_table_and_the_summary_keys() -> None:
    """On a diagnosis with an effect: the flat keys repeat the table, the set is 300 samples spanning the
    recording, the recording factor is the fitted samples per set sample; cause none: no retraining."""
    rng = np.random.default_rng(12)
    rec = magnetometer_stream(random_sensor(rng, "mag"), 40.0, 50.0, rng, noise=0.004)
    v = load_default_validator()
    out = validator_downstream(_fake_diagnosis(rec, "noise", ("noise", 0.003)), v, n_sets=40, seed=1)
    assert out["available"] and out["effect"] == "noise" and out["n_sets"] == 40
    assert out["n_points"] == N_SET and out["recording"] == 4 and out["noise"] == 0.004
    assert out["span_s"] == pytest.approx(float(rec.t[-1] - rec.t[0]), abs=0.05)
    table = out["validators"]
    assert out["predicted_before"] == table["original"]["predicted"]
    assert out["predicted_after"] == table["with_effect"]["predicted"]
    assert out["predicted_control"] == table["control"]["predicted"]
    for key in ("log_error_before", "log_error_after", "log_error_control"):
        assert out[key] >= 0
    assert out["log_error_after"] == table["with_effect"]["log_error"]
    none = validator_downstream(_fake_diagnosis(rec, "none", None), v, n_sets=40)
    assert none["available"] and set(none["validators"]) == {"original"}
    assert none["predicted_after"] == none["predicted_before"]
    assert validator_downstream(_fake_diagnosis(rec, "none", None), None) == {"available": False, "reason": "no validator"}


def test_measured_error_of_a_real_recording_is_its_recording_label(real_data_dir: Any) -> None:
    """On a real recording the measured error of the set is ``recording_error`` against the best fit
    of all samples, small for a full-sphere recording, and the default validator predicts it within a
    decade."""
    rec = read_recording(real_data_dir / "hamagure_lsm9ds1_full_sphere_mag.csv", sensor="mag")
    best = fit(rec.raw, model="sym", method="lm", norm=None)
    pick = np.linspace(0, len(rec.raw) - 1, N_SET).astype(np.intp)
    pred, meas = validator_errors(rec.raw[pick], best, load_default_validator())
    assert meas == recording_error(fit(rec.raw[pick], model="sym", method="lm", norm=None), best)
    assert 1e-4 < meas < 1e-2
    assert abs(math.log10(meas / pred)) < 1.0
