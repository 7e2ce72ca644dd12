"""Hostile input to ``margcal calibrate`` and ``margcal replay`` (issue 26, items 14, 15, 19, 20, 21).

Bad input gets one error line and exit code 2, or is dropped and counted; never a traceback, never a
calibration of the wrong thing with exit code 0. Recordings come from the package simulator, seeded.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.cli import main
from ros_margcal.cli.fit_rescue import rescue, screen
from ros_margcal.model.calibration import Calibration
from ros_margcal.model.errors import InputError
from ros_margcal.recordings import write_bag, write_csv
from ros_margcal.recordings.recording import Recording
from ros_margcal.sim.simulation import directions, magnetometer_stream, random_sensor, simulate, tumbling

SEED = 26


def _sphere(n: int = 3000, seed: int = SEED) -> Recording:
    """A clean magnetometer sphere: ``n`` uniform directions, 0.5 % noise, 50 Hz stamps, tesla."""
    rng = np.random.default_rng(seed)
    truth = random_sensor(rng, "mag")
    return simulate(truth, directions("uniform", n, rng), noise=0.005, rng=rng, t=np.arange(n) / 50.0)


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, list[str]]:
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err.strip().splitlines()


def _offset_error(fit: dict, truth: Calibration) -> float:
    """|fitted offset - true offset| in field norms."""
    return float(np.linalg.norm(np.asarray(fit["offset"]) - truth.offset) / truth.norm)


def _restarted(rec: Recording) -> Recording:
    """The recording with its clock restarted half way (a logger reboot: the stamps go back to about 0)."""
    half = len(rec.t) // 2
    rec.t = np.concatenate([rec.t[:half] + 1000.0, rec.t[half:] - rec.t[half] + 0.01])
    return rec


# -- 14: one spike of 20 field norms in a clean sphere ----------------------------------------------------------


def test_one_spike_of_twenty_field_norms_is_dropped_counted_and_the_sphere_fitted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """One reading 20 field norms from the centre used to make lm fail and the rescue fit the spike ("partial
    coverage", an offset 700 field norms off, exit 0): it is dropped as a spike, said, and the sphere fitted."""
    rec = _sphere()
    truth = rec.truth
    assert truth is not None
    rec.raw[1500] = truth.offset + np.array([20.0 * truth.norm, 0.0, 0.0])
    path = write_csv(tmp_path / "spike_mag.csv", rec)
    out = tmp_path / "fit.json"
    code, text, err = _run(capsys, "calibrate", str(path), "--json", str(out))
    assert code == 0, err
    assert "requested fit" not in text and "partial coverage" not in text
    assert any("dropped 1 of 3000 readings" in line and "spike" in line for line in err), err
    fit = json.loads(out.read_text())
    assert fit["dropped"] == {"spike": 1}
    assert fit["stats"]["n_points"] == 2999
    assert _offset_error(fit, truth) < 0.05


def test_a_spike_in_a_static_recording_leaves_it_static(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A still sensor and one spike used to be "partial coverage" with a calibration written: the spike is dropped,
    the recording is static, nothing is fitted (exit 3)."""
    rng = np.random.default_rng(SEED)
    truth = random_sensor(rng, "mag")
    rec = simulate(truth, np.tile([0.3, 0.2, 0.9], (1000, 1)), noise=0.005, rng=rng, t=np.arange(1000) / 50.0)
    rec.raw[500] = truth.offset + np.array([20.0 * truth.norm, 0.0, 0.0])
    out = tmp_path / "fit.json"
    code, text, err = _run(capsys, "calibrate", str(write_csv(tmp_path / "still_mag.csv", rec)), "--json", str(out))
    assert code == 3 and "static recording" in text and "partial coverage" not in text
    assert any("dropped 1 of 1000 readings" in line for line in err), err
    assert not out.exists()


def test_keep_spikes_fits_every_reading(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--keep-spikes`` turns the pre-filter off: the spike reaches the fit (which then needs the rescue)."""
    rec = _sphere(600)
    assert rec.truth is not None
    rec.raw[300] = rec.truth.offset + np.array([20.0 * rec.truth.norm, 0.0, 0.0])
    path = write_csv(tmp_path / "spike_mag.csv", rec)
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "T", "--keep-spikes", "--no-rescue")
    assert not any("dropped" in line for line in err)
    assert code == 2 and len(err) == 1 and "did not converge" in err[0], err


def test_the_spike_filter_keeps_a_long_rest_followed_by_turns() -> None:
    """Nine parts rest, one part turning: far from the rest, but no gap among the turning readings; nothing dropped."""
    rng = np.random.default_rng(SEED)
    truth = random_sensor(rng, "mag")
    rest = simulate(truth, np.tile([0.3, 0.2, 0.9], (2700, 1)), noise=0.002, rng=rng).raw
    turns = magnetometer_stream(truth, 6.0, 50.0, rng, motion="tumble").raw
    kept = screen(np.vstack([rest, turns]))
    assert kept.dropped == {} and kept.keep.all()


def test_the_spike_filter_keeps_a_clean_sphere_and_few_still_poses() -> None:
    """A clean sphere, and six still poses of an accelerometer (one mostly), lose no reading."""
    assert screen(_sphere().raw).keep.all()
    poses = np.array([[0, 0, 9.8]] * 25 + [[0, 0, -9.8], [9.8, 0, 0], [-9.8, 0, 0], [0, 9.8, 0], [0, -9.8, 0]], float)
    assert screen(poses + np.random.default_rng(SEED).normal(scale=0.01, size=poses.shape)).keep.all()


# -- 15: a cell of 1e308, --norm 1e308 / 1e-308 ------------------------------------------------------------------


@pytest.mark.parametrize("share", [0.0, 0.2], ids=["one cell", "a fifth of the rows"])
def test_a_cell_of_1e308_is_dropped_and_counted(tmp_path: Path, capsys: pytest.CaptureFixture[str], share: float) -> None:
    """A reading of 1e308 used to end in a LinAlgError (or LAPACK looping on inf): it is no reading in any unit,
    dropped and counted, and the rest fitted."""
    rec = _sphere(500)
    truth = rec.truth
    assert truth is not None
    rows = [10] if share == 0.0 else list(range(0, 500, int(1 / share)))
    rec.raw[rows, 0] = 1e308
    path = write_csv(tmp_path / "big_mag.csv", rec)
    out = tmp_path / "fit.json"
    code, _, err = _run(capsys, "calibrate", str(path), "--json", str(out))
    assert code == 0, err
    assert any(f"dropped {len(rows)} of 500 readings" in line and "absurd" in line for line in err), err
    fit = json.loads(out.read_text())
    assert fit["dropped"] == {"absurd": len(rows)}
    assert _offset_error(fit, truth) < 0.01


@pytest.mark.parametrize(("option", "value"), [("--norm", "1e308"), ("--norm", "1e-308"), ("--f-scale", "1e308"),
                                               ("--f-scale", "1e-308")])
def test_an_absurd_norm_or_f_scale_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                           option: str, value: str) -> None:
    """``--norm 1e308`` / ``1e-308`` used to raise ZeroDivisionError in the fit: now one line naming the option."""
    path = write_csv(tmp_path / "clean_mag.csv", _sphere(500))
    extra = ["--loss", "huber"] if option == "--f-scale" else []
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "T", option, value, *extra)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("margcal calibrate: error: ") and f"{option} {float(value):g}" in err[0]


