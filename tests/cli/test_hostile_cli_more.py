"""Hostile input to the ``margcal`` command line, second audit (2026-11-28).

Seeds and counts, outputs that clobber inputs or each other, a calibration file that holds another sensor, a truth in
another unit, absurd effect sizes, recordings ``diagnose`` cannot use, misleading notes. Each refusal is one line and
exit 2 (bad input) or 3 (nothing to diagnose), before any work; never a traceback, never a destroyed file.
Recordings come from the package simulator, seeded.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ros_margcal.cli import main
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.calibration_file import load_calibrations, read_calibration_file, save_calibrations
from ros_margcal.recordings import write_bag, write_csv
from ros_margcal.recordings.recording import Recording
from ros_margcal.sim.simulation import directions, magnetometer_stream, random_sensor, simulate, tumbling

SEED = 28


def _sphere(n: int = 600, seed: int = SEED) -> Recording:
    """A clean magnetometer sphere: ``n`` uniform directions, 0.5 % noise, 50 Hz stamps, tesla."""
    rng = np.random.default_rng(seed)
    return simulate(random_sensor(rng, "mag"), directions("uniform", n, rng), noise=0.005, rng=rng, t=np.arange(n) / 50.0)


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, list[str]]:
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err.strip().splitlines()


def _exit(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[Any, list[str]]:
    """The exit code of a command that ends in SystemExit (argparse, a benchmark's own parser) and its stderr."""
    with pytest.raises(SystemExit) as exc:
        main(list(argv))
    return exc.value.code, capsys.readouterr().err.strip().splitlines()


@pytest.fixture
def mag_csv(tmp_path: Path) -> Path:
    return write_csv(tmp_path / "sphere_mag.csv", _sphere())


# -- 1: negative seeds and counts -------------------------------------------------------------------------------------


@pytest.mark.parametrize("argv", [["build-corpus", "--out", "c.npz"], ["train-validator", "--out", "v.json"],
                                  ["evaluate-validator"]])
def test_validator_commands_refuse_a_negative_seed_on_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                               argv: list[str]) -> None:
    """``--seed -1`` raised numpy's "expected non-negative integer" with a traceback: now exit 2, one line."""
    argv = [str(tmp_path / a) if a.endswith((".npz", ".json")) else a for a in argv]
    code, _, err = _run(capsys, *argv, "--n-sets", "20", "--seed", "-1")
    assert code == 2 and len(err) == 1 and err[0].startswith(f"margcal {argv[0]}: error: --seed"), err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(("area", "argv"), [("fitting", ["--seed", "-1"]), ("fitting", ["--runs", "-3"]),
                                            ("fitting", ["--runs", "0"]), ("pipeline", ["--seed", "-1"]),
                                            ("coverage", ["--seed", "-1"]), ("diagnosis", ["--seed", "-1"])])
def test_benchmarks_refuse_a_negative_seed_or_count_on_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                                area: str, argv: list[str]) -> None:
    """``bench fitting --runs -3`` gave a TypeError after a minute, ``--runs 0`` ran the default; ``--seed -1`` numpy's
    traceback in every benchmark: exit 2 on one line naming the option."""
    extra = ["--limit", "1", "--no-real", "--no-speed", "--out", str(tmp_path / "b")] if area == "diagnosis" else []
    code, err = _exit(capsys, "bench", area, "--quick", *argv, *extra)
    assert code == 2 and len(err) == 1 and err[0].startswith(f"margcal bench {area}: error: {argv[0]}"), err


# -- 2: an output that is an input, lies inside one, or is another output -------------------------------------------


@pytest.mark.parametrize("argv", [["calibrate", "{rec}", "-o", "{rec}"], ["calibrate", "{rec}", "--json", "{rec}"],
                                  ["calibrate", "{rec}", "-o", "{tmp}/x.yaml", "--json", "{tmp}/x.yaml"],
                                  ["calibrate", "{rec}", "-o", "{tmp}/link.csv"],
                                  ["replay", "{rec}", "-q", "--json", "{rec}"],
                                  ["replay", "{rec}", "-q", "--plot", "{tmp}/f.png", "--json", "{tmp}/f.png"],
                                  ["replay", "{rec}", "-q", "--truth", "{tmp}/t.yaml", "--json", "{tmp}/t.yaml"],
                                  ["simulate", "{tmp}/g.csv", "--truth", "{tmp}/g.csv"],
                                  ["simulate", "{tmp}/g.csv", "--truth", "{tmp}/g.csv", "--force"],
                                  ["diagnose", "{rec}", "--out", "{rec}", "--quick", "--no-validator"]])
