"""``--set KEY=VALUE`` in ``replay`` and ``calibrate``: every PipelineConfig option, parsed by its kind, checked."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.cli import main
from ros_margcal.cli.replay import example_paths
from ros_margcal.cli.set_option import parse_sets, sensor_options
from ros_margcal.model.errors import ConfigError
from ros_margcal.recordings import write_csv
from ros_margcal.recordings.recording import Recording
from ros_margcal.sim.simulation import directions, random_sensor, simulate
from ros_margcal.stream.config import FIELD_SPECS, PipelineConfig
from ros_margcal.stream.replay import replay

SEED = 25


def test_values_are_parsed_by_the_kind_of_the_field() -> None:
    """Numbers, integers, booleans, none and inf where the field admits them; a sensor prefix keeps to its sensor."""
    sets = parse_sets(["max_offset_ratio=20", "max_iter=500", "gyro_aided=false", "max_offset=none",
                       "norm_max=inf", "accel.gate_cv_threshold=0.01", "model=diag"])
    assert sets[""] == {"max_offset_ratio": 20.0, "max_iter": 500, "gyro_aided": False, "max_offset": None,
                        "norm_max": math.inf, "model": "diag"}
    assert sensor_options(sets, "accel")["gate_cv_threshold"] == 0.01
    assert "gate_cv_threshold" not in sensor_options(sets, "mag")


@pytest.mark.parametrize(("item", "match"), [
    ("max_ofset_ratio=3", "unknown option 'max_ofset_ratio'; did you mean max_offset_ratio"),
    ("max_iter=2.5", "max_iter takes an integer"),
    ("max_iter=0", r"max_iter must be in \[1, 100000\]"),
    ("max_offset_ratio=abc", "max_offset_ratio takes a number"),
    ("max_offset_ratio=nan", r"max_offset_ratio must be in"),
    ("max_offset_ratio=inf", "max_offset_ratio must be finite"),
    ("gyro_aided=maybe", "gyro_aided takes true or false"),
    ("max_offset_ratio", "expected KEY=VALUE"),
    ("gyro.max_iter=3", "prefix of 'gyro.max_iter' must be mag. or accel."),
    ("unit=gauss", "give it with --unit"),
    ("model=banana", "model must be one of"),
])
def test_bad_items_are_refused_naming_them(item: str, match: str) -> None:
    """Unknown keys (with the near ones), bad values and a missing '=' are ConfigErrors."""
    with pytest.raises(ConfigError, match=match):
        parse_sets([item])


def test_every_option_a_message_asks_to_raise_is_settable() -> None:
    """The options the messages name (and every other field) parse and reach the configuration."""
    for key in ("max_magnitude", "gate_cv_threshold", "max_iter", "max_offset_ratio", "max_heading_p95_deg"):
        assert key in FIELD_SPECS
    sets = parse_sets(["max_magnitude=0.01", "gate_cv_threshold=0.02", "max_iter=900", "max_offset_ratio=40"])
    cfg = PipelineConfig.for_sensor("mag", "T", **sensor_options(sets, "mag"))
    assert (cfg.max_magnitude, cfg.gate_cv_threshold, cfg.max_iter, cfg.max_offset_ratio) == (0.01, 0.02, 900, 40.0)


def _poses(tmp_path: Path, noise: float) -> Path:
    """An accelerometer (m/s^2) still in 12 poses for 3 s each, white noise ``noise`` m/s^2, 50 Hz."""
    rng = np.random.default_rng(SEED)
    truth = random_sensor(rng, "accel")
    poses = np.repeat(directions("uniform", 12, rng), 150, axis=0)
    rec: Recording = simulate(truth, poses, noise=0.0, rng=rng, t=np.arange(len(poses)) / 50.0)
    rec.raw = rec.raw + rng.normal(scale=noise, size=rec.raw.shape)
    return write_csv(tmp_path / "poses_acc.csv", rec)


def test_calibrate_takes_the_gate_threshold_a_message_asks_to_raise(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """An accelerometer noisier than the learnt gate's cap (1e-2 of g) has no still period; the message names the
    option, and --set accel.gate_cv_threshold=... calibrates it."""
    path = _poses(tmp_path, noise=0.15)
    assert main(["calibrate", str(path), "--unit", "m/s^2"]) == 2
    err = capsys.readouterr().err
    assert "--set accel.gate_cv_threshold=" in err, err
    code = main(["calibrate", str(path), "--unit", "m/s^2", "--set", "accel.gate_cv_threshold=0.03"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "still samples" in err and "calibration of" in out


@pytest.mark.parametrize("command", ["calibrate", "replay"])
def test_a_bad_set_exits_2_on_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str) -> None:
    """Both commands refuse an unknown key and an out-of-range value before reading the recording: exit 2, one line."""
    path = _poses(tmp_path, noise=0.01)
    for item, match in (("bogus=1", "unknown option 'bogus'"), ("n_bins=3", "n_bins must be in [6")):
        assert main([command, str(path), "--set", item]) == 2
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.startswith("margcal ")]
        assert len(lines) == 1 and match in lines[0] and "Traceback" not in err, err


def test_replay_sets_one_sensors_option_on_a_recording_of_both(capsys: pytest.CaptureFixture[str]) -> None:
    """``--set accel.KEY`` on the example bag (both sensors) sets the accelerometer's calibrator alone, ``--set KEY``
    both; the replay runs (it was refused with "replay one with --sensor")."""
    path, _ = example_paths()
    opts = {"accel": {"gate_cv_threshold": 0.02, "n_bins": 24}, "mag": {"n_bins": 24}}
    cals = replay(path, progress=False, status_every=0.0, sensor_options=opts)["calibrators"]
    assert cals["accel"].config.gate_cv_threshold == 0.02 and cals["accel"].config.n_bins == 24
    default = PipelineConfig.for_sensor("mag")
    assert cals["mag"].config.gate_cv_threshold == default.gate_cv_threshold and cals["mag"].config.n_bins == 24
    assert main(["replay", "--example", "--quiet", "--set", "accel.gate_cv_threshold=0.02", "--set", "n_bins=24"]) == 0
    capsys.readouterr()


def test_replay_refuses_an_option_for_a_sensor_it_does_not_replay(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    path = _poses(tmp_path, noise=0.01)
    assert main(["replay", str(path), "--unit", "m/s^2", "--set", "mag.n_bins=24"]) == 2
    err = capsys.readouterr().err
    assert "replays no mag" in err and "Traceback" not in err, err
