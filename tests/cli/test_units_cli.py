"""``--unit`` means the recording's raw unit in every command: checked, inferred, refused with the unit that fits.

Recordings from the package simulator (seeded); the sizes are checked in ``cli/raw_units``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.cli import main
from ros_margcal.cli.raw_units import fitting_units, infer_sensor, resolve_unit, sizes
from ros_margcal.model.errors import ConfigError
from ros_margcal.recordings import write_bag, write_csv
from ros_margcal.recordings.recording import Recording, drop_zero_rows
from ros_margcal.sim.simulation import directions, random_sensor, simulate

SEED = 25


def _sphere(scale: float = 1e6, n: int = 2000, sensor: str = "mag", seed: int = SEED) -> Recording:
    """A clean sphere of ``sensor`` (simulated in SI), its readings times ``scale`` (1e6: tesla -> µT)."""
    rng = np.random.default_rng(seed)
    rec = simulate(random_sensor(rng, sensor), directions("uniform", n, rng), noise=0.003, rng=rng,
                   t=np.arange(n) / 50.0)
    rec.raw = rec.raw * scale
    return rec


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.mark.parametrize("command", [["calibrate"], ["replay", "-q"], ["diagnose", "--no-validator"]])
def test_a_wrong_unit_is_refused_with_the_unit_that_fits(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                          command: list[str]) -> None:
    """µT readings given as gauss: every command exits 2 on one line naming uT, and writes nothing."""
    path = write_csv(tmp_path / "field_mag.csv", _sphere())
    out = tmp_path / "out"
    extra = ["--out", str(out)] if command[0] == "diagnose" else ["--json", str(out)]
    code, _, err = _run(capsys, command[0], str(path), "--unit", "gauss", *command[1:], *extra)
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.startswith("margcal ")]
    assert len(lines) == 1 and "in gauss is not an Earth field" in lines[0] and "--unit uT?" in lines[0], err
    assert "Traceback" not in err and not out.exists()


@pytest.mark.parametrize("command", [["calibrate"], ["replay", "-q"], ["diagnose", "--no-validator"]])
@pytest.mark.parametrize(("unit", "said"), [("m/s^2", "is an accelerometer unit, not a magnetometer's"),
                                            ("g", "not a magnetometer's ('gauss'?)"), ("mg", "not a magnetometer's ('mG'?)"),
                                            ("", "names no unit"), (" ", "names no unit")])
def test_the_other_sensors_unit_or_none_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   command: list[str], unit: str, said: str) -> None:
    """A magnetometer's readings given an accelerometer's unit (or an empty one) were taken as counts: every check
    off, and the unit written into the calibration. Now every command exits 2 on one line, writing nothing."""
    path = write_csv(tmp_path / "field_mag.csv", _sphere())
    out = tmp_path / "out"
    extra = ["--out", str(out)] if command[0] == "diagnose" else ["--json", str(out)]
    code, _, err = _run(capsys, command[0], str(path), "--unit", unit, *command[1:], *extra)
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.startswith("margcal ")]
    assert len(lines) == 1 and said in lines[0], err
    assert "Traceback" not in err and not out.exists()


def test_an_accelerometer_given_a_magnetometers_unit_is_refused(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    path = write_csv(tmp_path / "poses_acc.csv", _sphere(1.0, sensor="accel"))
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "uT", "--samples", "all")
    assert code == 2 and "'uT' is a magnetometer unit, not an accelerometer's" in err, err


def test_an_accelerometer_in_m_s2_given_as_g_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """m/s^2 readings given as g: "9.8 in g is not gravity; 9.8 m/s^2 is"."""
    path = write_csv(tmp_path / "poses_acc.csv", _sphere(1.0, sensor="accel"))
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "g", "--samples", "all")
    assert code == 2 and "in g is not gravity" in err and "--unit m/s^2?" in err, err


def test_without_unit_calibrate_infers_it_and_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No --unit: the µT sphere is read as uT with a warning, fitted, and the calibration carries the unit."""
    path = write_csv(tmp_path / "field_mag.csv", _sphere())
    out = tmp_path / "fit.json"
    code, _, err = _run(capsys, "calibrate", str(path), "--json", str(out))
    assert code == 0, err
    assert "no --unit" in err and "read as uT" in err
    fit = json.loads(out.read_text())
    assert fit["unit"] == "uT" and 20.0 < fit["norm"] < 70.0