def test_an_output_that_is_an_input_or_another_output_is_refused_before_any_work(
        mag_csv: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str]) -> None:
    """Each of these wrote over the recording, the truth or its own other output, exit 0: now exit 2 on one line
    naming both paths, nothing read or written."""
    (tmp_path / "link.csv").symlink_to(mag_csv)
    before = mag_csv.read_bytes()
    words = [a.format(rec=mag_csv, tmp=tmp_path) for a in argv]
    code, out, err = _run(capsys, *words)
    assert code == 2 and len(err) == 1 and err[0].startswith(f"margcal {argv[0]}: error: "), err
    paths = [w for w in words[1:] if "/" in w]
    clash = [p for p in paths if paths.count(p) > 1] or paths  # the same path twice, or a link and its target
    assert all(err[0].count(p) >= clash.count(p) for p in clash), err
    assert mag_csv.read_bytes() == before and out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.csv", "sphere_mag.csv"]


def test_an_output_inside_an_input_bag_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``calibrate bag -o bag/metadata.yaml`` replaced the bag's index with a calibration: refused, naming both."""
    bag = write_bag(tmp_path / "bag", {"/imu/mag": _sphere()}, storage="mcap")
    meta = (bag / "metadata.yaml").read_bytes()
    for target in (bag / "metadata.yaml", bag / "sub" / "cal.yaml"):
        code, _, err = _run(capsys, "calibrate", str(bag), "--sensor", "mag", "-o", str(target))
        assert code == 2 and len(err) == 1 and str(target) in err[0] and f"the recording {bag}," in err[0], err
    assert (bag / "metadata.yaml").read_bytes() == meta and not (bag / "sub").exists()


def test_simulate_truth_does_not_replace_a_file_without_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``simulate h.csv --truth precious.csv`` replaced an existing file although OUT itself is never replaced without
    --force: refused before simulating; with --force it is replaced."""
    precious = tmp_path / "precious.csv"
    precious.write_text("keep me\n")
    out = tmp_path / "h.csv"
    code, _, err = _run(capsys, "simulate", str(out), "--truth", str(precious))
    assert code == 2 and len(err) == 1 and str(precious) in err[0] and "--force" in err[0], err
    assert precious.read_text() == "keep me\n" and not out.exists()
    code, _, err = _run(capsys, "simulate", str(out), "--truth", str(precious), "--force")
    assert code == 0, err
    assert set(load_calibrations(precious)) == {"mag"}


# -- 3: -o into a calibration file that holds another sensor ------------------------------------------------------------


def test_calibrate_keeps_the_other_sensors_calibration_of_its_output(mag_csv: Path, tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """The node's file holds both sensors: calibrating the magnetometer into it dropped the accelerometer's. It is
    kept (said), the magnetometer's replaced, the node's name kept (it was written as ``margcal``)."""
    acc = random_sensor(np.random.default_rng(SEED), "accel")
    old_mag = random_sensor(np.random.default_rng(SEED + 1), "mag")
    out = save_calibrations(tmp_path / "node.yaml", {"accel": acc, "mag": old_mag}, node="robot_imu_calib")
    code, _, err = _run(capsys, "calibrate", str(mag_csv), "-o", str(out))
    assert code == 0, err
    cals = load_calibrations(out)
    assert set(cals) == {"accel", "mag"} and cals["accel"].allclose(acc) and not cals["mag"].allclose(old_mag)
    assert any("accel" in line and "kept" in line for line in err), err
    assert read_calibration_file(out)[1] == "robot_imu_calib" and out.read_text().startswith("robot_imu_calib:")
    assert read_calibration_file(save_calibrations(tmp_path / "new.yaml", {"accel": acc}))[1] == "margcal"


def test_calibrate_refuses_to_replace_a_file_that_is_no_calibration_unless_forced(
        mag_csv: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A file that cannot be read as a calibration file was silently replaced: refused before the fit, naming
    --force, which replaces it."""
    out = tmp_path / "notes.yaml"
    out.write_text("shopping: [milk, bread]\n")
    code, text, err = _run(capsys, "calibrate", str(mag_csv), "-o", str(out))
    assert code == 2 and len(err) == 1 and str(out) in err[0] and "--force" in err[0], err
    assert out.read_text() == "shopping: [milk, bread]\n" and "calibration of" not in text
    code, _, err = _run(capsys, "calibrate", str(mag_csv), "-o", str(out), "--force")
    assert code == 0, err
    assert set(load_calibrations(out)) == {"mag"}


