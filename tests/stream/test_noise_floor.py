"""A noisy magnetometer's residual is its noise, not a misfit (``stream.config.white_noise``, ``residual_limit``).

A QMC5883L whose readings scatter by 4.8 % of its (weak) field per axis was refused by ``margcal calibrate`` for a
6.2 % residual, "one calibration does not explain the recording", where its white noise explains it; the stream's
full fits were held to the same fixed 5 %. The limit is now the wider of ``max_residual`` and 1.5 times the white noise
the readings' second differences show, which a slow disturbance (a magnet moving) does not raise. Streams of the
independent generator, seeded.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from conftest import INDEPENDENT
from hypothesis import given, settings
from hypothesis import strategies as st

from ros_margcal.cli import main
from ros_margcal.cli.fit_rescue import residual_note
from ros_margcal.model.calibration_file import load_calibrations
from ros_margcal.model.fitting import fit
from ros_margcal.stream.config import PipelineConfig, guard_rails, white_noise

GEN: ModuleType = INDEPENDENT
FIELD = 48e-6


def _tumble(seed: int, noise: float, seconds: float = 120.0) -> dict:
    """An independent tumble at 50 Hz, 30 uT hard iron, white noise ``noise`` of the field per axis, no slow noise."""
    return GEN.generate("mag", "tumble", duration_s=seconds, rate_hz=50.0, seed=seed, noise=noise * FIELD,
                        colored_noise=0.0, hard_iron_mag=30e-6, symmetric_soft_iron=True)


@settings(max_examples=20, deadline=None)
@given(noise=st.floats(0.002, 0.08), seed=st.integers(0, 2**16))
def test_white_noise_reads_the_noise_of_a_moving_sensor(noise: float, seed: int) -> None:
    """Within 15 % (plus the motion's share of the second differences, 0.3 % of the field at 50 Hz) on a tumble."""
    rec = _tumble(seed, noise, seconds=20.0)
    got = white_noise(rec["xyz"])
    assert abs(got - noise * FIELD) <= 0.15 * noise * FIELD + 0.003 * FIELD


def test_a_slow_disturbance_or_a_repeating_logger_does_not_raise_it() -> None:
    rec = _tumble(3, 0.005, seconds=60.0)
    base = white_noise(rec["xyz"])
    t = rec["t"][:, None]
    magnet = 0.3 * FIELD * np.sin(2 * np.pi * 0.05 * t) * np.array([[0.6, 0.0, 0.8]])  # 30 % of the field, 20 s period
    assert white_noise(rec["xyz"] + magnet) <= 1.05 * base
    held = np.repeat(rec["xyz"][::3], 3, axis=0)  # each reading logged three times (a logger faster than the sensor)
    assert white_noise(held) <= 1.25 * base  # the sensor's own steps (1.9 x with the repeats counted)
    assert white_noise(rec["xyz"][:2]) == 0.0


def test_a_noisy_sensors_fit_passes_the_residual_limit_a_misfit_does_not() -> None:
    cfg = PipelineConfig.for_sensor("mag", "T")
    noisy = _tumble(7, 0.06)["xyz"]
    cal = fit(noisy, model="sym", method="lm", sensor="mag", unit="T")
    assert cal.stats is not None and cal.stats.rms_relative > cfg.max_residual  # refused before
    assert residual_note(cal, cfg).startswith("residual RMS")
    assert residual_note(cal, cfg, white_noise(noisy)) == ""
    assert "residual" not in guard_rails(cal, cfg, noisy[-500:], None, noise=white_noise(noisy))
    quiet = _tumble(7, 0.002)
    t = quiet["t"][:, None]
    moved = quiet["xyz"] + 0.4 * FIELD * np.sin(2 * np.pi * 0.05 * t) * np.array([[0.6, 0.0, 0.8]])
    bad = fit(moved, model="sym", method="lm", sensor="mag", unit="T")
    assert bad.stats is not None and bad.stats.rms_relative > cfg.max_residual
    note = residual_note(bad, cfg, white_noise(moved))
    assert note.startswith("residual RMS") and "white noise" not in note  # the fixed limit still holds a misfit
    assert guard_rails(bad, cfg, moved[-500:], None, noise=white_noise(moved)).startswith("residual RMS")


def test_margcal_calibrate_writes_a_noisy_sensors_calibration(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """6 % white noise: written, offset within 1 % of the field (it exited 4, "residual RMS 6.03 % > limit 5 %")."""
    rec = _tumble(7, 0.06)
    path = tmp_path / "noisy_mag.csv"
    GEN.write_csv(path, rec)
    out = tmp_path / "cal.yaml"
    code = main(["calibrate", str(path), "--unit", "T", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    (cal,) = load_calibrations(out).values()
    assert np.linalg.norm(cal.offset - rec["truth"]["offset"]) < 0.01 * FIELD
