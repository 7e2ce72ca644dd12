"""Tests of ros_margcal.validation: ROC/AUC, threshold search, the fuzzy TSK validator, persistence."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.coverage.indicators import Indicators
from ros_margcal.model.errors import CalibrationFileError, ConfigError, InputError
from ros_margcal.validation.fuzzy import INDICATOR_NAMES, FuzzyValidator
from ros_margcal.validation.roc import auc, evaluate_threshold, operating_point, roc_auc, roc_curve
from ros_margcal.validation.shipped import load_default_validator
from ros_margcal.validation.threshold import ThresholdValidator


def _synthetic(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Two coverage-like features in [0, 1]; the error falls by three decades as both grow."""
    x = rng.uniform(0.0, 1.0, size=(n, 2))
    err = 10 ** (-3.0 + 2.5 * (1.0 - x[:, 0] * x[:, 1]) ** 2 + 0.15 * rng.normal(size=n))
    return x, err


def _pair_auc(score: np.ndarray, pos: np.ndarray) -> float:
    d = score[pos][:, None] - score[~pos][None, :]
    return float(((d > 0) + 0.5 * (d == 0)).mean())


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 6), st.booleans()), min_size=2, max_size=40))
def test_roc_auc_equals_pair_count_and_curve_area(rows: list[tuple[int, bool]]) -> None:
    """The rank AUC equals the pairwise count (ties half) and the trapezoid area under roc_curve."""
    score = np.array([r[0] for r in rows], dtype=float)
    pos = np.array([r[1] for r in rows])
    if pos.all() or not pos.any():
        with pytest.raises(InputError, match="both classes"):
            roc_auc(score, pos)
        return
    a = roc_auc(score, pos)
    assert a == pytest.approx(_pair_auc(score, pos))
    fpr, tpr, thr = roc_curve(score, pos)
    assert auc(fpr, tpr) == pytest.approx(a)
    assert fpr[0] == tpr[0] == 0.0 and fpr[-1] == tpr[-1] == 1.0
    assert np.all(np.diff(thr) < 0)


def test_roc_auc_orientation() -> None:
    """A score that ranks every good set first has AUC 1; reversed, 0."""
    pos = np.array([True, True, False, False])
    assert roc_auc([4, 3, 2, 1], pos) == 1.0
    assert roc_auc([1, 2, 3, 4], pos) == 0.0


@pytest.mark.parametrize(("score", "pos"), [([1.0, np.nan], [True, False]), ([1.0, 2.0], [True])])
def test_roc_rejects_bad_input(score: list[float], pos: list[bool]) -> None:
    """NaN scores and mismatched lengths are refused."""
    with pytest.raises(InputError):
        roc_auc(score, pos)


def test_operating_point_separable_and_capped() -> None:
    """Separable data give sensitivity = specificity = 1; the max_fpr cap is honoured."""
    score = np.array([0.1, 0.2, 0.3, 0.7, 0.8, 0.9])
    pos = score > 0.5
    op = operating_point(score, pos)
    assert (op.sensitivity, op.specificity, op.auc) == (1.0, 1.0, 1.0)
    assert 0.3 < op.threshold < 0.7
    # an overlapping set: one ill set scores above two good ones
    score2 = np.array([0.1, 0.2, 0.85, 0.7, 0.8, 0.9])
    pos2 = np.array([False, False, False, True, True, True])
    free = operating_point(score2, pos2)
    capped = operating_point(score2, pos2, max_fpr=0.0)
    assert capped.ill_accepted == 0.0 and capped.sensitivity == pytest.approx(1 / 3)
    assert free.sensitivity + free.specificity >= capped.sensitivity + capped.specificity
    assert evaluate_threshold(score2, pos2, capped.threshold) == capped
    with pytest.raises(ConfigError, match="max_fpr"):
        operating_point(score2, pos2, max_fpr=1.5)