# -- 4 and 5: replay --truth in another unit or of another sensor, --example with a recording ----------------------


@pytest.fixture(scope="module")
def tumble(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Calibration]:
    """A tumbling magnetometer in tesla that the stream calibrates, and its truth."""
    rng = np.random.default_rng(SEED)
    truth = random_sensor(rng, "mag")
    rec = magnetometer_stream(truth, 30.0, 50.0, rng, motion="tumble")
    return write_csv(tmp_path_factory.mktemp("tumble") / "tumble_mag.csv", rec), truth


def _comparison(capsys: pytest.CaptureFixture[str], rec: Path, truth: Path, json_path: Path) -> dict[str, float]:
    code, _, err = _run(capsys, "replay", str(rec), "-q", "--truth", str(truth), "--json", str(json_path))
    assert code == 0, err
    return json.loads(json_path.read_text())["sensors"]["mag"]["truth_comparison"]


def test_replay_converts_a_truth_in_another_known_unit(tumble: tuple[Path, Calibration], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """A truth in gauss against a recording in tesla was compared number for number (1e4 x off, or a tesla-sized
    truth labelled gauss "0.10 %"): it is converted, and compares as the same truth in tesla does."""
    rec, truth = tumble
    in_t = save_calibrations(tmp_path / "t.yaml", {"mag": truth})
    in_gauss = save_calibrations(tmp_path / "g.yaml", {"mag": truth.replace(offset=truth.offset * 1e4,
                                                                            norm=truth.norm * 1e4, unit="gauss")})
    ref = _comparison(capsys, rec, in_t, tmp_path / "t.json")
    got = _comparison(capsys, rec, in_gauss, tmp_path / "g.json")
    assert ref["offset_error_rel"] < 0.05
    for key, value in ref.items():
        assert got[key] == pytest.approx(value, rel=1e-6, abs=1e-12), (key, got, ref)


@pytest.mark.parametrize("case", ["furlong", "garbage", "accel in T"])
def test_replay_refuses_an_unusable_truth_before_the_replay(tumble: tuple[Path, Calibration], tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str], case: str) -> None:
    """A truth in an unknown unit compared number for number; a file that cannot be read cost the whole replay
    first; an entry whose sensor is another: exit 2 on one line, before the replay starts."""
    rec, truth = tumble
    path = tmp_path / "truth.yaml"
    if case == "garbage":
        path.write_text("not: [a calibration\n")
    else:
        bad = truth.replace(unit="furlong") if case == "furlong" else truth.replace(sensor="accel")
        save_calibrations(path, {"mag": bad})
    code, out, err = _run(capsys, "replay", str(rec), "-q", "--truth", str(path))
    lines = [line for line in err if line.startswith("margcal ")]  # beside the CSV's unit inferred, said
    assert code == 2 and len(lines) == 1 and str(path) in lines[0], err
    assert "replaying" not in out


