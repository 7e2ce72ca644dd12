"""Tests of ros_margcal.training.corpus (labelled simulated sets) and the validator subcommands."""

from __future__ import annotations

import argparse
import io
import json
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.cli import validator as cli
from ros_margcal.model.errors import CalibrationFileError, ConfigError
from ros_margcal.sim.simulation import EFFECTS, directions
from ros_margcal.training.corpus import (
    _STATIC_EFFECTS,
    FAILED_ERROR,
    FEATURES,
    Corpus,
    build_corpus,
    information_indicator,
    make_set,
)
from ros_margcal.validation.baselines import BASELINES
from ros_margcal.validation.fuzzy import FuzzyValidator
from ros_margcal.validation.roc import roc_auc
from ros_margcal.validation.shipped import load_default_validator


@pytest.fixture(scope="module")
def small_corpus() -> Corpus:
    """400 sets (about 3 s), shared by the tests of this module."""
    return build_corpus(400, seed=123)


def test_make_set_is_deterministic_and_independent_of_order() -> None:
    """A set depends only on (seed, index): regenerating it alone gives the same data and label."""
    a = make_set(5, 17)
    b = make_set(5, 17)
    c = make_set(5, 18)
    assert np.array_equal(a["points"], b["points"]) and a["error"] == b["error"]
    assert np.array_equal(a["features"], b["features"])
    assert not np.array_equal(a["features"], c["features"])
    assert a["features"].shape == (len(FEATURES),) and a["baselines"].shape == (len(BASELINES),)


def test_labels_follow_coverage() -> None:
    """Dense uniform coverage calibrates to well under 1 %; a 20° cap does not; the label is the
    held-out error of the set's own fit, so it is at least the truth's error (zero)."""
    full = make_set(1, 0, pattern="uniform", n=400)
    cap = make_set(1, 1, pattern="cap", n=400, params={"half_angle_deg": 20.0})
    assert full["error"] < 0.005
    assert cap["error"] > 0.02
    assert full["fit"] is not None
    ind_full = dict(zip(FEATURES, full["features"], strict=True))
    ind_cap = dict(zip(FEATURES, cap["features"], strict=True))
    assert ind_full["d_norm"] > 0.8 > ind_cap["d_norm"]
    assert ind_full["c_norm"] > ind_cap["c_norm"]


def test_information_indicator_sees_what_hull_volume_misses() -> None:
    """E is ~0 for uniform directions, invariant to centre and scale, and very negative for two full
    great circles, whose hull volume is still large (an ellipsoid deformation keeps every norm)."""
    rng = np.random.default_rng(0)
    uni = directions("uniform", 5000, rng)
    assert abs(information_indicator(uni, np.zeros(3), 1.0)) < 0.05
    c = np.array([3.0, -1.0, 2.0])
    assert information_indicator(uni * 7.0 + c, c, 7.0) == pytest.approx(information_indicator(uni, np.zeros(3), 1.0))
    circles = directions("great_circle", 400, rng, n_circles=2)
    cap = directions("cap", 400, rng, half_angle_deg=40.0)
    assert information_indicator(circles, np.zeros(3), 1.0) < -6
    assert -6 < information_indicator(cap, np.zeros(3), 1.0) < -1
    axes = directions("axis_ellipses", 400, rng)  # three circles determine the ellipsoid
    assert information_indicator(axes, np.zeros(3), 1.0) > -1


def test_corpus_shape_groups_and_failures(small_corpus: Corpus) -> None:
    """Columns agree, both groups and both classes are populated, labels are in (0, FAILED_ERROR]."""
    c = small_corpus
    n = len(c)
    assert c.features.shape == (n, len(FEATURES)) and c.baselines.shape == (n, len(BASELINES))
    assert np.all(np.isfinite(c.features)) and np.all(np.isfinite(c.baselines))
    assert set(np.unique(c.group)) == {0, 1}
    assert 0 < c.good(0.01).mean() < 1
    assert np.all((c.error > 0) & (c.error <= FAILED_ERROR))
    assert len(set(c.pattern)) >= 6 and set(c.kind) == {"mag", "accel"}
    assert c.column("d_norm").shape == (n,)
    with pytest.raises(ConfigError, match="no column"):
        c.column("E")


