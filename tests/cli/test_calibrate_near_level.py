"""``margcal calibrate`` on a near-level ring (issue 25 items 2 and 3): held level as the stream holds it.

Fitted free, a flat ring's plain fit does not converge and the prior fit takes cross terms from the ring's wobble: a
real robot's spins in place (LSM303DLHC, 1.6 deg thick) were refused at 21 deg or came 6-18 deg p95 off the level
heading of a 2-D ellipse fit of the ring, where the stream's level fit came within 0.1-0.3 deg. Now the batch tool
holds a ring flatter than ``mag.near_level_tilt_deg`` level, with the stream's figures (``observable.ring_figures``).
The independent generator's car (tests/independent: no code shared with the package), tilt within +-1.5 deg, seeded.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from conftest import INDEPENDENT

from ros_margcal.cli import main
from ros_margcal.model.calibration_file import load_calibrations

GEN: ModuleType = INDEPENDENT


@pytest.fixture(scope="module")
def car(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path]:
    """150 s of a car at 40 Hz, level on average, tilt within +-1.5 deg, no gyro in the file (seed 8)."""
    rec = GEN.generate("mag", "car", duration_s=150.0, rate_hz=40.0, seed=8, tilt_deg=1.5, mount_deg=(0.0, 0.0),
                       symmetric_soft_iron=True, hard_iron_mag=30e-6)
    path = tmp_path_factory.mktemp("car") / "car_mag.csv"
    GEN.write_csv(path, {**rec, "gyro": None})
    return rec, path


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _p95(rec: dict[str, Any], c: Any, tilt: float = 0.0) -> float:
    return float(GEN.heading_p95(c.matrix, c.offset, rec["truth"], tilt_deg=tilt))


def test_a_near_level_ring_is_written_held_level_with_an_honest_level_figure(
        car: tuple[dict[str, Any], Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Written (exit 0), said to be held level; its level bound covers the truth and is within the limit; the 30 deg
    figure is not determined (the vertical is the norm prior's). (Seeds 8-12: 0.21-1.33 deg true for bounds of 1.9-2.2
    deg; the stream on the same data 0.54-1.63 deg for 2.0-2.3.)"""
    rec, path = car
    yaml_out, json_out = tmp_path / "cal.yaml", tmp_path / "fit.json"
    code, out, err = _run(capsys, "calibrate", str(path), "--unit", "T", "-o", str(yaml_out), "--json", str(json_out))
    assert code == 0, out + err
    assert "near-level ring: the readings leave their ring's plane by" in out and "the ring held level" in out, out
    assert "not determined at 30 deg tilt" in out, out
    cal = load_calibrations(yaml_out)["mag"]
    figs = json.loads(json_out.read_text())["near_level"]
    assert figs["heading_p95_tilt30_deg"] is None and "norm prior's" in figs["note"]
    assert _p95(rec, cal) <= figs["heading_p95_level_deg"] <= 2.5, (figs, _p95(rec, cal))


def test_the_level_hold_follows_near_level_tilt_deg(car: tuple[dict[str, Any], Path], tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """``--set mag.near_level_tilt_deg=0`` (a sensor mounted tilted): no level hold, the free prior fit as before."""
    _, path = car
    code, out, err = _run(capsys, "calibrate", str(path), "--unit", "T", "--set", "mag.near_level_tilt_deg=0",
                          "-o", str(tmp_path / "cal.yaml"))
    assert "near-level ring" not in out and "the ring held level" not in out, out
    assert "note: --set" not in err  # an option calibrate uses (CALIBRATE_OPTIONS)
    assert code in (0, 4), out + err
