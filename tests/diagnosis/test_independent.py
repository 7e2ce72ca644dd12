"""The diagnosis on recordings it was not built from (``tests/independent/generator.py``): no traceback,
always a verdict, no offset change without evidence, and the pieces that make the twin fit such data
(closed-form fallback, slow noise, the sensor's own shape)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from ros_margcal.diagnosis import diagnose, locate_offset_change, stage_gaps
from ros_margcal.diagnosis.baseline_noise import ar1_noise, estimate_slow_noise, shaped_truth
from ros_margcal.diagnosis.changes import step_evidence
from ros_margcal.diagnosis.fit_checks import lm_diag, sym_fit
from ros_margcal.diagnosis.ranking import (
    CLOSE_MARGIN,
    PLAIN_GROUPS,
    STEP_MARGIN,
    EffectFit,
    gap_with,
    separate_close_calls,
    separate_step_from_walk,
)
from ros_margcal.diagnosis.stages import StageFeatures
from ros_margcal.diagnosis.twin import Twin, build_twin, subsample
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import ConvergenceError
from ros_margcal.model.fitting import fit
from ros_margcal.recordings.recording import Recording

VERDICTS = {"none", "unexplained", "ellipsoid_shape", "slow_drift", "temperature", "saturation", "nonlinearity",
            "quantization", "hard_iron_jump", "noise", "disturbance", "bias_drift"}


def _recording(gen: ModuleType, effect: str, motion: str = "tumble", duration: float = 20.0, seed: int = 1,
               magnitude: float | None = None) -> tuple[Recording, float]:
    rec = gen.generate("mag", motion, duration, 50.0, seed, effect=effect, magnitude=magnitude)
    return Recording(t=rec["t"], raw=rec["xyz"], sensor="mag"), float(rec["truth"]["norm"])


@pytest.mark.parametrize(("effect", "magnitude"), [("saturation", 0.9), ("nonlinearity", 0.02)])
def test_hostile_independent_recording_gets_a_verdict_and_no_split(independent: ModuleType, effect: str,
                                                                    magnitude: float) -> None:
    """Clipping and a cubic non-linearity (which kept lm from converging and read as a hard-iron change)
    give a verdict with a ranking, and no offset change is claimed."""
    rec, norm = _recording(independent, effect, magnitude=magnitude)
    d = diagnose(rec, sensor="mag", norm=norm, quick=True)
    assert d.cause in VERDICTS
    assert d.effects  # the ranking went on
    assert d.offset_change == {}
    assert json.dumps(d.to_dict(), default=float)


def test_clean_short_recording_is_not_split(independent: ModuleType) -> None:
    """A clean 20 s recording holds no offset change: neither the change search nor the diagnosis splits it."""
    rec, norm = _recording(independent, "none", seed=3)
    sub = subsample(len(rec.t), 6000)
    assert locate_offset_change(rec.t[sub], rec.raw[sub]) is None
    d = diagnose(rec, sensor="mag", norm=norm, quick=True)
    assert d.offset_change == {}
    assert d.cause != "hard_iron_jump"


def test_a_real_jump_is_still_located(independent: ModuleType) -> None:
    """The shared-shape test keeps a true hard-iron step of 0.2 field radii (the generator's default)."""
    rec, _ = _recording(independent, "hard_iron_jump", duration=30.0)
    change = locate_offset_change(rec.t, rec.raw)
    assert change is not None
    assert change.t == pytest.approx(15.0, abs=1.0)
    assert change.shared_drop > 0.9
    assert change.relative_step == pytest.approx(0.2, rel=0.2)


def test_partial_coverage_falls_back_to_the_closed_form(independent: ModuleType) -> None:
    """A band of directions (|roll|, |pitch| <= 20 deg) on which lm does not converge is measured with
    the closed-form fit, recording and twins alike, and gets a verdict."""
    rec, norm = _recording(independent, "none", motion="band")
    d = diagnose(rec, sensor="mag", norm=norm, quick=True)
    assert d.twin is not None and d.twin.closed_form
    assert d.cause in VERDICTS
    assert d.stages_before


def test_misalignment_is_none_with_the_sensors_shape_as_baseline(independent: ModuleType) -> None:
    """A rotation of the sensor axes is invisible to magnitudes: with the generator's own soft iron
    counted as the sensor's baseline the verdict is none (misalignment is listed as unobservable)."""
    rec, norm = _recording(independent, "misalignment", duration=30.0, seed=2)
    d = diagnose(rec, sensor="mag", norm=norm, quick=True, shape_tolerance=0.05)
    assert d.cause == "none"
    assert "misalignment" in d.unobservable


def test_stage_missing_from_the_spread_is_left_out() -> None:
    """A stage the effect twins have but the baseline's spread lacks (the validator stage when the
    baseline twins could not give it) is left out, not a KeyError."""
    rec = {"residual_size": np.array([1.0, 1.0]), "validator": np.array([0.3])}
    mean = {"residual_size": np.array([0.0, 0.0]), "validator": np.array([0.0])}
    sd = {"residual_size": np.array([0.5, 0.5])}
    assert set(stage_gaps(rec, mean, sd)) == {"residual_size"}


def test_shaped_truth_keeps_cross_terms_up_to_the_tolerance() -> None:
    """A shape within the tolerance is the baseline's; a larger one is scaled down to the tolerance as a
    whole (root sum of squares of the three cross terms), its pattern kept: only the excess is a gap."""
    w = np.array([[1.0, 0.03, -0.1], [0.03, 1.2, 0.0], [-0.1, 0.0, 0.9]])
    best = Calibration(np.zeros(3), w, norm=1.0, model="sym")
    diag = Calibration(np.zeros(3), np.diag(np.diag(w)), norm=1.0, model="diag")
    assert shaped_truth(diag, best, 0.0) is diag
    d = np.sqrt(np.outer(np.diag(w), np.diag(w)))
    upper = np.triu_indices(3, 1)
    size = float(np.linalg.norm((w / d)[upper]))
    out = shaped_truth(diag, best, 0.05).matrix
    assert float(np.linalg.norm((out / d)[upper])) == pytest.approx(0.05)
    np.testing.assert_allclose((out / d)[upper], (w / d)[upper] * 0.05 / size)
    assert np.allclose(np.diag(out), np.diag(w))
    np.testing.assert_allclose(shaped_truth(diag, best, 1.1 * size).matrix, w)  # within: kept as fitted
    # three terms each within a per-entry bound can still make a shape beyond the tolerance
    w3 = np.array([[1.0, 0.04, 0.04], [0.04, 1.0, 0.04], [0.04, 0.04, 1.0]])
    out3 = shaped_truth(diag.replace(matrix=np.eye(3)), best.replace(matrix=w3), 0.05).matrix
    assert float(np.linalg.norm(out3[upper])) == pytest.approx(0.05)


def test_slow_noise_is_found_only_where_there_is_some() -> None:
    """The slow part of a residual (AR(1) of half the white std) is found with about its size; white
    noise alone gives none."""
    rng = np.random.default_rng(4)
    t = np.arange(3000) * 0.02
    dirs = np.tile([0.0, 0.0, 1.0], (3000, 1))  # a still direction: the residual sees the noise fully
    white = 0.002 * rng.normal(size=3000)
    slow = ar1_noise(t, 0.001, 5.0, rng)[:, 2]
    std, tau = estimate_slow_noise(t, white + slow, 0.002, dirs)
    assert std == pytest.approx(0.001, rel=0.35)
    assert 1.0 < tau < 15.0
    assert estimate_slow_noise(t, white, 0.002, dirs)[0] == 0.0


def test_cli_writes_a_verdict_for_a_hostile_independent_csv(independent: ModuleType, tmp_path: Path) -> None:
    """margcal diagnose on the generator's CSV (t,x,y,z in tesla, --norm given) exits 0 with diagnosis.json."""
    from ros_margcal.cli import main

    rec = independent.generate("mag", "tumble", 20.0, 50.0, 5, effect="nonlinearity")
    independent.write_csv(tmp_path / "nl.csv", rec)
    out = tmp_path / "d"
    assert main(["diagnose", str(tmp_path / "nl.csv"), "--sensor", "mag", "--norm", "4.8e-05", "--out", str(out),
                 "--quick", "--no-validator"]) == 0
    assert json.loads((out / "diagnosis.json").read_text())["cause"] in VERDICTS


class _StubTwin:
    """Just what ``separate_close_calls`` reads: the recording's features and the effect twins' features."""

    def __init__(self, rec: dict[str, np.ndarray], per_effect: dict[str, list[dict[str, np.ndarray]]]) -> None:
        self.features_rec = StageFeatures(values=rec, residual=np.zeros(1), dirs=np.zeros((1, 3)), t=np.zeros(1),
                                          rest_noise=0.0)
        self._per = per_effect

    def try_features(self, effects: dict[str, float], seed: int) -> StageFeatures:
        (name,) = effects
        vals = self._per[name][seed]
        return StageFeatures(values=vals, residual=np.zeros(1), dirs=np.zeros((1, 3)), t=np.zeros(1), rest_noise=0.0)


def _fit(name: str, group: str, shrink: float) -> EffectFit:
    return EffectFit(name=name, group=group, magnitude=0.01, unit="", gap_before=5.0, gap_after=5.0 * (1 - shrink),
                     shrink=shrink, n_seeds=3)


def test_close_call_that_no_feature_separates_names_the_ellipsoid() -> None:
    """A non-linearity a hair ahead of a shape effect, on twins that agree on every feature (a band of
    directions), yields to the plainer ellipsoid; with a feature that separates them, the data decide."""
    same = [{"residual_size": np.array([-2.0 + 0.001 * s])} for s in range(3)]
    twin = _StubTwin({"residual_size": np.array([-2.0])}, {"nonlinearity": same, "soft_iron": same})
    fits = [_fit("nonlinearity", "nonlinearity", 0.74), _fit("soft_iron", "ellipsoid_shape", 0.73)]
    assert "ellipsoid_shape" in PLAIN_GROUPS
    assert separate_close_calls(twin, fits, (0, 1, 2))[0].name == "soft_iron"
    far = [{"residual_size": np.array([-1.0 + 0.001 * s])} for s in range(3)]  # the shape's twins miss the recording
    twin = _StubTwin({"residual_size": np.array([-2.0])}, {"nonlinearity": same, "soft_iron": far})
    assert separate_close_calls(twin, fits, (0, 1, 2))[0].name == "nonlinearity"
    fits_wide = [_fit("nonlinearity", "nonlinearity", 0.80), _fit("soft_iron", "ellipsoid_shape", 0.70)]
    assert separate_close_calls(twin, fits_wide, (0, 1, 2))[0].name == "nonlinearity"  # not a close call


def test_clipping_on_a_band_is_saturation(independent: ModuleType) -> None:
    """On a band of directions one axis can sit at the clip level most of the time and the fitted sphere
    overstates the range no reading reaches; the clip level is measured against the largest reading the
    motion gives, so the twin clips where the recording does and the verdict is saturation, not quantization."""
    rec, norm = _recording(independent, "saturation", motion="band", seed=1)
    clipped = np.mean(rec.raw == rec.raw.min(axis=0), axis=0) + np.mean(rec.raw == rec.raw.max(axis=0), axis=0)
    assert clipped.max() > 0.5  # the case: an axis at its clip level for most of the recording
    d = diagnose(rec, sensor="mag", norm=norm, quick=True, shape_tolerance=0.05)
    assert d.cause == "saturation"
    assert d.best is not None and 0.0 < d.best.magnitude < 0.2


def test_ill_conditioned_lm_fit_is_refused(independent: ModuleType) -> None:
    """On a ±20° band of tilts lm's bias-corrected diag fit can end far off the least-squares optimum (here
    several times the closed form's residual): ``lm_diag`` refuses it, so recording and twins are measured
    with the closed form, and the algebraic fit gives the cross terms ``lin_auto`` cannot."""
    rec = independent.generate("mag", "band", 60.0, 50.0, 2, effect="none", colored_noise=0.0, soft_iron=0.0)
    pts, norm = rec["xyz"], float(rec["truth"]["norm"])

    def rms(cal: Calibration) -> float:
        return float(np.sqrt(np.mean((np.linalg.norm(cal.apply(pts), axis=1) / norm - 1.0) ** 2)))

    closed = fit(pts, model="diag", method="lin_auto", norm=norm)
    lm = fit(pts, model="diag", method="lm", norm=norm, max_iter=400)
    assert rms(lm) > 2.0 * rms(closed)  # the case: lm converged, to the wrong place
    with pytest.raises(ConvergenceError):
        lm_diag(pts, norm)
    sym = sym_fit(pts, norm, closed_form=True)
    assert sym is not None and sym.model == "sym"
    assert rms(sym) <= 1.05 * rms(closed)


def test_band_recording_gives_finite_gaps_on_the_effects_own_spread(independent: ModuleType) -> None:
    """Regression: a band recording (closed-form fits) had a NaN feature (no sym fit) whose NaN spread made
    ``gap_with(own_spread=True)`` NaN, so the leading effects were never re-ranked on every seed."""
    rec, norm = _recording(independent, "soft_iron", motion="band", seed=1)
    twin = build_twin(rec.t, rec.raw, sensor="mag", norm=norm, shape_tolerance=0.05)
    base = twin.spread(4)
    assert twin.closed_form
    assert all(np.isfinite(v).all() for v in twin.features_rec.values.values())
    gap, stages = gap_with(twin, base, "soft_iron", 0.05, base.seeds, own_spread=True)
    assert math.isfinite(gap) and gap > 0
    assert stages and all(math.isfinite(g) for g in stages.values())
    # a feature undefined on every twin (NaN spread) costs nothing rather than poisoning the stage
    base.sd["residual_size"] = np.full_like(base.sd["residual_size"], np.nan)
    gap_nan, _ = gap_with(twin, base, "soft_iron", 0.05, base.seeds, own_spread=True)
    assert math.isfinite(gap_nan)


def test_axis_clipped_throughout_is_saturation_without_a_twin(independent: ModuleType) -> None:
    """On a band of tilts a clip level of 0.72 field radii holds one axis at its limit throughout: the points
    are coplanar and no twin can be fitted (this was ``unexplained`` in no time); the read-out alone shows
    the clipping, so the verdict is saturation with the reason. An unclipped recording too short for a twin
    stays ``unexplained``."""
    rec, norm = _recording(independent, "saturation", motion="band", duration=60.0, magnitude=0.72)
    d = diagnose(rec, sensor="mag", norm=norm, quick=True)
    assert d.twin is None  # no twin: the read-out verdict
    assert d.cause == "saturation"
    assert "clipping" in d.reason and "no twin can be fitted" in d.reason
    assert json.dumps(d.to_dict(), default=float)
    short, _ = _recording(independent, "none", duration=0.6)
    assert diagnose(short, sensor="mag", norm=norm, quick=True).cause == "unexplained"


def _band_twin(gen: ModuleType, effect: str, magnitude: float, seed: int) -> Twin:
    rec, norm = _recording(gen, effect, motion="band", duration=60.0, seed=seed, magnitude=magnitude)
    return build_twin(rec.t, rec.raw, sensor="mag", norm=norm, shape_tolerance=0.05)


def test_step_evidence_tells_a_step_from_a_random_walk(independent: ModuleType) -> None:
    """On a band of tilts one split with one shape and two centres removes nearly all of an offset step's
    residual and much less of a random walk's (its largest excursion a quarter of the step)."""
    jump = _band_twin(independent, "hard_iron_jump", 0.28, 1102)
    walk = _band_twin(independent, "bias_drift", 0.07, 1102)
    e_jump = step_evidence(jump.t[jump.sub], jump.raw[jump.sub])
    e_walk = step_evidence(walk.t[walk.sub], walk.raw[walk.sub])
    assert e_jump > 0.9 > 0.7 > e_walk > 0.2
    assert 0.0 <= e_walk < e_jump <= 1.0
    assert step_evidence(np.arange(3.0), np.zeros((3, 3))) == 0.0  # nothing to split


def test_step_against_walk_on_a_band(independent: ModuleType) -> None:
    """The two confusions of a band of tilts, with the shrinks the search gave them: a random walk whose jump
    twin closed more of the gap, and a step whose warm-up twin did. The offset's time course puts the right
    effect first; outside ``STEP_MARGIN``, or against an effect that is no rival, the order stands."""
    seeds = tuple(range(6))
    rivals = frozenset({"bias_drift", "temperature", "disturbance"})
    walk = _band_twin(independent, "bias_drift", 0.07, 1102)
    fits = [_fit("hard_iron_jump", "hard_iron_jump", 0.81), _fit("temperature", "slow_drift", 0.71)]
    fits[0].magnitude, fits[1].magnitude = 0.0212, 0.00135  # the magnitudes the search fitted
    assert [f.name for f in separate_step_from_walk(walk, fits, seeds, rivals)] == ["temperature", "hard_iron_jump"]
    assert separate_step_from_walk(walk, fits, seeds, rivals, margin=0.05)[0].name == "hard_iron_jump"
    assert separate_step_from_walk(walk, fits, seeds, frozenset({"bias_drift"}))[0].name == "hard_iron_jump"
    jump = _band_twin(independent, "hard_iron_jump", 0.28, 1102)
    fits = [_fit("temperature", "slow_drift", 0.89), _fit("hard_iron_jump", "hard_iron_jump", 0.81)]
    fits[0].magnitude, fits[1].magnitude = 0.0254, 1.0
    assert separate_step_from_walk(jump, fits, seeds, rivals)[0].name == "hard_iron_jump"
    assert STEP_MARGIN > CLOSE_MARGIN
