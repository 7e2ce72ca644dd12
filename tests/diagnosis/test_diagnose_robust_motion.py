"""Issue 27 item 4: fast motion does not read as noise, the withheld part tests the named cause, the summary's
ranking is in shrink order and says nothing of temperature without a temperature column, one progress bar."""

from __future__ import annotations

import importlib.util
import io
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from scipy.special import sph_harm_y

from ros_margcal.diagnosis import EffectFit, build_twin, diagnose_holdout, summary
from ros_margcal.diagnosis.core import Diagnosis
from ros_margcal.diagnosis.progress import HOLDOUT_STEPS, CommandProgress, command_steps, diagnosis_steps
from ros_margcal.diagnosis.ranking import applicable_effects
from ros_margcal.diagnosis.stages import residual_noise, rest_noise, sh_basis
from ros_margcal.diagnosis.twin import FAST_MOTION_MIN_STEP_DEG, _white_noise
from ros_margcal.model.errors import ConfigError
from ros_margcal.recordings.recording import Recording

WHITE = 0.1e-6 / 48e-6  # the generator's white noise, fraction of its 48 uT field


@pytest.fixture(scope="module")
def rough() -> ModuleType:
    """tests/independent/rough_motion.py (loaded by path, as the generator is)."""
    path = Path(__file__).resolve().parents[1] / "independent" / "rough_motion.py"
    spec = importlib.util.spec_from_file_location("margcal_test_rough_motion", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _rough_twin(independent: ModuleType, rough: ModuleType, speedup: float, shuffle: int):
    rec = rough.generate_rough(independent, "mag", "tumble", 20.0, 50.0, 5, speedup=speedup, shuffle=shuffle)
    twin = build_twin(rec["t"], rec["xyz"], sensor="mag", norm=float(rec["truth"]["norm"]), n_fit=1000)
    return rec, twin


def test_residual_noise_ignores_the_motion_second_differences_do_not(independent: ModuleType,
                                                                      rough: ModuleType) -> None:
    """On a vibrating platform (about 5 degrees per sample) second differences of the readings are many times
    the noise; first differences of the fit's residual stay at the generator's white noise."""
    rec, twin = _rough_twin(independent, rough, 2.0, 2)
    assert rec["meta"]["rough"]["median_step_deg"] > 3.0
    from_readings = rest_noise(rec["xyz"]) / twin.truth.raw_radius
    assert from_readings > 5 * WHITE, f"{from_readings:.4g} vs white {WHITE:.4g}"
    r = np.linalg.norm(twin.best.apply(rec["xyz"]), axis=1) / twin.best.norm - 1.0
    assert residual_noise(r) == pytest.approx(WHITE, rel=0.25)


def test_fast_motion_twin_takes_the_residual_noise_and_skips_rest_noise(independent: ModuleType,
                                                                        rough: ModuleType) -> None:
    """The twin of a rough recording gets the white noise, not the motion, and says why its rest-noise stage
    is left out; a smooth recording of the same generator keeps the stage."""
    _, twin = _rough_twin(independent, rough, 2.0, 2)
    assert "fast motion" in twin.skipped.get("rest_noise", "")
    assert "rest_noise" not in twin.features_rec.values
    assert twin.noise == pytest.approx(WHITE, rel=0.25)
    _, smooth = _rough_twin(independent, rough, 1.0, 1)
    assert "rest_noise" not in smooth.skipped
    assert smooth.noise == pytest.approx(WHITE, rel=0.25)


def test_residual_noise_of_white_noise() -> None:
    """Trimmed first differences give the std of white noise (seeded: within 5 %)."""
    r = np.random.default_rng(3).normal(0.0, 0.004, 20000)
    assert residual_noise(r) == pytest.approx(0.004, rel=0.05)
    assert residual_noise(r[:3]) == 0.0


def _fit(name: str, shrink: float, magnitude: float = 0.002) -> EffectFit:
    return EffectFit(name=name, group="slow_drift" if name in ("temperature", "bias_drift") else name,
                     magnitude=magnitude, unit="fraction of norm per K" if name == "temperature" else "x",
                     gap_before=5.0, gap_after=5.0 * (1 - shrink), shrink=shrink, stages_after={}, curve=[], n_seeds=6)


def _diagnosis(effects: list[EffectFit], *, has_temperature: bool) -> Diagnosis:
    best = effects[0]
    return Diagnosis(where="residual_time", cause="slow_drift", cause_effects=["bias_drift", "temperature"],
                     shrink=best.shrink, gap_before=5.0, gap_after=best.gap_after, stages_before={"residual_time": 9.0},
                     stages_after={}, effects=effects, equivalent=[], unobservable=[], null_gaps=[1.0], sensor="mag",
                     n_samples=3000, n_fit=3000, noise=0.002, seconds=1.0, has_temperature=has_temperature)


def test_summary_ranks_by_shrink_and_says_why_the_named_one_leads() -> None:
    """The named effect (decided on separating features) leads the diagnosis but the ranking line is in
    shrink order, and a line says the named one was put before a larger shrink."""
    d = _diagnosis([_fit("temperature", 0.70), _fit("bias_drift", 0.74), _fit("hard_iron_jump", 0.20)],
                   has_temperature=False)
    text = summary(d)
    line = next(x for x in text.splitlines() if x.startswith("ranking"))
    assert line.index("bias_drift 74 %") < line.index("warm-up drift 70 %") < line.index("hard_iron_jump 20 %")
    assert "named warm-up drift before bias_drift (70.0 % against 74.0 %)" in text


def test_no_temperature_wording_without_a_temperature_column() -> None:
    """Without a temperature column the temperature effect is a warm-up drift of the offset, in % of the field,
    never a coefficient per K; with the column it keeps its name and unit."""
    effects = [_fit("temperature", 0.8, 0.002), _fit("bias_drift", 0.5)]
    text = summary(_diagnosis(effects, has_temperature=False))
    assert "temperature" not in text
    assert "per K" not in text
    assert "drifts by about 3 % of the field" in text  # 0.002 per K over the synthesised 15 K warm-up
    text = summary(_diagnosis(effects, has_temperature=True))
    assert "temperature at 0.002 fraction of norm per K" in text


def test_holdout_fits_the_named_cause(independent: ModuleType) -> None:
    """The withheld-part check fits the effect it is given on the first part (not the first part's own top
    effect) and reports progress in ``HOLDOUT_STEPS`` steps; an unknown effect is refused up front."""
    g = independent.generate("mag", "tumble", 24.0, 50.0, 8, effect="bias_drift")
    rec = Recording(t=g["t"], raw=g["xyz"], sensor="mag")
    calls: list[str] = []
    out = diagnose_holdout(rec, split=0.5, effect="hard_iron_jump", sensor="mag", norm=float(g["truth"]["norm"]),
                           n_fit=800, n_seeds=1, n_spread=2, quick=True, progress=lambda d, t, name: calls.append(name))
    assert out["effect"] == "hard_iron_jump" and out["effect_fit"].name == "hard_iron_jump"
    assert out["fit"] is None
    assert len(calls) == HOLDOUT_STEPS
    assert math.isfinite(out["gap_before"]) and math.isfinite(out["gap_after"])
    with pytest.raises(ConfigError, match="unknown effect 'warp'"):
        diagnose_holdout(rec, split=0.5, effect="warp", sensor="mag")


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_command_progress_counts_every_step_and_draws_only_on_a_terminal() -> None:
    """The bar's total is the diagnosis' steps, one for the retraining and the withheld part's; it draws on a
    terminal and stays silent otherwise."""
    n_eff = len(applicable_effects("mag")[0])
    assert diagnosis_steps("mag") == 3 + n_eff
    assert command_steps("mag", downstream=True, holdout=True) == 3 + n_eff + 1 + HOLDOUT_STEPS
    tty, pipe = _Tty(), io.StringIO()
    for stream in (tty, pipe):
        bar = CommandProgress(4, file=stream)
        for k in range(4):
            bar(k + 1, 4, f"step {k}")
        assert bar.done == 4 and bar.seconds >= 0.0 and bar.bar.n == (4 if stream is tty else 0)
        bar.close()
    assert "diagnose:" in tty.getvalue() and "/4" in tty.getvalue()  # redrawn at most every 0.1 s
    assert pipe.getvalue() == ""


def test_slow_motion_is_never_taken_for_the_noise() -> None:
    """Readings whose second differences exceed the residual's noise (here: a jittered track) count as fast
    motion only when the sensor turns by at least ``FAST_MOTION_MIN_STEP_DEG`` per sample."""
    rng = np.random.default_rng(11)
    dirs = rng.normal(size=(4000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    noisy = dirs * (1.0 + 0.002 * rng.normal(size=(4000, 1)))  # radial noise 0.2 %, the track itself jumps
    below, why_below = _white_noise(noisy, noisy, 1.0, 1.0, 0.5 * FAST_MOTION_MIN_STEP_DEG)
    above, why_above = _white_noise(noisy, noisy, 1.0, 1.0, 3.0)
    assert why_below == "" and below > 0.1  # second differences of jumping directions: the motion
    assert "fast motion" in why_above and above == pytest.approx(0.002, rel=0.1)


def test_sh_basis_is_the_per_degree_reference() -> None:
    """The one-call harmonics equal the per-(l, m) ``sph_harm_y`` calls they replace, bit for bit."""
    rng = np.random.default_rng(4)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    theta, phi = np.arccos(np.clip(d[:, 2], -1.0, 1.0)), np.arctan2(d[:, 1], d[:, 0])
    cols = []
    for ell in range(5):
        for m in range(-ell, ell + 1):
            y = sph_harm_y(ell, abs(m), theta, phi)
            cols.append(y.real if m == 0 else math.sqrt(2.0) * (-1) ** m * (y.real if m > 0 else y.imag))
    assert np.array_equal(sh_basis(d), np.column_stack(cols))