def test_threshold_validator_directions() -> None:
    """C/D-like indicators accept high values, B (empty bins) low values; the paper's Eq. 13."""
    rng = np.random.default_rng(1)
    err = 10 ** rng.uniform(-3, -1, 200)
    good = err < 0.01
    vol = -np.log10(err) + 0.05 * rng.normal(size=200)  # high = good
    v = ThresholdValidator("d_norm").fit(vol, err)
    assert v.higher_is_better and v.train_point is not None and v.train_point.auc > 0.97
    assert np.mean(v.accept(vol) == good) > 0.97
    b = ThresholdValidator("B").fit(-vol, err)
    assert not b.higher_is_better
    assert np.array_equal(b.accept(-vol), v.accept(vol))
    with pytest.raises(ConfigError, match="not trained"):
        ThresholdValidator("C").accept(vol)


def test_fuzzy_learns_withheld_sets() -> None:
    """Trained on one synthetic set and tested on another, the AUC and rank correlation are high;
    an untrained system (all-zero consequents) is at chance."""
    rng = np.random.default_rng(7)
    xa, ea = _synthetic(rng, 600)
    xb, eb = _synthetic(rng, 600)
    untrained = FuzzyValidator()
    assert roc_auc(-untrained.predict(xb), eb < 0.01) == 0.5
    v = FuzzyValidator().fit(xa, ea, repeats=5, seed=3)
    pred = v.predict(xb)
    assert roc_auc(-pred, eb < 0.01) > 0.95
    rank = np.corrcoef(np.argsort(np.argsort(pred)), np.argsort(np.argsort(eb)))[0, 1]
    assert rank > 0.85
    # the threshold sits near the class boundary and caps ill sets accepted on the training data
    assert 0.002 < v.threshold < 0.05
    acc = v.accept(xa)
    assert np.mean(acc[ea >= 0.01]) <= 0.02 + 1e-12


def test_fuzzy_is_deterministic_and_centres_move() -> None:
    """Same seed, same model; centre training moves the partition without losing accuracy."""
    rng = np.random.default_rng(11)
    x, e = _synthetic(rng, 300)
    a = FuzzyValidator(n_mf=6).fit(x, e, repeats=4, seed=5)
    b = FuzzyValidator(n_mf=6).fit(x, e, repeats=4, seed=5)
    assert np.array_equal(a.consequents, b.consequents)
    fixed = FuzzyValidator(n_mf=6).fit(x, e, repeats=4, seed=5, train_centers=False)
    assert not np.allclose(a.centers[0], fixed.centers[0])
    def mse(v: FuzzyValidator) -> float:
        return float(np.mean((np.log10(v.predict(x)) - np.log10(e)) ** 2))
    assert mse(a) < mse(fixed) * 1.25
    # a huge l freezes the centres (Eq. 23: the step is eta * g / (|g| + l))
    frozen = FuzzyValidator(n_mf=6).fit(x, e, repeats=4, seed=5, l_rate=1e12)
    assert np.allclose(frozen.centers[0], fixed.centers[0], atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_inputs=st.integers(1, 3),
    n_mf=st.integers(2, 7),
    l_rate=st.floats(1e-4, 1.0),
    target=st.sampled_from(["log", "linear"]),
)
def test_fuzzy_partition_stays_complete_and_predictions_bounded(seed: int, n_inputs: int, n_mf: int,
                                                                 l_rate: float, target: str) -> None:
    """After training, centres stay strictly ordered with fixed ends, and every prediction (also
    outside the training range) lies within the consequent bounds (Eq. 17 is a convex mix)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(60, n_inputs)) * rng.uniform(0.1, 100.0)
    err = np.abs(rng.normal(size=60)) * 0.05 + 1e-4
    v = FuzzyValidator([f"f{i}" for i in range(n_inputs)], n_mf, target=target).fit(x, err, repeats=3, l_rate=l_rate, seed=seed)
    for c in v.centers:
        assert c[0] == 0.0 and c[-1] == 1.0
        assert np.all(np.diff(c) > 0)
    lo, hi = v.consequent_bounds()
    xt = rng.normal(size=(100, n_inputs)) * 300.0
    p = v.predict(xt)
    assert np.all(p >= lo - 1e-9 * abs(lo)) and np.all(p <= hi + 1e-9 * abs(hi))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), n_inputs=st.integers(1, 3), n_mf=st.integers(2, 6))
def test_lsq_consequents_never_raise_the_training_cost(seed: int, n_inputs: int, n_mf: int) -> None:
    """Re-solving the consequents minimises Eq. 19's cost plus a ridge term that is zero at the online
    result, so the training cost can only fall; the partition is the same as the paper's."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(80, n_inputs))
    err = 10 ** (-3 + np.tanh(x.sum(axis=1)) + 0.2 * rng.normal(size=80))
    paper = FuzzyValidator([f"f{i}" for i in range(n_inputs)], n_mf).fit(x, err, repeats=3, seed=seed)
    lsq = FuzzyValidator([f"f{i}" for i in range(n_inputs)], n_mf).fit(x, err, repeats=3, seed=seed, consequents="lsq")
    for a, b in zip(paper.centers, lsq.centers, strict=True):
        assert np.array_equal(a, b)
    def cost(v: FuzzyValidator) -> float:
        return float(np.sum((np.log10(v.predict(x)) - np.log10(err)) ** 2))
    assert cost(lsq) <= cost(paper) * (1 + 1e-9) + 1e-12
    assert lsq.metadata["consequents"] == "lsq" and paper.metadata["consequents"] == "paper"


