"""Stamps that are not seconds, and recordings named or shaped unlike what they hold.

Nanosecond epoch stamps (1.7e18) used to crash the inactivity gate (float spacing above 1.8e16 s is coarser than
its 2 s window); a recording in ms, µs or ns was fitted or diagnosed as if in seconds. The readers now refuse
such stamps with the likely unit, the stream's drop summary names it, and the gate never raises whatever the
stamps. Also: a bag directory without metadata.yaml, an upper-case or missing suffix, a CSV cell with an underscore.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import tumbling_imu

from ros_margcal import write_bag
from ros_margcal.cli import main
from ros_margcal.coverage.gate import GyroAidedGate, InactivityGate
from ros_margcal.model.errors import RecordingError
from ros_margcal.recordings.bag import is_bag
from ros_margcal.recordings.csvfile import write_csv
from ros_margcal.recordings.read import read_recording
from ros_margcal.recordings.recording import Recording, drop_stamp_glitches
from ros_margcal.stream.config import PipelineConfig
from ros_margcal.stream.intake import Intake

SEED = 29
G = 9.80665


@pytest.fixture(scope="module")
def imu() -> dict[str, Recording]:
    """Twelve seconds of an IMU at 100 Hz, stamps in seconds from 0: accelerometer (with gyro) and magnetometer."""
    acc, mag = tumbling_imu(12.0, 100.0, SEED)
    return {"accel": acc, "mag": mag}


def _restamped(rec: Recording, scale: float, offset: float = 0.0) -> Recording:
    out = rec.slice(slice(None))
    out.t = rec.t * scale + offset
    return out


# -- the gate never raises, whatever the stamps ------------------------------------------------------------------


@pytest.mark.parametrize("offset", [4e16, 1.7e18, -1.7e18, 1e300, -1e300])
@pytest.mark.parametrize("gate_cls", [InactivityGate, GyroAidedGate])
def test_the_gate_never_raises_on_stamps_coarser_than_its_window(offset: float, gate_cls: type) -> None:
    """Stamps far from 0, whose float spacing exceeds the window, pass through the gate without an exception."""
    rng = np.random.default_rng(SEED)
    gate = gate_cls(learn=True)
    for i in range(600):
        xyz = np.array([0.0, 0.0, G]) + rng.normal(scale=0.01, size=3)
        gate.push(offset + i * 0.01, xyz, rng.normal(scale=0.01, size=3) if i % 2 else None)
    counts = gate.counters
    assert counts["pushed"] == 600 and counts["emitted"] == 0


def test_the_gate_still_works_at_epoch_seconds() -> None:
    """Epoch stamps in seconds (1.7e9, spacing 2.4e-7 s) keep the gate's still detection."""
    rng = np.random.default_rng(SEED)
    gate = InactivityGate()
    still = np.array([0.0, 0.0, G]) + rng.normal(scale=0.002, size=(500, 3))
    out = [gate.push(1.7e9 + i / 100.0, still[i]) for i in range(500)]
    assert sum(o is not None for o in out) >= 1


# -- the readers refuse stamps that are not seconds, naming the likely unit ---------------------------------------


