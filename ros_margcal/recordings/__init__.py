"""Recordings on disk: CSV and rosbag2 (.mcap, .db3), read into a ``Recording`` and written back.

``read.read_recording`` picks the reader by path; ``csvfile`` and ``bag`` do the formats;
``recording`` holds the value and the checks every reader applies. rosbags is needed for bags only.
"""

from __future__ import annotations

from .bag import BAG_SUFFIXES, FRAME_ID, BagMessage, bag_topics, is_bag, iter_bag_messages, write_bag
from .csvfile import guess_sensor, read_csv, write_csv
from .read import read_recording
from .recording import (
    MAX_STAMP_S,
    TIME_ORDERS,
    Recording,
    check_order,
    check_sensor,
    check_stamps,
    continue_clock,
    drop_zero_rows,
    stamp_unit,
    time_order,
)

__all__ = [
    "BAG_SUFFIXES", "FRAME_ID", "MAX_STAMP_S", "TIME_ORDERS", "BagMessage", "Recording", "bag_topics", "check_order",
    "check_sensor", "check_stamps", "continue_clock", "drop_zero_rows", "guess_sensor", "is_bag", "iter_bag_messages",
    "read_csv", "read_recording", "stamp_unit", "time_order", "write_bag",
    "write_csv"
]