def test_replay_says_when_the_truth_holds_no_calibration_of_a_replayed_sensor(
        tumble: tuple[Path, Calibration], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A truth of the accelerometer only gave no comparison and no word: the replay says so."""
    rec, _ = tumble
    path = save_calibrations(tmp_path / "acc.yaml", {"accel": random_sensor(np.random.default_rng(SEED), "accel")})
    code, out, err = _run(capsys, "replay", str(rec), "-q", "--truth", str(path))
    assert code == 0, err
    assert any("no calibration for mag" in line and "accel" in line for line in err), err
    assert "vs truth" not in out


def test_replay_refuses_a_recording_with_example(mag_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``replay mag.csv --example`` replayed the example and ignored the recording: refused."""
    code, out, err = _run(capsys, "replay", str(mag_csv), "--example", "-q")
    assert code == 2 and len(err) == 1 and "--example" in err[0] and str(mag_csv) in err[0], err
    assert "replaying" not in out


# -- 6: simulate's effect sizes and --jump-at ----------------------------------------------------------------------------


@pytest.mark.parametrize("argv", [["--effect", f"{name}=1e300"] for name in
                                  ("misalignment", "quantization", "noise", "bias_drift", "temperature", "disturbance",
                                   "hard_iron_jump")]
                         + [["--pattern", "smooth", "--jump-at", at] for at in ("-5", "0", "60", "1e9")])
def test_simulate_refuses_absurd_effect_sizes_and_a_jump_outside_the_recording(tmp_path: Path,
                                                                              capsys: pytest.CaptureFixture[str],
                                                                              argv: list[str]) -> None:
    """misalignment=1e300 wrote NaN rows, quantization=1e300 zeros, noise=1e300 readings of 1e296; a jump before the
    start or after the end never happened although the truth file says mag_before/mag_after: exit 2, one line."""
    out = tmp_path / "s.csv"
    code, _, err = _run(capsys, "simulate", str(out), *argv)
    assert code == 2 and len(err) == 1 and err[0].startswith("margcal simulate: error: "), err
    assert argv[1].split("=")[0] in err[0] or "--jump-at" in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("argv", [["--effect", "misalignment=10"], ["--effect", "noise=0.05"],
                                  ["--effect", "hard_iron_jump=1"], ["--pattern", "smooth", "--jump-at", "30"]])
def test_simulate_keeps_sensible_effect_sizes(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str]) -> None:
    code, _, err = _run(capsys, "simulate", str(tmp_path / "s.csv"), *argv)
    assert code == 0, err


# -- 7: diagnose on recordings it cannot diagnose, and --rest-recording ---------------------------------------------------


def _rows(path: Path, rows: np.ndarray) -> Path:
    """A CSV of ``rows`` (n, 3) in tesla at 10 Hz."""
    write_csv(path, Recording(t=np.arange(len(rows)) * 0.1, raw=rows, sensor="mag", unit="T"))
    return path


@pytest.mark.parametrize("n", [1, 2, 10])
def test_diagnose_exits_3_on_a_recording_it_cannot_diagnose(n: int, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """One row, two rows, ten identical rows: a report of "unexplained" and exit 0; now exit 3 with the reason (as
    calibrate), no report."""
    rows = np.tile([2e-5, -3e-5, 3e-5], (n, 1)) + (0.0 if n == 10 else 1e-6 * np.arange(3 * n).reshape(n, 3))
    path = _rows(tmp_path / "few_mag.csv", rows)
    out = tmp_path / "d"
    code, _, err = _run(capsys, "diagnose", str(path), "--out", str(out), "--quick", "--no-validator", "--no-plots")
    assert code == 3 and f"at least 50 samples, got {n}" in err[-1], err
    assert not out.exists()


def test_diagnose_exits_3_on_a_static_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(SEED)
    path = _rows(tmp_path / "still_mag.csv", np.array([2e-5, -3e-5, 3e-5]) + 1e-8 * rng.normal(size=(500, 3)))
    code, _, err = _run(capsys, "diagnose", str(path), "--out", str(tmp_path / "d"), "--quick", "--no-validator")
    assert code == 3 and "static" in err[-1], err
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("rest", ["accelerometer", "one row", "identical rows"])
def test_diagnose_refuses_a_rest_recording_it_cannot_use(mag_csv: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str], rest: str) -> None:
    """An accelerometer in m/s^2 was taken as the tesla magnetometer's rest noise (20 000 times its noise), one row
    gave "rest noise 0": exit 2 on one line naming --rest-recording, before the diagnosis."""
    if rest == "accelerometer":
        rng = np.random.default_rng(SEED)
        path = write_csv(tmp_path / "still_acc.csv", tumbling(random_sensor(rng, "accel"), 20.0, 50.0, rng))
    else:
        n = 1 if rest == "one row" else 200
        path = _rows(tmp_path / "rest_mag.csv", np.tile([2e-5, -3e-5, 3e-5], (n, 1)))
    code, out, err = _run(capsys, "diagnose", str(mag_csv), "--rest-recording", str(path), "--out",
                          str(tmp_path / "d"), "--quick", "--no-validator", "--no-plots")
    lines = [line for line in err if line.startswith("margcal ")]
    assert code == 2 and len(lines) == 1 and "--rest-recording" in lines[0] and str(path) in lines[0], err
    assert out == "" and not (tmp_path / "d").exists()