def test_save_load_round_trip(small_corpus: Corpus, tmp_path: Path) -> None:
    """A saved corpus loads back identical; newer and garbage files are refused."""
    path = small_corpus.save(tmp_path / "c.npz")
    back = Corpus.load(path)
    assert np.array_equal(back.features, small_corpus.features)
    assert np.array_equal(back.error, small_corpus.error)
    assert list(back.pattern) == list(small_corpus.pattern) and back.feature_names == small_corpus.feature_names
    assert back.meta["seed"] == "123"
    newer = tmp_path / "newer.npz"
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    data["format_version"] = np.int64(99)
    np.savez(newer, **data)
    with pytest.raises(CalibrationFileError, match="newer"):
        Corpus.load(newer)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(CalibrationFileError, match="not a readable corpus"):
        Corpus.load(bad)


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_and_size_check() -> None:
    """Progress goes to the given stream: a carriage-return counter on a terminal, a line a quarter elsewhere (a log
    file reads line by line); tiny corpora are refused."""
    stream = _Terminal()
    build_corpus(4, seed=1, progress=stream)
    assert "\rcorpus: 4/4 sets" in stream.getvalue()
    log = io.StringIO()
    build_corpus(8, seed=1, progress=log)
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue() and [ln.split(",")[0] for ln in lines] == [f"corpus: {k}/8 sets" for k in (2, 4, 6, 8)]
    with pytest.raises(ConfigError, match="n_sets"):
        build_corpus(1)


def test_retrained_small_validator_clears_the_bar(small_corpus: Corpus) -> None:
    """Trained on one half and tested on the other, the fuzzy C&D validator ranks sets well
    (a trainer that does nothing scores 0.5, one with a sign error below 0.5)."""
    tr = small_corpus.subset(small_corpus.group == 0)
    te = small_corpus.subset(small_corpus.group == 1)
    v = FuzzyValidator().fit(tr.matrix(v_inputs := ("c_norm", "d_norm")), tr.error, repeats=5)
    pred = v.predict(te.matrix(v_inputs))
    good = te.good(0.01)
    assert roc_auc(-pred, good) > 0.95
    assert np.mean(v.accept(te.matrix(v_inputs))[~good]) < 0.08


def test_default_validator_generalises_to_a_fresh_corpus(small_corpus: Corpus) -> None:
    """The shipped model (trained on another seed) separates good from ill sets of this corpus."""
    v = load_default_validator()
    pred = v.predict(small_corpus.matrix(v.inputs))
    good = small_corpus.good(v.max_error)
    assert roc_auc(-pred, good) > 0.96
    assert np.mean(v.accept(small_corpus.matrix(v.inputs))[~good]) < 0.06


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser()
    cli.register(p.add_subparsers(dest="command"))
    return p