@pytest.mark.parametrize(
    ("scale", "offset", "unit"),
    [
        (1e9, 1.7e18, "nanoseconds since the epoch"),
        (1e6, 1.7e15, "microseconds since the epoch"),
        (1e3, 1.7e12, "milliseconds since the epoch"),
        (1e3, 0.0, "milliseconds"),
        (1e6, 0.0, "microseconds"),
        (1e9, 0.0, "nanoseconds"),
    ],
)
def test_the_reader_names_the_unit_of_stamps_that_are_not_seconds(
    tmp_path: Path, imu: dict[str, Recording], scale: float, offset: float, unit: str
) -> None:
    """A CSV and a bag stamped in ms, µs or ns (from 0 or since the epoch): one line naming the unit."""
    path = write_csv(tmp_path / "acc.csv", _restamped(imu["accel"], scale, offset))
    with pytest.raises(RecordingError, match=f"look like {unit}.*give seconds") as info:
        read_recording(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_a_bag_in_milliseconds_is_refused_too(tmp_path: Path, imu: dict[str, Recording]) -> None:
    """A bag whose header stamps count milliseconds (step 10 at 100 Hz): refused as a CSV is."""
    path = write_bag(tmp_path / "imu.mcap", {"/imu/mag": _restamped(imu["mag"], 1e3, 5e3)})
    with pytest.raises(RecordingError, match="look like milliseconds"):
        read_recording(path)


@pytest.mark.parametrize(("scale", "offset"), [(1.0, 0.0), (1.0, 1.7e9), (1.0, -1e6), (100.0, 0.0), (1e-3, 0.0)])
def test_stamps_in_seconds_are_read(tmp_path: Path, imu: dict[str, Recording], scale: float, offset: float) -> None:
    """Seconds from 0, since the epoch, negative, a 1 Hz logger and a 100 kHz one are all read unchanged."""
    rec = _restamped(imu["mag"], scale, offset)
    got = read_recording(write_csv(tmp_path / "mag.csv", rec))
    np.testing.assert_array_equal(got.t, rec.t)


def test_a_lone_stamp_beyond_any_clock_is_a_glitch_kept_for_the_stream(tmp_path: Path, imu: dict[str, Recording]) -> None:
    """One stamp of 1e23 s among seconds is no unit: read as it is (the stream drops it as bad_stamp)."""
    rec = _restamped(imu["mag"], 1.0)
    rec.t[100] = 1e23
    got = read_recording(write_csv(tmp_path / "mag.csv", rec), order="file")
    np.testing.assert_array_equal(got.t, rec.t)


@pytest.mark.parametrize("stray", [1e23, 0.0, -5.0])
def test_calibrate_drops_a_lone_stray_stamp_instead_of_moving_the_clock(
    tmp_path: Path, imu: dict[str, Recording], stray: float, capsys: pytest.CaptureFixture[str]
) -> None:
    """``calibrate`` took a lone 1e23 stamp for a logger restart and moved every earlier stamp back by 1e23 s (where
    float64 keeps none of them): the sample is dropped and said, the clock left as it is; a true restart is kept."""
    rec = _restamped(imu["mag"], 1.0, 50.0)
    rec.t[100] = stray
    path = write_csv(tmp_path / "mag.csv", rec)
    assert main(["calibrate", str(path), "--json", str(tmp_path / "c.json"), "--force"]) == 0  # (12 s: a young fit)
    err = capsys.readouterr().err
    assert "dropped 1 sample(s) whose stamp is out of line" in err and "logger restart" not in err, err
    got, glitches = drop_stamp_glitches(read_recording(path, order="file"))
    assert glitches.tolist() == [100] and len(got) == len(rec) - 1
    np.testing.assert_array_equal(got.t, np.delete(rec.t, 100))
    restart = _restamped(imu["mag"], 1.0, 50.0)
    restart.t[600:] -= 50.0  # the logger restarted: no lone stamp, the clock steps back and runs on
    assert drop_stamp_glitches(restart)[1].size == 0
    swapped = _restamped(imu["mag"], 1.0, 50.0)
    swapped.t[[200, 201]] = swapped.t[[201, 200]]  # two samples swapped: a small step back, left to continue_clock
    assert drop_stamp_glitches(swapped)[1].size == 0


@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_calibrate_and_diagnose_refuse_nanosecond_epoch_stamps(
    tmp_path: Path, imu: dict[str, Recording], command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``margcal calibrate`` (it crashed in the gate) and ``diagnose``: exit 2, one line naming nanoseconds."""
    path = write_csv(tmp_path / "tumble_acc.csv", _restamped(imu["accel"], 1e9, 1.7e18))
    extra = ["-o", str(tmp_path / "cal.yaml")] if command == "calibrate" else ["--out", str(tmp_path / "d"), "--quick"]
    assert main([command, str(path), *extra]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("margcal ")]
    assert "Traceback" not in err and len(lines) == 1 and "nanoseconds since the epoch" in lines[0], err


# -- the stream's drop summary says so ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("scale", "offset", "words"),
    [
        (1e9, 1.7e18, "nanoseconds since the epoch"),
        (1e6, 0.0, "microseconds"),
        (0.0, 0.0, "do not advance"),
    ],
)
def test_the_drop_summary_names_stamps_that_are_not_seconds(
    imu: dict[str, Recording], scale: float, offset: float, words: str
) -> None:
    """Nearly every sample dropped as bad_stamp, stamp_jump or repeated_stamp: the summary says why, not counts only."""
    rec = _restamped(imu["accel"], scale, offset)
    intake = Intake(PipelineConfig.for_sensor("accel"), use_gyro=True)
    for t, v in zip(rec.t.tolist(), rec.raw.tolist(), strict=True):
        intake.take(t, v)
    summary = intake.drop_summary()
    assert words in summary and "give" in summary, summary
    assert intake.stamp_note() in summary


def test_the_stamp_note_names_milliseconds_the_intake_takes(imu: dict[str, Recording]) -> None:
    """Milliseconds at 100 Hz step by 10 "s", within max_stamp_gap_s: nothing dropped, the note still names the unit."""
    rec = _restamped(imu["accel"], 1e3)
    intake = Intake(PipelineConfig.for_sensor("accel"))
    for t, v in zip(rec.t.tolist(), rec.raw.tolist(), strict=True):
        intake.take(t, v)
    assert intake.taken == len(rec) and "milliseconds" in intake.stamp_note()


def test_no_stamp_note_for_seconds(imu: dict[str, Recording]) -> None:
    """Seconds at 100 Hz, with a lone glitch: no note."""
    rec = _restamped(imu["mag"], 1.0)
    intake = Intake(PipelineConfig.for_sensor("mag"))
    for i, (t, v) in enumerate(zip(rec.t.tolist(), rec.raw.tolist(), strict=True)):
        intake.take(1e18 if i == 50 else t, v)
    assert intake.stamp_note() == "" and "epoch" not in intake.drop_summary()


# -- bags: a directory without metadata.yaml, suffixes and content --------------------------------------------------


def test_a_directory_without_metadata_names_its_storage_file(tmp_path: Path, imu: dict[str, Recording]) -> None:
    """A bag directory whose metadata.yaml is missing: said so, with the .mcap inside to pass instead."""
    folder = tmp_path / "nometa"
    folder.mkdir()
    inside = write_bag(folder / "imubag.mcap", {"/imu/mag": imu["mag"]})
    with pytest.raises(RecordingError, match=r"directory without metadata\.yaml") as info:
        read_recording(folder)
    assert str(inside) in str(info.value) and "Expected metadata file" not in str(info.value)


@pytest.mark.parametrize("name", ["emptydir", "dir_mag.csv"])
def test_an_empty_directory_is_no_recording(tmp_path: Path, name: str) -> None:
    """An empty directory (also one named like a CSV): no metadata.yaml, no storage file, said in one line."""
    (tmp_path / name).mkdir()
    with pytest.raises(RecordingError, match=r"without metadata\.yaml and has no \.mcap or \.db3"):
        read_recording(tmp_path / name)


@pytest.mark.parametrize(("written", "name"), [("imu.mcap", "IMU.MCAP"), ("imu.db3", "IMU.DB3"), ("imu.mcap", "imu_noext"),
                                               ("imu.db3", "imu_db3.mcap"), ("imu.mcap", "imu_mcap.csv")])
def test_a_bag_file_is_read_by_its_content(tmp_path: Path, imu: dict[str, Recording], written: str, name: str,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """An upper-case suffix, no suffix or the wrong one: the MCAP magic or SQLite header makes it a bag (read
    through a link named as rosbags wants, removed after)."""
    path = write_bag(tmp_path / "bag" / written, {"/imu/mag": imu["mag"]})
    moved = path.rename(tmp_path / "bag" / name)
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    assert is_bag(moved)
    got = read_recording(moved)
    np.testing.assert_allclose(got.t, imu["mag"].t, atol=1e-9)
    assert [p.name for p in (tmp_path / "bag").iterdir()] == [name] and not list((tmp_path / "tmp").iterdir())


def test_a_csv_cell_with_an_underscore_is_refused(tmp_path: Path) -> None:
    """Python's float() reads '1_0e-6' as 1e-5; a CSV cell is no Python literal: refused naming line and column."""
    path = tmp_path / "mag.csv"
    path.write_text("t,x,y,z\n0,1e-5,2e-5,3e-5\n0.01,1_0e-6,2e-5,3e-5\n")
    with pytest.raises(RecordingError, match=r"line 3, column 'x': '1_0e-6' is not a number"):
        read_recording(path)


def test_float_spacing_is_what_broke_the_gate() -> None:
    """The premise: above 1.8e16 s a float cannot tell stamps 2 s apart."""
    assert math.ulp(1.7e18) > 2.0 and math.ulp(1.7e9) < 1e-6