# -- 8: notes that were not true, messages that named the wrong thing, unwritable outputs ---------------------------------


@pytest.mark.parametrize(("item", "said"), [("min_magnitude=1", "ignored"), ("method=mvee", "--method"),
                                            ("mag.loss=cauchy", "--loss")])
def test_calibrate_ignores_the_streaming_options_it_says_it_does_not_use(mag_csv: Path, tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str],
                                                                         item: str, said: str) -> None:
    """``--set min_magnitude=1``: "calibrate does not use" it, then failed on it; ``--set method=mvee`` blamed the loss
    'soft_l1' the user never set. Ignored as said, and the note names calibrate's own option."""
    code, text, err = _run(capsys, "calibrate", str(mag_csv), "--set", item, "-o", str(tmp_path / "c.yaml"))
    assert code == 0, err
    notes = [line for line in err if line.startswith("note: --set")]
    assert len(notes) == 1 and item.split("=")[0].split(".")[-1] in notes[0] and said in notes[0], err
    assert "calibration of" in text


@pytest.mark.parametrize("command", ["calibrate", "replay"])
def test_an_altitude_out_of_range_names_alt(mag_csv: Path, capsys: pytest.CaptureFixture[str], command: str) -> None:
    """``--alt 1e9`` was refused as "altitude_m must be in ...": the option the user gave is named."""
    code, out, err = _run(capsys, command, str(mag_csv), "--lat", "45", "--lon", "10", "--alt", "1e9")
    assert code == 2 and len(err) == 1 and err[0].startswith(f"margcal {command}: error: --alt"), err
    assert "replaying" not in out


@pytest.fixture
def read_only(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A folder the process may not write in (the check is os.access: as root, chmod alone would not refuse)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    real = os.access

    def access(path: Any, mode: int, *args: Any, **kwargs: Any) -> bool:
        if mode & os.W_OK and Path(path).resolve() == folder.resolve():
            return False
        return real(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)
    return folder


@pytest.mark.parametrize("argv", [["calibrate", "{rec}", "-o", "{ro}/x.yaml"], ["calibrate", "{rec}", "--json", "{ro}/x.json"],
                                  ["replay", "{rec}", "-q", "--json", "{ro}/x.json"],
                                  ["replay", "{rec}", "-q", "--plot", "{ro}/deeper/x.png"],
                                  ["simulate", "{ro}/s.csv"],
                                  ["diagnose", "{rec}", "--out", "{ro}/d", "--quick", "--no-validator", "--no-plots"]])
def test_an_output_folder_that_cannot_be_written_is_refused_before_the_work(mag_csv: Path, read_only: Path,
                                                                           capsys: pytest.CaptureFixture[str],
                                                                           argv: list[str]) -> None:
    """A read-only -o folder was found after the fit, naming the temporary file '.x.yaml.NNN.tmp': now before any
    work, exit 2 on one line, naming the user's path."""
    words = [a.format(rec=mag_csv, ro=read_only) for a in argv]
    code, out, err = _run(capsys, *words)
    target = next(w for w in words if str(read_only) in w)
    assert code == 2 and len(err) == 1 and target in err[0] and ".tmp" not in err[0], err
    assert out == ""
