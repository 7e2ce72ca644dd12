"""``margcal calibrate`` on data a plain fit cannot take: it says why and fits what the data determine.

Recordings from the independent generator (``tests/independent``), in µT, and the real recordings of
``../shared/data/real`` where present.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from ros_margcal.cli import main
from ros_margcal.cli.calibrate_guard import EXIT_REFUSED
from ros_margcal.model.calibration_file import load_calibrations


def _csv(independent: ModuleType, tmp_path: Path, name: str, **kw: object) -> tuple[Path, dict]:
    rec = independent.generate("mag", seed=11, unit="uT", **kw)
    path = tmp_path / f"{name}.csv"
    independent.write_csv(path, rec)
    return path, rec


def _calibrate(path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, str, Path]:
    out = tmp_path / "fit.json"
    rc = main(["calibrate", str(path), "--sensor", "mag", "--model", "sym", "--method", "lm", "--json", str(out), *extra])
    return rc, capsys.readouterr().out, out


def test_a_full_hemisphere_is_fitted_plainly(independent: ModuleType, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Tilts up to 80 degrees determine the model: the plain fit stands, no diagnosis is printed."""
    path, rec = _csv(independent, tmp_path, "hemi", motion="hemisphere", duration_s=120.0)
    rc, text, out = _calibrate(path, tmp_path, capsys)
    assert rc == 0 and "requested fit" not in text
    d = json.loads(out.read_text())
    assert d["method"] == "lm"
    assert np.linalg.norm(np.array(d["offset"]) - rec["truth"]["offset"]) < 0.01 * rec["truth"]["norm"]


