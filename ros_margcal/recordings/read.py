"""Reading any recording: CSV or rosbag2, chosen by the path."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..model.errors import RecordingError
from .bag import is_bag, read_bag
from .csvfile import read_csv
from .recording import Recording, check_sensor, time_order

__all__ = ["read_recording"]

log = logging.getLogger(__name__)
Array = NDArray[np.float64]


def read_recording(
    path: str | os.PathLike[str], *, sensor: str | None = None, topic: str | None = None, sort: bool = False,
    order: str = "check",
) -> Recording:
    """Read a CSV or rosbag2 recording of one sensor.

    Args:
        path: a .csv file, a rosbag2 directory, or a .mcap / .db3 file (told by its content, else its suffix in
            any case).
        sensor: "mag" or "accel": for a bag, which message type to read; for a CSV, the label
            (default: guessed from the file name, "mag" / "acc", else "").
        topic: for a bag, the topic to read (needed when several match).
        sort: sort samples whose time goes backwards instead of refusing the file (``order="sort"``).
        order: when the time goes backwards: ``"check"`` refuses the file, ``"sort"`` sorts the samples
            stably, ``"file"`` keeps the file's order and stamps as they are (a clock restart: the streaming
            calibrator starts a new time base itself; ``recording.continue_clock`` gives a batch consumer
            non-decreasing times without interleaving the time bases).

    Returns:
        A Recording without ground truth (``truth`` None).

    Raises:
        RecordingError: missing file, a ROS 1 ``.bag`` (with the command that converts it), bad header,
            non-numeric or non-finite cells, empty file, no (or no unique) matching topic, time going
            backwards (``order="check"``), an unknown ``order``, stamps that are not seconds (with the unit they
            look like: ``recording.check_stamps``), a directory without metadata.yaml.
    """
    check_sensor(sensor)
    how = time_order(order, sort)
    p = Path(path)
    if not p.exists():
        msg = f"recording {p} does not exist"
        raise RecordingError(msg)
    if p.suffix.lower() == ".bag":  # ROS 1: rosbags reads it only through its converter
        msg = (f"{p} is a ROS 1 bag; convert it to rosbag2 first: rosbags-convert --src {p} --dst {p.with_suffix('')} "
               f"(the rosbags package), then pass {p.with_suffix('')}")
        raise RecordingError(msg)
    if is_bag(p):
        return read_bag(p, sensor, topic, how)
    if topic is not None:
        msg = f"topic= applies to rosbag2 recordings, not to {p}"
        raise RecordingError(msg)
    return read_csv(p, sensor, how)