def test_lsq_consequents_fit_a_target_the_online_rule_misses() -> None:
    """On a smooth target the least-squares consequents leave a much smaller training error than the
    online C = 1 rule, whose last steps follow the last sets it saw."""
    rng = np.random.default_rng(4)
    x, e = _synthetic(rng, 800)
    paper = FuzzyValidator().fit(x, e, repeats=5, seed=1)
    lsq = FuzzyValidator().fit(x, e, repeats=5, seed=1, consequents="lsq")
    def mse(v: FuzzyValidator) -> float:
        return float(np.mean((np.log10(v.predict(x)) - np.log10(e)) ** 2))
    assert mse(lsq) < 0.9 * mse(paper)
    with pytest.raises(ConfigError, match="consequents"):
        FuzzyValidator().fit(x, e, consequents="exact")


def test_fuzzy_reproduces_a_piecewise_linear_target() -> None:
    """With a linear target and fixed centres, the consequents converge to the values at the knots."""
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 1, size=(400, 1))
    y = 0.02 + 0.05 * x[:, 0]
    v = FuzzyValidator(["f"], 3, target="linear").fit(x, y, repeats=20, train_centers=False, max_fpr=None)
    lo, hi = x.min(), x.max()
    knots = lo + (hi - lo) * np.array([0.0, 0.5, 1.0])
    assert v.consequents == pytest.approx(0.02 + 0.05 * knots, abs=2e-3)


def test_fuzzy_predict_indicators_and_input_checks() -> None:
    """Indicators by mapping or attribute; missing names and wrong shapes are refused."""
    rng = np.random.default_rng(3)
    x, e = _synthetic(rng, 200)
    v = FuzzyValidator().fit(x, e, repeats=2)
    assert v.predict_indicators({"c_norm": 0.5, "d_norm": 0.4}) == pytest.approx(float(v.predict([[0.5, 0.4]])[0]))

    class Ind:
        c_norm = 0.5
        d_norm = 0.4

    assert v.predict_indicators(Ind()) == pytest.approx(v.predict_indicators({"c_norm": 0.5, "d_norm": 0.4}))
    with pytest.raises(InputError, match="d_norm"):
        v.predict_indicators({"c_norm": 0.5})
    with pytest.raises(InputError, match="shape"):
        v.predict(np.zeros((3, 3)))
    with pytest.raises(InputError, match="NaN"):
        v.predict([[np.nan, 0.1]])
    with pytest.raises(ConfigError):
        FuzzyValidator(n_mf=1)
    with pytest.raises(ConfigError):
        FuzzyValidator(target="cubic")
    with pytest.raises(ConfigError, match="threshold"):
        FuzzyValidator().accept(x)


def test_save_load_round_trip(tmp_path: Path) -> None:
    """A saved validator loads back with identical predictions and threshold."""
    rng = np.random.default_rng(4)
    x, e = _synthetic(rng, 200)
    v = FuzzyValidator(n_mf=(5, 7)).fit(x, e, repeats=2)
    path = v.save(tmp_path / "v.json")
    w = FuzzyValidator.load(path)
    assert w.inputs == v.inputs and w.n_mf == (5, 7) and w.threshold == v.threshold
    xt = rng.uniform(-0.5, 1.5, size=(50, 2))
    assert np.array_equal(w.predict(xt), v.predict(xt))
    assert np.array_equal(w.accept(xt), v.accept(xt))


