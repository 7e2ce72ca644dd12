"""``margcal calibrate`` never writes what the stream would refuse; ``--force`` writes it, marked; provenance is right.

Recordings from the package simulator and the independent generator, seeded.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from ros_margcal.cli import main
from ros_margcal.cli.calibrate_guard import EXIT_REFUSED, refusal
from ros_margcal.cli.fit_rescue import config_for, heading_text
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.calibration_file import load_calibrations
from ros_margcal.model.fitting_core import parameter_names
from ros_margcal.recordings import write_csv
from ros_margcal.recordings.recording import Recording
from ros_margcal.sim.simulation import directions, random_sensor, simulate

SEED = 25


def _sphere(n: int = 2000) -> Recording:
    """A clean magnetometer sphere in µT with a hard iron of 1-3 field norms."""
    rng = np.random.default_rng(SEED)
    rec = simulate(random_sensor(rng, "mag"), directions("uniform", n, rng), noise=0.003, rng=rng, t=np.arange(n) / 50.0)
    rec.raw = rec.raw * 1e6
    return rec


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_an_offset_beyond_the_guard_is_not_written_without_force(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """An offset limit below the sensor's hard iron (--set): exit 4, the reason, no file; --force writes it marked."""
    path = write_csv(tmp_path / "iron_mag.csv", _sphere())
    yaml_out, json_out = tmp_path / "cal.yaml", tmp_path / "fit.json"
    limits = ["--set", "max_offset_ratio=0.01", "--set", "max_offset=1e-6", "--unit", "uT"]
    code, _, err = _run(capsys, "calibrate", str(path), *limits, "-o", str(yaml_out), "--json", str(json_out))
    assert code == EXIT_REFUSED, err
    assert "refused by the guard rails: offset" in err and "--force" in err
    assert not yaml_out.exists() and not json_out.exists()
    code, _, err = _run(capsys, "calibrate", str(path), *limits, "-o", str(yaml_out), "--json", str(json_out), "--force")
    assert code == 0 and "written past the guard rails" in err, err
    cal = load_calibrations(yaml_out)["mag"]
    assert "forced past the guard rails: offset" in cal.method
    assert json.loads(json_out.read_text())["forced"].startswith("offset")


def test_the_guard_refuses_gains_far_from_one_and_an_implausible_norm() -> None:
    """``refusal`` on hand-made calibrations: gains 0.3/1.9 and a 200 µT field are refused, a good one passes."""
    cfg = config_for("mag", "uT")
    good = Calibration(np.zeros(3), np.eye(3), norm=48.0, sensor="mag", unit="uT")
    assert refusal(good, cfg) == ""
    squashed = Calibration(np.zeros(3), np.diag([0.5, 0.5, 3.0]), norm=48.0, sensor="mag", unit="uT")
    assert "axis gains" in refusal(squashed, cfg)
    strong = Calibration(np.zeros(3), np.eye(3), norm=200.0, sensor="mag", unit="uT")
    assert "field norm 200 uT outside" in refusal(strong, cfg)