def test_readings_too_small_to_square_are_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Readings of 1e-300 underflow in the fit's squares: one line, not a "static recording" diagnosis."""
    rec = _sphere(500)
    rec.raw = rec.raw * 1e-296
    path = write_csv(tmp_path / "tiny_mag.csv", rec)
    code, _, err = _run(capsys, "calibrate", str(path), "--unit", "counts")  # a unit without a scale: not checked
    assert code == 2 and len(err) == 1 and "too small to fit" in err[0], err


# -- 19: a clock that restarts half way ---------------------------------------------------------------------------


def test_replay_takes_a_csv_whose_clock_restarts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A logger reboot half way used to be refused ("read it with sort=True", no such option): the calibrator's
    new time base takes it, as for a bag."""
    rng = np.random.default_rng(SEED)
    rec = _restarted(magnetometer_stream(random_sensor(rng, "mag"), 60.0, 50.0, rng, motion="tumble"))
    path = write_csv(tmp_path / "reboot_mag.csv", rec)
    out = tmp_path / "replay.json"
    code, _, err = _run(capsys, "replay", str(path), "-q", "--json", str(out))
    assert code == 0, err
    mag = json.loads(out.read_text())["sensors"]["mag"]
    assert mag["status"]["time_base_resets"] == 1
    assert mag["calibration"] is not None


@pytest.mark.parametrize("sensor", ["mag", "accel"])
def test_calibrate_takes_a_csv_whose_clock_restarts(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    sensor: str) -> None:
    """Batch: the ellipsoid does not depend on time; the file order is kept (the accelerometer's gate runs on the
    one clock, the last) and the restart is said."""
    rng = np.random.default_rng(SEED)
    truth = random_sensor(rng, sensor)
    rec = (magnetometer_stream(truth, 60.0, 50.0, rng, motion="tumble") if sensor == "mag"
           else tumbling(truth, 120.0, 50.0, rng))
    path = write_csv(tmp_path / f"reboot_{'mag' if sensor == 'mag' else 'acc'}.csv", _restarted(rec))
    out = tmp_path / "fit.json"
    code, _, err = _run(capsys, "calibrate", str(path), "--json", str(out))
    assert code == 0, err
    assert any("time goes back at 1 place(s)" in line and "logger restart" in line for line in err), err
    fit = json.loads(out.read_text())
    assert _offset_error(fit, truth) < 0.01
    assert fit["stamp"] == pytest.approx(float(rec.t[-1]))  # the file's last stamp: the clock it ended with


# -- 20: two magnetometers in one bag -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def two_mags(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Calibration]]:
    """A bag with two MagneticField topics of two sensors with different hard irons."""
    recs, truths = {}, {}
    for k, topic in enumerate(("/left/mag", "/right/mag")):
        rng = np.random.default_rng(SEED + k)
        truth = random_sensor(rng, "mag")
        recs[topic], truths[topic] = magnetometer_stream(truth, 40.0, 50.0, rng, motion="tumble"), truth
    path = write_bag(tmp_path_factory.mktemp("bags") / "two_mag.mcap", recs)
    return path, truths


def test_replay_gives_one_calibration_per_magnetometer_topic(two_mags: tuple[Path, dict[str, Calibration]],
                                                             tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two MagneticField topics used to be pooled into one calibrator: now one each, each near its own truth."""
    path, truths = two_mags
    out = tmp_path / "replay.json"
    code, text, err = _run(capsys, "replay", str(path), "-q", "--json", str(out))
    assert code == 0, err
    sensors = json.loads(out.read_text())["sensors"]
    assert set(sensors) == {"mag:/left/mag", "mag:/right/mag"}
    for topic, truth in truths.items():
        entry = sensors[f"mag:{topic}"]
        other = next(t for name, t in truths.items() if name != topic)
        assert entry["topic"] == topic
        assert entry["calibration"] is not None
        assert _offset_error(entry["calibration"], truth) < 0.05 < _offset_error(entry["calibration"], other)
    assert "mag:/left/mag:" in text and "mag:/right/mag:" in text


