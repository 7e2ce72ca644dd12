"""Corrupt recordings: a cut .db3 and a bit-flipped .mcap give one error line and exit code 2, never a traceback.

The bags are written with ``write_bag`` into tmp_path and then damaged, so the test does not depend
on shipped files; the damage is placed by structure (the zstd frame magic), not by a byte offset.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import tumbling_imu

from ros_margcal import write_bag
from ros_margcal.cli import main
from ros_margcal.model.errors import RecordingError
from ros_margcal.recordings.bag import iter_bag_messages
from ros_margcal.recordings.read import read_recording
from ros_margcal.recordings.recording import Recording

SEED = 13
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


@pytest.fixture(scope="module")
def imu() -> dict[str, Recording]:
    """Ten seconds of an IMU at 50 Hz: accelerometer and magnetometer topics."""
    acc, mag = tumbling_imu(10.0, 50.0, SEED)
    return {"/imu/data_raw": acc, "/imu/mag": mag}


def _cut_db3(folder: Path, recs: dict[str, Recording]) -> Path:
    path = write_bag(folder / "cut.db3", recs)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


def _flipped_mcap(folder: Path, recs: dict[str, Recording]) -> Path:
    """An .mcap with one bit flipped in the magic number of its first zstd-compressed chunk."""
    path = write_bag(folder / "flipped.mcap", recs)
    data = bytearray(path.read_bytes())
    at = data.index(ZSTD_MAGIC)
    data[at] ^= 0x01
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("damage", [_cut_db3, _flipped_mcap])
@pytest.mark.parametrize("command", [["calibrate", "--sensor", "mag"], ["replay", "-q"]])
def test_corrupt_bag_is_one_line_and_exit_2(
    tmp_path: Path, imu: dict[str, Recording], damage: object, command: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """``margcal calibrate`` and ``margcal replay`` on a damaged bag: exit code 2, one error line naming the file."""
    path = damage(tmp_path, imu)  # type: ignore[operator]
    code = main([command[0], str(path), *command[1:]])
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("margcal ")]
    assert len(lines) == 1 and lines[0].startswith(f"margcal {command[0]}: error: ") and str(path) in lines[0], err


def test_iter_bag_messages_turns_a_decompression_failure_into_recording_error(
    tmp_path: Path, imu: dict[str, Recording]
) -> None:
    """The streaming reader fails while iterating (not at open) and says which file and why."""
    path = _flipped_mcap(tmp_path, imu)
    with pytest.raises(RecordingError, match="cannot read messages") as info:
        list(iter_bag_messages(path))
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_read_recording_refuses_a_cut_db3(tmp_path: Path, imu: dict[str, Recording]) -> None:
    """The offline reader gives a RecordingError for a half file, not an apsw error."""
    path = _cut_db3(tmp_path, imu)
    with pytest.raises(RecordingError, match=r"not a readable rosbag2 bag|cannot read messages"):
        read_recording(path, sensor="mag")


def test_an_error_of_the_consumer_is_not_blamed_on_the_bag(tmp_path: Path, imu: dict[str, Recording]) -> None:
    """An exception raised by the code consuming the messages propagates as itself."""
    path = write_bag(tmp_path / "good.mcap", imu)
    with pytest.raises(KeyError, match="consumer"):
        for _ in iter_bag_messages(path):
            raise KeyError("consumer")


def test_csv_with_a_bom_is_read(tmp_path: Path) -> None:
    """A spreadsheet's UTF-8 export starts with a byte order mark; the header is still 't,x,y,z'."""
    path = tmp_path / "mag.csv"
    path.write_bytes("t,x,y,z\r\n0,1,2,3\r\n0.5,4,5,6\r\n".encode("utf-8-sig"))
    rec = read_recording(path)
    assert rec.sensor == "mag"
    np.testing.assert_array_equal(rec.t, [0.0, 0.5])
    np.testing.assert_array_equal(rec.raw, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])


def test_replay_of_a_bag_without_messages_fails_like_calibrate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A bag whose topic holds no messages: replay exits 2 with one line, as calibrate does (it used to print
    "final state after 0 messages" and exit 0)."""
    empty = Recording(t=np.zeros(0), raw=np.zeros((0, 3)), sensor="mag", unit="T")
    path = write_bag(tmp_path / "empty.mcap", {"imu/mag": empty})
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert ("no sensor_msgs/Imu or MagneticField messages" in err or "holds no messages" in err) and "Traceback" not in err
    assert main(["calibrate", str(path), "--sensor", "mag"]) == 2


@pytest.mark.parametrize("command", ["calibrate", "replay", "diagnose"])
def test_a_ros1_bag_is_refused_with_the_command_that_converts_it(tmp_path: Path, command: str,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A ROS 1 .bag: exit 2, one line naming rosbags-convert with this file (not a CSV header complaint)."""
    bag = tmp_path / "drive.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n" + bytes(64))
    assert main([command, str(bag), "--sensor", "mag"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("margcal ")]
    assert len(err) == 1 and "ROS 1 bag" in err[0] and f"rosbags-convert --src {bag}" in err[0], err
