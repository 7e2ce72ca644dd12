"""The readers' time order: refuse, sort, or keep the file's order (a clock restart), and ``continue_clock``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ros_margcal.model.errors import RecordingError
from ros_margcal.recordings import continue_clock, read_recording, write_csv
from ros_margcal.recordings.recording import Recording

RESTART = np.array([100.0, 100.5, 101.0, 0.2, 0.7, 1.2])
"""A logger reboot after the third sample: the clock starts again near 0."""


def _rec() -> Recording:
    return Recording(t=RESTART.copy(), raw=np.arange(18.0).reshape(6, 3) + 1.0, sensor="mag", unit="T")


def _written(tmp_path: Path) -> Path:
    return write_csv(tmp_path / "reboot_mag.csv", _rec())


def test_order_file_keeps_the_csv_as_written(tmp_path: Path) -> None:
    """order="file": the samples and stamps of a restarted clock as the file holds them; "check" refuses it."""
    path = _written(tmp_path)
    rec = read_recording(path, order="file")
    np.testing.assert_array_equal(rec.t, RESTART)
    np.testing.assert_array_equal(rec.raw[:, 0], [1.0, 4.0, 7.0, 10.0, 13.0, 16.0])
    with pytest.raises(RecordingError, match="time goes backwards at 1 place"):
        read_recording(path)
    np.testing.assert_array_equal(read_recording(path, order="sort").t, np.sort(RESTART))


def test_order_file_keeps_a_bag_as_recorded(tmp_path: Path) -> None:
    """A bag whose header stamps restart (received in order) is read as received with order="file" (written by hand:
    ``write_bag`` orders the messages by their stamps)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types_ = store.types
    path = tmp_path / "reboot"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/imu/mag", "sensor_msgs/msg/MagneticField", typestore=store)
        for i, stamp in enumerate(RESTART):
            ns = round(stamp * 1e9)
            header = types_["std_msgs/msg/Header"](stamp=types_["builtin_interfaces/msg/Time"](
                sec=ns // 10**9, nanosec=ns % 10**9), frame_id="imu_link")
            msg = types_["sensor_msgs/msg/MagneticField"](
                header=header, magnetic_field=types_["geometry_msgs/msg/Vector3"](x=float(i), y=0.0, z=0.0),
                magnetic_field_covariance=np.zeros(9))
            writer.write(conn, (10 + i) * 10**9, store.serialize_cdr(msg, conn.msgtype))
    rec = read_recording(path, order="file")
    np.testing.assert_allclose(rec.t, RESTART)
    np.testing.assert_array_equal(rec.raw[:, 0], np.arange(6.0))
    with pytest.raises(RecordingError, match="time goes backwards"):
        read_recording(path)


@pytest.mark.parametrize(("kwargs", "match"), [({"order": "shuffle"}, "order must be one of"),
                                               ({"order": "file", "sort": True}, "contradict")])
def test_bad_order_is_refused(tmp_path: Path, kwargs: dict[str, object], match: str) -> None:
    """An unknown order, or sort=True with order="file", is a RecordingError naming the argument."""
    with pytest.raises(RecordingError, match=match):
        read_recording(_written(tmp_path), **kwargs)  # type: ignore[arg-type]


def test_continue_clock_keeps_every_interval_and_the_file_order() -> None:
    """Each backwards step becomes the typical step; the earlier stamps move back by as much, the last clock's stay,
    nothing is reordered."""
    times, back = continue_clock(RESTART)
    np.testing.assert_array_equal(back, [2])
    np.testing.assert_allclose(times, [-1.3, -0.8, -0.3, 0.2, 0.7, 1.2])
    two = np.array([5.0, 6.0, 1.0, 2.0, 0.0, 1.0])
    times, back = continue_clock(two)
    np.testing.assert_array_equal(back, [1, 3])
    np.testing.assert_allclose(times, [-4.0, -3.0, -2.0, -1.0, 0.0, 1.0])


def test_continue_clock_leaves_an_ordered_clock_alone() -> None:
    """Non-decreasing stamps (repeats included) come back unchanged, with no restart."""
    t = np.array([0.0, 0.0, 1.0, 2.5])
    times, back = continue_clock(t)
    np.testing.assert_array_equal(times, t)
    assert back.size == 0