def test_replay_topic_selects_and_a_missing_topic_lists_the_bag(two_mags: tuple[Path, dict[str, Calibration]],
                                                               tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--topic`` replays that topic alone (named ``mag`` as usual); an unknown one exits 2 listing the topics."""
    path, truths = two_mags
    out = tmp_path / "replay.json"
    code, _, err = _run(capsys, "replay", str(path), "-q", "--topic", "/right/mag", "--json", str(out))
    assert code == 0, err
    sensors = json.loads(out.read_text())["sensors"]
    assert list(sensors) == ["mag"] and sensors["mag"]["topic"] == "/right/mag"
    assert _offset_error(sensors["mag"]["calibration"], truths["/right/mag"]) < 0.05
    code, _, err = _run(capsys, "replay", str(path), "--topic", "/nope")
    assert code == 2 and len(err) == 1, err
    assert "/nope" in err[0] and "/left/mag (MagneticField)" in err[0] and "/right/mag (MagneticField)" in err[0]


def test_calibrate_refuses_two_magnetometers_naming_them_and_its_option(two_mags: tuple[Path, dict[str, Calibration]],
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """calibrate fits one sensor: it names the topics and ``--topic``, the option it has."""
    code, _, err = _run(capsys, "calibrate", str(two_mags[0]))
    assert code == 2 and len(err) == 1, err
    assert "['/left/mag', '/right/mag']" in err[0] and "--topic" in err[0]


# -- 21: --unit for a bag ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gauss_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Calibration]:
    """A bag whose driver publishes MagneticField in gauss (not REP-145's tesla), beside an Imu topic."""
    rng = np.random.default_rng(SEED)
    truth = random_sensor(rng, "mag", norm=0.5).replace(unit="gauss")
    mag = magnetometer_stream(truth, 40.0, 50.0, rng, motion="tumble")
    acc = tumbling(random_sensor(rng, "accel"), 40.0, 50.0, rng)
    path = write_bag(tmp_path_factory.mktemp("bags") / "gauss.mcap", {"/imu/mag": mag, "/imu/data_raw": acc})
    return path, truth


@pytest.mark.parametrize("extra", [[], ["--sensor", "mag"]], ids=["unit of the magnetometer", "--sensor mag"])
def test_replay_honours_unit_for_a_bag(gauss_bag: tuple[Path, Calibration], tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str], extra: list[str]) -> None:
    """``--unit gauss`` used to be ignored for bags (every sample dropped as 0.5 T, then "set --unit"): it now
    applies to the magnetometer, whose calibration is in gauss."""
    path, truth = gauss_bag
    out = tmp_path / "replay.json"
    code, _, err = _run(capsys, "replay", str(path), "-q", "--unit", "gauss", *extra, "--json", str(out))
    assert code == 0, err
    sensors = json.loads(out.read_text())["sensors"]
    assert set(sensors) == ({"mag"} if extra else {"mag", "accel"})
    cal = sensors["mag"]["calibration"]
    assert cal is not None and cal["unit"] == "gauss"
    assert _offset_error(cal, truth) < 0.05
    assert sensors["mag"]["status"]["dropped"].get("magnitude", 0) == 0


def test_replay_refuses_a_unit_of_no_known_sensor_for_a_bag_of_both(gauss_bag: tuple[Path, Calibration],
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``--unit counts`` could be either sensor's: one line asking for ``--sensor``."""
    code, _, err = _run(capsys, "replay", str(gauss_bag[0]), "--unit", "counts")
    assert code == 2 and len(err) == 1, err
    assert "--sensor mag or --sensor accel" in err[0]


def test_rescue_refuses_readings_it_cannot_square() -> None:
    """``rescue`` on a reading of 1e308 (its algebraic sphere fit made LAPACK loop on inf): an InputError at once."""
    pts = _sphere(100).raw
    pts[5, 0] = 1e308
    with pytest.raises(InputError, match="beyond 1e"):
        rescue(None, pts, failure="test", model="sym", norm=None, loss="linear", sensor="mag", unit="T", cfg=None)


# -- fuzzed (2026-11-27): inputs that gave a traceback, a hang or a calibration from part of a corrupt bag ----------


def test_a_csv_cell_beyond_the_csv_field_limit_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 140 000-character cell raised ``_csv.Error`` out of every command that reads CSV."""
    path = tmp_path / "big_mag.csv"
    path.write_text("t,x,y,z\n0,1,1," + "1" * 140_000 + "\n", encoding="utf-8")
    for command in ("calibrate", "replay"):
        code, _, err = _run(capsys, command, str(path))
        assert code == 2 and len(err) == 1 and "field larger than field limit" in err[0], err


@pytest.mark.parametrize("name", ["p.txt", "p", "sub"])
def test_a_plot_file_matplotlib_cannot_write_is_refused_before_the_replay(tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str],
                                                                          name: str) -> None:
    """``--plot p.txt`` raised matplotlib's ValueError after the whole replay; a directory is refused too."""
    (tmp_path / "sub.png").mkdir()
    path = write_csv(tmp_path / "clean_mag.csv", _sphere(300))
    target = tmp_path / ("sub.png" if name == "sub" else name)
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(path), "-q", "--plot", str(target)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "argument --plot" in err and "replaying" not in err, err
    assert not target.is_file()


@pytest.mark.parametrize("argv", [["--pattern", "tumbling", "--rate", "1e-300"],  # hung
                                  ["--pattern", "tumbling", "--duration", "1e300"],
                                  ["--pattern", "tumbling", "--rate", "1e6", "--duration", "1e4"],  # 74.5 GiB
                                  ["--seed", "-1"], ["--noise", "1e300"], ["-n", "100000000"],
                                  ["--pattern", "smooth", "--jump-at", "3", "--jump-size", "1e300"],
                                  ["--pattern", "smooth", "--jump-at", "nan"]])
def test_simulate_refuses_absurd_sizes_rates_and_seeds_in_one_line(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str],
                                                                   argv: list[str]) -> None:
    """Each of these raised deep in numpy (or never returned): now exit 2, one line naming the option, no file."""
    out = tmp_path / "s.csv"
    code, _, err = _run(capsys, "simulate", str(out), *argv)
    assert code == 2 and len(err) == 1 and err[0].startswith("margcal simulate: error: "), err
    assert any(word in err[0] for word in ("--rate", "--duration", "--seed", "--noise", "-n ", "--jump")), err
    assert not out.exists()


def test_a_bag_that_gives_fewer_messages_than_its_index_is_refused(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """A corrupt MCAP (a flipped bit in a message index) gave 2907 of its 3000 messages without an error, and
    calibrate wrote a fit of them. The same shortfall made here by a stale index (metadata.yaml listing more):
    calibrate and replay refuse it in one line; the intact bag calibrates."""
    bag = write_bag(tmp_path / "bag", {"/imu/mag": _sphere(600)}, storage="mcap")
    code, _, err = _run(capsys, "calibrate", str(bag), "-o", str(tmp_path / "ok.yaml"))
    assert code == 0, err
    meta = bag / "metadata.yaml"
    text = meta.read_text(encoding="utf-8")
    assert text.count("message_count: 600") >= 1
    meta.write_text(text.replace("message_count: 600", "message_count: 650"), encoding="utf-8")
    for argv in (["calibrate", str(bag), "-o", str(tmp_path / "cut.yaml")], ["replay", str(bag), "-q"]):
        code, _, err = _run(capsys, *argv)
        assert code == 2 and len(err) == 1 and "gave 600 of the 650 messages" in err[0], err
    assert not (tmp_path / "cut.yaml").exists()


def test_diagnose_benchmark_refuses_a_negative_limit(capsys: pytest.CaptureFixture[str]) -> None:
    """``--limit -1`` started all 160 recordings."""
    from ros_margcal.bench.diagnosis import main as bench_main
    with pytest.raises(SystemExit) as exc:
        bench_main(["--limit", "-1"])
    assert exc.value.code == 2 and "--limit must be >= 0" in capsys.readouterr().err