def test_partial_coverage_is_fitted_with_the_prior_and_says_which_parameters(
        independent: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A ground robot (yaw, 5 degrees of tilt): lm does not converge; the prior fit names updated and prior terms."""
    path, rec = _csv(independent, tmp_path, "ground", motion="ground", duration_s=120.0)
    rc, text, out = _calibrate(path, tmp_path, capsys)
    assert rc == 0
    assert "requested fit: lm did not converge" in text and "partial coverage" in text
    assert "updated by the data:" in text and "from the prior:" in text and "predicted heading error p95" in text
    assert "95 % bound; typical" in text
    d = json.loads(out.read_text())
    assert d["diagnosis"] == "partial" and d["from_prior"] and d["updated"]
    assert {"b_x", "b_y"} <= set(d["updated"])
    truth = rec["truth"]
    assert np.linalg.norm(np.array(d["offset"])[:2] - truth["offset"][:2]) < 0.03 * truth["norm"]


def test_a_static_recording_is_refused_with_the_reason(independent: ModuleType, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Static: only the norm is determined; nothing is fitted or written, exit code 3."""
    path, _ = _csv(independent, tmp_path, "static", motion="static", duration_s=60.0)
    rc, text, out = _calibrate(path, tmp_path, capsys)
    assert rc == 3
    assert "static recording" in text and "determine the field norm only" in text
    assert not out.exists()


def test_a_mid_way_hard_iron_change_gives_two_calibrations(independent: ModuleType, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """A hard-iron jump at half time: the change is located and each side fitted to within 1 % of its truth."""
    path, rec = _csv(independent, tmp_path, "jump", motion="tumble", duration_s=120.0, effect="hard_iron_jump",
                     magnitude=0.5)
    yaml_out = tmp_path / "cal.yaml"
    rc, text, out = _calibrate(path, tmp_path, capsys, "-o", str(yaml_out))
    assert rc == 0
    assert "the offset changed at t = " in text and "2 calibrations" in text
    parts = json.loads(out.read_text())["calibrations"]
    assert [p["diagnosis"] for p in parts] == ["change", "change"]
    truth = rec["truth"]
    for part, want in zip(parts, (truth["offset"], truth["offset_after"]), strict=True):
        assert np.linalg.norm(np.array(part["offset"]) - want) < 0.01 * truth["norm"]
    cals = load_calibrations(yaml_out)
    assert set(cals) == {"mag", "mag_1"}
    np.testing.assert_allclose(cals["mag"].offset, parts[1]["offset"])


def test_a_magnet_attached_and_removed_gives_three_calibrations(independent: ModuleType, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Offsets A, B, A (a magnet attached at 60 s, removed at 120 s): no single split explains the recording, one
    of its first two thirds does, and the stretch after it splits in turn; each of the three stretches is fitted to
    within 1 % of its truth and written (before: one ellipsoid, refused on its residual, nothing written)."""
    rec = independent.generate("mag", seed=11, unit="uT", motion="tumble", duration_s=180.0,
                               effect="hard_iron_jump", magnitude=0.5, t_jump=60.0)
    truth = rec["truth"]
    rec["xyz"][rec["t"] >= 120.0] -= truth["offset_after"] - truth["offset"]  # the magnet taken off again
    path = tmp_path / "aba.csv"
    independent.write_csv(path, rec)
    rc, text, out = _calibrate(path, tmp_path, capsys)
    assert rc == 0, text
    assert "3 calibrations" in text
    parts = json.loads(out.read_text())["calibrations"]
    for part, want in zip(parts, (truth["offset"], truth["offset_after"], truth["offset"]), strict=True):
        assert np.linalg.norm(np.array(part["offset"]) - want) < 0.01 * truth["norm"]


def test_a_rest_elsewhere_at_the_end_of_a_stretch_is_left_out(independent: ModuleType, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A hard-iron step at 60 s, then 120 s still where the field is 30 % weaker (a table with iron in it): no change
    search splits a still side off, and the second stretch's fit with it was refused on its residual (nothing
    written). Now that stretch is fitted without the still run at its end, which is said to be static."""
    rec = independent.generate("mag", seed=11, unit="uT", motion="tumble", duration_s=120.0,
                               effect="hard_iron_jump", magnitude=0.5, t_jump=60.0)
    truth = rec["truth"]
    rng = np.random.default_rng(3)
    n_rest = 6000  # 120 s at 50 Hz
    last = rec["xyz"][-1]
    rest = truth["offset_after"] + 0.7 * (last - truth["offset_after"]) + 0.05 * rng.standard_normal((n_rest, 3))
    rec["t"] = np.r_[rec["t"], rec["t"][-1] + 0.02 * np.arange(1, n_rest + 1)]
    rec["xyz"] = np.r_[rec["xyz"], rest]
    rec["gyro"] = None
    path = tmp_path / "rest.csv"
    independent.write_csv(path, rec)
    rc, text, out = _calibrate(path, tmp_path, capsys)
    assert rc == 0, text
    assert "2 calibrations and 1 static stretch(es)" in text and "static: no calibration (the fit with it was refused" in text
    parts = [p for p in json.loads(out.read_text())["calibrations"] if p.get("offset") is not None]
    for part, want in zip(parts, (truth["offset"], truth["offset_after"]), strict=True):
        assert np.linalg.norm(np.array(part["offset"]) - want) < 0.01 * truth["norm"]


def test_no_rescue_keeps_the_error(independent: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--no-rescue: the fit's own error, exit code 2."""
    path, _ = _csv(independent, tmp_path, "static", motion="static", duration_s=30.0)
    rc = main(["calibrate", str(path), "--sensor", "mag", "--model", "sym", "--method", "lm", "--no-rescue"])
    assert rc == 2
    assert "did not converge" in capsys.readouterr().err



def test_real_hemisphere_is_fitted_with_the_prior(real_recording: Callable[[str], Path], tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """The real one-hemisphere LSM9DS1 set: lm does not converge; the prior fit reports and stays plausible."""
    path = real_recording("hamagure_lsm9ds1_hemisphere_mag.csv")
    rc, text, out = _calibrate(path, tmp_path, capsys, "--unit", "gauss")
    assert rc == 0 and "partial coverage" in text
    d = json.loads(out.read_text())
    assert d["method"] == "map" and d["stats"]["rms_relative"] < 0.02


def test_real_static_recording_is_refused(real_recording: Callable[[str], Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The 10-minute static HMC5883L log: refused with the reason."""
    rc, text, _ = _calibrate(real_recording("sunsided_hmc5883l_static_10min_mag.csv"), tmp_path, capsys, "--unit", "gauss")
    assert rc == 3 and "static recording" in text


def test_real_magnet_taken_off_at_rest_is_left_out(real_recording: Callable[[str], Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """BROAD 36 (a magnet 5 cm away while it turns, taken off for a rest at the end; a rest at the start where the
    field is 12 % weaker): both stretches were refused on their residual (7.2 and 6.0 %: nothing written); without the
    rests at their ends they fit within 2.3 % and are written."""
    rc, text, out = _calibrate(real_recording("broad_36_disturbed_attached_magnet_5cm_mag.csv"), tmp_path, capsys,
                               "--unit", "uT")
    assert rc == 0, text
    assert "2 calibrations and 2 static stretch(es)" in text
    fits = [p for p in json.loads(out.read_text())["calibrations"] if p.get("offset") is not None]
    assert len(fits) == 2 and all(p["stats"]["rms_relative"] < 0.025 for p in fits)


def test_real_attached_magnet_is_located(real_recording: Callable[[str], Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """BROAD 32 (a magnet 1 cm away in mid-recording): the change is located and several calibrations fitted; the
    first stretch's prior fit is implausible, so nothing is written without --force (exit 4), and --force writes
    every part with the reason recorded."""
    path = real_recording("broad_32_disturbed_attached_magnet_1cm_mag.csv")
    rc, text, out = _calibrate(path, tmp_path, capsys, "--unit", "uT")
    assert rc == 4 and "the offset changed at t = " in text and not out.exists()
    rc, text, out = _calibrate(path, tmp_path, capsys, "--unit", "uT", "--force")
    assert rc == 0
    parts = json.loads(out.read_text())["calibrations"]
    assert any("forced" in p for p in parts)
    assert len(parts) >= 2
    # the magnet phase: the offset of the windowed sphere fits, about 58 uT along z
    assert any(abs(p["offset"][2] - 58.0) < 5.0 for p in parts)


def test_motion_in_accelerometer_data_keeps_the_plain_fit_past_the_guard_only_forced(
        independent: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """All samples of a moving accelerometer: a high residual but no offset change, so the plain fit stands; its
    residual is beyond the stream's ``max_residual``, so it is refused (exit 4, nothing written) unless forced."""
    rec = independent.generate("accel", "rest_and_move", duration_s=60.0, seed=3)
    path = tmp_path / "acc.csv"
    independent.write_csv(path, rec)
    out = tmp_path / "fit.json"
    rc = main(["calibrate", str(path), "--sensor", "accel", "--samples", "all", "--json", str(out)])
    captured = capsys.readouterr()
    assert rc == EXIT_REFUSED and not out.exists()
    assert "no offset change located" in captured.err and "requested fit" not in captured.out
    assert "refused by the guard rails: residual RMS" in captured.err and "record still poses" in captured.err
    rc = main(["calibrate", str(path), "--sensor", "accel", "--samples", "all", "--json", str(out), "--force"])
    assert rc == 0
    assert json.loads(out.read_text())["method"].startswith("lm forced past the guard rails: residual RMS")
