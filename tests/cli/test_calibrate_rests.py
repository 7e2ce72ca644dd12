"""``margcal calibrate`` leaves out a rest in another field (``fit_rescue.rests_apart``), says so, and keeps a rest in
the same field.

A sensor put down on a table with iron in it reads a field other than the one it turned in; its rest, thousands of
readings of one direction, pulled two public recordings' fits 1.9-2.5 deg toward it. Streams of the independent
generator (a tumble, then a rest), seeded.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from conftest import INDEPENDENT

from ros_margcal.cli import main
from ros_margcal.model.calibration_file import load_calibrations

GEN: ModuleType = INDEPENDENT
FIELD = 48e-6


def _csv(tmp_path: Path, shift: float) -> tuple[Path, dict]:
    """40 s of tumble, then 20 s at rest in the tumble's last pose whose readings move by ``shift`` field norms along
    the field (a disturbed table; the norm residual sees that part of a shift); µT."""
    rec = GEN.generate("mag", "tumble", duration_s=40.0, rate_hz=50.0, seed=5, hard_iron_mag=30e-6,
                       symmetric_soft_iron=True)
    t, xyz = rec["t"], rec["xyz"]
    rng = np.random.default_rng(5)
    n = 1000
    radial = (xyz[-1] - rec["truth"]["offset"]) / np.linalg.norm(xyz[-1] - rec["truth"]["offset"])  # the norm sees it
    rest = xyz[-1] + shift * FIELD * radial + 0.1e-6 * rng.standard_normal((n, 3))
    tt = np.r_[t, t[-1] + 0.02 * np.arange(1, n + 1)]
    raw = np.r_[xyz, rest] * 1e6
    path = tmp_path / "rest_mag.csv"
    np.savetxt(path, np.c_[tt, raw], delimiter=",", header="t,x,y,z", comments="", fmt="%.9g")
    return path, rec


def _heading(rec: dict, cal_path: Path) -> float:
    cal = load_calibrations(cal_path)["mag"]
    return float(GEN.heading_p95(cal.matrix * 1e6, cal.offset * 1e-6, rec["truth"], 30.0))


def test_a_rest_in_another_field_is_left_out(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path, rec = _csv(tmp_path, 0.08)
    assert main(["calibrate", str(path), "--unit", "uT", "--out", str(tmp_path / "c.yaml"), "--force"]) == 0
    err = capsys.readouterr().err
    assert "note: left out the rest at 40.0 to 60.0 s" in err and "off the field the sensor turned in" in err, err
    kept = _heading(rec, tmp_path / "c.yaml")
    assert main(["calibrate", str(path), "--unit", "uT", "--out", str(tmp_path / "n.yaml"), "--force",
                 "--no-rescue"]) == 0
    assert "left out" not in capsys.readouterr().err
    whole = _heading(rec, tmp_path / "n.yaml")
    assert kept < 0.5 * whole, (kept, whole)


def test_a_rest_in_the_same_field_is_kept(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path, _ = _csv(tmp_path, 0.0)
    assert main(["calibrate", str(path), "--unit", "uT", "--out", str(tmp_path / "c.yaml")]) == 0
    assert "left out" not in capsys.readouterr().err