def test_without_unit_replay_infers_it_instead_of_assuming_tesla(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """replay used to assume tesla for a CSV: it now infers gauss from gauss-sized readings, as calibrate does."""
    path = write_csv(tmp_path / "field_mag.csv", _sphere(1e4, n=500))
    out = tmp_path / "replay.json"
    code, _, err = _run(capsys, "replay", str(path), "-q", "--json", str(out))
    assert code == 0, err
    assert "read as gauss" in err


def test_a_bag_in_the_wrong_unit_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A MagneticField bag is tesla by REP-145; µT numbers in it are refused, naming --unit uT."""
    rec = _sphere(n=300)
    rec.unit = "T"
    path = write_bag(tmp_path / "wrong.mcap", {"imu/mag": rec})
    code, _, err = _run(capsys, "replay", str(path), "-q")
    assert code == 2 and "REP-145" in err and "--unit uT?" in err, err
    code, _, err = _run(capsys, "replay", str(path), "-q", "--unit", "uT", "--status-every", "0")
    assert code == 0, err


def test_inference_units_of_each_size() -> None:
    """Each unit's Earth field or gravity maps to that unit alone; an implausible size to none."""
    assert fitting_units("mag", (50e-6,)) == ["T"]
    assert fitting_units("mag", (0.05,)) == ["mT"]
    assert fitting_units("mag", (0.5,)) == ["gauss"]
    assert fitting_units("mag", (500.0,)) == ["mG"]
    assert fitting_units("mag", (50_000.0,)) == ["nT"]
    assert fitting_units("accel", (9.8,)) == ["m/s^2"]
    assert fitting_units("accel", (1000.0,)) == ["mg"]
    assert fitting_units("accel", (32768.0,)) == []


def test_counts_are_not_checked_and_an_unknown_size_is_refused_without_unit() -> None:
    """Raw counts of 32768 (an unsigned ADC): refused without --unit, naming --unit counts; taken with it."""
    pts = _sphere(1.0, sensor="accel").raw * 1000.0 + 32768.0
    with pytest.raises(ConfigError, match="--unit counts"):
        resolve_unit("accel", pts, None)
    assert resolve_unit("accel", pts, "counts") == "counts"


def test_the_sensor_is_inferred_from_the_size_or_refused() -> None:
    """A field in µT is a magnetometer, 9.8 m/s^2 an accelerometer; an unknown size asks for --sensor."""
    assert infer_sensor(_sphere().raw, None, "", None) == "mag"
    assert infer_sensor(_sphere(1.0, sensor="accel").raw, None, "", None) == "accel"
    with pytest.raises(ConfigError, match="--sensor mag or --sensor accel"):
        infer_sensor(_sphere(1e12).raw, None, "", None)


def test_a_file_without_sensor_in_its_name_is_calibrated_as_the_sensor_it_holds(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """'data.csv' holding a µT field: calibrate says it reads it as a magnetometer and writes sensor 'mag'."""
    path = write_csv(tmp_path / "data.csv", _sphere())
    out = tmp_path / "fit.json"
    code, _, err = _run(capsys, "calibrate", str(path), "--json", str(out))
    assert code == 0 and "read as --sensor mag" in err, err
    assert json.loads(out.read_text())["sensor"] == "mag"


def test_zero_rows_are_dropped_and_counted_in_every_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """239 all-zero rows: calibrate drops and counts them (also in its JSON); replay and diagnose say so too."""
    rec = _sphere()
    rec.raw[100:339] = 0.0
    kept, zeros = drop_zero_rows(rec)
    assert zeros == 239 and len(kept) == len(rec) - 239
    path = write_csv(tmp_path / "zeros_mag.csv", rec)
    out = tmp_path / "fit.json"
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "uT", "--json", str(out))
    assert code == 0 and "dropped 239 all-zero row(s)" in err, err
    fit = json.loads(out.read_text())
    assert fit["dropped"]["zero"] == 239 and fit["stats"]["n_points"] == len(rec) - 239
    code, _, err = _run(capsys, "replay", str(path), "--unit", "uT", "-q")
    assert code == 0 and "dropped 239 all-zero row(s)" in err, err
    code, _, err = _run(capsys, "diagnose", str(path), "--unit", "gauss", "--out", str(tmp_path / "d"))
    assert code == 2 and "dropped 239 all-zero row(s)" in err, err  # counted before the unit is refused


@pytest.mark.parametrize("command", ["calibrate", "replay", "diagnose"])
def test_a_recording_of_zero_rows_only_is_refused_on_one_line(
        command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Every row all-zero: exit 2 saying so (calibrate and diagnose said "points needs at least 1 rows, got 0")."""
    rec = _sphere()
    rec.raw[:] = 0.0
    path = write_csv(tmp_path / "zeros_mag.csv", rec)
    code, _, err = _run(capsys, command, str(path), "--unit", "uT")
    assert code == 2, err
    assert "dropped 2000 all-zero row(s) of 2000" in err and "every row of" in err and "is all-zero" in err, err
    assert "at least 1 rows" not in err and "Traceback" not in err, err


def test_sizes_of_a_static_recording_are_its_median_norm() -> None:
    """A still sensor gives one size, its median norm; a spike does not make it turn."""
    raw = np.tile([20.0, -5.0, 40.0], (500, 1)) + np.random.default_rng(SEED).normal(scale=0.1, size=(500, 3))
    raw[250] = [900.0, 0.0, 0.0]
    (size,) = sizes(raw)
    assert size == pytest.approx(np.linalg.norm([20.0, -5.0, 40.0]), rel=0.01)