def _corrupt(d: dict, key: str, value: object) -> dict:
    d = json.loads(json.dumps(d))
    d[key] = value
    return d


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (("format_version", 99), "newer"),
        (("format_version", "one"), "format_version"),
        (("kind", "something.else"), "not a ros_margcal"),
        (("consequents", [[0.0]]), "corrupt"),
        (("centers", [[0.0, 0.7, 0.5, 1.0, 1.0], [0.0, 1.0]]), "corrupt"),
        (("max_error", "x"), "corrupt"),
        (("threshold", float("nan")), "threshold nan"),
        (("threshold", -5.0), "threshold -5"),
        (("input_high", [0.0, 0.0]), "input ranges"),  # input_low 0: every input a point
        (("inputs", ["nope", "c_norm"]), "no coverage indicators"),
        (("n_mf", [1_000_000_000, 1_000_000_000]), "at most 100000 rules"),  # 7 TiB of consequents
        (("max_error", float("inf")), "finite"),
    ],
)
def test_load_refuses_bad_files(tmp_path: Path, change: tuple[str, object], match: str) -> None:
    """Newer, foreign and corrupt files raise CalibrationFileError naming the problem."""
    v = FuzzyValidator(n_mf=(5, 2))
    path = tmp_path / "v.json"
    path.write_text(json.dumps(_corrupt(v.to_dict(), *change)))
    with pytest.raises(CalibrationFileError, match=match):
        FuzzyValidator.load(path)


def test_load_refuses_non_json_and_missing(tmp_path: Path) -> None:
    """Garbage, absent and deeply nested files are refused with CalibrationFileError (nesting raised a
    RecursionError, which ended the node at start)."""
    path = tmp_path / "v.json"
    path.write_text("{not json")
    with pytest.raises(CalibrationFileError, match="JSON"):
        FuzzyValidator.load(path)
    with pytest.raises(CalibrationFileError, match="cannot read"):
        FuzzyValidator.load(tmp_path / "absent.json")
    path.write_text("[" * 200_000)
    with pytest.raises(CalibrationFileError, match="nested too deeply"):
        FuzzyValidator.load(path)


def test_load_refuses_a_fifo_or_a_device(tmp_path: Path) -> None:
    """A validator_file that is a FIFO (no writer: the read blocked for ever) or /dev/zero (endless) hung the node at
    start, deaf to SIGTERM: refused as not a regular file, at once."""
    fifo = tmp_path / "v.fifo"
    os.mkfifo(fifo)
    for path in (fifo, Path("/dev/zero")):
        with pytest.raises(CalibrationFileError, match="not a regular file"):
            FuzzyValidator.load(path)


def test_default_validator_ships_and_is_trained() -> None:
    """The packaged model loads, has a threshold near the 1 % label boundary and orders coverage:
    a full sphere (C, D normalised near their maxima) is predicted better than a small cap."""
    v = load_default_validator()
    assert v.threshold is not None and 0.0003 < v.threshold < 0.03
    assert set(v.inputs) <= {"c_norm", "d_norm", "b_frac", "e_info", "e_total", "A", "B", "C", "D"}
    # a full sphere of 600 samples against a 50-sample cap (e_total = e_info + log10 n)
    full = {"c_norm": 1.0, "d_norm": 1.0, "b_frac": 0.0, "e_info": 0.0, "e_total": math.log10(600)}
    poor = {"c_norm": 0.3, "d_norm": 0.01, "b_frac": 0.9, "e_info": -6.0, "e_total": -6.0 + math.log10(50)}
    assert v.predict_indicators(full) < v.threshold < v.predict_indicators(poor)


def test_the_inputs_a_validator_file_may_take_are_the_indicators() -> None:
    """``fuzzy.INDICATOR_NAMES`` (written out: validation sits below coverage) names every indicator the
    calibrator computes, and nothing else."""
    assert set(INDICATOR_NAMES) == {f.name for f in dataclasses.fields(Indicators)} | {"e_total"}