def test_cli_build_train_evaluate(small_corpus: Corpus, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The three subcommands run end to end: corpus file, validator JSON, tables, JSON and PNG."""
    p = _parser()
    corpus_path = tmp_path / "c.npz"
    args = p.parse_args(["build-corpus", "--n-sets", "6", "--seed", "3", "--out", str(corpus_path)])
    assert args.func(args) == 0 and corpus_path.exists()
    small_path = small_corpus.save(tmp_path / "small.npz")
    out = tmp_path / "v.json"
    args = p.parse_args(["train-validator", "--corpus", str(small_path), "--repeats", "2", "--out", str(out)])
    assert args.func(args) == 0
    assert FuzzyValidator.load(out).threshold is not None
    js, png = tmp_path / "e.json", tmp_path / "roc.png"
    args = p.parse_args(["evaluate-validator", "--corpus", str(small_path), "--repeats", "2", "--pairs", "c_norm,d_norm",
                         "C,D", "--json", str(js), "--plot", str(png)])
    assert args.func(args) == 0
    text = capsys.readouterr().out
    for heading in ("Table 1.", "Table 2.", "Table 3.", "Baselines", "motioncal_gap", "Summary"):
        assert heading in text
    res = json.loads(js.read_text())
    assert set(res["fuzzy"]) == {"c_norm&d_norm", "C&D"} and set(res["baselines"]) == set(BASELINES)
    for d in (*res["fuzzy"].values(), *res["baselines"].values()):
        assert 0.0 <= d["auc"]["mean"] <= 1.0 and len(d["runs"]) == 2
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_corpus_features_match_the_node_buffer() -> None:
    """The features the validator is trained on match what the node computes: the same sets pushed
    through ``DirectionBuffer`` and centred by a sphere fit give nearly the same predicted error."""
    import math

    from ros_margcal.coverage.buffer import DirectionBuffer

    v = load_default_validator()
    cols = [FEATURES.index(name) for name in v.inputs]
    ratios = []
    for i in range(12):
        r = make_set(31, i)
        buf = DirectionBuffer(n_bins=100, per_bin=10)
        for k, p in enumerate(r["points"]):
            buf.push(float(k), p)
        pts = buf.points()
        sol, *_ = np.linalg.lstsq(np.c_[2.0 * pts, np.ones(len(pts))], (pts * pts).sum(axis=1), rcond=None)
        buf.set_center(sol[:3], math.sqrt(sol[3] + sol[:3] @ sol[:3]))
        ratios.append(v.predict_indicators(buf.indicators()) / float(v.predict(r["features"][cols])[0]))
    assert np.median(np.abs(np.log10(ratios))) < 0.05


def test_make_set_applies_only_effects_of_its_sensor_kind() -> None:
    """An effect changes the set's points; an effect of the other sensor kind, or magnitude 0, changes nothing."""
    plain = make_set(5, 0, n=200, pattern="uniform")
    other = "motion_leak" if plain["kind"] == "mag" else "disturbance"
    assert plain["kind"] not in EFFECTS[other].sensors
    assert np.array_equal(make_set(5, 0, n=200, pattern="uniform", effects={other: 0.5})["points"], plain["points"])
    assert np.array_equal(make_set(5, 0, n=200, pattern="uniform", effects={"soft_iron": 0.0})["points"], plain["points"])
    shaped = make_set(5, 0, n=200, pattern="uniform", effects={"nonorthogonality": 2.0})
    assert np.abs(shaped["points"] - plain["points"]).max() > 1e-3 * np.abs(plain["points"]).max()


def test_static_effects_enter_the_label() -> None:
    """The label's sensor carries a static effect with the set's own random draws: a well-covered set
    of a sensor with skewed axes is labelled good, though its fit misses the effect-free sensor."""
    assert {"soft_iron", "nonorthogonality", "nonlinearity", "saturation", "misalignment"} <= _STATIC_EFFECTS
    assert not {"noise", "quantization", "bias_drift", "temperature", "disturbance", "hard_iron_jump"} & _STATIC_EFFECTS
    plain = make_set(5, 0, n=600, pattern="uniform")
    shaped = make_set(5, 0, n=600, pattern="uniform", effects={"nonorthogonality": 4.0})
    assert shaped["fit"] is not None and plain["fit"] is not None
    # the effect-free sensor, read at uniform directions through the plain set's (near-perfect) fit
    u = directions("uniform", 400, np.random.default_rng(1))
    raw = plain["fit"].inverse_apply(u * plain["fit"].norm)
    rel = np.linalg.norm(shaped["fit"].apply(raw), axis=1) / shaped["fit"].norm - 1.0
    assert float(np.sqrt(np.mean(rel**2))) > 10 * shaped["error"]
    assert shaped["error"] < 3 * plain["error"] + 1e-3


def test_duration_spreads_the_set_not_the_label() -> None:
    """Without ``recording`` a time span only spreads the set: without effects it changes nothing, and
    a drift stays out of the label's sensor (the label is against the drift-free truth, so the drift
    over 2 min costs the fit more than its absence)."""
    plain = make_set(5, 0, n=600, pattern="uniform")
    same = make_set(5, 0, n=600, pattern="uniform", duration_s=120.0)
    assert same["error"] == plain["error"] and np.array_equal(same["points"], plain["points"])
    assert same["reference"] is None
    spanned = make_set(5, 0, n=600, pattern="uniform", effects={"bias_drift": 0.05}, duration_s=120.0)
    assert spanned["error"] > 3 * plain["error"]


def test_make_set_options_are_checked_and_kind_can_be_forced() -> None:
    """``recording`` below 2 and an unknown ``kind`` are refused; a forced kind is used, and forcing the
    kind the set would have drawn changes nothing."""
    with pytest.raises(ConfigError):
        make_set(5, 0, recording=1)
    with pytest.raises(ConfigError):
        make_set(5, 0, kind="gyro")
    drawn = make_set(5, 0, n=100)
    other = "accel" if drawn["kind"] == "mag" else "mag"
    forced = make_set(5, 0, n=100, kind=other)
    assert forced["kind"] == other
    again = make_set(5, 0, n=100, kind=drawn["kind"])
    assert again["error"] == drawn["error"] and np.array_equal(again["points"], drawn["points"])
