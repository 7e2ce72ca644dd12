"""``margcal calibrate/replay --lat --lon``: the WMM field sets the magnetometer's norm and the heading inclination.

A clean sphere in µT of the model's field at a position (package simulator, seeded); bad positions and dates are
refused on one line (exit 2), never with a traceback.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.cli import calibrate_guard, main
from ros_margcal.cli.calibrate_guard import refusal
from ros_margcal.cli.fit_rescue import config_for, heading_text, inclination_of
from ros_margcal.model.fitting_core import parameter_names
from ros_margcal.model.geomag import field_at
from ros_margcal.recordings import write_csv
from ros_margcal.sim.simulation import directions, random_sensor, simulate

pytest.importorskip("pygeomag")

SEED = 28
WHERE = ("--lat", "-33.9", "--lon", "151.2", "--date", "2026-07-02")  # Sydney: inclination about -64.4 deg
FIELD = field_at(-33.9, 151.2, 0.0, dt.date(2026, 7, 2))


def _csv(tmp_path: Path, norm_t: float, n: int = 1500) -> Path:
    """A clean magnetometer sphere in µT of norm ``norm_t`` with a hard iron of 1-3 field norms."""
    rng = np.random.default_rng(SEED)
    sensor = random_sensor(rng, "mag", norm=norm_t)
    rec = simulate(sensor, directions("uniform", n, rng), noise=0.003, rng=rng, t=np.arange(n) / 50.0)
    rec.raw = rec.raw * 1e6
    path = tmp_path / "mag.csv"
    write_csv(path, rec)
    return path


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_calibrate_takes_the_model_norm(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The fit's norm is the model's intensity in the recording's unit, said with the model, position and date."""
    out_json = tmp_path / "fit.json"
    code, out, err = _run(capsys, "calibrate", str(_csv(tmp_path, FIELD.intensity_t)), "--unit", "uT", *WHERE,
                          "--json", str(out_json))
    assert code == 0, err
    assert "field from WMM2025 at 33.9°S 151.2°E" in out and "(WMM2025 at --lat/--lon, fixed)" in out
    d = json.loads(out_json.read_text())
    assert d["norm"] == pytest.approx(FIELD.intensity_t * 1e6, rel=1e-9)
    assert "reference norm" in d["field_model"] and "(2026.50)" in d["field_model"]  # 2 July: 2026.499


def test_norm_by_hand_wins(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--norm with a position: the hand norm is fitted, the model gives only the inclination (and says so)."""
    out_json = tmp_path / "fit.json"
    code, out, err = _run(capsys, "calibrate", str(_csv(tmp_path, FIELD.intensity_t)), "--unit", "uT", *WHERE,
                          "--norm", "50", "--json", str(out_json))
    assert code == 0, err
    assert json.loads(out_json.read_text())["norm"] == 50.0
    assert "the norm is given by hand" in out


@pytest.mark.parametrize(("extra", "match"), [
    (("--lat", "48.1"), "a position needs --lat and --lon, got --lat 48.1 and --lon None"),
    (("--lat", "95", "--lon", "11.6"), r"--lat must be a latitude in \[-90, 90\] deg, got 95.0"),
    (("--lat", "nan", "--lon", "11.6"), "--lat must be a latitude in"),
    (("--lat", "48.1", "--lon", "500"), r"--lon must be a longitude in \[-180, 360\] deg east, got 500.0"),
    (("--lat", "48.1", "--lon=-inf"), "--lon must be a longitude in"),
    (("--lat", "48.1", "--lon", "11.6", "--date", "2031-01-01"), r"the date 2031.000 is outside WMM2025's validity"),
    (("--lat", "48.1", "--lon", "11.6", "--date", "1.7.2026"), "--date must be YYYY-MM-DD, got '1.7.2026'"),
    (("--date", "2026-07-02"), "--alt and --date need a position"),
])
def test_bad_position_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: tuple[str, ...],
                              match: str) -> None:
    """A position the model cannot take: exit 2 with one line saying why."""
    code, _, err = _run(capsys, "calibrate", str(_csv(tmp_path, 48e-6, n=300)), "--unit", "uT", *extra)
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert __import__("re").search(match, err), err


def test_replay_says_the_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """replay --lat --lon: the calibrator runs with the model norm, and the final state says which field."""
    code, out, err = _run(capsys, "replay", str(_csv(tmp_path, FIELD.intensity_t)), "--sensor", "mag", "--unit", "uT",
                          "-q", *WHERE)
    assert code == 0, err
    assert out.count("field from WMM2025 at 33.9°S 151.2°E") == 2
    assert f"norm: {FIELD.intensity_t * 1e6:.6g} uT" in out


def test_heading_figures_use_the_model_inclination(monkeypatch: pytest.MonkeyPatch) -> None:
    """The guard and the printed heading figures take the configured inclination; 60 deg without a position."""
    cfg = config_for("mag", "uT", latitude_deg=-33.9, longitude_deg=151.2, field_year=2026.5)
    assert inclination_of(cfg) == pytest.approx(FIELD.inclination_deg) and inclination_of(None) == 60.0
    assert inclination_of(config_for("mag", "uT")) == 60.0
    rng = np.random.default_rng(SEED)
    names = parameter_names("sym", scale_free=False)
    cal = random_sensor(rng, "mag", norm=50.0).replace(covariance=np.eye(len(names)) * 1e-8, parameter_names=names)
    assert f"{FIELD.inclination_deg:.3g} deg inclination" in heading_text(cal, inclination_of(cfg))
    assert "60 deg inclination" in heading_text(cal)
    seen: list[float] = []
    monkeypatch.setattr(calibrate_guard, "heading_p95_quantile",
                        lambda c, *, tilt_deg, inclination: seen.append(inclination) or 0.1)
    assert refusal(cal, cfg) == "" and seen == [pytest.approx(FIELD.inclination_deg, abs=0.01)]


@pytest.mark.parametrize(("strength", "noted"), [(1.0, False), (0.9, True)])
def test_a_field_off_the_model_is_noted(tmp_path: Path, capsys: pytest.CaptureFixture[str], strength: float,
                                        noted: bool) -> None:
    """A sphere 10 % weaker than the model (indoors): a note with both radii; none when the field is the model's."""
    code, _, err = _run(capsys, "calibrate", str(_csv(tmp_path, FIELD.intensity_t * strength)), "--unit", "uT", *WHERE)
    assert code == 0, err
    assert ("% below the model's 57 uT" in err) is noted, err