def test_a_predicted_heading_error_above_the_limit_is_refused(independent: ModuleType, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A ground robot's prior fit passes at the default limit and is refused at a limit below its heading figure."""
    rec = independent.generate("mag", seed=11, unit="uT", motion="ground", duration_s=120.0)
    path = tmp_path / "ground_mag.csv"
    independent.write_csv(path, rec)
    code, out, err = _run(capsys, "calibrate", str(path))
    assert code == 0 and "partial coverage" in out, err
    code, out, err = _run(capsys, "calibrate", str(path), "--set", "max_heading_p95_deg=0.05", "-o", str(tmp_path / "c.yaml"))
    assert code == EXIT_REFUSED and "predicted heading error p95" in err and "max_heading_p95_deg" in err, err
    assert not (tmp_path / "c.yaml").exists()


def test_three_accelerometer_poses_do_not_give_a_calibration(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Three still poses cannot determine an accelerometer: no calibration with exit 0 (it used to write 8.03 m/s^2)."""
    rng = np.random.default_rng(SEED)
    truth = random_sensor(rng, "accel")
    poses = np.repeat(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), 200, axis=0)
    rec = simulate(truth, poses, noise=0.002, rng=rng, t=np.arange(600) / 50.0)
    path = write_csv(tmp_path / "three_acc.csv", rec)
    out = tmp_path / "acc.yaml"
    code, text, err = _run(capsys, "calibrate", str(path), "--unit", "m/s^2", "--samples", "all", "-o", str(out))
    assert code == EXIT_REFUSED and "refused by the guard rails" in err, text + err
    assert not out.exists()


def test_the_norm_given_by_the_user_is_printed_as_given(independent: ModuleType, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """--norm on a prior fit is "given by --norm", not "the prior's"; without it the prior fit names its source."""
    rec = independent.generate("mag", seed=11, unit="uT", motion="ground", duration_s=120.0)
    path = tmp_path / "ground_mag.csv"
    independent.write_csv(path, rec)
    code, out, err = _run(capsys, "calibrate", str(path), "--norm", "48")
    assert code == 0, err
    assert "(given by --norm, fixed)" in out and "the prior's" not in out
    code, out, err = _run(capsys, "calibrate", str(path))
    assert code == 0 and "(the readings' sphere radius, fixed)" in out, err


def test_an_undetermined_heading_figure_is_said_not_printed_as_millions_of_degrees() -> None:
    """A covariance that leaves the horizontal terms free: "not determined", never "9845001.40 deg"; refused."""
    names = parameter_names("sym", scale_free=False)
    cov = np.diag(np.r_[np.full(3, 2500.0), np.full(6, 1.0)])  # offsets +-50 uT: about a field norm
    cal = Calibration(np.zeros(3), np.eye(3), norm=48.0, model="sym", method="map", sensor="mag", unit="uT",
                      covariance=cov, parameter_names=names)
    assert "not determined" in heading_text(cal)
    assert "not determined" in refusal(cal, config_for("mag", "uT"))


def test_a_residual_beyond_the_streams_limit_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The clean sphere passes; a 3 % residual limit below what its 4 % noise leaves (--set max_residual=0.03, as
    the stream would refuse it): exit 4 with the residual named and nothing written, --force writes it marked."""
    rng = np.random.default_rng(SEED + 1)
    rec = simulate(random_sensor(rng, "mag"), directions("uniform", 2000, rng), noise=0.04, rng=rng,
                   t=np.arange(2000) / 50.0)
    rec.raw = rec.raw * 1e6
    path = write_csv(tmp_path / "noisy_mag.csv", rec)
    out = tmp_path / "cal.yaml"
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "uT", "-o", str(out))
    assert code == 0 and out.exists(), err  # 4 % is within the default 5 %
    out.unlink()
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "uT", "--set", "max_residual=0.03", "-o", str(out))
    assert code == EXIT_REFUSED and not out.exists(), err
    assert "refused by the guard rails: residual RMS" in err and "> limit 3 %: one calibration does not explain" in err
    assert "(max_residual; iron or a magnet moving near the sensor" in err
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "uT", "--set", "max_residual=0.03", "-o", str(out),
                        "--force")
    assert code == 0 and "forced past the guard rails: residual RMS" in load_calibrations(out)["mag"].method


def test_fewer_samples_than_the_stream_needs_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Ten samples fitted the 9-parameter model with 0.09 % residual at 0.5 % noise (fuzzed): the stream's first check,
    ``min_points``, refuses it (exit 4, nothing written); 60 samples, the stream's minimum, pass."""
    out = tmp_path / "cal.yaml"
    for n, code_wanted in ((10, EXIT_REFUSED), (60, 0)):
        path = write_csv(tmp_path / f"n{n}_mag.csv", _sphere(n))
        code, _, err = _run(capsys, "calibrate", str(path), "--unit", "uT", "-o", str(out))
        assert code == code_wanted and out.exists() == (code == 0), (n, err)
        if code:
            assert f"{n} samples < min_points 60: too few to fit the model" in err
